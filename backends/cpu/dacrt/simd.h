// SPDX-License-Identifier: MIT
// simd.h — the SIMD kernel policy of divide-and-conquer ray tracing (dacrt/recursion.h): the
// filter tests eight ray records per pass (a transpose of eight 32-byte records to SoA rows, as
// the paper's AVX filter), the leaf tests up to 64 rays against one triangle at a time with the
// packets' lane-by-lane watertight test (packet/triangle.h: each lane's own shear axes, the
// undecided lanes by tri_test itself). The same operations as the scalar policy
// (dacrt_scalar.cpp), lane by lane, so the same decisions and bytes.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/dacrt/recursion.h"
#include "backends/cpu/packet/packet.h"
#include "backends/cpu/packet/triangle.h"
#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/ray.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace dacrt {

/// What the leaf reads of a ray beyond its record, by id: the watertight test's shear
/// and axes, the best hit so far (its t is the record's tmax) and the direction (the fast
/// precision's Möller–Trumbore).
struct SimdSide {
  float s[3];         ///< sx, sy, sz
  std::uint8_t k[4];  ///< kx, ky, kz
  float u, v;
  std::uint32_t prim;
  float d[3];
};
static_assert(sizeof(SimdSide) == kDacrtSimdSideBytes, "the dacrt backends' state_bytes counts it");

struct SimdPolicy {
  using Side = SimdSide;
  /// The leaf's packet of up to 64 rays.
  struct Local {
    std::unique_ptr<packet::Packet> P = std::make_unique<packet::Packet>();
  };

  static bool set_up(const Ray& r, RayRec& rec, SimdSide& sd, bool fast) {
    RayPre p;
    if (!prepare_ray_simd(r, p)) return false;
    if (fast) relax_ray(p);
    fill_record(p, rec);
    for (int a = 0; a < 3; ++a) sd.d[a] = p.d[a];
    sd.s[0] = p.sx;
    sd.s[1] = p.sy;
    sd.s[2] = p.sz;
    sd.k[0] = static_cast<std::uint8_t>(p.kx);
    sd.k[1] = static_cast<std::uint8_t>(p.ky);
    sd.k[2] = static_cast<std::uint8_t>(p.kz);
    sd.k[3] = 0;
    sd.u = sd.v = 0.0f;
    sd.prim = MBVH_MISS_PRIM;
    return true;
  }
  static Hit best(const Work<SimdPolicy>& w, std::size_t p) {
    const SimdSide& sd = w.side[w.id[p]];
    return sd.prim == MBVH_MISS_PRIM ? miss_hit() : Hit{w.rec[p].tmax, sd.u, sd.v, sd.prim};
  }

  /// One bit a ray, eight records per pass: box_hit's operations lane by lane (blendv on the sign
  /// of inv picks the near plane as signbit does; maxps/minps discard NaN as max_nan/min_nan).
  template <bool Fast>
  static std::size_t test(Work<SimdPolicy>& w, std::size_t n, const Bounds& b) {
    const __m256 lo[3] = {_mm256_set1_ps(b.lo[0]), _mm256_set1_ps(b.lo[1]), _mm256_set1_ps(b.lo[2])};
    const __m256 hi[3] = {_mm256_set1_ps(b.hi[0]), _mm256_set1_ps(b.hi[1]), _mm256_set1_ps(b.hi[2])};
    const __m256 kf = _mm256_set1_ps(kFarFactor), slack = _mm256_set1_ps(kCullSlack);
    std::size_t na = 0;
    for (std::size_t base = 0; base < n; base += 64) {
      std::uint64_t word = 0;
      const std::size_t e = std::min(n, base + 64);
      std::size_t p = base;
      for (; p + 8 <= e; p += 8) {
        __m256 r[8];
        for (int l = 0; l < 8; ++l) r[l] = _mm256_load_ps(w.rec[p + l].o);
        transpose8(r);  // o x, y, z, tmin, inv x, y, z, tmax
        __m256 tn[3], tf[3];
        for (int a = 0; a < 3; ++a) {
          const __m256 inv = r[4 + a];
          const __m256 near = _mm256_blendv_ps(lo[a], hi[a], inv), far = _mm256_blendv_ps(hi[a], lo[a], inv);
          tn[a] = _mm256_mul_ps(_mm256_sub_ps(near, r[a]), inv);
          tf[a] = _mm256_mul_ps(_mm256_sub_ps(far, r[a]), Fast ? inv : _mm256_mul_ps(inv, kf));
        }
        const __m256 te = _mm256_max_ps(tn[2], _mm256_max_ps(tn[1], _mm256_max_ps(tn[0], r[3])));
        const __m256 tx = _mm256_min_ps(tf[2], _mm256_min_ps(tf[1], _mm256_min_ps(tf[0], _mm256_mul_ps(r[7], slack))));
        word |= std::uint64_t(static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(te, tx, _CMP_LE_OQ)))) << (p - base);
      }
      for (; p < e; ++p) word |= std::uint64_t(box_hit<Fast>(w.rec[p], b) ? 1 : 0) << (p - base);
      w.bits[base / 64] = word;
      na += static_cast<std::size_t>(std::popcount(word));
    }
    return na;
  }

  /// The rays [0, na) against the triangles tri[tb, te), 64 rays at a time: each triangle against
  /// every SIMD ray of the packet (tri_group: watertight; tri_group_mt: fast), keeping each ray's
  /// smallest (t, prim) (closest) or stopping a ray at its first hit (any).
  template <bool Any, bool Fast, bool Stats>
  static void leaf(Work<SimdPolicy>& w, std::size_t na, std::uint32_t tb, std::uint32_t te) {
    using packet::Packet;
    using packet::kLanes;
    Packet& P = *w.local->P;
    P.src = w.rays;  // an undecided lane prepares its own ray from the batch, by id
    for (std::size_t p0 = 0; p0 < na; p0 += Packet::N) {
      const int cnt = static_cast<int>(std::min<std::size_t>(Packet::N, na - p0));
      const int groups = (cnt + kLanes - 1) / kLanes;
      std::uint32_t code0 = 0;
      bool uniform = true;
      for (int s = 0; s < cnt; ++s) {  // the side records lie anywhere: every one asked for first
        const char* line = reinterpret_cast<const char*>(&w.side[w.id[p0 + s]]);
        __builtin_prefetch(line);
        __builtin_prefetch(line + sizeof(SimdSide) - 1);
      }
      for (int s = 0; s < groups * kLanes; ++s) {
        if (s >= cnt) {  // a lane past the rays: never tested (masked), its values only kept finite
          for (int a = 0; a < 3; ++a) {
            P.to[a][s] = P.ts[a][s] = P.o[a][s] = P.d[a][s] = 0.0f;
            P.k1[a][s] = P.k2[a][s] = 0;
          }
          P.tmin[s] = 0.0f;
          P.t[s] = -1.0f;
          P.u[s] = P.v[s] = 0.0f;
          P.prim[s] = MBVH_MISS_PRIM;
          continue;
        }
        const RayRec& rec = w.rec[p0 + s];
        const SimdSide& sd = w.side[w.id[p0 + s]];
        for (int a = 0; a < 3; ++a) {
          P.to[a][s] = rec.o[sd.k[a]];
          P.ts[a][s] = sd.s[a];
          P.k1[a][s] = -static_cast<std::int32_t>(sd.k[a] == 1);
          P.k2[a][s] = -static_cast<std::int32_t>(sd.k[a] == 2);
          if constexpr (Fast) {
            P.o[a][s] = rec.o[a];
            P.d[a][s] = sd.d[a];
          }
        }
        P.tmin[s] = rec.tmin;
        P.t[s] = rec.tmax;
        P.u[s] = sd.u;
        P.v[s] = sd.v;
        P.prim[s] = sd.prim;
        const std::uint32_t code = sd.k[0] | sd.k[1] << 2 | sd.k[2] << 4;
        if (s == 0) code0 = code;
        uniform = uniform && code == code0;
      }
      for (int g = 0; g < groups; ++g) {
        const int left = cnt - g * kLanes;
        P.live[g] = P.valid[g] = static_cast<packet::LaneBits>(left >= kLanes ? packet::kAllLanes : (1u << left) - 1u);
      }
      P.src_of = w.id + p0;
      P.uniform_k = uniform;
      P.k[0] = code0 & 3;
      P.k[1] = code0 >> 2 & 3;
      P.k[2] = code0 >> 4 & 3;
      P.tcull_lo = INFINITY;
      for (std::uint32_t j = tb; j < te; ++j) {
        const Tri& tri = w.tris[w.tri[j].id];
        packet::PV vb[3][3];
        const float* rows[3] = {tri.v0, tri.v1, tri.v2};
        for (int q = 0; q < 3; ++q)
          for (int a = 0; a < 3; ++a) vb[q][a] = packet::PL::set1(rows[q][a]);
        bool any_left = false;
        for (int g = 0; g < groups; ++g) {
          const unsigned lanes = P.live[g];
          if (lanes == 0) continue;
          if constexpr (Stats)
            for (unsigned l = lanes; l != 0; l &= l - 1) ++w.stats[w.id[p0 + g * kLanes + std::countr_zero(l)]].tris;
          unsigned hit;
          if constexpr (Fast) hit = packet::tri_group_mt<Any>(P, g, tri, vb, lanes);
          else hit = uniform ? packet::tri_group<Any, true>(P, g, tri, vb, lanes) : packet::tri_group<Any, false>(P, g, tri, vb, lanes);
          if constexpr (Any) {
            for (unsigned h = hit; h != 0; h &= h - 1) {
              const std::size_t at = p0 + g * kLanes + std::countr_zero(h);
              w.occluded[w.id[at]] = 1;
              w.rec[at].tmax = -1.0f;  // below every tmin: every later filter drops the ray
            }
            P.live[g] = static_cast<packet::LaneBits>(lanes & ~hit);
            any_left = any_left || P.live[g] != 0;
          }
        }
        if constexpr (Any)
          if (!any_left) break;
      }
      if constexpr (!Any)
        for (int s = 0; s < cnt; ++s) {
          SimdSide& sd = w.side[w.id[p0 + s]];
          w.rec[p0 + s].tmax = P.t[s];
          sd.u = P.u[s];
          sd.v = P.v[s];
          sd.prim = P.prim[s];
        }
    }
  }
};

/// The ISA's dacrt entry (CpuKernels::dacrt).
inline void trace_dacrt(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out,
                        unsigned threads, const DacrtSettings& s, DacrtBuffers& buffers) {
  trace<SimdPolicy>(acc, rays, opt, out, threads, s, buffers);
}

}  // namespace dacrt
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

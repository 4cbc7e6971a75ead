// SPDX-License-Identifier: MIT
// triangle.h — one triangle against a SIMD ray of a packet, lane by lane: the watertight test and
// the fast mode's Möller–Trumbore on the single-ray leaves' lane cores (simd/triangle.h).
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/packet/packet.h"
#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/ray.h"
#include "backends/cpu/simd/triangle.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace packet {

/// Closest hit, SIMD ray at lane i: the lanes of `sure` hit at t (u = un / det, v = vn / det);
/// each keeps the smaller (t, prim) as visit_leaf does (t <= its best t holds: replaced on t below
/// it or a smaller prim), its tmax shrinking to t.
[[gnu::always_inline]] inline void keep_closest(Packet& P, int i, unsigned sure, PV t, PV tmax, PV un, PV vn, PV det,
                                                std::uint32_t prim) {
  if (sure == 0) return;
  const unsigned smaller = PL::ugt(P.prim + i, prim);  // prim < best
  const unsigned upd = sure & (PL::bits(PL::cmp<_CMP_LT_OQ>(t, tmax)) | smaller);
  if (upd == 0) return;
  PL::store_a(P.t + i, PL::sel(upd, tmax, t));
  P.tcull_lo = std::min(P.tcull_lo, PL::hmin(PL::sel(upd, PL::set1(INFINITY), t)) * kCullSlack);
  PL::store_a(P.u + i, PL::sel(upd, PL::load(P.u + i), PL::div(un, det)));
  PL::store_a(P.v + i, PL::sel(upd, PL::load(P.v + i), PL::div(vn, det)));
  PL::store_prim(P.prim + i, upd, prim);
}

/// The `fast` precision's triangle test against the lanes `m` of SIMD ray g: mt_lanes, the
/// operations of tri_test_simd_mt, lane by lane (Möller–Trumbore with FMA and the refined reciprocal estimate), so a
/// ray's answer is the one the cpu backend's single-ray fast traversals give it (the hybrid's
/// too). Closest hit keeps each lane's smallest (t, prim); any hit returns the lanes that hit.
template <bool Any>
[[gnu::always_inline]] inline unsigned tri_group_mt(Packet& P, int g, const Tri& tri, const PV (&vb)[3][3], unsigned m) {
  using F = PL;
  const int i = g * kLanes;
  PV v0[3], e1[3], e2[3], d[3], s[3];
  for (int a = 0; a < 3; ++a) {
    v0[a] = vb[0][a];
    e1[a] = F::sub(vb[1][a], v0[a]);
    e2[a] = F::sub(vb[2][a], v0[a]);
    d[a] = F::load(P.d[a] + i);
    s[a] = F::sub(F::load(P.o[a] + i), v0[a]);
  }
  PV t, u, v;
  const PV tmax = F::load(P.t + i);
  const auto ok = mt_lanes<PL>(e1, e2, d, s, F::load(P.tmin + i), tmax, t, u, v);
  const PV one = F::set1(1.0f);
  const unsigned hit = m & F::bits(ok);
  if constexpr (!Any) keep_closest(P, i, hit, t, tmax, u, v, one, tri_prim(tri));
  return hit;
}

/// The SIMD ray's lanes at i: their coordinate of `role` (their kx, ky or kz) of the vertex rows v.
[[gnu::always_inline]] inline PV select_role(const Packet& P, int i, int role, const PV (&v)[3]) {
  return PL::pick_k(v[0], v[1], v[2], P.k1[role] + i, P.k2[role] + i);
}

/// The [tmin, tmax] of the SIMD ray's lanes at i (watertight_lanes' range).
struct LaneRange {
  const float* tmin;
  const float* tmax;
  [[gnu::always_inline]] PV lo() const { return PL::load(tmin); }
  [[gnu::always_inline]] PV hi() const { return PL::load(tmax); }
};

/// One triangle against the lanes `m` of SIMD ray g: tri_test (intersect.h) lane by lane — the
/// shear of each lane's own axes, the same operations in the same order, the undecided lanes by
/// tri_test itself. Closest hit: keeps each lane's smallest (t, prim) as visit_leaf does. Any
/// hit: returns the lanes that hit.
template <bool Any, bool UniformK>
[[gnu::always_inline]] inline unsigned tri_group(Packet& P, int g, const Tri& tri, const PV (&vb)[3][3], unsigned m) {
  using F = PL;
  const int i = g * kLanes;
  const PV o[3] = {F::load(P.to[0] + i), F::load(P.to[1] + i), F::load(P.to[2] + i)};
  const PV s[3] = {F::load(P.ts[0] + i), F::load(P.ts[1] + i), F::load(P.ts[2] + i)};
  PV X[3], Y[3], Z[3];
  for (int q = 0; q < 3; ++q) {
    if constexpr (UniformK)
      shear_lanes<F>(vb[q][P.k[0]], vb[q][P.k[1]], vb[q][P.k[2]], o, s, X[q], Y[q], Z[q]);
    else
      shear_lanes<F>(select_role(P, i, 0, vb[q]), select_role(P, i, 1, vb[q]), select_role(P, i, 2, vb[q]), o, s, X[q],
                     Y[q], Z[q]);
  }
  Watertight<F> w;
  watertight_lanes<F>(X, Y, Z, LaneRange{P.tmin + i, P.t + i}, m, w);
  unsigned sure = w.sure;
  const unsigned fallback = w.exact0 | (w.cand & ~sure);
  if constexpr (!Any)
    if (w.cand != 0) keep_closest(P, i, sure, w.t, F::load(P.t + i), w.V, w.W, w.det, tri_prim(tri));
  for (unsigned f = fallback; f != 0; f &= f - 1) {  // the rare undecided lanes: tri_test itself
    const int l = i + std::countr_zero(f);
    float tt, uu, vv;
    RayPre pre{};
    prepare_ray_simd(P.src[P.src_of ? P.src_of[l] : static_cast<std::uint32_t>(ray_of(l))], pre);  // valid: only live lanes are tested
    if (tri_test(pre, tri, P.t[l], tt, uu, vv)) {
      if constexpr (Any) {
        sure |= 1u << (l - i);
      } else {
        const std::uint32_t pr = tri_prim(tri);
        if (tt < P.t[l] || pr < P.prim[l]) {
          P.t[l] = tt;
          P.tcull_lo = std::min(P.tcull_lo, tt * kCullSlack);
          P.u[l] = uu;
          P.v[l] = vv;
          P.prim[l] = pr;
        }
      }
    }
  }
  return sure;
}

}  // namespace packet
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

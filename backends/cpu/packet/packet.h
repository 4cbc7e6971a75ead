// SPDX-License-Identifier: MIT
// packet.h — the cpu backend's coherent packets of rays (Áfra's thesis, ch. 2): their layout,
// their loading with the frustum and the hybrid switch.
//
// A packet is kPacketRays rays in an array-of-structures-of-arrays layout: G SIMD rays of
// 8 lanes (AVX2: a 4x2 block of an 8x8 tile each, MBVH_PACKET_RAYS = 64 rays) or 16 lanes
// (AVX-512: a 4x4 block, MBVH_PACKET_RAYS_16 = 128 rays, two tiles; ray_of). It walks the binary tree (MBVH2) of the one build:
// - ranged traversal (Wald, Boulos & Shirley, "Ray Tracing Deformable Scenes Using Dynamic
//   Bounding Volume Hierarchies", TOG 2007): the SIMD rays from the first to the last active one;
// - partition traversal (Overbeck, Ramamoorthi & Mark, "Large Ray Packets for Real-Time Whitted
//   Ray Tracing", IRT 2008): a list of the active SIMD rays, partitioned at every node;
// both cull a node for the whole packet first with interval arithmetic over the packet's origins
// and reciprocal directions (Boulos, Wald & Shirley 2006's frustum test).
//
// Exact per ray. Every lane carries its own mask along the path: a ray is tested against a box
// only where it passed every box above it, with its own conservative slab test (Ize 2013, the
// same operations as box_test), and against a triangle only in a leaf it reached so, with the
// watertight test lane by lane (tri_test's operations; the undecided lanes go to tri_test
// itself), keeping the smallest (t, prim) as visit_leaf does. The packet's order of children is
// not each ray's own, and it walks MBVH2 whatever layout the reference walks; but the smallest
// (t, prim) over the leaves a ray reaches does not depend on the order (its shrinking tmax only
// culls boxes that cannot hold a better hit, the boxes being conservative: the same argument that
// makes the MBVH2, MBVH4 and MBVH8 traversals agree), so its answer is its single-ray
// traversal's (packet_single_ray), bit for bit — but for the rare ray whose reference answer
// itself depends on the order (two hits within rounding at a corner, where a box's slab entry
// lies a few ulps past a triangle's watertight t: a classified tie; docs/backends.md). The
// frustum test decides for the whole packet only where that is exact: no lane can pass a box, or every lane does (rounding is monotone, so the
// interval's bounds bound every lane's computed entry and exit; frustum_cover). `fast`
// precision: the relaxed box test and tri_test_simd_mt's Möller–Trumbore lane by lane, the cpu
// backend's single-ray fast answers.
//
// Hybrid (as Embree's hybrid traversal drops to single rays): a packet whose rays' unit
// directions span kSpread or more on an axis has little coherence; it is traced ray by ray with
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/lanes16.h"
#include "backends/cpu/simd/ray.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace packet {

// The SIMD ray's width: 16 lanes (F16, mask registers) in the AVX-512 build, 8 (F8) in the AVX2
// one; MBVH_PACKET_LANES=8 compiles the AVX-512 build with 8 lanes too (a comparison).
#ifndef MBVH_PACKET_LANES
#if MBVH_CPU_ISA_ID == 2
#define MBVH_PACKET_LANES 16
#else
#define MBVH_PACKET_LANES 8
#endif
#endif
#if MBVH_PACKET_LANES == 16 && MBVH_CPU_ISA_ID != 2
#error "16-lane packets need the AVX-512 build"
#endif
constexpr int kLanes = MBVH_PACKET_LANES;
static_assert(kLanes == 8 || kLanes == 16, "a SIMD ray is 8 or 16 lanes");
// 16-lane SIMD rays: packets of two 8x8 tiles by default (eight SIMD rays of 4x4, as 64 rays
// make eight of 8 lanes), which measured faster than one tile (docs/benchmarks.md, AVX-512).
#ifndef MBVH_PACKET_RAYS_16
#define MBVH_PACKET_RAYS_16 (2 * MBVH_PACKET_RAYS)
#endif
/// The rays of a packet: MBVH_PACKET_RAYS, or MBVH_PACKET_RAYS_16 with 16-lane SIMD rays.
constexpr int kPacketRays = kLanes == 16 ? MBVH_PACKET_RAYS_16 : MBVH_PACKET_RAYS;
constexpr int kGroups = kPacketRays / kLanes;
static_assert(kGroups * kLanes == kPacketRays && kGroups <= 32, "a packet is whole SIMD rays, at most 32");
/// The lanes of a SIMD ray as bits.
using LaneBits = std::conditional_t<kLanes == 16, std::uint16_t, std::uint8_t>;
constexpr unsigned kAllLanes = (1u << kLanes) - 1u;

/// The packet traversal's lane operations: F8 or F16's, and the few a packet needs beside them
/// (a lane set's blend, reductions, the integer rows). 16 lanes keep lane sets in mask registers.
#if MBVH_PACKET_LANES == 16
struct PL : F16 {
  /// a where m's bit is clear, b where it is set.
  static V sel(unsigned m, V a, V b) { return _mm512_mask_blend_ps(static_cast<__mmask16>(m), a, b); }
  /// a where s's sign bit is clear, b where it is set.
  static V sel_sign(V a, V b, V s) { return _mm512_mask_blend_ps(_mm512_movepi32_mask(_mm512_castps_si512(s)), a, b); }
  static float hmin(V v) { return _mm512_reduce_min_ps(v); }
  static float hmax(V v) { return _mm512_reduce_max_ps(v); }
  /// The lanes where the rows of all ones at p are set.
  static unsigned ones(const std::int32_t* p) { return _mm512_movepi32_mask(_mm512_load_si512(p)); }
  /// Per lane: c0, c1 or c2 as the lane's k is 0, 1 or 2 (the rows k1, k2: all ones where k == 1, 2).
  static V pick_k(V c0, V c1, V c2, const std::int32_t* k1, const std::int32_t* k2) {
    return sel(ones(k2), sel(ones(k1), c0, c1), c2);
  }
  /// The lanes where the unsigned row at a exceeds b.
  static unsigned ugt(const std::uint32_t* a, std::uint32_t b) {
    return _mm512_cmpgt_epu32_mask(_mm512_load_si512(a), _mm512_set1_epi32(static_cast<int>(b)));
  }
  static void store_a(float* d, V v) { _mm512_store_ps(d, v); }
  static void store_prim(std::uint32_t* d, unsigned m, std::uint32_t prim) {
    _mm512_mask_storeu_epi32(d, static_cast<__mmask16>(m), _mm512_set1_epi32(static_cast<int>(prim)));
  }
};
#else
struct PL : F8 {
  static V sel(unsigned m, V a, V b) { return _mm256_blendv_ps(a, b, lane_mask(m)); }
  static V sel_sign(V a, V b, V s) { return _mm256_blendv_ps(a, b, s); }
  static float hmin(V v) { return hmin8(v); }
  static float hmax(V v) { return hmax8(v); }
  static V pick_k(V c0, V c1, V c2, const std::int32_t* k1, const std::int32_t* k2) {
    return select3(c0, c1, c2, _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(k1))),
                   _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(k2))));
  }
  static unsigned ugt(const std::uint32_t* a, std::uint32_t b) {
    const __m256i bias = _mm256_set1_epi32(INT32_MIN);
    const __m256i x = _mm256_load_si256(reinterpret_cast<const __m256i*>(a));
    return static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(
        _mm256_cmpgt_epi32(_mm256_xor_si256(x, bias), _mm256_xor_si256(_mm256_set1_epi32(static_cast<int>(b)), bias)))));
  }
  static void store_a(float* d, V v) { _mm256_store_ps(d, v); }
  static void store_prim(std::uint32_t* d, unsigned m, std::uint32_t prim) {
    const __m256i x = _mm256_load_si256(reinterpret_cast<const __m256i*>(d));
    _mm256_store_si256(reinterpret_cast<__m256i*>(d), _mm256_castps_si256(_mm256_blendv_ps(
        _mm256_castsi256_ps(x), _mm256_castsi256_ps(_mm256_set1_epi32(static_cast<int>(prim))), lane_mask(m))));
  }
};
#endif
using PV = PL::V;

/// The packet's ray in slot g * kLanes + l (lane l of SIMD ray g). Rays arrive in 8x8 image tiles,
/// row by row (raygen, render); a SIMD ray is a block of a tile, as in the thesis (ch. 2: 4x2
/// SIMD rays of 8 lanes, 4x4 of 16), not a row: its lanes lie closer together, so more of them
/// take the same branch (a higher SIMD utilisation, docs/benchmarks.md). Slot -> ray within
/// each 64 rays: block (g & 1, g >> 1) of 4 x (kLanes / 4), lane (l & 3, l >> 2) within it. Rays
/// that are no tile (secondary rays in arrival order) are as coherent either way. A permutation:
/// every ray of the packet has one slot.
constexpr int ray_of(int slot) {
  if constexpr (kPacketRays % 64 != 0) {
    return slot;
  } else {
    constexpr int rows = kLanes / 4;  // a block's rows
    const int g = (slot & 63) / kLanes, l = slot & (kLanes - 1);
    return (slot & ~63) | (((g >> 1) * rows + (l >> 2)) * 8 + (g & 1) * 4 + (l & 3));
  }
}

/// One packet's rays, SoA per SIMD ray (lane l of SIMD ray g is ray ray_of(g * kLanes + l) of the packet).
struct Packet {
  static constexpr int N = kPacketRays;
  alignas(64) float o[3][N], d[3][N], inv[3][N], invf[3][N], tmin[N];
  alignas(64) float oi[3][N];  ///< `fast` only: o * inv, the box test's FMA form (finish_fast_ray's)
  alignas(64) float tol[N];    ///< `fast` only: finish_fast_ray's tol, added to the cull bound
  alignas(64) float t[N], u[N], v[N];  ///< the best hit so far; t is the lane's tmax
  alignas(64) std::uint32_t prim[N];
  alignas(64) float to[3][N], ts[3][N];            ///< the triangle test's permuted origin and shear
  alignas(64) std::int32_t k1[3][N], k2[3][N];     ///< role x, y, z reads coordinate 1 / 2 (all ones)
  const mbvh::Ray* src = nullptr;  ///< the packet's rays (the scalar test of an undecided lane prepares its own)
  /// Where slot s's ray is in src: src_of[s] when set (dacrt's leaves, whose rays are ids into
  /// their batch), else ray_of(s).
  const std::uint32_t* src_of = nullptr;
  LaneBits live[kGroups];   ///< valid lanes; any hit: not yet occluded
  LaneBits valid[kGroups];  ///< valid lanes (the counters of the others stay 0)
  bool uniform_k = false;      ///< every valid lane has the same kx, ky, kz
  int k[3] = {0, 1, 2};
  // the frustum: interval bounds of the valid lanes, per axis (lane 3 unused)
  bool frustum = false;
  bool same_sign = false;  ///< every valid lane has the same direction signs (neg below)
  alignas(16) std::int32_t axis_off[4];  ///< all ones on an axis the frustum cannot bound
  alignas(16) float o_lo[4], o_hi[4], inv_lo[4], inv_hi[4], invf_lo[4], invf_hi[4];
  std::int32_t neg[3] = {0, 0, 0};  ///< the common sign of each axis (frustum only)
  float tmin_lo = 0, tmin_hi = 0, tcull_hi = 0;
  float tcull_lo = 0;  ///< at most every valid lane's t * kCullSlack (lowered as hits shrink t)
};

/// The hybrid switch: a packet is traced as one when its rays' unit directions span less than
/// kSpread on every axis (a packet of an 8x8 tile of a primary image spans about 0.05; diffuse
/// rays span nearly 2); otherwise ray by ray. Invalid rays do not count.
constexpr float kSpread = 0.5f;

/// Per lane: the row of (x, y, z) that k (0, 1, 2, as the masks k == 1, k == 2) names.
[[gnu::always_inline]] inline __m256 pick3(const __m256 (&v)[3], __m256i k) {
  const __m256 is1 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(k, _mm256_set1_epi32(1)));
  const __m256 is2 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(k, _mm256_set1_epi32(2)));
  return select3(v[0], v[1], v[2], is1, is2);
}

/// Whether the unit directions bounded by [lo, hi] (per axis, per lane) span kSpread or more on
/// some axis (no valid direction yet: no).
[[gnu::always_inline]] inline bool spread_exceeds(const __m256 (&lo)[3], const __m256 (&hi)[3]) {
  for (int a = 0; a < 3; ++a)
    if (hmax8(hi[a]) - hmin8(lo[a]) >= kSpread) return true;  // -inf - inf when none: false
  return false;
}

/// Fills the packet from rays[0, n), eight rays at a time in vector registers: prepare_ray's
/// checks and per-ray constants (prepare_ray_simd's, the same IEEE operations, so every bit is
/// the scalar's) as SoA rows, and the frustum. Counts the invalid rays in `invalid`. Returns
/// false when `hybrid` and the rays are too incoherent for a packet (kSpread): the caller traces
/// them ray by ray instead (the packet is then incomplete).
template <bool Fast>
inline bool load_packet(Packet& P, const mbvh::Ray* rays, int n, std::size_t& invalid, bool hybrid = true) {
  P.src = rays;
  const __m256 inf = _mm256_set1_ps(INFINITY), ninf = _mm256_set1_ps(-INFINITY), zero = _mm256_setzero_ps();
  const __m256 sign = _mm256_set1_ps(-0.0f);
  __m256 ulo[3] = {inf, inf, inf}, uhi[3] = {ninf, ninf, ninf};  // unit directions
  __m256 olo[3] = {inf, inf, inf}, ohi[3] = {ninf, ninf, ninf}, ilo[3] = {inf, inf, inf}, ihi[3] = {ninf, ninf, ninf};
  __m256 jlo[3] = {inf, inf, inf}, jhi[3] = {ninf, ninf, ninf}, tmin_lo = inf, tmin_hi = ninf, tcull_hi = ninf, tcull_lo = inf;
  unsigned neg_any[3] = {0, 0, 0}, pos_any[3] = {0, 0, 0};
  __m256i codes = _mm256_setzero_si256();
  bool any_valid = false;
  for (int g = 0; g < kGroups; ++g) P.live[g] = P.valid[g] = 0;
  for (int c = 0; c < kPacketRays / 8; ++c) {  // eight slots at a time, whatever the SIMD ray's width
    const int i = c * 8;
    __m256 r[8];
    unsigned in_batch = 0;
    for (int l = 0; l < 8; ++l) {
      const int at = ray_of(i + l);
      in_batch |= (at < n ? 1u : 0u) << l;
      r[l] = at < n ? _mm256_loadu_ps(&rays[at].ox) : zero;  // a missing ray: d = 0, invalid
    }
    transpose8(r);
    const __m256 o[3] = {r[0], r[1], r[2]}, d[3] = {r[4], r[5], r[6]};
    const __m256 tmin = r[3], tmax = r[7];
    // prepare_ray's checks: o, tmin, d finite, tmax not NaN, 0 <= tmin <= tmax, the largest
    // direction component normal
    __m256 ok = _mm256_cmp_ps(tmax, tmax, _CMP_ORD_Q);
    for (const __m256& x : {o[0], o[1], o[2], tmin, d[0], d[1], d[2]}) ok = _mm256_and_ps(ok, _mm256_cmp_ps(_mm256_andnot_ps(sign, x), inf, _CMP_LT_OQ));
    ok = _mm256_and_ps(ok, _mm256_and_ps(_mm256_cmp_ps(tmin, zero, _CMP_GE_OQ), _mm256_cmp_ps(tmin, tmax, _CMP_LE_OQ)));
    const __m256 ad[3] = {_mm256_andnot_ps(sign, d[0]), _mm256_andnot_ps(sign, d[1]), _mm256_andnot_ps(sign, d[2])};
    const __m256 y_gt = _mm256_cmp_ps(ad[1], ad[0], _CMP_GT_OQ);
    const __m256 amax01 = _mm256_blendv_ps(ad[0], ad[1], y_gt);
    const __m256 z_gt = _mm256_cmp_ps(ad[2], amax01, _CMP_GT_OQ);
    const __m256 amax = _mm256_blendv_ps(amax01, ad[2], z_gt);
    ok = _mm256_and_ps(ok, _mm256_cmp_ps(amax, _mm256_set1_ps(std::numeric_limits<float>::min()), _CMP_GE_OQ));
    const unsigned valid = static_cast<unsigned>(_mm256_movemask_ps(ok)) & in_batch;
    invalid += static_cast<std::size_t>(std::popcount(in_batch & ~valid));
    P.live[i / kLanes] = P.valid[i / kLanes] = static_cast<LaneBits>(P.valid[i / kLanes] | valid << (i % kLanes));
    const __m256 vm = lane_mask(valid);
    // kz = the largest |d| (ties to the lower axis), kx, ky the next two, swapped when d[kz] < 0
    const __m256i one = _mm256_set1_epi32(1), two = _mm256_set1_epi32(2);
    const __m256i kz = _mm256_blendv_epi8(_mm256_and_si256(_mm256_castps_si256(y_gt), one), two, _mm256_castps_si256(z_gt));
    const __m256i kx0 = _mm256_blendv_epi8(_mm256_add_epi32(kz, one), _mm256_setzero_si256(), _mm256_cmpeq_epi32(kz, two));
    const __m256i ky0 = _mm256_blendv_epi8(_mm256_add_epi32(kx0, one), _mm256_setzero_si256(), _mm256_cmpeq_epi32(kx0, two));
    const __m256 dkz = pick3(d, kz);
    const __m256i swap = _mm256_castps_si256(_mm256_cmp_ps(dkz, zero, _CMP_LT_OQ));
    const __m256i kx = _mm256_blendv_epi8(kx0, ky0, swap), ky = _mm256_blendv_epi8(ky0, kx0, swap);
    const __m256i k[3] = {kx, ky, kz};
    codes = _mm256_or_si256(codes, _mm256_and_si256(_mm256_sllv_epi32(one, _mm256_add_epi32(_mm256_slli_epi32(kx, 2), kz)),
                                                    _mm256_castps_si256(vm)));
    const __m256 sh[3] = {_mm256_div_ps(pick3(d, kx), dkz), _mm256_div_ps(pick3(d, ky), dkz),
                          _mm256_div_ps(_mm256_set1_ps(1.0f), dkz)};
    __m256 tolm = zero;
    for (int a = 0; a < 3; ++a) {
      const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), d[a]);
      const __m256 invf = Fast ? inv : _mm256_mul_ps(inv, _mm256_set1_ps(kFarFactor));
      _mm256_store_ps(P.o[a] + i, _mm256_and_ps(o[a], vm));
      _mm256_store_ps(P.d[a] + i, _mm256_and_ps(d[a], vm));
      _mm256_store_ps(P.inv[a] + i, _mm256_and_ps(inv, vm));
      _mm256_store_ps(P.invf[a] + i, _mm256_and_ps(invf, vm));
      if constexpr (Fast) {
        const __m256 oi = _mm256_mul_ps(o[a], inv);
        _mm256_store_ps(P.oi[a] + i, _mm256_and_ps(oi, vm));
        // finish_fast_ray's max over the axes, NaN left out (an ordered compare)
        const __m256 x = _mm256_andnot_ps(sign, oi);
        tolm = _mm256_blendv_ps(tolm, x, _mm256_cmp_ps(x, tolm, _CMP_GT_OQ));
      }
      _mm256_store_ps(P.to[a] + i, _mm256_and_ps(pick3(o, k[a]), vm));
      _mm256_store_ps(P.ts[a] + i, _mm256_and_ps(sh[a], vm));
      _mm256_store_si256(reinterpret_cast<__m256i*>(P.k1[a] + i), _mm256_cmpeq_epi32(k[a], one));
      _mm256_store_si256(reinterpret_cast<__m256i*>(P.k2[a] + i), _mm256_cmpeq_epi32(k[a], two));
      // the frustum's intervals and the signs, over the valid lanes
      olo[a] = _mm256_min_ps(olo[a], _mm256_blendv_ps(inf, o[a], vm));
      ohi[a] = _mm256_max_ps(ohi[a], _mm256_blendv_ps(ninf, o[a], vm));
      ilo[a] = _mm256_min_ps(ilo[a], _mm256_blendv_ps(inf, inv, vm));
      ihi[a] = _mm256_max_ps(ihi[a], _mm256_blendv_ps(ninf, inv, vm));
      jlo[a] = _mm256_min_ps(jlo[a], _mm256_blendv_ps(inf, invf, vm));
      jhi[a] = _mm256_max_ps(jhi[a], _mm256_blendv_ps(ninf, invf, vm));
      const unsigned s = static_cast<unsigned>(_mm256_movemask_ps(d[a]));
      neg_any[a] |= s & valid;
      pos_any[a] |= ~s & valid;
    }
    if (hybrid) {
      // the unit directions' spread (the hybrid switch; one division per lane, a heuristic's)
      const __m256 len = _mm256_sqrt_ps(_mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(d[0], d[0]), _mm256_mul_ps(d[1], d[1])),
                                                      _mm256_mul_ps(d[2], d[2])));
      const __m256 lm = _mm256_and_ps(vm, _mm256_and_ps(_mm256_cmp_ps(len, zero, _CMP_GT_OQ), _mm256_cmp_ps(len, inf, _CMP_LT_OQ)));
      const __m256 rlen = _mm256_div_ps(_mm256_set1_ps(1.0f), len);
      for (int a = 0; a < 3; ++a) {
        const __m256 u = _mm256_mul_ps(d[a], rlen);
        ulo[a] = _mm256_min_ps(ulo[a], _mm256_blendv_ps(inf, u, lm));
        uhi[a] = _mm256_max_ps(uhi[a], _mm256_blendv_ps(ninf, u, lm));
      }
      // incoherent rays usually show it in the first SIMD rays: stop loading then
      if ((c == 0 || c == 2) && spread_exceeds(ulo, uhi)) return false;
    }
    const __m256 tmin0 = _mm256_add_ps(tmin, zero);  // -0 becomes +0
    _mm256_store_ps(P.tmin + i, _mm256_and_ps(tmin0, vm));
    _mm256_store_ps(P.t + i, _mm256_blendv_ps(_mm256_set1_ps(-1.0f), tmax, vm));  // below every tmin: no box or triangle accepts it
    _mm256_store_ps(P.u + i, zero);
    _mm256_store_ps(P.v + i, zero);
    _mm256_store_si256(reinterpret_cast<__m256i*>(P.prim + i), _mm256_set1_epi32(-1));  // MBVH_MISS_PRIM
    tmin_lo = _mm256_min_ps(tmin_lo, _mm256_blendv_ps(inf, tmin0, vm));
    tmin_hi = _mm256_max_ps(tmin_hi, _mm256_blendv_ps(ninf, tmin0, vm));
    const __m256 tcull = _mm256_mul_ps(tmax, _mm256_set1_ps(kCullSlack));
    if constexpr (Fast) {
      const __m256 tol = _mm256_mul_ps(tolm, _mm256_set1_ps(0x1p-21f));
      _mm256_store_ps(P.tol + i, _mm256_and_ps(tol, vm));
      // the frustum's highest exit bounds every lane's raised cull bound
      tcull_hi = _mm256_max_ps(tcull_hi, _mm256_blendv_ps(ninf, _mm256_add_ps(tcull, tol), vm));
    }
    tcull_hi = _mm256_max_ps(tcull_hi, _mm256_blendv_ps(ninf, tcull, vm));
    tcull_lo = _mm256_min_ps(tcull_lo, _mm256_blendv_ps(inf, tcull, vm));
    any_valid = any_valid || valid != 0;
  }
  if (hybrid && spread_exceeds(ulo, uhi)) return false;
  // uniform kx, ky, kz: one code among the valid lanes
  alignas(64) std::uint32_t c[8];
  _mm256_store_si256(reinterpret_cast<__m256i*>(c), codes);
  const std::uint32_t all = c[0] | c[1] | c[2] | c[3] | c[4] | c[5] | c[6] | c[7];
  P.uniform_k = std::popcount(all) <= 1;
  if (all != 0) {
    const int code = std::countr_zero(all);
    P.k[0] = code >> 2;
    P.k[2] = code & 3;
    P.k[1] = 3 - P.k[0] - P.k[2];
  }
  // the frustum bounds each lane's entry and exit on an axis where the lanes share the sign of
  // the direction (so their near plane) and the reciprocals are finite (a zero direction
  // component makes (plane - o) * inv infinite or NaN); another axis, and lane 3, bound nothing
  P.same_sign = true;
  P.frustum = false;
  for (int a = 0; a < 4; ++a) {
    bool ok = false;
    if (a < 3 && any_valid) {
      P.neg[a] = neg_any[a] != 0 ? 1 : 0;
      P.same_sign = P.same_sign && (neg_any[a] == 0 || pos_any[a] == 0);
      P.o_lo[a] = hmin8(olo[a]);
      P.o_hi[a] = hmax8(ohi[a]);
      P.inv_lo[a] = hmin8(ilo[a]);
      P.inv_hi[a] = hmax8(ihi[a]);
      P.invf_lo[a] = hmin8(jlo[a]);
      P.invf_hi[a] = hmax8(jhi[a]);
      ok = (neg_any[a] == 0 || pos_any[a] == 0) && std::fabs(P.inv_lo[a]) < INFINITY && std::fabs(P.inv_hi[a]) < INFINITY &&
           std::fabs(P.invf_lo[a]) < INFINITY && std::fabs(P.invf_hi[a]) < INFINITY;
    }
    P.axis_off[a] = ok ? 0 : -1;
    if (!ok) P.o_lo[a] = P.o_hi[a] = P.inv_lo[a] = P.inv_hi[a] = P.invf_lo[a] = P.invf_hi[a] = 0.0f;
    P.frustum = P.frustum || ok;
  }
  P.tmin_lo = hmin8(tmin_lo);
  P.tmin_hi = hmax8(tmin_hi);
  P.tcull_hi = hmax8(tcull_hi);
  P.tcull_lo = hmin8(tcull_lo);
  return true;
}

}  // namespace packet
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

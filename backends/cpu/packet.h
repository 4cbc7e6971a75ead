// SPDX-License-Identifier: MIT
// packet.h — the cpu backend's coherent packet traversals (Áfra's thesis, ch. 2), included by
// simd_kernels.cpp under its ISA pragma, inside its namespace mbvh::MBVH_ISA_NS::(anonymous).
//
// A packet is MBVH_PACKET_RAYS rays in an array-of-structures-of-arrays layout: G SIMD rays of
// 8 lanes (a 4x2 block of an 8x8 tile each: ray_of). It walks the binary tree (MBVH2) of the one build:
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
// the single-ray kernels on the caller's layout instead (load_packet says so).
#pragma once

namespace packet {

constexpr int kLanes = 8;
constexpr int kGroups = MBVH_PACKET_RAYS / kLanes;
static_assert(kGroups * kLanes == MBVH_PACKET_RAYS && kGroups <= 32, "a packet is whole SIMD rays, at most 32");

/// The packet's ray in slot g * 8 + l (lane l of SIMD ray g). Rays arrive in 8x8 image tiles,
/// row by row (raygen, render); a SIMD ray is a 4x2 block of a tile, as in the thesis (ch. 2: 4x2
/// SIMD rays), not a row of 8: its lanes lie closer together, so more of them take the same
/// branch (bunny primary rays: utilisation 49 % -> 59 %, docs/benchmarks.md). Slot -> ray within
/// each 64 rays: block (g & 1, g >> 1) of 4x2, lane (l & 3, l >> 2) within it. Rays that are no
/// tile (secondary rays in arrival order) are as coherent either way. A permutation: every ray
/// of the packet has one slot.
constexpr int ray_of(int slot) {
  if constexpr (MBVH_PACKET_RAYS % 64 != 0) {
    return slot;
  } else {
    const int g = (slot & 63) >> 3, l = slot & 7;
    return (slot & ~63) | (((g >> 1) * 2 + (l >> 2)) * 8 + (g & 1) * 4 + (l & 3));
  }
}

/// One packet's rays, SoA per SIMD ray (lane l of SIMD ray g is ray ray_of(g * 8 + l) of the packet).
struct Packet {
  static constexpr int N = MBVH_PACKET_RAYS;
  alignas(32) float o[3][N], d[3][N], inv[3][N], invf[3][N], tmin[N];
  alignas(32) float t[N], u[N], v[N];  ///< the best hit so far; t is the lane's tmax
  alignas(32) std::uint32_t prim[N];
  alignas(32) float to[3][N], ts[3][N];            ///< the triangle test's permuted origin and shear
  alignas(32) std::int32_t k1[3][N], k2[3][N];     ///< role x, y, z reads coordinate 1 / 2 (all ones)
  const mbvh::Ray* src = nullptr;  ///< the packet's rays (the scalar test of an undecided lane prepares its own)
  std::uint8_t live[kGroups];   ///< valid lanes; any hit: not yet occluded
  std::uint8_t valid[kGroups];  ///< valid lanes (the counters of the others stay 0)
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

/// Transposes 8 rows of 8 floats (row r, lane l -> row l, lane r).
[[gnu::always_inline]] inline void transpose8(__m256 (&r)[8]) {
  const __m256 t0 = _mm256_unpacklo_ps(r[0], r[1]), t1 = _mm256_unpackhi_ps(r[0], r[1]);
  const __m256 t2 = _mm256_unpacklo_ps(r[2], r[3]), t3 = _mm256_unpackhi_ps(r[2], r[3]);
  const __m256 t4 = _mm256_unpacklo_ps(r[4], r[5]), t5 = _mm256_unpackhi_ps(r[4], r[5]);
  const __m256 t6 = _mm256_unpacklo_ps(r[6], r[7]), t7 = _mm256_unpackhi_ps(r[6], r[7]);
  const __m256 u0 = _mm256_shuffle_ps(t0, t2, 0x44), u1 = _mm256_shuffle_ps(t0, t2, 0xEE);
  const __m256 u2 = _mm256_shuffle_ps(t1, t3, 0x44), u3 = _mm256_shuffle_ps(t1, t3, 0xEE);
  const __m256 u4 = _mm256_shuffle_ps(t4, t6, 0x44), u5 = _mm256_shuffle_ps(t4, t6, 0xEE);
  const __m256 u6 = _mm256_shuffle_ps(t5, t7, 0x44), u7 = _mm256_shuffle_ps(t5, t7, 0xEE);
  r[0] = _mm256_permute2f128_ps(u0, u4, 0x20);
  r[1] = _mm256_permute2f128_ps(u1, u5, 0x20);
  r[2] = _mm256_permute2f128_ps(u2, u6, 0x20);
  r[3] = _mm256_permute2f128_ps(u3, u7, 0x20);
  r[4] = _mm256_permute2f128_ps(u0, u4, 0x31);
  r[5] = _mm256_permute2f128_ps(u1, u5, 0x31);
  r[6] = _mm256_permute2f128_ps(u2, u6, 0x31);
  r[7] = _mm256_permute2f128_ps(u3, u7, 0x31);
}

/// Horizontal min / max of 8 lanes.
[[gnu::always_inline]] inline float hmin8(__m256 v) {
  v = _mm256_min_ps(v, _mm256_permute_ps(v, 0xB1));
  v = _mm256_min_ps(v, _mm256_permute_ps(v, 0x4E));
  return _mm256_cvtss_f32(_mm256_min_ps(v, _mm256_permute2f128_ps(v, v, 0x01)));
}
[[gnu::always_inline]] inline float hmax8(__m256 v) {
  v = _mm256_max_ps(v, _mm256_permute_ps(v, 0xB1));
  v = _mm256_max_ps(v, _mm256_permute_ps(v, 0x4E));
  return _mm256_cvtss_f32(_mm256_max_ps(v, _mm256_permute2f128_ps(v, v, 0x01)));
}

/// Per lane: the row of (x, y, z) that k (0, 1, 2, as the masks k == 1, k == 2) names.
[[gnu::always_inline]] inline __m256 pick3(const __m256 (&v)[3], __m256i k) {
  const __m256 is1 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(k, _mm256_set1_epi32(1)));
  const __m256 is2 = _mm256_castsi256_ps(_mm256_cmpeq_epi32(k, _mm256_set1_epi32(2)));
  return _mm256_blendv_ps(_mm256_blendv_ps(v[0], v[1], is1), v[2], is2);
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
  for (int g = 0; g < kGroups; ++g) {
    const int i = g * kLanes;
    __m256 r[8];
    unsigned in_batch = 0;
    for (int l = 0; l < kLanes; ++l) {
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
    P.live[g] = P.valid[g] = static_cast<std::uint8_t>(valid);
    const __m256 vm = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
        _mm256_and_si256(_mm256_set1_epi32(static_cast<int>(valid)), _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128)),
        _mm256_setzero_si256()));
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
    for (int a = 0; a < 3; ++a) {
      const __m256 inv = _mm256_div_ps(_mm256_set1_ps(1.0f), d[a]);
      const __m256 invf = Fast ? inv : _mm256_mul_ps(inv, _mm256_set1_ps(kFarFactor));
      _mm256_store_ps(P.o[a] + i, _mm256_and_ps(o[a], vm));
      _mm256_store_ps(P.d[a] + i, _mm256_and_ps(d[a], vm));
      _mm256_store_ps(P.inv[a] + i, _mm256_and_ps(inv, vm));
      _mm256_store_ps(P.invf[a] + i, _mm256_and_ps(invf, vm));
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
      if ((g == 0 || g == 2) && spread_exceeds(ulo, uhi)) return false;
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
    tcull_hi = _mm256_max_ps(tcull_hi, _mm256_blendv_ps(ninf, tcull, vm));
    tcull_lo = _mm256_min_ps(tcull_lo, _mm256_blendv_ps(inf, tcull, vm));
    any_valid = any_valid || valid != 0;
  }
  if (hybrid && spread_exceeds(ulo, uhi)) return false;
  // uniform kx, ky, kz: one code among the valid lanes
  alignas(32) std::uint32_t c[8];
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

/// A child box of a Node2, as broadcast rows (lo, hi per axis) and its scalar planes.
struct Box8 {
  __m256 lo[3], hi[3];
  __m256 nearv[3], farv[3];  ///< the near and far planes broadcast, where the packet's signs agree
  alignas(16) float near[4], far[4];  ///< the frustum's planes (the packet's common signs)
};

inline void load_box(Box8& b, const float lox, const float hix, const float loy, const float hiy, const float loz,
                     const float hiz, const Packet& P) {
  const float lo[3] = {lox, loy, loz}, hi[3] = {hix, hiy, hiz};
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = _mm256_set1_ps(lo[a]);
    b.hi[a] = _mm256_set1_ps(hi[a]);
    b.near[a] = P.neg[a] ? hi[a] : lo[a];
    b.far[a] = P.neg[a] ? lo[a] : hi[a];
    b.nearv[a] = P.neg[a] ? b.hi[a] : b.lo[a];
    b.farv[a] = P.neg[a] ? b.lo[a] : b.hi[a];
  }
  b.near[3] = b.far[3] = 0.0f;
}

/// What the frustum says of a box for the whole packet.
enum class Cover { some, none, all };

/// The frustum test (Boulos, Wald & Shirley 2006; interval arithmetic) of box `b`, exact for
/// every lane: a lane computes tn = (near - o) * inv rounded; rounding is monotone, so the
/// rounded corner products of [near - o_hi, near - o_lo] x [inv_lo, inv_hi] bound every lane's
/// tn from both sides (likewise tf with inv_far), and a lane's entry max(tn, tmin) and exit
/// min(tf, tcull) lie within the bounds taken over the axes. none: the lowest entry exceeds the
/// highest exit, every lane misses (its own test would say so). all: the highest entry is at most
/// the lowest exit on a frustum of all three axes, every lane hits. `entry` receives the lowest
/// entry and `exit` the highest exit (the packet's order of children).
inline Cover frustum_cover(const Packet& P, const Box8& b, float& entry, float& exit) {
  const __m128 n = _mm_load_ps(b.near), f = _mm_load_ps(b.far);
  const __m128 olo = _mm_load_ps(P.o_lo), ohi = _mm_load_ps(P.o_hi);
  const __m128 alo = _mm_sub_ps(n, ohi), ahi = _mm_sub_ps(n, olo);
  const __m128 ilo = _mm_load_ps(P.inv_lo), ihi = _mm_load_ps(P.inv_hi);
  const __m128 p0 = _mm_mul_ps(alo, ilo), p1 = _mm_mul_ps(alo, ihi), p2 = _mm_mul_ps(ahi, ilo), p3 = _mm_mul_ps(ahi, ihi);
  const __m128 blo = _mm_sub_ps(f, ohi), bhi = _mm_sub_ps(f, olo);
  const __m128 jlo = _mm_load_ps(P.invf_lo), jhi = _mm_load_ps(P.invf_hi);
  const __m128 q0 = _mm_mul_ps(blo, jlo), q1 = _mm_mul_ps(blo, jhi), q2 = _mm_mul_ps(bhi, jlo), q3 = _mm_mul_ps(bhi, jhi);
  const __m128 off = _mm_castsi128_ps(_mm_load_si128(reinterpret_cast<const __m128i*>(P.axis_off)));
  const __m128 pinf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
  const __m128 tn_lo = _mm_blendv_ps(_mm_min_ps(_mm_min_ps(p0, p1), _mm_min_ps(p2, p3)), ninf, off);
  const __m128 tn_hi = _mm_blendv_ps(_mm_max_ps(_mm_max_ps(p0, p1), _mm_max_ps(p2, p3)), pinf, off);
  const __m128 tf_lo = _mm_blendv_ps(_mm_min_ps(_mm_min_ps(q0, q1), _mm_min_ps(q2, q3)), ninf, off);
  const __m128 tf_hi = _mm_blendv_ps(_mm_max_ps(_mm_max_ps(q0, q1), _mm_max_ps(q2, q3)), pinf, off);
  alignas(16) float nl[4], nh[4], fl[4], fh[4];
  _mm_store_ps(nl, tn_lo);
  _mm_store_ps(nh, tn_hi);
  _mm_store_ps(fl, tf_lo);
  _mm_store_ps(fh, tf_hi);
  entry = std::max(std::max(nl[0], nl[1]), std::max(nl[2], P.tmin_lo));
  const float exit_hi = std::min(std::min(fh[0], fh[1]), std::min(fh[2], P.tcull_hi));
  exit = exit_hi;
  if (entry > exit_hi) return Cover::none;
  const float entry_hi = std::max(std::max(nh[0], nh[1]), std::max(nh[2], P.tmin_hi));
  const float exit_lo = std::min(std::min(fl[0], fl[1]), std::min(fl[2], P.tcull_lo));
  return entry_hi <= exit_lo ? Cover::all : Cover::some;
}

/// box_test (intersect.h) on the 8 lanes of SIMD ray g against two boxes at once: each lane's
/// near and far planes by the sign of its direction, the same operations in the same order.
/// Returns the hit lanes of each box and their entry distances. SameSign: every lane has the
/// packet's signs, so the planes are the box's broadcast ones.
template <bool SameSign>
[[gnu::always_inline]] inline void box2_group(const Packet& P, int g, const Box8& b0, const Box8& b1, unsigned& h0,
                                              unsigned& h1, __m256& te0, __m256& te1) {
  const int i = g * kLanes;
  const __m256 tcull = _mm256_mul_ps(_mm256_load_ps(P.t + i), _mm256_set1_ps(kCullSlack));
  const __m256 tmin = _mm256_load_ps(P.tmin + i);
  __m256 e0 = tmin, e1 = tmin, x0 = tcull, x1 = tcull;
  for (int a = 0; a < 3; ++a) {
    const __m256 o = _mm256_load_ps(P.o[a] + i);
    const __m256 inv = _mm256_load_ps(P.inv[a] + i), invf = _mm256_load_ps(P.invf[a] + i);
    __m256 n0, f0, n1, f1;
    if constexpr (SameSign) {
      n0 = b0.nearv[a], f0 = b0.farv[a], n1 = b1.nearv[a], f1 = b1.farv[a];
    } else {
      const __m256 s = _mm256_load_ps(P.d[a] + i);  // the sign bit selects the planes
      n0 = _mm256_blendv_ps(b0.lo[a], b0.hi[a], s), f0 = _mm256_blendv_ps(b0.hi[a], b0.lo[a], s);
      n1 = _mm256_blendv_ps(b1.lo[a], b1.hi[a], s), f1 = _mm256_blendv_ps(b1.hi[a], b1.lo[a], s);
    }
    // box_test's order: te = max(tnz, max(tny, max(tnx, tmin))), tx likewise from tcull
    e0 = _mm256_max_ps(_mm256_mul_ps(_mm256_sub_ps(n0, o), inv), e0);
    x0 = _mm256_min_ps(_mm256_mul_ps(_mm256_sub_ps(f0, o), invf), x0);
    e1 = _mm256_max_ps(_mm256_mul_ps(_mm256_sub_ps(n1, o), inv), e1);
    x1 = _mm256_min_ps(_mm256_mul_ps(_mm256_sub_ps(f1, o), invf), x1);
  }
  h0 = static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(e0, x0, _CMP_LE_OQ)));
  h1 = static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(e1, x1, _CMP_LE_OQ)));
  te0 = e0;
  te1 = e1;
}

/// Per lane: c == 0 ? a : c == 1 ? b : c2 (c as the masks k1 / k2).
[[gnu::always_inline]] inline __m256 select3(__m256 a, __m256 b, __m256 c, __m256 is1, __m256 is2) {
  return _mm256_blendv_ps(_mm256_blendv_ps(a, b, is1), c, is2);
}

/// All ones in the lanes of `m`.
[[gnu::always_inline]] inline __m256 lane_mask(unsigned m) {
  return _mm256_castsi256_ps(_mm256_cmpgt_epi32(
      _mm256_and_si256(_mm256_set1_epi32(static_cast<int>(m)), _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128)),
      _mm256_setzero_si256()));
}

/// Closest hit, SIMD ray at lane i: the lanes of `sure` hit at t (u = un / det, v = vn / det);
/// each keeps the smaller (t, prim) as visit_leaf does (t <= its best t holds: replaced on t below
/// it or a smaller prim), its tmax shrinking to t.
[[gnu::always_inline]] inline void keep_closest(Packet& P, int i, unsigned sure, __m256 t, __m256 tmax, __m256 un, __m256 vn,
                                                __m256 det, std::uint32_t prim) {
  if (sure == 0) return;
  const __m256i bias = _mm256_set1_epi32(INT32_MIN);
  const __m256i pr = _mm256_set1_epi32(static_cast<int>(prim));
  const __m256i bp = _mm256_load_si256(reinterpret_cast<const __m256i*>(P.prim + i));
  const __m256 smaller = _mm256_castsi256_ps(_mm256_cmpgt_epi32(_mm256_xor_si256(bp, bias), _mm256_xor_si256(pr, bias)));  // prim < best
  const unsigned upd = sure & static_cast<unsigned>(_mm256_movemask_ps(_mm256_or_ps(_mm256_cmp_ps(t, tmax, _CMP_LT_OQ), smaller)));
  if (upd == 0) return;
  const __m256 lanes = lane_mask(upd);
  _mm256_store_ps(P.t + i, _mm256_blendv_ps(tmax, t, lanes));
  P.tcull_lo = std::min(P.tcull_lo, hmin8(_mm256_blendv_ps(_mm256_set1_ps(INFINITY), t, lanes)) * kCullSlack);
  _mm256_store_ps(P.u + i, _mm256_blendv_ps(_mm256_load_ps(P.u + i), _mm256_div_ps(un, det), lanes));
  _mm256_store_ps(P.v + i, _mm256_blendv_ps(_mm256_load_ps(P.v + i), _mm256_div_ps(vn, det), lanes));
  _mm256_store_si256(reinterpret_cast<__m256i*>(P.prim + i),
                     _mm256_castps_si256(_mm256_blendv_ps(_mm256_castsi256_ps(bp), _mm256_castsi256_ps(pr), lanes)));
}

/// The `fast` precision's triangle test against the lanes `m` of SIMD ray g: mt_lanes, the
/// operations of tri_test_simd_mt, lane by lane (Möller–Trumbore with FMA and the refined reciprocal estimate), so a
/// ray's answer is the one the cpu backend's single-ray fast traversals give it (the hybrid's
/// too). Closest hit keeps each lane's smallest (t, prim); any hit returns the lanes that hit.
template <bool Any>
[[gnu::always_inline]] inline unsigned tri_group_mt(Packet& P, int g, const Tri& tri, const __m256 (&vb)[3][3], unsigned m) {
  using F = F8;
  const int i = g * kLanes;
  __m256 v0[3], e1[3], e2[3], d[3], s[3];
  for (int a = 0; a < 3; ++a) {
    v0[a] = vb[0][a];
    e1[a] = F::sub(vb[1][a], v0[a]);
    e2[a] = F::sub(vb[2][a], v0[a]);
    d[a] = F::load(P.d[a] + i);
    s[a] = F::sub(F::load(P.o[a] + i), v0[a]);
  }
  __m256 t, u, v;
  const __m256 tmax = F::load(P.t + i);
  const __m256 ok = mt_lanes<F>(e1, e2, d, s, F::load(P.tmin + i), tmax, t, u, v);
  const __m256 one = F::set1(1.0f);
  const unsigned hit = m & F::bits(ok);
  if constexpr (!Any) keep_closest(P, i, hit, t, tmax, u, v, one, tri_prim(tri));
  return hit;
}

/// Lanes i..i+7's coordinate of `role` (their kx, ky or kz) of the vertex rows v.
[[gnu::always_inline]] inline __m256 select_role(const Packet& P, int i, int role, const __m256 (&v)[3]) {
  return select3(v[0], v[1], v[2], _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(P.k1[role] + i))),
                 _mm256_castsi256_ps(_mm256_load_si256(reinterpret_cast<const __m256i*>(P.k2[role] + i))));
}

/// One triangle against the lanes `m` of SIMD ray g: tri_test (intersect.h) lane by lane — the
/// shear of each lane's own axes, the same operations in the same order, the undecided lanes by
/// tri_test itself. Closest hit: keeps each lane's smallest (t, prim) as visit_leaf does. Any
/// hit: returns the lanes that hit.
template <bool Any, bool UniformK>
[[gnu::always_inline]] inline unsigned tri_group(Packet& P, int g, const Tri& tri, const __m256 (&vb)[3][3], unsigned m) {
  const int i = g * kLanes;
  const __m256 ox = _mm256_load_ps(P.to[0] + i), oy = _mm256_load_ps(P.to[1] + i), oz = _mm256_load_ps(P.to[2] + i);
  const __m256 sx = _mm256_load_ps(P.ts[0] + i), sy = _mm256_load_ps(P.ts[1] + i), sz = _mm256_load_ps(P.ts[2] + i);
  __m256 X[3], Y[3], Z[3];
  for (int q = 0; q < 3; ++q) {
    __m256 px, py, pz;
    if constexpr (UniformK) {
      px = vb[q][P.k[0]];
      py = vb[q][P.k[1]];
      pz = vb[q][P.k[2]];
    } else {
      px = select_role(P, i, 0, vb[q]);
      py = select_role(P, i, 1, vb[q]);
      pz = select_role(P, i, 2, vb[q]);
    }
    const __m256 ax = _mm256_sub_ps(px, ox), ay = _mm256_sub_ps(py, oy), az = _mm256_sub_ps(pz, oz);
    X[q] = _mm256_sub_ps(ax, _mm256_mul_ps(sx, az));
    Y[q] = _mm256_sub_ps(ay, _mm256_mul_ps(sy, az));
    Z[q] = _mm256_mul_ps(sz, az);
  }
  const __m256 U = _mm256_sub_ps(_mm256_mul_ps(X[2], Y[1]), _mm256_mul_ps(Y[2], X[1]));
  const __m256 V = _mm256_sub_ps(_mm256_mul_ps(X[0], Y[2]), _mm256_mul_ps(Y[0], X[2]));
  const __m256 W = _mm256_sub_ps(_mm256_mul_ps(X[1], Y[0]), _mm256_mul_ps(Y[1], X[0]));
  const __m256 zero = _mm256_setzero_ps();
  const unsigned exact0 = static_cast<unsigned>(_mm256_movemask_ps(_mm256_or_ps(
      _mm256_cmp_ps(U, zero, _CMP_EQ_OQ), _mm256_or_ps(_mm256_cmp_ps(V, zero, _CMP_EQ_OQ), _mm256_cmp_ps(W, zero, _CMP_EQ_OQ)))));
  const __m256 neg = _mm256_or_ps(_mm256_cmp_ps(U, zero, _CMP_LT_OQ),
                                  _mm256_or_ps(_mm256_cmp_ps(V, zero, _CMP_LT_OQ), _mm256_cmp_ps(W, zero, _CMP_LT_OQ)));
  const __m256 pos = _mm256_or_ps(_mm256_cmp_ps(U, zero, _CMP_GT_OQ),
                                  _mm256_or_ps(_mm256_cmp_ps(V, zero, _CMP_GT_OQ), _mm256_cmp_ps(W, zero, _CMP_GT_OQ)));
  unsigned fallback = m & exact0;
  const unsigned inside = m & ~exact0 & ~static_cast<unsigned>(_mm256_movemask_ps(_mm256_and_ps(neg, pos)));
  unsigned sure = 0;
  if (inside != 0) {
    const __m256 det = _mm256_add_ps(_mm256_add_ps(U, V), W);
    const __m256 T = _mm256_add_ps(_mm256_add_ps(_mm256_mul_ps(U, Z[0]), _mm256_mul_ps(V, Z[1])), _mm256_mul_ps(W, Z[2]));
    const __m256 t = _mm256_div_ps(T, det);
    const __m256 tmax = _mm256_load_ps(P.t + i);
    const __m256 in = _mm256_and_ps(_mm256_cmp_ps(t, _mm256_load_ps(P.tmin + i), _CMP_GE_OQ), _mm256_cmp_ps(t, tmax, _CMP_LE_OQ));
    const unsigned cand =
        inside & static_cast<unsigned>(_mm256_movemask_ps(_mm256_and_ps(in, _mm256_cmp_ps(det, zero, _CMP_NEQ_UQ))));
    if (cand != 0) {
      // conservative t > 0 (pbrt-v3), tri_test's bound
      const __m256 dt = t_error_bound<F8>(X, Y, Z, U, V, W, det);
      sure = cand & static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(t, dt, _CMP_GT_OQ)));
      fallback |= cand & ~sure;
      if constexpr (!Any) keep_closest(P, i, sure, t, tmax, V, W, det, tri_prim(tri));
    }
  }
  for (unsigned f = fallback; f != 0; f &= f - 1) {  // the rare undecided lanes: tri_test itself
    const int l = i + std::countr_zero(f);
    float tt, uu, vv;
    RayPre pre{};
    prepare_ray_simd(P.src[ray_of(l)], pre);  // valid: only live lanes are tested
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

/// The active SIMD rays of a traversal step: ranged, the span [first, last] of SIMD rays (those
/// between with no lane left are skipped); partition, the list of those with a lane left.
template <bool Partition>
struct Active {
  std::uint8_t n = 0;            ///< partition: SIMD rays listed; ranged: last + 1
  std::uint8_t first = 0;        ///< ranged
  std::uint8_t ids[kGroups]{};   ///< partition
  std::uint8_t mask[kGroups]{};  ///< lanes per SIMD ray
  // the SIMD rays to visit: g = at(k) for k in [begin(), end()), skipping mask[g] == 0
  int begin() const { return Partition ? 0 : first; }
  int end() const { return n; }
  int at(int k) const { return Partition ? ids[k] : k; }
  void clear() {
    n = 0;
    first = kGroups;
  }
  /// Records SIMD ray g's lanes `m` (g rising between clears).
  [[gnu::always_inline]] void add(int g, unsigned m) {
    mask[g] = static_cast<std::uint8_t>(m);
    if constexpr (Partition) {  // without a branch: the list grows by one only when m != 0
      ids[n] = static_cast<std::uint8_t>(g);  // n <= g < kGroups: one add per g between clears
      n = static_cast<std::uint8_t>(n + (m != 0 ? 1 : 0));
    } else {
      if (m == 0) return;
      if (first == kGroups) first = static_cast<std::uint8_t>(g);
      n = static_cast<std::uint8_t>(g + 1);
    }
  }
  bool empty() const { return Partition ? n == 0 : first >= n; }
};

/// Counts one SIMD operation on SIMD ray g, lanes `m` active (RayStats::lane_ops, group_ops).
inline void count_op(RayStats* st, int g, unsigned m) {
  for (int l = 0; l < kLanes; ++l) {
    RayStats& s = st[g * kLanes + l];
    ++s.group_ops;
    s.lane_ops += (m >> l) & 1u;
  }
}

/// Adds to the counters of SIMD ray g's lanes `m`.
inline void count_lanes(RayStats* st, int g, unsigned m, unsigned nodes, unsigned boxes, unsigned leaves = 0, unsigned tris = 0) {
  for (; m != 0; m &= m - 1) {
    RayStats& s = st[g * kLanes + std::countr_zero(m)];
    s.nodes += nodes;
    s.box_tests += boxes;
    s.leaves += leaves;
    s.tris += tris;
  }
}

/// Traces the packet through the MBVH2 nodes of v: ranged or partition traversal with the
/// frustum test, the nearer child (the smaller entry over the packet's hit lanes) first; any hit
/// with a frustum: the child of the longer chord first.
/// Stats: st[i] counts lane i's work — the nodes and leaves it was active in, the triangles
/// tested for it (as its own traversal would count them), and the peak stack depth.
template <bool Any, bool Partition, bool UniformK, bool SameSign, bool Stats, bool Fast>
inline void trace_packet(const TraceView& v, Packet& P, RayStats* st) {
  using A = Active<Partition>;
  struct Entry {
    std::int32_t node;
    A act;
  };
  Entry stack[MBVH_STACK2_ENTRIES + 1];
  unsigned sp = 0;
  std::int32_t cur = 0;
  A act;
  act.clear();
  for (int g = 0; g < kGroups; ++g) {
    act.mask[g] = 0;
    act.add(g, P.live[g]);
  }
  if (act.empty()) return;
  for (;;) {
    if (cur >= 0) {
      const Node2& n = v.n2[cur];
      Box8 b0, b1;
      load_box(b0, n.c0[0], n.c0[1], n.c0[2], n.c0[3], n.zz[0], n.zz[1], P);
      load_box(b1, n.c1[0], n.c1[1], n.c1[2], n.c1[3], n.zz[2], n.zz[3], P);
      if constexpr (Stats) {
        for (int k = act.begin(); k < act.end(); ++k) {
          const int g = act.at(k);
          count_lanes(st, g, Any ? act.mask[g] & P.live[g] : act.mask[g], 1, 2);
        }
      }
      Cover c0 = Cover::some, c1 = Cover::some;
      float ent0 = 0, ent1 = 0, ex0 = 0, ex1 = 0;
      if (P.frustum) {
        c0 = frustum_cover(P, b0, ent0, ex0);
        c1 = frustum_cover(P, b1, ent1, ex1);
      }
      if (c0 != Cover::none || c1 != Cover::none) {
        A a0, a1;
        a0.clear();
        a1.clear();
        if (c0 == Cover::all) a0 = act;
        if (c1 == Cover::all) a1 = act;
        if (c0 == Cover::some || c1 == Cover::some) {
          // the lanes' own tests, for the boxes the frustum leaves open
          __m256 near0 = _mm256_set1_ps(INFINITY), near1 = near0;
          for (int k = act.begin(); k < act.end(); ++k) {
            const int g = act.at(k);
            unsigned lanes = act.mask[g];
            if constexpr (Any) lanes &= P.live[g];
            if (lanes == 0) continue;
            if constexpr (Stats) count_op(st, g, lanes);
            unsigned h0, h1;
            __m256 te0, te1;
            box2_group<SameSign>(P, g, b0, b1, h0, h1, te0, te1);
            if (c0 == Cover::some) a0.add(g, h0 & lanes);
            if (c1 == Cover::some) a1.add(g, h1 & lanes);
            if (!P.frustum) {  // the order of children from the lanes' entries
              near0 = _mm256_min_ps(near0, _mm256_blendv_ps(_mm256_set1_ps(INFINITY), te0, lane_mask(h0 & lanes)));
              near1 = _mm256_min_ps(near1, _mm256_blendv_ps(_mm256_set1_ps(INFINITY), te1, lane_mask(h1 & lanes)));
            }
          }
          if (!P.frustum) {
            ent0 = hmin8(near0);
            ent1 = hmin8(near1);
          }
        }
        const bool e0 = a0.empty(), e1 = a1.empty();
        if (!e0 || !e1) {
          int k = e0 ? 1 : 0;
          if (!e0 && !e1) {
            // closest hit: the nearer child first. Any hit: the longer chord first (the
            // frustum's widest span through the box), as the single-ray any-hit traversals
            // (longest_slot) — a shadow ray leaves its surface through the near boxes it
            // grazes; its occluder lies in the box it crosses longest (bunny shadow rays 4.1 ->
            // 5.8 Mrays/s, Sibenik 9.6 -> 18.8, Sponza primary any-hit 17.1 -> 24.2; conference
            // and Cornell unchanged, the bunny's primary any-hit 4 % slower: docs/benchmarks.md)
            if (Any && P.frustum) k = ex1 - ent1 > ex0 - ent0 ? 1 : 0;
            else k = ent1 < ent0 ? 1 : 0;
            if (sp >= MBVH_STACK2_ENTRIES) throw std::runtime_error("packet traversal stack overflow: the tree is deeper than its cap");
            stack[sp].node = n.link[2 + (1 - k)];
            stack[sp].act = k ? a0 : a1;
            ++sp;
            if constexpr (Stats)
              for (int i = 0; i < Packet::N; ++i) st[i].max_depth = std::max(st[i].max_depth, static_cast<std::uint32_t>(sp));
          }
          cur = n.link[2 + k];
          act = k ? a1 : a0;
          continue;
        }
      }
    } else if (cur != MBVH_EMPTY) {
      const Leaf l = v.leaves[~cur];
      for (std::uint32_t j = l.first; j < l.first + l.count; ++j) {
        const Tri& tri = v.tris[j];
        __m256 vb[3][3];
        const float* rows[3] = {tri.v0, tri.v1, tri.v2};
        for (int q = 0; q < 3; ++q)
          for (int a = 0; a < 3; ++a) vb[q][a] = _mm256_set1_ps(rows[q][a]);
        bool any_left = false;
        for (int k = act.begin(); k < act.end(); ++k) {
          const int g = act.at(k);
          unsigned lanes = act.mask[g];
          if constexpr (Any) lanes &= P.live[g];
          if (lanes == 0) continue;
          if constexpr (Stats) {
            count_lanes(st, g, lanes, 0, 0, j == l.first ? 1 : 0, 1);
            count_op(st, g, lanes);
          }
          unsigned hit;
          if constexpr (Fast) hit = tri_group_mt<Any>(P, g, tri, vb, lanes);
          else hit = tri_group<Any, UniformK>(P, g, tri, vb, lanes);
          if constexpr (Any) {
            for (unsigned h = hit; h != 0; h &= h - 1) P.prim[g * kLanes + std::countr_zero(h)] = tri_prim(tri);
            P.live[g] = static_cast<std::uint8_t>(P.live[g] & ~hit);
            any_left = any_left || (lanes & ~hit) != 0;
          }
        }
        if constexpr (Any) {
          if (!any_left) break;
        }
      }
    }
    // pop the next entry with a lane left
    for (;;) {
      if (sp == 0) return;
      --sp;
      cur = stack[sp].node;
      act = stack[sp].act;
      if constexpr (Any) {
        bool left = false;
        for (int k = act.begin(); k < act.end() && !left; ++k) left = (act.mask[act.at(k)] & P.live[act.at(k)]) != 0;
        if (!left) continue;
      }
      break;
    }
  }
}

}  // namespace packet

// SPDX-License-Identifier: MIT
// lanes.h — 4 and 8 lanes of float (F4, F8: the width-generic operations the kernels are written
// in), lane masks, horizontal reductions, the fast mode's FMA products and the MBVH8 push tables.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

inline unsigned mask4(__m128 m) { return static_cast<unsigned>(_mm_movemask_ps(m)); }

#if MBVH_CPU_ISA_ID == 2
/// 8-bit masks bit-reversed (slot s <-> 7 - s).
constexpr std::array<std::uint8_t, 256> kReverse8 = [] {
  std::array<std::uint8_t, 256> t{};
  for (unsigned m = 0; m < 256; ++m) {
    unsigned r = 0;
    for (int b = 0; b < 8; ++b)
      if ((m >> b) & 1u) r |= 1u << (7 - b);
    t[m] = static_cast<std::uint8_t>(r);
  }
  return t;
}();
#endif

#if MBVH_CPU_ISA_ID != 2
/// For each 8-bit mask, its set slots one byte each, highest first if `descending` else lowest
/// first (the AVX2 compress of the MBVH8 pushes).
constexpr std::array<std::uint64_t, 256> set_lanes8(bool descending) {
  std::array<std::uint64_t, 256> t{};
  for (unsigned m = 0; m < 256; ++m) {
    std::uint64_t packed = 0;
    int n = 0;
    for (int k = 0; k < 8; ++k) {
      const int s = descending ? 7 - k : k;
      if ((m >> s) & 1u) packed |= std::uint64_t(s) << (8 * n++);
    }
    t[m] = packed;
  }
  return t;
}
/// The MBVH8 stack's push (highest slot first, so the lowest pops first).
constexpr std::array<std::uint64_t, 256> kDescending8 = set_lanes8(true);
/// The octant-ordered push (lowest lane of the order first).
constexpr std::array<std::uint64_t, 256> kAscending8 = set_lanes8(false);
#endif

/// 4 and 8 lanes of float: the operations the box test needs.
struct F4 {
  using V = __m128;
  static V load(const float* p) { return _mm_load_ps(p); }
  static V set1(float x) { return _mm_set1_ps(x); }
  static V bcast(const float* p) { return _mm_broadcast_ss(p); }
  static V sub(V a, V b) { return _mm_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm_mul_ps(a, b); }
  static V max(V a, V b) { return _mm_max_ps(a, b); }
  static V min(V a, V b) { return _mm_min_ps(a, b); }
  static void store(float* d, V v) { _mm_storeu_ps(d, v); }
  static V add(V a, V b) { return _mm_add_ps(a, b); }
  static V div(V a, V b) { return _mm_div_ps(a, b); }
  static V and_(V a, V b) { return _mm_and_ps(a, b); }
  static V or_(V a, V b) { return _mm_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm_andnot_ps(a, b); }
  static V zero() { return _mm_setzero_ps(); }
  template <int Cmp>
  static V cmp(V a, V b) { return _mm_cmp_ps(a, b, Cmp); }
  static unsigned bits(V m) { return mask4(m); }
  static V fmsub(V a, V b, V c) { return _mm_fmsub_ps(a, b, c); }
  static V fmadd(V a, V b, V c) { return _mm_fmadd_ps(a, b, c); }
  static V fnmadd(V a, V b, V c) { return _mm_fnmadd_ps(a, b, c); }
  static V rcp(V a) { return _mm_rcp_ps(a); }
  /// Row `row` of the pack at p: its four lanes.
  static V row(const Tri4* p, int row) { return _mm_load_ps(p->v[row]); }
#if MBVH_CPU_ISA_ID == 2
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
#else
  static unsigned le(V a, V b) { return mask4(_mm_cmp_ps(a, b, _CMP_LE_OQ)); }
#endif
};
struct F8 {
  using V = __m256;
  static V load(const float* p) { return _mm256_load_ps(p); }
  static V set1(float x) { return _mm256_set1_ps(x); }
  static V bcast(const float* p) { return _mm256_broadcast_ss(p); }
  static V sub(V a, V b) { return _mm256_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  static V max(V a, V b) { return _mm256_max_ps(a, b); }
  static V min(V a, V b) { return _mm256_min_ps(a, b); }
  static void store(float* d, V v) { _mm256_storeu_ps(d, v); }
  static V add(V a, V b) { return _mm256_add_ps(a, b); }
  static V div(V a, V b) { return _mm256_div_ps(a, b); }
  static V and_(V a, V b) { return _mm256_and_ps(a, b); }
  static V or_(V a, V b) { return _mm256_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm256_andnot_ps(a, b); }
  static V zero() { return _mm256_setzero_ps(); }
  template <int Cmp>
  static V cmp(V a, V b) { return _mm256_cmp_ps(a, b, Cmp); }
  static unsigned bits(V m) { return static_cast<unsigned>(_mm256_movemask_ps(m)); }
  static V fmsub(V a, V b, V c) { return _mm256_fmsub_ps(a, b, c); }
  static V fmadd(V a, V b, V c) { return _mm256_fmadd_ps(a, b, c); }
  static V fnmadd(V a, V b, V c) { return _mm256_fnmadd_ps(a, b, c); }
  static V rcp(V a) { return _mm256_rcp_ps(a); }
  /// Row `row` of the two consecutive packs at p: eight lanes, p[0]'s four low, p[1]'s high.
  static V row(const Tri4* p, int row) {
    return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_load_ps(p[0].v[row])), _mm_load_ps(p[1].v[row]), 1);
  }
#if MBVH_CPU_ISA_ID == 2
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm256_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
#else
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(a, b, _CMP_LE_OQ))); }
#endif
};

/// max(|a|, |b|, |c|) lane by lane (the error bounds' maxima; andnot of -0 clears the sign).
template <class F>
[[gnu::always_inline]] inline typename F::V absmax3(typename F::V a, typename F::V b, typename F::V c) {
  const typename F::V sign = F::set1(-0.0f);
  return F::max(F::andnot(sign, a), F::max(F::andnot(sign, b), F::andnot(sign, c)));
}
/// The fast mode's cross and dot products, with FMA (plain functions, not lambdas: a lambda is
/// not compiled for the ISA of the pragma around it).
template <class F>
[[gnu::always_inline]] inline void cross_fma(const typename F::V a[3], const typename F::V b[3], typename F::V c[3]) {
  c[0] = F::fmsub(a[1], b[2], F::mul(a[2], b[1]));
  c[1] = F::fmsub(a[2], b[0], F::mul(a[0], b[2]));
  c[2] = F::fmsub(a[0], b[1], F::mul(a[1], b[0]));
}
template <class F>
[[gnu::always_inline]] inline typename F::V dot_fma(const typename F::V a[3], const typename F::V b[3]) {
  return F::fmadd(a[0], b[0], F::fmadd(a[1], b[1], F::mul(a[2], b[2])));
}

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

/// Horizontal min / max of 8 lanes, in every lane.
[[gnu::always_inline]] inline __m256 hmin8_splat(__m256 v) {
  v = _mm256_min_ps(v, _mm256_permute_ps(v, 0xB1));
  v = _mm256_min_ps(v, _mm256_permute_ps(v, 0x4E));
  return _mm256_min_ps(v, _mm256_permute2f128_ps(v, v, 0x01));
}
[[gnu::always_inline]] inline __m256 hmax8_splat(__m256 v) {
  v = _mm256_max_ps(v, _mm256_permute_ps(v, 0xB1));
  v = _mm256_max_ps(v, _mm256_permute_ps(v, 0x4E));
  return _mm256_max_ps(v, _mm256_permute2f128_ps(v, v, 0x01));
}
/// Horizontal min / max of 8 lanes.
[[gnu::always_inline]] inline float hmin8(__m256 v) { return _mm256_cvtss_f32(hmin8_splat(v)); }
[[gnu::always_inline]] inline float hmax8(__m256 v) { return _mm256_cvtss_f32(hmax8_splat(v)); }

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

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

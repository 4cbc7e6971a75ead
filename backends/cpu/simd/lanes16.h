// SPDX-License-Identifier: MIT
// lanes16.h — 16 lanes of float (F16: F4's and F8's width-generic operations on AVX-512), for
// the 16-wide SIMD rays of the packets (packet/packet.h) in the AVX-512 build.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/lanes.h"

#if MBVH_CPU_ISA_ID == 2
namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// A comparison's lanes in a mask register (F16::cmp): and_, or_ and bits as F4's and F8's
/// all-ones vectors, without moving them to a vector register.
struct M16 {
  __mmask16 k;
};

/// 16 lanes of float. A comparison's result is a mask register (M16), which the width-generic
/// kernels combine with and_ / or_ as they do F4's and F8's all-ones vectors. rcp is the 8-lane estimate on each half: the fast mode's Möller–Trumbore then
/// computes the bits F8's does (rcp14 would give other estimates than the single-ray leaves').
struct F16 {
  using V = __m512;
  static V load(const float* p) { return _mm512_load_ps(p); }
  static V set1(float x) { return _mm512_set1_ps(x); }
  static V bcast(const float* p) { return _mm512_set1_ps(*p); }
  static V sub(V a, V b) { return _mm512_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm512_mul_ps(a, b); }
  static V max(V a, V b) { return _mm512_max_ps(a, b); }
  static V min(V a, V b) { return _mm512_min_ps(a, b); }
  static void store(float* d, V v) { _mm512_storeu_ps(d, v); }
  static V add(V a, V b) { return _mm512_add_ps(a, b); }
  static V div(V a, V b) { return _mm512_div_ps(a, b); }
  static V and_(V a, V b) { return _mm512_and_ps(a, b); }
  static V or_(V a, V b) { return _mm512_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm512_andnot_ps(a, b); }
  static V zero() { return _mm512_setzero_ps(); }
  template <int Cmp>
  static M16 cmp(V a, V b) { return {_mm512_cmp_ps_mask(a, b, Cmp)}; }
  static M16 and_(M16 a, M16 b) { return {static_cast<__mmask16>(a.k & b.k)}; }
  static M16 or_(M16 a, M16 b) { return {static_cast<__mmask16>(a.k | b.k)}; }
  static unsigned bits(M16 m) { return m.k; }
  static unsigned bits(V m) { return static_cast<unsigned>(_mm512_movepi32_mask(_mm512_castps_si512(m))); }
  static V fmsub(V a, V b, V c) { return _mm512_fmsub_ps(a, b, c); }
  static V fmadd(V a, V b, V c) { return _mm512_fmadd_ps(a, b, c); }
  static V fnmadd(V a, V b, V c) { return _mm512_fnmadd_ps(a, b, c); }
  static V rcp(V a) {
    const __m256 lo = _mm256_rcp_ps(_mm512_castps512_ps256(a));
    const __m256 hi = _mm256_rcp_ps(_mm256_castpd_ps(_mm512_extractf64x4_pd(_mm512_castps_pd(a), 1)));
    return _mm512_castpd_ps(_mm512_insertf64x4(_mm512_castps_pd(_mm512_castps256_ps512(lo)), _mm256_castps_pd(hi), 1));
  }
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm512_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
};

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh
#endif

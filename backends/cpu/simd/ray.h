// SPDX-License-Identifier: MIT
// ray.h — the SIMD policies' ray: prepare_ray in vector registers and the per-ray constants the
// kernels read (near and far plane offsets, the triangle test's permuted origin).
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/lanes.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// The SIMD policies' ray: RayPre plus the per-ray constants the kernels need beyond it, made
/// once per ray (finish) instead of at every node and leaf: the offsets of each axis' near and far
/// plane rows in a Node4 and a Node8 (Embree's nearX/farX) and the triangle test's permuted origin
/// (Woop et al. 2013). The kernels broadcast RayPre's scalars where they use them (a broadcast
/// from memory is one load, as a load of a stored broadcast is, so stored broadcasts would only
/// add set-up work).
struct SimdRay : RayPre {
  float tri_o[3];  ///< the triangle test's permuted origin (o[kx], o[ky], o[kz]; robust only, unset in fast)
  int near4[4], far4[4], near8[4], far8[4];  ///< three axes (the fourth entry unused)
  float oinv[3];  ///< o * inv per axis: the `fast` box test's FMA form (finish_fast_ray; unset in robust)
  float tol;      ///< `fast`: what the FMA form's distances may exceed the subtraction's by (finish_fast_ray)
  const TraceView* view;  ///< what the ray traverses (for prefetches)
  bool prefetch;          ///< the closest-hit walks prefetch pending children (prefetches(view))
};

/// The closest-hit walks prefetch the records of the hit children left for later
/// (SimdKernelsT::prefetch) only on a tree whose nodes take more than kPrefetchNodeBytes: where
/// they fit in the caches a pending child is mostly there already, and the prefetches (a node is
/// four lines on MBVH8) cost more instructions than the misses they hide (docs/backends.md).
/// Decided once per ray (finish_ray), not at every node the walk tests.
inline constexpr std::size_t kPrefetchNodeBytes = std::size_t{12} << 20;
inline bool prefetches(const TraceView& v) {
  const std::size_t node = v.n8 ? sizeof(Node8) : v.n4 ? sizeof(Node4) : sizeof(Node2);
  return v.nodes > kPrefetchNodeBytes / node;
}

/// prepare_ray (intersect.h) in vector registers: the same checks — every component finite
/// (|x| < inf, false for NaN) but tmax, which may be +inf, tmin in [0, tmax], the largest
/// direction component normal — and the same per-ray constants with the same IEEE operations
/// (1 / d, inv * K, the shear's three quotients in one division), so every bit is the scalar's,
/// in about half its instructions (the set-up is a large share of a short shadow ray's work).
/// Shear off (the `fast` precision, whose Möller–Trumbore test reads o, d and tmin only): the
/// watertight test's constants (kx, ky, sx, sy, sz; finish_ray's permuted origin) are left unset,
/// and inv_far is inv (relax_ray's); the checks are the same, so the same rays are valid.
template <bool Shear = true>
[[gnu::always_inline]] inline bool prepare_ray_simd(const Ray& ray, RayPre& p) {
  static_assert(offsetof(RayPre, d) == offsetof(RayPre, o) + 12 && offsetof(RayPre, inv) == offsetof(RayPre, d) + 12 &&
                    offsetof(RayPre, inv_far) == offsetof(RayPre, inv) + 12 &&
                    offsetof(RayPre, neg) == offsetof(RayPre, inv_far) + 12 && offsetof(RayPre, tmin) == offsetof(RayPre, neg) + 12,
                "RayPre's rows are written 16 bytes at a time, each store's fourth lane overwritten by the next");
  const __m128 o = _mm_loadu_ps(&ray.ox), d = _mm_loadu_ps(&ray.dx);  // (o, tmin), (d, tmax)
  const __m128 sign = _mm_set1_ps(-0.0f), inf = _mm_set1_ps(INFINITY);
  const __m128 ad = _mm_andnot_ps(sign, d);
  const unsigned finite_o = mask4(_mm_cmp_ps(_mm_andnot_ps(sign, o), inf, _CMP_LT_OQ));
  const unsigned finite_d = mask4(_mm_cmp_ps(ad, inf, _CMP_LT_OQ));
  if ((finite_o & (finite_d | 8u)) != 0xFu || std::isnan(ray.tmax)) return false;
  if (!(ray.tmin >= 0.0f) || !(ray.tmin <= ray.tmax)) return false;
  alignas(16) float a[4];
  _mm_store_ps(a, ad);
  int kz = 0;
  if (a[1] > a[0]) kz = 1;
  if (a[2] > a[kz]) kz = 2;
  if (!(a[kz] >= std::numeric_limits<float>::min())) return false;  // zero or subnormal (a[kz] is finite)
  char* base = reinterpret_cast<char*>(&p);
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), d);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, o)), o);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, d)), d);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, inv)), inv);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, inv_far)), Shear ? _mm_mul_ps(inv, _mm_set1_ps(kFarFactor)) : inv);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(base + offsetof(RayPre, neg)), _mm_srli_epi32(_mm_castps_si128(d), 31));
  p.tmin = ray.tmin + 0.0f;  // -0 becomes +0
  p.tmax = ray.tmax;
  p.kz = kz;
  if constexpr (!Shear) return true;
  constexpr int next[3] = {1, 2, 0};
  int kx = next[kz], ky = next[kx];
  if (p.d[kz] < 0.0f) std::swap(kx, ky);
  p.kx = kx;
  p.ky = ky;
  alignas(16) float sh[4];
  _mm_store_ps(sh, _mm_div_ps(_mm_setr_ps(p.d[kx], p.d[ky], 1.0f, 1.0f), _mm_setr_ps(p.d[kz], p.d[kz], p.d[kz], 1.0f)));
  p.sx = sh[0];
  p.sy = sh[1];
  p.sz = sh[2];
  return true;
}

/// Fills SimdRay's constants from its (validated, possibly relaxed) RayPre part; Shear as
/// prepare_ray_simd's (off: no permuted origin).
template <bool Shear = true>
inline void finish_ray(SimdRay& r, const TraceView& v) {
  r.view = &v;
  r.prefetch = prefetches(v);
  // rows lo_x, hi_x, lo_y, ... are W floats apart: near = (2a + neg) * W, far = near ^ W, the
  // three axes at once (neg's fourth lane is tmin's bits: its entries are never read)
  const __m128i near8 = _mm_slli_epi32(_mm_add_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(r.neg)),
                                                     _mm_setr_epi32(0, 2, 4, 0)), 3);
  const __m128i near4 = _mm_srli_epi32(near8, 1);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.near8), near8);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.far8), _mm_xor_si128(near8, _mm_set1_epi32(8)));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.near4), near4);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.far4), _mm_xor_si128(near4, _mm_set1_epi32(4)));
  if constexpr (!Shear) return;
  r.tri_o[0] = r.o[r.kx];
  r.tri_o[1] = r.o[r.ky];
  r.tri_o[2] = r.o[r.kz];
}

/// The `fast` precision's extra constant: o * inv per axis, so the box test's plane distance
/// (p - o) * inv becomes one FMA, p * inv - o * inv (Embree's non-robust and tinybvh's form; it
/// rounds o * inv once more, which is why robust keeps the subtraction first). An axis with
/// inv = +-inf gives NaN distances, which the min/max chain discards: the slab is then not
/// tested (more boxes visited, never fewer). The rounding of o * inv can put a box's entry past
/// a hit on its face by more than kCullSlack allows for, which would make a closest hit depend on
/// the order the boxes are visited in (packets and single rays would differ): the cull bound is
/// raised by tol = 2^-21 max|o * inv| (twice that rounding and the result's), NaN axes left out.
[[gnu::always_inline]] inline void finish_fast_ray(SimdRay& r) {
  float m = 0.0f;
  for (int a = 0; a < 3; ++a) {
    r.oinv[a] = r.o[a] * r.inv[a];
    const float x = std::fabs(r.oinv[a]);
    m = x > m ? x : m;  // NaN (0 * inf) left out
  }
  r.tol = m * 0x1p-21f;
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

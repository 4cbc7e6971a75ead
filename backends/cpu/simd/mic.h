// SPDX-License-Identifier: MIT
// mic.h — the MIC path natively (AVX-512 only): the MBVH4 traversals with each node's four children
// tested in 16 lanes, on the layout's 16-wide view (Node4W), as the Xeon Phi code of Áfra's thesis
// (ch. 4) and Áfra & Szirmay-Kalos 2014 test an MBVH4 node: one 512-bit operation per row.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/kernels.h"

#if MBVH_CPU_ISA_ID == 2
namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// The MIC path's ray: SimdRay plus what the 16-lane node test reads — the lanes whose near plane
/// is the box's hi (lane 4s + a for a ray whose direction on axis a is negative) and where the
/// 16-wide view lies relative to the MBVH4 nodes the engine walks (the same index, the same
/// record size).
struct MicRay : SimdRay {
  std::ptrdiff_t wide_at;  ///< (char*)TraceView::n4w - (char*)TraceView::n4
  __mmask16 negk;
};

/// The cpu policy with the MIC node test for MBVH4 (cpu.mic): the engine walks the MBVH4 view
/// (Node4: topology, references, the same visit order as ever) and the box test reads the Node4W
/// record of the same index — lo row (x, y, z, child) and hi row (x, y, z, link) of the four
/// children, one 512-bit load each. Per lane the conservative slab test's operations in box_test's
/// order (Ize 2013): the near and far planes picked by the ray's direction signs (a mask blend),
/// (plane - o) * inv (inv_far for the far planes), then per child the max (min) chain over x, y, z
/// from tmin (tcull), in-lane shuffles bringing y and z to the child's lane 0, and an ordered <=:
/// the bits of box_test_wide, so every answer and counter is the 8-lane path's and cpu-scalar's.
/// The w lanes (references) are masked out of the arithmetic. MBVH8 and the leaves are SimdKernelsT's.
template <bool Fast>
struct MicKernelsT : SimdKernelsT<Fast> {
  using Base = SimdKernelsT<Fast>;
  using Ray = MicRay;
  static constexpr bool uses_node4w = true;
  static constexpr bool octant_any = false;  // the per-octant any hit prepares SimdRays, not MicRays
  static constexpr bool mbvh4_only = true;  // batch.h: runs_mic (isa_kernels.cpp) traces MBVH4 alone with it
  [[gnu::always_inline]] static bool prepare(const mbvh::Ray& ray, Ray& r) { return prepare_ray_simd<!Fast>(ray, r); }
  static void finish(Ray& r, const TraceView& v) {
    finish_ray<!Fast>(r, v);
    if constexpr (Fast) finish_fast_ray(r);
    r.wide_at = reinterpret_cast<const char*>(v.n4w) - reinterpret_cast<const char*>(v.n4);
    unsigned k = 0;
    for (int a = 0; a < 3; ++a)
      if (r.neg[a]) k |= 0x1111u << a;
    r.negk = static_cast<__mmask16>(k);
  }
  using Base::test;
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node4& n, const Ray& r, float tcull, float d[4]) {
    const auto* w = reinterpret_cast<const Node4W*>(reinterpret_cast<const char*>(&n) + r.wide_at);
    constexpr __mmask16 xyz = 0x7777;  // lanes 0-2 of each child: the slabs; lane 3: a reference
    const __m512 lo = _mm512_load_ps(&w->lo[0][0]), hi = _mm512_load_ps(&w->hi[0][0]);
    const __m512 nearp = _mm512_mask_blend_ps(r.negk, lo, hi), farp = _mm512_mask_blend_ps(r.negk, hi, lo);
    // RayPre's o, inv, inv_far rows: (x, y, z, next word) broadcast to the four children
    const __m512 inv = _mm512_broadcast_f32x4(_mm_loadu_ps(r.inv));
    __m512 tn, tf;
    if constexpr (Fast) {  // box_test_wide's FMA form: p * inv - o * inv (inv_far = inv)
      const __m512 oinv = _mm512_broadcast_f32x4(_mm_loadu_ps(r.oinv));
      tn = _mm512_maskz_fmsub_ps(xyz, nearp, inv, oinv);
      tf = _mm512_maskz_fmsub_ps(xyz, farp, inv, oinv);
    } else {
      const __m512 o = _mm512_broadcast_f32x4(_mm_loadu_ps(r.o));
      const __m512 invf = _mm512_broadcast_f32x4(_mm_loadu_ps(r.inv_far));
      tn = _mm512_maskz_mul_ps(xyz, _mm512_maskz_sub_ps(xyz, nearp, o), inv);
      tf = _mm512_maskz_mul_ps(xyz, _mm512_maskz_sub_ps(xyz, farp, o), invf);
    }
    // lane 4s: x as computed, y and z shuffled down within the child's 128-bit row
    const __m512 tny = _mm512_permute_ps(tn, _MM_SHUFFLE(3, 3, 3, 1)), tnz = _mm512_permute_ps(tn, _MM_SHUFFLE(3, 3, 3, 2));
    const __m512 tfy = _mm512_permute_ps(tf, _MM_SHUFFLE(3, 3, 3, 1)), tfz = _mm512_permute_ps(tf, _MM_SHUFFLE(3, 3, 3, 2));
    const __m512 te = _mm512_max_ps(tnz, _mm512_max_ps(tny, _mm512_max_ps(tn, _mm512_set1_ps(r.tmin))));
    const __m512 tx = _mm512_min_ps(tfz, _mm512_min_ps(tfy, _mm512_min_ps(tf, _mm512_set1_ps(Fast ? tcull + r.tol : tcull))));
    const __m512i pick = _mm512_setr_epi32(0, 4, 8, 12, 0, 4, 8, 12, 0, 4, 8, 12, 0, 4, 8, 12);
    __m512 out;
    if constexpr (Chord) out = _mm512_max_ps(_mm512_sub_ps(tx, te), _mm512_setzero_ps());  // max_nan(tx - te, 0)
    else if constexpr (Fast) out = _mm512_sub_ps(te, _mm512_set1_ps(r.tol));  // box_test_wide's fast entries
    else out = te;
    _mm_storeu_ps(d, _mm512_castps512_ps128(_mm512_permutexvar_ps(pick, out)));
    // lanes 0, 4, 8, 12 -> bits 0-3
    unsigned k = static_cast<unsigned>(_mm512_mask_cmp_ps_mask(0x1111, te, tx, _CMP_LE_OQ));
    k |= k >> 3;
    k |= k >> 6;
    return k & 0xFu;
  }
};

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh
#endif

// SPDX-License-Identifier: MIT
// quant8.h — the cpu policy on the quantized MBVH8 view (`cpu.quant8`; backends/cpu/quant8.h):
// the engine walks the MBVH8 nodes (their child references: one line), the box test decodes the
// Node8Q record of the same index (one line) — compressed wide nodes as Ylitie, Karras & Laine
// 2017 and Embree's quantized BVH8 — and tests the decoded planes with box_test_wide's operations.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/quant8.h"
#include "backends/cpu/simd/kernels.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// The view of a quantized trace: the MBVH8 view and its Node8Q records (q8[i] is n8[i]'s boxes).
struct QuantView : TraceView {
  const Node8Q* q8 = nullptr;
};

/// The quantized policy's ray: SimdRay plus where the records lie.
struct QuantRay : SimdRay {
  const char* n8;
  const Node8Q* q8;
};

/// One decoded row of eight planes: origin + float(q) * 2^e, quant8.h's decode_plane lane by lane
/// in one FMA (the product is exact, so the fused sum rounds as the builder's mul and add: the
/// bits it checked).
[[gnu::always_inline]] inline __m256 decode_row(const std::uint8_t* q, __m256 origin, __m256 scale) {
  const __m256 qf = _mm256_cvtepi32_ps(_mm256_cvtepu8_epi32(_mm_loadl_epi64(reinterpret_cast<const __m128i*>(q))));
  return _mm256_fmadd_ps(qf, scale, origin);
}

/// The cpu policy with the quantized MBVH8 box test: the decoded planes are conservative (lo at
/// most, hi at least the float node's), the slab test is box_test_wide's, so a child the float
/// node's test keeps is kept: the same leaves can win, their exact tests decide, and the answers
/// are the float path's (closest hit: the smallest (t, prim) whatever the visit order; any hit:
/// whether some triangle is hit). Only the work and the visit order differ; traced uncounted only.
template <bool Fast>
struct QuantKernelsT : SimdKernelsT<Fast> {
  using Base = SimdKernelsT<Fast>;
  using Ray = QuantRay;
  [[gnu::always_inline]] static bool prepare(const mbvh::Ray& ray, Ray& r) { return prepare_ray_simd(ray, r); }
  static void finish(Ray& r, const TraceView& v) {
    finish_ray(r, v);
    r.n8 = reinterpret_cast<const char*>(v.n8);
    r.q8 = static_cast<const QuantView&>(v).q8;  // the one driver of this policy passes a QuantView
  }
  using Base::test;
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node8& n, const Ray& r, float tcull, float d[8]) {
    const Node8Q& q = r.q8[static_cast<std::size_t>(reinterpret_cast<const char*>(&n) - r.n8) / sizeof(Node8)];
    // the three scales 2^e at once: exp (and the valid byte) sign-extended, biased, shifted into
    // the exponent field
    std::int32_t ew;
    std::memcpy(&ew, q.exp, 4);
    const __m256 s4 = _mm256_castps128_ps256(_mm_castsi128_ps(
        _mm_slli_epi32(_mm_add_epi32(_mm_cvtepi8_epi32(_mm_cvtsi32_si128(ew)), _mm_set1_epi32(127)), 23)));
    __m256 org[3], sc[3];
    for (int a = 0; a < 3; ++a) {
      org[a] = _mm256_broadcast_ss(&q.origin[a]);
      sc[a] = _mm256_permutevar8x32_ps(s4, _mm256_set1_epi32(a));
    }
    // near8[a] = (2a + neg) * 8: the near row's byte offset in q (8 bytes a row)
    const std::uint8_t* rows = &q.q[0][0];
    const __m256 nx = decode_row(rows + r.near8[0], org[0], sc[0]), fx = decode_row(rows + r.far8[0], org[0], sc[0]);
    const __m256 ny = decode_row(rows + r.near8[1], org[1], sc[1]), fy = decode_row(rows + r.far8[1], org[1], sc[1]);
    const __m256 nz = decode_row(rows + r.near8[2], org[2], sc[2]), fz = decode_row(rows + r.far8[2], org[2], sc[2]);
    const __m256 ox = _mm256_broadcast_ss(&r.o[0]), oy = _mm256_broadcast_ss(&r.o[1]), oz = _mm256_broadcast_ss(&r.o[2]);
    const __m256 tnx = _mm256_mul_ps(_mm256_sub_ps(nx, ox), _mm256_broadcast_ss(&r.inv[0]));
    const __m256 tny = _mm256_mul_ps(_mm256_sub_ps(ny, oy), _mm256_broadcast_ss(&r.inv[1]));
    const __m256 tnz = _mm256_mul_ps(_mm256_sub_ps(nz, oz), _mm256_broadcast_ss(&r.inv[2]));
    const __m256 tfx = _mm256_mul_ps(_mm256_sub_ps(fx, ox), _mm256_broadcast_ss(&r.inv_far[0]));
    const __m256 tfy = _mm256_mul_ps(_mm256_sub_ps(fy, oy), _mm256_broadcast_ss(&r.inv_far[1]));
    const __m256 tfz = _mm256_mul_ps(_mm256_sub_ps(fz, oz), _mm256_broadcast_ss(&r.inv_far[2]));
    const __m256 te = _mm256_max_ps(tnz, _mm256_max_ps(tny, _mm256_max_ps(tnx, _mm256_broadcast_ss(&r.tmin))));
    const __m256 tx = _mm256_min_ps(tfz, _mm256_min_ps(tfy, _mm256_min_ps(tfx, _mm256_set1_ps(tcull))));
    if constexpr (Chord) _mm256_storeu_ps(d, _mm256_max_ps(_mm256_sub_ps(tx, te), _mm256_setzero_ps()));
    else _mm256_storeu_ps(d, te);
    return F8::le(te, tx) & q.valid;
  }
  /// Closest hit's prefetch of the pending children: an inner child's reference line and its
  /// record, a leaf's first pack.
  using Base::prefetch;
  [[gnu::always_inline]] static void prefetch(const Node8& n, const Ray& r, unsigned mask) {
    const char* packs = reinterpret_cast<const char*>(r.view->tri4);
    for (unsigned k = mask; k != 0; k &= k - 1) {
      const std::int32_t c = n.child[std::countr_zero(k)];
      if (c >= 0) {
        _mm_prefetch(r.n8 + static_cast<std::size_t>(c) * sizeof(Node8) + offsetof(Node8, child), _MM_HINT_T0);
        _mm_prefetch(reinterpret_cast<const char*>(r.q8 + c), _MM_HINT_T0);
      } else if (r.view->packed_refs) {
        _mm_prefetch(packs + static_cast<std::size_t>(static_cast<std::uint32_t>(~c) >> 3) * sizeof(Tri4), _MM_HINT_T0);
      } else {
        _mm_prefetch(reinterpret_cast<const char*>(r.view->leaf4 + ~c), _MM_HINT_T0);
      }
    }
  }
};

/// trace_parallel (batch.h) on the quantized view, uncounted: the MBVH8 view of `opt` and its
/// records `q8` (made in prepare from the same nodes).
template <class K>
void trace_quant(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
                 const Node8Q* q8) {
  QuantView v;
  static_cast<TraceView&>(v) = trace_view(acc, opt.layout, true, opt.leaf_block, true, false);
  v.q8 = q8;
  const bool any = opt.query == Query::any;
  out.resize_for(rays.size(), opt);
  std::atomic<std::size_t> invalid{0};
  parallel_for(rays.size(), kTraceChunk, threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::size_t inv = 0;
    if (any) run_batch<true, false, K>(v, rays, b, e, opt, out, inv);
    else run_batch<false, false, K>(v, rays, b, e, opt, out, inv);
    invalid += inv;
  });
  out.invalid = invalid;
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

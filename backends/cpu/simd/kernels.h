// SPDX-License-Identifier: MIT
// kernels.h — the SIMD cpu backends' kernel policy (SimdKernelsT): the reference's traversals
// (host/core/trace) with four or eight boxes per node test and four or eight triangles per leaf pass.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/box.h"
#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/ray.h"
#include "backends/cpu/simd/triangle.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

void occluded_octant_run(const TraceView& v, std::span<const Ray> rays, std::size_t b, std::size_t e, TraceOutput& out,
                         std::size_t& invalid);  // defined in occlusion.h, which isa_kernels.cpp includes after this header

/// The cpu backend's kernels: four or eight boxes per test, four or eight triangles per pass (the
/// leaves as Tri4 packs).
/// A leaf's answer is the reference's: any hit takes the first hit triangle in leaf order,
/// closest hit the smallest (t, prim) — what the sequential loop of visit_leaf keeps, as tmax
/// only shrinks to the best hit's t. With statistics on, the scalar leaf counts the work. Fast: the
/// `fast` accuracy mode (relax_ray's box test in box_test_wide's FMA form, tri_test_simd_mt).
template <bool Fast>
struct SimdKernelsT {
  static constexpr bool uses_packs = true;
  static constexpr bool fast = Fast;
  static constexpr bool interleave = true;  // batch.h: two rays in turn (walked_in_turn says where)
  using Ray = SimdRay;
  /// batch.h: the MBVH8 octant-ordered stack's any hit in `fast` precision walked per direction
  /// octant (occlusion.h) in place of OctantWalk (robust keeps OctantWalk: measured faster there).
  static constexpr bool octant_any = Fast;
  static void trace_octant_any(const TraceView& v, std::span<const mbvh::Ray> rays, std::size_t b, std::size_t e,
                               TraceOutput& out, std::size_t& invalid) {
    occluded_octant_run(v, rays, b, e, out, invalid);
  }
  [[gnu::always_inline]] static bool prepare(const mbvh::Ray& ray, Ray& r) { return prepare_ray_simd<!Fast>(ray, r); }
  static void finish(Ray& r, const TraceView& v) {
    finish_ray<!Fast>(r, v);
    if constexpr (Fast) finish_fast_ray(r);
  }
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node4& n, const Ray& r, float tcull, float d[4]) {
    return box_test_wide<F4, Chord, Node4, Fast>(n, r, tcull, d);
  }
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node8& n, const Ray& r, float tcull, float d[8]) {
    return box_test_wide<F8, Chord, Node8, Fast>(n, r, tcull, d);
  }
  /// Closest hit: the record of every child in `mask` (the traversals pass the hit children left
  /// for later: an inner node's lines, a leaf's first pack, or its leaf4 entry where the references
  /// are not packed) is asked for at once, so the misses
  /// of the children visited later overlap the work before them.
  /// With packed references (the default) the address is picked without a branch (a node or
  /// the leaf's first pack; the node's size in lines either way: a leaf of five or more triangles
  /// reads into its second pack): a branch on the child's kind mispredicts often on incoherent
  /// rays.
  /// Only on a tree whose nodes take more than kPrefetchNodeBytes (SimdRay::prefetch, ray.h).
  template <class N>
  [[gnu::always_inline]] static void prefetch(const N& n, const Ray& r, unsigned mask) {
    if (!r.prefetch) return;
    const char* nodes = reinterpret_cast<const char*>(detail::nodes_of<N>(*r.view));
    if (r.view->packed_refs) {
      const char* packs = reinterpret_cast<const char*>(r.view->tri4);
      for (unsigned k = mask; k != 0; k &= k - 1) {
        const std::int32_t c = n.child[std::countr_zero(k)];
        const std::size_t node_at = static_cast<std::size_t>(static_cast<std::uint32_t>(c)) * sizeof(N);
        const std::size_t pack_at = static_cast<std::size_t>(static_cast<std::uint32_t>(~c) >> 3) * sizeof(Tri4);
        const char* p = c >= 0 ? nodes + node_at : packs + pack_at;
        for (std::size_t line = 0; line < sizeof(N); line += 64) _mm_prefetch(p + line, _MM_HINT_T0);
      }
      return;
    }
    for (unsigned k = mask; k != 0; k &= k - 1) {
      const std::int32_t c = n.child[std::countr_zero(k)];
      if (c >= 0) {
        const char* p = nodes + static_cast<std::size_t>(c) * sizeof(N);
        for (std::size_t line = 0; line < sizeof(N); line += 64) _mm_prefetch(p + line, _MM_HINT_T0);
      } else {
        _mm_prefetch(reinterpret_cast<const char*>(r.view->leaf4 + ~c), _MM_HINT_T0);
      }
    }
  }
  /// The hit slot of `mask` with the smallest d (Largest: the largest; an occlusion query's
  /// chords), ties to the lower slot, without a branch per slot: two hits by one compare, more by
  /// a horizontal min (max) over the row with the misses set to +inf (-inf) and the lowest slot
  /// equal to it (d is never NaN: entries start at tmin, chords are clamped at 0).
  template <int W, bool Largest>
  [[gnu::always_inline]] static int extreme(unsigned mask, const float* d) {
    const unsigned rest = mask & (mask - 1);
    if (rest == 0) return std::countr_zero(mask);
    if ((rest & (rest - 1)) == 0) {  // two hits, the commonest case: one compare
      const int a = std::countr_zero(mask), b = std::countr_zero(rest);
      return (Largest ? d[b] > d[a] : d[b] < d[a]) ? b : a;
    }
    if constexpr (W == 8) {
      const __m256 none = _mm256_set1_ps(Largest ? -INFINITY : INFINITY);
      const __m256 v = _mm256_blendv_ps(none, _mm256_loadu_ps(d), lane_mask(mask));
      __m256 m;
      if constexpr (Largest) m = hmax8_splat(v);
      else m = hmin8_splat(v);
      const unsigned eq = static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(v, m, _CMP_EQ_OQ))) & mask;
      return std::countr_zero(eq);
    } else {
      return detail::extreme_slot<W, Largest>(mask, d);
    }
  }
  template <int W>
  [[gnu::always_inline]] static int nearest(unsigned mask, const float* d) { return extreme<W, false>(mask, d); }
  template <int W>
  [[gnu::always_inline]] static int longest(unsigned mask, const float* d) { return extreme<W, true>(mask, d); }

  /// MBVH8 pushes (stack.h: highest slot first): AVX-512 reverses the row of child links,
  /// compresses the hit ones (the mask bit-reversed) in a register and stores the whole row (a
  /// compress straight to memory is microcoded on some CPUs).
  [[gnu::always_inline]] static unsigned push8(std::int32_t* stack, unsigned sp, unsigned mask, const std::int32_t* child) {
#if MBVH_CPU_ISA_ID == 2
    const __m256i links = _mm256_permutexvar_epi32(_mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0),
                                                   _mm256_loadu_si256(reinterpret_cast<const __m256i*>(child)));
    const unsigned rev = static_cast<unsigned>(kReverse8[mask & 0xFFu]);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(stack + sp), _mm256_maskz_compress_epi32(static_cast<__mmask8>(rev), links));
    return sp + static_cast<unsigned>(std::popcount(mask));
#else
    // AVX2 has no compress: a table gives each mask's slots highest first, one permute gathers them
    const __m256i idx = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kDescending8[mask & 0xFFu])));
    const __m256i links = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(child));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(stack + sp), _mm256_permutevar8x32_epi32(links, idx));
    return sp + static_cast<unsigned>(std::popcount(mask));
#endif
  }

#if MBVH_CPU_ISA_ID == 2
  /// The MBVH8 ordered stack's push of four or more hit children (stack.h, OrderedWalk; AVX-512):
  /// every slot's (node, d) entry sorted in registers by the key (d, slot) — d's bits as an
  /// ordered integer (the sign flipped into two's complement: the `fast` mode's entries may be
  /// negative) above the slot, the misses below every hit — farthest first, with a sorting network
  /// of six layers (19 comparators; Knuth, TAOCP vol. 3, §5.3.4), each one permute, one min and
  /// one masked max: no branch on the distances (the insertion sort's mispredict often on
  /// incoherent rays). The row of eight entries is stored whole at `entries`; its first
  /// popcount(mask) are the hits, the farthest first: the nearest, the child entered now (K::nearest's
  /// slot: the smallest d, ties to the lower slot), is the last of them and is not counted by
  /// the caller. Equal distances keep the insertion sort's order (the lower slot popped first).
  static constexpr bool sorted_push8 = true;
  [[gnu::always_inline]] static void push_sorted8(void* entries, unsigned mask, const std::int32_t* child, const float* d) {
    // -0 as +0, so that the integer order is the float compare's (d is never NaN)
    const __m256 dv = _mm256_add_ps(_mm256_loadu_ps(d), _mm256_setzero_ps());
    const __m256i bits = _mm256_castps_si256(dv);
    const __m256i ord = _mm256_xor_si256(bits, _mm256_srli_epi32(_mm256_srai_epi32(bits, 31), 1));
    const __m512i slot = _mm512_setr_epi64(0, 1, 2, 3, 4, 5, 6, 7);
    const __m512i hit = _mm512_or_si512(_mm512_slli_epi64(_mm512_cvtepi32_epi64(ord), 32), slot);
    __m512i v = _mm512_mask_mov_epi64(_mm512_or_si512(_mm512_set1_epi64(INT64_MIN), slot), static_cast<__mmask8>(mask), hit);
    const auto layer = [&v](__m512i perm, __mmask8 lower) {  // lower: each pair's first lane takes the larger key
      const __m512i p = _mm512_permutexvar_epi64(perm, v);
      v = _mm512_mask_max_epi64(_mm512_min_epi64(v, p), lower, v, p);
    };
    layer(_mm512_setr_epi64(2, 3, 0, 1, 6, 7, 4, 5), 0x33);
    layer(_mm512_setr_epi64(4, 5, 6, 7, 0, 1, 2, 3), 0x0F);
    layer(_mm512_setr_epi64(1, 0, 3, 2, 5, 4, 7, 6), 0x55);
    layer(_mm512_setr_epi64(0, 1, 4, 5, 2, 3, 6, 7), 0x0C);
    layer(_mm512_setr_epi64(0, 4, 2, 6, 1, 5, 3, 7), 0x0A);
    layer(_mm512_setr_epi64(0, 2, 1, 4, 3, 6, 5, 7), 0x2A);
    // the entries (node in the low half, d in the high half, as stack.h's Entry), in key order
    const __m512i row = _mm512_permutex2var_epi32(
        _mm512_castsi256_si512(_mm256_loadu_si256(reinterpret_cast<const __m256i*>(child))),
        _mm512_setr_epi32(0, 16, 1, 17, 2, 18, 3, 19, 4, 20, 5, 21, 6, 22, 7, 23),
        _mm512_castsi256_si512(_mm256_castps_si256(_mm256_loadu_ps(d))));
    _mm512_storeu_si512(entries, _mm512_permutexvar_epi64(_mm512_and_si512(v, _mm512_set1_epi64(7)), row));
  }
#endif

  /// The octant-ordered push (stack.h, trace_mbvh8_octant): the order's lanes unpacked (one
  /// variable shift), the hit mask permuted into that order (one shift puts slot s's bit in lane
  /// k's sign), the permuted hit lanes compressed into the list of their slots (AVX-512:
  /// vpcompressd in a register; AVX2: a table of each mask's set lanes and one permute), then
  /// the child links (and the distances) gathered by that list with one permute each and stored
  /// as whole rows.
  template <bool Dist>
  [[gnu::always_inline]] static unsigned push_octant(std::int32_t* stack, float* dist, unsigned sp, unsigned mask,
                                                     std::uint32_t order, const std::int32_t* child, const float* d,
                                                     int& top) {
    const __m256i slots = _mm256_and_si256(_mm256_srlv_epi32(_mm256_set1_epi32(static_cast<int>(order)),
                                                             _mm256_setr_epi32(0, 3, 6, 9, 12, 15, 18, 21)),
                                           _mm256_set1_epi32(7));
    const __m256i bits = _mm256_sllv_epi32(_mm256_set1_epi32(static_cast<int>(mask)), _mm256_sub_epi32(_mm256_set1_epi32(31), slots));
    const unsigned pm = static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(bits)));
#if MBVH_CPU_ISA_ID == 2
    const __m256i sel = _mm256_maskz_compress_epi32(static_cast<__mmask8>(pm), slots);
#else
    const __m256i sel = _mm256_permutevar8x32_epi32(
        slots, _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kAscending8[pm]))));
#endif
    const __m256i links = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(child));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(stack + sp), _mm256_permutevar8x32_epi32(links, sel));
    if constexpr (Dist) _mm256_storeu_ps(dist + sp, _mm256_permutevar8x32_ps(_mm256_loadu_ps(d), sel));
    top = static_cast<int>((order >> (3 * (31 - std::countl_zero(pm)))) & 7u);
    return sp + static_cast<unsigned>(std::popcount(mask));
  }

  /// The octant bitstack's ranks (ScalarKernelsT::octant_ranks): lane j holds the slot of rank j
  /// (one variable shift), shifted so that slot s's bit of the mask lands in the lane's sign (31 -
  /// s = 31 ^ s), one movemask.
  [[gnu::always_inline]] static unsigned octant_ranks(unsigned mask, std::uint32_t order) {
    const __m256i slots = _mm256_and_si256(_mm256_srlv_epi32(_mm256_set1_epi32(static_cast<int>(order)),
                                                             _mm256_setr_epi32(21, 18, 15, 12, 9, 6, 3, 0)),
                                           _mm256_set1_epi32(7));
    const __m256i bits = _mm256_sllv_epi32(_mm256_set1_epi32(static_cast<int>(mask)), _mm256_xor_si256(slots, _mm256_set1_epi32(31)));
    return static_cast<unsigned>(_mm256_movemask_ps(_mm256_castsi256_ps(bits)));
  }

  /// One pass of a leaf's test over the pack at p (F4: lanes k..k+3 of the leaf) or the two packs
  /// at p (F8: lanes k..k+7), `valid` its lanes that hold a triangle. Closest hit: keeps the
  /// smallest (t, prim) in best and shrinks tmax; any hit: true at the first certain hit. The
  /// undecided lanes (occlusion: only while no lane is certain) are settled as tri_test settles
  /// them: a lane with t within its error bound of 0 by the plane distance in double, a lane with
  /// an edge function exactly 0 by the scalar test itself (rare). The reference accepts exactly
  /// the same lanes, and the smallest (t, prim) of a leaf does not depend on how its triangles
  /// are grouped into passes.
  template <class F, bool Any>
  [[gnu::always_inline]] static bool leaf_pass(const Tri4* p, unsigned valid, const Ray& r, float& tmax, Hit& best) {
    constexpr int L = sizeof(typename F::V) / sizeof(float);
    const auto prim = [p](int lane) {
      if constexpr (Fast) return mt_prim<F>(p, lane);  // TriPacks::mt's layout (the fast view's packs)
      else return p[lane >> 2].prim[lane & 3];
    };
    float t[L], u[L], w[L], det[L];
    [[maybe_unused]] unsigned fallback = 0, near0 = 0;  // robust only
    unsigned hit;
    if constexpr (Fast) hit = tri_test_simd_mt<F, Any>(p, r, valid, tmax, t, u, w);
    else hit = tri_test_simd<F, Any>(p, r, valid, tmax, t, u, w, det, fallback, near0);
    if constexpr (Any) {
      if (hit != 0) {
        best.prim = prim(std::countr_zero(hit));
        return true;
      }
    }
    // the watertight test's exact steps (robust only: they read the shear, which a fast ray's
    // set-up leaves out)
    if constexpr (!Fast) {
      for (unsigned f = near0; f != 0; f &= f - 1) {  // tri_test's last step: t's sign in double
        const int lane = std::countr_zero(f);
        if (plane_t_double(r, tri_of(p[lane >> 2], lane & 3)) > 0.0) {
          if constexpr (Any) {
            best.prim = prim(lane);
            return true;
          }
          hit |= 1u << lane;  // t, V, W and det as tri_test's: u = V / det, v = W / det below
        }
      }
      for (unsigned f = fallback; f != 0; f &= f - 1) {
        const int lane = std::countr_zero(f);
        if (tri_test(r, tri_of(p[lane >> 2], lane & 3), tmax, t[lane], u[lane], w[lane])) {
          if constexpr (Any) {
            best.prim = prim(lane);
            return true;
          }
          hit |= 1u << lane;
          det[lane] = 1.0f;  // u, w are the quotients already (x / 1 is exact)
        }
      }
    }
    if constexpr (!Any) {
      if (hit == 0) return false;
      int q = std::countr_zero(hit);
      for (unsigned o = hit & (hit - 1); o != 0; o &= o - 1) {
        const int s = std::countr_zero(o);
        if (t[s] < t[q] || (t[s] == t[q] && prim(s) < prim(q))) q = s;
      }
      if (t[q] < best.t || prim(q) < best.prim) {  // t[q] <= best.t, as in visit_leaf
        if constexpr (Fast) best = Hit{t[q], u[q], w[q], prim(q)};  // tri_test_simd_mt's weights
        else best = Hit{t[q], u[q] / det[q], w[q] / det[q], prim(q)};
        tmax = t[q];
      }
    }
    return false;
  }

  /// A leaf's triangles eight at a time (two packs per pass: the same instructions on 256-bit
  /// registers), its last one to four in a four-lane pass.
  template <bool Any, class St>
  [[gnu::always_inline]] static bool leaf(const TraceView& v, std::int32_t ref, const Ray& r, float& tmax, Hit& best,
                                          St& st) {
    if constexpr (St::on) {
      return detail::visit_leaf<Any, St, Fast>(v, ref, r, tmax, best, st);
    } else {
      if (v.packed_refs) {  // TraceView::packed_refs: the reference locates the packs, 1 to 8 triangles
        const Leaf l = packed_leaf(ref);
        const Tri4* p = v.tri4 + l.first;
        const unsigned valid = (1u << l.count) - 1u;  // the loop below's one pass, without its loop
        if (l.count > 4) return leaf_pass<F8, Any>(p, valid, r, tmax, best);
        return leaf_pass<F4, Any>(p, valid, r, tmax, best);
      }
      const Leaf l = v.leaf4[~ref];
      const Tri4* p = v.tri4 + l.first;
      std::uint32_t k = 0;
      for (; k + 4 < l.count; k += 8, p += 2) {
        const unsigned valid = l.count - k >= 8 ? 0xFFu : (1u << (l.count - k)) - 1u;
        if (leaf_pass<F8, Any>(p, valid, r, tmax, best)) return true;
      }
      if (k < l.count) return leaf_pass<F4, Any>(p, (1u << (l.count - k)) - 1u, r, tmax, best);
      return false;
    }
  }
};

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

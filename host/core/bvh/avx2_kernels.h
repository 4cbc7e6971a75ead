// SPDX-License-Identifier: MIT
// avx2_kernels.h — the binned SAH's per-record loops compiled for AVX2 (internal to
// host/core/bvh/, included by binned_sah.cpp only): the core is built for the baseline ISA, and
// these functions alone carry a target attribute; binned_sah.cpp calls them where the CPU has
// AVX2 (use_vec256) and its SSE2 loops elsewhere. A 256-bit register holds a whole record (lo
// row and prim id, hi row and pad), so two records take one step: their centroids, bins and
// sides in one register each, the lane-by-lane float operations those of the SSE2 loops (the
// same bins, sides and stores; VEX encodings, no FMA: the build sets -ffp-contract=off).
//   - partition: records to the front (left) and the back (right) of the other array, with each
//     side's centroid bounds (the SSE2 loop's SideBounds on two records at once);
//   - side_count / scatter: partition_chunked's count pass and its stable scatter;
//   - bin_pairs: the dense bins' update (DenseBins::bin_parts) with each bin kept as one register,
//     [lo | -hi], so one min grows both rows (min(-a, -b) = -max(a, b), ties and signed zeros
//     included: both take the second operand).
// The children's centroid bounds are reduced from two halves at the end, an order the SSE2 loop
// does not take: a bound may differ from it only in the sign of a zero, which no split decision
// sees (the bins' origin and scale, and the side test, are the same for +0 and -0).
#pragma once
#if defined(__SSE2__) && (defined(__x86_64__) || defined(__i386__)) && (defined(__GNUC__) || defined(__clang__))
#define MBVH_BUILD_AVX2 1
#include <immintrin.h>

#include <cstdint>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/dense_bins.h"

// Named for the registers: the core's symbols name none of the cpu backend's ISAs
// (tests/consumer/core_symbols.sh looks for them).
namespace mbvh::build::vec256 {

/// A node's side test: f = (centroid - origin) * scale < split on each axis.
struct Split {
  float origin[3], scale[3];
  unsigned split;
};

#define MBVH_AVX2 [[gnu::target("avx2")]]

// The loops' constants: rows of two records.
struct Consts {
  __m256 half, xyz, o, s, sp, inf, ninf, sign;
  MBVH_AVX2 explicit Consts(const Split& g) {
    half = _mm256_set1_ps(0.5f);
    xyz = _mm256_castsi256_ps(_mm256_setr_epi32(-1, -1, -1, 0, -1, -1, -1, 0));
    o = _mm256_setr_ps(g.origin[0], g.origin[1], g.origin[2], 0.0f, g.origin[0], g.origin[1], g.origin[2], 0.0f);
    s = _mm256_setr_ps(g.scale[0], g.scale[1], g.scale[2], 0.0f, g.scale[0], g.scale[1], g.scale[2], 0.0f);
    sp = _mm256_set1_ps(static_cast<float>(g.split));
    inf = _mm256_set1_ps(INFINITY);
    ninf = _mm256_set1_ps(-INFINITY);
    sign = _mm256_set1_ps(-0.0f);
  }
};

// Two records' rows (r0, r1: each a whole record, lo with its prim id and hi with its pad) and
// their centroids (lanes 0-2 the first's, 4-6 the second's).
struct Pair {
  __m256 r0, r1, ce;
};
// Records a and b, anywhere.
MBVH_AVX2 inline Pair load_two(const Consts& k, const PrimRef* a, const PrimRef* b) {
  Pair q;
  q.r0 = _mm256_loadu_ps(a->lo);
  q.r1 = _mm256_loadu_ps(b->lo);
  const __m256 lo = _mm256_permute2f128_ps(q.r0, q.r1, 0x20), hi = _mm256_permute2f128_ps(q.r0, q.r1, 0x31);
  q.ce = _mm256_mul_ps(_mm256_add_ps(_mm256_and_ps(lo, k.xyz), hi), k.half);
  return q;
}
// Records p[0] and p[1].
MBVH_AVX2 inline Pair load_pair(const Consts& k, const PrimRef* p) { return load_two(k, p, p + 1); }
// A single record as a pair's first half (the second half a copy: callers use lanes 0-3 only).
MBVH_AVX2 inline Pair load_one(const Consts& k, const PrimRef* p) {
  Pair q;
  q.r0 = q.r1 = _mm256_loadu_ps(p[0].lo);
  const __m256 lo = _mm256_permute2f128_ps(q.r0, q.r0, 0x00), hi = _mm256_permute2f128_ps(q.r0, q.r0, 0x11);
  q.ce = _mm256_mul_ps(_mm256_add_ps(_mm256_and_ps(lo, k.xyz), hi), k.half);
  return q;
}
// Lanes set where the centroid is left of the split (bits 0-2 and 4-6 of the mask).
MBVH_AVX2 inline unsigned left_mask(const Consts& k, __m256 ce, __m256& lt) {
  lt = _mm256_cmp_ps(_mm256_mul_ps(_mm256_sub_ps(ce, k.o), k.s), k.sp, _CMP_LT_OS);
  return static_cast<unsigned>(_mm256_movemask_ps(lt));
}

// Each side's centroid bounds, lane by lane as the SSE2 loop's SideBounds: max(ce, side) is ce
// for a record of that side and +inf for the other's.
template <int A>
struct Sides {
  __m256 acc[2][2];
  MBVH_AVX2 explicit Sides(const Consts& k) { acc[0][0] = acc[1][0] = k.inf, acc[0][1] = acc[1][1] = k.ninf; }
  MBVH_AVX2 void grow(const Consts& k, __m256 ce, __m256 lt) {
    const __m256 left = _mm256_permute_ps(lt, _MM_SHUFFLE(A, A, A, A));  // per 128-bit half
    const __m256 side = _mm256_xor_ps(k.inf, _mm256_and_ps(left, k.sign));
    const __m256 other = _mm256_xor_ps(side, k.sign);
    acc[0][0] = _mm256_min_ps(_mm256_max_ps(ce, side), acc[0][0]);
    acc[0][1] = _mm256_max_ps(_mm256_min_ps(ce, other), acc[0][1]);
    acc[1][0] = _mm256_min_ps(_mm256_max_ps(ce, other), acc[1][0]);
    acc[1][1] = _mm256_max_ps(_mm256_min_ps(ce, side), acc[1][1]);
  }
  MBVH_AVX2 void store(FastBox (&box)[2]) const {
    for (int s = 0; s < 2; ++s) {
      const __m128 lo = _mm_min_ps(_mm256_castps256_ps128(acc[s][0]), _mm256_extractf128_ps(acc[s][0], 1));
      const __m128 hi = _mm_max_ps(_mm256_castps256_ps128(acc[s][1]), _mm256_extractf128_ps(acc[s][1], 1));
      set_rows(box[s], lo, hi);
    }
  }
};

// Records [b, e) of src to dst, those left of the split from dst[b] on, the others from dst[e - 1]
// down, in order; each side's centroid bounds into c. Returns the first right record.
template <int A>
MBVH_AVX2 [[gnu::noinline]] std::uint32_t partition_axis(const Split& g, const PrimRef* src, std::uint32_t b,
                                                         std::uint32_t e, PrimRef* dst, FastBox (&c)[2]) {
  const Consts k(g);
  Sides<A> sides(k);
  std::uint32_t l = b, r = e, i = b;
  for (; i + 2 <= e; i += 2) {
    const Pair q = load_pair(k, src + i);
    __m256 lt;
    const unsigned m = left_mask(k, q.ce, lt);
    const unsigned right0 = ~m >> A & 1u, right1 = ~m >> (4 + A) & 1u;
    std::uint32_t at = right0 ? r - 1 : l;
    _mm256_storeu_ps(dst[at].lo, q.r0);
    l += 1 - right0;
    r -= right0;
    at = right1 ? r - 1 : l;
    _mm256_storeu_ps(dst[at].lo, q.r1);
    l += 1 - right1;
    r -= right1;
    sides.grow(k, q.ce, lt);
  }
  if (i < e) {
    const Pair q = load_one(k, src + i);
    __m256 lt;
    const unsigned right = ~left_mask(k, q.ce, lt) >> A & 1u;
    _mm256_storeu_ps(dst[right ? r - 1 : l].lo, q.r0);
    l += 1 - right;
    sides.grow(k, q.ce, lt);
  }
  sides.store(c);
  return l;
}

inline std::uint32_t partition(const Split& g, int axis, const PrimRef* src, std::uint32_t b, std::uint32_t e,
                               PrimRef* dst, FastBox (&c)[2]) {
  if (axis == 0) return partition_axis<0>(g, src, b, e, dst, c);
  if (axis == 1) return partition_axis<1>(g, src, b, e, dst, c);
  return partition_axis<2>(g, src, b, e, dst, c);
}

// partition_chunked's count pass over records [b, e): each side's centroid bounds into box, the
// left records returned.
template <int A>
MBVH_AVX2 [[gnu::noinline]] std::uint32_t side_count_axis(const Split& g, const PrimRef* src, std::size_t b,
                                                          std::size_t e, FastBox (&box)[2]) {
  const Consts k(g);
  Sides<A> sides(k);
  std::uint32_t l = 0;
  std::size_t i = b;
  for (; i + 2 <= e; i += 2) {
    const Pair q = load_pair(k, src + i);
    __m256 lt;
    const unsigned m = left_mask(k, q.ce, lt);
    l += (m >> A & 1u) + (m >> (4 + A) & 1u);
    sides.grow(k, q.ce, lt);
  }
  if (i < e) {
    const Pair q = load_one(k, src + i);
    __m256 lt;
    l += left_mask(k, q.ce, lt) >> A & 1u;
    sides.grow(k, q.ce, lt);
  }
  sides.store(box);
  return l;
}

inline std::uint32_t side_count(const Split& g, int axis, const PrimRef* src, std::size_t b, std::size_t e,
                                FastBox (&box)[2]) {
  if (axis == 0) return side_count_axis<0>(g, src, b, e, box);
  if (axis == 1) return side_count_axis<1>(g, src, b, e, box);
  return side_count_axis<2>(g, src, b, e, box);
}

// partition_chunked's scatter: records [b, e) in order, the left ones to dst[l++], the right
// ones to dst[r++].
MBVH_AVX2 [[gnu::noinline]] inline void scatter(const Split& g, int axis, const PrimRef* src, std::size_t b,
                                                std::size_t e, PrimRef* dst, std::uint32_t& l_out,
                                                std::uint32_t& r_out) {
  const Consts k(g);
  std::uint32_t l = l_out, r = r_out;
  std::size_t i = b;
  const unsigned a0 = static_cast<unsigned>(axis), a1 = a0 + 4;
  for (; i + 2 <= e; i += 2) {
    const Pair q = load_pair(k, src + i);
    __m256 lt;
    const unsigned m = left_mask(k, q.ce, lt);
    const unsigned left0 = m >> a0 & 1u, left1 = m >> a1 & 1u;
    _mm256_storeu_ps(dst[left0 ? l : r].lo, q.r0);
    l += left0;
    r += 1 - left0;
    _mm256_storeu_ps(dst[left1 ? l : r].lo, q.r1);
    l += left1;
    r += 1 - left1;
  }
  if (i < e) {
    const Pair q = load_one(k, src + i);
    __m256 lt;
    const unsigned left = left_mask(k, q.ce, lt) >> a0 & 1u;
    _mm256_storeu_ps(dst[left ? l : r].lo, q.r0);
    l += left;
    r += 1 - left;
  }
  l_out = l;
  r_out = r;
}

// DenseBins::bin_parts<2>'s steps: record b + i into s0 and record b + n + i into s1 for i in
// [0, n), one step for both (the bins of DenseBins::Binning: the same float operations; g's
// split unused).
MBVH_AVX2 [[gnu::noinline]] inline void bin_pairs(const Split& g, unsigned last, DenseBins& s0, DenseBins& s1,
                                                  const PrimRef* p, std::size_t b, std::size_t n) {
  const Consts k(g);
  const __m256 zero = _mm256_setzero_ps();
  const __m256 neg_hi = _mm256_setr_ps(0.0f, 0.0f, 0.0f, 0.0f, -0.0f, -0.0f, -0.0f, -0.0f);
  const __m256i lst = _mm256_set1_epi32(static_cast<int>(last));
  for (std::size_t i = 0; i < n; ++i) {
    const Pair q = load_two(k, p + b + i, p + b + n + i);
    const __m256 f = _mm256_max_ps(_mm256_mul_ps(_mm256_sub_ps(q.ce, k.o), k.s), zero);
    alignas(32) std::uint32_t ks[8];  // f <= bins: the 16-bit min is the clamp (DenseBins::Binning)
    _mm256_store_si256(reinterpret_cast<__m256i*>(ks), _mm256_min_epi16(_mm256_cvttps_epi32(f), lst));
    const __m256 b0 = _mm256_xor_ps(_mm256_and_ps(q.r0, k.xyz), neg_hi), b1 = _mm256_xor_ps(_mm256_and_ps(q.r1, k.xyz), neg_hi);
    for (int a = 0; a < 3; ++a) {
      float* w0 = reinterpret_cast<float*>(&s0.row[a][ks[a]]);
      _mm256_store_ps(w0, _mm256_min_ps(_mm256_load_ps(w0), b0));
      ++s0.count[a][ks[a]];
      float* w1 = reinterpret_cast<float*>(&s1.row[a][ks[4 + a]]);
      _mm256_store_ps(w1, _mm256_min_ps(_mm256_load_ps(w1), b1));
      ++s1.count[a][ks[4 + a]];
    }
  }
}

#undef MBVH_AVX2

}  // namespace mbvh::build::vec256
#endif

// SPDX-License-Identifier: MIT
// dense_bins.h — the binned-SAH bins of a large node as SSE rows (internal to host/core/bvh/):
// every bin cleared up front, a record binned on all three axes without a branch, and the SAH
// sweep run on the three axes at once, one axis per lane (the layout of Embree's binning,
// Wald 2007 / Wald, "Fast Construction of SAH BVHs on the Intel MIC Architecture", 2012).
// The float operations are those of SahBuilder's sparse bins lane by lane (centroid, bin, box
// unions, half areas, costs), so both choose the same split, and the tree does not depend on
// which of the two a node took.
#pragma once
#if defined(__SSE2__)
#include <emmintrin.h>

#include <cstdint>

#include "host/core/bvh/builder.h"

namespace mbvh::build {

/// The centroid bins of one node on three axes: a box row pair and a count per axis and bin
/// (one address per update). 64 bins at most. A bin's box is kept as lo and -hi, so that both
/// rows grow by a min (min(-a, -b) = -max(a, b), ties and signed zeros included: both give the
/// second operand), and the pair, 32 bytes, is one 256-bit row for the AVX2 binning
/// (avx2_kernels.h).
struct DenseBins {
  static constexpr unsigned kMax = 64;
  struct Row {
    __m128 lo, nhi;  // nhi: -hi
  };
  alignas(32) Row row[3][kMax];
  std::uint32_t count[3][kMax];

  /// Empties the first `bins` bins of every axis.
  void clear(unsigned bins) {
    const __m128 inf = _mm_set1_ps(INFINITY);
    for (int a = 0; a < 3; ++a)
      for (unsigned k = 0; k < bins; ++k) {
        row[a][k].lo = inf;
        row[a][k].nhi = inf;
        count[a][k] = 0;
      }
  }

  /// A node's binning: bin = min(last, floor(max(0, (centroid - origin) * scale))) per axis.
  struct Binning {
    __m128 half = _mm_set1_ps(0.5f), zero = _mm_setzero_ps(), o, s;
    __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));  // drops the prim id's lane
    __m128 sign = _mm_set1_ps(-0.0f);
    __m128i lst;
    Binning(const float origin[3], const float scale[3], unsigned last)
        : o(_mm_setr_ps(origin[0], origin[1], origin[2], 0.0f)), s(_mm_setr_ps(scale[0], scale[1], scale[2], 0.0f)),
          lst(_mm_set1_epi32(static_cast<int>(last))) {}
    /// A record's rows: lo without the prim id, hi.
    void load(const PrimRef& r, __m128& l, __m128& h) const {
      l = _mm_and_ps(_mm_loadu_ps(r.lo), xyz);
      h = _mm_loadu_ps(r.hi);
    }
    /// The record's bin on each axis (lanes 0-2).
    __m128i index(__m128 l, __m128 h) const {
      // f <= bins (1 + 2 ulp): the truncated bin fits 16 bits, so a 16-bit min is the clamp
      const __m128 f = _mm_max_ps(_mm_mul_ps(_mm_sub_ps(_mm_mul_ps(_mm_add_ps(l, h), half), o), s), zero);
      return _mm_min_epi16(_mm_cvttps_epi32(f), lst);
    }
  };

  /// Grows bin k of axis a by a record's rows l and -h (`nh`).
  void add(int a, unsigned k, __m128 l, __m128 nh) {
    Row& r = row[a][k];
    r.lo = _mm_min_ps(r.lo, l);
    r.nhi = _mm_min_ps(r.nhi, nh);
    ++count[a][k];
  }

  /// Bins records [b, e) (Binning's bins).
  void bin(const PrimRef* p, std::size_t b, std::size_t e, const float origin[3], const float scale[3], unsigned last) {
    const Binning g(origin, scale, last);
    std::size_t i = b;
    for (; i + 2 <= e; i += 2) {  // two records per step: their index math overlaps
      __m128 l0, h0, l1, h1;
      g.load(p[i], l0, h0);
      g.load(p[i + 1], l1, h1);
      alignas(16) std::uint32_t k0[4], k1[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(k0), g.index(l0, h0));
      _mm_store_si128(reinterpret_cast<__m128i*>(k1), g.index(l1, h1));
      h0 = _mm_xor_ps(h0, g.sign);
      h1 = _mm_xor_ps(h1, g.sign);
      for (int a = 0; a < 3; ++a) add(a, k0[a], l0, h0);
      for (int a = 0; a < 3; ++a) add(a, k1[a], l1, h1);
    }
    for (; i < e; ++i) {
      __m128 l0, h0;
      g.load(p[i], l0, h0);
      alignas(16) std::uint32_t k0[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(k0), g.index(l0, h0));
      h0 = _mm_xor_ps(h0, g.sign);
      for (int a = 0; a < 3; ++a) add(a, k0[a], l0, h0);
    }
  }

  /// Bins records [b, e) into P sets at once: part q of P contiguous parts into set[q], one
  /// record of each part per step, so that runs of records falling in the same bin (neighbours
  /// in a partitioned array often do) make P independent chains of bin updates, not one. The
  /// parts are contiguous and in order, so merging set[1..P) into set[0] in order gives the
  /// bits of binning [b, e) in order into one set: a bin's min (max) keeps the last of its
  /// records equal to the minimum (maximum), as _mm_min_ps(bin, record) does on ties (signed
  /// zeros), and a later part's records are the later ones. set[1..P) must be cleared.
  template <int P>
  static void bin_parts(DenseBins* const (&set)[P], const PrimRef* p, std::size_t b, std::size_t e,
                        const float origin[3], const float scale[3], unsigned last, unsigned bins) {
    const Binning g(origin, scale, last);
    const std::size_t n = (e - b) / P;
    for (std::size_t i = 0; i < n; ++i) {
      __m128 l[P], h[P];
      alignas(16) std::uint32_t k[P][4];
      for (int q = 0; q < P; ++q) {
        g.load(p[b + std::size_t(q) * n + i], l[q], h[q]);
        _mm_store_si128(reinterpret_cast<__m128i*>(k[q]), g.index(l[q], h[q]));
        h[q] = _mm_xor_ps(h[q], g.sign);
      }
      for (int a = 0; a < 3; ++a)
        for (int q = 0; q < P; ++q) set[q]->add(a, k[q][a], l[q], h[q]);
    }
    const std::size_t tail = b + std::size_t(P) * n;
    if (tail < e) set[P - 1]->bin(p, tail, e, origin, scale, last);  // the remainder: the last part's end
    for (int q = 1; q < P; ++q) set[0]->merge(*set[q], bins);
  }

  /// Adds another node's bins (the same geometry) into these.
  void merge(const DenseBins& o, unsigned bins) {
    for (int a = 0; a < 3; ++a)
      for (unsigned k = 0; k < bins; ++k) {
        row[a][k].lo = _mm_min_ps(row[a][k].lo, o.row[a][k].lo);
        row[a][k].nhi = _mm_min_ps(row[a][k].nhi, o.row[a][k].nhi);
        count[a][k] += o.count[a][k];
      }
  }

  /// The union of the boxes of the first `bins` bins of axis 0 (every record is in one).
  void bounds(unsigned bins, FastBox& box) const {
    __m128 l = _mm_set1_ps(INFINITY), nh = _mm_set1_ps(INFINITY);
    for (unsigned k = 0; k < bins; ++k) {
      l = _mm_min_ps(l, row[0][k].lo);
      nh = _mm_min_ps(nh, row[0][k].nhi);
    }
    set_rows(box, l, _mm_xor_ps(nh, _mm_set1_ps(-0.0f)));
  }

  /// The cheapest split (bins < split to the left) of the three axes, a triangle costing 1:
  /// cost = half_area(left) * n_left + half_area(right) * n_right, the first minimum in (axis,
  /// split) order among splits with both sides occupied. Returns false when none exists.
  bool best_split(unsigned bins, float& best_cost, int& best_axis, unsigned& best_split) const {
    // -- one lane per axis: the rows x, y, z of bin k's box on axis (lane)
    struct Rows {
      __m128 lx, ly, lz, hx, hy, hz;
    };
    auto rows = [&](unsigned k) {
      __m128 l0 = row[0][k].lo, l1 = row[1][k].lo, l2 = row[2][k].lo, l3 = _mm_setzero_ps();
      const __m128 sign = _mm_set1_ps(-0.0f);
      __m128 h0 = _mm_xor_ps(row[0][k].nhi, sign), h1 = _mm_xor_ps(row[1][k].nhi, sign),
             h2 = _mm_xor_ps(row[2][k].nhi, sign), h3 = _mm_setzero_ps();
      _MM_TRANSPOSE4_PS(l0, l1, l2, l3);
      _MM_TRANSPOSE4_PS(h0, h1, h2, h3);
      return Rows{l0, l1, l2, h0, h1, h2};
    };
    auto grow = [](Rows& acc, const Rows& r) {
      acc.lx = _mm_min_ps(acc.lx, r.lx), acc.ly = _mm_min_ps(acc.ly, r.ly), acc.lz = _mm_min_ps(acc.lz, r.lz);
      acc.hx = _mm_max_ps(acc.hx, r.hx), acc.hy = _mm_max_ps(acc.hy, r.hy), acc.hz = _mm_max_ps(acc.hz, r.hz);
    };
    auto counts = [&](unsigned k) {
      return _mm_setr_epi32(static_cast<int>(count[0][k]), static_cast<int>(count[1][k]), static_cast<int>(count[2][k]), 0);
    };
    auto area = [](const Rows& r) {  // FastBox::half_area's operations
      const __m128 ex = _mm_sub_ps(r.hx, r.lx), ey = _mm_sub_ps(r.hy, r.ly), ez = _mm_sub_ps(r.hz, r.lz);
      return _mm_add_ps(_mm_add_ps(_mm_mul_ps(ex, ey), _mm_mul_ps(ey, ez)), _mm_mul_ps(ez, ex));
    };
    const __m128 inf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
    const Rows empty{inf, inf, inf, ninf, ninf, ninf};
    // -- from the top: area and count of bins >= k
    __m128 right_area[kMax];
    __m128i right_count[kMax];
    Rows acc = empty;
    __m128i cnt = _mm_setzero_si128();
    for (unsigned k = bins - 1; k >= 1; --k) {
      grow(acc, rows(k));
      cnt = _mm_add_epi32(cnt, counts(k));
      right_area[k] = area(acc);
      right_count[k] = cnt;
    }
    // -- from the bottom: the cost of each split, the first minimum per lane
    acc = empty;
    cnt = _mm_setzero_si128();
    const __m128i zero = _mm_setzero_si128();
    __m128 best = inf;
    __m128i split = zero;
    for (unsigned k = 0; k + 1 < bins; ++k) {
      grow(acc, rows(k));
      cnt = _mm_add_epi32(cnt, counts(k));
      const __m128i rc = right_count[k + 1];
      const __m128 cost = _mm_add_ps(_mm_mul_ps(area(acc), _mm_cvtepi32_ps(cnt)),
                                     _mm_mul_ps(right_area[k + 1], _mm_cvtepi32_ps(rc)));
      const __m128i both = _mm_andnot_si128(_mm_or_si128(_mm_cmpeq_epi32(cnt, zero), _mm_cmpeq_epi32(rc, zero)),
                                            _mm_set1_epi32(-1));
      const __m128i take = _mm_and_si128(_mm_castps_si128(_mm_cmplt_ps(cost, best)), both);
      best = _mm_or_ps(_mm_and_ps(_mm_castsi128_ps(take), cost), _mm_andnot_ps(_mm_castsi128_ps(take), best));
      split = _mm_or_si128(_mm_and_si128(take, _mm_set1_epi32(static_cast<int>(k + 1))), _mm_andnot_si128(take, split));
    }
    // -- the axes in order
    alignas(16) float bc[4];
    alignas(16) std::uint32_t bs[4];
    _mm_store_ps(bc, best);
    _mm_store_si128(reinterpret_cast<__m128i*>(bs), split);
    best_cost = INFINITY;
    best_axis = -1;
    for (int a = 0; a < 3; ++a)
      if (bs[a] != 0 && bc[a] < best_cost) {
        best_cost = bc[a];
        best_axis = a;
        best_split = bs[a];
      }
    return best_axis >= 0;
  }
};

}  // namespace mbvh::build
#endif

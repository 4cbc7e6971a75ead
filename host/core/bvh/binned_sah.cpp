// SPDX-License-Identifier: MIT
// binned_sah.cpp — the one BVH build: a binned-SAH binary BVH over the non-degenerate triangles
// (Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies", 2007), with the binary
// depth capped so that every path fits the 64-bit bitstack (TRAVERSAL.md §3.5).
//
// Parallel and deterministic: the top of the tree is split breadth-first with binning spread
// over threads (box unions and counts are exact, so the reduction order does not matter), then
// the remaining subtrees are built one per task. Every split decision is the same function of
// the same inputs, so the bytes do not depend on the thread count.
#include <algorithm>
#include <atomic>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "host/core/layouts.h"
#include "host/core/bvh/builder.h"
#include "host/core/bvh/dense_bins.h"
#include "host/core/bvh/sbvh.h"
#include "host/core/bvh/triangles.h"
#include "mbvh/error.h"
#include "host/core/enum_check.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"

namespace mbvh {

const char* to_string(Layout l) { return l == Layout::mbvh2 ? "mbvh2" : l == Layout::mbvh4 ? "mbvh4" : "mbvh8"; }

Layout parse_layout(const std::string& s) {
  if (s == "mbvh2") return Layout::mbvh2;
  if (s == "mbvh4") return Layout::mbvh4;
  if (s == "mbvh8") return Layout::mbvh8;
  throw Error("unknown layout '" + s + "' (known: mbvh2, mbvh4, mbvh8)");
}

const char* to_string(BuildQuality q) {
  return q == BuildQuality::low ? "low" : q == BuildQuality::medium ? "medium" : "high";
}

BuildQuality parse_quality(const std::string& s) {
  if (s == "low") return BuildQuality::low;
  if (s == "medium") return BuildQuality::medium;
  if (s == "high") return BuildQuality::high;
  throw Error("unknown build quality '" + s + "' (known: low, medium, high)");
}

std::uint64_t hash_bytes(const void* p, std::size_t n, std::uint64_t h) {
  // FNV-1a's step over 64-bit words in four interleaved lanes (independent multiplies), the
  // lanes then folded in order, then the tail's bytes: many times faster than byte by byte,
  // which made hashing a large build cost as much as a refit.
  const unsigned char* b = static_cast<const unsigned char*>(p);
  constexpr std::uint64_t prime = 0x100000001b3ull;
  std::uint64_t lane[4] = {h, h ^ 1, h ^ 2, h ^ 3};
  std::size_t i = 0;
  for (; i + 32 <= n; i += 32)
    for (int k = 0; k < 4; ++k) {
      std::uint64_t w;
      std::memcpy(&w, b + i + 8 * k, 8);
      lane[k] = (lane[k] ^ w) * prime;
      lane[k] ^= lane[k] >> 29;
    }
  for (int k = 0; k < 4; ++k) h = ((h ^ lane[k]) * prime) ^ (lane[k] >> 31);
  for (; i < n; ++i) h = (h ^ b[i]) * prime;
  return h;
}

namespace build {
namespace {

constexpr unsigned kMaxBins = 64;
// Nodes of at least kParallelMin records are binned and partitioned in chunks of kGrain records
// (in parallel where threads are free), reduced in chunk order; smaller ones in one pass. Which
// path a node takes depends only on its size, so the bytes do not depend on the thread count.
constexpr std::uint32_t kParallelMin = 65536;
constexpr std::size_t kGrain = 16384;
// Nodes of at least kDenseMin records are binned in dense bins (dense_bins.h), smaller ones in
// sparse bins; both choose the same split (a node box may differ in the sign of a zero bound:
// min(+0, -0) keeps the operand order, which differs; Sibenik's tree bytes change with the
// threshold, its splits do not). Sparse bins cost fewer instructions below 64 records (callgrind,
// conference and Sibenik: thresholds 8, 16, 32 take 23 %, 7 % and 1.6 % more).
constexpr std::uint32_t kDenseMin = 64;
static_assert(DenseBins::kMax == kMaxBins);

struct Bin {  // lane 3 unused
  alignas(16) float lo[4];
  alignas(16) float hi[4];
  void grow(const float* l, const float* h) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], l[a]);
      hi[a] = std::max(hi[a], h[a]);
    }
  }
};

// Sparse bins of the three axes, one set per task, reused from node to node: every bin is empty
// between nodes (reset() empties only the bins `mask` marks occupied), so binning a record
// needs no test whether its bin was set up.
struct Bins {
  std::uint64_t mask[3] = {0, 0, 0};
  Bin bin[3][kMaxBins];
  std::uint32_t count[3][kMaxBins];
  Bins() {
    for (int a = 0; a < 3; ++a)
      for (unsigned k = 0; k < kMaxBins; ++k) empty(a, k);
  }
  void empty(int a, unsigned k) {
    for (int d = 0; d < 4; ++d) {
      bin[a][k].lo[d] = INFINITY;
      bin[a][k].hi[d] = -INFINITY;
    }
    count[a][k] = 0;
  }
  void reset() {
    for (int a = 0; a < 3; ++a) {
      for (std::uint64_t m = mask[a]; m; m &= m - 1) empty(a, static_cast<unsigned>(std::countr_zero(m)));
      mask[a] = 0;
    }
  }
};

class SahBuilder {
public:
  SahBuilder(const BuildOptions& opt, RawVector<PrimRef>& prims)
      : opt_(opt), prims_(prims), scratch_(prims.size()), bins_(std::clamp(opt.bins, 2u, kMaxBins)) {}

  // Splits node n (in `arena`) into two children appended to `arena`, or marks it a leaf.
  // `threads`: workers for a large node's chunks (1 inside a subtree task).
  // `work`: the task's sparse bins.
  void split(std::vector<TmpNode>& arena, std::size_t n, unsigned threads, Bins& work) {
    TmpNode c[2];
    if (!split_node(arena[n], c, threads, work)) return;
    for (int side = 0; side < 2; ++side) {
      arena[n].child[side] = static_cast<std::int32_t>(arena.size());
      arena.push_back(c[side]);
    }
  }

  // Splits `t` into the children c (their ranges, depths, boxes) and returns true, or marks `t`
  // a leaf and returns false. Touches only t's records: nodes of disjoint ranges may be split
  // at the same time.
  bool split_node(TmpNode& t, TmpNode (&c)[2], unsigned threads, Bins& work) {
    const TmpNode node = t;
    const std::uint32_t count = node.end - node.begin;
    const bool at_cap = node.depth >= opt_.depth_cap;
    if (count <= 1 || at_cap) {
      const PrimRef* src = records(node.depth);
      t.box = FastBox();
      for (std::uint32_t i = node.begin; i < node.end; ++i) t.box.grow(src[i]);
      make_leaf(t, count > opt_.max_leaf);
      return false;
    }
    // -- bin centroids along the three axes: bin = floor((c - lo) * bins / extent), as floats
    Geometry g;
    for (int a = 0; a < 3; ++a) {
      const float ext = node.cbox.hi[a] - node.cbox.lo[a];
      g.origin[a] = node.cbox.lo[a];
      g.scale[a] = ext > 0 ? static_cast<float>(bins_) / ext : 0.0f;
    }
    g.last = bins_ - 1;
    float best_cost = INFINITY;
    int best_axis = -1;
    unsigned best_split = 0;
    // the sweeps also bound the node's records (the union of its bins; partitions bound only
    // the children's centroids)
    if (count == 2) {
      pair_sweep(g, node, t.box, best_cost, best_axis, best_split);
    } else
#if defined(__SSE2__)
    if (count >= kDenseMin && opt_.leaf_block <= 1) {
      dense_sweep(g, node, threads, t.box, best_cost, best_axis, best_split);
    } else
#endif
      sparse_sweep(g, node, threads, work, t.box, best_cost, best_axis, best_split);
    const float area = t.box.half_area();
    const float leaf_cost = blocks(count);
    const float split_cost = opt_.traversal_cost + (area > 0 ? best_cost / area : 0.0f);
    std::uint32_t mid;
    if (best_axis < 0) {
      // all centroids equal: no spatial split exists; halve by index if the leaf would be too big
      if (count <= opt_.max_leaf) {
        make_leaf(t, false);
        return false;
      }
      mid = node.begin + count / 2;
      const PrimRef* src = records(node.depth);
      PrimRef* dst = records(node.depth + 1);
      for (std::uint32_t i = node.begin; i < node.end; ++i) {
        c[i < mid ? 0 : 1].cbox.grow_centroid(src[i]);
        dst[i] = src[i];
      }
    } else {
      if (count <= opt_.max_leaf && leaf_cost <= split_cost) {
        make_leaf(t, false);
        return false;
      }
      mid = count >= kParallelMin ? partition_chunked(g, best_axis, best_split, node, c, threads)
                                  : partition(g, best_axis, best_split, node, c);
    }
    // -- children
    for (int side = 0; side < 2; ++side) {
      c[side].begin = side == 0 ? node.begin : mid;
      c[side].end = side == 0 ? mid : node.end;
      c[side].depth = node.depth + 1;
    }
    return true;
  }

  float blocks(std::uint32_t n) const {
    return opt_.leaf_block <= 1 ? static_cast<float>(n) : build::blocks(n, opt_.leaf_block);
  }

  void build_subtree(std::vector<TmpNode>& arena) {
    Bins work;
    for (std::size_t n = 0; n < arena.size(); ++n) split(arena, n, 1, work);
  }

private:
  // The records of a node at `depth`: partitions move them from one array to the other, so a
  // node at an even depth finds its records in prims_, one at an odd depth in scratch_.
  PrimRef* records(std::uint32_t depth) { return depth & 1 ? scratch_.data() : prims_.data(); }
  const PrimRef* records(std::uint32_t depth) const { return depth & 1 ? scratch_.data() : prims_.data(); }

  // Makes `t` a leaf, its records moved to prims_ (the leaf order the caller reads).
  void make_leaf(TmpNode& t, bool forced) {
    t.leaf = true;
    t.forced = forced;
    if (t.depth & 1) std::copy(scratch_.begin() + t.begin, scratch_.begin() + t.end, prims_.begin() + t.begin);
  }

  struct Geometry {
    float origin[3], scale[3];
    unsigned last;
    unsigned bin(const PrimRef& r, int a) const {
      const float f = (r.centroid(a) - origin[a]) * scale[a];
      return std::min(last, static_cast<unsigned>(f > 0 ? f : 0));
    }
    // bin(r, a) < split for a split in [1, last]: the clamps and the truncation do not change
    // the side, so one float compare decides it.
    bool left(const PrimRef& r, int a, unsigned split) const {
      return (r.centroid(a) - origin[a]) * scale[a] < static_cast<float>(split);
    }
  };

  // The sweep's answer for two records (a third of all nodes split), without bins: on every
  // axis where the centroids differ they fall in bin 0 and a bin >= 1 (the smaller centroid is
  // the bins' origin), so every such axis offers one split, one record on each side, at the same
  // cost (a sum of the same two areas); the sweep keeps the first such axis, at split 1.
  void pair_sweep(const Geometry& g, const TmpNode& node, FastBox& box, float& best_cost, int& best_axis,
                  unsigned& best_split) const {
    const PrimRef* p = records(node.depth) + node.begin;
    FastBox first, second;
    first.grow(p[0]);
    second.grow(p[1]);
    box = first;
    box.grow(second);
    for (int a = 0; a < 3 && best_axis < 0; ++a)
      if (g.scale[a] != 0.0f) best_axis = a;
    if (best_axis < 0) return;
    best_cost = first.half_area() * blocks(1) + second.half_area() * blocks(1);
    best_split = 1;
  }

  // Sparse bins (small nodes, and any node where blocks() is not a plain count): only occupied
  // bins are initialised and swept (a mask per axis): a split between two occupied bins prices
  // the same at every empty bin between them, and the sweep keeps the first, so visiting the
  // occupied ones gives the same choice as visiting all. The cheapest SAH split (bin < split to
  // the left, the first minimum in (axis, split) order) into best_*.
  void sparse_sweep(const Geometry& g, const TmpNode& node, unsigned threads, Bins& bins, FastBox& box,
                    float& best_cost, int& best_axis, unsigned& best_split) const {
    const std::uint32_t count = node.end - node.begin;
    if (count >= kParallelMin) {
      const std::size_t chunks = (count + kGrain - 1) / kGrain;
      std::vector<Bins> partial(chunks);
      parallel_for(count, kGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
        bin_range(g, records(node.depth), node.begin + b, node.begin + e, partial[b / kGrain]);
      });
      for (std::size_t c = 0; c < chunks; ++c)
        for (int a = 0; a < 3; ++a)
          for (std::uint64_t m = partial[c].mask[a]; m; m &= m - 1) {
            const unsigned k = static_cast<unsigned>(std::countr_zero(m));
            bins.bin[a][k].grow(partial[c].bin[a][k].lo, partial[c].bin[a][k].hi);
            bins.count[a][k] += partial[c].count[a][k];
            bins.mask[a] |= std::uint64_t(1) << k;
          }
    } else {
      bin_range(g, records(node.depth), node.begin, node.end, bins);
    }
    box = FastBox();  // every record is in one bin of axis 0
    for (std::uint64_t m = bins.mask[0]; m; m &= m - 1) {
      const Bin& b = bins.bin[0][std::countr_zero(m)];
      box.grow_rows(b.lo, b.hi);
    }
#if defined(__SSE2__)
    // a running box as two rows; its half area with FastBox::half_area's operations in order:
    // (e0 e1 + e1 e2) + e2 e0
    struct Acc {
      __m128 lo = _mm_set1_ps(INFINITY), hi = _mm_set1_ps(-INFINITY);
      void grow(const Bin& b) {
        lo = _mm_min_ps(lo, _mm_load_ps(b.lo));
        hi = _mm_max_ps(hi, _mm_load_ps(b.hi));
      }
      float half_area() const {
        const __m128 e = _mm_sub_ps(hi, lo);
        const __m128 p = _mm_mul_ps(e, _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1)));
        const __m128 s = _mm_add_ss(p, _mm_shuffle_ps(p, p, _MM_SHUFFLE(1, 1, 1, 1)));
        return _mm_cvtss_f32(_mm_add_ss(s, _mm_shuffle_ps(p, p, _MM_SHUFFLE(2, 2, 2, 2))));
      }
    };
#else
    struct Acc {
      FastBox box;
      void grow(const Bin& b) { box.grow_rows(b.lo, b.hi); }
      float half_area() const { return box.half_area(); }
    };
#endif
    for (int a = 0; a < 3; ++a) {
      if (g.scale[a] == 0.0f) continue;
      const std::uint64_t mask = bins.mask[a];
      float right_area[kMaxBins];
      std::uint32_t right_count[kMaxBins];
      Acc acc;
      std::uint32_t cnt = 0;
      for (std::uint64_t m = mask; m;) {  // occupied bins from the top: bounds of bins >= k
        const unsigned k = 63u - static_cast<unsigned>(std::countl_zero(m));
        m &= ~(std::uint64_t(1) << k);
        acc.grow(bins.bin[a][k]);
        cnt += bins.count[a][k];
        right_area[k] = acc.half_area();
        right_count[k] = cnt;
      }
      acc = Acc();
      cnt = 0;
      for (std::uint64_t m = mask; m;) {
        const unsigned k = static_cast<unsigned>(std::countr_zero(m));
        m &= m - 1;
        if (m == 0) break;  // the last occupied bin: nothing to its right
        acc.grow(bins.bin[a][k]);
        cnt += bins.count[a][k];
        const unsigned next = static_cast<unsigned>(std::countr_zero(m));
        const float cost = acc.half_area() * blocks(cnt) + right_area[next] * blocks(right_count[next]);
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_split = k + 1;
        }
      }
    }
    bins.reset();
  }

#if defined(__SSE2__)
  // Dense bins (dense_bins.h) for nodes of at least kDenseMin records: the same choice as
  // sparse_sweep, in fewer operations per record and per bin.
  void dense_sweep(const Geometry& g, const TmpNode& node, unsigned threads, FastBox& box, float& best_cost,
                   int& best_axis, unsigned& best_split) const {
    const std::uint32_t count = node.end - node.begin;
    DenseBins bins;
    bins.clear(bins_);
    if (count >= kParallelMin) {
      const std::size_t chunks = (count + kGrain - 1) / kGrain;
      std::vector<DenseBins> partial(chunks);
      parallel_for(count, kGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
        DenseBins& p = partial[b / kGrain];
        p.clear(bins_);
        p.bin(records(node.depth), node.begin + b, node.begin + e, g.origin, g.scale, g.last);
      });
      for (std::size_t c = 0; c < chunks; ++c) bins.merge(partial[c], bins_);
    } else {
      bins.bin(records(node.depth), node.begin, node.end, g.origin, g.scale, g.last);
    }
    bins.bounds(bins_, box);
    bins.best_split(bins_, best_cost, best_axis, best_split);
  }
#endif

  // Out of line (as partition()), so that profiles show binning and partitioning apart.
  [[gnu::noinline]] void bin_range(const Geometry& g, const PrimRef* src, std::size_t b, std::size_t e,
                                   Bins& out) const {
#if defined(__SSE2__)
    // Four lanes at once: the centroid, its bin on each axis (the same float operations as
    // Geometry::bin, so the same bins; f <= bins (1 + 2 ulp), so a 16-bit min is the clamp) and
    // the bin's box as one min and one max.
    const __m128 half = _mm_set1_ps(0.5f), zero = _mm_setzero_ps();
    const __m128 origin = _mm_setr_ps(g.origin[0], g.origin[1], g.origin[2], 0.0f);
    const __m128 scale = _mm_setr_ps(g.scale[0], g.scale[1], g.scale[2], 0.0f);
    const __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));  // drops the prim id's lane
    const __m128i last = _mm_set1_epi32(static_cast<int>(g.last));
    std::uint64_t mask[3] = {out.mask[0], out.mask[1], out.mask[2]};
    for (std::size_t i = b; i < e; ++i) {
      const PrimRef& r = src[i];
      const __m128 lo = _mm_and_ps(_mm_loadu_ps(r.lo), xyz);
      const __m128 hi = _mm_loadu_ps(r.hi);  // lane 3: pad = 0
      const __m128 f = _mm_max_ps(_mm_mul_ps(_mm_sub_ps(_mm_mul_ps(_mm_add_ps(lo, hi), half), origin), scale), zero);
      alignas(16) std::uint32_t ks[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(ks), _mm_min_epi16(_mm_cvttps_epi32(f), last));
      for (int a = 0; a < 3; ++a) {
        const unsigned kb = ks[a];
        Bin& bn = out.bin[a][kb];
        _mm_store_ps(bn.lo, _mm_min_ps(_mm_load_ps(bn.lo), lo));
        _mm_store_ps(bn.hi, _mm_max_ps(_mm_load_ps(bn.hi), hi));
        ++out.count[a][kb];
        mask[a] |= std::uint64_t(1) << kb;
      }
    }
    for (int a = 0; a < 3; ++a) out.mask[a] = mask[a];
#else
    for (std::size_t i = b; i < e; ++i) {
      const PrimRef& r = src[i];
      for (int a = 0; a < 3; ++a) {
        const unsigned k = g.bin(r, a);
        out.bin[a][k].grow(r.lo, r.hi);
        ++out.count[a][k];
        out.mask[a] |= std::uint64_t(1) << k;
      }
    }
#endif
  }

  // Partition of the node's records (bin < split on `axis` to the left) into the other array
  // (records()), left ones from the front, right ones from the back, without a branch per
  // record; also bounds each side's boxes and centroids. Returns the first right record.
  [[gnu::noinline]] std::uint32_t partition(const Geometry& g, int axis, unsigned split, const TmpNode& node,
                                            TmpNode (&c)[2]) {
    const PrimRef* src = records(node.depth);
    PrimRef* dst = records(node.depth + 1);
    std::uint32_t l = node.begin, r = node.end;
#if defined(__SSE2__)
    // f = (centroid - origin) * scale, Geometry::bin's operations on four lanes, and bin(f) <
    // split exactly when f < split: split is an integer in [1, last], so the clamps to 0 and to
    // the last bin and the truncation do not change the side. The four bounds of each side as
    // four-lane min/max (lane 3 unused).
    const __m128 half = _mm_set1_ps(0.5f);
    const __m128 origin = _mm_setr_ps(g.origin[0], g.origin[1], g.origin[2], 0.0f);
    const __m128 scale = _mm_setr_ps(g.scale[0], g.scale[1], g.scale[2], 0.0f);
    const __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
    const __m128 sp = _mm_set1_ps(static_cast<float>(split));
    const __m128 inf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
    __m128 acc[2][2] = {{inf, ninf}, {inf, ninf}};  // centroid lo, hi
    for (std::uint32_t i = node.begin; i < node.end; ++i) {
      const __m128 raw = _mm_loadu_ps(src[i].lo), hi = _mm_loadu_ps(src[i].hi);
      const __m128 lo = _mm_and_ps(raw, xyz);
      const __m128 ce = _mm_mul_ps(_mm_add_ps(lo, hi), half);
      const __m128 f = _mm_mul_ps(_mm_sub_ps(ce, origin), scale);
      const unsigned right = ~static_cast<unsigned>(_mm_movemask_ps(_mm_cmplt_ps(f, sp))) >> axis & 1u;
      const std::uint32_t at = right ? r - 1 : l;
      _mm_storeu_ps(dst[at].lo, raw);
      _mm_storeu_ps(dst[at].hi, hi);
      l += 1 - right;
      r -= right;
      __m128* a = acc[right];
      a[0] = _mm_min_ps(a[0], ce);
      a[1] = _mm_max_ps(a[1], ce);
    }
    for (int s = 0; s < 2; ++s) {
      alignas(16) float v[2][4];
      for (int q = 0; q < 2; ++q) _mm_store_ps(v[q], acc[s][q]);
      for (int a = 0; a < 3; ++a) {
        c[s].cbox.lo[a] = v[0][a];
        c[s].cbox.hi[a] = v[1][a];
      }
    }
#else
    for (std::uint32_t i = node.begin; i < node.end; ++i) {
      const PrimRef& p = src[i];
      const int s = g.left(p, axis, split) ? 0 : 1;
      dst[s ? --r : l++] = p;
      c[s].cbox.grow_centroid(p);
    }
#endif
    return l;
  }

  // Stable partition in chunks of kGrain: count and bound each chunk's sides, scatter into the
  // other array (records()) by the chunks' prefix sums; side boxes reduced in chunk order.
  std::uint32_t partition_chunked(const Geometry& g, int axis, unsigned split, const TmpNode& node, TmpNode (&c)[2],
                                  unsigned threads) {
    const std::uint32_t count = node.end - node.begin;
    const std::size_t chunks = (count + kGrain - 1) / kGrain;
    const PrimRef* src = records(node.depth);
    PrimRef* dst = records(node.depth + 1);
    std::vector<TmpNode> side(2 * chunks);
    std::vector<std::uint32_t> left(chunks);
    parallel_for(count, kGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      const std::size_t k = b / kGrain;
      std::uint32_t l = 0;
      for (std::size_t i = node.begin + b; i < node.begin + e; ++i) {
        const PrimRef& r = src[i];
        const int s = g.left(r, axis, split) ? 0 : 1;
        side[2 * k + s].cbox.grow_centroid(r);
        l += s == 0 ? 1 : 0;
      }
      left[k] = l;
    });
    std::vector<std::uint32_t> loff(chunks), roff(chunks);
    std::uint32_t total_left = 0;
    for (std::size_t k = 0; k < chunks; ++k) {
      loff[k] = total_left;
      total_left += left[k];
    }
    for (std::size_t k = 0; k < chunks; ++k) {
      roff[k] = total_left + static_cast<std::uint32_t>(k * kGrain) - loff[k];
      for (int s = 0; s < 2; ++s) c[s].cbox.grow(side[2 * k + static_cast<std::size_t>(s)].cbox);
    }
    parallel_for(count, kGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      const std::size_t k = b / kGrain;
      std::uint32_t l = node.begin + loff[k], r = node.begin + roff[k];
      for (std::size_t i = node.begin + b; i < node.begin + e; ++i) {
        const PrimRef& p = src[i];
        dst[g.left(p, axis, split) ? l++ : r++] = p;
      }
    });
    return node.begin + total_left;
  }

  const BuildOptions& opt_;
  RawVector<PrimRef>& prims_;
  RawVector<PrimRef> scratch_;  // the records of odd depths (disjoint ranges: safe across tasks)
  unsigned bins_;
};

// Emits arena nodes depth-first at fixed places of `out` (inner nodes from `node`, leaves from
// `leaf`), so that the subtrees can be emitted side by side once their places are known.
// `sub_ref`/`sub_height`: what each subtree's root became (the upper arena's last pass).
struct Flattener {
  const Arenas& a;
  Bvh2& out;
  std::vector<Leaf>& leaves;
  std::size_t node = 0, leaf = 0;
  std::size_t largest = 0, forced = 0;
  const std::vector<std::int32_t>* sub_ref = nullptr;
  const std::vector<std::uint32_t>* sub_height = nullptr;
  const std::vector<std::pair<std::size_t, std::size_t>>* sub_size = nullptr;  // inner nodes, leaves

  // Returns the child reference of arena node n.
  std::int32_t emit(const std::vector<TmpNode>& arena, std::size_t n, std::int32_t parent, std::uint32_t& height) {
    const TmpNode& t = arena[n];
    if (&arena == &a.upper && a.subtree_of[n] >= 0) {
      const std::size_t j = static_cast<std::size_t>(a.subtree_of[n]);
      node += (*sub_size)[j].first;
      leaf += (*sub_size)[j].second;
      height = (*sub_height)[j];
      return (*sub_ref)[j];
    }
    if (t.leaf) {
      leaves[leaf] = {t.begin, t.end - t.begin};
      out.leaf_boxes[leaf] = t.box.box();
      largest = std::max<std::size_t>(largest, t.end - t.begin);
      forced += t.forced ? 1 : 0;
      height = 0;
      return ~static_cast<std::int32_t>(leaf++);
    }
    const std::int32_t self = static_cast<std::int32_t>(node++);
    Bvh2::Node& d = out.nodes[static_cast<std::size_t>(self)];
    d = {t.box.box(), {MBVH_EMPTY, MBVH_EMPTY}, parent, 0};
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side)
      if (t.child[side] >= 0) d.child[side] = emit(arena, static_cast<std::size_t>(t.child[side]), self, h[side]);
    height = 1 + std::max(h[0], h[1]);
    d.height = height;
    return self;
  }

  // Where subtree j's nodes and leaves start and its root's parent, as the depth-first walk of
  // the upper arena reaches them (nothing written).
  void place(std::size_t n, std::int32_t parent, std::vector<std::pair<std::size_t, std::size_t>>& at,
             std::vector<std::int32_t>& parent_of) {
    const TmpNode& t = a.upper[n];
    if (a.subtree_of[n] >= 0) {
      const std::size_t j = static_cast<std::size_t>(a.subtree_of[n]);
      at[j] = {node, leaf};
      parent_of[j] = parent;
      node += (*sub_size)[j].first;
      leaf += (*sub_size)[j].second;
      return;
    }
    if (t.leaf) {
      ++leaf;
      return;
    }
    const std::int32_t self = static_cast<std::int32_t>(node++);
    for (int side = 0; side < 2; ++side)
      if (t.child[side] >= 0) place(static_cast<std::size_t>(t.child[side]), self, at, parent_of);
  }
};

}  // namespace

void flatten(const Arenas& a, Bvh2& out, std::vector<Leaf>& leaves, unsigned threads) {
  // -- each subtree's inner nodes and leaves, then their places in the depth-first order
  const std::size_t subs = a.subtrees.size();
  std::vector<std::pair<std::size_t, std::size_t>> size(subs), at(subs);
  parallel_for(subs, 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t j = b; j < e; ++j) {
      std::size_t inner = 0;
      for (const TmpNode& t : a.subtrees[j]) inner += t.leaf ? 0 : 1;
      size[j] = {inner, a.subtrees[j].size() - inner};
    }
  });
  std::vector<std::int32_t> parent_of(subs, MBVH_NONE), ref(subs, 0);
  std::vector<std::uint32_t> height(subs, 0);
  Flattener top{a, out, leaves};
  top.sub_size = &size;
  top.place(0, MBVH_NONE, at, parent_of);
  out.nodes.resize(top.node);
  out.leaf_boxes.resize(top.leaf);
  leaves.resize(top.leaf);
  // -- the subtrees side by side, then the upper nodes around them
  std::vector<std::size_t> largest(subs, 0), forced(subs, 0);
  parallel_for(subs, 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t j = b; j < e; ++j) {
      Flattener fl{a, out, leaves, at[j].first, at[j].second};
      ref[j] = fl.emit(a.subtrees[j], 0, parent_of[j], height[j]);
      largest[j] = fl.largest;
      forced[j] = fl.forced;
    }
  });
  top.node = top.leaf = 0;
  top.sub_ref = &ref;
  top.sub_height = &height;
  std::uint32_t h = 0;
  top.emit(a.upper, 0, MBVH_NONE, h);
  out.largest_leaf = top.largest;
  out.forced_leaves = top.forced;
  for (std::size_t j = 0; j < subs; ++j) {
    out.largest_leaf = std::max(out.largest_leaf, largest[j]);
    out.forced_leaves += forced[j];
  }
}

void build_binned_sah(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                      Arenas& out) {
  // -- top of the tree, breadth-first, large nodes binned and partitioned in parallel chunks
  SahBuilder builder(opt, prims);
  std::vector<TmpNode>& upper = out.upper;
  upper.assign(1, TmpNode());
  upper[0].box = root;
  upper[0].cbox = croot;
  upper[0].begin = 0;
  upper[0].end = static_cast<std::uint32_t>(prims.size());
  upper[0].depth = 0;
  const unsigned threads = resolve_threads(opt.threads);
  const std::size_t small = std::max<std::size_t>(4096, prims.size() / (8 * std::size_t(threads)));
  std::vector<std::size_t> jobs;
  Bins work;
  std::vector<std::unique_ptr<Bins>> worker_bins(threads);  // made by their worker on first use
  std::vector<std::size_t> batch;
  std::vector<TmpNode> kids;
  std::vector<std::uint8_t> split_done;
  for (std::size_t k = 0; k < upper.size();) {
    // one level at a time: small nodes become subtree jobs, large ones are split with their
    // chunks in parallel, the others are split side by side, one per worker; children are
    // appended in node order, so the arena does not depend on which worker split what
    const std::size_t level_end = upper.size();
    batch.clear();
    for (; k < level_end; ++k) {
      const std::size_t count = upper[k].end - upper[k].begin;
      if (k > 0 && count <= small) jobs.push_back(k);
      else if (k == 0 || count >= kParallelMin) builder.split(upper, k, threads, work);
      else batch.push_back(k);
    }
    kids.assign(2 * batch.size(), TmpNode());
    split_done.assign(batch.size(), 0);
    parallel_for(batch.size(), 1, threads, [&](std::size_t b, std::size_t e, unsigned worker) {
      for (std::size_t i = b; i < e; ++i) {
        TmpNode c[2];
        if (!worker_bins[worker]) worker_bins[worker] = std::make_unique<Bins>();
        split_done[i] = builder.split_node(upper[batch[i]], c, 1, *worker_bins[worker]);
        kids[2 * i] = c[0];
        kids[2 * i + 1] = c[1];
      }
    });
    for (std::size_t i = 0; i < batch.size(); ++i)
      if (split_done[i])
        for (int side = 0; side < 2; ++side) {
          upper[batch[i]].child[side] = static_cast<std::int32_t>(upper.size());
          upper.push_back(kids[2 * i + static_cast<std::size_t>(side)]);
        }
  }
  // -- remaining subtrees, one per task, largest first
  build_subtrees(out, jobs, opt, [&](std::vector<TmpNode>& subtree) {
    // a binary tree over n records has at most 2n - 1 nodes (leaves of one record are common
    // here): reserved address space, never a reallocation
    subtree.reserve(2 * std::size_t(subtree[0].end - subtree[0].begin));
    builder.build_subtree(subtree);
  });
}

}  // namespace build

namespace {

[[noreturn]] void throw_below_scene_scale(const Scene& scene, float largest) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                ": the largest coordinate magnitude is %.9g, below 2^-36 (%.3g), the smallest scene scale mbvh traces "
                "exactly (float products of three coordinates would underflow); rescale the scene",
                double(largest), double(kMinSceneScale));
  throw Error(scene.display_name() + buf);
}

// The scene's non-degenerate triangles must lie in the exactly traced range (accel.h): a
// coordinate beyond ±kMaxCoordinate is named with its triangle; a scene whose largest magnitude
// is below kMinSceneScale is refused as a whole. `largest`: the largest magnitude of the records.
void check_traceable_range(const Scene& scene, const build::RawVector<build::PrimRef>& prims, float largest) {
  if (largest > kMaxCoordinate) {
    for (const build::PrimRef& r : prims) {  // the first offending triangle, in scene order
      Vec3f p[3];
      scene.triangle(r.prim, p[0], p[1], p[2]);
      const GeomPrim g = scene.geometry_of(r.prim);
      const std::array<std::uint32_t, 3> index =
          scene.meshes().empty() ? scene.triangles[r.prim] : scene.meshes()[g.geom_id].triangle(g.prim_id);
      for (int k = 0; k < 3; ++k)
        for (float c : {p[k].x, p[k].y, p[k].z})
          if (std::fabs(c) > kMaxCoordinate) {
            char buf[320];
            const std::string where =
                scene.meshes().empty() ? "" : ", geometry " + std::to_string(g.geom_id) + " triangle " + std::to_string(g.prim_id);
            std::snprintf(buf, sizeof buf,
                          ": coordinate %.9g of vertex %u (triangle %u%s) is beyond +-2^40 (%.3g), the range mbvh traces "
                          "exactly (float products of three coordinates would overflow); rescale the scene",
                          double(c), index[k], r.prim, where.c_str(), double(kMaxCoordinate));
            throw Error(scene.display_name() + buf);
          }
    }
  }
  if (largest < kMinSceneScale) throw_below_scene_scale(scene, largest);
}

}  // namespace

namespace build {

void throw_too_small(const Scene& scene, std::uint32_t prim, const char* who) {
  Vec3f p[3];
  scene.triangle(prim, p[0], p[1], p[2]);
  double edge[3];
  for (int k = 0; k < 3; ++k) {
    const Vec3f& a = p[k];
    const Vec3f& b = p[(k + 1) % 3];
    const double d[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
    edge[k] = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  }
  std::string where;
  if (!scene.meshes().empty()) {
    const GeomPrim g = scene.geometry_of(prim);
    where = " (geometry " + std::to_string(g.geom_id) + " triangle " + std::to_string(g.prim_id) + ")";
  }
  char buf[512];
  std::snprintf(buf, sizeof buf,
                ": %striangle %u%s has area %.3g (edges %.3g, %.3g, %.3g), below 2^-110 (%.3g, accel.h "
                "kMinTriangleArea), the smallest triangle mbvh traces exactly (float products of its edges would "
                "underflow and rays pass through it); rescale the scene or remove the triangle",
                who, prim, where.c_str(), 0.5 * std::sqrt(twice_area_sq(p[0], p[1], p[2])), edge[0], edge[1], edge[2],
                double(kMinTriangleArea));
  throw Error(scene.display_name() + buf);
}

}  // namespace build

namespace {

// The leaf-ordered triangle records: tris[i] is the triangle `prim(order[i])` of the scene.
// `order` holds prim ids (SBVH) or the leaf-ordered records (binned SAH, LBVH).
std::uint32_t prim_of(std::uint32_t p) { return p; }
std::uint32_t prim_of(const build::PrimRef& r) { return r.prim; }

template <class Order>
void fill_tris(const Scene& scene, const Order& order, AlignedVector<Tri>& tris, unsigned threads) {
  constexpr std::size_t grain = 65536;
  build::with_triangles(scene, [&](const auto& src) {
    parallel_for(order.size(), grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      constexpr std::size_t ahead = 16;  // triangles: vertices fetched this far ahead, indices twice as far
      for (std::size_t i = b; i < e; ++i) {
        if (i + 2 * ahead < e) src.prefetch_index(prim_of(order[i + 2 * ahead]));
        if (i + ahead < e) src.prefetch_vertices(prim_of(order[i + ahead]));
        const std::uint32_t prim = prim_of(order[i]);
        Vec3f v0, v1, v2;
        src.get(prim, v0, v1, v2);
        build::fill_tri(tris[i], v0, v1, v2, prim);
      }
    });
  });
}

}  // namespace

namespace build {

std::uint64_t hash_build(const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned threads,
                         const std::uint64_t* tri_hashes) {
  struct Block {
    const unsigned char* p;
    std::size_t n;
  };
  std::vector<Block> blocks;
  auto add = [&](const void* p, std::size_t n) {
    const unsigned char* c = static_cast<const unsigned char*>(p);
    for (std::size_t o = 0; o < n; o += kHashBlock) blocks.push_back({c + o, std::min(kHashBlock, n - o)});
  };
  add(b.nodes.data(), b.nodes.size() * sizeof(Bvh2::Node));
  add(leaves.data(), leaves.size() * sizeof(Leaf));
  const std::size_t given = tri_hashes ? blocks.size() : std::size_t(-1);  // the triangles' blocks from here
  add(tris.data(), tris.size() * sizeof(Tri));
  std::vector<std::uint64_t> h(blocks.size());
  parallel_for(std::min(given, blocks.size()), 4, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t i = lo; i < hi; ++i) h[i] = hash_bytes(blocks[i].p, blocks[i].n);
  });
  for (std::size_t i = given; i < blocks.size(); ++i) h[i] = tri_hashes[i - given];
  return hash_bytes(h.data(), h.size() * sizeof(std::uint64_t));
}

double sah_of_binary(const Bvh2& b, const std::vector<Leaf>& leaves, float ct) {
  const double root = b.nodes[0].box.half_area();
  if (!(root > 0)) return 0;
  double cost = 0;
  for (const auto& n : b.nodes) cost += ct * n.box.half_area() / root;
  for (std::size_t i = 0; i < leaves.size(); ++i) cost += double(leaves[i].count) * b.leaf_boxes[i].half_area() / root;
  return cost;
}

}  // namespace build

std::unique_ptr<Accel> Accel::build(const Scene& scene, const BuildOptions& opt_in) try {
  using build::PrimRef;
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  // -- what the build is given: indices in range and finite vertices (checked by the record
  //    pass below, Scene::validate naming the first fault), a usable SAH cost
  check_enum(opt_in.quality, "Accel::build: " + scene.display_name(), "BuildOptions::quality");
  if (!scene.meshes().empty() && !scene.triangles.empty()) scene.validate();
  if (!std::isfinite(opt_in.traversal_cost) || opt_in.traversal_cost < 0)
    throw Error("BuildOptions::traversal_cost " + std::to_string(opt_in.traversal_cost) + " must be finite and >= 0");
  std::unique_ptr<Accel> acc(new Accel());
  acc->impl_->opt_ = opt_in;
  BuildOptions& opt = acc->impl_->opt_;
  opt.depth_cap = std::clamp(opt.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP));
  opt.max_leaf = std::max(opt.max_leaf, 1u);
  acc->impl_->scene_triangles_ = scene.triangle_count();
  acc->impl_->geometry_offsets_.resize(scene.geometry_count() + 1);
  for (std::size_t g = 0; g <= scene.geometry_count(); ++g) acc->impl_->geometry_offsets_[g] = scene.geometry_offset(g);
  auto report = [&opt](double f) {
    if (opt.progress) opt.progress(f);
  };

  // -- one record per non-degenerate (non-zero area) triangle, in scene order: chunks count
  //    their kept triangles, then write them at their prefix offsets with the chunk's bounds;
  //    compiled once for the owned arrays and once for mesh views (triangles.h)
  const std::size_t n = scene.triangle_count();
  if (n > kMaxTriangles) throw Error(scene.display_name() + ": too many triangles for 32-bit references");
  constexpr std::size_t grain = 65536;
  const std::size_t chunks = (n + grain - 1) / grain;
  std::vector<std::size_t> kept_in(chunks, 0);
  build::RawVector<PrimRef> prims(n);
  std::vector<build::FastBox> cb(chunks), ccb(chunks);
  std::vector<float> mag(chunks, 0.0f);
  std::vector<float> tiny_mag(chunks, 0.0f);  // per chunk: the largest magnitude of its too-small triangles
  std::vector<std::size_t> tiny(chunks, SIZE_MAX);  // per chunk: its first triangle too small to trace
  std::atomic<bool> invalid{false};
  build::with_triangles(scene, [&](const auto& src) {
    parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      const std::size_t c = b / grain;
      std::size_t o = b;
      build::FastBox box, cbox;
      for (std::size_t i = b; i < e; ++i) {
        Vec3f v0, v1, v2;
        if (!src.get_checked(i, v0, v1, v2) || !build::finite(v0, v1, v2)) {
          invalid = true;
          continue;
        }
        const double a2 = build::twice_area_sq(v0, v1, v2);
        if (a2 == 0) continue;  // degenerate: in no leaf
        if (build::too_small(a2)) {  // refused below, the first in scene order named
          tiny[c] = std::min(tiny[c], i);
          for (const Vec3f& v : {v0, v1, v2})
            tiny_mag[c] = std::max({tiny_mag[c], std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)});
          continue;
        }
        const PrimRef r = build::prim_ref(v0, v1, v2, static_cast<std::uint32_t>(i));
        box.grow(r);
        cbox.grow_centroid(r);
        prims[o++] = r;
      }
      float m = 0;  // the largest magnitude of the records: on each axis, their least lo or greatest hi
      if (o > b)
        for (int a = 0; a < 3; ++a) m = std::max({m, std::fabs(box.lo[a]), std::fabs(box.hi[a])});
      kept_in[c] = o - b;
      cb[c] = box;
      ccb[c] = cbox;
      mag[c] = m;
    });
  });
  if (invalid) {
    scene.validate();  // throws, naming the first bad triangle
    throw Error(scene.display_name() + ": internal: a triangle failed the build's index or finiteness check but not Scene::validate");
  }
  if (const std::size_t first = chunks ? *std::min_element(tiny.begin(), tiny.end()) : SIZE_MAX; first != SIZE_MAX) {
    // a scene too small as a whole is named as such before any of its triangles
    float all = 0;
    for (std::size_t c = 0; c < chunks; ++c) all = std::max({all, mag[c], tiny_mag[c]});
    if (all < kMinSceneScale) throw_below_scene_scale(scene, all);
    build::throw_too_small(scene, static_cast<std::uint32_t>(first), "");
  }
  std::size_t kept = 0;  // close the chunks' gaps (in place: a record only moves down)
  for (std::size_t c = 0; c < chunks; ++c) {
    if (kept != c * grain) std::memmove(&prims[kept], &prims[c * grain], kept_in[c] * sizeof(PrimRef));
    kept += kept_in[c];
  }
  prims.resize(kept);
  acc->impl_->bvh2_.degenerate = n - kept;
  if (kept == 0)
    throw Error(scene.display_name() + ": the scene has no non-degenerate triangle (" + std::to_string(n) + " triangles, " +
                std::to_string(acc->impl_->bvh2_.degenerate) + " degenerate)");
  build::FastBox root, croot;
  float largest = 0;
  for (std::size_t c = 0; c < chunks; ++c) {
    root.grow(cb[c]);
    croot.grow(ccb[c]);
    largest = std::max(largest, mag[c]);
  }
  check_traceable_range(scene, prims, largest);
  const auto t_prep = Clock::now();
  report(0.05);

  Bvh2& out = acc->impl_->bvh2_;
  auto t_tree = Clock::now();
  if (opt.quality == BuildQuality::high) {
    // -- spatial splits (sbvh.cpp): a triangle may sit in several leaves (never twice in one)
    std::vector<Box> boxes(n);
    std::vector<std::uint32_t> idx(prims.size());
    for (std::size_t i = 0; i < prims.size(); ++i) {
      const PrimRef& r = prims[i];
      idx[i] = r.prim;
      boxes[r.prim].lo = {r.lo[0], r.lo[1], r.lo[2]};
      boxes[r.prim].hi = {r.hi[0], r.hi[1], r.hi[2]};
    }
    SbvhResult r = build_sbvh(scene, opt, boxes, idx);
    t_tree = Clock::now();
    r.bvh.degenerate = out.degenerate;
    out = std::move(r.bvh);
    acc->impl_->leaves_ = std::move(r.leaves);
    acc->impl_->tris_.resize(r.prims.size());
    fill_tris(scene, r.prims, acc->impl_->tris_, opt.threads);
  } else {
    // -- the binary tree
    build::Arenas arenas;
    if (opt.quality == BuildQuality::low) build::build_lbvh(prims, root, croot, opt, arenas);
    else build::build_binned_sah(prims, root, croot, opt, arenas);
    t_tree = Clock::now();

    // -- flatten depth-first; leaves come out in record order
    build::flatten(arenas, out, acc->impl_->leaves_, opt.threads);

    arenas = build::Arenas();
    acc->impl_->tris_.resize(prims.size());
    fill_tris(scene, prims, acc->impl_->tris_, opt.threads);
  }
  acc->impl_->bounds_ = out.nodes[0].box;
  const auto t_flat = Clock::now();

  // -- statistics (the hash is made on first use: Accel::hash)
  LayoutStats& st = acc->impl_->binary_stats_;
  st.layout = "binary";
  st.nodes = out.nodes.size();
  st.leaves = acc->impl_->leaves_.size();
  st.depth = out.nodes[0].height;
  st.sah_cost = build::sah_of_binary(out, acc->impl_->leaves_, opt.traversal_cost);
  st.bytes = out.nodes.size() * sizeof(Bvh2::Node) + acc->impl_->leaves_.size() * (sizeof(Leaf) + sizeof(Box)) +
             acc->impl_->tris_.size() * sizeof(Tri);
  st.bitstack_bits = st.depth;
  if (st.depth > opt.depth_cap) throw Error("internal: binary depth " + std::to_string(st.depth) + " exceeds the cap");
  const auto t1 = Clock::now();
  auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  st.build_ms = ms(t0, t1);
  st.phase_ms[0] = ms(t0, t_prep);
  st.phase_ms[1] = ms(t_prep, t_tree);
  st.phase_ms[2] = ms(t_tree, t_flat);
  st.phase_ms[3] = ms(t_flat, t1);
  report(1.0);
  return acc;
} catch (const std::bad_alloc&) {  // the build's arrays, beyond the scene: named, not a bare std::bad_alloc
  throw_out_of_memory(scene.display_name() + ": the BVH build of its " +
                          std::to_string(scene.triangle_count()) + " triangles",
                      build_memory_estimate(scene.triangle_count(), scene.vertices.size()));
}

Accel::Accel() : impl_(std::make_unique<Impl>()) {}
Accel::~Accel() = default;
const Bvh2& Accel::bvh2() const { return impl_->bvh2_; }
const AlignedVector<Tri>& Accel::tris() const { return impl_->tris_; }
const std::vector<Leaf>& Accel::leaves() const { return impl_->leaves_; }
const Box& Accel::bounds() const { return impl_->bounds_; }
std::size_t Accel::scene_triangles() const { return impl_->scene_triangles_; }
std::size_t Accel::geometry_count() const { return impl_->geometry_offsets_.size() - 1; }

GeomPrim Accel::geometry_of(std::uint32_t prim) const {
  const std::vector<std::uint64_t>& o = impl_->geometry_offsets_;
  if (prim >= o.back()) return {};
  const std::size_t g = geometry_index(o.data(), o.size() - 1, prim);
  return {static_cast<std::uint32_t>(g), static_cast<std::uint32_t>(prim - o[g])};
}
const LayoutStats& Accel::binary_stats() const { return impl_->binary_stats_; }
const BuildOptions& Accel::options() const { return impl_->opt_; }
std::uint64_t Accel::hash() const {
  if (!impl_->hash_known_.load(std::memory_order_acquire)) {
    std::lock_guard<std::mutex> lock(impl_->hash_m_);
    if (!impl_->hash_known_.load(std::memory_order_relaxed)) {
      impl_->hash_ = build::hash_build(impl_->bvh2_, impl_->leaves_, impl_->tris_, impl_->opt_.threads);
      impl_->hash_known_.store(true, std::memory_order_release);
    }
  }
  return impl_->hash_;
}
std::uint64_t Accel::generation() const { return impl_->generation_; }
double Accel::last_refit_ms() const { return impl_->refit_ms_; }

const Mbvh2& Accel::mbvh2() const {
  std::call_once(impl_->once2_, [this] { impl_->mbvh2_ = make_mbvh2(impl_->bvh2_, impl_->leaves_); });
  return impl_->mbvh2_;
}

void Accel::make_layout(Layout l) const {
  check_enum(l, "Accel::make_layout", "the layout");
  if (l == Layout::mbvh2) mbvh2();
  else if (l == Layout::mbvh4) mbvh4();
  else mbvh8();
}

const Mbvh8& Accel::mbvh8() const {
  std::call_once(impl_->once8_, [this] { impl_->mbvh8_ = make_mbvh8(impl_->bvh2_, impl_->leaves_, impl_->opt_.threads); });
  return impl_->mbvh8_;
}

const Mbvh4& Accel::mbvh4() const {
  std::call_once(impl_->once4_, [this] { impl_->mbvh4_ = make_mbvh4(impl_->bvh2_, impl_->leaves_, impl_->opt_.threads); });
  return impl_->mbvh4_;
}

const TriPacks& Accel::tri_packs() const {
  std::call_once(impl_->oncep_, [this] { impl_->packs_ = make_tri_packs(impl_->tris_, impl_->leaves_); });
  return impl_->packs_;
}

const Mbvh4Wide& Accel::mbvh4_wide() const {
  std::call_once(impl_->once4w_, [this] { impl_->mbvh4w_ = make_mbvh4_wide(mbvh4()); });
  return impl_->mbvh4w_;
}

}  // namespace mbvh

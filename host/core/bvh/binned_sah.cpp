// SPDX-License-Identifier: MIT
// binned_sah.cpp — the binned-SAH builder (BuildQuality::medium): a binary BVH over the build's
// records (Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies", 2007), with the
// binary depth capped so that every path fits the 64-bit bitstack (TRAVERSAL.md §3.5); and
// flatten, which turns its arenas and the LBVH's into the Bvh2.
//
// Parallel and deterministic: the root (and the largest nodes, while there are fewer open nodes
// than workers) is split with its binning and partition in chunks spread over the workers (box
// unions and counts are exact, and chunks are reduced in order); then every worker takes the
// largest open node from a shared heap, splits it (its children go back in the heap) or, at
// most `small` records, builds its whole subtree, with no barrier between levels. Every split
// decision is the same function of the same inputs whoever makes it, and flatten follows the
// child links, so the bytes do not depend on the thread count or on the timing.
#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <condition_variable>
#include <memory>
#include <mutex>
#include <type_traits>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "host/core/bvh/avx2_kernels.h"
#include "host/core/bvh/builder.h"
#include "host/core/bvh/dense_bins.h"
#include "host/core/bvh/flat_writer.h"
#include "host/core/huge_pages.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"

namespace mbvh {

namespace build {
namespace {

std::atomic<SahKernels> g_kernels{SahKernels::best};

#if defined(MBVH_BUILD_AVX2)
// Whether the per-record loops run avx2_kernels.h's: the CPU has AVX2, and no test asked for SSE2.
bool use_vec256() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has && g_kernels.load(std::memory_order_relaxed) == SahKernels::best;
}
vec256::Split vec256_split(const float origin[3], const float scale[3], unsigned split) {
  return {{origin[0], origin[1], origin[2]}, {scale[0], scale[1], scale[2]}, split};
}
#endif

constexpr unsigned kMaxBins = 64;
// Nodes of at least kParallelMin records are binned and partitioned in chunks of kGrain records
// (in parallel where threads are free), reduced in chunk order; smaller ones in one pass. Which
// path a node takes depends only on its size, so the bytes do not depend on the thread count.
constexpr std::uint32_t kParallelMin = 65536;
constexpr std::size_t kGrain = 16384;
// Nodes of at least kDenseMin records are binned in dense bins (dense_bins.h), smaller ones in
// sparse bins; both choose the same split (a node box may differ in the sign of a zero bound:
// min(+0, -0) keeps the operand order, which differs, so a tree's bytes may change with the
// threshold while its splits do not). Below 64 records sparse bins take fewer instructions.
constexpr std::uint32_t kDenseMin = 64;
#if defined(__SSE2__)  // dense bins are SSE rows: elsewhere (aarch64) every node takes sparse bins
static_assert(DenseBins::kMax == kMaxBins);
#endif

// Calls fn(b, e) for the kGrain chunks of [0, count) on up to `threads` workers, each of which
// first takes a contiguous run of chunks, in order, and then, its run done, takes chunks from
// the ends of the others' runs: the passes over one node (binning, the partition's count and
// scatter) and over its children then find most of their records in the cache of the core that
// last touched them, where chunks claimed one at a time alternate between cores and every pass
// moves the lines across; the taking from the ends keeps the workers busy to the end (a run is
// a whole number of chunks, and a woken worker starts later than the caller). fn sees the same
// chunks whoever runs them, so the results do not depend on it.
template <class Fn>
void for_chunks(std::size_t count, unsigned threads, Fn&& fn) {
  const std::size_t chunks = (count + kGrain - 1) / kGrain;
  const std::size_t runs = std::min<std::size_t>(resolve_threads(threads), chunks);
  auto chunk = [&](std::size_t c) { fn(c * kGrain, std::min(count, (c + 1) * kGrain)); };
  if (runs <= 1) {
    for (std::size_t c = 0; c < chunks; ++c) chunk(c);
    return;
  }
  // run r's chunks not yet taken: [next, end) packed as next << 32 | end, taken from the front by
  // its worker and from the back by the others
  std::vector<std::atomic<std::uint64_t>> left(runs);
  for (std::size_t r = 0; r < runs; ++r)
    left[r] = std::uint64_t(r * chunks / runs) << 32 | std::uint64_t((r + 1) * chunks / runs);
  auto take = [&](std::size_t r, bool front, std::size_t& c) {
    std::uint64_t v = left[r].load(std::memory_order_relaxed);
    for (;;) {
      const std::uint64_t next = v >> 32, end = v & 0xffffffffu;
      if (next >= end) return false;
      const std::uint64_t to = front ? (next + 1) << 32 | end : next << 32 | (end - 1);
      if (left[r].compare_exchange_weak(v, to, std::memory_order_relaxed)) {
        c = static_cast<std::size_t>(front ? next : end - 1);
        return true;
      }
    }
  };
  parallel_for(runs, 1, threads, [&](std::size_t rb, std::size_t re, unsigned) {
    for (std::size_t run = rb; run < re; ++run) {
      std::size_t c;
      while (take(run, true, c)) chunk(c);
      for (std::size_t o = 1; o < runs; ++o)
        while (take((run + o) % runs, false, c)) chunk(c);
    }
  });
}

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
// between nodes (the sweep, or reset(), empties only the bins `mask` marks occupied), so binning a record
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
  // `scratch`: room for prims.size() records the partitions may use, or null (then an array of
  // its own, or the context's).
  SahBuilder(const BuildOptions& opt, RawVector<PrimRef>& prims, PrimRef* scratch)
      : opt_(opt), prims_(prims), bins_(std::clamp(opt.bins, 2u, kMaxBins)) {
    if (!scratch) {
      scratch_ = take_from(opt, &BuildContext_Store::scratch);
      scratch_.resize(prims.size());
      scratch = scratch_.data();
    }
    odd_ = scratch;
  }
  ~SahBuilder() { give_back(opt_, &BuildContext_Store::scratch, scratch_); }
  SahBuilder(const SahBuilder&) = delete;
  SahBuilder& operator=(const SahBuilder&) = delete;

  // Splits node n (in `arena`) into two children appended to `arena`, or marks it a leaf.
  // `threads`: workers for a large node's chunks (1 inside a subtree task).
  // `work`: the task's sparse bins.
  // `cbox`: the centroid bounds of node n; the children's into `cc` (when split).
  bool split(std::vector<TmpNode>& arena, std::size_t n, const FastBox& cbox, FastBox (&cc)[2], unsigned threads, Bins& work) {
    TmpNode c[2];
    if (!split_node(arena[n], cbox, c, cc, threads, work)) return false;
    for (int side = 0; side < 2; ++side) {
      arena[n].child[side] = static_cast<std::int32_t>(arena.size());
      arena.push_back(c[side]);
    }
    return true;
  }

  // Splits `t` into the children c (their ranges, depths, boxes) and returns true, or marks `t`
  // a leaf and returns false. Touches only t's records: nodes of disjoint ranges may be split
  // at the same time.
  // `cbox`: the bounds of t's centroids; the children's into `cc`.
  bool split_node(TmpNode& t, const FastBox& cbox, TmpNode (&c)[2], FastBox (&cc)[2], unsigned threads, Bins& work) {
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
    // -- bin centroids along the three axes: bin = floor((c - lo) * bins / extent), as floats,
    //    with fewer bins at small nodes (bins_for)
    const unsigned nb = bins_for(count);
    Geometry g;
    for (int a = 0; a < 3; ++a) {
      const float ext = cbox.hi[a] - cbox.lo[a];
      g.origin[a] = cbox.lo[a];
      g.scale[a] = ext > 0 ? static_cast<float>(nb) / ext : 0.0f;
    }
    g.last = nb - 1;
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
        cc[i < mid ? 0 : 1].grow_centroid(src[i]);
        dst[i] = src[i];
      }
    } else {
      if (count <= opt_.max_leaf && leaf_cost <= split_cost) {
        make_leaf(t, false);
        return false;
      }
      mid = count >= kParallelMin ? partition_chunked(g, best_axis, best_split, node, cc, threads)
                                  : partition(g, best_axis, best_split, node, cc);
    }
    // -- children
    for (int side = 0; side < 2; ++side) {
      c[side].begin = side == 0 ? node.begin : mid;
      c[side].end = side == 0 ? mid : node.end;
      c[side].depth = node.depth + 1;
    }
    return true;
  }

  // The bins of a node of `count` records: 4 + count / 20, at most the options' (Embree's rule,
  // BinMapping: min(BINS, 4 + 0.05 N)). A small node's records fill few of 32 bins, and the
  // sweep's and the bins' set-up cost per bin outweighs the binning of its records; with fewer
  // bins the choice is almost always the same split (Wald 2007 finds 8 to 16 bins within a few
  // per cent of a full sweep). A function of the count only, so the tree does not depend on
  // the thread count.
  unsigned bins_for(std::uint32_t count) const { return std::min<unsigned>(bins_, 4u + count / 20u); }

  float blocks(std::uint32_t n) const {
    return opt_.leaf_block <= 1 ? static_cast<float>(n) : build::blocks(n, opt_.leaf_block);
  }

  // Builds the subtree of upper node `top` (centroid bounds `cbox`) into `arena`, depth first,
  // its root at arena node 0: the nodes still to split are kept on the stack with their ranges,
  // depths and centroid bounds, and each is written to the arena once, when split (an inner
  // node and its two children's places, next to each other) or made a leaf. The arena's order is
  // not the tree's: flatten follows the child links.
  void build_subtree(SubArena& arena, const TmpNode& top, const FastBox& cbox) {
    Bins work;
    struct Pending {
      TmpNode t;
      std::size_t at;  // its place in the arena
      FastBox cbox;
    };
    std::vector<Pending> stack;
    stack.reserve(2 * std::size_t(opt_.depth_cap) + 2);
    stack.push_back({top, arena.add(1), cbox});
    while (!stack.empty()) {
      Pending p = stack.back();
      stack.pop_back();
      TmpNode c[2];
      FastBox cc[2];
      if (!split_node(p.t, p.cbox, c, cc, 1, work)) {
        arena[p.at] = SubNode::leaf(p.t.box, p.t.begin, p.t.end - p.t.begin, p.t.forced);
        continue;
      }
      const std::size_t first = arena.add(2);
      arena[p.at] = SubNode::inner(p.t.box, first);
      for (int side = 1; side >= 0; --side) stack.push_back({c[side], first + std::size_t(side), cc[side]});
    }
  }

private:
  // The records of a node at `depth`: partitions move them from one array to the other, so a
  // node at an even depth finds its records in prims_, one at an odd depth in scratch_.
  PrimRef* records(std::uint32_t depth) { return depth & 1 ? odd_ : prims_.data(); }
  const PrimRef* records(std::uint32_t depth) const { return depth & 1 ? odd_ : prims_.data(); }

  // Makes `t` a leaf, its records moved to prims_ (the leaf order the caller reads).
  void make_leaf(TmpNode& t, bool forced) {
    t.leaf = true;
    t.forced = forced;
    if (t.depth & 1) std::copy(odd_ + t.begin, odd_ + t.end, prims_.begin() + t.begin);
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
      for_chunks(count, threads, [&](std::size_t b, std::size_t e) {
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
    // the plain count or blocks of records, chosen once (not per bin: best_* may alias opt_ as
    // far as the compiler knows, so a call in the loop reloads and tests opt_.leaf_block)
    if (opt_.leaf_block <= 1)
      sweep_axes(g, count, bins, best_cost, best_axis, best_split,
                 [](std::uint32_t n) { return static_cast<float>(n); });
    else
      sweep_axes(g, count, bins, best_cost, best_axis, best_split,
                 [b = opt_.leaf_block](std::uint32_t n) { return build::blocks(n, b); });
  }

  // sparse_sweep's sweep over the occupied bins of each axis, `cost_of(n)` the cost of n
  // records (blocks()); empties every bin it reads (Bins::reset's work, without a pass of its own).
  template <class CostOf>
  static void sweep_axes(const Geometry& g, std::uint32_t count, Bins& bins, float& best_cost_out, int& best_axis_out,
                         unsigned& best_split_out, CostOf cost_of) {
    // the best so far in locals: a store through a float& could alias the bins' floats
    float best_cost = best_cost_out;
    int best_axis = best_axis_out;
    unsigned best_split = best_split_out;
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
      const std::uint64_t mask = bins.mask[a];
      bins.mask[a] = 0;
      if (g.scale[a] == 0.0f) {
        for (std::uint64_t m = mask; m; m &= m - 1) bins.empty(a, static_cast<unsigned>(std::countr_zero(m)));
        continue;
      }
      float right_area[kMaxBins];
      Acc acc;
      // occupied bins from the top, all but the lowest (never the first bin right of a split):
      // bounds of bins >= k; the records right of a split are the node's less those left of it
      for (std::uint64_t m = mask; m & (m - 1);) {
        const unsigned k = 63u - static_cast<unsigned>(std::countl_zero(m));
        m &= ~(std::uint64_t(1) << k);
        acc.grow(bins.bin[a][k]);
        right_area[k] = acc.half_area();
      }
      acc = Acc();
      std::uint32_t cnt = 0;
      for (std::uint64_t m = mask; m;) {
        const unsigned k = static_cast<unsigned>(std::countr_zero(m));
        m &= m - 1;
        if (m == 0) {  // the last occupied bin: nothing to its right
          bins.empty(a, k);
          break;
        }
        acc.grow(bins.bin[a][k]);
        cnt += bins.count[a][k];
        bins.empty(a, k);
        const unsigned next = static_cast<unsigned>(std::countr_zero(m));
        const float cost = acc.half_area() * cost_of(cnt) + right_area[next] * cost_of(count - cnt);
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_split = k + 1;
        }
      }
    }
    best_cost_out = best_cost;
    best_axis_out = best_axis;
    best_split_out = best_split;
  }

#if defined(__SSE2__)
  // Dense bins (dense_bins.h) for nodes of at least kDenseMin records: the same choice as
  // sparse_sweep, in fewer operations per record and per bin.
  void dense_sweep(const Geometry& g, const TmpNode& node, unsigned threads, FastBox& box, float& best_cost,
                   int& best_axis, unsigned& best_split) const {
    const std::uint32_t count = node.end - node.begin;
    DenseBins bins;
    const unsigned nb = g.last + 1;
    bins.clear(nb);
    if (count >= kParallelMin) {
      const std::size_t chunks = (count + kGrain - 1) / kGrain;
      std::vector<DenseBins> partial(chunks);
      for_chunks(count, threads, [&](std::size_t b, std::size_t e) {
        DenseBins& p = partial[b / kGrain];
        p.clear(nb);
        bin_parts(p, records(node.depth), node.begin + b, node.begin + e, g);
      });
      for (std::size_t c = 0; c < chunks; ++c) bins.merge(partial[c], nb);
    } else {
      bin_parts(bins, records(node.depth), node.begin, node.end, g);
    }
    bins.bounds(nb, box);
    bins.best_split(nb, best_cost, best_axis, best_split);
  }

  // Bins records [b, e) into `out` (cleared) in two contiguous parts (DenseBins::bin_parts: the
  // bits of binning them in order).
  void bin_parts(DenseBins& out, const PrimRef* src, std::size_t b, std::size_t e, const Geometry& g) const {
    DenseBins more;
    more.clear(g.last + 1);
#if defined(MBVH_BUILD_AVX2)
    if (use_vec256()) {  // DenseBins::bin_parts<2>'s steps on AVX2, then its remainder and merge
      const std::size_t n = (e - b) / 2;
      vec256::bin_pairs(vec256_split(g.origin, g.scale, 0), g.last, out, more, src, b, n);
      if (b + 2 * n < e) more.bin(src, b + 2 * n, e, g.origin, g.scale, g.last);
      out.merge(more, g.last + 1);
      return;
    }
#endif
    DenseBins* const set[2] = {&out, &more};
    DenseBins::bin_parts<2>(set, src, b, e, g.origin, g.scale, g.last, g.last + 1);
  }
#endif

  // Out of line (as partition()), so that profiles show binning and partitioning apart.
  [[gnu::noinline]] void bin_range(const Geometry& g, const PrimRef* src, std::size_t b, std::size_t e,
                                   Bins& out) const {
#if defined(__SSE2__)
    // Four lanes at once: the centroid, its bin on each axis (the dense bins' index, the same
    // float operations as Geometry::bin, so the same bins) and the bin's box as one min and one max.
    const DenseBins::Binning bg(g.origin, g.scale, g.last);
    std::uint64_t mask[3] = {out.mask[0], out.mask[1], out.mask[2]};
    for (std::size_t i = b; i < e; ++i) {
      __m128 lo, hi;  // hi's lane 3: pad = 0
      bg.load(src[i], lo, hi);
      alignas(16) std::uint32_t ks[4];
      _mm_store_si128(reinterpret_cast<__m128i*>(ks), bg.index(lo, hi));
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

#if defined(__SSE2__)
  // The partitions' test on four lanes: f = (centroid - origin) * scale, Geometry::bin's
  // operations, and bin(f) < split exactly when f < split (split is an integer in [1, last], so
  // the clamps to 0 and to the last bin and the truncation do not change the side).
  struct SideTest {
    __m128 half = _mm_set1_ps(0.5f), xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0)), origin, scale, sp;
    SideTest(const Geometry& g, unsigned split)
        : origin(_mm_setr_ps(g.origin[0], g.origin[1], g.origin[2], 0.0f)),
          scale(_mm_setr_ps(g.scale[0], g.scale[1], g.scale[2], 0.0f)), sp(_mm_set1_ps(static_cast<float>(split))) {}
    __m128 centroid(__m128 lo, __m128 hi) const { return _mm_mul_ps(_mm_add_ps(_mm_and_ps(lo, xyz), hi), half); }
    __m128 centroid(const PrimRef& r) const { return centroid(_mm_loadu_ps(r.lo), _mm_loadu_ps(r.hi)); }
    // lanes set where the centroid is left of the split, on each axis
    __m128 left(__m128 ce) const { return _mm_cmplt_ps(_mm_mul_ps(_mm_sub_ps(ce, origin), scale), sp); }
  };

  // Each side's centroid bounds in registers (lane 3 unused), grown without a branch per record:
  // `side` is -inf on every lane for a record that goes left, +inf for one that goes right, `other`
  // its negation, so max(ce, side) is ce on the left and +inf on the right, whose min with the
  // left's lower bound leaves it as it was, and so on for the other three bounds. The operations
  // are FastBox::grow_centroid's (std::min(lo, c) is _mm_min_ps(c, lo), bit for bit, signed zeros
  // included).
  struct SideBounds {
    __m128 inf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY), sign = _mm_set1_ps(-0.0f);
    __m128 acc[2][2] = {{inf, ninf}, {inf, ninf}};  // side, lo / hi
    // ce's record goes left where lt's lane A is set
    template <int A>
    void grow(__m128 ce, __m128 lt) {
      const __m128 left = _mm_shuffle_ps(lt, lt, _MM_SHUFFLE(A, A, A, A));  // all set: left
      const __m128 side = _mm_xor_ps(inf, _mm_and_ps(left, sign));
      const __m128 other = _mm_xor_ps(side, sign);
      acc[0][0] = _mm_min_ps(_mm_max_ps(ce, side), acc[0][0]);
      acc[0][1] = _mm_max_ps(_mm_min_ps(ce, other), acc[0][1]);
      acc[1][0] = _mm_min_ps(_mm_max_ps(ce, other), acc[1][0]);
      acc[1][1] = _mm_max_ps(_mm_min_ps(ce, side), acc[1][1]);
    }
    void store(FastBox (&box)[2]) const {
      for (int s = 0; s < 2; ++s) set_rows(box[s], acc[s][0], acc[s][1]);
    }
  };
#endif

  // Partition of the node's records (bin < split on `axis` to the left) into the other array
  // (records()), left ones from the front, right ones from the back, without a branch per
  // record; also bounds each side's boxes and centroids. Returns the first right record.
  [[gnu::noinline]] std::uint32_t partition(const Geometry& g, int axis, unsigned split, const TmpNode& node,
                                            FastBox (&c)[2]) {
    const PrimRef* src = records(node.depth);
    PrimRef* dst = records(node.depth + 1);
    std::uint32_t l = node.begin, r = node.end;
#if defined(MBVH_BUILD_AVX2)
    if (use_vec256()) return vec256::partition(vec256_split(g.origin, g.scale, split), axis, src, l, r, dst, c);
#endif
#if defined(__SSE2__)
    const SideTest st(g, split);
    SideBounds sides;
    auto loop = [&](auto axis_c) {
      constexpr int A = decltype(axis_c)::value;
      const std::uint32_t end = node.end;
      for (std::uint32_t i = node.begin; i < end; ++i) {
        const __m128 lo = _mm_loadu_ps(src[i].lo), hi = _mm_loadu_ps(src[i].hi);
        const __m128 ce = st.centroid(lo, hi);
        const __m128 lt = st.left(ce);
        const unsigned right = ~static_cast<unsigned>(_mm_movemask_ps(lt)) >> A & 1u;
        const std::uint32_t at = right ? r - 1 : l;
        _mm_storeu_ps(dst[at].lo, lo);
        _mm_storeu_ps(dst[at].hi, hi);
        l += 1 - right;
        r -= right;
        sides.grow<A>(ce, lt);
      }
    };
    if (axis == 0) loop(std::integral_constant<int, 0>());
    else if (axis == 1) loop(std::integral_constant<int, 1>());
    else loop(std::integral_constant<int, 2>());
    sides.store(c);
#else
    for (std::uint32_t i = node.begin; i < node.end; ++i) {
      const PrimRef& p = src[i];
      const int s = g.left(p, axis, split) ? 0 : 1;
      dst[s ? --r : l++] = p;
      c[s].grow_centroid(p);
    }
#endif
    return l;
  }

#if defined(__SSE2__)
  // The count pass of partition_chunked over records [b, e): bounds each side's centroids into
  // box[0] (left) and box[1] (right) (SideBounds) and returns the left records.
  [[gnu::noinline]] static std::uint32_t side_boxes(const Geometry& g, int axis, unsigned split, const PrimRef* src,
                                                    std::size_t b, std::size_t e, FastBox (&box)[2]) {
#if defined(MBVH_BUILD_AVX2)
    if (use_vec256()) return vec256::side_count(vec256_split(g.origin, g.scale, split), axis, src, b, e, box);
#endif
    const SideTest st(g, split);
    SideBounds sides;
    std::uint32_t l = 0;
    auto loop = [&](auto axis_c) {
      constexpr int A = decltype(axis_c)::value;
      for (std::size_t i = b; i < e; ++i) {
        const __m128 ce = st.centroid(src[i]);
        const __m128 lt = st.left(ce);
        l += static_cast<unsigned>(_mm_movemask_ps(lt)) >> A & 1u;
        sides.grow<A>(ce, lt);
      }
    };
    if (axis == 0) loop(std::integral_constant<int, 0>());
    else if (axis == 1) loop(std::integral_constant<int, 1>());
    else loop(std::integral_constant<int, 2>());
    sides.store(box);
    return l;
  }

  // The scatter pass of partition_chunked: records [b, e) in order, the left ones to dst[l++],
  // the right ones to dst[r++].
  [[gnu::noinline]] static void scatter(const Geometry& g, int axis, unsigned split, const PrimRef* src, std::size_t b,
                                        std::size_t e, PrimRef* dst, std::uint32_t& l_out, std::uint32_t& r_out) {
#if defined(MBVH_BUILD_AVX2)
    if (use_vec256()) return vec256::scatter(vec256_split(g.origin, g.scale, split), axis, src, b, e, dst, l_out, r_out);
#endif
    const SideTest st(g, split);
    std::uint32_t l = l_out, r = r_out;
    for (std::size_t i = b; i < e; ++i) {
      const __m128 lo = _mm_loadu_ps(src[i].lo), hi = _mm_loadu_ps(src[i].hi);
      const unsigned left = static_cast<unsigned>(_mm_movemask_ps(st.left(st.centroid(lo, hi)))) >> axis & 1u;
      const std::uint32_t at = left ? l : r;
      _mm_storeu_ps(dst[at].lo, lo);
      _mm_storeu_ps(dst[at].hi, hi);
      l += left;
      r += 1 - left;
    }
    l_out = l;
    r_out = r;
  }
#endif

  // Stable partition in chunks of kGrain: count and bound each chunk's sides, scatter into the
  // other array (records()) by the chunks' prefix sums; side boxes reduced in chunk order.
  std::uint32_t partition_chunked(const Geometry& g, int axis, unsigned split, const TmpNode& node, FastBox (&c)[2],
                                  unsigned threads) {
    const std::uint32_t count = node.end - node.begin;
    const std::size_t chunks = (count + kGrain - 1) / kGrain;
    const PrimRef* src = records(node.depth);
    PrimRef* dst = records(node.depth + 1);
    std::vector<FastBox> side(2 * chunks);
    std::vector<std::uint32_t> left(chunks);
    for_chunks(count, threads, [&](std::size_t b, std::size_t e) {
      const std::size_t k = b / kGrain;
      std::uint32_t l = 0;
      FastBox box[2];  // bounded here, stored once: neighbouring chunks' boxes share cache lines
#if defined(__SSE2__)
      l = side_boxes(g, axis, split, src, node.begin + b, node.begin + e, box);
#else
      for (std::size_t i = node.begin + b; i < node.begin + e; ++i) {
        const PrimRef& r = src[i];
        const int s = g.left(r, axis, split) ? 0 : 1;
        box[s].grow_centroid(r);
        l += s == 0 ? 1 : 0;
      }
#endif
      side[2 * k] = box[0];
      side[2 * k + 1] = box[1];
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
      for (int s = 0; s < 2; ++s) c[s].grow(side[2 * k + static_cast<std::size_t>(s)]);
    }
    for_chunks(count, threads, [&](std::size_t b, std::size_t e) {
      const std::size_t k = b / kGrain;
      std::uint32_t l = node.begin + loff[k], r = node.begin + roff[k];
#if defined(__SSE2__)
      scatter(g, axis, split, src, node.begin + b, node.begin + e, dst, l, r);
#else
      for (std::size_t i = node.begin + b; i < node.begin + e; ++i) {
        const PrimRef& p = src[i];
        dst[g.left(p, axis, split) ? l++ : r++] = p;
      }
#endif
    });
    return node.begin + total_left;
  }

  const BuildOptions& opt_;
  RawVector<PrimRef>& prims_;
  RawVector<PrimRef> scratch_;  // odd_'s array when the caller gave none
  PrimRef* odd_ = nullptr;      // the records of odd depths (disjoint ranges: safe across tasks)
  unsigned bins_;
};

}  // namespace

void set_sah_kernels(SahKernels k) { g_kernels.store(k, std::memory_order_relaxed); }

void flatten(const Arenas& a, Bvh2& out, std::vector<Leaf>& leaves, unsigned threads) {
  // -- each subtree's inner nodes and leaves, then their places in the depth-first order
  const std::size_t subs = a.subtrees.size();
  std::vector<std::pair<std::size_t, std::size_t>> size(subs), at(subs);
  for (std::size_t j = 0; j < subs; ++j) {  // two children to every inner node (Arenas)
    const std::size_t n = a.subtrees[j].size();
    size[j] = {(n - 1) / 2, (n + 1) / 2};
  }
  std::vector<std::int32_t> parent_of(subs, MBVH_NONE), ref(subs, 0);
  std::vector<std::uint32_t> height(subs, 0);
  FlatWriter top{out, leaves};
  top.subtree_of = &a.subtree_of;
  top.sub_size = &size;
  top.place(a.upper, 0, MBVH_NONE, at, parent_of);
  resize_touched(threads, std::pair{&out.nodes, top.node}, std::pair{&out.leaf_boxes, top.leaf}, std::pair{&leaves, top.leaf});
  // -- the subtrees side by side, then the upper nodes around them
  std::vector<std::size_t> largest(subs, 0), forced(subs, 0);
  parallel_for(subs, 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t j = b; j < e; ++j) {
      FlatWriter fl{out, leaves, at[j].first, at[j].second};
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
                      Arenas& out, PrimRef* scratch) {
  SahBuilder builder(opt, prims, scratch);
  std::vector<TmpNode>& upper = out.upper;
  upper.assign(1, TmpNode());
  upper[0].box = root;
  std::vector<FastBox> ucbox(1, croot);  // centroid bounds of the upper nodes
  upper[0].begin = 0;
  upper[0].end = static_cast<std::uint32_t>(prims.size());
  upper[0].depth = 0;
  const unsigned threads = resolve_threads(opt.threads);
  const std::size_t small = std::max<std::size_t>(4096, prims.size() / (8 * std::size_t(threads)));
  auto size = [&](std::size_t k) { return std::size_t(upper[k].end - upper[k].begin); };
  // the nodes not yet split, a heap with the most records on top (then the lowest index)
  std::vector<std::size_t> open;
  auto fewer = [&](std::size_t x, std::size_t y) { return size(x) != size(y) ? size(x) < size(y) : x > y; };
  auto push = [&](std::size_t k) {
    open.push_back(k);
    std::push_heap(open.begin(), open.end(), fewer);
  };
  auto pop = [&] {
    std::pop_heap(open.begin(), open.end(), fewer);
    const std::size_t k = open.back();
    open.pop_back();
    return k;
  };
  // -- the root, then the largest open node while there are fewer than workers, split with their
  //    chunks on every worker (the other workers would have nothing to do)
  {
    Bins work;
    std::size_t k = 0;
    for (;;) {
      FastBox cc[2];
      if (builder.split(upper, k, ucbox[k], cc, threads, work)) {
        ucbox.insert(ucbox.end(), {cc[0], cc[1]});
        push(static_cast<std::size_t>(upper[k].child[0]));
        push(static_cast<std::size_t>(upper[k].child[1]));
      }
      if (open.empty() || open.size() >= threads || size(open.front()) < kParallelMin || size(open.front()) <= small) break;
      k = pop();
    }
  }
  // -- then one node at a time per worker from `open`, the largest first: a node of at most
  //    `small` records becomes a subtree built depth first by the worker that took it (a job),
  //    a larger one is split and its children go back into `open`. A worker takes the next node
  //    as soon as it is done, so no worker waits for the others to finish a level, and it most
  //    often takes a child it has just partitioned, whose records are still in its cache. The
  //    upper arena's and the jobs' order depend on the timing; the tree does not: flatten follows
  //    the child links, and every node is split the same way by whichever worker (split_node
  //    with its chunks on one worker makes the same choice and order as on many).
  out.block.ensure_bytes(2 * sizeof(SubNode) * prims.size());  // here, on the calling thread (NodeBlock)
  std::vector<SubArena> subs;     // job j's arena
  std::vector<std::size_t> jobs;  // job j's top node
  // the vectors the workers grow, allocated here for the nodes a tree of subtrees of about
  // `small` records has above them: a vector a worker grows frees its old block on that worker,
  // whose own cache (glibc's tcache) keeps a small one, then a chunk between the calling thread's
  // large arrays that the next build's arrays cannot take (fresh pages faulted in instead)
  const std::size_t expect = upper.size() + 8 * (prims.size() / small + 1);
  upper.reserve(expect);
  ucbox.reserve(expect);
  open.reserve(expect);
  subs.reserve(expect);
  jobs.reserve(expect);
  std::mutex m;
  std::condition_variable wake;
  unsigned busy = 0;  // workers splitting a node or building a job
  std::atomic<std::size_t> built{0};
  const double total = static_cast<double>(std::max<std::size_t>(1, prims.size()));
  bool failed = false;  // a worker threw: the others stop (parallel_for rethrows its exception)
  parallel_for(threads, 1, threads, [&](std::size_t, std::size_t, unsigned) {
    Bins work;
    std::unique_lock<std::mutex> lock(m);
    for (;;) {
      wake.wait(lock, [&] { return !open.empty() || busy == 0 || failed; });
      if (open.empty() || failed) return;  // nothing open and no worker that could open more: done
      const std::size_t k = pop();
      TmpNode t = upper[k];  // copies: `upper` grows under the lock meanwhile
      const FastBox cbox = ucbox[k];
      ++busy;
      struct Busy {  // a worker that throws leaves the others a way out
        std::unique_lock<std::mutex>& lock;
        std::condition_variable& wake;
        bool& failed;
        bool done = false;
        ~Busy() {
          if (done) return;
          if (!lock.owns_lock()) lock.lock();
          failed = true;
          wake.notify_all();
        }
      } guard{lock, wake, failed};
      if (size(k) <= small) {
        const std::size_t j = jobs.size();
        jobs.push_back(k);
        subs.emplace_back();
        lock.unlock();
        SubArena subtree = out.arena_for(t);
        builder.build_subtree(subtree, t, cbox);
        const std::size_t done = built += t.end - t.begin;
        if (opt.progress) opt.progress(0.25 + 0.7 * static_cast<double>(done) / total);
        lock.lock();
        subs[j] = subtree;
      } else {
        lock.unlock();
        TmpNode c[2];
        FastBox cc[2];
        const bool split = builder.split_node(t, cbox, c, cc, 1, work);
        lock.lock();
        upper[k] = t;
        if (split)
          for (int side = 0; side < 2; ++side) {
            upper[k].child[side] = static_cast<std::int32_t>(upper.size());
            upper.push_back(c[side]);
            ucbox.push_back(cc[side]);
            push(upper.size() - 1);
          }
      }
      guard.done = true;
      if (--busy == 0 || !open.empty()) wake.notify_all();
    }
  });
  // -- the subtrees in the arenas, each named by its top node
  make_root_inner(upper);
  subtree_of_jobs(out.subtree_of, upper.size(), jobs);
  out.subtrees = std::move(subs);
}

}  // namespace build

}  // namespace mbvh

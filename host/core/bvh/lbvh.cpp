// SPDX-License-Identifier: MIT
// lbvh.cpp — the fast builder (`--quality low`): a linear BVH over Morton codes of the triangles'
// centroids (Lauterbach et al., "Fast BVH Construction on GPUs", 2009; Karras, "Maximizing
// Parallelism in the Construction of BVHs, Octrees, and k-d Trees", HPG 2012). The records are
// sorted by a 30-bit code (10 bits per axis, ties kept in scene order by a stable radix sort),
// every node splits its range where the highest differing code bit flips (a binary search), and
// boxes are unions of the children's, bottom-up. Two additions keep it usable by every layout:
//  - the depth cap: a node whose Morton halves would need more levels than remain to reach leaves
//    of max_leaf triangles is halved by count instead (each halving removes exactly one level);
//  - leaves: a subtree of at most max_leaf triangles becomes one leaf where the SAH prices that
//    lower (the bottom-up collapse of Karras & Aila, "Fast Parallel Construction of High-Quality
//    BVHs", HPG 2013, without the treelet rotations).
// Deterministic: the split positions depend only on the sorted codes, the top of the tree is split
// breadth-first and the subtrees below are built one per task into their own arenas.
#include <algorithm>
#include <array>
#include <atomic>
#include <bit>

#include "host/core/bvh/builder.h"
#include "host/core/parallel.h"

namespace mbvh::build {
namespace {

// Spreads the low 10 bits of v to every third bit (bit i to bit 3i).
std::uint32_t spread3(std::uint32_t v) {
  v &= 0x3FFu;
  v = (v | (v << 16)) & 0x030000FFu;
  v = (v | (v << 8)) & 0x0300F00Fu;
  v = (v | (v << 4)) & 0x030C30C3u;
  v = (v | (v << 2)) & 0x09249249u;
  return v;
}

class LbvhBuilder {
public:
  LbvhBuilder(const BuildOptions& opt, const RawVector<PrimRef>& prims, const RawVector<std::uint32_t>& codes)
      : opt_(opt), prims_(prims), codes_(codes) {}

  // Binary levels below a node of `c` records down to leaves of at most max_leaf.
  unsigned needed(std::uint32_t c) const {
    unsigned l = 0;
    for (std::uint64_t reach = opt_.max_leaf; reach < c; reach *= 2) ++l;
    return l;
  }

  // Where node t splits (a record index strictly inside its range), or 0: t is a leaf.
  std::uint32_t split_of(const TmpNode& t) const {
    const std::uint32_t b = t.begin, e = t.end, count = e - b;
    if (count <= 1 || t.depth >= opt_.depth_cap) return 0;
    std::uint32_t mid;
    if (codes_[b] == codes_[e - 1]) {
      if (count <= opt_.max_leaf) return 0;
      mid = b + count / 2;
    } else {
      const std::uint32_t bit = 1u << (31 - std::countl_zero(codes_[b] ^ codes_[e - 1]));
      mid = static_cast<std::uint32_t>(
          std::partition_point(codes_.begin() + b, codes_.begin() + e, [bit](std::uint32_t c) { return (c & bit) == 0; }) -
          codes_.begin());
    }
    const unsigned below = opt_.depth_cap - t.depth - 1;  // levels left under a child
    if (needed(mid - b) > below || needed(e - mid) > below) mid = b + count / 2;
    return mid;
  }

  void make_leaf(TmpNode& t) const {
    t.leaf = true;
    t.forced = t.end - t.begin > opt_.max_leaf;
    t.child[0] = t.child[1] = -1;
    t.box = FastBox();
    for (std::uint32_t i = t.begin; i < t.end; ++i) t.box.grow(prims_[i]);
  }

  // Builds the subtree of arena node n (its range and depth set).
  void build(std::vector<TmpNode>& arena, std::size_t n) const {
    if (arena[n].end - arena[n].begin <= opt_.max_leaf) {
      FastBox box;
      build_small(arena, n, box);
      return;
    }
    const std::uint32_t mid = split_of(arena[n]);
    if (mid == 0) {
      make_leaf(arena[n]);
      return;
    }
    const std::size_t first = arena.size();
    push_children(arena, n, mid);
    build(arena, first);
    build(arena, first + 1);
    TmpNode& t = arena[n];
    t.box = arena[first].box;
    t.box.grow(arena[first + 1].box);
  }

  // Builds the subtree of arena node n of at most max_leaf records bottom-up and returns its SAH
  // cost (area units: node visits traversal_cost, triangles priced by blocks()) with its box: its
  // Morton split is made first, then undone (the children popped from the arena) where one leaf
  // prices no higher; every node below is priced once.
  float build_small(std::vector<TmpNode>& arena, std::size_t n, FastBox& box) const {
    const std::uint32_t mid = split_of(arena[n]);
    const std::uint32_t count = arena[n].end - arena[n].begin;
    if (mid == 0) {
      make_leaf(arena[n]);
      box = arena[n].box;
      return blocks(count, opt_.leaf_block) * box.half_area();
    }
    const std::size_t first = arena.size();
    push_children(arena, n, mid);
    FastBox rb;
    float split = build_small(arena, first, box);
    split += build_small(arena, first + 1, rb);
    box.grow(rb);
    const float area = box.half_area();
    const float cost = split + opt_.traversal_cost * area;
    const float leaf = blocks(count, opt_.leaf_block) * area;
    TmpNode& t = arena[n];
    t.box = box;
    if (leaf <= cost) {
      arena.resize(first);
      t.leaf = true;
      t.child[0] = t.child[1] = -1;
      return leaf;
    }
    return cost;
  }

  static void push_children(std::vector<TmpNode>& arena, std::size_t n, std::uint32_t mid) {
    TmpNode c[2];
    c[0].begin = arena[n].begin;
    c[0].end = c[1].begin = mid;
    c[1].end = arena[n].end;
    c[0].depth = c[1].depth = arena[n].depth + 1;
    arena[n].child[0] = static_cast<std::int32_t>(arena.size());
    arena[n].child[1] = static_cast<std::int32_t>(arena.size() + 1);
    arena.push_back(c[0]);
    arena.push_back(c[1]);
  }

private:
  const BuildOptions& opt_;
  const RawVector<PrimRef>& prims_;
  const RawVector<std::uint32_t>& codes_;
};

}  // namespace

void build_lbvh(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                Arenas& out) {
  const std::size_t n = prims.size();
  constexpr std::size_t grain = 65536;
  // -- Morton codes of the centroids, quantised to 1024 cells per axis of the centroid bounds
  float scale[3];
  for (int a = 0; a < 3; ++a) {
    const float ext = croot.hi[a] - croot.lo[a];
    scale[a] = ext > 0 ? 1024.0f / ext : 0.0f;
  }
  RawVector<std::uint32_t> key(n), val(n), key2(n), val2(n);
  parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) {
      std::uint32_t code = 0;
      for (int a = 0; a < 3; ++a) {
        const float f = (prims[i].centroid(a) - croot.lo[a]) * scale[a];
        code |= spread3(std::min(1023u, static_cast<std::uint32_t>(f > 0 ? f : 0))) << (2 - a);
      }
      key[i] = code;
      val[i] = static_cast<std::uint32_t>(i);
    }
  });
  // -- stable LSD radix sort of (code, record) by code, 8, 8, 8 and 6 bits a pass, each pass in
  //    chunks on the pool: the chunks' digit counts, their offsets in (digit, chunk) order, then
  //    every chunk scatters its records in order; a stable sort has one result at any thread count
  const std::size_t chunks = (n + grain - 1) / grain;
  std::vector<std::array<std::uint32_t, 256>> offset(chunks);
  for (unsigned shift = 0; shift < 30; shift += 8) {
    parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      std::array<std::uint32_t, 256>& h = offset[b / grain];
      h.fill(0);
      for (std::size_t i = b; i < e; ++i) ++h[(key[i] >> shift) & 255u];
    });
    std::uint32_t sum = 0;
    for (unsigned d = 0; d < 256; ++d)
      for (std::size_t c = 0; c < chunks; ++c) {
        const std::uint32_t k = offset[c][d];
        offset[c][d] = sum;
        sum += k;
      }
    parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      std::array<std::uint32_t, 256>& h = offset[b / grain];
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t d = h[(key[i] >> shift) & 255u]++;
        key2[d] = key[i];
        val2[d] = val[i];
      }
    });
    key.swap(key2);
    val.swap(val2);
  }
  {
    RawVector<PrimRef> sorted(n);
    parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) {
        if (i + 16 < e) __builtin_prefetch(&prims[val[i + 16]]);
        sorted[i] = prims[val[i]];
      }
    });
    prims.swap(sorted);
  }
  if (opt.progress) opt.progress(0.2);

  // -- top of the tree breadth-first (splits only: a binary search each), then subtrees per task
  LbvhBuilder builder(opt, prims, key);
  std::vector<TmpNode>& upper = out.upper;
  upper.assign(1, TmpNode());
  upper[0].begin = 0;
  upper[0].end = static_cast<std::uint32_t>(n);
  upper[0].depth = 0;
  const unsigned threads = resolve_threads(opt.threads);
  const std::size_t small = std::max<std::size_t>(4096, n / (8 * std::size_t(threads)));
  std::vector<std::size_t> jobs;
  for (std::size_t k = 0; k < upper.size(); ++k) {
    if (k > 0 && upper[k].end - upper[k].begin <= small) {
      jobs.push_back(k);
      continue;
    }
    const std::uint32_t mid = builder.split_of(upper[k]);
    if (mid == 0) builder.make_leaf(upper[k]);
    else LbvhBuilder::push_children(upper, k, mid);
  }
  build_subtrees(out, jobs, opt, [&](std::vector<TmpNode>& subtree, std::size_t) {
    subtree.reserve(2 * (subtree[0].end - subtree[0].begin) + 1);
    builder.build(subtree, 0);
  });
  // -- the top's boxes bottom-up (children follow their parent in the breadth-first arena)
  for (std::size_t k = upper.size(); k-- > 0;) {
    TmpNode& t = upper[k];
    if (out.subtree_of[k] >= 0) t.box = out.subtrees[static_cast<std::size_t>(out.subtree_of[k])][0].box;
    else if (!t.leaf) {
      t.box = FastBox();
      for (int s = 0; s < 2; ++s)
        if (t.child[s] >= 0) t.box.grow(upper[static_cast<std::size_t>(t.child[s])].box);
    }
  }
  (void)root;
}

}  // namespace mbvh::build

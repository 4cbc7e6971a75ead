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
#include <atomic>
#include <bit>

#include "host/core/build/builder.h"
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

  // The SAH cost (area units: node visits traversal_cost, triangles priced by blocks()) and box
  // of the subtree over [b, e) at `depth` as build() would make it, without making it: a
  // small range's leaf-or-split choice is priced before any node is written.
  float price(std::uint32_t b, std::uint32_t e, std::uint32_t depth, FastBox& box) const {
    TmpNode t;
    t.begin = b;
    t.end = e;
    t.depth = depth;
    const std::uint32_t mid = split_of(t);
    box = FastBox();
    if (mid == 0) {
      for (std::uint32_t i = b; i < e; ++i) box.grow(prims_[i]);
      return blocks(e - b, opt_.leaf_block) * box.half_area();
    }
    FastBox cb;
    float cost = price(b, mid, depth + 1, box);
    cost += price(mid, e, depth + 1, cb);
    box.grow(cb);
    const float area = box.half_area();
    cost += opt_.traversal_cost * area;
    return std::min(cost, blocks(e - b, opt_.leaf_block) * area);  // a leaf where the SAH prices it lower
  }

  // Builds the subtree of arena node n (its range and depth set).
  void build(std::vector<TmpNode>& arena, std::size_t n) const {
    const std::uint32_t mid = split_of(arena[n]);
    const std::uint32_t count = arena[n].end - arena[n].begin;
    if (mid == 0) {
      make_leaf(arena[n]);
      return;
    }
    if (count <= opt_.max_leaf) {  // a leaf unless its split subtree prices lower
      FastBox lb, rb;
      const std::uint32_t depth = arena[n].depth + 1;
      const float split = price(arena[n].begin, mid, depth, lb) + price(mid, arena[n].end, depth, rb);
      lb.grow(rb);
      const float area = lb.half_area();
      if (blocks(count, opt_.leaf_block) * area <= split + opt_.traversal_cost * area) {
        arena[n].leaf = true;
        arena[n].box = lb;
        return;
      }
    }
    const std::size_t first = arena.size();
    push_children(arena, n, mid);
    build(arena, first);
    build(arena, first + 1);
    TmpNode& t = arena[n];
    t.box = arena[first].box;
    t.box.grow(arena[first + 1].box);
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
  // -- stable LSD radix sort of (code, record) by code: 8, 8, 8 and 6 bits
  for (unsigned shift = 0; shift < 30; shift += 8) {
    std::size_t count[256] = {};
    for (std::size_t i = 0; i < n; ++i) ++count[(key[i] >> shift) & 255u];
    std::size_t sum = 0;
    for (std::size_t& c : count) {
      const std::size_t k = c;
      c = sum;
      sum += k;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::size_t d = count[(key[i] >> shift) & 255u]++;
      key2[d] = key[i];
      val2[d] = val[i];
    }
    key.swap(key2);
    val.swap(val2);
  }
  {
    RawVector<PrimRef> sorted(n);
    parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) sorted[i] = prims[val[i]];
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
  build_subtrees(out, jobs, opt, [&](std::vector<TmpNode>& subtree) {
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

// SPDX-License-Identifier: MIT
// lbvh.cpp — the fast builder (`--quality low`): a linear BVH over Morton codes of the triangles'
// centroids (Lauterbach et al., "Fast BVH Construction on GPUs", 2009; Karras, "Maximizing
// Parallelism in the Construction of BVHs, Octrees, and k-d Trees", HPG 2012). The records are
// sorted by a 30-bit code (10 bits per axis, ties kept in scene order: a radix sort, one pass on
// the top digit over the whole array, then each digit's bucket on its own while it is in cache),
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
#include <memory>
#include <type_traits>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/parallel.h"

namespace mbvh::build {
namespace {

// Spreads the low 10 bits of v to every third bit (bit i to bit 3i).
constexpr std::uint32_t spread3(std::uint32_t v) {
  v &= 0x3FFu;
  v = (v | (v << 16)) & 0x030000FFu;
  v = (v | (v << 8)) & 0x0300F00Fu;
  v = (v | (v << 4)) & 0x030C30C3u;
  v = (v | (v << 2)) & 0x09249249u;
  return v;
}

// spread3 of every 10-bit value: a Morton code is three lookups.
constexpr std::array<std::uint32_t, 1024> kSpread = [] {
  std::array<std::uint32_t, 1024> t{};
  for (std::uint32_t v = 0; v < 1024; ++v) t[v] = spread3(v);
  return t;
}();

// A sort item: the Morton code in the high half, the record's index in the low half.
inline std::uint32_t code_of(std::uint64_t item) { return static_cast<std::uint32_t>(item >> 32); }

static_assert(sizeof(Tri) == 48, "build_lbvh's scratch: 48 bytes a record, the triangle records' array");

class LbvhBuilder {
public:
  // `items`: the records' sort items (code_of: their Morton codes), in record order.
  LbvhBuilder(const BuildOptions& opt, const RawVector<PrimRef>& prims, const std::uint64_t* items)
      : opt_(opt), prims_(prims), items_(items) {}

  // blocks(): triangles priced in blocks of leaf_block; the division only where that is not 1.
  float price(std::uint32_t n) const { return opt_.leaf_block <= 1 ? static_cast<float>(n) : blocks(n, opt_.leaf_block); }

  // Binary levels below a node of `c` records down to leaves of at most max_leaf.
  unsigned needed(std::uint32_t c) const {
    unsigned l = 0;
    for (std::uint64_t reach = opt_.max_leaf; reach < c; reach *= 2) ++l;
    return l;
  }

  // Where node t splits (a record index strictly inside its range), or 0: t is a leaf.
  std::uint32_t split_of(const TmpNode& t) const { return split_of(t.begin, t.end, t.depth); }
  std::uint32_t split_of(std::uint32_t b, std::uint32_t e, std::uint32_t depth) const {
    const std::uint32_t count = e - b;
    if (count <= 1 || depth >= opt_.depth_cap) return 0;
    std::uint32_t mid;
    const std::uint32_t cb = code_of(items_[b]), ce = code_of(items_[e - 1]);
    if (cb == ce) {
      if (count <= opt_.max_leaf) return 0;
      mid = b + count / 2;
    } else {
      // the first item with the bit set (the range shares the code bits above it, so the clear
      // ones come first): a binary search without branches on the items, which mispredict half
      // the time
      const std::uint64_t bit = std::uint64_t(1) << (63 - std::countl_zero(cb ^ ce));
      const std::uint64_t* first = items_ + b;
      for (std::uint32_t len = count; len > 1;) {
        const std::uint32_t half = len / 2;
        first += (first[half - 1] & bit) == 0 ? half : 0;
        len -= half;
      }
      mid = static_cast<std::uint32_t>(first - items_) + ((*first & bit) == 0 ? 1 : 0);
    }
    const unsigned below = opt_.depth_cap - depth - 1;  // levels left under a child
    // (a child never needs more levels than its parent's records would)
    if (needed(count) > below && (needed(mid - b) > below || needed(e - mid) > below)) mid = b + count / 2;
    return mid;
  }

  void make_leaf(TmpNode& t) const {
    FastBox box;
    for (std::uint32_t i = t.begin; i < t.end; ++i) box.grow(prims_[i]);
    make_leaf(t, box);
  }
  // make_leaf with the records' box known.
  void make_leaf(TmpNode& t, const FastBox& box) const {
    t.leaf = true;
    t.forced = t.end - t.begin > opt_.max_leaf;
    t.child[0] = t.child[1] = -1;
    t.box = box;
  }

  // A node of build_small's tree while it is priced (outside the arena): its record range, its
  // box and its first child's index in the same array (the second follows it), -1 for a leaf.
  // (Plain rows, no initialisers: the array is not filled before it is used.)
  struct Small {
    float lo[3], hi[3];
    std::uint32_t begin, end;
    std::int32_t child;
    FastBox box() const {
      FastBox f;
      for (int a = 0; a < 3; ++a) f.lo[a] = lo[a], f.hi[a] = hi[a];
      return f;
    }
    void set_box(const FastBox& f) {
      for (int a = 0; a < 3; ++a) lo[a] = f.lo[a], hi[a] = f.hi[a];
    }
  };
  static_assert(std::is_trivially_default_constructible_v<Small>);

  // Builds a subtree task's tree from its arena's node 0 (its range and depth set).
  void build(SubArena& arena) const {
    constexpr std::size_t kStack = 64;  // build_small's nodes on the stack: max_leaf up to 32
    Small stack[kStack];
    // room for 2 c nodes, c the largest range build_small sees: max_leaf, or the task's whole range
    // where that is smaller (a caller's max_leaf may be huge); not filled (Small has no initialisers)
    const std::size_t room = 2 * std::min<std::size_t>(opt_.max_leaf, arena[0].end - arena[0].begin);
    std::unique_ptr<Small[]> heap;
    Small* nodes = stack;
    if (room > kStack) {
      heap.reset(new Small[room]);
      nodes = heap.get();
    }
    build(arena, 0, nodes);
  }

  // Builds the subtree of arena node n (its range and depth set); `nodes`: build_small's room.
  void build(SubArena& arena, std::size_t n, Small* nodes) const {
    if (arena[n].end - arena[n].begin <= opt_.max_leaf) {
      build_small(arena, n, nodes);
      return;
    }
    const std::uint32_t mid = split_of(arena[n]);
    if (mid == 0) {
      make_leaf(arena[n]);
      return;
    }
    const std::size_t first = arena.size();
    push_children(arena, n, mid);
    build(arena, first, nodes);
    build(arena, first + 1, nodes);
    TmpNode& t = arena[n];
    t.box = arena[first].box;
    t.box.grow(arena[first + 1].box);
  }

  // Builds the subtree of arena node n of at most max_leaf records bottom-up: its Morton split is
  // made first, then undone where one leaf prices no higher, every node below priced once (price()).
  // The pricing runs on `nodes`, room for 2 max_leaf (a range of c records has at most 2c - 1
  // nodes); only the nodes kept are written to the arena, in the order a depth-first build
  // pushes them.
  void build_small(SubArena& arena, std::size_t n, Small* nodes) const {
    nodes[0].begin = arena[n].begin;
    nodes[0].end = arena[n].end;
    std::uint32_t size = 1;
    price_small(nodes, size, 0, arena[n].depth);
    emit_small(arena, n, nodes, 0);
  }

  // Prices node `self` of `nodes` (its range set) at `depth` and returns its SAH cost (area units:
  // node visits traversal_cost, triangles priced by blocks()); its box set, the children it keeps
  // appended from `size`. A node of two records prices its two one-record leaves without
  // splitting (equal codes make one leaf).
  float price_small(Small* nodes, std::uint32_t& size, std::uint32_t self, std::uint32_t depth) const {
    Small& t = nodes[self];
    const std::uint32_t b = t.begin, count = t.end - t.begin;
    if (count == 2 && depth < opt_.depth_cap && opt_.max_leaf >= 2) {
      FastBox c[2];
      c[0].grow(prims_[b]);
      c[1].grow(prims_[b + 1]);
      FastBox box = c[0];
      box.grow(c[1]);
      t.set_box(box);
      t.child = -1;
      const float area = box.half_area();
      const float leaf = price(2) * area;
      if (code_of(items_[b]) != code_of(items_[b + 1])) {
        const float one = price(1);
        const float cost = one * c[0].half_area() + one * c[1].half_area() + opt_.traversal_cost * area;
        if (leaf > cost) {
          t.child = static_cast<std::int32_t>(size);
          for (std::uint32_t k = 0; k < 2; ++k) {
            Small& l = nodes[size + k];
            l.set_box(c[k]);
            l.begin = b + k;
            l.end = b + k + 1;
            l.child = -1;
          }
          size += 2;
          return cost;
        }
      }
      return leaf;
    }
    const std::uint32_t mid = split_of(b, t.end, depth);
    if (mid == 0) {
      FastBox box;
      for (std::uint32_t i = b; i < t.end; ++i) box.grow(prims_[i]);
      t.set_box(box);
      t.child = -1;
      return price(count) * box.half_area();
    }
    const std::uint32_t first = size;
    nodes[first].begin = b;
    nodes[first].end = nodes[first + 1].begin = mid;
    nodes[first + 1].end = t.end;
    size += 2;
    float split = price_small(nodes, size, first, depth + 1);
    split += price_small(nodes, size, first + 1, depth + 1);
    FastBox box = nodes[first].box();
    box.grow(nodes[first + 1].box());
    const float area = box.half_area();
    const float cost = split + opt_.traversal_cost * area;
    const float leaf = price(count) * area;
    t.set_box(box);
    if (leaf <= cost) {
      size = first;  // its descendants were appended after its children
      t.child = -1;
      return leaf;
    }
    t.child = static_cast<std::int32_t>(first);
    return cost;
  }

  // Writes priced node `self` into arena node n (its range and depth set), its kept children
  // pushed after it and written depth-first.
  void emit_small(SubArena& arena, std::size_t n, const Small* nodes, std::uint32_t self) const {
    const Small& s = nodes[self];
    if (s.child < 0) {
      make_leaf(arena[n], s.box());
      return;
    }
    const std::size_t first = arena.size();
    const std::uint32_t c = static_cast<std::uint32_t>(s.child);
    push_children(arena, n, nodes[c].end);
    arena[n].box = s.box();
    emit_small(arena, first, nodes, c);
    emit_small(arena, first + 1, nodes, c + 1);
  }

  template <class Arena>  // the upper arena (a vector) or a subtree's (SubArena)
  static void push_children(Arena& arena, std::size_t n, std::uint32_t mid) {
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
  const std::uint64_t* items_;
};

}  // namespace

void build_lbvh(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                Arenas& out, PrimRef* scratch) {
  const std::size_t n = prims.size();
  // chunks of the passes below: about four per worker (a stable sort has one result whatever
  // the chunks, so they may follow the thread count)
  const std::size_t grain = std::max<std::size_t>(8192, (n + 4 * resolve_threads(opt.threads) - 1) / (4 * resolve_threads(opt.threads)));
  // -- working memory, 48 bytes a record: two arrays of sort items and a copy of the records; the
  //    caller's (the triangle records' array, written after the build: no pages of its own to
  //    fault in), else an array of our own
  RawVector<std::uint64_t> own;
  if (!scratch) {
    own.resize(6 * n);
    scratch = reinterpret_cast<PrimRef*>(static_cast<void*>(own.data()));
  }
  std::uint64_t* item = reinterpret_cast<std::uint64_t*>(static_cast<void*>(scratch));
  std::uint64_t* item2 = item + n;
  PrimRef* copy = reinterpret_cast<PrimRef*>(static_cast<void*>(item + 2 * n));
  // -- Morton codes of the centroids, quantised to 1024 cells per axis of the centroid bounds;
  //    the same pass copies the records aside (the gather below reads them there and writes the
  //    records' array in code order: no copy back) and counts each chunk's top digits
  float scale[3];
  for (int a = 0; a < 3; ++a) {
    const float ext = croot.hi[a] - croot.lo[a];
    scale[a] = ext > 0 ? 1024.0f / ext : 0.0f;
  }
  constexpr unsigned kDigits = 1024;
  constexpr unsigned kTop = 52;  // the top 10 of the code's 30 bits, in a sort item
  const std::size_t chunks = (n + grain - 1) / grain;
  std::vector<std::array<std::uint32_t, kDigits>> offset(chunks);
  parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::array<std::uint32_t, kDigits>& h = offset[b / grain];
    h.fill(0);
    for (std::size_t i = b; i < e; ++i) {
      const PrimRef r = prims[i];
      copy[i] = r;
      std::uint32_t code = 0;
      for (int a = 0; a < 3; ++a) {
        const float f = (r.centroid(a) - croot.lo[a]) * scale[a];
        code |= kSpread[std::min(1023u, static_cast<std::uint32_t>(f > 0 ? f : 0))] << (2 - a);
      }
      item[i] = std::uint64_t(code) << 32 | i;
      ++h[code >> 20];
    }
  });
  // -- the items sorted by code, ties in record order (so by the whole item: codes above the
  //    unique record indices): one stable most-significant-digit pass on the top 10 bits in chunks
  //    on the pool (the chunks' digit counts, their offsets in (digit, chunk) order, every chunk
  //    scattering its items in order), then each digit's bucket, mostly small enough to stay in
  //    cache, sorted on its own (least-significant-digit passes over the code's low 20 bits, or
  //    std::sort of the items where it is short) and its records gathered in code order. One result at any
  //    thread count.
  std::uint32_t sum = 0;
  std::array<std::uint32_t, kDigits + 1> bucket{};
  for (unsigned d = 0; d < kDigits; ++d) {
    bucket[d] = sum;
    for (std::size_t c = 0; c < chunks; ++c) {
      const std::uint32_t k = offset[c][d];
      offset[c][d] = sum;
      sum += k;
    }
  }
  bucket[kDigits] = sum;
  parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::array<std::uint32_t, kDigits>& h = offset[b / grain];
    for (std::size_t i = b; i < e; ++i) item2[h[item[i] >> kTop]++] = item[i];
  });
  parallel_for(kDigits, 16, opt.threads, [&](std::size_t d0, std::size_t d1, unsigned) {
    std::array<std::uint32_t, kDigits> h;
    for (std::size_t d = d0; d < d1; ++d) {
      const std::uint32_t b = bucket[d], e = bucket[d + 1];
      std::uint64_t* const s = item2 + b;
      const std::uint32_t m = e - b;
      std::uint64_t* src = s;
      if (m <= 64) {
        std::sort(s, s + m);
      } else {
        // the code's low 20 bits: three passes of 7, 7 and 6 bits where the bucket is short (the
        // counts' prefix sums cost about as much as the items), else two of 10
        const bool short_bucket = m <= 2048;
        const unsigned passes = short_bucket ? 3 : 2;
        std::uint64_t* dst = item + b;
        for (unsigned p = 0; p < passes; ++p) {
          const unsigned shift = short_bucket ? 32 + 7 * p : 32 + 10 * p;
          const unsigned bits = short_bucket ? (p == 2 ? 6 : 7) : 10;
          const std::uint64_t mask = (std::uint64_t(1) << bits) - 1;
          std::fill_n(h.begin(), std::size_t(1) << bits, 0u);
          for (std::uint32_t i = 0; i < m; ++i) ++h[(src[i] >> shift) & mask];
          std::uint32_t at = 0;
          for (unsigned k = 0; k < (1u << bits); ++k) {
            const std::uint32_t c = h[k];
            h[k] = at;
            at += c;
          }
          for (std::uint32_t i = 0; i < m; ++i) dst[h[(src[i] >> shift) & mask]++] = src[i];
          std::swap(src, dst);
        }
      }
      // the records gathered in code order (and the items back in place after an odd number of
      // passes)
      for (std::uint32_t i = 0; i < m; ++i) {
        if (i + 16 < m) __builtin_prefetch(&copy[static_cast<std::uint32_t>(src[i + 16])]);
        prims[b + i] = copy[static_cast<std::uint32_t>(src[i])];
      }
      if (src != s) std::copy(src, src + m, s);
    }
  });
  item = item2;
  if (opt.progress) opt.progress(0.2);

  // -- top of the tree breadth-first (splits only: a binary search each), then subtrees per task
  LbvhBuilder builder(opt, prims, item);
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
  build_subtrees(out, jobs, opt, [&](SubArena& subtree, std::size_t) { builder.build(subtree); });
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

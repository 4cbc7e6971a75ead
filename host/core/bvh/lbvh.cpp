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
// breadth-first and the subtrees below are built one per task. A task writes its subtree in the
// flattened form (Bvh2 nodes depth-first, leaves in record order) numbered from 0 in scratch of
// its own; once every task's size is known the subtrees are moved into their places and their
// references shifted there, the bytes flatten would write from arenas of the same tree.
#include <algorithm>
#include <array>
#include <bit>
#include <memory>
#include <type_traits>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/flat_writer.h"
#include "host/core/huge_pages.h"
#include "host/core/layouts.h"
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

// A box as two rows (x, y, z in lanes 0-2), grown and priced as FastBox is, to the same bits (the
// SSE min and max return their second operand unless the first is smaller, larger: a
// FastBox::grow's std::min and std::max with the operands swapped), so the subtrees' boxes and
// SAH decisions are FastBox's: one instruction a row where FastBox takes three.
#if defined(__SSE2__)
struct Rows {
  __m128 lo, hi;
  static Rows empty() { return {_mm_set1_ps(INFINITY), _mm_set1_ps(-INFINITY)}; }
  // lane 3 (the record's prim id and pad) zeroed: as a float a prim id is a subnormal, which
  // half_area's subtraction and product would carry through
  static Rows of(const PrimRef& r) {
    const __m128 xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
    return {_mm_and_ps(_mm_loadu_ps(r.lo), xyz), _mm_and_ps(_mm_loadu_ps(r.hi), xyz)};
  }
  void grow(const Rows& o) {
    lo = _mm_min_ps(o.lo, lo);
    hi = _mm_max_ps(o.hi, hi);
  }
  // FastBox::half_area: e0 e1 + e1 e2 + e2 e0, summed in that order; 0 for an empty box
  float half_area() const {
    if (!(_mm_cvtss_f32(lo) <= _mm_cvtss_f32(hi))) return 0.0f;
    const __m128 e = _mm_sub_ps(hi, lo);
    alignas(16) float p[4];
    _mm_store_ps(p, _mm_mul_ps(e, _mm_shuffle_ps(e, e, _MM_SHUFFLE(3, 0, 2, 1))));
    return p[0] + p[1] + p[2];
  }
  Box box() const {
    alignas(16) float l[4], h[4];
    _mm_store_ps(l, lo);
    _mm_store_ps(h, hi);
    Box b;
    b.lo = {l[0], l[1], l[2]};
    b.hi = {h[0], h[1], h[2]};
    return b;
  }
  FastBox fast() const {
    FastBox f;
    set_rows(f, lo, hi);
    return f;
  }
};
#else
struct Rows {
  FastBox f;
  static Rows empty() { return {}; }
  static Rows of(const PrimRef& r) {
    Rows x;
    x.f.grow(r);
    return x;
  }
  void grow(const Rows& o) { f.grow(o.f); }
  float half_area() const { return f.half_area(); }
  Box box() const { return f.box(); }
  FastBox fast() const { return f; }
};
#endif

class LbvhBuilder {
public:
  // `codes`: the records' Morton codes, in record order.
  LbvhBuilder(const BuildOptions& opt, const RawVector<PrimRef>& prims, const std::uint32_t* codes)
      : opt_(opt), prims_(prims), codes_(codes) {}

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
    const std::uint32_t cb = codes_[b], ce = codes_[e - 1];
    if (cb == ce) {
      if (count <= opt_.max_leaf) return 0;
      mid = b + count / 2;
    } else {
      // the first code with the bit set (the range shares the code bits above it, so the clear
      // ones come first): a binary search without branches on the codes, which mispredict half
      // the time
      const std::uint32_t bit = std::uint32_t(1) << (31 - std::countl_zero(cb ^ ce));
      const std::uint32_t* first = codes_ + b;
      for (std::uint32_t len = count; len > 1;) {
        const std::uint32_t half = len / 2;
        first += (first[half - 1] & bit) == 0 ? half : 0;
        len -= half;
      }
      mid = static_cast<std::uint32_t>(first - codes_) + ((*first & bit) == 0 ? 1 : 0);
    }
    const unsigned below = opt_.depth_cap - depth - 1;  // levels left under a child
    // (a child never needs more levels than its parent's records would)
    if (needed(count) > below && (needed(mid - b) > below || needed(e - mid) > below)) mid = b + count / 2;
    return mid;
  }

  // Upper node t made a leaf of its records.
  void make_leaf(TmpNode& t) const {
    t.leaf = true;
    t.forced = t.end - t.begin > opt_.max_leaf;
    t.child[0] = t.child[1] = -1;
    t.box = FastBox();
    for (std::uint32_t i = t.begin; i < t.end; ++i) t.box.grow(prims_[i]);
  }

  // A node of build_small's tree while it is priced (outside the arena): its record range, its
  // box and its first child's index in the same array (the second follows it), -1 for a leaf.
  // (Plain rows, no initialisers: the array is not filled before it is used.)
  struct Small {
    Rows box;
    std::uint32_t begin, end;
    std::int32_t child;
  };
#if defined(__SSE2__)  // (the portable Rows is a FastBox, which initialises itself)
  static_assert(std::is_trivially_default_constructible_v<Small>);
#endif

  // A subtree task's part of the flattened tree, numbered from 0 within the task: its inner nodes
  // depth-first (a box and two child references: the parents and heights are filled in when the
  // subtree is moved into place), its leaves in record order with their boxes, as flatten numbers
  // a subtree's (root: inner node 0 or leaf 0). Both in one room of `room` 32-byte entries, the
  // nodes from its start, the leaves from its end down; a subtree that needs more entries than
  // the room holds stops writing and is marked `overflow` (built again in a room that holds it).
  struct LocalNode {
    Box box;
    std::int32_t child[2];
  };
  struct LocalLeaf {
    Leaf leaf;
    Box box;
  };
  static_assert(sizeof(LocalNode) == 32 && sizeof(LocalLeaf) == 32);
  struct Local {
    LocalNode* nodes = nullptr;
    LocalLeaf* leaves_end = nullptr;  // leaf l at leaves_end[-1 - l]
    std::size_t room = 0;
    bool overflow = false;
    std::uint32_t node = 0, leaf = 0;
    std::size_t largest = 0, forced = 0;
    std::int32_t root = 0;
    std::uint32_t height = 0;
    Rows box;
    // Points the room at `bytes` bytes from `p` (4-byte aligned), emptied.
    void set_room(unsigned char* p, std::size_t bytes) {
      room = bytes / 32;
      nodes = reinterpret_cast<LocalNode*>(static_cast<void*>(p));
      leaves_end = reinterpret_cast<LocalLeaf*>(static_cast<void*>(p + 32 * room));
      overflow = false;
      node = leaf = 0;
      largest = forced = 0;
    }
    // Counts one more entry: overflow where the room is full.
    void take() {
      if (node + leaf >= room) overflow = true;
    }
  };

  // Builds the subtree of upper node `top` (its range and depth) into `local`.
  void build(const TmpNode& top, Local& local) const {
    constexpr std::size_t kStack = 64;  // build_small's nodes on the stack: max_leaf up to 32
    Small stack[kStack];
    // room for 2 c nodes, c the largest range build_small sees: max_leaf, or the task's whole range
    // where that is smaller (a caller's max_leaf may be huge); not filled (Small has no initialisers)
    const std::size_t room = 2 * std::min<std::size_t>(opt_.max_leaf, top.end - top.begin);
    std::unique_ptr<Small[]> heap;
    Small* nodes = stack;
    if (room > kStack) {
      heap.reset(new Small[room]);
      nodes = heap.get();
    }
    local.root = build(local, top.begin, top.end, top.depth, nodes, local.box, local.height);
  }

  // A leaf of records [b, e) with box `box` appended to `local`: its reference; height 0.
  std::int32_t leaf(Local& local, std::uint32_t b, std::uint32_t e, const Rows& box, std::uint32_t& height) const {
    local.take();
    const std::uint32_t l = local.leaf++;
    if (!local.overflow) ::new (static_cast<void*>(local.leaves_end - 1 - l)) LocalLeaf{{b, e - b}, box.box()};
    local.largest = std::max<std::size_t>(local.largest, e - b);
    local.forced += e - b > opt_.max_leaf ? 1 : 0;
    height = 0;
    return ~static_cast<std::int32_t>(l);
  }

  // Builds the subtree of records [b, e) at `depth` into `local` depth-first (a node before its
  // children). Returns its reference; its box and height set. `nodes`: build_small's room.
  std::int32_t build(Local& local, std::uint32_t b, std::uint32_t e, std::uint32_t depth, Small* nodes, Rows& box,
                     std::uint32_t& height) const {
    if (e - b <= opt_.max_leaf) return build_small(local, b, e, depth, nodes, box, height);
    const std::uint32_t mid = split_of(b, e, depth);
    if (mid == 0) {
      box = records_box(b, e);
      return leaf(local, b, e, box, height);
    }
    local.take();
    const std::int32_t self = static_cast<std::int32_t>(local.node++);
    Rows c[2];
    std::uint32_t h[2];
    const std::int32_t r0 = build(local, b, mid, depth + 1, nodes, c[0], h[0]);
    const std::int32_t r1 = build(local, mid, e, depth + 1, nodes, c[1], h[1]);
    box = c[0];
    box.grow(c[1]);
    height = 1 + std::max(h[0], h[1]);
    if (!local.overflow) ::new (static_cast<void*>(local.nodes + self)) LocalNode{box.box(), {r0, r1}};
    return self;
  }

  // Builds the subtree of records [b, e), at most max_leaf of them, bottom-up: its Morton split is
  // made first, then undone where one leaf prices no higher, every node below priced once (price()).
  // The pricing runs on `nodes`, room for 2 max_leaf (a range of c records has at most 2c - 1
  // nodes); only the nodes kept are written to `local`, depth-first.
  std::int32_t build_small(Local& local, std::uint32_t b, std::uint32_t e, std::uint32_t depth, Small* nodes, Rows& box,
                           std::uint32_t& height) const {
    nodes[0].begin = b;
    nodes[0].end = e;
    std::uint32_t size = 1;
    price_small(nodes, size, 0, depth);
    box = nodes[0].box;
    return emit_small(local, nodes, 0, height);
  }

  // Prices node `self` of `nodes` (its range set) at `depth` and returns its SAH cost (area units:
  // node visits traversal_cost, triangles priced by blocks()); its box set, the children it keeps
  // appended from `size`. A node of two records prices its two one-record leaves without
  // splitting (equal codes make one leaf).
  float price_small(Small* nodes, std::uint32_t& size, std::uint32_t self, std::uint32_t depth) const {
    Small& t = nodes[self];
    const std::uint32_t b = t.begin, count = t.end - t.begin;
    if (count == 2 && depth < opt_.depth_cap && opt_.max_leaf >= 2) {
      const Rows c[2] = {Rows::of(prims_[b]), Rows::of(prims_[b + 1])};
      Rows box = c[0];
      box.grow(c[1]);
      t.box = box;
      t.child = -1;
      const float area = box.half_area();
      const float leaf = price(2) * area;
      if (codes_[b] != codes_[b + 1]) {
        const float one = price(1);
        const float cost = one * c[0].half_area() + one * c[1].half_area() + opt_.traversal_cost * area;
        if (leaf > cost) {
          t.child = static_cast<std::int32_t>(size);
          for (std::uint32_t k = 0; k < 2; ++k) {
            Small& l = nodes[size + k];
            l.box = c[k];
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
      t.box = records_box(b, t.end);
      t.child = -1;
      return price(count) * t.box.half_area();
    }
    const std::uint32_t first = size;
    nodes[first].begin = b;
    nodes[first].end = nodes[first + 1].begin = mid;
    nodes[first + 1].end = t.end;
    size += 2;
    float split = price_small(nodes, size, first, depth + 1);
    split += price_small(nodes, size, first + 1, depth + 1);
    Rows box = nodes[first].box;
    box.grow(nodes[first + 1].box);
    const float area = box.half_area();
    const float cost = split + opt_.traversal_cost * area;
    const float leaf = price(count) * area;
    t.box = box;
    if (leaf <= cost) {
      size = first;  // its descendants were appended after its children
      t.child = -1;
      return leaf;
    }
    t.child = static_cast<std::int32_t>(first);
    return cost;
  }

  // The box of records [b, e).
  Rows records_box(std::uint32_t b, std::uint32_t e) const {
    Rows box = Rows::empty();
    for (std::uint32_t i = b; i < e; ++i) box.grow(Rows::of(prims_[i]));
    return box;
  }

  // Writes priced node `self` into `local` depth-first (a node before its kept children).
  // Returns its reference; its height set.
  std::int32_t emit_small(Local& local, const Small* nodes, std::uint32_t self, std::uint32_t& height) const {
    const Small& s = nodes[self];
    if (s.child < 0) return leaf(local, s.begin, s.end, s.box, height);
    local.take();
    const std::int32_t id = static_cast<std::int32_t>(local.node++);
    const std::uint32_t c = static_cast<std::uint32_t>(s.child);
    std::uint32_t h[2];
    const std::int32_t r0 = emit_small(local, nodes, c, h[0]);
    const std::int32_t r1 = emit_small(local, nodes, c + 1, h[1]);
    height = 1 + std::max(h[0], h[1]);
    if (!local.overflow) ::new (static_cast<void*>(local.nodes + id)) LocalNode{s.box.box(), {r0, r1}};
    return id;
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
  const std::uint32_t* codes_;
};

}  // namespace

void build_lbvh(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                Arenas& out, Bvh2& tree, std::vector<Leaf>& leaves, PrimRef* scratch) {
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
  // -- the sorted codes alone (4 bytes a record) at the scratch's start: the splits read them,
  //    and the rest of the scratch, 44 bytes a record, is the subtrees' room
  std::uint32_t* const codes = reinterpret_cast<std::uint32_t*>(static_cast<void*>(scratch));
  parallel_for(n, grain, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) codes[i] = code_of(item2[i]);
  });
  unsigned char* const spare = reinterpret_cast<unsigned char*>(static_cast<void*>(scratch)) + 4 * n;
  constexpr std::size_t kSpare = 44;  // bytes a record
  static_assert(4 + kSpare == sizeof(Tri));
  if (opt.progress) opt.progress(0.2);

  // -- top of the tree breadth-first (splits only: a binary search each), then subtrees per task
  LbvhBuilder builder(opt, prims, codes);
  std::vector<TmpNode>& upper = out.upper;
  upper.assign(1, TmpNode());
  upper[0].begin = 0;
  upper[0].end = static_cast<std::uint32_t>(n);
  upper[0].depth = 0;
  const unsigned threads = resolve_threads(opt.threads);
  // A node of at most max_leaf records is always a task's (but the root, which the top always
  // splits): the task prices it as one leaf or a subtree (build_small), which the top's split
  // would not; so the tree is the same whatever `small` the thread count makes.
  const std::size_t small = std::max<std::size_t>({4096, n / (8 * std::size_t(threads)), opt.max_leaf});
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
  make_root_inner(upper);
  // -- the subtrees, one task each (largest first: the order only spreads the work), each into
  //    its records' run of the scratch's spare bytes (pages the sort has touched); a subtree of
  //    more leaves than that holds (above about 0.69 a record: max_leaf 1, say) is built again
  //    into its records' run of the node block (2 TmpNodes a record, 96 bytes: 2 c - 1
  //    entries of 32 bytes always fit), allocated only then
  std::vector<std::int32_t> subtree_of;
  subtree_of_jobs(subtree_of, upper.size(), jobs);
  const std::vector<std::size_t> order = largest_first(upper, jobs);
  std::vector<LbvhBuilder::Local> local(jobs.size());
  run_subtree_jobs(order, opt, [&](std::size_t j) {
    const TmpNode& top = upper[jobs[j]];
    local[j].set_room(spare + kSpare * top.begin, kSpare * (top.end - top.begin));
    builder.build(top, local[j]);
  });
  std::vector<std::size_t> again;
  for (const std::size_t j : order)
    if (local[j].overflow) again.push_back(j);
  if (!again.empty()) {
    static_assert(3 * sizeof(LbvhBuilder::LocalNode) <= 2 * sizeof(TmpNode));
    TmpNode* const block = out.block.ensure(2 * n);  // here, on the calling thread (NodeBlock)
    parallel_for(again.size(), 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t o = b; o < e; ++o) {
        const std::size_t j = again[o];
        const TmpNode& top = upper[jobs[j]];
        local[j].set_room(reinterpret_cast<unsigned char*>(static_cast<void*>(block + 2 * std::size_t(top.begin))),
                          2 * sizeof(TmpNode) * (top.end - top.begin));
        builder.build(top, local[j]);
        if (local[j].overflow) throw Error("internal: an LBVH subtree overflows its room in the node block");
      }
    });
  }
  // -- the top's boxes bottom-up (children follow their parent in the breadth-first arena)
  for (std::size_t k = upper.size(); k-- > 0;) {
    TmpNode& t = upper[k];
    if (subtree_of[k] >= 0) t.box = local[static_cast<std::size_t>(subtree_of[k])].box.fast();
    else if (!t.leaf) {
      t.box = FastBox();
      for (int s = 0; s < 2; ++s)
        if (t.child[s] >= 0) t.box.grow(upper[static_cast<std::size_t>(t.child[s])].box);
    }
  }
  // -- the flattened tree: the subtrees' places in the depth-first order (a walk of the top),
  //    the top's nodes and leaves written around them, each subtree moved into its place with its
  //    references shifted there (side by side on the pool): its nodes last to first, so that a
  //    node's children have their heights when it is written and get their parent from it
  const std::size_t subs = jobs.size();
  std::vector<std::pair<std::size_t, std::size_t>> size(subs), at(subs);
  std::vector<std::int32_t> parent_of(subs, MBVH_NONE), ref(subs, 0);
  std::vector<std::uint32_t> sub_height(subs, 0);
  for (std::size_t j = 0; j < subs; ++j) {
    size[j] = {local[j].node, local[j].leaf};
    sub_height[j] = local[j].height;
  }
  FlatWriter top{tree, leaves};
  top.subtree_of = &subtree_of;
  top.sub_size = &size;
  top.place(upper, 0, MBVH_NONE, at, parent_of);
  resize_touched(opt.threads, std::pair{&tree.nodes, top.node}, std::pair{&tree.leaf_boxes, top.leaf}, std::pair{&leaves, top.leaf});
  for (std::size_t j = 0; j < subs; ++j)  // a subtree's root: its first node, or its one leaf
    ref[j] = local[j].root >= 0 ? static_cast<std::int32_t>(at[j].first) : ~static_cast<std::int32_t>(at[j].second);
  top.node = top.leaf = 0;
  top.sub_ref = &ref;
  top.sub_height = &sub_height;
  std::uint32_t height = 0;
  top.emit(upper, 0, MBVH_NONE, height);
  parallel_for(jobs.size(), 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t j = b; j < e; ++j) {
      const LbvhBuilder::Local& l = local[j];
      const std::int32_t node0 = static_cast<std::int32_t>(at[j].first);
      const std::int32_t leaf0 = static_cast<std::int32_t>(at[j].second);
      Bvh2::Node* dst = tree.nodes.data() + node0;
      for (std::uint32_t i = l.node; i-- > 0;) {
        const LbvhBuilder::LocalNode& s = l.nodes[i];
        Bvh2::Node& d = dst[i];
        d.box = s.box;
        std::uint32_t h = 0;
        for (int k = 0; k < 2; ++k) {
          const std::int32_t c = s.child[k];
          if (c >= 0) {
            d.child[k] = c + node0;
            h = std::max(h, dst[c].height);
            dst[c].parent = static_cast<std::int32_t>(i) + node0;
          } else {
            d.child[k] = c - leaf0;
          }
        }
        d.height = 1 + h;
      }
      if (l.node > 0) dst[0].parent = parent_of[j];
      for (std::uint32_t k = 0; k < l.leaf; ++k) {
        const LbvhBuilder::LocalLeaf& f = l.leaves_end[-1 - static_cast<std::ptrdiff_t>(k)];
        leaves[leaf0 + k] = f.leaf;
        tree.leaf_boxes[leaf0 + k] = f.box;
      }
    }
  });
  tree.largest_leaf = top.largest;
  tree.forced_leaves = top.forced;
  for (const LbvhBuilder::Local& l : local) {
    tree.largest_leaf = std::max(tree.largest_leaf, l.largest);
    tree.forced_leaves += l.forced;
  }
  (void)root;
}

}  // namespace mbvh::build

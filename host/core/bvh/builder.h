// SPDX-License-Identifier: MIT
// builder.h — what the binary builders share (internal to host/core/bvh/): the primitive records
// they reorder, the temporary node arena they fill and its depth-first flattening into Bvh2.
// Accel::build (accel.cpp) takes the records from make_prim_refs (prim_refs.cpp), calls one
// builder by BuildOptions::quality and turns the leaf-ordered records into the triangles and
// statistics; hash_build (hash.cpp) makes the hash.
#pragma once
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>
#include <mutex>
#include <type_traits>
#include <utility>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "mbvh/accel.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"

namespace mbvh::build {

/// One triangle's box and scene index, 32 bytes: builders move these records, not indices, so
/// binning and partitioning stream through memory. Its centroid is centroid(a) (= Box::center()).
struct PrimRef {
  float lo[3];
  std::uint32_t prim;
  float hi[3];
  std::uint32_t pad;
  float centroid(int a) const { return 0.5f * (lo[a] + hi[a]); }
};
static_assert(sizeof(PrimRef) == 32);

/// An allocator that default-initialises (leaves PrimRefs and integers uninitialised): the
/// builders' large arrays are first written by parallel passes, so their pages are first touched
/// there, not zeroed by one thread beforehand.
template <class T>
struct NoInit : std::allocator<T> {
  using value_type = T;
  NoInit() = default;
  template <class U>
  NoInit(const NoInit<U>&) {}
  template <class U>
  struct rebind {
    using other = NoInit<U>;
  };
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    if constexpr (sizeof...(Args) == 0) ::new (static_cast<void*>(p)) U;
    else ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
};
template <class T>
using RawVector = std::vector<T, NoInit<T>>;

/// An axis-aligned box kept as two float[3] rows, grown inline (Box::grow is out of line).
struct FastBox {
  float lo[3] = {INFINITY, INFINITY, INFINITY};
  float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  void grow(const PrimRef& r) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], r.lo[a]);
      hi[a] = std::max(hi[a], r.hi[a]);
    }
  }
  void grow(const FastBox& b) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], b.lo[a]);
      hi[a] = std::max(hi[a], b.hi[a]);
    }
  }
  void grow_rows(const float* l, const float* h) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], l[a]);
      hi[a] = std::max(hi[a], h[a]);
    }
  }
  void grow_point(const float p[3]) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], p[a]);
      hi[a] = std::max(hi[a], p[a]);
    }
  }
  void grow_centroid(const PrimRef& r) {
    const float c[3] = {r.centroid(0), r.centroid(1), r.centroid(2)};
    grow_point(c);
  }
  /// As Box::half_area(): 0 for an empty box.
  float half_area() const {
    if (!(lo[0] <= hi[0])) return 0.0f;
    const float e[3] = {hi[0] - lo[0], hi[1] - lo[1], hi[2] - lo[2]};
    return e[0] * e[1] + e[1] * e[2] + e[2] * e[0];
  }
  Box box() const {
    Box b;
    b.lo = {lo[0], lo[1], lo[2]};
    b.hi = {hi[0], hi[1], hi[2]};
    return b;
  }
};

#if defined(__SSE2__)
/// `box` made the box of two SSE rows (lanes 0-2; lane 3 ignored).
inline void set_rows(FastBox& box, __m128 lo, __m128 hi) {
  alignas(16) float l[4], h[4];
  _mm_store_ps(l, lo);
  _mm_store_ps(h, hi);
  for (int a = 0; a < 3; ++a) {
    box.lo[a] = l[a];
    box.hi[a] = h[a];
  }
}
#endif

/// A node of a builder's arena: a range of the record array, children in the same arena. The
/// bounds of its centroids, which only splitting it needs, are kept by the builder beside it.
struct TmpNode {
  FastBox box;                // bounds of the triangles
  std::uint32_t begin, end;   // range of the record array
  std::uint32_t depth;
  std::int32_t child[2] = {-1, -1};  // indices into the same arena; -1: none
  bool leaf = false;
  bool forced = false;        // leaf made by the depth cap or unsplittable centroids
};
static_assert(sizeof(TmpNode) == 48);

/// A node of a subtree's arena, 32 bytes (TmpNode's 48 less what only the builder needs: the
/// depth, kept on its stack, and the range of an inner node): its box, and an inner node's
/// first child (the two children sit next to each other) or a leaf's range of the record array.
struct SubNode {
  static constexpr std::uint32_t kInner = ~0u;  // b of an inner node
  float lo[3];
  std::uint32_t a;  // inner: the first child's index in the arena; leaf: the first record
  float hi[3];
  std::uint32_t b;  // inner: kInner; leaf: count << 1 | forced
  static SubNode inner(const FastBox& box, std::size_t first_child) {
    return make(box, static_cast<std::uint32_t>(first_child), kInner);
  }
  static SubNode leaf(const FastBox& box, std::uint32_t begin, std::uint32_t count, bool forced) {
    return make(box, begin, count << 1 | (forced ? 1u : 0u));
  }
  bool is_leaf() const { return b != kInner; }
  std::uint32_t count() const { return b >> 1; }
  bool forced() const { return (b & 1u) != 0; }
  Box box() const {
    Box r;
    r.lo = {lo[0], lo[1], lo[2]};
    r.hi = {hi[0], hi[1], hi[2]};
    return r;
  }

private:
  static SubNode make(const FastBox& box, std::uint32_t a, std::uint32_t b) {
    SubNode n;
    for (int k = 0; k < 3; ++k) {
      n.lo[k] = box.lo[k];
      n.hi[k] = box.hi[k];
    }
    n.a = a;
    n.b = b;
    return n;
  }
};
static_assert(sizeof(SubNode) == 32 && std::is_trivially_copyable_v<SubNode>);

/// The build's storage for its subtrees' nodes: raw memory (no node written until a subtree
/// task writes it, so its pages are first touched there), allocated by the thread that calls the
/// builder. The subtree tasks run on the pool's workers; arenas of their own would come from the
/// workers' heaps (glibc: one arena per thread), where the memory they free stays and the calling
/// thread's later arrays (the flatten's, the layouts', a leaf variant's) cannot reuse it. One
/// block from the calling thread's heap returns there, for the next build and the layouts.
class NodeBlock {
public:
  NodeBlock() = default;
  NodeBlock(NodeBlock&& o) noexcept : p_(std::move(o.p_)), cap_(std::exchange(o.cap_, 0)) {}
  NodeBlock& operator=(NodeBlock&& o) noexcept {
    p_ = std::move(o.p_);
    cap_ = std::exchange(o.cap_, 0);
    return *this;
  }
  /// Room for `bytes` bytes (the contents not kept when it grows).
  void* ensure_bytes(std::size_t bytes) {
    if (bytes > cap_) {
      p_.reset();
      p_.reset(static_cast<unsigned char*>(::operator new(bytes)));
      cap_ = bytes;
    }
    return p_.get();
  }
  /// Room for `n` TmpNodes.
  TmpNode* ensure(std::size_t n) { return static_cast<TmpNode*>(ensure_bytes(n * sizeof(TmpNode))); }
  void* data() const { return p_.get(); }
  std::size_t capacity_bytes() const { return cap_; }

private:
  struct Free {
    void operator()(unsigned char* p) const { ::operator delete(static_cast<void*>(p)); }
  };
  std::unique_ptr<unsigned char, Free> p_;
  std::size_t cap_ = 0;
};
static_assert(std::is_trivially_copyable_v<TmpNode> && std::is_trivially_destructible_v<TmpNode>);

/// A subtree task's arena: up to `cap` nodes of the build's NodeBlock, grown by add and never
/// moved. A binary tree over n records has at most 2n - 1 nodes, so the subtree of records
/// [b, e) takes the block's nodes [2b, 2e) (Arenas::arena_for): the subtrees' ranges are
/// disjoint, and where a subtree's nodes lie does not depend on which task built it or when.
class SubArena {
public:
  SubArena() = default;
  SubArena(SubNode* p, std::size_t cap) : p_(p), cap_(cap) {}
  std::size_t size() const { return n_; }
  bool empty() const { return n_ == 0; }
  SubNode& operator[](std::size_t i) { return p_[i]; }
  const SubNode& operator[](std::size_t i) const { return p_[i]; }
  /// Appends `k` nodes, unwritten (the caller writes each), and returns the first one's index.
  std::size_t add(std::size_t k) {
    if (cap_ - n_ < k) throw Error("internal: a subtree's arena holds more than 2n - 1 nodes");
    const std::size_t first = n_;
    n_ += k;
    return first;
  }
  void clear() { n_ = 0; }

private:
  SubNode* p_ = nullptr;
  std::size_t n_ = 0, cap_ = 0;
};

/// A builder's result before flattening: the top of the tree in `upper`; an upper node whose
/// subtree was built by its own task names that task's arena in subtree_of (else -1), whose
/// node 0 stands for it. Every inner node of a subtree's arena has two children (the builders
/// split a node into two or make it a leaf), so an arena of n nodes holds (n - 1) / 2 inner
/// nodes and (n + 1) / 2 leaves (flatten counts so); only the upper root may have one child.
/// The subtrees' arenas are runs of `block` (2 SubNodes a record, 64 bytes: BuildContext keeps it).
struct Arenas {
  std::vector<TmpNode> upper;
  NodeBlock block;
  std::vector<SubArena> subtrees;
  std::vector<std::int32_t> subtree_of;
  /// The arena of the subtree below upper node `top` (its records' run of `block`, which must
  /// have room for 2 nodes a record of the build), empty.
  SubArena arena_for(const TmpNode& top) const {
    return SubArena(static_cast<SubNode*>(block.data()) + 2 * std::size_t(top.begin), 2 * std::size_t(top.end - top.begin));
  }
};

/// What a BuildContext (accel.h) holds between builds: a build's working arrays (taken at its
/// start, given back when it returns) and a build's output arrays (given back when its Accel is
/// destroyed). Of two arrays for one place the one of larger capacity is kept, so it holds at
/// most one build's worth of each, the largest. take() hands an array out empty, its capacity
/// kept; a build sizes it without value-initialising (RawVector, AlignedVector of Tri and Node4)
/// or overwrites every element, so the bytes built do not depend on what it held.
struct BuildContext_Store {
  RawVector<PrimRef> prims, scratch;
  Arenas arenas;
  std::vector<Bvh2::Node> nodes;
  std::vector<Box> leaf_boxes;
  std::vector<Leaf> leaves;
  AlignedVector<Tri> tris;
  AlignedVector<Node4> node4;
};

}  // namespace mbvh::build

namespace mbvh {

struct BuildContext::Impl {
  mutable std::mutex m;
  build::BuildContext_Store s;
  template <class V>
  V take(V build::BuildContext_Store::*slot) {
    std::lock_guard<std::mutex> lock(m);
    V v = std::move(s.*slot);
    s.*slot = V();
    v.clear();
    return v;
  }
  template <class V>
  void give(V build::BuildContext_Store::*slot, V&& v) {
    std::lock_guard<std::mutex> lock(m);
    if (v.capacity() > (s.*slot).capacity()) s.*slot = std::move(v);
    V().swap(v);
  }
  build::Arenas take_arenas();
  void give_arenas(build::Arenas&& a);
  std::size_t bytes() const;
};

}  // namespace mbvh

namespace mbvh::build {

/// The array a build uses for `slot`: the context's (empty, capacity kept), or a new one.
template <class V>
V take_from(const BuildOptions& opt, V BuildContext_Store::*slot) {
  return opt.context ? opt.context->impl().take(slot) : V();
}
/// Gives a build's array back to its context (kept if larger than what it holds), or frees it.
template <class V>
void give_back(const BuildOptions& opt, V BuildContext_Store::*slot, V& v) {
  if (opt.context) opt.context->impl().give(slot, std::move(v));
  else V().swap(v);
}

/// The root of `upper` made an inner node: a one-leaf tree gets a root with one leaf child.
inline void make_root_inner(std::vector<TmpNode>& upper) {
  if (!upper[0].leaf) return;
  TmpNode leaf = upper[0];
  leaf.depth = 1;
  upper[0].leaf = false;
  upper[0].forced = false;
  upper[0].child[0] = static_cast<std::int32_t>(upper.size());
  upper.push_back(leaf);
}

/// Which subtree job starts at each of `upper_size` upper nodes: jobs[j]'s entry is j, the
/// others' -1 (Arenas::subtree_of).
inline void subtree_of_jobs(std::vector<std::int32_t>& of, std::size_t upper_size, const std::vector<std::size_t>& jobs) {
  of.assign(upper_size, -1);  // into `of`'s own capacity (a kept BuildContext's Arenas::subtree_of)
  for (std::size_t j = 0; j < jobs.size(); ++j) of[jobs[j]] = static_cast<std::int32_t>(j);
}

/// The subtree jobs (jobs[j]: the upper node it starts from) largest first by their records,
/// ties in job order: the order only spreads the work over the pool (a large job started last
/// would run alone at the end); what a job writes does not depend on it.
inline std::vector<std::size_t> largest_first(const std::vector<TmpNode>& upper, const std::vector<std::size_t>& jobs) {
  std::vector<std::size_t> order(jobs.size());
  for (std::size_t j = 0; j < jobs.size(); ++j) order[j] = j;
  std::stable_sort(order.begin(), order.end(), [&](std::size_t x, std::size_t y) {
    return upper[jobs[x]].end - upper[jobs[x]].begin > upper[jobs[y]].end - upper[jobs[y]].begin;
  });
  return order;
}

/// Runs `run(j)` for every job j of `order` (largest_first's) on the pool, one job a task, in
/// that order; progress goes from 0.25 to 0.95 as they finish.
template <class Run>
void run_subtree_jobs(const std::vector<std::size_t>& order, const BuildOptions& opt, Run&& run) {
  std::atomic<std::size_t> built{0};
  parallel_for(order.size(), 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t o = b; o < e; ++o) {
      run(order[o]);
      if (opt.progress) opt.progress(0.25 + 0.7 * static_cast<double>(++built) / static_cast<double>(order.size()));
    }
  });
}

/// Flattens the arenas depth-first into `out` (record 0 = root, which is always an inner node)
/// and `leaves` (in record order: a leaf's triangles are its range of the record array); the
/// subtrees side by side on up to `threads` workers, the same bytes at any count.
void flatten(const Arenas& a, Bvh2& out, std::vector<Leaf>& leaves, unsigned threads);

/// The square of twice the triangle's area: its edges' cross product, in double, squared (no
/// square root; the squares of float products cannot underflow a double). 0: degenerate.
inline double twice_area_sq(const Vec3f& a, const Vec3f& bb, const Vec3f& c) {
  const double e1[3] = {double(bb.x) - a.x, double(bb.y) - a.y, double(bb.z) - a.z};
  const double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
  const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2], cz = e1[0] * e2[1] - e1[1] * e2[0];
  return cx * cx + cy * cy + cz * cz;
}

/// Whether the triangle has area (its edges' cross product, in double, is not zero): the build
/// keeps the others out of leaves.
inline bool has_area(const Vec3f& a, const Vec3f& bb, const Vec3f& c) { return twice_area_sq(a, bb, c) != 0; }

/// twice_area_sq below which a triangle with area is too small to trace (accel.h kMinTriangleArea).
constexpr double kMinTwiceAreaSq = 4.0 * double(kMinTriangleArea) * double(kMinTriangleArea);

/// Whether a triangle of twice_area_sq `a2` has area but less than kMinTriangleArea.
inline bool too_small(double a2) { return a2 > 0 && a2 < kMinTwiceAreaSq; }

/// The Error of Accel::build and Accel::refit (`who`: "" or "refit: ") for triangle `prim` of
/// `scene`, too small to trace exactly: its index (and geometry), area, edge lengths and the limit.
[[noreturn]] void throw_too_small(const Scene& scene, std::uint32_t prim, const char* who);

/// Accel::build's records: one per non-degenerate triangle, in scene order, and the bounds of
/// their boxes (`root`) and of their centroids (`croot`).
struct PrimRefs {
  RawVector<PrimRef> prims;
  FastBox root, croot;
  std::size_t degenerate = 0;  ///< triangles kept out of leaves (zero area)
};

/// The record pass of Accel::build on up to `threads` workers (prim_refs.cpp), with the checks a
/// build makes of its scene: Scene::validate's, no triangle too small to trace, every coordinate
/// in the exactly traced range (accel.h), a triangle with area. Throws Error naming the first fault.
/// `storage`: the records' array to reuse (emptied; BuildContext), or none.
PrimRefs make_prim_refs(const Scene& scene, unsigned threads, RawVector<PrimRef>&& storage = {});

/// The leaf-ordered triangle records: tris[i] (sized by the caller) is the scene's triangle that
/// order[i] names, a prim id (SBVH) or a record (binned SAH, LBVH).
void fill_tris(const Scene& scene, const RawVector<PrimRef>& order, AlignedVector<Tri>& tris, unsigned threads);
void fill_tris(const Scene& scene, const std::vector<std::uint32_t>& order, AlignedVector<Tri>& tris, unsigned threads);

/// The record of a triangle: the box of its three vertices.
inline PrimRef prim_ref(const Vec3f& a, const Vec3f& b, const Vec3f& c, std::uint32_t prim) {
  PrimRef r;
  r.lo[0] = std::min(std::min(a.x, b.x), c.x);
  r.lo[1] = std::min(std::min(a.y, b.y), c.y);
  r.lo[2] = std::min(std::min(a.z, b.z), c.z);
  r.hi[0] = std::max(std::max(a.x, b.x), c.x);
  r.hi[1] = std::max(std::max(a.y, b.y), c.y);
  r.hi[2] = std::max(std::max(a.z, b.z), c.z);
  r.prim = prim;
  r.pad = 0;
  return r;
}

/// The triangle record of the leaf-ordered array: three vertex rows, the prim id in v0[3].
inline void fill_tri(Tri& d, const Vec3f& a, const Vec3f& b, const Vec3f& c, std::uint32_t prim) {
  const Vec3f* v[3] = {&a, &b, &c};
  float* rows[3] = {d.v0, d.v1, d.v2};
  for (int k = 0; k < 3; ++k) {
    rows[k][0] = v[k]->x;
    rows[k][1] = v[k]->y;
    rows[k][2] = v[k]->z;
    rows[k][3] = 0.0f;
  }
  std::memcpy(&d.v0[3], &prim, 4);
}

/// The box of a triangle record: the min and max of its three vertex rows (as prim_ref's).
inline Box tri_box(const Tri& t) {
  Box b;
  b.lo = {std::min(std::min(t.v0[0], t.v1[0]), t.v2[0]), std::min(std::min(t.v0[1], t.v1[1]), t.v2[1]),
          std::min(std::min(t.v0[2], t.v1[2]), t.v2[2])};
  b.hi = {std::max(std::max(t.v0[0], t.v1[0]), t.v2[0]), std::max(std::max(t.v0[1], t.v1[1]), t.v2[1]),
          std::max(std::max(t.v0[2], t.v1[2]), t.v2[2])};
  return b;
}

/// SAH price of testing `n` triangles: blocks of `leaf_block` (BuildOptions::leaf_block).
inline float blocks(std::uint32_t n, unsigned leaf_block) {
  const std::uint32_t b = std::max(leaf_block, 1u);
  return static_cast<float>((n + b - 1) / b);
}

/// The bytes hash_build hashes in blocks of kHashBlock, each on its own (in parallel), then the
/// blocks' hashes in order: the same value at any thread count.
inline constexpr std::size_t kHashBlock = std::size_t(1) << 20;

/// Accel::hash of a build: its nodes, leaves and triangles (Accel::hash's contract). With
/// `tri_hashes`, the triangles' blocks are not read: tri_hashes[k] must be hash_bytes of bytes
/// [k kHashBlock, (k + 1) kHashBlock) of the triangle array (the last block shorter), as refit
/// computes them while the triangles it writes are still in cache.
std::uint64_t hash_build(const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned threads,
                         const std::uint64_t* tri_hashes = nullptr);

/// Nodes (or leaves) a run of the SAH statistics' sums holds: each run summed on its own, the
/// runs' sums added in order, so a statistic has the same bits at any thread count.
inline constexpr std::size_t kSahRun = 16384;

/// The sum of node(i) for i < nodes and leaf(i) for i < leaves, in runs of kSahRun on up to
/// `threads` workers, the runs' sums added in order (the SAH statistics of every layout).
template <class NodeTerm, class LeafTerm>
double sum_in_runs(std::size_t nodes, NodeTerm node, std::size_t leaves, LeafTerm leaf, unsigned threads) {
  const std::size_t node_runs = (nodes + kSahRun - 1) / kSahRun, leaf_runs = (leaves + kSahRun - 1) / kSahRun;
  std::vector<double> part(node_runs + leaf_runs);
  parallel_for(part.size(), 1, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t r = lo; r < hi; ++r) {
      double c = 0;
      if (r < node_runs) {
        const std::size_t e = std::min(nodes, (r + 1) * kSahRun);
        for (std::size_t i = r * kSahRun; i < e; ++i) c += node(i);
      } else {
        const std::size_t f = (r - node_runs) * kSahRun, e = std::min(leaves, f + kSahRun);
        for (std::size_t i = f; i < e; ++i) c += leaf(i);
      }
      part[r] = c;
    }
  });
  double cost = 0;
  for (const double c : part) cost += c;
  return cost;
}

/// LayoutStats::sah_cost of a binary tree: nodes priced at `ct`, triangles at 1 (summed in runs
/// of kSahRun on up to `threads` workers).
double sah_of_binary(const Bvh2& b, const std::vector<Leaf>& leaves, float ct, unsigned threads = 1);

/// make_mbvh4 (layouts.h) into `storage` (emptied; its capacity reused: BuildContext).
Mbvh4 make_mbvh4(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads, AlignedVector<Node4>&& storage);

/// The loops of the binned SAH's binning and partitions: `best` runs the AVX2 ones where the CPU
/// has AVX2 (x86-64: avx2_kernels.h), `baseline` always the SSE2 ones (the portable ones where
/// there is no SSE2). The same bytes either way. Process-wide: for the tests that compare the two.
enum class SahKernels { best, baseline };
void set_sah_kernels(SahKernels k);

/// The builders: reorder `prims` into leaf order and fill the arenas. `root` bounds every record,
/// `croot` their centroids. Deterministic: the same arenas at any opt.threads.
/// build_binned_sah's `scratch`: room for prims.size() records its partitions may overwrite (the
/// caller's array that is written after the build, e.g. the triangle records), or null: an
/// array of its own (or the context's).
void build_binned_sah(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                      Arenas& out, PrimRef* scratch = nullptr);
/// build_lbvh writes the flattened tree itself, the bytes flatten would write from its arenas:
/// `tree`'s nodes and leaf boxes, `leaves`, largest_leaf and forced_leaves (each subtree built
/// straight into a compact form in spare bytes of `scratch`, then moved into place: no subtree
/// arenas, no flatten walk; `out.block` only for a subtree too large for its spare bytes);
/// `out.upper` holds the top of the tree. Its `scratch`: room for 48 bytes a record (e.g. the
/// triangle records' array, written after the build) for its sort and subtrees, or null: an
/// array of its own.
void build_lbvh(RawVector<PrimRef>& prims, const FastBox& root, const FastBox& croot, const BuildOptions& opt,
                Arenas& out, Bvh2& tree, std::vector<Leaf>& leaves, PrimRef* scratch = nullptr);

}  // namespace mbvh::build

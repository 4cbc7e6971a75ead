// SPDX-License-Identifier: MIT
// layouts.h — the build's private structures behind mbvh/accel.h: the binary BVH, the MBVH2/4/8
// layouts and their views, the SIMD triangle packs, the collapse and validation functions, and
// Accel's state (Accel::Impl). Backends and tools of this repository include it; users do not.
#pragma once
#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <new>
#include <type_traits>
#include <utility>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/mbvh_layout.h"

namespace mbvh {

/// The binary BVH: inner nodes in depth-first order (record 0 = root; children before siblings'
/// subtrees), each child a reference as in mbvh_layout.h.
struct Bvh2 {
  struct Node {
    Box box;             ///< the node's own box
    std::int32_t child[2];
    std::int32_t parent;
    std::uint32_t height;  ///< binary levels below this node to its deepest leaf
  };
  std::vector<Node> nodes;
  std::vector<Box> leaf_boxes;
  std::size_t forced_leaves = 0;   ///< leaves made by the depth cap or unsplittable centroids
  std::size_t largest_leaf = 0;
  std::size_t degenerate = 0;      ///< triangles kept out of leaves (zero area)
  const Box& box(std::int32_t ref) const { return ref >= 0 ? nodes[static_cast<std::size_t>(ref)].box : leaf_boxes[static_cast<std::size_t>(~ref)]; }
};

struct Mbvh2 {
  AlignedVector<Node2> nodes;
  LayoutStats stats;
};

struct Mbvh4 {
  AlignedVector<Node4> nodes;
  LayoutStats stats;
};

struct Mbvh8 {
  AlignedVector<Node8> nodes;
  LayoutStats stats;
};

/// The MBVH4 layout's 16-wide view (mbvh_layout.h, Node4W): same topology and references.
struct Mbvh4Wide {
  AlignedVector<Node4W> nodes;
};

/// The leaves' triangles as 4-wide SoA packs (mbvh_layout.h, Tri4) for SIMD leaf tests:
/// leaves[i] = (first pack, triangle count) of leaf i, its triangles those of Accel::leaves()[i]
/// in the same order.
struct TriPacks {
  AlignedVector<Tri4> packs;
  std::vector<Leaf> leaves;
  /// The `fast` precision's copy of `packs`, laid out for Möller–Trumbore (make_mt_packs): made on
  /// first use (thread-safe), so only a fast trace pays its memory.
  const AlignedVector<Tri4>& mt() const;
  /// Makes mt() again from `packs` where it was made (refit moved their vertices).
  void refresh_mt();
  /// mt()'s bytes where it was made, else 0 (Accel::memory).
  std::size_t mt_bytes() const { return mt_ ? mt_->packs.size() * sizeof(Tri4) : 0; }

private:
  struct Mt {
    std::once_flag once;
    AlignedVector<Tri4> packs;
  };
  std::unique_ptr<Mt> mt_ = std::make_unique<Mt>();
};

/// A leaf policy's variant of the one build (TraceOptions::leaf_block; leaf_variant.cpp): the
/// binary tree with subtrees regrouped into leaves where the SAH prices a leaf in blocks of
/// `block` triangles, over the build's own triangles in the build's order, and its layouts and
/// SIMD packs made on first use (thread-safe, as Accel's own); its MBVH4 and MBVH8 by the
/// SAH-optimal collapse (make_mbvh4_sah, make_mbvh8_sah). The regrouped tree is not kept (only a
/// collapse reads it): tree() makes it again from the build's, the same bytes every time.
struct LeafVariant {
  unsigned block = 1;
  float node_cost = 1;  ///< the build's BuildOptions::traversal_cost
  unsigned threads = 0;  ///< the build's BuildOptions::threads (the layouts' collapses and checks)
  unsigned max_leaf = 1;  ///< the largest regrouped leaf (regroup_leaves)
  /// The build's tree, leaves and triangles this variant regroups: the Accel's own (refit drops the
  /// variants before it changes them).
  const Bvh2* src = nullptr;
  const std::vector<Leaf>* src_leaves = nullptr;
  const AlignedVector<Tri>* src_tris = nullptr;
  std::vector<Leaf> leaves;    ///< the regrouped leaves, in the order tree() references them
  std::size_t largest_leaf = 0;  ///< triangles of its largest leaf
  /// The regrouped binary tree (its leaf i is leaves[i]): regroup_leaves of the build's, made at
  /// each call (O(nodes)).
  Bvh2 tree() const;
  const Mbvh2& mbvh2() const;
  const Mbvh4& mbvh4() const;
  const Mbvh8& mbvh8() const;
  /// Its MBVH4's 16-wide view (the cpu backend's MIC path reads it beside the MBVH4 nodes).
  const Mbvh4Wide& mbvh4_wide() const;
  const TriPacks& tri_packs(const AlignedVector<Tri>& tris) const;
  void make_layout(Layout l) const;  ///< makes layout `l` now (as Accel::make_layout)
  /// Layout `l`'s nodes (Node2, Node4 or Node8) with every leaf reference replaced by
  /// ~(first pack << 3 | count - 1) (TraceView::packed_refs), made on first use; nullptr when a
  /// leaf holds more than 8 triangles (a leaf the depth cap forced) or the packs pass 2^28 - 2.
  const void* packed_nodes(Layout l, const AlignedVector<Tri>& tris) const;
  /// The bytes of what has been made on first use so far (Accel::memory): layouts and packed-reference
  /// copies (nodes), packs and their leaf table (packs).
  struct Bytes {
    std::size_t nodes = 0, packs = 0;
  };
  Bytes bytes() const;

private:
  mutable std::once_flag once2_, once4_, once8_, once4w_, oncep_, oncek_[3];
  mutable Mbvh2 m2_;
  mutable Mbvh4 m4_;
  mutable Mbvh4Wide m4w_;
  mutable Mbvh8 m8_;
  mutable TriPacks packs_;
  mutable bool packable_ = false;  ///< every leaf fits a packed reference (set with packs_)
  mutable AlignedVector<Node2> k2_;
  mutable AlignedVector<Node4> k4_;
  mutable AlignedVector<Node8> k8_;
};

/// Regroups `bvh`'s subtrees into leaves where a leaf priced in blocks of `block` triangles (at
/// most `max_leaf`) costs no more than the subtree (node visits at `node_cost`); the root stays an
/// inner node. Only subtrees whose triangles are one contiguous range of distinct triangles (a
/// spatial-split build references one triangle from several leaves) are regrouped.
void regroup_leaves(const Bvh2& bvh, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned block,
                    unsigned max_leaf, float node_cost, Bvh2& out, std::vector<Leaf>& out_leaves);

/// Accel's state: what build, load and refit write, and the layouts made on first use.
struct Accel::Impl {
  BuildOptions opt_;
  Bvh2 bvh2_;
  AlignedVector<Tri> tris_;
  std::vector<Leaf> leaves_;
  Box bounds_;
  std::size_t scene_triangles_ = 0;
  /// Scene::geometry_offset(g) for g = 0 .. geometries: the prim ids of each geometry; {0, n}
  /// for an owned scene or a build loaded without its scene (Accel::load).
  std::vector<std::uint64_t> geometry_offsets_{0, 0};
  LayoutStats binary_stats_;
  /// Accel::hash, computed on its first call (a trace never needs it) unless refit or load
  /// wrote it: hash_ is valid once hash_known_ is set.
  mutable std::uint64_t hash_ = 0;
  mutable std::atomic<bool> hash_known_{false};
  mutable std::mutex hash_m_;
  std::uint64_t generation_ = 0;
  double refit_ms_ = 0;
  mutable std::once_flag once2_, once4_, once8_, once4w_, oncep_;
  mutable Mbvh2 mbvh2_;
  mutable Mbvh4 mbvh4_;
  mutable Mbvh8 mbvh8_;
  mutable Mbvh4Wide mbvh4w_;
  mutable TriPacks packs_;
  /// Leaf variants by block (Accel::leaf_variant), made on first use; refit drops them.
  mutable std::mutex variants_m_;
  mutable std::map<unsigned, std::unique_ptr<LeafVariant>> variants_;
};

/// Collapses a binary BVH into the layouts (host/core/bvh/collapse.cpp).
Mbvh2 make_mbvh2(const Bvh2& bvh, const std::vector<Leaf>& leaves);
/// The wide collapses run on up to `threads` workers (0: every hardware thread); the same bytes at
/// any count.
Mbvh4 make_mbvh4(const Bvh2& bvh, const std::vector<Leaf>& leaves, unsigned threads = 0);
Mbvh8 make_mbvh8(const Bvh2& bvh, const std::vector<Leaf>& leaves, unsigned threads = 0);
/// Completes a collapsed MBVH4: the cyclic sibling links (sib[k] = parent.child[(slot + 1 + k) &
/// 3]), the bitstack bits of its depth, and validate_layout on up to `threads` workers.
void finish_mbvh4(Mbvh4& m, std::size_t leaf_count, unsigned threads = 0);
/// The SAH-optimal MBVH8 collapse (wide_sah.cpp; Ylitie et al. 2017): leaves priced in blocks of
/// `block` triangles, node visits at `node_cost`; the greedy make_mbvh8 where it would exceed the
/// MBVH8 level cap; checked (validate_layout) on up to `threads` workers.
Mbvh8 make_mbvh8_sah(const Bvh2& bvh, const std::vector<Leaf>& leaves, unsigned block, float node_cost,
                     unsigned threads = 0);
/// The same for MBVH4 (with its cyclic sibling links), the greedy make_mbvh4 beyond its level cap.
Mbvh4 make_mbvh4_sah(const Bvh2& bvh, const std::vector<Leaf>& leaves, unsigned block, float node_cost,
                     unsigned threads = 0);
/// Rewrites the MBVH4 SoA records as the 16-wide view (a permutation of each record's words;
/// host/core/bvh/views.cpp).
Mbvh4Wide make_mbvh4_wide(const Mbvh4& m);
/// Packs each leaf's triangles four at a time (SoA), in leaf order (views.cpp).
TriPacks make_tri_packs(const AlignedVector<Tri>& tris, const std::vector<Leaf>& leaves);
/// The `fast` precision's packs (views.cpp), what Embree's Triangle4 and tinybvh's BVH8_CPU leaves
/// hold for Möller–Trumbore (1997): each triangle as v0 and its edges e1 = v1 - v0, e2 = v2 - v0
/// (the subtractions the test made per pass, the same bits), the slots of `p.packs` reused pass
/// by pass as the SIMD leaves read them (SimdKernelsT::leaf): a leaf's triangles k..k+7 while
/// k + 4 < count as one eight-lane block over its two slots (rows v0.x, v0.y, v0.z, e1.x, ...,
/// e2.z of 8 lanes, then the 8 prim ids: 320 bytes, so each row is one aligned load), the last
/// 1 to 4 as one Tri4 slot with rows v0, e1, e2 and its prim ids.
/// write_mt_packs writes it into `out` (resized only where its size differs: a refit rewrites the
/// copy in place).
void write_mt_packs(const TriPacks& p, AlignedVector<Tri4>& out);
inline AlignedVector<Tri4> make_mt_packs(const TriPacks& p) {
  AlignedVector<Tri4> out;
  write_mt_packs(p, out);
  return out;
}

/// Structural checks of a layout (host/core/bvh/validate.cpp): every reference in range, every
/// inner node referenced once by a node of smaller index (so descent always terminates), every
/// leaf once, parent and sibling links consistent. Throws Error naming the first broken node.
/// O(nodes). The wide layouts are checked on up to `threads` workers (0: every hardware thread;
/// a build passes its own count).
/// Whether an MBVH4 child's sibling links match its parent's other slots (the child in slot `s`).
inline bool sibling_links_ok(const Node4& ch, const Node4& p, int s) {
  for (int k = 0; k < 3; ++k)
    if (ch.sib[k] != p.child[(s + 1 + k) & 3]) return false;
  return true;
}
inline bool sibling_links_ok(const Node8&, const Node8&, int) { return true; }  // MBVH8 keeps none

/// validate_layout's check of wide node i (validate.cpp's wide_ok on the pool; the collapse as it
/// writes each node): every child is a node in (i, end) naming i as its parent, with matching
/// sibling links, listed once by i; every leaf reference is below `leaf_count` and marks its leaf
/// in `leaf_seen` (a relaxed store). Adds i's child and leaf references to `inner` and `leaf_refs`.
template <class N>
bool wide_node_ok(const N* nodes, std::size_t i, std::size_t end, std::uint8_t* leaf_seen, std::size_t leaf_count,
                  std::size_t& inner, std::size_t& leaf_refs) {
  constexpr int W = sizeof(N::child) / sizeof(N::child[0]);
  const N& p = nodes[i];
  bool good = true;
  for (int s = 0; s < W; ++s) {
    const std::int32_t c = p.child[s];
    if (c == MBVH_EMPTY) continue;
    if (c >= 0) {
      const std::size_t ci = static_cast<std::size_t>(c);
      if (ci <= i || ci >= end || nodes[ci].parent != static_cast<std::int32_t>(i) || !sibling_links_ok(nodes[ci], p, s))
        good = false;
      for (int t = 0; t < s; ++t) good = good && p.child[t] != c;
      ++inner;
    } else {
      const std::size_t li = static_cast<std::size_t>(~c);
      if (li < leaf_count) std::atomic_ref<std::uint8_t>(leaf_seen[li]).store(1, std::memory_order_relaxed);
      else good = false;
      ++leaf_refs;
    }
  }
  return good;
}

void validate_layout(const Mbvh2& m, std::size_t leaf_count);
void validate_layout(const Mbvh4& m, std::size_t leaf_count, unsigned threads = 0);
void validate_layout(const Mbvh8& m, std::size_t leaf_count, unsigned threads = 0);

/// A 64-bit hash of n bytes (FNV-1a's step over 64-bit words, then the tail bytes), continuing from
/// h (host/core/bvh/hash.cpp).
std::uint64_t hash_bytes(const void* p, std::size_t n, std::uint64_t h = 0xcbf29ce484222325ull);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// leaf_variant.cpp — a backend's leaf policy from the one build:
// the binary tree with subtrees regrouped into leaves where the SAH, with a leaf priced in blocks
// of B triangles (Embree's SAH "blocks": one SIMD leaf test covers B triangles), prices the leaf
// below the subtree; and the layouts made from it on first use. Nothing is rebuilt: the triangles,
// their leaf order and every box are the build's, a regrouped leaf is the subtree's contiguous
// range of triangles and its box the subtree's, so the variant traces the same triangles with
// exact, conservative boxes — only fewer, fuller leaves. O(nodes), deterministic.
#include <algorithm>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "host/core/bvh/builder.h"
#include "host/core/layouts.h"
#include "host/core/resources.h"
#include "host/core/trace/view.h"  // the packed leaf references
#include "mbvh/error.h"

namespace mbvh {

namespace {

struct Regrouper {
  const Bvh2& in;
  const std::vector<Leaf>& leaves;
  const AlignedVector<Tri>& tris;
  unsigned block, max_leaf;
  float node_cost;
  std::vector<std::uint32_t> first, count;  // per inner node: its triangle range (when contiguous)
  std::vector<char> as_leaf;                // per inner node: regrouped into one leaf
  Bvh2 out;
  std::vector<Leaf> out_leaves;

  // Whether the c triangles from f are distinct triangles (a spatial-split build references one
  // triangle from several leaves: never twice in one leaf, accel.h)
  bool distinct(std::uint32_t f, std::uint32_t c) const {
    std::uint32_t ids[64];
    const std::uint32_t n = std::min<std::uint32_t>(c, 64);
    for (std::uint32_t k = 0; k < n; ++k) std::memcpy(&ids[k], &tris[f + k].v0[3], 4);
    std::sort(ids, ids + n);
    return std::adjacent_find(ids, ids + n) == ids + n;
  }

  // -- bottom-up: inner nodes are in depth-first order (a child after its parent)
  void decide() {
    const std::size_t n = in.nodes.size();
    first.assign(n, 0);
    count.assign(n, 0);
    as_leaf.assign(n, 0);
    std::vector<float> cost(n, 0.0f);
    for (std::size_t i = n; i-- > 0;) {
      const Bvh2::Node& node = in.nodes[i];
      bool contiguous = true;
      std::uint32_t f = 0, c = 0;
      float children = 0;
      for (int side = 0; side < 2; ++side) {
        const std::int32_t ref = node.child[side];
        if (ref == MBVH_EMPTY) continue;
        std::uint32_t cf, cc;
        if (ref < 0) {
          const Leaf& l = leaves[static_cast<std::size_t>(~ref)];
          cf = l.first;
          cc = l.count;
          children += build::blocks(cc, block) * in.leaf_boxes[static_cast<std::size_t>(~ref)].half_area();
        } else {
          const std::size_t k = static_cast<std::size_t>(ref);
          cf = first[k];
          cc = count[k];
          contiguous = contiguous && (as_leaf[k] || count[k] != 0);
          children += cost[k];
        }
        if (c != 0 && cf != f + c) contiguous = false;
        if (c == 0) f = cf;
        c += cc;
      }
      const float area = node.box.half_area();
      const float split = node_cost * area + children;
      cost[i] = split;
      // count[k] == 0 marks a subtree whose triangles are not one range (never regrouped above)
      if (contiguous) {
        first[i] = f;
        count[i] = c;
      }
      if (i != 0 && contiguous && c != 0 && c <= max_leaf && distinct(f, c)) {  // the root stays inner
        const float leaf = build::blocks(c, block) * area;
        if (leaf <= split) {
          as_leaf[i] = 1;
          cost[i] = leaf;
        }
      }
    }
  }

  // -- the kept inner nodes and the leaves below `ref` (emit's counts), so that emit's arrays are
  //    allocated once at their size: grown by doubling, they would leave their outgrown copies as
  //    holes in the heap that the layouts made next cannot use
  void count_kept(std::int32_t ref, std::size_t& nodes, std::size_t& leaf_count) const {
    if (ref == MBVH_EMPTY) return;
    if (ref < 0 || as_leaf[static_cast<std::size_t>(ref)]) {
      ++leaf_count;
      return;
    }
    ++nodes;
    for (int side = 0; side < 2; ++side)
      count_kept(in.nodes[static_cast<std::size_t>(ref)].child[side], nodes, leaf_count);
  }

  // -- top-down: the kept inner nodes depth-first, as the build's flatten emits them
  std::int32_t emit(std::int32_t ref, std::int32_t parent, std::uint32_t& height) {
    if (ref == MBVH_EMPTY) {
      height = 0;
      return MBVH_EMPTY;
    }
    if (ref < 0 || as_leaf[static_cast<std::size_t>(ref)]) {
      Leaf l;
      Box b;
      if (ref < 0) {
        l = leaves[static_cast<std::size_t>(~ref)];
        b = in.leaf_boxes[static_cast<std::size_t>(~ref)];
      } else {
        l = Leaf{first[static_cast<std::size_t>(ref)], count[static_cast<std::size_t>(ref)]};
        b = in.nodes[static_cast<std::size_t>(ref)].box;
      }
      out_leaves.push_back(l);
      out.leaf_boxes.push_back(b);
      out.largest_leaf = std::max<std::size_t>(out.largest_leaf, l.count);
      height = 0;
      return ~static_cast<std::int32_t>(out_leaves.size() - 1);
    }
    const Bvh2::Node& s = in.nodes[static_cast<std::size_t>(ref)];
    const std::int32_t self = static_cast<std::int32_t>(out.nodes.size());
    out.nodes.push_back({s.box, {MBVH_EMPTY, MBVH_EMPTY}, parent, 0});
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side) {
      const std::int32_t c = emit(s.child[side], self, h[side]);
      out.nodes[static_cast<std::size_t>(self)].child[side] = c;
    }
    height = 1 + std::max(h[0], h[1]);
    out.nodes[static_cast<std::size_t>(self)].height = height;
    return self;
  }
};

}  // namespace

void regroup_leaves(const Bvh2& bvh, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned block,
                    unsigned max_leaf, float node_cost, Bvh2& out, std::vector<Leaf>& out_leaves) {
  Regrouper g{bvh, leaves, tris, std::max(block, 1u), std::min(std::max(max_leaf, 1u), 64u), node_cost, {}, {}, {}, {}, {}};
  if (!bvh.nodes.empty()) {
    g.decide();
    std::size_t nodes = 0, leaf_count = 0;
    g.count_kept(0, nodes, leaf_count);
    g.out.nodes.reserve(nodes);
    g.out.leaf_boxes.reserve(leaf_count);
    g.out_leaves.reserve(leaf_count);
    std::uint32_t h = 0;
    g.emit(0, MBVH_NONE, h);
  }
  g.out.forced_leaves = bvh.forced_leaves;
  g.out.degenerate = bvh.degenerate;
  out = std::move(g.out);
  out_leaves = std::move(g.out_leaves);
}

const LeafVariant& Accel::leaf_variant(unsigned block) const {
  require_hierarchy("leaf_variant");
  if (block < 2 || block > 64)  // block 1 is the build itself (trace_view traces it, not a variant)
    throw Error("leaf block " + std::to_string(block) + " is out of range (TraceOptions::leaf_block: 0 for the backend's own, or 1 to 64)");
  std::lock_guard<std::mutex> lock(impl_->variants_m_);
  std::unique_ptr<LeafVariant>& v = impl_->variants_[block];
  if (!v) {
    v = std::make_unique<LeafVariant>();
    v->block = block;
    v->node_cost = impl_->opt_.traversal_cost;
    v->threads = impl_->opt_.threads;
    // max leaf: the build's, but at least one full block (a regrouped leaf of B triangles costs
    // one test)
    v->max_leaf = std::max(impl_->opt_.max_leaf, block);
    v->src = &impl_->bvh2_;
    v->src_leaves = &impl_->leaves_;
    v->src_tris = &impl_->tris_;
    Bvh2 tree;
    regroup_leaves(impl_->bvh2_, impl_->leaves_, impl_->tris_, block, v->max_leaf, v->node_cost, tree, v->leaves);
    v->largest_leaf = tree.largest_leaf;
  }
  return *v;
}

void Accel::drop_leaf_variants() {
  std::lock_guard<std::mutex> lock(impl_->variants_m_);
  impl_->variants_.clear();
}

Bvh2 LeafVariant::tree() const {
  Bvh2 t;
  std::vector<Leaf> l;
  regroup_leaves(*src, *src_leaves, *src_tris, block, max_leaf, node_cost, t, l);
  return t;
}

const Mbvh2& LeafVariant::mbvh2() const {
  std::call_once(once2_, [this] {
    m2_ = make_mbvh2(tree(), leaves);
    release_free_heap();
  });
  return m2_;
}
const Mbvh4& LeafVariant::mbvh4() const {
  std::call_once(once4_, [this] {
    m4_ = make_mbvh4_sah(tree(), leaves, block, node_cost, threads);
    release_free_heap();
  });
  return m4_;
}
const Mbvh4Wide& LeafVariant::mbvh4_wide() const {
  std::call_once(once4w_, [this] { m4w_ = make_mbvh4_wide(mbvh4()); });
  return m4w_;
}
const Mbvh8& LeafVariant::mbvh8() const {
  std::call_once(once8_, [this] {
    m8_ = make_mbvh8_sah(tree(), leaves, block, node_cost, threads);
    release_free_heap();
  });
  return m8_;
}
void LeafVariant::make_layout(Layout l) const {
  if (l == Layout::mbvh2) mbvh2();
  else if (l == Layout::mbvh4) mbvh4();
  else mbvh8();
}
const TriPacks& LeafVariant::tri_packs(const AlignedVector<Tri>& tris) const {
  std::call_once(oncep_, [this, &tris] {
    packs_ = make_tri_packs(tris, leaves);
    packable_ = std::all_of(packs_.leaves.begin(), packs_.leaves.end(), [](const Leaf& f) { return packable(f); });
    release_free_heap();
  });
  return packs_;
}

LeafVariant::Bytes LeafVariant::bytes() const {
  auto of = [](const auto& v) { return v.size() * sizeof(v[0]); };
  Bytes b;
  b.nodes = of(leaves) + of(m2_.nodes) + of(m4_.nodes) + of(m8_.nodes) + of(m4w_.nodes) + of(k2_) + of(k4_) + of(k8_);
  b.packs = of(packs_.packs) + of(packs_.leaves) + packs_.mt_bytes();
  return b;
}

namespace {

// The packed reference of reference `ref` (leaves only; nodes, MBVH_EMPTY and the root's
// MBVH_NONE links are not passed here).
std::int32_t packed_ref(std::int32_t ref, const std::vector<Leaf>& leaf4) {
  if (ref >= 0 || ref == MBVH_EMPTY) return ref;
  return packed_leaf_ref(leaf4[static_cast<std::size_t>(~ref)]);
}

}  // namespace

const void* LeafVariant::packed_nodes(Layout l, const AlignedVector<Tri>& tris) const {
  const TriPacks& p = tri_packs(tris);
  if (!packable_) return nullptr;
  const int k = l == Layout::mbvh2 ? 0 : l == Layout::mbvh4 ? 1 : 2;
  std::call_once(oncek_[k], [&] {
    // the root's parent and sibling links are MBVH_NONE, every other link field a reference
    if (l == Layout::mbvh2) {
      k2_ = mbvh2().nodes;
      for (std::size_t i = 0; i < k2_.size(); ++i)
        for (int f = i == 0 ? 2 : 1; f < 4; ++f) k2_[i].link[f] = packed_ref(k2_[i].link[f], p.leaves);
    } else if (l == Layout::mbvh4) {
      k4_ = mbvh4().nodes;
      for (std::size_t i = 0; i < k4_.size(); ++i) {
        for (std::int32_t& c : k4_[i].child) c = packed_ref(c, p.leaves);
        if (i > 0)
          for (std::int32_t& c : k4_[i].sib) c = packed_ref(c, p.leaves);
      }
    } else {
      k8_ = mbvh8().nodes;
      for (Node8& n : k8_)
        for (std::int32_t& c : n.child) c = packed_ref(c, p.leaves);
    }
  });
  if (k == 0) return k2_.data();
  if (k == 1) return k4_.data();
  return k8_.data();
}

}  // namespace mbvh

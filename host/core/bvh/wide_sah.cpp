// SPDX-License-Identifier: MIT
// wide_sah.cpp — the SAH-optimal collapse of a binary BVH into MBVH4 and MBVH8 nodes: the dynamic program
// of Ylitie, Karras & Laine ("Efficient Incoherent Ray Traversal on GPUs Through Compressed Wide
// BVHs", HPG 2017, §3.1; their node quantisation is not used). For every binary node n and every
// slot budget j = 1..W it finds the cheapest way to hang n's subtree into j slots of a wide node:
// j = 1 makes n a wide node of its own, whose W slots its two children share; j > 1 dissolves n
// and gives its children k and j - k slots. The greedy top-down collapse (collapse.cpp) opens the
// largest child until a node is full, which leaves the nodes above small subtrees half empty;
// the program fills them where the SAH says so. Leaves stay the binary tree's (a slot each).
// O(nodes x W^2), deterministic. A result deeper than the layout's level cap (its bitstack word)
// falls back to the greedy collapse.
#include <algorithm>
#include <chrono>
#include <cstring>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/wide_node.h"
#include "host/core/layouts.h"
#include "host/core/trace/view.h"  // node_width

namespace mbvh {

namespace {

template <class N>
struct WideDp {
  static constexpr int W = node_width<N>();
  const Bvh2& b;
  const std::vector<Leaf>& leaves;
  unsigned block;
  float node_cost;
  // per binary node, j = 1..W: cost[j], and how it is reached: split[j] = k slots to child 0
  // (k + (j - k) = j), or 0 when j slots cost no less than j - 1 (take j - 1); split[1]: the
  // distribution of the node's own W slots
  struct Row {
    double cost[W + 1];
    std::uint8_t split[W + 1];
  };
  std::vector<Row> rows;
  AlignedVector<N>* out = nullptr;
  unsigned max_level = 0;
  double sah = 0, root_area = 1;

  double leaf_cost(std::int32_t ref) const {
    const std::size_t i = static_cast<std::size_t>(~ref);
    return build::blocks(leaves[i].count, block) * b.leaf_boxes[i].half_area();
  }
  double cost(std::int32_t ref, int j) const {  // j >= 1 slots for the subtree at ref
    if (ref < 0) return leaf_cost(ref);
    return rows[static_cast<std::size_t>(ref)].cost[j];
  }

  // cheapest split of j >= 2 slots between a node's children (an EMPTY second child: all to the first)
  double distribute(const Bvh2::Node& n, int j, std::uint8_t& best_k) const {
    if (n.child[1] == MBVH_EMPTY) {
      best_k = static_cast<std::uint8_t>(j);
      return cost(n.child[0], j);
    }
    double best = 0;
    best_k = 0;
    for (int k = 1; k < j; ++k) {
      const double c = cost(n.child[0], k) + cost(n.child[1], j - k);
      if (best_k == 0 || c < best) {
        best = c;
        best_k = static_cast<std::uint8_t>(k);
      }
    }
    return best;
  }

  void solve() {
    rows.resize(b.nodes.size());
    for (std::size_t i = b.nodes.size(); i-- > 0;) {  // children after parents (depth-first)
      const Bvh2::Node& n = b.nodes[i];
      Row& r = rows[i];
      r.cost[1] = node_cost * n.box.half_area() + distribute(n, W, r.split[1]);
      r.split[0] = 0;
      for (int j = 2; j <= W; ++j) {
        std::uint8_t k = 0;
        const double d = distribute(n, j, k);
        if (d < r.cost[j - 1]) {
          r.cost[j] = d;
          r.split[j] = k;
        } else {
          r.cost[j] = r.cost[j - 1];
          r.split[j] = 0;
        }
      }
    }
  }

  // the subtree at ref in at most j slots: appends its slot references (binary refs: leaves, or
  // binary nodes that become wide nodes)
  void expand(std::int32_t ref, int j, std::vector<std::int32_t>& slots) const {
    if (ref == MBVH_EMPTY) return;
    if (ref < 0 || j == 1) {
      slots.push_back(ref);
      return;
    }
    const Row& r = rows[static_cast<std::size_t>(ref)];
    while (j > 1 && r.split[j] == 0) --j;
    if (j == 1) {
      slots.push_back(ref);
      return;
    }
    const Bvh2::Node& n = b.nodes[static_cast<std::size_t>(ref)];
    const int k = r.split[j];
    expand(n.child[0], k, slots);
    expand(n.child[1], j - k, slots);
  }

  std::int32_t emit(std::int32_t bref, std::int32_t parent, unsigned level) {
    const Bvh2::Node& bn = b.nodes[static_cast<std::size_t>(bref)];
    std::vector<std::int32_t> slots;
    const int k = rows[static_cast<std::size_t>(bref)].split[1];
    expand(bn.child[0], k, slots);
    expand(bn.child[1], W - k, slots);
    const std::int32_t self = static_cast<std::int32_t>(out->size());
    out->emplace_back();
    std::int32_t none[W];  // the children's references are set as they are emitted, below
    for (int s = 0; s < W; ++s) none[s] = MBVH_EMPTY;
    const Box all = build::write_wide_node((*out)[static_cast<std::size_t>(self)], none, parent, [&](int s) {
      return s < static_cast<int>(slots.size()) ? b.box(slots[static_cast<std::size_t>(s)]) : Box();
    });
    sah += all.half_area() / root_area;
    for (std::size_t s = 0; s < slots.size(); ++s) {
      std::int32_t ref = slots[s];
      if (ref >= 0) ref = emit(ref, self, level + 1);
      else max_level = std::max(max_level, level + 1);
      (*out)[static_cast<std::size_t>(self)].child[s] = ref;
    }
    return self;
  }
};

}  // namespace

namespace {

// Runs the program for layout M (Mbvh4 or Mbvh8); false when the result exceeds level cap `cap`.
template <class M>
bool collapse_sah(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned block, float node_cost, unsigned cap,
                  const char* name, M& out) {
  using N = typename decltype(out.nodes)::value_type;
  WideDp<N> dp{b, leaves, std::max(block, 1u), node_cost, {}, nullptr, 0, 0, 1};
  dp.solve();
  out.nodes.reserve(b.nodes.size() / 3 + 1);
  dp.out = &out.nodes;
  dp.root_area = std::max(1e-30, static_cast<double>(b.nodes[0].box.half_area()));
  dp.emit(0, MBVH_NONE, 0);
  if (dp.max_level > cap) return false;
  for (std::size_t i = 0; i < leaves.size(); ++i)
    dp.sah += double(leaves[i].count) * b.leaf_boxes[i].half_area() / dp.root_area;
  LayoutStats& st = out.stats;
  st.layout = name;
  st.nodes = out.nodes.size();
  st.leaves = leaves.size();
  st.depth = dp.max_level;
  st.sah_cost = dp.sah;
  st.bytes = out.nodes.size() * sizeof(N);
  return true;
}

using Clock = std::chrono::steady_clock;
double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

}  // namespace

Mbvh8 make_mbvh8_sah(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned block, float node_cost,
                     unsigned threads) {
  const auto t0 = Clock::now();
  Mbvh8 out;
  if (b.nodes.empty() || !collapse_sah(b, leaves, block, node_cost, MBVH_MBVH8_LEVEL_CAP, "mbvh8", out))
    return make_mbvh8(b, leaves, threads);  // the bitstack's cap wins
  out.stats.bitstack_bits = 8 * out.stats.depth;  // 8 pending-slot bits per level (128-bit word)
  validate_layout(out, leaves.size(), threads);
  out.stats.build_ms = ms_since(t0);
  return out;
}

Mbvh4 make_mbvh4_sah(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned block, float node_cost,
                     unsigned threads) {
  const auto t0 = Clock::now();
  Mbvh4 out;
  if (b.nodes.empty() || !collapse_sah(b, leaves, block, node_cost, MBVH_MBVH4_LEVEL_CAP, "mbvh4", out))
    return make_mbvh4(b, leaves, threads);
  finish_mbvh4(out, leaves.size(), threads);
  out.stats.build_ms = ms_since(t0);
  return out;
}

}  // namespace mbvh

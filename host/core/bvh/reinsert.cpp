// SPDX-License-Identifier: MIT
// reinsert.cpp — insertion-based optimisation of the high-quality build's binary BVH
// (Bittner, Hapala & Havran, "Fast Insertion-Based Optimization of Bounding Volume Hierarchies",
// CGF 2013; Meister & Bittner, "Parallel Reinsertion for Bounding Volume Hierarchy
// Optimization", CGF (Eurographics) 2018).
//
// A subtree N is taken out of the tree with its parent P (N's sibling takes P's place, the boxes
// above are refit), then put back as the sibling of the node X where that costs least: X's place
// gets a new inner node (P's record, reused) over X and N. With the leaves fixed, the SAH changes
// only by the inner nodes' areas: taking N out saves A(P) plus what its ancestors shrink; putting
// it beside X costs A(X ∪ N) plus the induced cost, what X's ancestors grow, Σ A(Y ∪ N) − A(Y).
// The best X is found by branch and bound from the root (Bittner et al. 2013, §4.2): candidates
// in order of their induced cost, a subtree skipped where its induced cost plus A(N) (a lower
// bound of any insertion below) is no better than the best found. N's old place is one of the
// candidates, so a move never raises the SAH; N is moved only where the cost falls.
//
// Each round takes the nodes (inner nodes and leaves) in order of decreasing area — the ones whose
// cost is largest (Meister & Bittner 2018 reinsert every node; the largest are where the top-down
// build errs most) — and reinserts them one after another; rounds repeat while they pay, each
// after the first taking only the nodes where the last one changed the tree. Leaves are
// moved whole: their triangles and boxes do not change. The depth cap holds: X qualifies only
// where X's and N's deepest leaves stay within opt.depth_cap levels after the insertion.
// Sequential, every choice a function of the tree alone: the same tree at any thread count.
#include "host/core/bvh/reinsert.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "mbvh/error.h"

namespace mbvh::build {
namespace {

// A node of the optimised tree, what the search reads (32 bytes, two to a cache line): inner
// nodes keep their Bvh2 index, leaf l is node ninner + l. Parents and heights are kept aside.
struct RNode {
  float lo[3], hi[3];
  std::int32_t child[2];  // -1 for a leaf
};

// Half the box's area, in double: the costs are sums of differences of areas.
inline double area_of(const float* lo, const float* hi) {
  const double e0 = double(hi[0]) - lo[0], e1 = double(hi[1]) - lo[1], e2 = double(hi[2]) - lo[2];
  return e0 * e1 + e1 * e2 + e2 * e0;
}
inline double area_of(const RNode& a) { return area_of(a.lo, a.hi); }

inline double union_area(const RNode& a, const RNode& b) {
  float lo[3], hi[3];
  for (int k = 0; k < 3; ++k) {
    lo[k] = std::min(a.lo[k], b.lo[k]);
    hi[k] = std::max(a.hi[k], b.hi[k]);
  }
  return area_of(lo, hi);
}

class Reinserter {
public:
  Reinserter(const Bvh2& bvh, unsigned depth_cap) : ninner_(bvh.nodes.size()), cap_(depth_cap) {
    const std::size_t n = ninner_ + bvh.leaf_boxes.size();
    nodes_.resize(n);
    parent_.assign(n, -1);
    changed_.assign(n, 0);
    height_.assign(n, 0);
    for (std::size_t i = 0; i < ninner_; ++i) {
      const Bvh2::Node& s = bvh.nodes[i];
      RNode& t = nodes_[i];
      set_box(t, s.box);
      for (int k = 0; k < 2; ++k) {
        t.child[k] = s.child[k] >= 0 ? s.child[k] : static_cast<std::int32_t>(ninner_ + std::size_t(~s.child[k]));
        parent_[static_cast<std::size_t>(t.child[k])] = static_cast<std::int32_t>(i);
      }
      height_[i] = s.height;
    }
    for (std::size_t l = 0; l < bvh.leaf_boxes.size(); ++l) {
      RNode& t = nodes_[ninner_ + l];
      set_box(t, bvh.leaf_boxes[l]);
      t.child[0] = t.child[1] = -1;
    }
  }

  double inner_area() const {
    double s = 0;
    for (std::size_t i = 0; i < ninner_; ++i) s += area_of(nodes_[i]);
    return s;
  }

  // One round: every node below the root's children (after the first round only those that moved
  // or were refit in the last one, or whose parent or sibling was: where the tree changed; the
  // others keep the place their last search found), largest area first, taken out and put back
  // where it costs least. Returns the number moved.
  std::size_t round() {
    order_.clear();
    for (std::size_t i = 0; i < nodes_.size(); ++i) {
      const std::int32_t p = parent_[i];
      if (p < 0 || p == root_) continue;
      const std::int32_t sib = at(p).child[0] == static_cast<std::int32_t>(i) ? at(p).child[1] : at(p).child[0];
      if (!first_round_ && !changed_[i] && !changed_[static_cast<std::size_t>(p)] && !changed_[static_cast<std::size_t>(sib)]) continue;
      order_.push_back({area_of(nodes_[i]), static_cast<std::int32_t>(i)});
    }
    first_round_ = false;
    std::fill(changed_.begin(), changed_.end(), 0);
    std::sort(order_.begin(), order_.end(), [](const Ranked& a, const Ranked& b) {
      return a.area > b.area || (a.area == b.area && a.id < b.id);
    });
    std::size_t moved = 0;
    for (const Ranked& r : order_) moved += reinsert(r.id) ? 1 : 0;
    return moved;
  }

  // The tree depth-first (child 0 first), as the builders flatten theirs: inner nodes in `out`
  // (boxes from their RNode), leaves renumbered in that order with their boxes and triangles.
  void emit(const Bvh2& in, const std::vector<Leaf>& in_leaves, const std::vector<std::uint32_t>& in_prims, Bvh2& out,
            std::vector<Leaf>& leaves, std::vector<std::uint32_t>& prims) const {
    out.nodes.clear();
    out.leaf_boxes.clear();
    leaves.clear();
    prims.clear();
    out.nodes.reserve(ninner_);
    out.leaf_boxes.reserve(in_leaves.size());
    leaves.reserve(in_leaves.size());
    prims.reserve(in_prims.size());
    struct Item {
      std::int32_t id, parent;
      int side;
    };
    std::vector<Item> stack;
    stack.push_back({root_, MBVH_NONE, 0});
    while (!stack.empty()) {
      const Item it = stack.back();
      stack.pop_back();
      const RNode& t = at(it.id);
      std::int32_t ref;
      if (static_cast<std::size_t>(it.id) >= ninner_) {
        const std::size_t l = static_cast<std::size_t>(it.id) - ninner_;
        const Leaf& src = in_leaves[l];
        ref = ~static_cast<std::int32_t>(leaves.size());
        leaves.push_back({static_cast<std::uint32_t>(prims.size()), src.count});
        prims.insert(prims.end(), in_prims.begin() + src.first, in_prims.begin() + src.first + src.count);
        out.leaf_boxes.push_back(in.leaf_boxes[l]);
      } else {
        ref = static_cast<std::int32_t>(out.nodes.size());
        Bvh2::Node b;
        b.box.lo = {t.lo[0], t.lo[1], t.lo[2]};
        b.box.hi = {t.hi[0], t.hi[1], t.hi[2]};
        b.child[0] = b.child[1] = MBVH_EMPTY;
        b.parent = it.parent;
        b.height = height_[static_cast<std::size_t>(it.id)];
        out.nodes.push_back(b);
        stack.push_back({t.child[1], ref, 1});
        stack.push_back({t.child[0], ref, 0});
      }
      if (it.parent != MBVH_NONE) out.nodes[static_cast<std::size_t>(it.parent)].child[it.side] = ref;
    }
  }

  std::uint32_t height() const { return height_[static_cast<std::size_t>(root_)]; }

private:
  static void set_box(RNode& t, const Box& b) {
    t.lo[0] = b.lo.x;
    t.lo[1] = b.lo.y;
    t.lo[2] = b.lo.z;
    t.hi[0] = b.hi.x;
    t.hi[1] = b.hi.y;
    t.hi[2] = b.hi.z;
  }

  RNode& at(std::int32_t i) { return nodes_[static_cast<std::size_t>(i)]; }
  const RNode& at(std::int32_t i) const { return nodes_[static_cast<std::size_t>(i)]; }
  std::int32_t& parent(std::int32_t i) { return parent_[static_cast<std::size_t>(i)]; }
  std::uint32_t& height(std::int32_t i) { return height_[static_cast<std::size_t>(i)]; }

  // Recomputes the boxes and heights from inner node y up to the root (stopping where nothing
  // changes); returns the sum of the areas' decrease.
  double refit_up(std::int32_t y) {
    double saved = 0;
    for (; y >= 0; y = parent(y)) {
      RNode& t = at(y);
      const RNode& a = at(t.child[0]);
      const RNode& b = at(t.child[1]);
      float lo[3], hi[3];
      bool same = true;
      for (int k = 0; k < 3; ++k) {
        lo[k] = std::min(a.lo[k], b.lo[k]);
        hi[k] = std::max(a.hi[k], b.hi[k]);
        same = same && lo[k] == t.lo[k] && hi[k] == t.hi[k];
      }
      const std::uint32_t h = 1 + std::max(height(t.child[0]), height(t.child[1]));
      same = same && h == height(y);
      if (same) break;
      touched_.push_back(y);
      saved += area_of(t) - area_of(lo, hi);
      std::copy(lo, lo + 3, t.lo);
      std::copy(hi, hi + 3, t.hi);
      height(y) = h;
    }
    return saved;
  }

  static int side_of(const RNode& p, std::int32_t c) { return p.child[0] == c ? 0 : 1; }

  // Puts n back as X's sibling under inner node p (n on `side`), in X's place.
  void insert(std::int32_t n, std::int32_t x, std::int32_t p, int side) {
    const std::int32_t g = parent(x);
    if (g < 0) root_ = p;
    else at(g).child[side_of(at(g), x)] = p;
    RNode& pn = at(p);
    parent(p) = g;
    pn.child[side] = n;
    pn.child[1 - side] = x;
    parent(x) = p;
    parent(n) = p;
    height(p) = ~0u;  // forces refit_up to recompute it
    refit_up(p);
  }

  // The cheapest X to put n beside (its cost: A(X ∪ n) plus the induced cost), by branch and
  // bound, depth first: a node's children are priced when it is taken from the stack, the one
  // with the smaller cost explored first. Only positions costing less than `best_cost` on entry
  // are considered (-1: none).
  std::int32_t best_position(std::int32_t n, double& best_cost) {
    const RNode& nn = at(n);
    const double an = area_of(nn);
    const std::uint32_t hn = height(n);
    std::int32_t best = -1;
    auto consider = [&](std::int32_t x, double cost, std::uint32_t depth) {
      if (cost < best_cost && depth + 1 + std::max(height(x), hn) <= cap_) {
        best_cost = cost;
        best = x;
      }
    };
    const RNode& r = at(root_);
    const double root_cost = union_area(r, nn);
    consider(root_, root_cost, 0);
    stack_.clear();
    if (r.child[0] >= 0) stack_.push_back({root_cost - area_of(r), root_, 0});
    while (!stack_.empty()) {
      const Candidate c = stack_.back();
      stack_.pop_back();
      if (c.induced + an >= best_cost) continue;  // nothing below can beat the best
      const RNode& x = at(c.id);
      const RNode* ch[2] = {&at(x.child[0]), &at(x.child[1])};
      double cost[2];
      for (int k = 0; k < 2; ++k) {
        cost[k] = c.induced + union_area(*ch[k], nn);
        consider(x.child[k], cost[k], c.depth + 1);
      }
      const int first = cost[1] < cost[0] ? 1 : 0;  // pushed last, explored first
      for (int k : {1 - first, first}) {
        if (ch[k]->child[0] < 0) continue;
        const double below = cost[k] - area_of(*ch[k]);
        if (below + an < best_cost) stack_.push_back({below, x.child[k], c.depth + 1});
      }
    }
    return best;
  }

  // Takes n out (its parent P freed, its sibling in P's place) and puts it back where it costs
  // least; true if that is somewhere else.
  bool reinsert(std::int32_t n) {
    const std::int32_t p = parent(n);
    if (p < 0 || p == root_) return false;
    const int side = side_of(at(p), n);
    const std::int32_t s = at(p).child[1 - side];
    const std::int32_t g = parent(p);
    // -- out: the sibling takes P's place
    at(g).child[side_of(at(g), p)] = s;
    parent(s) = g;
    const double saved = area_of(at(p)) + refit_up(g);
    // -- back, where it costs least (its old place, beside s, if nowhere costs less)
    double cost = saved - 1e-9 * saved;  // what a move must beat: the cost of n's old place
    std::int32_t x = best_position(n, cost);
    const bool move = x >= 0 && x != s;
    if (!move) x = s;
    insert(n, x, p, side);
    if (move) {  // what the next round looks at: the nodes moved, their old and new places, the boxes refit
      for (std::int32_t t : touched_) changed_[static_cast<std::size_t>(t)] = 1;
      for (std::int32_t t : {n, x, s, p}) changed_[static_cast<std::size_t>(t)] = 1;
    }
    touched_.clear();
    return move;
  }

  struct Candidate {
    double induced;  // what the ancestors grow by, put beside this node's children
    std::int32_t id;
    std::uint32_t depth;
  };
  struct Ranked {
    double area;
    std::int32_t id;
  };

  std::size_t ninner_;
  unsigned cap_;
  std::int32_t root_ = 0;
  std::vector<RNode> nodes_;
  std::vector<std::int32_t> parent_;
  std::vector<std::uint32_t> height_;
  std::vector<std::uint8_t> changed_;  // moved or refit this round: where the next round looks
  bool first_round_ = true;
  std::vector<std::int32_t> touched_;  // the nodes refit by one reinsert
  std::vector<Ranked> order_;
  std::vector<Candidate> stack_;
};

constexpr unsigned kMaxRounds = 8;
// Rounds repeat while the last one lowered the inner nodes' area by at least this share (later
// rounds move few nodes: each costs about as much as the first).
constexpr double kMinRoundGain = 0.01;

}  // namespace

ReinsertStats reinsert(Bvh2& bvh, std::vector<Leaf>& leaves, std::vector<std::uint32_t>& prims, const BuildOptions& opt) {
  ReinsertStats st;
  // a root with one child (a one-leaf tree) or a tree too small to change: nothing to move
  if (bvh.nodes.size() < 3 || bvh.nodes[0].child[1] == MBVH_EMPTY || !(opt.traversal_cost > 0)) return st;
  Reinserter r(bvh, opt.depth_cap);
  st.inner_area_before = r.inner_area();
  double area = st.inner_area_before;
  while (st.rounds < kMaxRounds) {
    st.moved += r.round();
    ++st.rounds;
    const double now = r.inner_area();
    if (area - now < kMinRoundGain * area) break;
    area = now;
  }
  st.inner_area_after = r.inner_area();
  if (r.height() > opt.depth_cap)
    throw Error("internal: reinsertion made binary depth " + std::to_string(r.height()) + " beyond the cap");
  Bvh2 out;
  out.forced_leaves = bvh.forced_leaves;
  out.largest_leaf = bvh.largest_leaf;
  out.degenerate = bvh.degenerate;
  std::vector<Leaf> new_leaves;
  std::vector<std::uint32_t> new_prims;
  r.emit(bvh, leaves, prims, out, new_leaves, new_prims);
  bvh = std::move(out);
  leaves = std::move(new_leaves);
  prims = std::move(new_prims);
  return st;
}

}  // namespace mbvh::build

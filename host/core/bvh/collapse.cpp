// SPDX-License-Identifier: MIT
// collapse.cpp — the MBVH2 and MBVH4 layouts made from the one binary BVH, with the parent and
// sibling links the stackless bitstack traversal needs (Áfra & Szirmay-Kalos, "Stackless
// Multi-BVH Traversal for CPU, MIC and GPU Ray Tracing", CGF 2014; TRAVERSAL.md §2).
#include <algorithm>
#include <atomic>
#include <memory>
#include <bit>
#include <cstring>
#include <limits>
#include <chrono>

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/view.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

using Clock = std::chrono::steady_clock;

Box empty_box() { return Box(); }  // lo = +inf, hi = -inf: never hit (TRAVERSAL.md §2.1)

// The cyclic sibling links of MBVH4 node p's children: sib[k] = p.child[(slot + 1 + k) & 3].
void link_children(Node4* nodes, std::size_t p) {
  const Node4& n = nodes[p];
  for (int s = 0; s < 4; ++s)
    if (n.child[s] >= 0)
      for (int k = 0; k < 3; ++k) nodes[static_cast<std::size_t>(n.child[s])].sib[k] = n.child[(s + 1 + k) & 3];
}

double leaf_sah(const Bvh2& b, const std::vector<Leaf>& leaves, double root) {
  double c = 0;
  for (std::size_t i = 0; i < leaves.size(); ++i) c += double(leaves[i].count) * b.leaf_boxes[i].half_area() / root;
  return c;
}

}  // namespace

// MBVH2: the binary tree itself, both child boxes in the parent (Aila & Laine 2009).
Mbvh2 make_mbvh2(const Bvh2& b, const std::vector<Leaf>& leaves) {
  const auto t0 = Clock::now();
  Mbvh2 out;
  out.nodes.resize(b.nodes.size());
  for (std::size_t i = 0; i < b.nodes.size(); ++i) {
    const Bvh2::Node& s = b.nodes[i];
    Node2& d = out.nodes[i];
    const Box b0 = s.child[0] == MBVH_EMPTY ? empty_box() : b.box(s.child[0]);
    const Box b1 = s.child[1] == MBVH_EMPTY ? empty_box() : b.box(s.child[1]);
    d.c0[0] = b0.lo.x; d.c0[1] = b0.hi.x; d.c0[2] = b0.lo.y; d.c0[3] = b0.hi.y;
    d.c1[0] = b1.lo.x; d.c1[1] = b1.hi.x; d.c1[2] = b1.lo.y; d.c1[3] = b1.hi.y;
    d.zz[0] = b0.lo.z; d.zz[1] = b0.hi.z; d.zz[2] = b1.lo.z; d.zz[3] = b1.hi.z;
    d.link[0] = s.parent;
    d.link[1] = MBVH_NONE;
    d.link[2] = s.child[0];
    d.link[3] = s.child[1];
  }
  for (std::size_t i = 0; i < b.nodes.size(); ++i)
    for (int k = 0; k < 2; ++k) {
      const std::int32_t c = b.nodes[i].child[k];
      if (c >= 0) out.nodes[static_cast<std::size_t>(c)].link[1] = b.nodes[i].child[1 - k];
    }
  LayoutStats& st = out.stats;
  st.layout = "mbvh2";
  st.nodes = out.nodes.size();
  st.leaves = leaves.size();
  st.depth = b.nodes[0].height;
  const double root = b.nodes[0].box.half_area();
  double cost = 0;
  if (root > 0) {
    for (const auto& n : b.nodes) cost += n.box.half_area() / root;
    cost += leaf_sah(b, leaves, root);
  }
  st.sah_cost = cost;
  st.bytes = out.nodes.size() * sizeof(Node2);
  st.bitstack_bits = st.depth;
  if (st.depth > MBVH_MBVH2_LEVEL_CAP) throw Error("internal: MBVH2 depth exceeds the 64-bit bitstack");
  validate_layout(out, leaves.size());
  st.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

namespace {

// Depth-aware greedy collapse into W-wide nodes (W = 4: MBVH4, W = 8: MBVH8). A node at level L
// takes its binary node's two children and repeatedly opens one inner child until it holds W:
// first any child that would break the level cap (an inner child of binary height h at level L+1
// needs L+1+ceil(h/B) <= cap, B = log2(W) binary levels per level, what opening every descendant
// B levels down achieves), else the child of largest surface area (the SAH greedy of Wald et al.
// 2008). With the binary cap of 42 the root satisfies ceil(42/B) <= cap and the invariant carries
// down: MBVH4 never exceeds 21 levels (63 bits of a 64-bit word), MBVH8 never 14.
//
// Nodes are numbered depth-first (a node, then its children's subtrees in slot order), the same
// at any thread count: the top of the tree is walked once to cut it into subtrees of at most
// kTaskSpan binary nodes, the subtrees' wide nodes are counted on the pool, the top is written
// with every subtree's index range known, and the subtrees are written into their ranges on the
// pool. A collapse on one worker writes everything in the top walk.
template <class N, unsigned Cap>
struct Collapser {
  static constexpr int W = node_width<N>();
  static constexpr unsigned B = static_cast<unsigned>(std::countr_zero(static_cast<unsigned>(W)));  // log2(W)
  static constexpr std::size_t kTaskSpan = 4096;  // binary nodes of a subtree task (at most)
  const Bvh2& b;
  N* out = nullptr;      // the node array, sized by the count
  float* area = nullptr; // per wide node: half area of its box (summed in node order: the SAH stat)

  struct Tally {
    std::size_t nodes = 0;
    unsigned max_level = 0;
  };
  struct Task {
    std::int32_t bref;
    std::int32_t parent;
    unsigned level;
    std::size_t first = 0;  // its root's index
    Tally tally;
  };

  bool violates(std::int32_t ref, unsigned level) const {
    if (ref < 0) return false;
    const unsigned h = b.nodes[static_cast<std::size_t>(ref)].height;
    return level + (h + B - 1) / B > Cap;
  }

  // The children (binary references, in binary in-order) of the wide node made of binary node
  // `bref` at `level`; unused slots MBVH_EMPTY.
  void choose(std::int32_t bref, unsigned level, std::int32_t (&kids)[W]) const {
    const Bvh2::Node& bn = b.nodes[static_cast<std::size_t>(bref)];
    for (int k = 0; k < W; ++k) kids[k] = MBVH_EMPTY;
    kids[0] = bn.child[0];
    kids[1] = bn.child[1];
    int count = bn.child[1] == MBVH_EMPTY ? 1 : 2;
    // each kid's half area and whether it breaks the level cap, computed once as it enters
    // (only inner kids are ever compared)
    float area_k[W];
    bool viol[W];
    auto enter = [&](int k) {
      const std::int32_t ref = kids[k];
      area_k[k] = ref >= 0 ? b.nodes[static_cast<std::size_t>(ref)].box.half_area() : 0.0f;
      viol[k] = violates(ref, level + 1);
    };
    for (int k = 0; k < count; ++k) enter(k);
    while (count < W) {
      int pick = -1;
      for (int k = 0; k < count; ++k)
        if (viol[k] && (pick < 0 || area_k[k] > area_k[pick])) pick = k;
      if (pick < 0)
        for (int k = 0; k < count; ++k)
          if (kids[k] >= 0 && (pick < 0 || area_k[k] > area_k[pick])) pick = k;
      if (pick < 0) break;
      const Bvh2::Node& open = b.nodes[static_cast<std::size_t>(kids[pick])];
      for (int k = count; k > pick + 1; --k) {
        kids[k] = kids[k - 1];
        area_k[k] = area_k[k - 1];
        viol[k] = viol[k - 1];
      }
      kids[pick] = open.child[0];
      kids[pick + 1] = open.child[1];
      enter(pick);
      enter(pick + 1);
      ++count;
    }
  }

  // Binary nodes in the subtree of inner node r (depth-first: it ends at its last inner descendant).
  std::size_t span(std::int32_t r) const {
    std::int32_t e = r;
    for (;;) {
      const Bvh2::Node& n = b.nodes[static_cast<std::size_t>(e)];
      if (n.child[1] >= 0) e = n.child[1];
      else if (n.child[0] >= 0) e = n.child[0];
      else return static_cast<std::size_t>(e - r) + 1;
    }
  }

  void count(std::int32_t bref, unsigned level, Tally& t) const {
    std::int32_t kids[W];
    choose(bref, level, kids);
    ++t.nodes;
    for (int s = 0; s < W; ++s) {
      if (kids[s] >= 0) count(kids[s], level + 1, t);
      else if (kids[s] != MBVH_EMPTY) t.max_level = std::max(t.max_level, level + 1);
    }
  }

  // Writes wide node `self` of binary node `bref` (children references in `child`).
  void write(std::size_t self, const std::int32_t (&kids)[W], const std::int32_t (&child)[W], std::int32_t parent) {
    N& n = out[self];
    Box all;
    for (int s = 0; s < W; ++s) {
      const Box bx = kids[s] == MBVH_EMPTY ? empty_box() : b.box(kids[s]);
      all.grow(bx);
      n.lo_x[s] = bx.lo.x; n.hi_x[s] = bx.hi.x;
      n.lo_y[s] = bx.lo.y; n.hi_y[s] = bx.hi.y;
      n.lo_z[s] = bx.lo.z; n.hi_z[s] = bx.hi.z;
      n.child[s] = child[s];
    }
    n.parent = parent;
    if constexpr (W == 4) n.sib[0] = n.sib[1] = n.sib[2] = MBVH_NONE;  // set by the parent (links)
    else std::memset(n.pad, 0, sizeof(n.pad));
    area[self] = all.half_area();
  }

  void links(std::size_t self) {
    if constexpr (W == 4) link_children(out, self);
  }

  // The top walk: children of at most kTaskSpan binary nodes become tasks (in depth-first order).
  void plan(std::int32_t bref, unsigned level, std::vector<Task>& tasks) const {
    std::int32_t kids[W];
    choose(bref, level, kids);
    for (int s = 0; s < W; ++s)
      if (kids[s] >= 0) {
        if (span(kids[s]) <= kTaskSpan) tasks.push_back(Task{kids[s], -1, level + 1, 0, {}});
        else plan(kids[s], level + 1, tasks);
      }
  }

  // Where the top walk stands: the tasks in depth-first order, the next one to meet, and the top
  // nodes written (their children's links wait until the tasks are written).
  struct Top {
    std::vector<Task>& tasks;
    std::size_t cursor = 0;
    std::vector<std::size_t> nodes;
  };

  // Writes the subtree of bref depth-first from index `next` and returns its root's index. With
  // `top` (the top walk), a child that is the next task gets that task's range and parent
  // instead of being written.
  std::int32_t emit(std::int32_t bref, std::int32_t parent, unsigned level, std::size_t& next, Tally& t, Top* top) {
    const std::size_t self = next++;
    std::int32_t kids[W], child[W];
    choose(bref, level, kids);
    for (int s = 0; s < W; ++s) {
      child[s] = kids[s];
      if (kids[s] >= 0) {
        if (top && top->cursor < top->tasks.size() && top->tasks[top->cursor].bref == kids[s]) {
          Task& k = top->tasks[top->cursor++];
          k.first = next;
          k.parent = static_cast<std::int32_t>(self);
          next += k.tally.nodes;
          child[s] = static_cast<std::int32_t>(k.first);
        } else {
          child[s] = emit(kids[s], static_cast<std::int32_t>(self), level + 1, next, t, top);
        }
      } else if (kids[s] != MBVH_EMPTY) {
        t.max_level = std::max(t.max_level, level + 1);
      }
    }
    write(self, kids, child, parent);
    if (top) top->nodes.push_back(self);
    else links(self);
    return static_cast<std::int32_t>(self);
  }
};

// Collapses `b` into `out` (nodes and stats of a wide layout named `name`; every word of a node
// written) on up to `threads` workers.
template <unsigned Cap, class M>
void collapse(const Bvh2& b, const std::vector<Leaf>& leaves, const char* name, M& out, unsigned threads) {
  using N = typename decltype(out.nodes)::value_type;
  using C = Collapser<N, Cap>;
  C c{b};
  std::vector<typename C::Task> tasks;
  if (resolve_threads(threads) > 1 && b.nodes.size() > 2 * C::kTaskSpan) c.plan(0, 0, tasks);
  parallel_for(tasks.size(), 1, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t k = lo; k < hi; ++k) c.count(tasks[k].bref, tasks[k].level, tasks[k].tally);
  });
  out.nodes.resize(std::max<std::size_t>(b.nodes.size(), 1));
  std::vector<float> area(out.nodes.size());
  c.out = out.nodes.data();
  c.area = area.data();
  typename C::Tally top_tally;
  std::size_t next = 0;
  typename C::Top top{tasks, 0, {}};
  c.emit(0, MBVH_NONE, 0, next, top_tally, &top);
  parallel_for(tasks.size(), 1, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t k = lo; k < hi; ++k) {
      auto& t = tasks[k];
      std::size_t at = t.first;
      typename C::Tally tally;
      c.emit(t.bref, t.parent, t.level, at, tally, nullptr);
    }
  });
  for (const std::size_t n : top.nodes) c.links(n);
  out.nodes.resize(next);
  unsigned max_level = top_tally.max_level;
  for (const auto& k : tasks) max_level = std::max(max_level, k.tally.max_level);
  const double root_area = std::max(1e-30, static_cast<double>(b.nodes[0].box.half_area()));
  double cost = 0;
  for (std::size_t i = 0; i < next; ++i) cost += area[i] / root_area;  // in node order, as written before
  LayoutStats& st = out.stats;
  st.layout = name;
  st.nodes = out.nodes.size();
  st.leaves = leaves.size();
  st.depth = max_level;
  st.sah_cost = cost + leaf_sah(b, leaves, root_area);
  st.bytes = out.nodes.size() * sizeof(N);
  if (st.depth > Cap) throw Error(std::string("internal: ") + name + " depth exceeds its level cap");
}

}  // namespace

void finish_mbvh4(Mbvh4& out, std::size_t leaf_count) {
  // cyclic sibling links: sib[k] = parent.child[(slot + 1 + k) & 3]
  out.nodes[0].sib[0] = out.nodes[0].sib[1] = out.nodes[0].sib[2] = MBVH_NONE;
  for (std::size_t p = 0; p < out.nodes.size(); ++p) link_children(out.nodes.data(), p);
  out.stats.bitstack_bits = 3 * out.stats.depth;
  validate_layout(out, leaf_count);
}

Mbvh4 make_mbvh4(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads) {
  const auto t0 = Clock::now();
  Mbvh4 out;
  collapse<MBVH_MBVH4_LEVEL_CAP>(b, leaves, "mbvh4", out, threads);  // with the sibling links
  out.stats.bitstack_bits = 3 * out.stats.depth;
  validate_layout(out, leaves.size());
  out.stats.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

Mbvh8 make_mbvh8(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads) {
  const auto t0 = Clock::now();
  Mbvh8 out;
  collapse<MBVH_MBVH8_LEVEL_CAP>(b, leaves, "mbvh8", out, threads);
  out.stats.bitstack_bits = 8 * out.stats.depth;  // 8 pending-slot bits per level, in a 128-bit word
  validate_layout(out, leaves.size());
  out.stats.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

namespace {

[[noreturn]] void corrupt(const char* layout, std::size_t node, const std::string& what) {
  throw Error(std::string("corrupt ") + layout + " layout: node " + std::to_string(node) + ": " + what);
}

// Checks child reference `c` of node `i`; counts references into `seen` / `leaf_seen`.
void check_ref(const char* layout, std::size_t i, std::int32_t c, std::size_t nodes, std::size_t leaves,
               std::vector<std::uint8_t>& seen, std::vector<std::uint8_t>& leaf_seen) {
  if (c == MBVH_EMPTY) return;
  if (c >= 0) {
    const std::size_t ci = static_cast<std::size_t>(c);
    if (ci <= i || ci >= nodes) corrupt(layout, i, "child " + std::to_string(c) + " is not a later node (a cycle or out of range)");
    if (seen[ci]++) corrupt(layout, i, "node " + std::to_string(c) + " has two parents");
  } else {
    const std::size_t li = static_cast<std::size_t>(~c);
    if (li >= leaves) corrupt(layout, i, "leaf " + std::to_string(li) + " out of range");
    if (leaf_seen[li]++) corrupt(layout, i, "leaf " + std::to_string(li) + " referenced twice");
  }
}

}  // namespace

void validate_layout(const Mbvh2& m, std::size_t leaf_count) {
  const std::size_t n = m.nodes.size();
  if (n == 0) corrupt("MBVH2", 0, "no root");
  if (m.nodes[0].link[0] != MBVH_NONE) corrupt("MBVH2", 0, "the root has a parent");
  std::vector<std::uint8_t> seen(n, 0), leaf_seen(leaf_count, 0);
  for (std::size_t i = 0; i < n; ++i)
    for (int k = 0; k < 2; ++k) {
      const std::int32_t c = m.nodes[i].link[2 + k];
      check_ref("MBVH2", i, c, n, leaf_count, seen, leaf_seen);
      if (c >= 0) {
        const Node2& ch = m.nodes[static_cast<std::size_t>(c)];
        if (ch.link[0] != static_cast<std::int32_t>(i) || ch.link[1] != m.nodes[i].link[2 + (1 - k)])
          corrupt("MBVH2", static_cast<std::size_t>(c), "parent or sibling link does not match its parent");
      }
    }
  for (std::size_t i = 1; i < n; ++i)
    if (!seen[i]) corrupt("MBVH2", i, "unreachable");
}

Mbvh4Wide make_mbvh4_wide(const Mbvh4& m) {
  Mbvh4Wide w;
  w.nodes.resize(m.nodes.size());
  for (std::size_t i = 0; i < m.nodes.size(); ++i) {
    const Node4& n = m.nodes[i];
    Node4W& o = w.nodes[i];
    const std::int32_t link[4] = {n.parent, n.sib[0], n.sib[1], n.sib[2]};
    for (int s = 0; s < 4; ++s) {
      o.lo[s][0] = n.lo_x[s];
      o.lo[s][1] = n.lo_y[s];
      o.lo[s][2] = n.lo_z[s];
      std::memcpy(&o.lo[s][3], &n.child[s], 4);
      o.hi[s][0] = n.hi_x[s];
      o.hi[s][1] = n.hi_y[s];
      o.hi[s][2] = n.hi_z[s];
      std::memcpy(&o.hi[s][3], &link[s], 4);
    }
  }
  return w;
}

TriPacks make_tri_packs(const AlignedVector<Tri>& tris, const std::vector<Leaf>& leaves) {
  TriPacks p;
  p.leaves.reserve(leaves.size());
  std::size_t total = 0;
  for (const Leaf& l : leaves) total += (l.count + 3) / 4;
  Tri4 empty;
  for (auto& row : empty.v)
    for (float& x : row) x = std::numeric_limits<float>::quiet_NaN();
  for (auto& id : empty.prim) id = MBVH_MISS_PRIM;
  p.packs.assign(total, empty);
  std::size_t next = 0;
  for (const Leaf& l : leaves) {
    p.leaves.push_back(Leaf{static_cast<std::uint32_t>(next), l.count});
    for (std::uint32_t k = 0; k < l.count; ++k) {
      const Tri& t = tris[l.first + k];
      Tri4& o = p.packs[next + k / 4];
      const float* vert[3] = {t.v0, t.v1, t.v2};
      for (int i = 0; i < 3; ++i)
        for (int a = 0; a < 3; ++a) o.v[3 * i + a][k % 4] = vert[i][a];
      std::memcpy(&o.prim[k % 4], &t.v0[3], 4);
    }
    next += (l.count + 3) / 4;
  }
  return p;
}

namespace {

// Whether a W-wide layout passes validate_wide, checked on the pool without a per-node count:
// every child reference of node i is a later node naming i as its parent (with matching links),
// no node lists a child twice, and every node but the root names an earlier parent that lists
// it; by induction on the index every node is then reachable from the root, once. Leaves are
// counted atomically. validate_wide runs only where this fails, for its first fault's message.
template <class N, class LinksOk>
bool wide_ok(const AlignedVector<N>& nodes, std::size_t leaf_count, LinksOk links_ok) {
  constexpr int W = node_width<N>();
  const std::size_t n = nodes.size();
  if (n == 0 || nodes[0].parent != MBVH_NONE) return false;
  const auto leaf_seen = std::make_unique<std::atomic<std::uint8_t>[]>(leaf_count);  // value-initialised: 0
  std::atomic<bool> ok{true};
  parallel_for(n, 8192, 0, [&](std::size_t b, std::size_t e, unsigned) {
    bool good = true;
    for (std::size_t i = b; i < e && good; ++i) {
      const N& p = nodes[i];
      for (int s = 0; s < W; ++s) {
        const std::int32_t c = p.child[s];
        if (c == MBVH_EMPTY) continue;
        if (c >= 0) {
          const std::size_t ci = static_cast<std::size_t>(c);
          if (ci <= i || ci >= n || nodes[ci].parent != static_cast<std::int32_t>(i) || !links_ok(nodes[ci], p, s)) good = false;
          for (int t = 0; t < s; ++t) good = good && p.child[t] != c;
        } else {
          const std::size_t li = static_cast<std::size_t>(~c);
          good = good && li < leaf_count && leaf_seen[li].exchange(1, std::memory_order_relaxed) == 0;
        }
      }
      if (i > 0) {
        const std::int32_t q = p.parent;
        bool listed = false;
        if (q >= 0 && static_cast<std::size_t>(q) < i)
          for (int s = 0; s < W; ++s) listed = listed || nodes[static_cast<std::size_t>(q)].child[s] == static_cast<std::int32_t>(i);
        good = good && listed;
      }
    }
    if (!good) ok = false;
  });
  return ok;
}

// The checks of a W-wide layout; `links_ok(child, parent node, slot)` checks a child's own links.
template <class N, class LinksOk>
void validate_wide(const AlignedVector<N>& nodes, const char* name, std::size_t leaf_count, LinksOk links_ok) {
  if (wide_ok(nodes, leaf_count, links_ok)) return;
  const std::size_t n = nodes.size();
  if (n == 0) corrupt(name, 0, "no root");
  if (nodes[0].parent != MBVH_NONE) corrupt(name, 0, "the root has a parent");
  std::vector<std::uint8_t> seen(n, 0), leaf_seen(leaf_count, 0);
  for (std::size_t i = 0; i < n; ++i)
    for (int s = 0; s < node_width<N>(); ++s) {
      const std::int32_t c = nodes[i].child[s];
      check_ref(name, i, c, n, leaf_count, seen, leaf_seen);
      if (c >= 0) {
        const N& ch = nodes[static_cast<std::size_t>(c)];
        if (ch.parent != static_cast<std::int32_t>(i) || !links_ok(ch, nodes[i], s))
          corrupt(name, static_cast<std::size_t>(c), "parent or sibling links do not match its parent");
      }
    }
  for (std::size_t i = 1; i < n; ++i)
    if (!seen[i]) corrupt(name, i, "unreachable");
  throw Error(std::string("internal: ") + name + " layout failed the parallel check but not the serial one");
}

}  // namespace

void validate_layout(const Mbvh4& m, std::size_t leaf_count) {
  validate_wide(m.nodes, "MBVH4", leaf_count, [](const Node4& ch, const Node4& p, int s) {
    for (int k = 0; k < 3; ++k)
      if (ch.sib[k] != p.child[(s + 1 + k) & 3]) return false;
    return true;
  });
}

void validate_layout(const Mbvh8& m, std::size_t leaf_count) {
  validate_wide(m.nodes, "MBVH8", leaf_count, [](const Node8&, const Node8&, int) { return true; });
}

}  // namespace mbvh

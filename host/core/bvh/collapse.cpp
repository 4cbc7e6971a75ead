// SPDX-License-Identifier: MIT
// collapse.cpp — the MBVH2, MBVH4 and MBVH8 layouts made from the binary BVH by the greedy
// collapse, with the parent and sibling links the stackless bitstack traversal needs (Áfra &
// Szirmay-Kalos, "Stackless Multi-BVH Traversal for CPU, MIC and GPU Ray Tracing", CGF 2014;
// TRAVERSAL.md §2).
#include <algorithm>
#include <bit>
#include <chrono>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/wide_node.h"
#include "host/core/huge_pages.h"
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

// The SAH statistic of a wide layout: its nodes' half areas (`area`, `nodes` of them) and its
// leaves', over the root's (build::sum_in_runs: the same bits at any thread count).
double wide_sah(const float* area, std::size_t nodes, const Bvh2& b, const std::vector<Leaf>& leaves, double root,
                unsigned threads) {
  return build::sum_in_runs(
      nodes, [&](std::size_t i) { return area[i] / root; }, leaves.size(),
      [&](std::size_t i) { return double(leaves[i].count) * b.leaf_boxes[i].half_area() / root; }, threads);
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
    build::set_boxes(d, b0, b1);
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
  st.sah_cost = build::sah_of_binary(b, leaves, 1.0f);  // nodes priced at 1, as the wide layouts' are
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
// pool (inline on one worker), the node array sized by the count. A tree of at most 2 kTaskSpan
// binary nodes is written in the top walk alone, into an array of one node a binary node.
template <class N, unsigned Cap>
struct Collapser {
  static constexpr int W = node_width<N>();
  static constexpr unsigned B = static_cast<unsigned>(std::countr_zero(static_cast<unsigned>(W)));  // log2(W)
  static constexpr std::size_t kTaskSpan = 4096;  // binary nodes of a subtree task (at most)
  const Bvh2& b;
  N* out = nullptr;      // the node array, sized by the count
  std::size_t cap = 0;   // its size: emit refuses an index past it before writing there
  float* area = nullptr; // per wide node: half area of its box (summed in node order: the SAH stat)
  std::uint8_t* leaf_seen = nullptr;  // per leaf: referenced (zeroed; marked by check())
  std::size_t leaf_count = 0;

  struct Tally {
    std::size_t nodes = 0;
    unsigned max_level = 0;
  };
  struct Kids {
    std::int32_t k[W];
  };
  // validate_layout's check folded into the write (wide_ok's argument, validate.cpp), per writer:
  // every child reference of a node checked is a node of its own subtree (a later index below the
  // writer's next one, so already written by this writer) naming it as parent, with matching
  // sibling links and no child listed twice; its leaf references are in range, marked and counted.
  struct Check {
    bool good = true;
    std::size_t inner = 0, leaf_refs = 0;
  };
  struct Task {
    std::int32_t bref;
    std::int32_t parent;
    unsigned level;
    std::size_t first = 0;  // its root's index
    Tally tally;
    std::size_t span = 0;   // its binary inner nodes: a bound on its wide nodes
    Kids* kids = nullptr;   // choose()'s answer for each of its wide nodes, in the write's order
    Check check;
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
    // (only inner kids are ever compared; the slots past `count` start defined: the shift below
    // reads every slot)
    float area_k[W] = {};
    bool viol[W] = {};
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
      // slots pick+1 .. count-1 move up one: every slot above pick+1 rewritten by a select, highest
      // first (a loop over just the moved slots is compiled into a memmove call each)
      for (int k = W - 1; k > 0; --k) {
        const bool move = k > pick + 1 && k <= count;
        kids[k] = move ? kids[k - 1] : kids[k];
        area_k[k] = move ? area_k[k - 1] : area_k[k];
        viol[k] = move ? viol[k - 1] : viol[k];
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

  // Counts the wide nodes of the subtree of bref and keeps each one's children at `memo` (the
  // depth-first order in which emit meets them; one entry a wide node, so at most one a binary
  // inner node), so that the write does not choose again.
  void count(std::int32_t bref, unsigned level, Tally& t, Kids*& memo) const {
    Kids& c = *memo++;
    choose(bref, level, c.k);
    const std::int32_t (&kids)[W] = c.k;
    ++t.nodes;
    for (int s = 0; s < W; ++s) {
      if (kids[s] >= 0) count(kids[s], level + 1, t, memo);
      else if (kids[s] != MBVH_EMPTY) t.max_level = std::max(t.max_level, level + 1);
    }
  }

  // Writes wide node `self` of binary node `bref` (children references in `child`).
  void write(std::size_t self, const std::int32_t (&kids)[W], const std::int32_t (&child)[W], std::int32_t parent) {
    const Box all = build::write_wide_node(out[self], child, parent, [&](int s) {
      return kids[s] == MBVH_EMPTY ? empty_box() : b.box(kids[s]);
    });
    area[self] = all.half_area();
  }

  void links(std::size_t self) {
    if constexpr (W == 4) link_children(out, self);
  }

  // Checks written node `self` (wide_node_ok) once its children's links are written, every node
  // in (self, end) written already (its subtree).
  void check(std::size_t self, std::size_t end, Check& k) const {
    k.good = wide_node_ok(out, self, end, leaf_seen, leaf_count, k.inner, k.leaf_refs) && k.good;
  }

  // The top walk: children of at most kTaskSpan binary nodes become tasks (in depth-first order);
  // `top_nodes` counts the wide nodes it passes, the ones emit's top walk writes itself.
  void plan(std::int32_t bref, unsigned level, std::vector<Task>& tasks, std::size_t& top_nodes) const {
    std::int32_t kids[W];
    choose(bref, level, kids);
    ++top_nodes;
    for (int s = 0; s < W; ++s)
      if (kids[s] >= 0) {
        if (const std::size_t n = span(kids[s]); n <= kTaskSpan)
          tasks.push_back(Task{kids[s], -1, level + 1, 0, {}, n, nullptr, {}});
        else plan(kids[s], level + 1, tasks, top_nodes);
      }
  }

  // Where the top walk stands: the tasks in depth-first order, the next one to meet, and the top
  // nodes written (their children's links wait until the tasks are written).
  struct Top {
    std::vector<Task>& tasks;
    std::size_t cursor = 0;
    std::vector<std::size_t> nodes;
    std::vector<std::size_t> unchecked;  // its nodes with a task in their subtree: checked after the tasks
  };

  // Writes the subtree of bref depth-first from index `next` and returns its root's index. With
  // `top` (the top walk), a child that is the next task gets that task's range and parent
  // instead of being written. With `memo` (a task's write), the children count() chose, in order.
  // Each node is checked (check()) as written, or, in the top walk where its subtree holds a task
  // (written later), listed in top->unchecked.
  std::int32_t emit(std::int32_t bref, std::int32_t parent, unsigned level, std::size_t& next, Tally& t, Top* top,
                    Check& chk, const Kids** memo = nullptr) {
    const std::size_t self = next++;
    const std::size_t cursor0 = top ? top->cursor : 0;
    if (self >= cap) throw Error("internal: the collapse writes more wide nodes than it counted");
    std::int32_t kids[W], child[W];
    if (memo) {
      for (int s = 0; s < W; ++s) kids[s] = (*memo)->k[s];
      ++*memo;
    } else {
      choose(bref, level, kids);
    }
    bool task_child = false;  // a child written later on the pool: this node's links wait for it
    Top* walk = top;          // past the last task the walk goes on as a plain subtree's (links inline)
    for (int s = 0; s < W; ++s) {
      child[s] = kids[s];
      if (kids[s] >= 0) {
        if (walk && walk->cursor == walk->tasks.size()) walk = nullptr;
        if (walk && walk->tasks[walk->cursor].bref == kids[s]) {
          Task& k = walk->tasks[walk->cursor++];
          k.first = next;
          k.parent = static_cast<std::int32_t>(self);
          next += k.tally.nodes;
          child[s] = static_cast<std::int32_t>(k.first);
          task_child = true;
        } else {
          child[s] = emit(kids[s], static_cast<std::int32_t>(self), level + 1, next, t, walk, chk, memo);
        }
      } else if (kids[s] != MBVH_EMPTY) {
        t.max_level = std::max(t.max_level, level + 1);
      }
    }
    write(self, kids, child, parent);
    if (task_child) top->nodes.push_back(self);
    else links(self);
    if (top && top->cursor != cursor0) top->unchecked.push_back(self);  // a task's range in its subtree, unwritten
    else check(self, next, chk);
    return static_cast<std::int32_t>(self);
  }
};

// Collapses `b` into `out` (nodes and stats of a wide layout named `name`; every word of a node
// written) on up to `threads` workers. Returns whether the layout passed validate_layout's checks,
// made as each node was written (Collapser::check); where it did not, the caller's
// validate_layout names the fault.
template <unsigned Cap, class M>
bool collapse(const Bvh2& b, const std::vector<Leaf>& leaves, const char* name, M& out, unsigned threads) {
  using N = typename decltype(out.nodes)::value_type;
  using C = Collapser<N, Cap>;
  C c{b};
  std::vector<typename C::Task> tasks;
  std::size_t top_nodes = 0;
  if (b.nodes.size() > 2 * C::kTaskSpan) c.plan(0, 0, tasks, top_nodes);
  // the tasks' memos: runs of one array the calling thread allocates (growing a vector per task,
  // on the workers, would leave small blocks between the build's large arrays that glibc's
  // per-thread caches keep, and the next build's arrays would not fit back in their places)
  std::size_t memo_size = 0;
  for (const auto& t : tasks) memo_size += t.span;
  build::RawVector<typename C::Kids> memo(memo_size);  // written only where a task has a wide node
  for (std::size_t k = 0, at = 0; k < tasks.size(); at += tasks[k++].span) tasks[k].kids = memo.data() + at;
  parallel_for(tasks.size(), 1, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t k = lo; k < hi; ++k) {
      typename C::Kids* m = tasks[k].kids;
      c.count(tasks[k].bref, tasks[k].level, tasks[k].tally, m);
    }
  });
  // as many nodes as the collapse keeps where the tasks counted theirs (the top walk's counted by
  // plan), else one a binary node, the most there can be: an array no larger than it needs fits
  // back into memory the build freed more often (fewer fresh pages to fault in)
  std::size_t kept = top_nodes;
  for (const auto& t : tasks) kept += t.tally.nodes;
  out.nodes.resize(tasks.empty() ? std::max<std::size_t>(b.nodes.size(), 1) : kept);
  build::RawVector<float> area(out.nodes.size());  // written for every node kept (not zeroed: only those pages touched)
  // both written from their start, up to the nodes kept (emit numbers the nodes in order)
  advise_huge_pages(out.nodes.data(), out.nodes.size() * sizeof(N));
  advise_huge_pages(area.data(), area.size() * sizeof(float));
  c.out = out.nodes.data();
  c.cap = out.nodes.size();
  c.area = area.data();
  const auto leaf_seen = std::make_unique<std::uint8_t[]>(leaves.size());  // value-initialised: 0
  c.leaf_seen = leaf_seen.get();
  c.leaf_count = leaves.size();
  typename C::Tally top_tally;
  typename C::Check top_check;
  std::size_t next = 0;
  typename C::Top top{tasks, 0, {}, {}};
  c.emit(0, MBVH_NONE, 0, next, top_tally, &top, top_check);
  parallel_for(tasks.size(), 1, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t k = lo; k < hi; ++k) {
      auto& t = tasks[k];
      std::size_t at = t.first;
      typename C::Tally tally;
      const typename C::Kids* m = t.kids;
      c.emit(t.bref, t.parent, t.level, at, tally, nullptr, t.check, &m);
      // its range written exactly (so every node of the array is written once, by one writer)
      t.check.good = t.check.good && at == t.first + t.tally.nodes;
    }
  });
  for (const std::size_t n : top.nodes) c.links(n);
  if (!tasks.empty() && next != kept) throw Error("internal: the collapse wrote another count of wide nodes than it counted");
  for (const std::size_t n : top.unchecked) c.check(n, next, top_check);
  // wide_ok's conclusion (validate.cpp): n - 1 child references, each to a later node naming its
  // parent, make a tree from node 0; as many leaf references as leaves, all marked, each leaf once
  typename C::Check all = top_check;
  for (const auto& t : tasks) {
    all.good = all.good && t.check.good;
    all.inner += t.check.inner;
    all.leaf_refs += t.check.leaf_refs;
  }
  // (parallel_for's end orders the workers' marks before this read)
  const bool checked = all.good && next > 0 && out.nodes[0].parent == MBVH_NONE && all.inner == next - 1 &&
                       all.leaf_refs == leaves.size() &&
                       (leaves.empty() || std::memchr(leaf_seen.get(), 0, leaves.size()) == nullptr);
  out.nodes.resize(next);
  unsigned max_level = top_tally.max_level;
  for (const auto& k : tasks) max_level = std::max(max_level, k.tally.max_level);
  const double root_area = std::max(1e-30, static_cast<double>(b.nodes[0].box.half_area()));
  LayoutStats& st = out.stats;
  st.layout = name;
  st.nodes = out.nodes.size();
  st.leaves = leaves.size();
  st.depth = max_level;
  st.sah_cost = wide_sah(area.data(), next, b, leaves, root_area, threads);
  st.bytes = out.nodes.size() * sizeof(N);
  if (st.depth > Cap) throw Error(std::string("internal: ") + name + " depth exceeds its level cap");
  return checked;
}

}  // namespace

void finish_mbvh4(Mbvh4& out, std::size_t leaf_count, unsigned threads) {
  // cyclic sibling links: sib[k] = parent.child[(slot + 1 + k) & 3]
  out.nodes[0].sib[0] = out.nodes[0].sib[1] = out.nodes[0].sib[2] = MBVH_NONE;
  for (std::size_t p = 0; p < out.nodes.size(); ++p) link_children(out.nodes.data(), p);
  out.stats.bitstack_bits = 3 * out.stats.depth;
  validate_layout(out, leaf_count, threads);
}

Mbvh4 make_mbvh4(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads) {
  return build::make_mbvh4(b, leaves, threads, {});
}

Mbvh4 build::make_mbvh4(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads, AlignedVector<Node4>&& storage) {
  const auto t0 = Clock::now();
  Mbvh4 out;
  out.nodes = std::move(storage);  // empty; every node the collapse keeps is written
  out.nodes.clear();
  const bool checked = collapse<MBVH_MBVH4_LEVEL_CAP>(b, leaves, "mbvh4", out, threads);  // with the sibling links
  out.stats.bitstack_bits = 3 * out.stats.depth;
  if (!checked) validate_layout(out, leaves.size(), threads);
  out.stats.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

Mbvh8 make_mbvh8(const Bvh2& b, const std::vector<Leaf>& leaves, unsigned threads) {
  const auto t0 = Clock::now();
  Mbvh8 out;
  const bool checked = collapse<MBVH_MBVH8_LEVEL_CAP>(b, leaves, "mbvh8", out, threads);
  out.stats.bitstack_bits = 8 * out.stats.depth;  // 8 pending-slot bits per level, in a 128-bit word
  if (!checked) validate_layout(out, leaves.size(), threads);
  out.stats.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
  return out;
}

}  // namespace mbvh

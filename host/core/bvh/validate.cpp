// SPDX-License-Identifier: MIT
// validate.cpp — the structural checks of the layouts (validate_layout): every reference in
// range, every node and leaf referenced once, the parent and sibling links consistent. The wide
// layouts are checked on the pool first (wide_ok); the serial walk runs only to name a fault.
// The greedy collapse (collapse.cpp, Collapser::check) makes wide_ok's checks as it writes each
// node and calls validate_layout only where they fail.
#include <atomic>
#include <cstring>
#include <memory>
#include <string>
#include <vector>

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/view.h"
#include "mbvh/error.h"

namespace mbvh {
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

// Whether a W-wide layout passes validate_wide, checked on the pool without a per-node count:
// every child reference of node i is a later node naming i as its parent (with matching links)
// and no node lists a child twice, so a node is listed by at most one node, its parent; with n - 1
// such references among n nodes (counted per chunk) every node but the root is listed exactly
// once, by an earlier node, and by induction on the index is reachable from the root. Likewise
// each leaf reference in range marks its leaf (a relaxed store, no read-modify-write) and is
// counted: every leaf marked and as many references as leaves means each leaf is listed once.
// validate_wide runs only where this fails, for its first fault's message.
template <class N>
bool wide_ok(const AlignedVector<N>& nodes, std::size_t leaf_count, unsigned threads) {
  const std::size_t n = nodes.size();
  if (n == 0 || nodes[0].parent != MBVH_NONE) return false;
  const auto leaf_seen = std::make_unique<std::uint8_t[]>(leaf_count);  // value-initialised: 0
  std::atomic<bool> ok{true};
  std::atomic<std::size_t> node_refs{0}, leaf_refs{0};
  parallel_for(n, 2048, threads, [&](std::size_t b, std::size_t e, unsigned) {
    bool good = true;
    std::size_t inner = 0, refs = 0;
    for (std::size_t i = b; i < e && good; ++i) good = wide_node_ok(nodes.data(), i, n, leaf_seen.get(), leaf_count, inner, refs);
    node_refs.fetch_add(inner, std::memory_order_relaxed);
    leaf_refs.fetch_add(refs, std::memory_order_relaxed);
    if (!good) ok = false;
  });
  if (!ok || node_refs.load() != n - 1 || leaf_refs.load() != leaf_count) return false;
  // (parallel_for's end orders the workers' marks before this read)
  return leaf_count == 0 || std::memchr(leaf_seen.get(), 0, leaf_count) == nullptr;
}

// The checks of a W-wide layout on up to `threads` workers (a child's own links: sibling_links_ok).
template <class N>
void validate_wide(const AlignedVector<N>& nodes, const char* name, std::size_t leaf_count, unsigned threads) {
  if (wide_ok(nodes, leaf_count, threads)) return;
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
        if (ch.parent != static_cast<std::int32_t>(i) || !sibling_links_ok(ch, nodes[i], s))
          corrupt(name, static_cast<std::size_t>(c), "parent or sibling links do not match its parent");
      }
    }
  for (std::size_t i = 1; i < n; ++i)
    if (!seen[i]) corrupt(name, i, "unreachable");
  throw Error(std::string("internal: ") + name + " layout failed the parallel check but not the serial one");
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

void validate_layout(const Mbvh4& m, std::size_t leaf_count, unsigned threads) {
  validate_wide(m.nodes, "MBVH4", leaf_count, threads);
}

void validate_layout(const Mbvh8& m, std::size_t leaf_count, unsigned threads) {
  validate_wide(m.nodes, "MBVH8", leaf_count, threads);
}

}  // namespace mbvh

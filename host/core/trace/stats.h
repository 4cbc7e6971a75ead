// SPDX-License-Identifier: MIT
// stats.h — the traversals' statistics policies (NoStats compiles every counter away, CountStats
// fills RayStats) and the termination guard of checked builds.
#pragma once
#include <cstddef>
#include <cstdint>
#include <stdexcept>
#include <vector>

#include "host/core/trace/intersect.h"  // MBVH_ISA_NS
#include "host/core/trace/view.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

struct NoStats {
  static constexpr bool on = false;
  void node(unsigned) {}
  void leaf(std::int32_t) {}
  void tri() {}
  void climb() {}
  void retest() {}
  void depth(unsigned) {}
};

struct CountStats {
  static constexpr bool on = true;
  RayStats s;
  std::vector<std::int32_t>* leaf_log = nullptr;  ///< if set, every visited leaf in order
  void node(unsigned boxes) { ++s.nodes; s.box_tests += boxes; }
  void leaf(std::int32_t ref) { ++s.leaves; if (leaf_log) leaf_log->push_back(ref); }
  void tri() { ++s.tris; }
  void climb() { ++s.climbs; }
  void retest() { ++s.retests; }
  void depth(unsigned d) { if (d > s.max_depth) s.max_depth = d; }
};

/// Termination guard of checked builds (Debug and sanitizer builds define
/// MBVH_CHECK_TERMINATION): a tree traversal enters each node and leaf at most once, climbs at
/// most once per node and makes at most one sibling move per entry, so more loop steps than
/// 3 * nodes + 2 * leaves + 2 mean a corrupt tree; it throws instead of looping. Release builds
/// compile it away (validate_layout guards them).
struct StepGuard {
#ifdef MBVH_CHECK_TERMINATION
  std::size_t left;
  explicit StepGuard(const TraceView& v) : left(3 * v.nodes + 2 * v.leaf_count + 2) {}
  void step() {
    if (left-- == 0) throw std::runtime_error("traversal exceeded its step bound: the tree is corrupt");
  }
  void room(unsigned sp, unsigned need, unsigned capacity) {
    if (sp + need > capacity) throw std::runtime_error("traversal stack overflow: the tree is deeper than its cap");
  }
#else
  explicit StepGuard(const TraceView&) {}
  void step() {}
  void room(unsigned, unsigned, unsigned) {}
#endif
};

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

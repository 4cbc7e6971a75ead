// SPDX-License-Identifier: MIT
// view.h — what a traversal reads (one layout's nodes, the leaves and triangles) and the
// per-ray work counters it fills. Plain records outside the ISA namespaces, so a per-ISA kernel
// (backends/cpu) includes them at the baseline ISA before it switches its own code to AVX.
#pragma once
#include <cstddef>
#include <cstdint>

#include "shaders/mbvh_layout.h"

namespace mbvh {

/// Children per node of a wide layout (Node4: 4, Node8: 8).
template <class N>
constexpr int node_width() { return sizeof(N::child) / sizeof(N::child[0]); }

/// Per-ray work counters.
struct RayStats {
  std::uint32_t nodes = 0;      ///< inner-node records visited
  std::uint32_t box_tests = 0;  ///< child boxes tested (2 per MBVH2 node, 4 per MBVH4 node)
  std::uint32_t leaves = 0;
  std::uint32_t tris = 0;       ///< triangle tests
  std::uint32_t climbs = 0;     ///< parent reads while backtracking (bitstack only)
  std::uint32_t retests = 0;    ///< parent nodes re-tested on a sibling move (variant B only)
  std::uint32_t max_depth = 0;  ///< peak stack entries (stack) or bitstack levels (bitstack)
};

/// What a traversal reads: one layout's nodes plus the shared leaves and triangles.
struct TraceView {
  const Node2* n2 = nullptr;
  const Node4* n4 = nullptr;
  const Node8* n8 = nullptr;
  const Leaf* leaves = nullptr;
  const Tri* tris = nullptr;
  const Tri4* tri4 = nullptr;   ///< SIMD leaf packs (Accel::tri_packs), where a kernel uses them
  const Leaf* leaf4 = nullptr;  ///< per leaf: (first pack, triangle count)
  std::size_t nodes = 0, leaf_count = 0;  ///< sizes, for the termination guard
};

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// view.h — what a traversal reads (one layout's nodes, the leaves and triangles) and the
// per-ray work counters it fills. Plain records outside the ISA namespaces, so a per-ISA kernel
// (backends/cpu) includes them at the baseline ISA before it switches its own code to AVX.
#pragma once
#include <cstddef>
#include <cstdint>

#include "mbvh/mbvh_layout.h"
#include "mbvh/trace.h"  // RayStats

namespace mbvh {

/// Children per node of a wide layout (Node4: 4, Node8: 8).
template <class N>
constexpr int node_width() { return sizeof(N::child) / sizeof(N::child[0]); }

/// TraceView::packed_refs' leaf references: ~(first pack << 3 | count - 1) for a leaf of 1 to
/// kPackedLeafMax triangles whose packs start below kPackedFirstEnd (every code then stays below
/// 2^31 - 1, so no reference becomes MBVH_EMPTY). The one encoding LeafVariant::packed_nodes
/// writes and the SIMD kernels read.
constexpr std::uint32_t kPackedLeafMax = 8;
constexpr std::uint32_t kPackedFirstEnd = (1u << 28) - 1;
inline bool packable(const Leaf& l) { return l.count >= 1 && l.count <= kPackedLeafMax && l.first < kPackedFirstEnd; }
inline std::int32_t packed_leaf_ref(const Leaf& l) { return ~static_cast<std::int32_t>(l.first << 3 | (l.count - 1)); }
inline Leaf packed_leaf(std::int32_t ref) {
  const auto code = static_cast<std::uint32_t>(~ref);
  return Leaf{code >> 3, (code & 7u) + 1u};
}

/// What a traversal reads: one layout's nodes plus the shared leaves and triangles.
struct TraceView {
  const Node2* n2 = nullptr;
  const Node4* n4 = nullptr;
  const Node8* n8 = nullptr;
  /// The MBVH4 nodes' 16-wide view (Node4W; n4w[i] is n4[i]'s boxes), where a kernel tests an
  /// MBVH4 node in 16 lanes (the cpu backend's MIC path, cpu.mic): the walk reads n4, the box
  /// test n4w.
  const Node4W* n4w = nullptr;
  const Leaf* leaves = nullptr;
  const Tri* tris = nullptr;
  const Tri4* tri4 = nullptr;   ///< SIMD leaf packs (Accel::tri_packs), where a kernel uses them
  const Leaf* leaf4 = nullptr;  ///< per leaf: (first pack, triangle count)
  /// The nodes' leaf references locate the packs themselves: ~(first pack << 3 | count - 1) (a
  /// leaf of 1 to 8 triangles; LeafVariant::packed_nodes), so a leaf costs no leaf4 look-up, one
  /// dependent load less (Embree's tagged child pointers do the same). Only the SIMD kernels'
  /// uncounted traversals read such a view.
  bool packed_refs = false;
  std::size_t nodes = 0, leaf_count = 0;  ///< sizes, for the termination guard and the prefetch threshold
};

}  // namespace mbvh

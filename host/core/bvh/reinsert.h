// SPDX-License-Identifier: MIT
// reinsert.h — insertion-based optimisation of a finished binary BVH (host/core/bvh/reinsert.cpp):
// subtrees moved to where they lower the SAH most. Internal to the high-quality build (sbvh.cpp).
#pragma once
#include <cstdint>
#include <vector>

#include "host/core/layouts.h"

namespace mbvh::build {

/// What reinsert did: the rounds run, the subtrees moved, the sum of the inner nodes' half areas
/// before and after (the part of the SAH it changes; leaves are not touched).
struct ReinsertStats {
  unsigned rounds = 0;
  std::size_t moved = 0;
  double inner_area_before = 0, inner_area_after = 0;
};

/// Moves subtrees of `bvh` (depth-first, as the builders emit it; leaves ranges of `prims`, which
/// are not changed) to the positions that lower its SAH, then emits it depth-first again: `bvh`,
/// `leaves` and `prims` rewritten (the same leaves with the same boxes and triangles, renumbered in
/// the new depth-first order), every invariant of Bvh2 kept (parent links, heights, the leaf depth
/// within opt.depth_cap). Sequential and a function of its input alone: deterministic.
ReinsertStats reinsert(Bvh2& bvh, std::vector<Leaf>& leaves, std::vector<std::uint32_t>& prims, const BuildOptions& opt);

}  // namespace mbvh::build

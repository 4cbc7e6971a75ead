// SPDX-License-Identifier: MIT
// sbvh.h — the high-quality build (BuildQuality::high): a binary BVH with spatial splits
// (host/core/bvh/sbvh.cpp). Internal to Accel::build.
#pragma once
#include <cstdint>
#include <vector>

#include "host/core/layouts.h"

namespace mbvh {

struct SbvhResult {
  Bvh2 bvh;                          ///< nodes and leaf boxes (boxes bound the clipped references)
  std::vector<Leaf> leaves;          ///< ranges of `prims`, in depth-first order
  std::vector<std::uint32_t> prims;  ///< per leaf slot, the original triangle (a prim may repeat across leaves, never in one)
  std::size_t references = 0;        ///< prims.size()
};

/// Builds the SBVH over the triangles `idx` of `scene` (non-degenerate, validated), their boxes
/// `boxes` (indexed by prim). Deterministic: the result does not depend on opt.threads.
SbvhResult build_sbvh(const Scene& scene, const BuildOptions& opt, const std::vector<Box>& boxes,
                      const std::vector<std::uint32_t>& idx);

}  // namespace mbvh

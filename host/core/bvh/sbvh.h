// SPDX-License-Identifier: MIT
// sbvh.h — the high-quality build (BuildQuality::high): a binary BVH with spatial splits, or
// without where that costs less after reinsertion (host/core/bvh/sbvh.cpp). Internal to Accel::build.
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
  double sah = 0;                    ///< build_high: the kept tree's binary SAH (build::sah_of_binary)
};

/// Builds the SBVH over the triangles `idx` of `scene` (non-degenerate, validated), their boxes
/// `boxes` (indexed by prim). `spatial` false: object splits only (no reference budget beyond one
/// per triangle), the same binning otherwise. Deterministic: the result does not depend on opt.threads.
SbvhResult build_sbvh(const Scene& scene, const BuildOptions& opt, const std::vector<Box>& boxes,
                      const std::vector<std::uint32_t>& idx, bool spatial = true);

/// The high-quality build's tree (BuildQuality::high): two candidates, the SBVH with spatial
/// splits and the same builder with object splits only, each optimised by reinsertion
/// (reinsert.cpp; the two reinsertions run concurrently), and the one of lower binary SAH kept
/// (the spatial one on a tie). Deterministic: the result does not depend on opt.threads.
SbvhResult build_high(const Scene& scene, const BuildOptions& opt, const std::vector<Box>& boxes,
                      const std::vector<std::uint32_t>& idx);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// tinybvh_kernels.h — the narrow interface between the `tinybvh` peer backend (portable code,
// tinybvh_backend.cpp) and the one translation unit that compiles tinybvh's header with AVX2 and
// FMA (tinybvh_kernels.cpp): a tree built from triangles, traced over a range of rays. Only the
// backend includes it, and only calls it on a CPU with AVX2 and FMA.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "mbvh/trace.h"

namespace mbvh::tinybvh_peer {

/// tinybvh's wide CPU layouts: BVH4_CPU (4-wide nodes, SSE) and BVH8_CPU (8-wide, AVX2 + FMA).
enum class Width { bvh4, bvh8 };

/// One tinybvh tree over a triangle list. Its answers carry the file's prim ids.
class Tree {
public:
  virtual ~Tree() = default;
  /// Closest hits of rays[b, e) into hits[b, e) (misses left as they are); counts the invalid
  /// rays (the numerical contract's defined misses) into `invalid`.
  virtual void closest(std::span<const Ray> rays, std::size_t b, std::size_t e, Hit* hits, std::size_t& invalid) const = 0;
  /// Occlusion of rays[b, e) into occluded[b, e) (1 = occluded; the rest left as they are).
  virtual void any(std::span<const Ray> rays, std::size_t b, std::size_t e, std::uint8_t* occluded,
                   std::size_t& invalid) const = 0;
};

/// Builds tinybvh's `width` layout (its default builder, binned SAH, or with `hq` its BuildHQ,
/// spatial splits; then the collapse to 4 or 8 wide) over `xyz`: 9 floats per triangle (v0, v1,
/// v2); triangle i answers as prim `prims[i]`. At least one triangle. Needs AVX2 and FMA (the
/// caller checks the CPU).
std::unique_ptr<Tree> build_tree(Width width, bool hq, const std::vector<float>& xyz, std::vector<std::uint32_t> prims);

}  // namespace mbvh::tinybvh_peer

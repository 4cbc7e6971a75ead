// SPDX-License-Identifier: MIT
// source.h — triangles as a stream of chunks (a generator's output, a .mtri file's records):
// the record every streamed source shares, and how chunks become an in-core Scene.
#pragma once
#include <cstdint>
#include <functional>
#include <span>

#include "mbvh/lod.h"
#include "mbvh/scene.h"

namespace mbvh {

// SourceTri and ChunkFn are public (mbvh/lod.h): a TriangleSource streams them.

/// Appends triangles to an owned scene as they come, vertices not shared: triangle i gets the
/// vertices 3i, 3i + 1, 3i + 2 (a stream knows no vertex indices; the builders and the watertight
/// test need none, since equal coordinates are equal bits). Requires the scene to hold 3 vertices
/// a triangle already (as it does when built by this function alone).
inline void append_triangles(Scene& s, std::span<const SourceTri> tris) {
  for (const SourceTri& t : tris) {
    const auto v = static_cast<std::uint32_t>(s.vertices.size());
    s.vertices.push_back({t.v[0], t.v[1], t.v[2]});
    s.vertices.push_back({t.v[3], t.v[4], t.v[5]});
    s.vertices.push_back({t.v[6], t.v[7], t.v[8]});
    s.triangles.push_back({v, v + 1, v + 2});
  }
}

}  // namespace mbvh

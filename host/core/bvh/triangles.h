// SPDX-License-Identifier: MIT
// triangles.h — how the builders read a scene's triangles (internal to host/core/bvh/): one
// accessor type for the owned arrays and one for the caller's mesh views (mbvh/geometry.h), so a
// pass over the triangles is written once, as a generic lambda, and compiled once per kind;
// the owned scene's pass is the plain array walk it always was.
#pragma once
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "mbvh/scene.h"

namespace mbvh::build {

/// The owned arrays: triangle i is scene.triangles[i] of scene.vertices.
struct OwnedTriangles {
  const Vec3f* vertices;
  std::size_t vertex_count;
  const std::array<std::uint32_t, 3>* triangles;

  void get(std::size_t i, Vec3f& a, Vec3f& b, Vec3f& c) const {
    const auto& t = triangles[i];
    a = vertices[t[0]], b = vertices[t[1]], c = vertices[t[2]];
  }
  /// As get, but false (and a, b, c untouched) when an index is out of range.
  bool get_checked(std::size_t i, Vec3f& a, Vec3f& b, Vec3f& c) const {
    const auto& t = triangles[i];
    if (t[0] >= vertex_count || t[1] >= vertex_count || t[2] >= vertex_count) return false;
    get(i, a, b, c);
    return true;
  }
  /// Cache hints for a gather in another order than the scene's (refit's, in leaf order):
  /// triangle i's indices, then, once they have arrived, its vertices. Read nothing else.
  void prefetch_index(std::size_t i) const { __builtin_prefetch(&triangles[i]); }
  void prefetch_vertices(std::size_t i) const {
    const auto& t = triangles[i];
    for (int k = 0; k < 3; ++k) __builtin_prefetch(&vertices[t[k]]);
  }
};

/// The caller's meshes: prim i is triangle i - offset[g] of mesh g, offset[g] <= i < offset[g + 1].
struct ViewTriangles {
  const MeshView* meshes;
  const std::uint64_t* offsets;  ///< meshes + 1 entries
  std::size_t mesh_count;

  std::size_t mesh_of(std::size_t i) const {
    return geometry_index(offsets, mesh_count, i);
  }
  void get(std::size_t i, Vec3f& a, Vec3f& b, Vec3f& c) const {
    const std::size_t g = mesh_of(i);
    const MeshView& m = meshes[g];
    const auto t = m.triangle(i - static_cast<std::size_t>(offsets[g]));
    a = m.vertex(t[0]), b = m.vertex(t[1]), c = m.vertex(t[2]);
  }
  bool get_checked(std::size_t i, Vec3f& a, Vec3f& b, Vec3f& c) const {
    const std::size_t g = mesh_of(i);
    const MeshView& m = meshes[g];
    const auto t = m.triangle(i - static_cast<std::size_t>(offsets[g]));
    if (t[0] >= m.vertex_count || t[1] >= m.vertex_count || t[2] >= m.vertex_count) return false;
    a = m.vertex(t[0]), b = m.vertex(t[1]), c = m.vertex(t[2]);
    return true;
  }
  void prefetch_index(std::size_t) const {}  ///< no hints: finding the mesh costs a search
  void prefetch_vertices(std::size_t) const {}
};

/// Calls f with the scene's accessor (OwnedTriangles or ViewTriangles) and returns its result.
template <class F>
decltype(auto) with_triangles(const Scene& scene, F&& f) {
  if (scene.meshes().empty())
    return f(OwnedTriangles{scene.vertices.data(), scene.vertices.size(), scene.triangles.data()});
  std::vector<std::uint64_t> offsets(scene.meshes().size() + 1);
  for (std::size_t g = 0; g < offsets.size(); ++g) offsets[g] = scene.geometry_offset(g);
  return f(ViewTriangles{scene.meshes().data(), offsets.data(), scene.meshes().size()});
}

/// True when the three vertices are finite (Scene::validate's coordinate condition): x - x is
/// +0 for a finite x and NaN for an infinite or NaN one, and a NaN survives the sum (the build
/// has -fno-fast-math), so one compare checks all nine coordinates without a branch each.
inline bool finite(const Vec3f& a, const Vec3f& b, const Vec3f& c) {
  const float s = ((a.x - a.x) + (a.y - a.y) + (a.z - a.z)) + ((b.x - b.x) + (b.y - b.y) + (b.z - b.z)) +
                  ((c.x - c.x) + (c.y - c.y) + (c.z - c.z));
  return s == 0.0f;
}

}  // namespace mbvh::build

// SPDX-License-Identifier: MIT
// displace.cpp — the refit benchmarks' smooth vertex displacement, frame by frame.
#include "host/tools/displace.h"

#include <algorithm>
#include <bit>
#include <cassert>
#include <cmath>
#include <vector>

#include "mbvh/error.h"

namespace mbvh {

void displace_vertices(std::span<const Vec3f> original, std::span<Vec3f> moved, const Box& bounds, unsigned frame) {
  assert(moved.size() == original.size() && frame >= 1);
  const Vec3f e = bounds.extent();
  const float ext = std::max({e.x, e.y, e.z});
  const float amp = 0.002f * ext, phase = 0.7f * static_cast<float>(frame - 1);
  for (std::size_t i = 0; i < original.size(); ++i) {
    const Vec3f p = original[i];
    moved[i].x = p.x + amp * std::sin(6.0f * p.y / ext + phase);
    moved[i].y = p.y + amp * std::sin(6.0f * p.z / ext + phase);
    moved[i].z = p.z + amp * std::sin(6.0f * p.x / ext + phase);
  }
}

Scene without_degenerate(const Scene& scene, const Accel& acc) {
  if (!scene.meshes().empty()) throw Error(scene.display_name() + ": only an owned scene's vertices can be moved (no mesh views)");
  std::vector<bool> kept(scene.triangles.size(), false);
  for (const Tri& t : acc.tris()) kept[std::bit_cast<std::uint32_t>(t.v0[3])] = true;  // row 0 w: the prim id (a spatial split's second reference: the same)
  Scene out;
  out.name = scene.name;
  out.vertices = scene.vertices;
  for (std::size_t i = 0; i < scene.triangles.size(); ++i)
    if (kept[i]) out.triangles.push_back(scene.triangles[i]);
  return out;
}

}  // namespace mbvh

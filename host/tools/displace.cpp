// SPDX-License-Identifier: MIT
// displace.cpp — the refit benchmarks' smooth vertex displacement, frame by frame.
#include "host/tools/displace.h"

#include <algorithm>
#include <cassert>
#include <cmath>

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

}  // namespace mbvh

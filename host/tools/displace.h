// SPDX-License-Identifier: MIT
// displace.h — the smooth vertex displacement that moves a scene for the refit benchmarks
// (`mbvh info --refit`, `mbvh bench --dynamic`): deterministic, one field per frame.
#pragma once
#include <span>

#include "mbvh/scene.h"

namespace mbvh {

/// Sets moved[i] to original[i] moved by frame `frame`'s displacement field: each coordinate
/// shifted by 0.2 % of the largest extent E of `bounds` (the original scene's) times
/// sin(6·c/E + 0.7·(frame − 1)), c the next coordinate (x by y, y by z, z by x). Frame 1 is
/// `mbvh info --refit`'s displacement; each frame moves the original vertices (nothing
/// accumulates), so every vertex travels a smooth closed path of amplitude 0.2 % E around its
/// original place and a refit of the original build stays about as good frame after frame.
/// Requires moved.size() == original.size() and frame >= 1. O(vertices), one thread.
void displace_vertices(std::span<const Vec3f> original, std::span<Vec3f> moved, const Box& bounds, unsigned frame);

}  // namespace mbvh

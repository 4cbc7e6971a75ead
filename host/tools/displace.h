// SPDX-License-Identifier: MIT
// displace.h — the smooth vertex displacement that moves a scene for the refit benchmarks
// (`mbvh info --refit`, `mbvh bench --dynamic`): deterministic, one field per frame.
#pragma once
#include <span>

#include "mbvh/accel.h"
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

/// `scene` (an owned scene: no mesh views) with only the triangles `acc`, its build, keeps: the
/// degenerate (zero-area) ones left out, the rest in scene order, renumbered; vertices and name
/// as they are. A displacement gives a degenerate triangle whose vertices are distinct area,
/// which Accel::refit refuses (it is in no leaf); without them every frame refits. Throws Error
/// for a scene of mesh views. O(triangles).
Scene without_degenerate(const Scene& scene, const Accel& acc);

}  // namespace mbvh

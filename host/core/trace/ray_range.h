// SPDX-License-Identifier: MIT
// ray_range.h — check_ray_range (mbvh/trace.h) against a box instead of a build: what a caller
// that traces the rays of one scene part by part checks against the whole scene's bounds
// (host/mpi/data_parallel.cpp), since each part's build has smaller bounds of its own.
#pragma once
#include <span>
#include <string>

#include "mbvh/mbvh_layout.h"
#include "mbvh/scene.h"

namespace mbvh {

/// check_ray_range with S taken from `bounds` (an empty box accepts every ray): throws the same
/// Error, naming `who`, for the first valid ray of `rays` outside the range traced exactly in a
/// scene of these bounds. Cost: a few operations a ray.
void check_ray_range(const Box& bounds, std::span<const Ray> rays, const std::string& who);

}  // namespace mbvh

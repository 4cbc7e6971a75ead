// SPDX-License-Identifier: MIT
// stress.h — deterministic stress rays for numerical robustness (shared by the stress tests and
// `mbvh check --kind inside|special`): rays from inside a closed mesh aimed exactly at its
// vertices and edge midpoints, and rays that hit the special cases of the box and triangle tests.
#pragma once
#include <cstdint>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/scene.h"

namespace mbvh {

/// Rays from `inside` toward every vertex and every edge midpoint of the scene (directions are
/// target - origin, computed in float, so they aim exactly at the shared feature), at most
/// `max_features` of them spread over the mesh, plus `random` uniformly random directions.
/// For a closed mesh around `inside` every one of them must hit.
std::vector<Ray> feature_rays(const Scene& scene, const Vec3f& inside, std::size_t max_features, std::size_t random,
                              std::uint64_t seed);

/// A point inside a generated closed mesh (sphere, cube, torus, grid; after @scale/@offset):
/// the box centre, or a point on the torus's core circle.
Vec3f inside_point(const Scene& scene);

/// Special rays for `scene`: axis-aligned with +0/-0 components, denormal direction components,
/// rays lying in triangle planes and aimed at the triangle, rays along the faces of the scene box,
/// huge and infinite tmax, tmin = tmax at a hit, and invalid rays (tmin > tmax, NaN and infinite
/// components, zero direction). About `count` rays, deterministic by seed.
std::vector<Ray> special_rays(const Scene& scene, const Accel& acc, std::size_t count, std::uint64_t seed);

}  // namespace mbvh

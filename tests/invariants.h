// SPDX-License-Identifier: MIT
// invariants.h — the builder invariants the build and refit tests check (tests/invariants.cpp).
#pragma once
#include "mbvh/accel.h"
#include "mbvh/geometry.h"
#include "mbvh/scene.h"

namespace mbvh_test {

/// True when `inner` lies inside `outer` (closed boxes).
bool contains(const mbvh::Box& outer, const mbvh::Box& inner);
/// CHECKs every invariant of `acc`, built from `scene`, with Catch2.
void check_invariants(const mbvh::Scene& scene, const mbvh::Accel& acc);

}  // namespace mbvh_test

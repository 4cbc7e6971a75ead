// SPDX-License-Identifier: MIT
// test_checked_build.cpp — what only checked builds (Debug and the sanitizers: MBVH_CHECK_TERMINATION)
// do: a traversal handed a cyclic tree directly throws at its step bound instead of looping. Compiled
// in each build with its own definitions, like build_config.cpp (the traversals it instantiates take
// the build's StepGuard); release builds have no such test (validate_layout guards them, tested in
// test_stress.cpp).
#include <catch2/catch.hpp>

#include <cmath>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/mbvh.h"

#ifdef MBVH_CHECK_TERMINATION
using namespace mbvh;

TEST_CASE("stress: a checked build bounds the steps of a traversal handed a cyclic tree", "[stress]") {
  const Scene s = load_scene("gen:soup:2000");
  const auto acc = Accel::build(s);
  // a root whose four children are itself, with boxes every ray enters: a cycle
  Mbvh4 cyclic4 = acc->mbvh4();
  for (int k = 0; k < 4; ++k) {
    Node4& n = cyclic4.nodes[0];
    n.child[k] = 0;
    n.lo_x[k] = n.lo_y[k] = n.lo_z[k] = -1e30f;
    n.hi_x[k] = n.hi_y[k] = n.hi_z[k] = 1e30f;
  }
  TraceView v;
  v.n4 = cyclic4.nodes.data();
  v.nodes = cyclic4.nodes.size();
  v.leaves = acc->leaves().data();
  v.leaf_count = acc->leaves().size();
  v.tris = acc->tris().data();
  RayPre r;
  const Box b = acc->bounds();
  const Vec3f c = b.center();
  REQUIRE(prepare_ray(Ray{c.x, c.y, c.z, 0, 0.3f, 0.5f, 0.8f, INFINITY}, r));
  NoStats st;
  CHECK_THROWS_WITH((trace_mbvh4_stack<false>(v, r, st)), Catch::Contains("stack overflow") || Catch::Contains("step bound"));
  CHECK_THROWS_WITH((trace_mbvh4_bitstack<false>(v, r, st)), Catch::Contains("step bound"));
  CHECK_THROWS_WITH((trace_mbvh4_bitstack<true>(v, r, st)), Catch::Contains("step bound"));
}
#endif

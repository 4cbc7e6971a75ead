// SPDX-License-Identifier: MIT
// test_reinsert.cpp — the high-quality build's reinsertion (host/core/bvh/reinsert.cpp): the
// optimised tree keeps every invariant of the binary BVH (depth-first order, parent links,
// heights, the depth cap, the SBVH's leaves with their triangles), its SAH is no higher than the
// SBVH's, it is the same at 1 and 2 threads, and it traces the same hits as the default build.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cstring>
#include <map>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/reinsert.h"
#include "host/core/bvh/sbvh.h"
#include "host/core/layouts.h"
#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/helpers.h"
#include "tests/invariants.h"

using namespace mbvh;
using mbvh_test::contains;

namespace {

// An SBVH of `scene` (with or without spatial splits) as Accel::build makes it for quality high,
// before reinsertion.
SbvhResult sbvh_of(const Scene& scene, const BuildOptions& opt, bool spatial = true) {
  std::vector<Box> boxes(scene.triangle_count());
  std::vector<std::uint32_t> idx;
  for (std::uint32_t p = 0; p < scene.triangle_count(); ++p) {
    Vec3f v[3];
    scene.triangle(p, v[0], v[1], v[2]);
    if (!build::has_area(v[0], v[1], v[2])) continue;
    for (const Vec3f& x : v) boxes[p].grow(x);
    idx.push_back(p);
  }
  return build_sbvh(scene, opt, boxes, idx, spatial);
}

// The structural invariants of a Bvh2 with its leaves over `prims`: depth-first order (a child
// after its parent, the first child's subtree right after it), parent links, heights, leaves in
// depth-first order covering `prims` in order, boxes containing their children, the depth cap.
void check_tree(const Bvh2& b, const std::vector<Leaf>& leaves, const std::vector<std::uint32_t>& prims, unsigned cap) {
  REQUIRE(!b.nodes.empty());
  REQUIRE(b.nodes[0].parent == MBVH_NONE);
  REQUIRE(b.leaf_boxes.size() == leaves.size());
  std::size_t next_node = 0, next_leaf = 0, covered = 0;
  // depth-first walk in child order: records must appear in exactly that order
  struct Item {
    std::int32_t ref, parent;
    std::uint32_t depth;
  };
  std::vector<Item> stack{{0, MBVH_NONE, 0}};
  std::vector<std::uint32_t> height(b.nodes.size(), 0);
  std::size_t visited = 0;
  while (!stack.empty()) {
    const Item it = stack.back();
    stack.pop_back();
    REQUIRE(it.depth <= cap);
    if (it.ref < 0) {
      const std::size_t l = static_cast<std::size_t>(~it.ref);
      REQUIRE(l == next_leaf++);
      REQUIRE(leaves[l].first == covered);
      REQUIRE(leaves[l].count >= 1);
      covered += leaves[l].count;
      continue;
    }
    const std::size_t i = static_cast<std::size_t>(it.ref);
    REQUIRE(i == next_node++);  // inner nodes in depth-first order
    ++visited;
    const Bvh2::Node& n = b.nodes[i];
    REQUIRE(n.parent == it.parent);
    for (int k = 1; k >= 0; --k) {
      REQUIRE(n.child[k] != MBVH_EMPTY);
      REQUIRE(contains(n.box, b.box(n.child[k])));
      stack.push_back({n.child[k], it.ref, it.depth + 1});
    }
  }
  REQUIRE(visited == b.nodes.size());
  REQUIRE(next_leaf == leaves.size());
  REQUIRE(covered == prims.size());
  // heights: levels below to the deepest leaf, within the cap
  for (std::size_t i = b.nodes.size(); i-- > 0;) {
    std::uint32_t h = 0;
    for (std::int32_t c : b.nodes[i].child) h = std::max(h, 1 + (c >= 0 ? height[static_cast<std::size_t>(c)] : 0u));
    height[i] = h;
    REQUIRE(b.nodes[i].height == h);
  }
  REQUIRE(height[0] <= cap);
}

// Each leaf's triangles, keyed by its box: the leaves as a set, whatever their order.
std::multimap<std::string, std::vector<std::uint32_t>> leaf_set(const Bvh2& b, const std::vector<Leaf>& leaves,
                                                                 const std::vector<std::uint32_t>& prims) {
  std::multimap<std::string, std::vector<std::uint32_t>> m;
  for (std::size_t l = 0; l < leaves.size(); ++l) {
    std::string key(reinterpret_cast<const char*>(&b.leaf_boxes[l]), sizeof(Box));
    m.emplace(key, std::vector<std::uint32_t>(prims.begin() + leaves[l].first, prims.begin() + leaves[l].first + leaves[l].count));
  }
  return m;
}

}  // namespace

TEST_CASE("reinsertion keeps the binary tree's invariants, lowers its SAH and is deterministic", "[build][quality]") {
  for (const std::string& spec : {std::string("gen:soup:6000"), mbvh_test::scene_path("sibenik.obj.zst")}) {
    for (unsigned cap : {unsigned(MBVH_BINARY_DEPTH_CAP), 12u}) {
      if (cap != MBVH_BINARY_DEPTH_CAP && spec.find("gen:") != 0) continue;  // the cap on the small scene only
      INFO(spec << ", depth cap " << cap);
      const Scene s = load_scene(spec);
      BuildOptions o;
      o.quality = BuildQuality::high;
      o.threads = 2;
      o.depth_cap = cap;
      const SbvhResult before = sbvh_of(s, o);
      SbvhResult after = before;
      const build::ReinsertStats st = build::reinsert(after.bvh, after.leaves, after.prims, o);
      CHECK(st.rounds >= 1);
      CHECK(st.moved > 0);
      check_tree(after.bvh, after.leaves, after.prims, cap);
      // the same leaves (boxes and triangles), only placed elsewhere; the same statistics
      CHECK(leaf_set(after.bvh, after.leaves, after.prims) == leaf_set(before.bvh, before.leaves, before.prims));
      CHECK(after.bvh.nodes.size() == before.bvh.nodes.size());
      CHECK(after.bvh.largest_leaf == before.bvh.largest_leaf);
      CHECK(after.bvh.forced_leaves == before.bvh.forced_leaves);
      // the SAH falls (inner nodes only change)
      const double sah0 = build::sah_of_binary(before.bvh, before.leaves, o.traversal_cost);
      const double sah1 = build::sah_of_binary(after.bvh, after.leaves, o.traversal_cost);
      CHECK(st.inner_area_after < st.inner_area_before);
      CHECK(sah1 < sah0);
      // the build through Accel: the same bytes at 1 and 2 threads, valid layouts, and the SAH of
      // the optimised tree: the lower of the two candidates' (with and without spatial splits),
      // which the build keeps with its references
      if (cap != MBVH_BINARY_DEPTH_CAP) continue;
      SbvhResult flat = sbvh_of(s, o, false);
      {  // no spatial split: every triangle referenced once
        std::vector<std::uint32_t> ids = flat.prims;
        std::sort(ids.begin(), ids.end());
        CHECK(std::adjacent_find(ids.begin(), ids.end()) == ids.end());
        CHECK(flat.references <= before.references);
      }
      build::reinsert(flat.bvh, flat.leaves, flat.prims, o);
      check_tree(flat.bvh, flat.leaves, flat.prims, cap);
      const double sah_flat = build::sah_of_binary(flat.bvh, flat.leaves, o.traversal_cost);
      const auto acc2 = Accel::build(s, o);
      BuildOptions o1 = o;
      o1.threads = 1;
      const auto acc1 = Accel::build(s, o1);
      CHECK(acc1->hash() == acc2->hash());
      CHECK(acc2->binary_stats().sah_cost == Approx(std::min(sah1, sah_flat)).epsilon(1e-9));
      CHECK(acc2->tris().size() == (sah_flat < sah1 ? flat.references : after.references));
      REQUIRE_NOTHROW(validate_layout(acc2->mbvh2(), acc2->leaves().size()));
      REQUIRE_NOTHROW(validate_layout(acc2->mbvh4(), acc2->leaves().size()));
      REQUIRE_NOTHROW(validate_layout(acc2->mbvh8(), acc2->leaves().size()));
      // the same closest hits as the default build's tree on diffuse rays (the cpu backend)
      const auto med = Accel::build(s);
      RayGenOptions ro;
      ro.kind = RayKind::diffuse;
      ro.count = 10000;
      const std::vector<Ray> rays = generate_rays(s, *med, ro);
      auto be = make_backend("cpu", BackendOptions{});
      for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) {
        TraceOptions to;
        to.layout = l;
        TraceOutput a, b;
        be->trace(*acc2, rays, to, a);
        be->trace(*med, rays, to, b);
        REQUIRE(a.hits.size() == rays.size());
        CHECK(std::memcmp(a.hits.data(), b.hits.data(), rays.size() * sizeof(Hit)) == 0);
      }
    }
  }
}

// SPDX-License-Identifier: MIT
// test_refit.cpp — refit: a refitted build traces moved vertices as a fresh build does, and every box
// of every layout is exact, the same bytes at any thread count.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "host/core/bvh/wide_node.h"  // slot_box
#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/backend.h"
#include "host/tools/check.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "host/tools/raygen.h"
#include "mbvh/trace.h"
#include "tests/backends.h"
#include "tests/helpers.h"
#include "tests/invariants.h"

using namespace mbvh;
using mbvh::build::slot_box;
using mbvh_test::check_invariants;

TEST_CASE("refit: a refitted build traces moved vertices as a fresh build does on every backend", "[build]") {
  const VariantGrid grid = mbvh_test::all_backends();
  const Scene a = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  Scene b = a;  // the same triangles, every vertex moved by a smooth non-rigid displacement
  b.name = "bunny, deformed";
  for (Vec3f& v : b.vertices) {
    const Vec3f p = v;
    v.x = p.x + 0.01f * std::sin(40.0f * p.y);
    v.y = p.y + 0.01f * std::sin(30.0f * p.z);
    v.z = p.z + 0.01f * std::sin(20.0f * p.x);
  }
  auto acc = Accel::build(a);
  // every layout and pack made, and every backend prepared (device copies) on the old positions
  for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) acc->make_layout(l);
  acc->mbvh4_wide();
  acc->tri_packs();
  RayGenOptions ro_a;
  ro_a.count = 1000;
  const std::vector<Ray> rays_a = generate_rays(a, *acc, ro_a);
  std::vector<std::unique_ptr<Backend>> backends;
  for (const std::string& name : grid.backends) {
    backends.push_back(make_backend(name));
    for (Layout l : grid.layouts)
      for (Traversal t : grid.traversals)
        if (backends.back()->supports(l, t)) {
          TraceOutput out;
          backends.back()->trace(*acc, rays_a, TraceOptions{l, t, Query::closest, false}, out);
        }
  }
  // a scene of another size, or a vertex out of range, is refused and leaves the build as it was
  const std::uint64_t h0 = acc->hash();
  Scene smaller = b;
  smaller.triangles.pop_back();
  CHECK_THROWS_AS(acc->refit(smaller), Error);
  Scene far = b;
  far.vertices[a.triangles[0][0]].x = 0x1p41f;
  CHECK_THROWS_AS(acc->refit(far), Error);
  CHECK(acc->hash() == h0);
  CHECK(acc->generation() == 0);

  acc->refit(b);
  CHECK(acc->generation() == 1);
  CHECK(acc->hash() != h0);
  check_invariants(b, *acc);
  const auto fresh = Accel::build(b);
  CHECK(acc->bounds().lo.x == fresh->bounds().lo.x);
  CHECK(acc->bounds().hi.z == fresh->bounds().hi.z);
  CHECK(acc->tris().size() == fresh->tris().size());

  for (RayKind kind : {RayKind::primary, RayKind::diffuse}) {
    INFO(to_string(kind) << " rays");
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = 10000;
    const std::vector<Ray> rays = generate_rays(b, *fresh, ro);
    // the fresh build's answers (cpu-scalar) against every backend on the refitted build: the
    // same t bit for bit, the same triangle except where two triangles tie at that t
    TraceOutput want[2];
    for (int q = 0; q < 2; ++q)
      trace_reference(*fresh, rays, TraceOptions{Layout::mbvh4, Traversal::stack, q ? Query::any : Query::closest, false},
                      want[q], 0);
    std::size_t hits = 0;
    for (const Hit& h : want[0].hits) hits += h.prim != MBVH_MISS_PRIM;
    CHECK(hits > (kind == RayKind::primary ? rays.size() / 10 : 0));
    for (auto& backend : backends) {
      if (backend->peer()) continue;  // its own BVH and test: checked up to ties by run_check below
      for (Layout l : grid.layouts)
        for (Traversal t : grid.traversals)
          for (Query q : grid.queries) {
            if (!backend->supports(l, t)) continue;
            TraceOutput got;
            backend->trace(*acc, rays, TraceOptions{l, t, q, false}, got);
            INFO(backend->name() << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
            std::size_t bad = 0;
            if (q == Query::closest) {
              for (std::size_t i = 0; i < rays.size(); ++i) {
                const Hit &w = want[0].hits[i], &g = got.hits[i];
                const bool same_t = std::memcmp(&w.t, &g.t, sizeof(float)) == 0;
                bad += !same_t || (w.prim == g.prim && std::memcmp(&w, &g, sizeof(Hit)) != 0);
              }
            } else {
              bad = got.occluded == want[1].occluded ? 0 : 1;
            }
            CHECK(bad == 0);
          }
    }
    CheckOptions co;
    co.grid = grid;
    co.brute_rays = 2000;
    const CheckReport rep = run_check(*acc, rays, co);
    INFO(rep.table(rays));
    CHECK(rep.mismatches() == 0);
  }
}

namespace {

bool same_bits(const Box& a, const Box& b) { return std::memcmp(&a, &b, sizeof(Box)) == 0; }

// Every box of a wide layout is its child's exactly: a leaf's box, or the union of the child
// node's slots.
template <class M>
std::size_t wide_box_faults(const M& m, const Bvh2& b) {
  using N = typename decltype(m.nodes)::value_type;
  constexpr int W = static_cast<int>(sizeof(N::child) / sizeof(N::child[0]));
  std::size_t bad = 0;
  for (const N& n : m.nodes)
    for (int s = 0; s < W; ++s) {
      const std::int32_t c = n.child[s];
      if (c == MBVH_EMPTY) continue;
      Box want;
      if (c < 0) want = b.leaf_boxes[static_cast<std::size_t>(~c)];
      else
        for (int g = 0; g < W; ++g)
          if (m.nodes[static_cast<std::size_t>(c)].child[g] != MBVH_EMPTY)
            want.grow(slot_box(m.nodes[static_cast<std::size_t>(c)], g));  // Box::grow, refit's union
      bad += !same_bits(want, slot_box(n, s));
    }
  return bad;
}

template <class V>
bool same_bytes(const V& a, const V& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(a[0])) == 0;
}

}  // namespace

TEST_CASE("refit: every box of every layout is exact, the same bytes at 1 2 3 threads, and refitting back restores the build", "[build]") {
  for (BuildQuality q : {BuildQuality::medium, BuildQuality::low}) {
    INFO(to_string(q));
    const Scene a = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
    Scene b = a;
    for (Vec3f& v : b.vertices) {
      const Vec3f p = v;
      v.x = p.x + 0.01f * std::sin(40.0f * p.y);
      v.y = p.y + 0.01f * std::sin(30.0f * p.z);
      v.z = p.z + 0.01f * std::sin(20.0f * p.x);
    }
    std::unique_ptr<Accel> first;
    for (unsigned t = 1; t <= 3; ++t) {
      INFO(t << " threads");
      BuildOptions o;
      o.quality = q;
      o.threads = t;
      auto acc = Accel::build(a, o);
      const std::uint64_t built = acc->hash();
      for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) acc->make_layout(l);
      acc->mbvh4_wide();
      acc->tri_packs().mt();
      acc->refit(b);
      const Bvh2& bv = acc->bvh2();
      REQUIRE(bv.nodes.size() > 3 * 4096);  // the refit's parallel cut has subtrees and upper nodes
      // exact: leaves from the triangles, nodes from their children, every layout from these
      std::size_t bad = 0;
      for (std::size_t i = 0; i < acc->leaves().size(); ++i) {
        Box want;
        const Leaf& l = acc->leaves()[i];
        for (std::uint32_t k = l.first; k < l.first + l.count; ++k) {
          const Tri& tr = acc->tris()[k];
          Vec3f p[3];
          b.triangle(tri_prim(tr), p[0], p[1], p[2]);
          bad += tr.v0[0] != p[0].x || tr.v1[1] != p[1].y || tr.v2[2] != p[2].z;
          Box tb;
          tb.lo = {std::min(std::min(p[0].x, p[1].x), p[2].x), std::min(std::min(p[0].y, p[1].y), p[2].y),
                   std::min(std::min(p[0].z, p[1].z), p[2].z)};
          tb.hi = {std::max(std::max(p[0].x, p[1].x), p[2].x), std::max(std::max(p[0].y, p[1].y), p[2].y),
                   std::max(std::max(p[0].z, p[1].z), p[2].z)};
          want.grow(tb);
          const Tri4& pk = acc->tri_packs().packs[acc->tri_packs().leaves[i].first + (k - l.first) / 4];
          bad += pk.v[3][(k - l.first) % 4] != p[1].x || pk.v[8][(k - l.first) % 4] != p[2].z;
        }
        bad += !same_bits(want, bv.leaf_boxes[i]);
      }
      for (std::size_t i = 0; i < bv.nodes.size(); ++i) {
        const Bvh2::Node& nd = bv.nodes[i];
        Box want;
        for (int s = 0; s < 2; ++s)
          if (nd.child[s] != MBVH_EMPTY) want.grow(bv.box(nd.child[s]));
        bad += !same_bits(want, nd.box);
        const Node2& m2 = acc->mbvh2().nodes[i];
        const Box c0 = bv.box(nd.child[0]);
        bad += m2.c0[0] != c0.lo.x || m2.c0[1] != c0.hi.x || m2.zz[0] != c0.lo.z || m2.zz[1] != c0.hi.z;
      }
      CHECK(bad == 0);
      CHECK(same_bytes(acc->tri_packs().mt(), make_mt_packs(acc->tri_packs())));  // the fast packs made again
      CHECK(wide_box_faults(acc->mbvh4(), bv) == 0);
      CHECK(wide_box_faults(acc->mbvh8(), bv) == 0);
      for (std::size_t i = 0; i < acc->mbvh4().nodes.size(); ++i)
        for (int s = 0; s < 4; ++s)
          bad += acc->mbvh4_wide().nodes[i].lo[s][1] != acc->mbvh4().nodes[i].lo_y[s] ||
                 acc->mbvh4_wide().nodes[i].hi[s][2] != acc->mbvh4().nodes[i].hi_z[s];
      CHECK(bad == 0);
      // the same bytes at any thread count
      if (t == 1) {
        first = std::move(acc);
        continue;
      }
      CHECK(acc->hash() == first->hash());
      CHECK(same_bytes(acc->mbvh2().nodes, first->mbvh2().nodes));
      CHECK(same_bytes(acc->mbvh4().nodes, first->mbvh4().nodes));
      CHECK(same_bytes(acc->mbvh8().nodes, first->mbvh8().nodes));
      CHECK(same_bytes(acc->tri_packs().packs, first->tri_packs().packs));
      CHECK(acc->binary_stats().sah_cost == first->binary_stats().sah_cost);
      CHECK(acc->mbvh4().stats.sah_cost == first->mbvh4().stats.sah_cost);
      // a vertex no triangle uses may hold anything (Scene::validate checks the used ones)
      Scene b2 = b;
      b2.vertices.push_back({NAN, 0x1p50f, 0});
      acc->refit(b2);
      CHECK(acc->hash() == first->hash());
      // back to the positions it was built for: the build's bytes again
      acc->refit(a);
      CHECK(acc->hash() == built);
      const auto fresh = Accel::build(a, o);
      CHECK(same_bytes(acc->mbvh4().nodes, fresh->mbvh4().nodes));
      CHECK(same_bytes(acc->mbvh8().nodes, fresh->mbvh8().nodes));
      CHECK(same_bytes(acc->mbvh2().nodes, fresh->mbvh2().nodes));
      CHECK(acc->mbvh4().stats.sah_cost == Approx(fresh->mbvh4().stats.sah_cost).epsilon(1e-9));
      CHECK(acc->binary_stats().sah_cost == Approx(fresh->binary_stats().sah_cost).epsilon(1e-9));
    }
  }
}

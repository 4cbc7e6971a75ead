// SPDX-License-Identifier: MIT
// test_instances.cpp — instancing (InstanceScene, mbvh/instance.h) on every SIMD cpu backend that
// runs here: each ray's answer equals, bit for bit, the exact answer of the contract computed
// without the top level (every instance's mesh query on its object-space ray), and matches the
// double brute force over the flattened scene up to classified ties (zero genuine mismatches),
// under rotations, non-uniform scales, a mirror and far translations; hits name the right
// instance, geometry and triangle; ray masks skip instances; refit after a move; any hit; zero
// instances; bad input refused by name.
#include <catch2/catch.hpp>

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/error.h"
#include "mbvh/instance.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

/// The contract's answer without the top level: every instance whose mask meets `mask`, traced
/// on its object-space ray by a query made apart from the scene's; the smallest t, equal t to the
/// smaller instance (Hit.prim holds the flattened prim id).
Hit contract_answer(const InstanceScene& s, const std::vector<RayQuery>& q, const Ray& ray, std::uint32_t mask) {
  Hit best{INFINITY, 0, 0, MBVH_MISS_PRIM};
  if (!ray_valid(ray)) return best;
  for (std::size_t i = 0; i < s.instance_count(); ++i) {
    if (!(s.instance(i).mask & mask)) continue;
    const Hit h = q[s.instance(i).mesh].intersect(s.object_ray(i, ray));
    if (h.prim != MBVH_MISS_PRIM && h.t < best.t)
      best = Hit{h.t, h.u, h.v, static_cast<std::uint32_t>(s.flat_offset(i) + h.prim)};
  }
  return best;
}
bool contract_occluded(const InstanceScene& s, const std::vector<RayQuery>& q, const Ray& ray, std::uint32_t mask) {
  if (!ray_valid(ray)) return false;
  for (std::size_t i = 0; i < s.instance_count(); ++i)
    if ((s.instance(i).mask & mask) && q[s.instance(i).mesh].occluded(s.object_ray(i, ray))) return true;
  return false;
}

bool same_bits(const Hit& a, const Hit& b) { return std::memcmp(&a, &b, sizeof a) == 0; }

/// Rays of several kinds into the flattened scene, `n` of each.
std::vector<Ray> rays_for(const Scene& flat, const Accel& acc, std::size_t n, std::uint64_t seed) {
  std::vector<Ray> rays;
  for (RayKind k : {RayKind::primary, RayKind::random, RayKind::diffuse, RayKind::shadow}) {
    RayGenOptions o;
    o.kind = k;
    o.count = n;
    o.seed = seed;
    const std::vector<Ray> r = generate_rays(flat, acc, o);
    rays.insert(rays.end(), r.begin(), r.end());
  }
  return rays;
}

/// The transforms under test: rotation, non-uniform scale, mirror (negative determinant), and
/// their products; all moved by (far, far, -far) (a scene far from the origin).
std::vector<Affine> transforms(float far) {
  std::vector<Affine> t = {Affine::identity(),
          Affine::translation(3, 0, 0) * Affine::rotation(1, 2, 3, 0.7f),
          Affine::translation(0, 3, 0) * Affine::scale(2.5f, 0.4f, 1.3f),
          Affine::translation(0, 0, 3) * Affine::scale(-1, 1, 1),  // mirror
          Affine::translation(-3, 1, 0) * Affine::rotation(0, 1, 0, 2.1f) * Affine::scale(0.7f, -1.6f, 0.9f),
          Affine::translation(2, -3, 2) * Affine::rotation(1, 0, 1, -1.1f) * Affine::scale(3, 1, 2)};
  for (Affine& a : t) a = Affine::translation(far, far, -far) * a;
  return t;
}

/// Every ray through `s` on both queries against the contract's answer (bit for bit) and the
/// flattened brute force (zero genuine mismatches); returns the comparison.
Comparison check_scene(const InstanceScene& s, Backend& backend, const std::vector<std::shared_ptr<const Accel>>& meshes,
                       const std::vector<Ray>& rays, float far = 0) {
  std::vector<RayQuery> q;
  for (const auto& m : meshes) q.push_back(backend.ray_query(*m));
  const Scene flat = s.flatten();
  const auto flat_acc = Accel::build(flat);
  InstanceOutput out, occ;
  s.trace(rays, Query::closest, out);
  s.trace(rays, Query::any, occ);
  REQUIRE(out.hits.size() == rays.size());
  std::vector<Hit> brute(rays.size());
  std::size_t contract_diff = 0, occ_diff = 0;
  for (std::size_t k = 0; k < rays.size(); ++k) {
    const InstanceHit& h = out.hits[k];
    const Hit mine{h.t, h.u, h.v, static_cast<std::uint32_t>(s.flat_prim(h))};
    contract_diff += same_bits(mine, contract_answer(s, q, rays[k], ~0u)) ? 0 : 1;
    occ_diff += (occ.occluded[k] != 0) == contract_occluded(s, q, rays[k], ~0u) ? 0 : 1;
    REQUIRE(same_bits(Hit{h.t, h.u, h.v, h.prim_id}, [&] {  // the single-ray call equals the batch
      const InstanceHit one = s.intersect(rays[k]);
      return Hit{one.t, one.u, one.v, one.prim_id};
    }()));
    brute[k] = brute_force(*flat_acc, rays[k]);
  }
  CHECK(contract_diff == 0);
  CHECK(occ_diff == 0);
  const Comparison c = compare_flattened(s, flat, rays, out.hits, brute);
  INFO("vs flattened brute force: " << c.equal << " equal, " << c.ties << " ties, " << c.mismatches
                                    << " mismatches of " << c.rays);
  CHECK(c.mismatches == 0);
  CHECK(c.equal >= c.rays * 95 / 100);  // far from the origin the flattened vertices round coarsely: more ties
  // the rule is not blind: answers with every hit dropped are mismatches, but for edge hits
  std::vector<InstanceHit> dropped(out.hits.size());
  std::size_t hits = 0;
  for (const InstanceHit& h : out.hits) hits += h.hit() ? 1 : 0;
  const Comparison bad = compare_flattened(s, flat, rays, dropped, brute);
  // (far from the origin the flattened triangles' own rounding, 2^-24 of 3e5 = 0.018 on unit
  // spheres, is a good part of a triangle: there the tolerance covers most hits, and only the
  // contract's bit-for-bit check above is sharp)
  if (far <= 1e4f) CHECK(bad.mismatches >= hits * 7 / 10);
  CHECK(hits > rays.size() / 10);
  return c;
}

}  // namespace

TEST_CASE("instances: answers equal the contract's bit for bit and the flattened brute force up to ties",
          "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) {
    WARN("no SIMD cpu backend runs here: nothing to test");
    return;
  }
  const std::shared_ptr<const Accel> sphere = Accel::build(generate_scene("sphere:24"));
  const std::shared_ptr<const Accel> soup = Accel::build(generate_scene("soup:300:5"));
  for (const std::string& name : names) {
    auto backend = make_backend(name);
    for (float far : {0.0f, 1e4f, 3e5f}) {
      INFO(name << ", far translation " << far);
      std::vector<Instance> inst;
      const std::vector<Affine> tf = transforms(far);
      for (std::size_t i = 0; i < tf.size(); ++i) inst.push_back({static_cast<std::uint32_t>(i % 2), tf[i]});
      const InstanceScene s = InstanceScene::build(*backend, {sphere, soup}, inst);
      const Scene flat = s.flatten();
      const auto flat_acc = Accel::build(flat);
      check_scene(s, *backend, {sphere, soup}, rays_for(flat, *flat_acc, 400, 11), far);
    }
  }
}

TEST_CASE("instances: hits name the instance, the geometry and the triangle", "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  // one mesh of two geometries (unit quads side by side at z = 0), a second of one
  const float quad_a[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  const float quad_b[12] = {2, 0, 0, 3, 0, 0, 3, 1, 0, 2, 1, 0};
  const std::uint32_t idx[6] = {0, 1, 2, 0, 2, 3};
  Scene two;
  REQUIRE(two.add_mesh({quad_a, 4, 12, idx, 2, 12}) == 0);
  REQUIRE(two.add_mesh({quad_b, 4, 12, idx, 2, 12}) == 1);
  const std::shared_ptr<const Accel> m0 = Accel::build(two);
  const std::shared_ptr<const Accel> m1 = Accel::build(generate_scene("cube:2"));
  auto backend = make_backend(names[0]);
  std::vector<Instance> inst;
  for (int i = 0; i < 6; ++i)
    inst.push_back({0, Affine::translation(10.0f * float(i), 0, 0) * Affine::rotation(0, 0, 1, 0.3f * float(i)) *
                           Affine::scale(i % 2 ? -1.5f : 1.0f, 0.5f + float(i), 1)});
  inst.push_back({1, Affine::translation(0, 20, 0)});
  const InstanceScene s = InstanceScene::build(*backend, {m0, m1}, inst);
  // a ray straight down onto the centroid of each triangle of each quad instance
  std::size_t checked = 0;
  for (std::uint32_t i = 0; i < 6; ++i)
    for (std::uint32_t g = 0; g < 2; ++g)
      for (std::uint32_t p = 0; p < 2; ++p) {
        const float* v = g == 0 ? quad_a : quad_b;
        Vec3f c{};
        for (int k = 0; k < 3; ++k)
          for (int a = 0; a < 3; ++a) c[a] += v[3 * idx[3 * p + k] + a] / 3;
        const Vec3f w = inst[i].transform.apply(c);
        const Ray ray{w.x, w.y, 5, 0, 0, 0, -1, INFINITY};
        const InstanceHit h = s.intersect(ray);
        INFO("instance " << i << ", geometry " << g << ", triangle " << p);
        REQUIRE(h.hit());
        CHECK(h.inst_id == i);
        CHECK(h.geom_id == g);
        CHECK(h.prim_id == p);
        CHECK(std::fabs(h.t - 5) < 1e-5f);
        CHECK(s.flat_prim(h) == s.flat_offset(i) + 2 * g + p);
        ++checked;
      }
  CHECK(checked == 24);
  const InstanceHit cube = s.intersect(Ray{0, 20, 10, 0, 0, 0, -1, INFINITY});
  CHECK(cube.inst_id == 6);
  CHECK(cube.geom_id == 0);
  CHECK(std::fabs(cube.t - 9) < 1e-5f);  // the cube spans [-1, 1]
  const InstanceHit miss = s.intersect(Ray{0, -50, 5, 0, 0, 0, -1, INFINITY});
  CHECK(!miss.hit());
  CHECK(miss.inst_id == kInvalidInstance);
  CHECK(miss.geom_id == kInvalidGeometry);
  CHECK(miss.prim_id == MBVH_MISS_PRIM);
  CHECK(s.flat_prim(miss) == MBVH_MISS_PRIM);
}

TEST_CASE("instances: ray masks skip the instances they do not meet", "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  auto backend = make_backend(names[0]);
  const std::shared_ptr<const Accel> sphere = Accel::build(generate_scene("sphere:16"));
  // two spheres on the z axis, the nearer one of mask 0x1, the farther of 0x2, a third of both
  std::vector<Instance> inst = {{0, Affine::translation(0, 0, 0), 0x1},
                                {0, Affine::translation(0, 0, -4), 0x2},
                                {0, Affine::translation(5, 0, 0), 0x3}};
  InstanceScene s = InstanceScene::build(*backend, {sphere}, inst);
  const Ray down{0.01f, 0.02f, 10, 0, 0, 0, -1, INFINITY};
  CHECK(s.intersect(down).inst_id == 0);
  CHECK(s.intersect(down, 0x1).inst_id == 0);
  CHECK(s.intersect(down, 0x2).inst_id == 1);
  CHECK(!s.intersect(down, 0x4).hit());
  CHECK(s.occluded(down, 0x2));
  CHECK(!s.occluded(down, 0x4));
  // a batch with one mask per ray, against the contract's answer with that mask
  std::vector<RayQuery> q{backend->ray_query(*sphere)};
  const Scene flat = s.flatten();
  const auto flat_acc = Accel::build(flat);
  const std::vector<Ray> rays = rays_for(flat, *flat_acc, 300, 5);
  std::vector<std::uint32_t> masks(rays.size());
  for (std::size_t k = 0; k < rays.size(); ++k) masks[k] = static_cast<std::uint32_t>(k % 4);
  InstanceOutput out, occ;
  s.trace(rays, Query::closest, out, masks);
  s.trace(rays, Query::any, occ, masks);
  std::size_t masked_hits = 0;
  for (std::size_t k = 0; k < rays.size(); ++k) {
    const Hit want = contract_answer(s, q, rays[k], masks[k]);
    CHECK(s.flat_prim(out.hits[k]) == want.prim);
    CHECK((occ.occluded[k] != 0) == contract_occluded(s, q, rays[k], masks[k]));
    if (out.hits[k].hit()) CHECK((s.instance(out.hits[k].inst_id).mask & masks[k]) != 0);
    if (masks[k] == 0) CHECK(!out.hits[k].hit());
    masked_hits += masks[k] != 0 && out.hits[k].hit() ? 1 : 0;
  }
  CHECK(masked_hits > 0);
  // a mask change takes effect at refit
  s.set_mask(0, 0x2);
  CHECK_THROWS_WITH(s.intersect(down), Catch::Contains("refit"));
  s.refit();
  CHECK(s.intersect(down, 0x2).inst_id == 0);
  CHECK(!s.intersect(down, 0x1).hit());
  const std::vector<std::uint32_t> short_masks(3, 1);
  CHECK_THROWS_WITH(s.trace(rays, Query::closest, out, short_masks), Catch::Contains("3 masks"));
}

TEST_CASE("instances: refit and rebuild after moving instances equal a fresh build", "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  auto backend = make_backend(names[0]);
  const std::shared_ptr<const Accel> sphere = Accel::build(generate_scene("sphere:20"));
  std::vector<Instance> inst;
  for (int i = 0; i < 12; ++i)
    inst.push_back({0, Affine::translation(3.0f * float(i % 4), 3.0f * float(i / 4), 0) * Affine::scale(1, 1 + 0.1f * float(i), 1)});
  InstanceScene s = InstanceScene::build(*backend, {sphere}, inst);
  // move a third of them far and rotate others
  for (std::size_t i = 0; i < inst.size(); i += 3) {
    inst[i].transform = Affine::translation(-20, 5.0f * float(i), 7) * Affine::rotation(1, 1, 0, 0.5f * float(i));
    s.set_transform(i, inst[i].transform);
  }
  CHECK_THROWS_WITH(s.intersect(Ray{0, 0, 10, 0, 0, 0, -1, INFINITY}), Catch::Contains("refit"));
  s.refit();
  const InstanceScene fresh = InstanceScene::build(*backend, {sphere}, inst);
  const Scene flat = fresh.flatten();
  const auto flat_acc = Accel::build(flat);
  const std::vector<Ray> rays = rays_for(flat, *flat_acc, 300, 9);
  InstanceOutput a, b;
  s.trace(rays, Query::closest, a);
  fresh.trace(rays, Query::closest, b);
  std::size_t diff = 0;
  for (std::size_t k = 0; k < rays.size(); ++k)
    diff += std::memcmp(&a.hits[k], &b.hits[k], sizeof(InstanceHit)) == 0 ? 0 : 1;
  CHECK(diff == 0);
  check_scene(s, *backend, {sphere}, rays);
  s.rebuild();
  s.trace(rays, Query::closest, a);
  for (std::size_t k = 0; k < rays.size(); ++k) diff += std::memcmp(&a.hits[k], &b.hits[k], sizeof(InstanceHit)) == 0 ? 0 : 1;
  CHECK(diff == 0);
  CHECK(s.stats().instances == 12);
  CHECK(s.stats().leaves == 12);
}

TEST_CASE("instances: zero instances and zero meshes are a scene every ray misses", "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  auto backend = make_backend(names[0]);
  const std::shared_ptr<const Accel> sphere = Accel::build(generate_scene("sphere:8"));
  for (const auto& meshes : {std::vector<std::shared_ptr<const Accel>>{}, std::vector<std::shared_ptr<const Accel>>{sphere}}) {
    const InstanceScene s = InstanceScene::build(*backend, meshes, {});
    const Ray r{0, 0, 5, 0, 0, 0, -1, INFINITY};
    CHECK(!s.intersect(r).hit());
    CHECK(!s.occluded(r));
    CHECK(s.bounds().empty());
    CHECK(s.instance_count() == 0);
    CHECK(s.flatten().triangle_count() == 0);
    InstanceOutput out;
    const std::vector<Ray> rays(5, r);
    s.trace(rays, Query::closest, out);
    REQUIRE(out.hits.size() == 5);
    for (const InstanceHit& h : out.hits) CHECK(!h.hit());
  }
}

TEST_CASE("instances: invalid rays are counted misses; bad input is refused by name", "[instances]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  auto backend = make_backend(names[0]);
  const std::shared_ptr<const Accel> sphere = Accel::build(generate_scene("sphere:8"));
  const InstanceScene ok = InstanceScene::build(*backend, {sphere}, {{0, Affine::identity()}});
  InstanceOutput out;
  const std::vector<Ray> rays = {Ray{0, 0, 5, 0, 0, 0, -1, INFINITY}, Ray{0, 0, 5, 0, 0, 0, 0, INFINITY},
                                 Ray{NAN, 0, 5, 0, 0, 0, -1, INFINITY}};
  ok.trace(rays, Query::closest, out);
  CHECK(out.hits[0].hit());
  CHECK(!out.hits[1].hit());
  CHECK(!out.hits[2].hit());
  CHECK(out.invalid == 2);

  using Catch::Contains;
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {sphere}, {{1, Affine::identity()}}),
                    Contains("instance 0 names mesh 1, out of range (1 meshes)"));
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {nullptr}, {}), Contains("mesh 0 is null"));
  Affine nan = Affine::identity();
  nan.m[6] = NAN;
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {sphere}, {{0, Affine::identity()}, {0, nan}}),
                    Contains("instance 1: transform entry m[6] (row 1, column 2) is nan"));
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {sphere}, {{0, Affine::scale(1, 0, 1)}}),
                    Contains("instance 0: transform is singular (determinant 0)"));
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {sphere}, {{0, Affine::scale(1, 1e-7f, 1)}}),
                    Contains("ill-conditioned"));
  CHECK_THROWS_WITH(InstanceScene::build(*backend, {sphere}, {{0, Affine::translation(1e13f, 0, 0)}}),
                    Contains("beyond kMaxCoordinate"));
  CHECK_THROWS_WITH(Affine::rotation(0, 0, 0, 1), Contains("axis"));
  InstanceScene s = InstanceScene::build(*backend, {sphere}, {{0, Affine::identity()}});
  CHECK_THROWS_WITH(s.set_transform(3, Affine::identity()), Contains("instance 3 out of range (1 instances)"));
  CHECK_THROWS_WITH(s.set_transform(0, Affine::scale(0, 0, 0)), Contains("singular"));
  CHECK(s.intersect(rays[0]).hit());  // a refused move leaves the scene as it was, not stale
  auto scalar = make_backend("cpu-scalar");
  CHECK_THROWS_WITH(InstanceScene::build(*scalar, {sphere}, {}), Contains("single-ray"));
}

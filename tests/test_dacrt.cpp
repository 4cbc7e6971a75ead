// SPDX-License-Identifier: MIT
// test_dacrt.cpp — divide-and-conquer ray tracing without a hierarchy (the dacrt backends): the
// reference's answers on every shared scene and the generated ones, every ray kind, closest and
// any hit (bytes equal on at least 99.99 % of the rays, every other ray a classified tie), the same
// bytes from dacrt and dacrt-scalar and at any thread count, every setting, the degenerate
// inputs, and clear errors for bad settings.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/backends.h"
#include "mbvh/error.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

const std::size_t kRays = mbvh_test::sanitized() ? 5000 : 30000;

/// The dacrt backends this machine runs (dacrt-scalar always; dacrt where the CPU has AVX2).
std::vector<std::string> dacrt_backends() {
  std::vector<std::string> names;
  for (const std::string& n : runnable_backends())
    if (n.rfind("dacrt", 0) == 0 && mbvh_test::backend_selected(n)) names.push_back(n);
  REQUIRE(std::find(names.begin(), names.end(), "dacrt-scalar") != names.end());
  return names;
}

TraceOptions dacrt_options(Query q, Precision p = Precision::robust) {
  TraceOptions o;
  o.traversal = Traversal::dacrt;
  o.query = q;
  o.precision = p;
  return o;
}

/// The reference's answers for `q`: the single-ray traversal whose answers dacrt gives (closest
/// hit the ordered stack, any hit the stack, MBVH4).
const TraceOutput& reference(const Accel& acc, const std::vector<Ray>& rays, Query q, TraceOutput (&cache)[2]) {
  TraceOutput& out = cache[q == Query::any ? 1 : 0];
  if (out.hits.empty() && out.occluded.empty() && !rays.empty())
    trace_reference(acc, rays, TraceOptions{Layout::mbvh4, packet_single_ray(Layout::mbvh4, q == Query::any), q}, out, 0);
  return out;
}

/// `got` against the reference: the same bytes on at least 99.99 % of the rays (order-dependent
/// corner ties may differ, DESIGN.md), every difference settled by the oracle, the same invalid count.
void require_reference(const Accel& acc, const std::vector<Ray>& rays, Query q, const TraceOutput& got,
                       TraceOutput (&cache)[2]) {
  const TraceOutput& ref = reference(acc, rays, q, cache);
  CHECK(got.invalid == ref.invalid);
  const TieRule settle = oracle_settlement(acc, rays, oracle_tie_rule(acc, rays));
  std::size_t differ = 0;
  Comparison c;
  if (q == Query::closest) {
    REQUIRE(got.hits.size() == rays.size());
    c = compare_hit_arrays(got.hits, ref.hits, {}, settle);
    differ = rays.size() - c.bit_identical;
  } else {
    REQUIRE(got.occluded.size() == rays.size());
    TraceOutput closest;
    trace_reference(acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest}, closest, 0);
    c = compare_occlusion_arrays(got.occluded, ref.occluded, closest.hits, rays, {}, {}, settle);
    for (std::size_t i = 0; i < rays.size(); ++i) differ += got.occluded[i] != ref.occluded[i];
  }
  CHECK(c.mismatches == 0);
  CHECK(differ <= std::max<std::size_t>(1, rays.size() / 10000));
  if (differ) std::printf("dacrt: %zu of %zu rays differ from the reference's bytes (classified ties)\n", differ, rays.size());
}

bool same_bytes(const TraceOutput& a, const TraceOutput& b) {
  return a.invalid == b.invalid && a.occluded == b.occluded && a.hits.size() == b.hits.size() &&
         (a.hits.empty() || std::memcmp(a.hits.data(), b.hits.data(), a.hits.size() * sizeof(Hit)) == 0);
}

/// Every dacrt backend on `rays`, both queries: the reference's answers, and the same bytes from
/// each backend and at 1 and 2 threads with chunks small enough that a batch has several.
void check_rays(const Accel& acc, const std::vector<Ray>& rays, const BackendOptions& settings = {}) {
  TraceOutput cache[2];
  for (Query q : {Query::closest, Query::any}) {
    TraceOutput first;
    bool have_first = false;
    for (const std::string& name : dacrt_backends())
      for (unsigned threads : {1u, 2u}) {
        BackendOptions bo = settings;
        bo.threads = threads;
        if (threads == 2 && !bo.settings.count("dacrt.chunk")) bo.set("dacrt.chunk", std::to_string(rays.size() / 3 + 1));
        auto b = make_backend(name, bo);
        INFO(name << ", " << threads << " thread(s), " << to_string(q) << ", " << b->describe());
        TraceOutput got;
        b->trace(acc, rays, dacrt_options(q), got);
        if (!have_first) {
          require_reference(acc, rays, q, got, cache);
          first = std::move(got);
          have_first = true;
        } else {
          CHECK(same_bytes(got, first));
        }
      }
  }
}

void check_scene(const std::string& spec, std::size_t n = kRays) {
  const Scene scene = load_scene(spec);
  const auto acc = Accel::build(scene);
  for (RayKind kind : {RayKind::primary, RayKind::shadow, RayKind::diffuse, RayKind::random, RayKind::path}) {
    INFO(spec << ", " << to_string(kind) << " rays");
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = n;
    check_rays(*acc, generate_rays(scene, *acc, ro));
  }
}

Scene triangles(const std::vector<float>& v, const std::vector<std::uint32_t>& idx) {
  Scene s;
  for (std::size_t i = 0; i + 2 < v.size(); i += 3) s.vertices.push_back(Vec3f{v[i], v[i + 1], v[i + 2]});
  for (std::size_t i = 0; i + 2 < idx.size(); i += 3) s.triangles.push_back({idx[i], idx[i + 1], idx[i + 2]});
  return s;
}

}  // namespace

TEST_CASE("dacrt: the reference's answers on the Cornell box, every ray kind, both backends and thread counts",
          "[dacrt][isa]") {
  check_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
}
TEST_CASE("dacrt: the reference's answers on a closed sphere", "[dacrt][isa]") { check_scene("gen:sphere:256"); }
TEST_CASE("dacrt: the reference's answers on the Stanford bunny", "[dacrt][heavy]") {
  check_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
}
TEST_CASE("dacrt: the reference's answers on Sibenik", "[dacrt][heavy]") { check_scene(mbvh_test::scene_path("sibenik.obj.zst")); }
TEST_CASE("dacrt: the reference's answers on Sponza", "[dacrt][heavy]") {
  check_scene(mbvh_test::scene_path("sponza_dabrovic.obj.zst"));
}
TEST_CASE("dacrt: the reference's answers on the conference room", "[dacrt][heavy]") {
  check_scene(mbvh_test::scene_path("conference.obj.zst"), 20000);
}
TEST_CASE("dacrt: the reference's answers on a closed cube, a triangle soup and a hairball", "[dacrt][heavy]") {
  check_scene("gen:cube:24");
  check_scene("gen:soup:100000", 20000);
  check_scene("gen:hairball:300000", 20000);
}

TEST_CASE("dacrt: every setting keeps the answers (SAH, middle, unordered, the deepest recursion, one-ray chunks)",
          "[dacrt][isa]") {
  const Scene scene = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(scene);
  RayGenOptions ro;
  ro.kind = RayKind::diffuse;
  ro.count = 8000;
  const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
  const BackendOptions cases[] = {
      BackendOptions{}.set("dacrt.partition", "sah"),
      BackendOptions{}.set("dacrt.partition", "middle").set("dacrt.ordered", "0"),
      BackendOptions{}.set("dacrt.leaf-rays", "1").set("dacrt.leaf-tris", "1"),
      BackendOptions{}.set("dacrt.ratio", "0").set("dacrt.bins", "2"),
      BackendOptions{}.set("dacrt.chunk", "1"),
      BackendOptions{}.set("dacrt.chunk", "9").set("dacrt.leaf-rays", "100000"),
  };
  for (const BackendOptions& bo : cases) {
    std::string what;
    for (const auto& [k, v] : bo.settings) what += k + "=" + v + " ";
    INFO(what);
    check_rays(*acc, rays, bo);
  }
}

TEST_CASE("dacrt: rays from inside closed meshes never leak", "[dacrt][isa]") {
  for (const char* spec : {"gen:sphere:256", "gen:cube:24"}) {
    const Scene scene = load_scene(spec);
    const auto acc = Accel::build(scene);
    RayGenOptions ro;
    ro.kind = RayKind::inside;
    ro.count = 20000;
    const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
    for (const std::string& name : dacrt_backends()) {
      INFO(spec << ", " << name);
      for (Query q : {Query::closest, Query::any}) {
        TraceOutput out;
        make_backend(name)->trace(*acc, rays, dacrt_options(q), out);
        std::size_t leaks = 0;
        for (std::size_t i = 0; i < rays.size(); ++i)
          leaks += q == Query::any ? out.occluded[i] == 0 : out.hits[i].prim == MBVH_MISS_PRIM;
        CHECK(leaks == 0);
      }
    }
  }
}

TEST_CASE("dacrt: degenerate inputs - equal centroids, one triangle, zero-area triangles, every sign, 0 to 9 rays",
          "[dacrt][isa]") {
  // a stack of 40 identical triangles (every centroid equal: no split), a lone triangle beside
  // them and two zero-area ones (left out by the build)
  std::vector<float> v = {0, 0, 0, 1, 0, 0, 0, 1, 0, 3, 3, 3, 4, 3, 3, 3, 4, 3, 5, 5, 5, 6, 6, 6, 7, 7, 7};
  std::vector<std::uint32_t> idx;
  for (int i = 0; i < 40; ++i) idx.insert(idx.end(), {0, 1, 2});
  idx.insert(idx.end(), {3, 4, 5, 6, 7, 8, 0, 0, 1});
  const Scene scene = triangles(v, idx);
  const auto acc = Accel::build(scene);
  const Scene one = triangles({0, 0, 0, 1, 0, 0, 0, 1, 0}, {0, 1, 2});
  const auto acc1 = Accel::build(one);
  // rays of every direction sign pattern and the axis-parallel ones, through both groups, with
  // tmax = inf, tmin > 0 and a few invalid ones
  std::vector<Ray> rays;
  for (int sx = -1; sx <= 1; ++sx)
    for (int sy = -1; sy <= 1; ++sy)
      for (int sz = -1; sz <= 1; ++sz)
        for (float f : {0.25f, 3.25f}) {
          const float d[3] = {float(sx), float(sy), float(sz)};
          Ray r{f - 2 * d[0], f - 2 * d[1], f + 0.1f - 2 * d[2], 0.0f, d[0], d[1], d[2], INFINITY};
          rays.push_back(r);
          r.tmin = 1.0f;
          r.tmax = 50.0f;
          rays.push_back(r);
        }
  rays.push_back(Ray{0.2f, 0.2f, 5.0f, 0.0f, 0.0f, 0.0f, -1.0f, INFINITY});  // axis-parallel, straight down
  rays.push_back(Ray{0.2f, 0.2f, 5.0f, 0.0f, 0.0f, 0.0f, 0.0f, INFINITY});   // invalid: zero direction
  rays.push_back(Ray{0.2f, 0.2f, 5.0f, 2.0f, 0.0f, 0.0f, -1.0f, 1.0f});      // invalid: tmin > tmax
  rays.push_back(Ray{NAN, 0.2f, 5.0f, 0.0f, 0.0f, 0.0f, -1.0f, INFINITY});   // invalid: NaN
  for (const auto* a : {acc.get(), acc1.get()}) {
    check_rays(*a, rays);
    for (std::size_t n : {0, 1, 7, 8, 9}) {
      INFO(n << " rays");
      const std::vector<Ray> few(rays.end() - static_cast<std::ptrdiff_t>(std::max<std::size_t>(n, 1)), rays.end());
      check_rays(*a, std::vector<Ray>(few.begin(), few.begin() + static_cast<std::ptrdiff_t>(n)));
    }
  }
  // the straight-down ray hits the stack: the smallest prim id of the equal hits
  TraceOutput out;
  make_backend("dacrt-scalar")->trace(*acc, std::span<const Ray>(rays).subspan(rays.size() - 4, 1), dacrt_options(Query::closest), out);
  CHECK(out.hits[0].prim == 0);
  CHECK(out.hits[0].t == Approx(5.0f));
}

TEST_CASE("dacrt: the fast precision gives the cpu backends' fast answers", "[dacrt][isa]") {
  const Scene scene = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(scene);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 8000;
  const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
  // Moller-Trumbore with the relaxed slab test: dacrt-scalar's operations are cpu-scalar's, the
  // SIMD dacrt's lanes the SIMD cpu backends' (FMA, the refined reciprocal): the same answers but
  // for the order-dependent ties and the rays a non-watertight test may lose either way
  const std::pair<const char*, const char*> pairs[] = {{"dacrt-scalar", "cpu-scalar"}, {"dacrt", "cpu"}};
  for (const auto& [d, c] : pairs) {
    if (!mbvh_test::backend_selected(d) || !make_backend(c)) continue;
    INFO(d << " vs " << c);
    TraceOutput got, ref;
    make_backend(d)->trace(*acc, rays, dacrt_options(Query::closest, Precision::fast), got);
    TraceOptions o{Layout::mbvh4, Traversal::stack_ordered, Query::closest};
    o.precision = Precision::fast;
    make_backend(c)->trace(*acc, rays, with_leaves_of(*make_backend(c), o), ref);
    std::size_t differ = 0, hits = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
      differ += std::memcmp(&got.hits[i], &ref.hits[i], sizeof(Hit)) != 0;
      hits += got.hits[i].prim != MBVH_MISS_PRIM;
    }
    CHECK(hits > rays.size() / 2);
    CHECK(differ <= rays.size() / 1000);
  }
}

TEST_CASE("dacrt: statistics count its work, answers unchanged", "[dacrt]") {
  const Scene scene = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(scene);
  RayGenOptions ro;
  ro.count = 3000;
  const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
  for (const std::string& name : dacrt_backends()) {
    auto b = make_backend(name);
    TraceOutput plain, counted;
    TraceOptions o = dacrt_options(Query::closest);
    b->trace(*acc, rays, o, plain);
    o.stats = true;
    b->trace(*acc, rays, o, counted);
    CHECK(std::memcmp(plain.hits.data(), counted.hits.data(), rays.size() * sizeof(Hit)) == 0);
    REQUIRE(counted.stats.size() == rays.size());
    std::size_t tris = 0, tests = 0;
    for (const RayStats& s : counted.stats) {
      tris += s.tris;
      tests += s.box_tests;
      CHECK(s.nodes <= s.box_tests);
    }
    CHECK(tris > 0);
    CHECK(tests >= rays.size());
  }
}

TEST_CASE("dacrt: bad settings and unsupported variants are clear errors", "[dacrt]") {
  const std::pair<const char*, const char*> bad[] = {
      {"dacrt.partition", "best"}, {"dacrt.ratio", "-1"}, {"dacrt.ratio", "nan"},      {"dacrt.bins", "1"},
      {"dacrt.bins", "65"},        {"dacrt.leaf-rays", "0"}, {"dacrt.leaf-tris", "x"}, {"dacrt.chunk", "0"},
      {"dacrt.ordered", "maybe"},  {"dacrt.depth", "3"},
  };
  for (const auto& [k, v] : bad) {
    INFO(k << "=" << v);
    try {
      make_backend("dacrt-scalar", BackendOptions{}.set(k, v));
      FAIL("accepted");
    } catch (const Error& e) {
      CHECK(std::string(e.what()).find(k) != std::string::npos);
    }
  }
  auto b = make_backend("dacrt-scalar");
  CHECK_FALSE(b->supports(Layout::mbvh4, Traversal::stack));
  CHECK(b->supports(Layout::mbvh8, Traversal::dacrt));
  const auto acc = Accel::build(load_scene("gen:sphere:16"));
  const std::vector<Ray> rays(3, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  TraceOutput out;
  CHECK_THROWS_WITH(b->trace(*acc, rays, TraceOptions{Layout::mbvh4, Traversal::bitstack}, out),
                    Catch::Contains("dacrt-scalar"));
  b->trace(*acc, rays, TraceOptions{}, out);  // the defaults: its own traversal, dacrt
  CHECK(resolve_options(*b, TraceOptions{}).traversal == Traversal::dacrt);
}

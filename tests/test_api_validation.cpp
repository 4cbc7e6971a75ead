// SPDX-License-Identifier: MIT
// test_api_validation.cpp — the library refuses what it cannot use with an Error, never undefined
// behaviour: out-of-range indices and non-finite vertices in Accel::build, any thread count,
// cameras that cannot make rays (and a view along `up`, which can), comparison arrays that do not
// line up, and rays the embree peer cannot take.
#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <limits>
#include <stdexcept>
#include <thread>
#include <vector>

#include "mbvh/config.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "mbvh/error.h"
#include "mbvh/log.h"
#include "tests/helpers.h"
#include "host/core/parallel.h"
#include "host/tools/raygen.h"
#include "host/tools/render.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

Scene one_triangle() {
  Scene s;
  s.name = "tri";
  s.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  s.triangles = {{0, 1, 2}};
  return s;
}

std::string build_error(const Scene& s, const BuildOptions& o = {}) {
  try {
    Accel::build(s, o);
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace

TEST_CASE("Accel::build refuses out-of-range indices and NaN or infinite vertices and names them", "[api]") {
  Scene s = one_triangle();
  s.triangles.push_back({0, 1, 7});
  CHECK_THAT(build_error(s), Catch::Contains("tri: triangle 1 names vertex 7, out of range (the scene has 3 vertices)"));
  s.triangles[1] = {0, 1, std::numeric_limits<std::uint32_t>::max()};
  CHECK_THAT(build_error(s), Catch::Contains("triangle 1") && Catch::Contains("out of range"));
  for (float bad : {NAN, INFINITY, -INFINITY}) {
    Scene t = one_triangle();
    t.vertices[2].y = bad;
    INFO(bad);
    CHECK_THAT(build_error(t), Catch::Contains("tri: vertex 2 of triangle 0 has coordinate y") && Catch::Contains("finite"));
  }
  // an unused non-finite vertex is not looked at
  Scene u = one_triangle();
  u.vertices.push_back({NAN, 0, 0});
  CHECK_NOTHROW(Accel::build(u));
  BuildOptions o;
  o.traversal_cost = NAN;
  CHECK_THAT(build_error(one_triangle(), o), Catch::Contains("traversal_cost"));
  o.traversal_cost = -1;
  CHECK_THAT(build_error(one_triangle(), o), Catch::Contains("traversal_cost"));
  // a generator whose modifiers overflow the floats is refused when it is generated
  CHECK_THROWS_WITH(load_scene("gen:sphere:8@scale=3e38@offset=3e38"),
                    Catch::Contains("gen:sphere:8@scale=3e38@offset=3e38") && Catch::Contains("inf"));
}

TEST_CASE("any thread count is safe - clamped to kMaxThreads with the build and the trace unchanged", "[api]") {
  CHECK(resolve_threads(1) == 1);
  CHECK(resolve_threads(536870912u) == kMaxThreads);
  CHECK(resolve_threads(UINT32_MAX) == kMaxThreads);
  CHECK(resolve_threads(0) >= 1);
  const Scene s = load_scene("gen:soup:20000");
  BuildOptions one, huge;
  one.threads = 1;
  huge.threads = 536870912u;  // 8 * threads wrapped to 0 in the builder's subtree size: SIGFPE
  const auto a = Accel::build(s, one);
  const auto b = Accel::build(s, huge);
  CHECK(a->hash() == b->hash());
  BackendOptions bo;
  bo.threads = UINT32_MAX;
  for (const char* name : {"cpu-scalar", "cpu"}) {
    auto backend = make_backend(name, bo);
    CHECK_THAT(backend->describe(), Catch::Contains(std::to_string(kMaxThreads) + " thread(s)"));
    RayGenOptions ro;
    ro.count = 1000;
    const std::vector<Ray> rays = generate_rays(s, *a, ro);
    TraceOutput out;
    backend->trace(*a, rays, TraceOptions{}, out);
    CHECK(out.hits.size() == rays.size());
  }
}

TEST_CASE("a camera looking along its up vector makes rays - one that cannot is an Error", "[api]") {
  const Scene s = load_scene("gen:sphere:16");
  const auto acc = Accel::build(s);
  RayGenOptions o;
  o.count = 400;
  o.has_camera = true;
  for (const Vec3f eye : {Vec3f{0, 2.5f, 0}, Vec3f{0, -2.5f, 0}}) {  // straight down, straight up: parallel to (0, 1, 0)
    o.camera.eye = eye;
    o.camera.target = {0, 0, 0};
    const std::vector<Ray> rays = generate_rays(s, *acc, o);
    TraceOutput out;
    trace_reference(*acc, rays, TraceOptions{}, out, 1);
    std::size_t valid = 0, hits = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
      valid += ray_valid(rays[i]);
      hits += out.hits[i].prim != MBVH_MISS_PRIM;
    }
    CHECK(valid == rays.size());
    CHECK(hits > rays.size() / 4);  // the sphere fills the middle of the view
    CHECK(hits < rays.size());
    const Ray centre = camera_ray(o.camera, 0.5, 0.5);
    CHECK(std::fabs(centre.dy - (eye.y > 0 ? -1.0f : 1.0f)) < 1e-6f);
  }
  struct Bad {
    Camera c;
    const char* says;
  };
  Camera eq, nan_eye, inf_target, fov0, fov180, up0;
  eq.eye = eq.target = {1, 2, 3};
  nan_eye.eye = {NAN, 0, 5};
  inf_target.eye = {0, 0, 5};
  inf_target.target = {INFINITY, 0, 0};
  fov0.eye = fov180.eye = up0.eye = {0, 0, 5};
  fov0.fov_deg = 0;
  fov180.fov_deg = 180;
  up0.up = {0, 0, 0};
  for (const Bad& b : {Bad{eq, "eye equals the target"}, Bad{nan_eye, "eye is not finite"},
                       Bad{inf_target, "target is not finite"}, Bad{fov0, "field of view"}, Bad{fov180, "field of view"},
                       Bad{up0, "up vector is zero"}}) {
    INFO(b.says);
    CHECK_THAT(camera_problem(b.c), Catch::Contains(b.says));
    o.camera = b.c;
    CHECK_THROWS_WITH(generate_rays(s, *acc, o), Catch::Contains("camera: ") && Catch::Contains(b.says));
    RenderOptions ro;
    ro.width = ro.height = 4;
    ro.spp = 1;
    ro.has_camera = true;
    ro.camera = b.c;
    ro.traversal = Traversal::stack;
    auto backend = make_backend("cpu-scalar");
    CHECK_THROWS_WITH(render(s, *acc, *backend, ro), Catch::Contains("render: camera: ") && Catch::Contains(b.says));
  }
  CHECK(camera_problem(default_camera(acc->bounds())).empty());
}

TEST_CASE("comparisons refuse arrays that do not line up", "[api]") {
  const std::vector<Hit> two(2), three(3);
  const std::vector<std::uint8_t> o2(2), o3(3);
  const std::vector<Ray> r2(2);
  const std::vector<std::size_t> bad_index{0, 5};
  CHECK_THROWS_WITH(compare_hit_arrays(two, three), Catch::Contains("compare_hit_arrays") && Catch::Contains("2 and 3"));
  CHECK_THROWS_AS(compare_hit_arrays(two, two, std::vector<std::size_t>{0}), Error);
  CHECK_NOTHROW(compare_hit_arrays(two, two));
  CHECK_THROWS_AS(compare_occlusion_arrays(o2, o3, two, r2), Error);
  CHECK_THROWS_WITH(compare_occlusion_arrays(o2, o2, three, r2), Catch::Contains("3 closest hits for 2 answers"));
  CHECK_THROWS_WITH(compare_occlusion_arrays(o2, o2, two, std::vector<Ray>(1)), Catch::Contains("1 rays for 2 answers"));
  CHECK_THROWS_WITH(compare_occlusion_arrays(o2, o2, two, r2, bad_index), Catch::Contains("names ray 5 of 2"));
  CHECK_NOTHROW(compare_occlusion_arrays(o2, o2, two, r2));
}

TEST_CASE("every backend traces an empty batch and refuses a traversal or precision it lacks with one message",
          "[api]") {
  const Scene s = load_scene("gen:cube:4");
  const auto acc = Accel::build(s);
  const std::vector<Ray> rays(1, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  for (const std::string& name : mbvh_test::all_backends().backends) {
    INFO(name);
    auto backend = make_backend(name);
    std::size_t refused = 0;
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
      for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered, Traversal::bitstack_retest,
                          Traversal::packet_ranged, Traversal::packet_partition, Traversal::packet, Traversal::dacrt}) {
        INFO(to_string(l) << " " << to_string(t));
        if (!backend->supports(l, t)) {  // Backend::trace refuses it before the backend sees it
          TraceOutput out;
          CHECK_THROWS_WITH(backend->trace(*acc, rays, TraceOptions{l, t}, out),
                            Catch::StartsWith(name + ": traversal '" + to_string(t) + "' is not implemented for " +
                                              to_string(l) + " ("));
          ++refused;
          continue;
        }
        for (Query q : {Query::closest, Query::any}) {
          TraceOutput out;  // a reused output: an empty batch leaves it empty
          out.hits.assign(3, Hit{});
          out.occluded.assign(3, 1);
          out.invalid = 7;
          CHECK_NOTHROW(backend->trace(*acc, std::span<const Ray>(), TraceOptions{l, t, q, true}, out));
          CHECK(out.hits.empty());
          CHECK(out.occluded.empty());
          CHECK(out.stats.empty());
          CHECK(out.invalid == 0);
        }
      }
    CHECK(refused > 0);  // every backend lacks some pair (cpu: bitstack-retest on MBVH2)
    const Traversal t = backend->supports(Layout::mbvh4, Traversal::stack) ? Traversal::stack : Traversal::bitstack;
    for (Precision p : {Precision::robust, Precision::exact, Precision::fast})
      if (!backend->supports_precision(p)) {
        TraceOutput out;
        TraceOptions o{Layout::mbvh4, t};
        o.precision = p;
        CHECK_THROWS_WITH(backend->trace(*acc, rays, o, out),
                          Catch::StartsWith(name + ": precision '" + to_string(p) +
                                            "' is not available (its precisions: "));
      }
  }
}

#ifdef MBVH_HAVE_EMBREE
TEST_CASE("the embree peer reports a ray beyond what Embree accepts as an Error - the other backends trace it", "[api]") {
  const Scene s = load_scene("gen:sphere:16");
  const auto acc = Accel::build(s);
  auto embree = make_backend("embree");
  const TraceOptions o{Layout::mbvh4, Traversal::stack, Query::closest, false};
  std::vector<Ray> rays(4, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  TraceOutput out;
  embree->trace(*acc, rays, o, out);  // fine rays: hits
  CHECK(out.hits[0].prim != MBVH_MISS_PRIM);
  rays[3] = Ray{0, 0, 5, 0, -2e18f, 0, 0, INFINITY};  // valid by the contract; Embree asserts ray.valid()
  rays[2] = Ray{0, 0, 5, 0, 0, 0, -1e20f, INFINITY};
  for (Query q : {Query::closest, Query::any}) {
    TraceOptions oq = o;
    oq.query = q;
    CHECK_THROWS_WITH(embree->trace(*acc, rays, oq, out),
                      Catch::Contains("embree: ray 2 has direction z = -1e+20") && Catch::Contains("1.844e18"));
  }
  rays[2] = rays[0];
  CHECK_THROWS_WITH(embree->trace(*acc, rays, o, out), Catch::Contains("embree: ray 3 has direction x = -2e+18"));
  rays[3] = Ray{0, 0, 5, 0, -1.8e18f, 0, 0, INFINITY};  // within Embree's range: traced
  CHECK_NOTHROW(embree->trace(*acc, rays, o, out));
  // invalid rays stay defined misses, whatever their size
  rays[3] = Ray{INFINITY, 0, 0, 0, -1, 0, 0, INFINITY};
  CHECK_NOTHROW(embree->trace(*acc, rays, o, out));
  CHECK(out.invalid == 1);
  // mbvh's own backends trace the ray Embree refuses
  rays[3] = Ray{0, 0, 5, 0, -2e18f, 0, 0, INFINITY};
  auto scalar = make_backend("cpu-scalar");
  CHECK_NOTHROW(scalar->trace(*acc, rays, o, out));
  // an origin at 2e18 leaves the range traced exactly (check_ray_range): every backend refuses it
  // before Embree sees it
  rays[3] = Ray{2e18f, 0, 0, 0, -1, 0, 0, INFINITY};
  CHECK_THROWS_WITH(scalar->trace(*acc, rays, o, out), Catch::Contains("cpu-scalar: ray 3") && Catch::Contains("leaves the range traced exactly"));
  CHECK_THROWS_WITH(embree->trace(*acc, rays, o, out), Catch::Contains("embree: ray 3") && Catch::Contains("leaves the range traced exactly"));
  // a scene beyond Embree's range never reaches it: the build refuses anything beyond ±2^40
  // (kMaxCoordinate), far inside Embree's ±1.844e18 (the peer's own vertex check stays as a guard)
  CHECK_THROWS_WITH(Accel::build(load_scene("gen:sphere:8@scale=1e19")), Catch::Contains("is beyond +-2^40"));
}
#endif

TEST_CASE("parallel_for on the persistent pool - every chunk once - nested and concurrent calls - errors rethrown",
          "[api]") {
  // every chunk exactly once, chunk bounds as documented, worker ids below the thread count
  for (unsigned threads : {1u, 2u, 3u, 8u})
    for (std::size_t n : {std::size_t{1}, std::size_t{7}, std::size_t{1000}, std::size_t{4097}}) {
      std::vector<std::atomic<int>> seen(n);
      std::atomic<unsigned> max_worker{0};
      std::atomic<int> bad_bounds{0};  // Catch's CHECK is not thread-safe: count, check after
      mbvh::parallel_for(n, 64, threads, [&](std::size_t b, std::size_t e, unsigned w) {
        bad_bounds += b % 64 != 0 || e != std::min(n, b + 64);
        for (std::size_t i = b; i < e; ++i) ++seen[i];
        unsigned m = max_worker.load();
        while (w > m && !max_worker.compare_exchange_weak(m, w)) {}
      });
      CHECK(bad_bounds == 0);
      for (std::size_t i = 0; i < n; ++i) CHECK(seen[i] == 1);
      CHECK(max_worker < threads);
    }
  // a call from inside a running parallel_for runs inline (no deadlock on the pool)
  std::atomic<std::size_t> inner{0}, inner_workers{0};
  mbvh::parallel_for(64, 1, 4, [&](std::size_t, std::size_t, unsigned) {
    mbvh::parallel_for(10, 3, 4, [&](std::size_t b, std::size_t e, unsigned w) {
      inner_workers += w;
      inner += e - b;
    });
  });
  CHECK(inner == 640);
  CHECK(inner_workers == 0);
  // concurrent callers from other threads each get all their chunks
  std::vector<std::thread> callers;
  std::atomic<std::size_t> total{0};
  for (int c = 0; c < 4; ++c)
    callers.emplace_back([&] {
      for (int rep = 0; rep < 20; ++rep)
        mbvh::parallel_for(500, 7, 2, [&](std::size_t b, std::size_t e, unsigned) { total += e - b; });
    });
  for (std::thread& t : callers) t.join();
  CHECK(total == 4 * 20 * 500);
  // the first exception reaches the caller; the pool stays usable
  CHECK_THROWS_WITH(mbvh::parallel_for(100, 1, 2,
                                       [](std::size_t b, std::size_t, unsigned) {
                                         if (b == 50) throw std::runtime_error("chunk 50");
                                       }),
                    Catch::Contains("chunk 50"));
  std::atomic<std::size_t> after{0};
  mbvh::parallel_for(100, 1, 2, [&](std::size_t b, std::size_t e, unsigned) { after += e - b; });
  CHECK(after == 100);
  // calls back to back (the workers still polling for the next one) and calls apart (2 ms, past
  // the polling: the workers asleep on their condition variable) each get all their chunks
  for (const int gap_us : {0, 2000}) {
    std::atomic<std::size_t> got{0};
    for (int rep = 0; rep < 10; ++rep) {
      if (gap_us) std::this_thread::sleep_for(std::chrono::microseconds(gap_us));
      mbvh::parallel_for(64, 1, 3, [&](std::size_t b, std::size_t e, unsigned) { got += e - b; });
    }
    CHECK(got == 10 * 64);
  }
}

TEST_CASE("cpu.leaf-block chooses the leaves a cpu backend traces - the reference on the same leaves gives its bytes", "[api]") {
  const Scene s = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::diffuse;
  ro.count = 20000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  TraceOptions o;
  o.layout = Layout::mbvh8;
  o.traversal = Traversal::stack;
  for (const std::string& name : mbvh_test::all_backends().backends) {
    if (name.rfind("cpu", 0) != 0) continue;
    INFO(name);
    const unsigned own = name == "cpu-scalar" ? 1u : 4u;
    CHECK(make_backend(name)->leaf_block(o) == own);
    TraceOptions any = o;
    any.query = Query::any;
    CHECK(make_backend(name)->leaf_block(any) == own);  // one variant for both queries (memory: docs/backends.md)
    for (unsigned block : {1u, 2u, 8u}) {
      auto b = make_backend(name, BackendOptions{}.set("cpu.leaf-block", std::to_string(block)));
      CHECK(b->leaf_block(o) == block);
      TraceOptions asked = o;
      asked.leaf_block = 4;
      CHECK(b->leaf_block(asked) == 4);  // a call's own choice wins
      TraceOutput got, want;
      b->trace(*acc, rays, o, got);
      trace_reference(*acc, rays, with_leaves_of(*b, o), want, 0);
      CHECK(std::memcmp(got.hits.data(), want.hits.data(), rays.size() * sizeof(Hit)) == 0);
    }
    for (const char* bad : {"0", "65", "four"})
      CHECK_THROWS_WITH(make_backend(name, BackendOptions{}.set("cpu.leaf-block", bad)), Catch::Contains("cpu.leaf-block"));
  }
  TraceOutput out;
  TraceOptions wrong = o;
  wrong.leaf_block = 65;
  CHECK_THROWS_WITH(trace_reference(*acc, rays, wrong, out, 0), Catch::Contains("leaf block 65 is out of range"));
}

TEST_CASE("cpu.mic: the MIC path needs the AVX-512 kernels - cpu-avx2 refuses it by name, cpu-scalar accepts it", "[api][isa]") {
  CHECK(make_backend("cpu-scalar", BackendOptions{}.set("cpu.mic", "1")) != nullptr);
  for (const std::string& name : mbvh_test::simd_cpu_backends()) {
    INFO(name);
    CHECK_THROWS_WITH(make_backend(name, BackendOptions{}.set("cpu.mic", "maybe")), Catch::Contains("cpu.mic='maybe'"));
    if (name == "cpu-avx2")
      CHECK_THROWS_WITH(make_backend(name, BackendOptions{}.set("cpu.mic", "1")),
                        Catch::Contains("cpu.mic=1") && Catch::Contains("AVX-512") && Catch::Contains("'cpu-avx2'"));
    else
      CHECK_THAT(make_backend(name, BackendOptions{}.set("cpu.mic", "1"))->describe(), Catch::Contains("the MIC path"));
  }
  // `cpu` where it runs AVX2's kernels (as on a machine without AVX-512): a usage error naming the setting
  mbvh_test::TempDir dir;
  const auto r = mbvh_test::run_cli("trace gen:sphere:8 --count 10 --backend cpu --set cpu.mic=1 -o " + dir.file("x.hits"),
                                    "MBVH_CPU_ISA=avx2");
  INFO(r.output);
  const auto simd = mbvh_test::simd_cpu_backends();
  if (std::find(simd.begin(), simd.end(), "cpu-avx2") != simd.end()) {  // else `cpu` is cpu-scalar, which accepts it
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("cpu.mic=1") && Catch::Contains("AVX-512"));
  }
}

TEST_CASE("backend settings belong to their backend - unknown names are refused by name", "[api]") {
  // another family's setting is not this backend's concern: one options object serves several
  BackendOptions o;
  o.set("vulkan.device", "0").set("embree.quality", "high");
  CHECK(make_backend("cpu", o) != nullptr);
  // a family no backend has, or a name without a family: refused
  CHECK_THROWS_WITH(make_backend("cpu", BackendOptions{}.set("vulcan.device", "0")),
                    Catch::Contains("backend setting 'vulcan.device'") && Catch::Contains("FAMILY.NAME"));
  CHECK_THROWS_WITH(make_backend("cpu", BackendOptions{}.set("device", "0")), Catch::Contains("backend setting 'device'"));
  // a name of the backend's own family that it does not declare: refused, naming the ones it has
  const bool have_vulkan = [] {
    for (const BackendInfo& b : list_backends())
      if (b.name == "vulkan") return static_cast<bool>(b.make);
    return false;
  }();
  if (have_vulkan) {
    CHECK_THROWS_WITH(make_backend("vulkan", BackendOptions{}.set("vulkan.stagin", "1")),
                      Catch::Contains("backend 'vulkan' has no setting 'vulkan.stagin'") &&
                          Catch::Contains("vulkan.staging"));
    CHECK_THROWS_WITH(make_backend("vulkan", BackendOptions{}.set("vulkan.staging", "maybe")),
                      Catch::Contains("vulkan.staging='maybe'"));
    CHECK_THROWS_WITH(make_backend("vulkan", BackendOptions{}.set("vulkan.max-binding-bytes", "-1")),
                      Catch::Contains("vulkan.max-binding-bytes='-1'"));
  }
  CHECK_THROWS_WITH(make_backend("cpu-scalar", BackendOptions{}.set("cpu.threads", "2")),
                    Catch::Contains("backend 'cpu-scalar' has no setting 'cpu.threads' (its settings: cpu.leaf-block, cpu.packet-hybrid, cpu.mic)"));
  // the CLI: --set FAMILY.NAME=VALUE reaches the backend; a malformed one is a usage error
  auto r = mbvh_test::run_cli("devices --set vulkan.validation=1");
  CHECK(r.code == 0);
  mbvh_test::TempDir dir;
  r = mbvh_test::run_cli("trace gen:sphere:8 --count 10 --set nonsense -o " + dir.file("x.hits"));
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--set 'nonsense': expected FAMILY.NAME=VALUE"));
}

TEST_CASE("the log callback gets the library's messages, returns the one it replaces, and none drops them", "[api]") {
  std::vector<std::string> got;
  const mbvh::LogCallback before = mbvh::set_log_callback(
      [&](mbvh::LogLevel level, const std::string& m) { got.push_back(std::string(mbvh::to_string(level)) + " " + m); });
  mbvh::log_message(mbvh::LogLevel::info, "one");
  mbvh::log_message(mbvh::LogLevel::warning, "two");
  const mbvh::LogCallback mine = mbvh::set_log_callback({});
  CHECK(static_cast<bool>(mine));
  mbvh::log_message(mbvh::LogLevel::info, "dropped");
  CHECK(got == std::vector<std::string>{"info one", "warning two"});
  mbvh::set_log_callback(before);  // the test program's own, if it set one
}

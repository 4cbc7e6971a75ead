// SPDX-License-Identifier: MIT
// test_hostile_inputs.cpp — library misuse, loaders and CLI options under hostile input.
#include <catch2/catch.hpp>

#include "tests/helpers.h"

#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <span>
#include <thread>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

bool same_answers(const TraceOutput& a, const TraceOutput& b) {
  return a.hits.size() == b.hits.size() && a.occluded == b.occluded && a.invalid == b.invalid &&
         (a.hits.empty() || std::memcmp(a.hits.data(), b.hits.data(), a.hits.size() * sizeof(Hit)) == 0);
}

}  // namespace

TEST_CASE("hostile: several threads tracing on one backend object give the single-threaded answers",
          "[reliability][hostile]") {
  const Scene s = load_scene("gen:sphere:24");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 3000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (const std::string& name : mbvh_test::all_backends().backends) {
    INFO("backend " << name);
    auto backend = make_backend(name, BackendOptions{});
    // two option sets, so that concurrent calls also switch the backend's prepared layout and query
    const Traversal t = backend->supports(Layout::mbvh4, Traversal::stack) ? Traversal::stack : Traversal::bitstack;
    const Layout other = backend->supports(Layout::mbvh2, t) ? Layout::mbvh2 : Layout::mbvh4;
    const TraceOptions opts[2] = {TraceOptions{Layout::mbvh4, t, Query::closest, false},
                                  TraceOptions{other, t, Query::any, false}};
    TraceOutput want[2];
    {
      auto fresh = make_backend(name, BackendOptions{});
      for (int k = 0; k < 2; ++k) fresh->trace(*acc, rays, opts[k], want[k]);
    }
    constexpr int kThreads = 4, kRounds = 4;
    std::vector<int> wrong(kThreads, 0);
    std::vector<std::string> errors(kThreads);
    std::vector<std::thread> pool;
    for (int i = 0; i < kThreads; ++i)
      pool.emplace_back([&, i] {
        try {
          for (int r = 0; r < kRounds; ++r) {
            const int k = (i + r) % 2;
            TraceOutput out;
            backend->trace(*acc, rays, opts[k], out);
            wrong[i] += !same_answers(out, want[k]);
          }
        } catch (const std::exception& e) {
          errors[i] = e.what();
        }
      });
    for (auto& th : pool) th.join();
    backend.reset();  // Vulkan's validation reports what it saw while tearing down
    for (int i = 0; i < kThreads; ++i) {
      INFO("thread " << i);
      CHECK(errors[i] == "");
      CHECK(wrong[i] == 0);
    }
    if (const auto info = [&] {
          for (const BackendInfo& b : list_backends())
            if (b.name == name) return b;
          return BackendInfo{};
        }();
        info.pending_problems)
      CHECK(info.pending_problems().empty());
  }
}

TEST_CASE("hostile: enum values cast from out-of-range ints are refused at every entry point, naming the argument",
          "[reliability][hostile]") {
  Scene s = load_scene("gen:cube:4");
  BuildOptions bo;
  bo.quality = static_cast<BuildQuality>(7);
  CHECK_THROWS_WITH(Accel::build(s, bo), Catch::Contains("BuildOptions::quality is 7, not a BuildQuality"));
  CHECK_THROWS_WITH(Accel::cache_key(s, bo), Catch::Contains("BuildOptions::quality is 7"));
  {
    mbvh_test::TempDir dir;
    CHECK_THROWS_WITH(Accel::build_cached(s, bo, dir.path.string()), Catch::Contains("BuildOptions::quality is 7"));
  }
  const auto acc = Accel::build(s);
  CHECK_THROWS_WITH(acc->make_layout(static_cast<Layout>(3)), Catch::Contains("the layout is 3, not a Layout"));
  CHECK_THROWS_WITH(state_bytes_per_ray(Layout::mbvh4, static_cast<Traversal>(11)),
                    Catch::Contains("the traversal is 11, not a Traversal"));
  const std::vector<Ray> rays(4, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  struct Bad {
    TraceOptions opt;
    const char* says;
  };
  std::vector<Bad> bad;
  {
    TraceOptions o{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.query = static_cast<Query>(7);
    bad.push_back({o, "TraceOptions::query is 7, not a Query"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.precision = static_cast<Precision>(9);
    bad.push_back({o, "TraceOptions::precision is 9, not a Precision"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.layout = static_cast<Layout>(-1);
    bad.push_back({o, "TraceOptions::layout is -1, not a Layout"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.traversal = static_cast<Traversal>(7);
    bad.push_back({o, "TraceOptions::traversal is 7, not a Traversal"});
  }
  for (const Bad& b : bad) {
    INFO(b.says);
    TraceOutput out;
    CHECK_THROWS_WITH(trace_reference(*acc, rays, b.opt, out, 1), Catch::Contains(b.says));
    CHECK_THROWS_WITH(trace_one(*acc, rays[0], b.opt), Catch::Contains(b.says));
    for (const std::string& name : mbvh_test::all_backends().backends) {
      INFO("backend " << name);
      auto backend = make_backend(name);
      CHECK_THROWS_WITH(backend->trace(*acc, rays, b.opt, out), Catch::Contains(name + ": ") && Catch::Contains(b.says));
      CHECK_THROWS_WITH(backend->prepare(*acc, b.opt), Catch::Contains(b.says));
    }
  }
}

TEST_CASE("hostile: library messages name the scene (an unnamed one as such) and the argument, never a CLI option",
          "[reliability][hostile]") {
  Scene s;
  s.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  s.triangles = {{0, 1, 5}};
  CHECK(s.display_name() == "scene (unnamed)");
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): triangle 0 names vertex 5"));
  s.triangles = {{0, 1, 2}};
  s.vertices[1].x = 1e13f;  // beyond the exactly traced range
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): coordinate"));
  s.vertices = {{0, 0, 0}, {1e-12f, 0, 0}, {0, 1e-12f, 0}};  // below the smallest scene scale
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): "));
  s.vertices = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): the scene has no non-degenerate triangle"));
  s.name = "mine.obj";
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("mine.obj: "));
  // a cache directory that is a file: named as the BVH cache directory, not as the CLI's --cache
  mbvh_test::TempDir dir;
  const std::string file = dir.write("plain", "x");
  const Scene cube = load_scene("gen:cube:2");
  try {
    Accel::build_cached(cube, {}, file);
    FAIL("build_cached took a file for its directory");
  } catch (const Error& e) {
    const std::string what = e.what();
    INFO(what);
    CHECK(what.find("--") == std::string::npos);
    CHECK(what.find(file) != std::string::npos);
    CHECK(what.find("BVH cache directory") != std::string::npos);
  }
#ifdef MBVH_HAVE_EMBREE
  auto embree = make_backend("embree");
  const auto acc = Accel::build(cube);
  TraceOutput out;
  const std::vector<Ray> rays(1, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  try {
    embree->trace(*acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false, Precision::exact}, out);
    FAIL("embree traced Precision::exact");
  } catch (const Error& e) {
    const std::string what = e.what();
    INFO(what);
    CHECK(what.find("--") == std::string::npos);
    CHECK(what.find("Precision::robust") != std::string::npos);
  }
#endif
}

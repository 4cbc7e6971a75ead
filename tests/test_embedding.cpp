// SPDX-License-Identifier: MIT
// test_embedding.cpp — what a renderer embedding mbvh relies on: the defaults (TraceOptions{}
// traces each backend's fastest exact traversal, resolve_options says which, and its answers are
// those of the named options bit for bit) and the task hook (mbvh/tasks.h: the caller's scheduler
// runs the library's parallel loops, with the pool's answers, whatever order or threads it uses).
#include <catch2/catch.hpp>

#include <atomic>
#include <cstring>
#include <stdexcept>
#include <thread>
#include <vector>

#ifdef MBVH_TEST_TBB
#include <tbb/parallel_for.h>
#endif

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/tools/raygen.h"
#include "mbvh/error.h"
#include "mbvh/tasks.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

std::vector<Ray> some_rays(const Scene& scene, const Accel& acc, std::size_t n) {
  std::vector<Ray> rays;
  for (RayKind k : {RayKind::primary, RayKind::diffuse, RayKind::shadow}) {
    RayGenOptions o;
    o.kind = k;
    o.count = n;
    o.seed = 11;
    const std::vector<Ray> r = generate_rays(scene, acc, o);
    rays.insert(rays.end(), r.begin(), r.end());
  }
  return rays;
}

/// Closest hits then occlusion flags of `rays` on `backend` with the default options.
std::vector<std::uint8_t> answers(Backend& backend, const Accel& acc, const std::vector<Ray>& rays) {
  TraceOptions c, a;
  a.query = Query::any;
  TraceOutput oc, oa;
  backend.trace(acc, rays, c, oc);
  backend.trace(acc, rays, a, oa);
  std::vector<std::uint8_t> bytes(oc.hits.size() * sizeof(Hit));
  std::memcpy(bytes.data(), oc.hits.data(), bytes.size());
  bytes.insert(bytes.end(), oa.occluded.begin(), oa.occluded.end());
  return bytes;
}

/// Sets a task runner for its scope, restoring the one before.
struct RunnerScope {
  TaskRunner before;
  explicit RunnerScope(TaskRunner r) : before(set_task_runner(std::move(r))) {}
  ~RunnerScope() { set_task_runner(before); }
};

}  // namespace

TEST_CASE("defaults: TraceOptions{} traces each backend's fastest exact traversal, named by resolve_options",
          "[defaults]") {
  const Scene scene = load_scene("gen:hairball:20000");
  const auto acc = Accel::build(scene);
  const std::vector<Ray> rays = some_rays(scene, *acc, 2000);
  const VariantGrid grid = mbvh_test::all_backends();
  const auto backends = make_backends(grid, {});
  for (const auto& [name, b] : backends) {
    INFO(name);
    for (Query q : {Query::closest, Query::any}) {
      TraceOptions asked;
      asked.query = q;
      const TraceOptions r = resolve_options(*b, asked);
      INFO(to_string(q) << ": " << to_string(r.layout) << "/" << to_string(r.traversal));
      REQUIRE(r.layout != Layout::automatic);
      REQUIRE(r.traversal != Traversal::automatic);
      CHECK(b->supports(r.layout, r.traversal));
      CHECK(!is_packet(r.traversal));
      // the measured choices (docs/library.md, "Defaults")
      const std::string isa = b->isa();
      if (b->supports(Layout::mbvh4, Traversal::dacrt) && !b->supports(Layout::mbvh4, Traversal::stack)) {
        CHECK(r.traversal == Traversal::dacrt);  // its only traversal
      } else if (isa == "avx2" || isa == "avx512") {
        CHECK(r.layout == Layout::mbvh8);
        CHECK(r.traversal == (q == Query::any ? Traversal::stack_octant : Traversal::stack_ordered));
      } else if (name == "cpu-scalar") {
        CHECK(r.layout == Layout::mbvh4);
        CHECK(r.traversal == Traversal::stack_ordered);
      } else if (b->peer()) {
        CHECK(r.traversal == Traversal::stack);
      } else {  // the device backends: MBVH4 stack
        CHECK(r.layout == Layout::mbvh4);
        CHECK(r.traversal == Traversal::stack);
      }
      // the defaults' answers are the resolved options' bit for bit
      TraceOutput by_default, named;
      b->trace(*acc, rays, asked, by_default);
      b->trace(*acc, rays, r, named);
      if (q == Query::any) CHECK(by_default.occluded == named.occluded);
      else CHECK(std::memcmp(by_default.hits.data(), named.hits.data(), rays.size() * sizeof(Hit)) == 0);
    }
  }
  // the reference resolves by its own ranking (cpu-scalar's), and traces it
  TraceOptions closest;
  TraceOutput ref_default, ref_named;
  trace_reference(*acc, rays, closest, ref_default, 0);
  closest.layout = Layout::mbvh4;
  closest.traversal = Traversal::stack_ordered;
  trace_reference(*acc, rays, closest, ref_named, 0);
  CHECK(std::memcmp(ref_default.hits.data(), ref_named.hits.data(), rays.size() * sizeof(Hit)) == 0);
}

TEST_CASE("defaults: a named layout or traversal is kept, the other resolved; a pair that fits none is refused",
          "[defaults]") {
  const auto cpu = make_backend("cpu-scalar");
  TraceOptions o;
  o.layout = Layout::mbvh2;
  CHECK(resolve_options(*cpu, o).traversal == Traversal::stack);  // MBVH2 has no ordered stack
  o = TraceOptions{};
  o.traversal = Traversal::bitstack_retest;
  CHECK(resolve_options(*cpu, o).layout == Layout::mbvh4);  // bitstack-retest is MBVH4's alone
  o = TraceOptions{};
  o.traversal = Traversal::packet;
  CHECK(resolve_options(*cpu, o).traversal == Traversal::packet);
  o.layout = Layout::mbvh8;
  o.traversal = Traversal::bitstack;
  const TraceOptions named = resolve_options(*cpu, o);
  CHECK((named.layout == Layout::mbvh8 && named.traversal == Traversal::bitstack));  // both named: unchanged
  // a pair that fits nothing the backend has, named by backend
  o = TraceOptions{};
  o.layout = Layout::mbvh2;
  o.traversal = Traversal::automatic;
  for (const std::string& n : runnable_backends())
    if (n == "embree") {
      const auto e = make_backend("embree");
      const TraceOptions r = resolve_options(*e, o);  // MBVH2 kept, nothing fits: refused by trace, naming what it has
      CHECK(r.layout == Layout::mbvh2);
      const Scene s = load_scene("gen:sphere:8");
      const auto acc = Accel::build(s);
      TraceOutput out;
      CHECK_THROWS_WITH(e->trace(*acc, some_rays(s, *acc, 10), o, out), Catch::Contains("embree") && Catch::Contains("mbvh2"));
    }
  // past the entry points, an unresolved auto is refused by name
  CHECK_THROWS_WITH(state_bytes_per_ray(Layout::automatic, Traversal::stack), Catch::Contains("auto"));
  CHECK(parse_traversal("auto") == Traversal::automatic);
  CHECK(parse_layout("auto") == Layout::automatic);
  CHECK(std::string(to_string(Traversal::automatic)) == "auto");
}

TEST_CASE("defaults: mbvh trace names the traversal it picked", "[defaults]") {
  const mbvh_test::RunResult r = mbvh_test::run_cli("trace gen:sphere:16 --backend cpu-scalar --kind primary --count 1000");
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK(r.output.find("mbvh4/stack-ordered/closest") != std::string::npos);
  const mbvh_test::RunResult a =
      mbvh_test::run_cli("trace gen:sphere:16 --backend cpu-scalar --kind shadow --query any --count 1000");
  INFO(a.output);
  REQUIRE(a.code == 0);
  CHECK(a.output.find("mbvh4/stack-ordered/any") != std::string::npos);
}

TEST_CASE("task hook: the caller's runner runs the build and the trace, with the pool's answers", "[tasks]") {
  const Scene scene = load_scene("gen:hairball:30000");
  BuildOptions bo;
  bo.threads = 2;
  const auto own = Accel::build(scene, bo);
  const std::vector<Ray> rays = some_rays(scene, *own, 4000);
  BackendOptions opt;
  opt.threads = 2;
  auto backend = make_backend("cpu", opt);
  const std::vector<std::uint8_t> expected = answers(*backend, *own, rays);

  // a runner on threads of its own, one per task, counting what it runs
  std::atomic<std::size_t> calls{0}, tasks{0};
  {
    RunnerScope scope([&](std::size_t count, const std::function<void(std::size_t)>& task) {
      ++calls;
      std::vector<std::thread> ts;
      for (std::size_t i = 0; i < count; ++i) ts.emplace_back([&, i] {
        ++tasks;
        task(i);
      });
      for (std::thread& t : ts) t.join();
    });
    const auto acc = Accel::build(scene, bo);
    CHECK(acc->hash() == own->hash());
    auto b = make_backend("cpu", opt);
    CHECK(answers(*b, *acc, rays) == expected);
  }
  CHECK(calls > 0);
  CHECK(tasks >= calls);
  const std::size_t after = calls;

  // every task on the caller's thread, one after another; then a runner that skips all but the
  // first task: the answers still the pool's
  for (bool skip : {false, true}) {
    INFO((skip ? "skipping runner" : "serial runner"));
    RunnerScope scope([skip](std::size_t count, const std::function<void(std::size_t)>& task) {
      for (std::size_t i = 0; i < (skip ? 1 : count); ++i) task(i);
    });
    const auto acc = Accel::build(scene, bo);
    CHECK(acc->hash() == own->hash());
    auto b = make_backend("cpu", opt);
    CHECK(answers(*b, *acc, rays) == expected);
  }
  CHECK(calls == after);  // restored: the pool again

#ifdef MBVH_TEST_TBB
  {
    RunnerScope scope([](std::size_t count, const std::function<void(std::size_t)>& task) {
      tbb::parallel_for(std::size_t(0), count, [&](std::size_t i) { task(i); });
    });
    const auto acc = Accel::build(scene, bo);
    CHECK(acc->hash() == own->hash());
    auto b = make_backend("cpu", opt);
    CHECK(answers(*b, *acc, rays) == expected);
  }
#endif
}

TEST_CASE("task hook: a build at BuildOptions::threads = 1 asks no loop for more than one task, its layouts' checks included",
          "[tasks]") {
  const Scene scene = load_scene("gen:hairball:100000");
  std::atomic<std::size_t> most{0}, calls{0};
  {
    RunnerScope scope([&](std::size_t count, const std::function<void(std::size_t)>& task) {
      ++calls;
      for (std::size_t seen = most; count > seen && !most.compare_exchange_weak(seen, count);) {
      }
      for (std::size_t i = 0; i < count; ++i) task(i);
    });
    BuildOptions bo;
    bo.threads = 1;
    const auto acc = Accel::build(scene, bo);
    REQUIRE(acc->mbvh4().nodes.size() > 8192);  // more nodes than one chunk of the layout check
    REQUIRE(acc->mbvh8().nodes.size() > 0);
    // a leaf variant's layouts (the cpu backend's leaves) are checked at the build's count too
    const auto big = Accel::build(load_scene("gen:hairball:300000"), bo);
    REQUIRE(big->leaf_variant(4).mbvh4().nodes.size() > 8192);
    REQUIRE(big->leaf_variant(4).mbvh8().nodes.size() > 0);
  }
  INFO(calls << " runner calls");
  CHECK(most <= 1);
}

TEST_CASE("task hook: work that throws is rethrown on the caller; a nested loop runs inline", "[tasks]") {
  RunnerScope scope([](std::size_t count, const std::function<void(std::size_t)>& task) {
    std::vector<std::thread> ts;
    for (std::size_t i = 0; i < count; ++i) ts.emplace_back([&, i] { task(i); });
    for (std::thread& t : ts) t.join();
  });
  CHECK_THROWS_WITH(parallel_for(100, 1, 4,
                                 [](std::size_t b, std::size_t, unsigned) {
                                   if (b == 37) throw Error("chunk 37");
                                 }),
                    "chunk 37");
  std::atomic<std::size_t> sum{0};
  parallel_for(8, 1, 4, [&](std::size_t b, std::size_t e, unsigned) {
    parallel_for(10, 1, 4, [&](std::size_t b2, std::size_t e2, unsigned w) {
      CHECK(w == 0);  // inline on the task's thread
      sum += (e - b) * (e2 - b2);
    });
  });
  CHECK(sum == 80);
}

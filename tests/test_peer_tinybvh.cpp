// SPDX-License-Identifier: MIT
// test_peer_tinybvh.cpp — the tinybvh peer (backends/tinybvh): its two layouts agree with
// cpu-scalar up to a tiny share of genuine mismatches (it is not watertight: counted as a
// witness's, as `mbvh check` does), tmin is honoured, the options it cannot honour are refused by
// name, and a build without it says why.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/backends.h"
#include "mbvh/config.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

const BackendInfo* info_of(const std::string& name) {
  static std::vector<BackendInfo> all;
  all = list_backends();
  for (const BackendInfo& b : all)
    if (b.name == name) return &b;
  return nullptr;
}

/// Whether the tinybvh peer can run here (built, and the CPU has AVX2 and FMA); says why not.
bool tinybvh_runs() {
  register_builtin_backends();
  const BackendInfo* b = info_of("tinybvh");
  REQUIRE(b != nullptr);  // registered in every build: built, or not_built with the reason
  if (!b->make) {
    std::printf("tinybvh peer not built: %s\n", b->unavailable.c_str());
    return false;
  }
  if (b->missing_hardware && !b->missing_hardware().empty()) {
    std::printf("tinybvh peer cannot run here: %s\n", b->missing_hardware().c_str());
    return false;
  }
  return true;
}

}  // namespace

TEST_CASE("the tinybvh peer is registered: built, or not built with the reason", "[peer]") {
  register_builtin_backends();
  const BackendInfo* b = info_of("tinybvh");
  REQUIRE(b != nullptr);
#ifdef MBVH_HAVE_TINYBVH
  CHECK(b->make);
#else
  CHECK_FALSE(b->make);
  CHECK_THAT(b->unavailable, Catch::Contains("no tinybvh peer"));
  CHECK_THROWS_WITH(make_backend("tinybvh"), Catch::Contains("tinybvh") && Catch::Contains("no tinybvh peer"));
#endif
}

TEST_CASE("the tinybvh peer's hits agree with cpu-scalar's up to a tiny share, on both layouts", "[peer]") {
  if (!tinybvh_runs()) return;
  const Scene scene = load_scene("gen:sphere:24");
  const auto acc = Accel::build(scene);
  for (RayKind kind : {RayKind::primary, RayKind::shadow, RayKind::diffuse}) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = 4000;
    const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
    CheckOptions co;
    co.brute_rays = 500;
    co.grid.backends = {"cpu-scalar", "tinybvh"};
    co.grid.layouts = {Layout::mbvh4, Layout::mbvh8};
    co.grid.traversals = {Traversal::stack};
    co.grid.precisions = {Precision::robust, Precision::fast};  // cpu-scalar robust: the reference
    if (kind == RayKind::diffuse) co.backend.set("tinybvh.build", "hq");  // its spatial-split builder once
    const CheckReport rep = run_check(*acc, rays, co);
    INFO(to_string(kind) << " rays\n" << rep.table(rays));
    std::size_t compared = 0, tiny = 0;
    for (const Comparison& c : rep.comparisons) {
      const bool peer = c.a.rfind("tinybvh/", 0) == 0;
      if (!peer) {
        CHECK(c.mismatches == 0);  // cpu-scalar's own answers, robust and fast
        continue;
      }
      ++compared;
      tiny += c.mismatches;
      CHECK(c.rays > 0);
      CHECK(c.mismatches * 1000 <= c.rays);  // at most 0.1 %: a non-watertight test's edge misses
    }
    CHECK(compared == 2 * 2 * 2 + 2);  // 2 layouts x (closest: 2 comparisons; any: 3)
    if (tiny) std::printf("tinybvh peer, %s rays: %zu genuine mismatches (counted, as a witness's)\n", to_string(kind), tiny);
  }
}

TEST_CASE("the tinybvh peer honours tmin and tmax", "[peer]") {
  if (!tinybvh_runs()) return;
  const Scene scene = load_scene("gen:sphere:16");
  const auto acc = Accel::build(scene);
  auto tiny = make_backend("tinybvh");
  auto ref = make_backend("cpu-scalar");
  // from outside along -z: the front surface, then (tmin past it) the back one; tmax before both: a miss
  std::vector<Ray> rays = {Ray{0.01f, 0.02f, 5, 0, 0, 0, -1, INFINITY}, Ray{0.01f, 0.02f, 5, 4.5f, 0, 0, -1, INFINITY},
                           Ray{0.01f, 0.02f, 5, 0, 0, 0, -1, 3.0f}, Ray{NAN, 0, 5, 0, 0, 0, -1, INFINITY}};
  for (Layout l : {Layout::mbvh4, Layout::mbvh8}) {
    TraceOptions o{l, Traversal::stack, Query::closest, false, Precision::fast};
    TraceOutput a, b;
    tiny->trace(*acc, rays, o, a);
    o.precision = Precision::robust;
    ref->trace(*acc, rays, o, b);
    INFO(to_string(l));
    CHECK(a.invalid == 1);
    for (std::size_t i = 0; i < rays.size(); ++i) {
      INFO("ray " << i);
      CHECK(a.hits[i].prim == b.hits[i].prim);
      if (b.hits[i].prim != MBVH_MISS_PRIM) {
        CHECK(std::fabs(a.hits[i].t - b.hits[i].t) <= 1e-5f * b.hits[i].t);
        CHECK(std::fabs(a.hits[i].u - b.hits[i].u) <= 1e-4f);  // u, v weight vertices 1 and 2 in both
        CHECK(std::fabs(a.hits[i].v - b.hits[i].v) <= 1e-4f);
      }
    }
    CHECK(a.hits[1].t > 4.5f);
    o = TraceOptions{l, Traversal::stack, Query::any, false, Precision::fast};
    tiny->trace(*acc, rays, o, a);
    CHECK(std::vector<int>(a.occluded.begin(), a.occluded.end()) == std::vector<int>{1, 1, 0, 0});
  }
}

TEST_CASE("the tinybvh peer refuses the options it cannot honour, naming them", "[peer]") {
  if (!tinybvh_runs()) return;
  const auto acc = Accel::build(load_scene("gen:sphere:8"));
  auto tiny = make_backend("tinybvh");
  const std::vector<Ray> rays(4, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  TraceOutput out;
  // robust and exact are mbvh's contracts: tinybvh's test is not watertight
  for (Precision p : {Precision::robust, Precision::exact})
    CHECK_THROWS_WITH(tiny->trace(*acc, rays, TraceOptions{Layout::mbvh8, Traversal::stack, Query::closest, false, p}, out),
                      Catch::Contains("tinybvh") && Catch::Contains(to_string(p)));
  // no binary layout, one traversal
  CHECK_THROWS_WITH(tiny->trace(*acc, rays, TraceOptions{Layout::mbvh2, Traversal::stack, Query::closest, false, Precision::fast}, out),
                    Catch::Contains("tinybvh") && Catch::Contains("mbvh2"));
  for (Traversal t : {Traversal::bitstack, Traversal::stack_ordered, Traversal::packet})
    CHECK_THROWS_WITH(tiny->trace(*acc, rays, TraceOptions{Layout::mbvh8, t, Query::closest, false, Precision::fast}, out),
                      Catch::Contains("tinybvh") && Catch::Contains(to_string(t)));
  // one setting of its own, checked by name
  CHECK_THROWS(make_backend("tinybvh", BackendOptions{}.set("tinybvh.layout", "bvh8")));
  CHECK_THROWS_WITH(make_backend("tinybvh", BackendOptions{}.set("tinybvh.build", "best")),
                    Catch::Contains("tinybvh.build='best'"));
  CHECK_THAT(make_backend("tinybvh", BackendOptions{}.set("tinybvh.build", "hq"))->describe(), Catch::Contains("BuildHQ"));
  // the automatic layout and traversal: BVH8_CPU, its stack
  CHECK(resolve_options(*tiny, TraceOptions{Layout::automatic, Traversal::automatic, Query::closest, false, Precision::fast}).layout ==
        Layout::mbvh8);
}

TEST_CASE("mbvh check and bench with the tinybvh peer: fast precision is asked for by name, a witness's mismatches counted", "[peer][cli]") {
  if (!tinybvh_runs()) return;
  // robust (the default): nothing to run, and the error says which precision the peer has
  for (const char* cmd : {"check gen:sphere:8 --backend tinybvh --count 100", "bench gen:sphere:8 --backend tinybvh --count 100"}) {
    const auto r = mbvh_test::run_cli(cmd);
    INFO(cmd << "\n" << r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("backend 'tinybvh' traces none of the precisions asked (it has --precision fast)"));
  }
  const auto r = mbvh_test::run_cli("check gen:sphere:8 --backend cpu-scalar,tinybvh --precision robust,fast --count 500 --kinds primary,shadow");
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("tinybvh/mbvh8/stack/closest/fast") && Catch::Contains("tinybvh/mbvh4/stack/any/fast"));
}

// SPDX-License-Identifier: MIT
// test_single_ray.cpp — the single-ray query (Backend::ray_query, RayQuery in mbvh/backend.h): on
// every SIMD cpu backend that runs here, each ray's closest hit and occlusion flag equal, bit for
// bit, the batch trace of the same backend with the query's options and the reference's
// (cpu-scalar) on the same leaves; several threads calling one query on one shared Accel get the
// same answers; unsupported options and out-of-range rays are refused by name.
#include <catch2/catch.hpp>

#include <atomic>
#include <cmath>
#include <cstring>
#include <thread>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/error.h"
#include "mbvh/geometry.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

/// Rays of several kinds (primary, diffuse, shadow, random and the special rays: invalid ones,
/// grazing ones, shared edges), `n` of each.
std::vector<Ray> mixed_rays(const Scene& scene, const Accel& acc, std::size_t n) {
  std::vector<Ray> rays;
  for (RayKind k : {RayKind::primary, RayKind::diffuse, RayKind::shadow, RayKind::random, RayKind::special}) {
    RayGenOptions o;
    o.kind = k;
    o.count = n;
    o.seed = 7;
    const std::vector<Ray> r = generate_rays(scene, acc, o);
    rays.insert(rays.end(), r.begin(), r.end());
  }
  return rays;
}

/// Every ray of `rays` through `q` equals the batch trace of `backend` with the query's options,
/// closest and any hit, and (robust precision) the reference's bytes.
void check_query(Backend& backend, const Accel& acc, const RayQuery& q, const std::vector<Ray>& rays) {
  INFO(backend.name() << " " << to_string(q.options(Query::closest).layout) << "/"
                      << to_string(q.options(Query::closest).traversal) << " and "
                      << to_string(q.options(Query::any).layout) << "/" << to_string(q.options(Query::any).traversal)
                      << ", precision " << to_string(q.options(Query::closest).precision) << ", leaf block "
                      << q.options(Query::closest).leaf_block);
  std::vector<Hit> hits(rays.size());
  std::vector<std::uint8_t> occ(rays.size());
  for (std::size_t i = 0; i < rays.size(); ++i) {
    hits[i] = q.intersect(rays[i]);
    occ[i] = q.occluded(rays[i]) ? 1 : 0;
  }
  TraceOutput batch_c, batch_a;
  backend.trace(acc, rays, q.options(Query::closest), batch_c);
  backend.trace(acc, rays, q.options(Query::any), batch_a);
  REQUIRE(batch_c.hits.size() == rays.size());
  CHECK(std::memcmp(hits.data(), batch_c.hits.data(), rays.size() * sizeof(Hit)) == 0);
  CHECK(occ == batch_a.occluded);
  if (q.options(Query::closest).precision != Precision::fast) {  // fast answers per backend
    TraceOutput ref_c, ref_a;
    trace_reference(acc, rays, q.options(Query::closest), ref_c, 0);
    trace_reference(acc, rays, q.options(Query::any), ref_a, 0);
    CHECK(std::memcmp(hits.data(), ref_c.hits.data(), rays.size() * sizeof(Hit)) == 0);
    CHECK(occ == ref_a.occluded);
  }
  std::size_t hit_count = 0, occluded_count = 0;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    hit_count += hits[i].prim != MBVH_MISS_PRIM;
    occluded_count += occ[i];
  }
  CHECK(hit_count > rays.size() / 10);  // the rays are not all misses
  CHECK(occluded_count >= hit_count);  // a closest hit is an occlusion
  CHECK(batch_c.invalid > 0);          // the special rays hold invalid ones: defined misses
}

}  // namespace

TEST_CASE("single-ray query: every ray equals the batch trace and the reference, each layout and traversal",
          "[single-ray]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) {
    WARN("no SIMD cpu backend runs here: nothing to test");
    return;
  }
  for (const char* file : {"gen:hairball:20000", "bun_zipper.ply.zst", "conference.obj.zst"}) {
    const std::string spec = std::string(file).rfind("gen:", 0) == 0 ? file : mbvh_test::scene_path(file);
    const Scene scene = load_scene(spec);
    const auto acc = Accel::build(scene);
    const std::vector<Ray> rays = mixed_rays(scene, *acc, 1500);
    for (const std::string& name : names) {
      INFO(file << " on " << name);
      auto backend = make_backend(name);
      // the defaults: the fastest exact single-ray traversals
      const RayQuery def = backend->ray_query(*acc);
      CHECK(def.valid());
      CHECK(def.backend() == name);
      CHECK(def.options(Query::closest).layout == Layout::mbvh8);
      CHECK(def.options(Query::closest).traversal == Traversal::stack_ordered);
      CHECK(def.options(Query::any).layout == Layout::mbvh8);
      CHECK(def.options(Query::any).traversal == Traversal::bitstack);
      CHECK(def.options(Query::closest).leaf_block == backend->leaf_block(TraceOptions{}));
      TraceOptions any_default;
      any_default.query = Query::any;  // the any-hit query traces the backend's own leaves for any hit
      CHECK(def.options(Query::any).leaf_block == backend->leaf_block(any_default));
      check_query(*backend, *acc, def, rays);
      // every other single-ray pair, a precision and a leaf block (the kernels chosen per call)
      std::vector<TraceOptions> others;
      for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
        for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered, Traversal::bitstack_retest,
                            Traversal::stack_octant, Traversal::bitstack_octant})
          if (backend->supports(l, t)) others.push_back(TraceOptions{l, t});
      TraceOptions fast{Layout::mbvh8, Traversal::stack_ordered};
      fast.precision = Precision::fast;
      others.push_back(fast);
      // fast any hit on the octant stack: the batch walks it per direction octant (simd/occlusion.h),
      // the query with OctantWalk
      TraceOptions fast_octant{Layout::mbvh8, Traversal::stack_octant};
      fast_octant.precision = Precision::fast;
      others.push_back(fast_octant);
      TraceOptions own{Layout::mbvh4, Traversal::bitstack};
      own.leaf_block = 1;  // the build's own leaves
      others.push_back(own);
      for (const TraceOptions& o : others) check_query(*backend, *acc, backend->ray_query(*acc, o), rays);
    }
    // the MIC path (cpu.mic=1) where there is one: its MBVH4 queries, robust and fast
    for (const std::string& name : mbvh_test::mic_backends()) {
      INFO(file << " on " << name << " with cpu.mic=1");
      auto backend = make_backend(name, BackendOptions{}.set("cpu.mic", "1"));
      for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered, Traversal::bitstack_retest})
        for (Precision p : {Precision::robust, Precision::fast}) {
          TraceOptions o{Layout::mbvh4, t};
          o.precision = p;
          check_query(*backend, *acc, backend->ray_query(*acc, o), rays);
        }
    }
  }
}

TEST_CASE("single-ray query: threads calling one query on one shared Accel agree with the batch", "[single-ray]") {
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  const Scene scene = load_scene("gen:hairball:30000");
  const auto acc = Accel::build(scene);
  const std::vector<Ray> rays = mixed_rays(scene, *acc, 2000);
  for (const std::string& name : names) {
    INFO(name);
    auto backend = make_backend(name);
    constexpr unsigned kThreads = 4;
    // each thread makes its own query on its own backend object while the others trace (the
    // layouts and leaf variants are made once, under the Accel's own locks), then all trace one
    // shared query: every ray, both queries, several passes each
    std::vector<RayQuery> own(kThreads);
    const RayQuery shared = backend->ray_query(*acc);
    std::vector<std::vector<Hit>> hits(kThreads, std::vector<Hit>(rays.size()));
    std::vector<std::vector<std::uint8_t>> occ(kThreads, std::vector<std::uint8_t>(rays.size()));
    std::vector<std::size_t> own_differ(kThreads, 0);
    std::atomic<unsigned> ready{0};
    std::vector<std::thread> pool;
    for (unsigned t = 0; t < kThreads; ++t)
      pool.emplace_back([&, t] {
        auto mine = make_backend(name);
        TraceOptions o{t % 2 ? Layout::mbvh4 : Layout::mbvh8, Traversal::stack_ordered};
        own[t] = mine->ray_query(*acc, o);
        ++ready;
        while (ready.load() < kThreads) std::this_thread::yield();
        for (int pass = 0; pass < 3; ++pass)
          for (std::size_t k = 0; k < rays.size(); ++k) {
            const std::size_t i = (k + t * rays.size() / kThreads) % rays.size();  // threads at different rays
            hits[t][i] = shared.intersect(rays[i]);
            occ[t][i] = shared.occluded(rays[i]) ? 1 : 0;
            const Hit h = own[t].intersect(rays[i]);
            own_differ[t] += h.prim != hits[t][i].prim || h.t != hits[t][i].t;  // leaves are the same: same hit
          }
      });
    for (std::thread& th : pool) th.join();
    TraceOutput batch_c, batch_a;
    backend->trace(*acc, rays, shared.options(Query::closest), batch_c);
    backend->trace(*acc, rays, shared.options(Query::any), batch_a);
    for (unsigned t = 0; t < kThreads; ++t) {
      INFO("thread " << t);
      CHECK(std::memcmp(hits[t].data(), batch_c.hits.data(), rays.size() * sizeof(Hit)) == 0);
      CHECK(occ[t] == batch_a.occluded);
      CHECK(own_differ[t] == 0);
    }
  }
}

TEST_CASE("single-ray query: unsupported options, backends and out-of-range rays are refused by name",
          "[single-ray]") {
  const Scene scene = load_scene("gen:sphere:16");
  const auto acc = Accel::build(scene);
  const auto refused = [](const std::function<void()>& f, const std::string& words) {
    INFO(words);
    CHECK_THROWS_WITH(f(), Catch::Contains(words));
  };
  // a backend without a single-ray path names the ones that have it
  auto scalar = make_backend("cpu-scalar");
  refused([&] { scalar->ray_query(*acc); }, "cpu-scalar: no single-ray query (Backend::ray_query): only the SIMD cpu backends");
  const RayQuery empty;
  CHECK(!empty.valid());
  refused([&] { (void)empty.intersect(Ray{0, 0, 5, 0, 0, 0, -1, INFINITY}); }, "an empty query");
  const std::vector<std::string> names = mbvh_test::simd_cpu_backends();
  if (names.empty()) return;
  auto cpu = make_backend(names.front());
  TraceOptions stats{Layout::mbvh4, Traversal::stack};
  stats.stats = true;
  refused([&] { cpu->ray_query(*acc, stats); }, "a single-ray query counts no statistics");
  refused([&] { cpu->ray_query(*acc, TraceOptions{Layout::mbvh2, Traversal::packet}); },
          "traversal 'packet' traces batches of rays, not one ray per call");
  refused([&] { cpu->ray_query(*acc, TraceOptions{Layout::mbvh8, Traversal::bitstack_retest}); },
          "traversal 'bitstack-retest' is not implemented for mbvh8");
  TraceOptions block{};
  block.leaf_block = 65;
  refused([&] { cpu->ray_query(*acc, block); }, "leaf block 65 is out of range");
  BuildOptions none;
  none.quality = BuildQuality::none;
  const auto flat = Accel::build(scene, none);
  refused([&] { cpu->ray_query(*flat); }, "this build has no hierarchy");

  // rays: a valid one hits, an invalid one is a defined miss, one outside the exactly traced range
  // is refused as Backend::trace refuses it (the quick test's bounds pass on to check_ray_range)
  const RayQuery q = cpu->ray_query(*acc);
  const Ray down{0.01f, 0.02f, 5, 0, 0, 0, -1, INFINITY};
  CHECK(q.intersect(down).prim != MBVH_MISS_PRIM);
  CHECK(q.occluded(down));
  const Ray nan{NAN, 0, 5, 0, 0, 0, -1, INFINITY}, zero{0, 0, 5, 0, 0, 0, 0, INFINITY},
      inf_origin{INFINITY, 0, 5, 0, 0, 0, -1, INFINITY}, backwards{0, 0, 5, 2, 0, 0, -1, 1};  // tmin > tmax
  for (const Ray& r : {nan, zero, inf_origin, backwards}) {
    CHECK(q.intersect(r).prim == MBVH_MISS_PRIM);
    CHECK(!q.occluded(r));
  }
  const Ray tiny_dir{0.01f, 0.02f, 5, 0, 0, 0, -1e-37f, INFINITY}, huge_dir{0.01f, 0.02f, 5, 0, 0, 0, -1e37f, INFINITY},
      far_origin{0.01f, 0.02f, 1e36f, 0, 0, 0, -1, INFINITY};
  for (const Ray& r : {tiny_dir, huge_dir, far_origin}) {
    const std::vector<Ray> one{r};
    TraceOutput out;
    CHECK_THROWS_WITH(cpu->trace(*acc, one, q.options(Query::closest), out), Catch::Contains("leaves the range traced exactly"));
    CHECK_THROWS_WITH(q.intersect(r), Catch::Contains("(RayQuery): ray 0") && Catch::Contains("leaves the range traced exactly"));
    CHECK_THROWS_WITH(q.occluded(r), Catch::Contains("leaves the range traced exactly"));
  }
  // an origin outside the scene passes the quick test (up to 2^16 times the scene's largest
  // coordinate); one farther away, or a direction far from unit length, passes on to the full
  // check, which accepts them as Backend::trace does
  const Ray outside{40, 0.02f, 0.01f, 0, -1, 0, 0, INFINITY}, far_away{1e6f, 0.02f, 0.01f, 0, -1, 0, 0, INFINITY},
      short_dir{0.01f, 0.02f, 5, 0, 0, 0, -0x1p-90f, INFINITY};
  for (const Ray& r : {outside, far_away, short_dir}) {
    TraceOutput out;
    cpu->trace(*acc, std::vector<Ray>{r}, q.options(Query::closest), out);
    const Hit h = q.intersect(r);
    CHECK(std::memcmp(&h, &out.hits[0], sizeof(Hit)) == 0);
    CHECK(h.prim != MBVH_MISS_PRIM);
    CHECK(q.occluded(r));
  }
}

// SPDX-License-Identifier: MIT
// test_build_context.cpp — BuildContext (accel.h): builds that reuse a kept context's arrays
// make the same bytes as builds without one, at any thread count, whatever the context held
// (a bigger scene's arrays, then a smaller one's, then the bigger again), for every quality.
#include <catch2/catch.hpp>

#include <cstring>
#include <memory>
#include <thread>
#include <vector>

#include "host/core/layouts.h"
#include "mbvh/accel.h"
#include "mbvh/scene.h"
#include "tests/helpers.h"
#include "tests/invariants.h"

using namespace mbvh;

namespace {

struct Reference {
  std::uint64_t hash = 0;
  AlignedVector<Node4> n4;
};

Reference reference_of(const Accel& a) { return {a.hash(), a.mbvh4().nodes}; }

void check_same(const Accel& a, const Reference& r) {
  CHECK(a.hash() == r.hash);
  REQUIRE(a.mbvh4().nodes.size() == r.n4.size());
  CHECK(std::memcmp(a.mbvh4().nodes.data(), r.n4.data(), r.n4.size() * sizeof(Node4)) == 0);
}

}  // namespace

TEST_CASE("a kept BuildContext gives the same nodes as no context, across scenes and thread counts", "[build][context]") {
  const Scene big = load_scene("gen:hairball:60000");
  const Scene small = load_scene("gen:soup:5000:3");
  for (BuildQuality q : {BuildQuality::medium, BuildQuality::low, BuildQuality::high, BuildQuality::none}) {
    INFO("quality " << to_string(q));
    BuildOptions o;
    o.quality = q;
    o.threads = 2;
    const auto ref_big = Accel::build(big, o), ref_small = Accel::build(small, o);
    const std::uint64_t hb = ref_big->hash(), hs = ref_small->hash();
    Reference rb, rs;
    if (q != BuildQuality::none) {
      rb = reference_of(*ref_big);
      rs = reference_of(*ref_small);
    }
    BuildOptions c = o;
    c.context = std::make_shared<BuildContext>();
    std::unique_ptr<Accel> kept;
    unsigned k = 0;
    for (const Scene* s : {&big, &small, &big, &small, &big}) {
      c.threads = 1 + k++ % 3;
      INFO("build " << k << " threads " << c.threads);
      kept = Accel::build(*s, c);  // the previous build is alive during this one, then recycled
      if (q == BuildQuality::none) {
        CHECK(kept->hash() == (s == &big ? hb : hs));
        continue;
      }
      check_same(*kept, s == &big ? rb : rs);
      if (q != BuildQuality::high) mbvh_test::check_invariants(*s, *kept);  // high: a triangle may sit in two leaves
    }
    kept.reset();
    CHECK(c.context->retained_bytes() > 0);
    if (q == BuildQuality::medium || q == BuildQuality::low) {
      // the retained bound accel.h documents, the big scene's: its records (32 B each), the node
      // block (room for two 48-byte nodes a record, kept whole) and its outputs (the binary tree,
      // the triangles, the MBVH4 array: its capacity), beside the upper arena's few nodes
      const std::size_t refs = ref_big->tris().size();
      const Accel::MemoryStats m = ref_big->memory();
      const std::size_t outputs = m.tree + m.triangles + ref_big->mbvh4().nodes.capacity() * sizeof(Node4);
      CHECK(c.context->retained_bytes() >= 96 * refs);
      CHECK(c.context->retained_bytes() <= (32 + 96) * refs + outputs + (std::size_t(1) << 16));
    }
    c.context->release();
    CHECK(c.context->retained_bytes() == 0);
    // after release it still builds the same bytes
    kept = Accel::build(big, c);
    CHECK(kept->hash() == hb);
  }
}

TEST_CASE("builds on several threads may share one BuildContext", "[build][context]") {
  const Scene s = load_scene("gen:hairball:20000");
  BuildOptions o;
  o.threads = 1;
  const std::uint64_t h = Accel::build(s, o)->hash();
  o.context = std::make_shared<BuildContext>();
  std::uint64_t got[4] = {0, 0, 0, 0};
  std::vector<std::thread> ts;
  for (int t = 0; t < 4; ++t)
    ts.emplace_back([&, t] {
      for (int r = 0; r < 3; ++r) got[t] = Accel::build(s, o)->hash() == h ? got[t] + 1 : got[t];
    });
  for (auto& t : ts) t.join();
  for (int t = 0; t < 4; ++t) CHECK(got[t] == 3);
}

TEST_CASE("mbvh build-bench --rebuild reports rebuilds in a kept context and page faults", "[cli][context]") {
  const auto r = mbvh_test::run_cli("build-bench gen:soup:3000 --repeats 2 --threads 2 --rebuild --json -");
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("rebuild in a kept BuildContext") && Catch::Contains("minor page faults"));
  CHECK_THAT(r.output, Catch::Contains("\"rebuild_speedup\"") && Catch::Contains("\"faults_per_triangle\""));
  CHECK_THAT(r.output, Catch::Contains("\"faults_all\"") && Catch::Contains("\"rebuild_faults_all\""));
}

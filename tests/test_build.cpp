// SPDX-License-Identifier: MIT
// test_build.cpp — builder invariants: every triangle in exactly one leaf, boxes contain their
// children, parent/sibling links consistent, depth within the bitstack's cap, the same bytes at
// any thread count, degenerate triangles kept out (the checks: tests/invariants.cpp).
#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <iterator>
#include <stdexcept>

#include "host/core/bvh/builder.h"  // tri_box
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
using mbvh_test::check_invariants;
using mbvh_test::contains;
using mbvh::build::slot_box;
using mbvh::build::tri_box;

TEST_CASE("builder invariants on shared and generated scenes", "[build]") {
  for (const std::string& spec : {mbvh_test::scene_path("cornell_box.obj.zst"), mbvh_test::scene_path("bun_zipper.ply.zst"),
                                 mbvh_test::scene_path("conference.obj.zst"), std::string("gen:sphere:64"),
                                 std::string("gen:soup:50000"), std::string("gen:hairball:200000"),
                                 std::string("gen:exponential:200"), std::string("gen:cube:4")}) {
    INFO(spec);
    const Scene s = load_scene(spec);
    const auto acc = Accel::build(s);
    check_invariants(s, *acc);
  }
}

TEST_CASE("leaf variants regroup the one build: every triangle once, conservative boxes, fuller leaves, valid layouts", "[build]") {
  // gen:exponential: a skewed tree deep enough for the collapses' level caps; quality high: spatial
  // splits reference one triangle from several leaves, never twice in one
  const std::pair<std::string, BuildQuality> cases[] = {{mbvh_test::scene_path("cornell_box.obj.zst"), BuildQuality::medium},
                                                        {mbvh_test::scene_path("bun_zipper.ply.zst"), BuildQuality::medium},
                                                        {"gen:soup:50000", BuildQuality::medium},
                                                        {"gen:cube:4", BuildQuality::medium},
                                                        {"gen:exponential:200", BuildQuality::medium},
                                                        {"gen:soup:20000", BuildQuality::high}};
  for (const auto& [spec, quality] : cases) {
    INFO(spec << ", quality " << to_string(quality));
    const Scene s = load_scene(spec);
    BuildOptions bo;
    bo.threads = 2;
    bo.quality = quality;
    const auto acc = Accel::build(s, bo);
    for (unsigned block : {4u, 8u}) {
      INFO("block " << block);
      const LeafVariant& v = acc->leaf_variant(block);
      REQUIRE(&v == &acc->leaf_variant(block));  // made once, kept
      const Bvh2 tree = v.tree();  // made anew at each call, the same bytes every time
      REQUIRE(tree.nodes.size() == v.tree().nodes.size());
      REQUIRE(std::memcmp(tree.nodes.data(), v.tree().nodes.data(), tree.nodes.size() * sizeof(Bvh2::Node)) == 0);
      REQUIRE(tree.leaf_boxes.size() == v.leaves.size());
      CHECK(tree.largest_leaf == v.largest_leaf);
      // -- the same triangles, each in exactly one leaf, every leaf a range of the build's order
      std::vector<int> seen(acc->tris().size(), 0);
      std::size_t in_leaves = 0, base = 0;
      for (const Leaf& l : acc->leaves()) base += l.count;
      for (std::size_t i = 0; i < v.leaves.size(); ++i) {
        const Leaf& l = v.leaves[i];
        REQUIRE(l.count >= 1);
        REQUIRE(l.count <= std::max(bo.max_leaf, block));
        REQUIRE(l.first + l.count <= acc->tris().size());
        std::vector<std::uint32_t> ids;
        for (std::uint32_t k = l.first; k < l.first + l.count; ++k) ids.push_back(tri_prim(acc->tris()[k]));
        std::sort(ids.begin(), ids.end());
        REQUIRE(std::adjacent_find(ids.begin(), ids.end()) == ids.end());  // never twice in one leaf
        const Box& lb = tree.leaf_boxes[i];
        for (std::uint32_t k = l.first; k < l.first + l.count; ++k) {
          ++seen[k];
          const Tri& t = acc->tris()[k];
          if (quality != BuildQuality::high)  // spatial splits bound a clipped part of the triangle
            for (const float* p : {t.v0, t.v1, t.v2})
              for (int a = 0; a < 3; ++a) REQUIRE((p[a] >= (&lb.lo.x)[a] && p[a] <= (&lb.hi.x)[a]));
        }
        in_leaves += l.count;
      }
      CHECK(in_leaves == base);
      std::size_t once = 0;
      for (int c : seen) once += c == 1;
      CHECK(once == base);
      CHECK(v.leaves.size() <= acc->leaves().size());
      if (acc->leaves().size() > 100) CHECK(v.leaves.size() < acc->leaves().size());  // fuller leaves
      // -- inner boxes contain their children; the layouts made from it are well formed
      for (std::size_t i = 0; i < tree.nodes.size(); ++i)
        for (std::int32_t c : tree.nodes[i].child)
          if (c != MBVH_EMPTY) REQUIRE(contains(tree.nodes[i].box, tree.box(c)));
      REQUIRE_NOTHROW(validate_layout(v.mbvh2(), v.leaves.size()));
      REQUIRE_NOTHROW(validate_layout(v.mbvh4(), v.leaves.size()));
      REQUIRE_NOTHROW(validate_layout(v.mbvh8(), v.leaves.size()));
      REQUIRE(v.tri_packs(acc->tris()).leaves.size() == v.leaves.size());
      // -- the SAH-optimal MBVH8 (wide_sah.cpp) costs no more than the greedy collapse of the same
      //    tree, in the program's own model (node visits 1, leaves priced in blocks)
      auto cost8 = [&](const Mbvh8& m) {
        double c = 0;
        for (const Node8& n : m.nodes)
          for (int k = 0; k < 8; ++k) {
            if (n.child[k] == MBVH_EMPTY) continue;
            const double a = slot_box(n, k).half_area();
            c += n.child[k] >= 0 ? a : a * std::ceil(double(v.leaves[static_cast<std::size_t>(~n.child[k])].count) / block);
          }
        return c;
      };
      const Mbvh8 greedy = make_mbvh8(tree, v.leaves);
      CHECK(cost8(v.mbvh8()) <= cost8(greedy) * (1 + 1e-6));
      CHECK(v.mbvh8().nodes.size() <= greedy.nodes.size());
      CHECK(v.mbvh8().stats.depth <= MBVH_MBVH8_LEVEL_CAP);
      const Mbvh4 greedy4 = make_mbvh4(tree, v.leaves);
      CHECK(v.mbvh4().nodes.size() <= greedy4.nodes.size());
      CHECK(v.mbvh4().stats.depth <= MBVH_MBVH4_LEVEL_CAP);
      // -- deterministic: the same variant from a build at another thread count
      BuildOptions b3 = bo;
      b3.threads = 3;
      const auto acc3 = Accel::build(s, b3);
      const LeafVariant& v3 = acc3->leaf_variant(block);
      REQUIRE(v3.leaves.size() == v.leaves.size());
      CHECK(std::memcmp(v3.leaves.data(), v.leaves.data(), v.leaves.size() * sizeof(Leaf)) == 0);
      REQUIRE(v3.mbvh8().nodes.size() == v.mbvh8().nodes.size());
      CHECK(std::memcmp(v3.mbvh8().nodes.data(), v.mbvh8().nodes.data(), v.mbvh8().nodes.size() * sizeof(Node8)) == 0);
    }
  }
}

TEST_CASE("the depth cap holds on a worst-case scene and the capped tree still traces exactly", "[build]") {
  const Scene s = load_scene("gen:exponential:200");  // the deepest tree binned SAH makes
  const auto natural = Accel::build(s);
  const unsigned cap = 8;
  REQUIRE(natural->binary_stats().depth > cap);
  CHECK(natural->binary_stats().depth <= MBVH_BINARY_DEPTH_CAP);
  BuildOptions capped_opt;
  capped_opt.depth_cap = cap;
  const auto acc = Accel::build(s, capped_opt);
  CHECK(acc->binary_stats().depth == cap);
  CHECK(acc->bvh2().forced_leaves >= 1);
  CHECK(acc->bvh2().largest_leaf > capped_opt.max_leaf);
  CHECK(acc->mbvh4().stats.depth <= cap);
  CHECK(acc->mbvh8().stats.depth <= MBVH_MBVH8_LEVEL_CAP);
  check_invariants(s, *acc);
  // rays along the row of triangles, each aimed at one of them
  for (std::size_t i = 0; i < s.triangles.size(); i += 7) {
    const Vec3f a = s.vertices[s.triangles[i][0]], b = s.vertices[s.triangles[i][1]], c = s.vertices[s.triangles[i][2]];
    const Vec3f p{(a.x + b.x + c.x) / 3, (a.y + b.y + c.y) / 3, (a.z + b.z + c.z) / 3};
    const float w = b.x - a.x;  // the triangle lies in the plane y = z: aim along its normal
    const Ray r{p.x, p.y + w, p.z - w, 0.0f, 0.0f, -1.0f, 1.0f, INFINITY};
    REQUIRE(brute_force(*acc, r).prim == i);
    const Hit want = brute_force(*acc, r);
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
      for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered}) {
        if (!reference_supports(l, t)) continue;
        TraceOptions o;
        o.layout = l;
        o.traversal = t;
        const Hit h = trace_one(*acc, r, o);
        REQUIRE(h.prim == want.prim);
      }
  }
  // a tight cap on a real scene: depth within it, answers unchanged
  BuildOptions tight;
  tight.depth_cap = 6;
  const Scene bunny = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto capped = Accel::build(bunny, tight);
  CHECK(capped->binary_stats().depth <= 6);
  check_invariants(bunny, *capped);
}

TEST_CASE("quality low's flattened tree: depth-first order, parents, heights, leaves in record order", "[build]") {
  // the LBVH writes the flattened tree itself (subtrees built apart, then moved into place and
  // their references shifted): every node's first inner child follows it, parents and heights
  // match the children, leaves come in record order and a depth-first walk meets them in index
  // order. max_leaf 1 makes every subtree too large for its spare bytes in the scratch (built
  // again in the node block); 3 threads and 1 give the same bytes
  for (const std::string& spec : {mbvh_test::scene_path("bun_zipper.ply.zst"), std::string("gen:hairball:50000"),
                                 std::string("gen:soup:3"), std::string("gen:exponential:200")}) {
    const Scene s = load_scene(spec);
    for (unsigned ml : {1u, 8u}) {
      INFO(spec << " max_leaf " << ml);
      BuildOptions o;
      o.quality = BuildQuality::low;
      o.max_leaf = ml;
      o.threads = 3;
      const auto acc = Accel::build(s, o);
      const Bvh2& b = acc->bvh2();
      const std::vector<Leaf>& leaves = acc->leaves();
      REQUIRE(b.nodes[0].parent == MBVH_NONE);
      std::size_t largest = 0;
      for (std::size_t k = 0; k < leaves.size(); ++k) {
        largest = std::max<std::size_t>(largest, leaves[k].count);
        if (k > 0) REQUIRE(leaves[k].first == leaves[k - 1].first + leaves[k - 1].count);
      }
      CHECK(b.largest_leaf == largest);
      std::size_t next_leaf = 0;
      std::vector<std::int32_t> stack{0};
      std::int32_t expect = 0;  // depth-first: the inner nodes in index order
      while (!stack.empty()) {
        const std::int32_t ref = stack.back();
        stack.pop_back();
        if (ref < 0) {
          REQUIRE(static_cast<std::size_t>(~ref) == next_leaf++);
          continue;
        }
        REQUIRE(ref == expect++);
        const Bvh2::Node& n = b.nodes[static_cast<std::size_t>(ref)];
        std::uint32_t h = 0;
        for (int k = 0; k < 2; ++k) {
          const std::int32_t c = n.child[k];
          if (c == MBVH_EMPTY || c < 0) continue;
          REQUIRE(b.nodes[static_cast<std::size_t>(c)].parent == ref);
          h = std::max(h, b.nodes[static_cast<std::size_t>(c)].height);
        }
        REQUIRE(n.height == 1 + h);
        for (int k = 1; k >= 0; --k)
          if (n.child[k] != MBVH_EMPTY) stack.push_back(n.child[k]);
      }
      CHECK(static_cast<std::size_t>(expect) == b.nodes.size());
      CHECK(next_leaf == leaves.size());
      o.threads = 1;
      CHECK(Accel::build(s, o)->hash() == acc->hash());
    }
  }
}

TEST_CASE("the build is deterministic: the same bytes at any thread count", "[build]") {
  // 1 to 3 threads and 7 (more workers than the top levels have nodes: the binned SAH splits the
  // largest nodes with their chunks on every worker until there are as many nodes as workers,
  // then hands nodes and subtrees out one at a time, in an order that depends on the timing)
  const Scene s = load_scene("gen:hairball:400000");
  constexpr unsigned kThreads[] = {1, 2, 3, 7};
  constexpr std::size_t kRuns = std::size(kThreads);
  for (BuildQuality q : {BuildQuality::medium, BuildQuality::low}) {
    INFO("quality " << to_string(q));
    std::uint64_t hashes[kRuns];
    AlignedVector<Node4> n4[kRuns];
    AlignedVector<Node8> n8[kRuns];
    double sah4[kRuns], sah8[kRuns];
    for (std::size_t r = 0; r < kRuns; ++r) {
      BuildOptions o;
      o.threads = kThreads[r];
      o.quality = q;
      const auto acc = Accel::build(s, o);
      hashes[r] = acc->hash();
      n4[r] = acc->mbvh4().nodes;
      n8[r] = acc->mbvh8().nodes;
      // a collapse of a tree this large counts its wide nodes first: an array of just those
      CHECK(acc->mbvh4().nodes.capacity() == acc->mbvh4().nodes.size());
      CHECK(acc->mbvh8().nodes.capacity() == acc->mbvh8().nodes.size());
      sah4[r] = acc->mbvh4().stats.sah_cost;
      sah8[r] = acc->mbvh8().stats.sah_cost;
    }
    for (std::size_t r = 1; r < kRuns; ++r) {
      INFO("threads " << kThreads[r]);
      CHECK(hashes[0] == hashes[r]);
      REQUIRE(n4[0].size() == n4[r].size());
      CHECK(std::memcmp(n4[0].data(), n4[r].data(), n4[0].size() * sizeof(Node4)) == 0);
      REQUIRE(n8[0].size() == n8[r].size());
      CHECK(std::memcmp(n8[0].data(), n8[r].data(), n8[0].size() * sizeof(Node8)) == 0);
      CHECK(sah4[0] == sah4[r]);
      CHECK(sah8[0] == sah8[r]);
    }
    BuildOptions o;
    o.quality = q;
    const auto other = Accel::build(load_scene("gen:hairball:400000:2"), o);
    CHECK(other->hash() != hashes[0]);
  }
}

TEST_CASE("the binned SAH's AVX2 and SSE2 loops build the same bytes", "[build]") {
  // the AVX2 loops (avx2_kernels.h) where the CPU has AVX2, against the SSE2 ones: nodes above
  // and below the chunked threshold (65536 records) and the dense bins' (64), odd and even
  // ranges (the loops take two records a step), at 1 and 3 threads
  struct Restore {
    ~Restore() { build::set_sah_kernels(build::SahKernels::best); }
  } restore;
  for (const std::string& spec : {mbvh_test::scene_path("conference.obj.zst"), mbvh_test::scene_path("cornell_box.obj.zst"),
                                 std::string("gen:hairball:150001"), std::string("gen:soup:999"),
                                 std::string("gen:cube:4"), std::string("gen:exponential:200")}) {
    INFO(spec);
    const Scene s = load_scene(spec);
    for (unsigned t : {1u, 3u}) {
      INFO("threads " << t);
      BuildOptions o;
      o.threads = t;
      build::set_sah_kernels(build::SahKernels::best);
      const auto best = Accel::build(s, o);
      build::set_sah_kernels(build::SahKernels::baseline);
      const auto base = Accel::build(s, o);
      CHECK(best->hash() == base->hash());
      CHECK(best->mbvh4().stats.sah_cost == base->mbvh4().stats.sah_cost);
    }
  }
}

TEST_CASE("the binned SAH bins a node of n records in min(bins, 4 + n / 20) bins", "[build]") {
  // every node of a scene of n triangles has at most n records, so with bins = 4 + n / 20 the
  // option never lowers a node's bins and the tree is the default's; with fewer it must differ
  for (unsigned n : {19u, 100u, 400u}) {
    INFO("triangles " << n);
    const Scene s = load_scene("gen:soup:" + std::to_string(n));
    BuildOptions o;
    o.threads = 1;
    const std::uint64_t want = Accel::build(s, o)->hash();
    o.bins = 4 + n / 20;
    CHECK(Accel::build(s, o)->hash() == want);
    if (n >= 100) {
      o.bins = 4;
      CHECK(Accel::build(s, o)->hash() != want);
    }
  }
}

TEST_CASE("a progress callback that throws inside the build is rethrown at any thread count; the next build is whole",
          "[build]") {
  // the binned SAH's workers take nodes from a shared heap and wait while others may still add
  // to it: a worker that throws (here in the callback, called as subtrees finish) must not leave
  // the others waiting for it
  const Scene s = load_scene("gen:hairball:100000");
  BuildOptions one;
  one.threads = 1;
  const std::uint64_t want = Accel::build(s, one)->hash();
  for (unsigned t : {1u, 2u, 3u, 7u}) {
    INFO("threads " << t);
    BuildOptions o;
    o.threads = t;
    std::atomic<int> calls{0};
    o.progress = [&calls](double f) {
      if (f > 0.3 && f < 0.9 && calls++ == 0) throw std::runtime_error("progress stops the build");
    };
    CHECK_THROWS_WITH(Accel::build(s, o), "progress stops the build");
    CHECK(calls.load() >= 1);
    BuildOptions again;
    again.threads = t;
    CHECK(Accel::build(s, again)->hash() == want);
  }
}

TEST_CASE("quality low builds a valid tree within the depth cap and max leaf", "[build]") {
  for (const std::string& spec : {mbvh_test::scene_path("cornell_box.obj.zst"), mbvh_test::scene_path("bun_zipper.ply.zst"),
                                 std::string("gen:sphere:64"), std::string("gen:soup:50000"),
                                 std::string("gen:hairball:200000"), std::string("gen:exponential:200"),
                                 std::string("gen:cube:4")}) {
    INFO(spec);
    const Scene s = load_scene(spec);
    BuildOptions o;
    o.quality = BuildQuality::low;
    const auto acc = Accel::build(s, o);
    check_invariants(s, *acc);
    CHECK(acc->binary_stats().depth <= MBVH_BINARY_DEPTH_CAP);
    CHECK(acc->bvh2().largest_leaf <= o.max_leaf);
    CHECK(acc->bvh2().forced_leaves == 0);
  }
  // a tight cap: halvings by count keep every leaf within max_leaf while the cap allows it
  BuildOptions tight;
  tight.quality = BuildQuality::low;
  tight.depth_cap = 14;
  const Scene bunny = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));  // 69K triangles: 2^14 * 8 > 69K
  const auto capped = Accel::build(bunny, tight);
  CHECK(capped->binary_stats().depth <= 14);
  CHECK(capped->bvh2().largest_leaf <= tight.max_leaf);
  check_invariants(bunny, *capped);
  tight.depth_cap = 6;
  const auto forced = Accel::build(bunny, tight);
  CHECK(forced->binary_stats().depth <= 6);
  CHECK(forced->bvh2().forced_leaves >= 1);
  check_invariants(bunny, *forced);
  // max_leaf of 1 (no leaf SAH collapse), the default 8, beyond the leaf pricing's room on the
  // stack (32), and beyond the smallest subtree task (4,096 records, where the top's split and a
  // task's collapse must agree): valid, within max_leaf, none forced, the same bytes at 1 and 2 threads
  for (unsigned ml : {1u, 8u, 33u, 48u, 5000u}) {
    INFO("max_leaf " << ml);
    BuildOptions o;
    o.quality = BuildQuality::low;
    o.max_leaf = ml;
    std::uint64_t hash[2];
    for (unsigned t = 1; t <= 2; ++t) {
      o.threads = t;
      const auto acc = Accel::build(bunny, o);
      check_invariants(bunny, *acc);
      CHECK(acc->bvh2().largest_leaf <= ml);
      CHECK(acc->bvh2().forced_leaves == 0);
      hash[t - 1] = acc->hash();
    }
    CHECK(hash[0] == hash[1]);
  }
  CHECK(parse_quality("low") == BuildQuality::low);
  CHECK_THROWS_AS(parse_quality("best"), Error);
}

// The LBVH's top splits nodes of more records than its smallest subtree task (at least 4,096,
// more at fewer threads) and hands the rest to tasks; a task prices a node of at most max_leaf
// records as one leaf or a subtree. Where max_leaf exceeds the task size, a node in between must
// be priced the same way at every thread count: here 72,000 slivers that each span the unit cube,
// so every node of at most max_leaf records prices cheapest as one leaf, and their Morton halvings
// pass through nodes of about 4,500 records.
TEST_CASE("quality low with max_leaf above the subtree task size: the same nodes at any thread count", "[build]") {
  Scene s;
  s.name = "slivers";
  std::uint64_t state = 12345;
  const auto next = [&] {  // a uniform float in [0, 1)
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    return static_cast<float>(state >> 40) * 0x1p-24f;
  };
  for (std::uint32_t i = 0; i < 72000; ++i) {
    const float j = 1e-3f * next(), k = 1e-3f * next(), l = 1e-3f * next();
    s.vertices.push_back({j, k, l});
    s.vertices.push_back({1.0f - k, 1.0f - l, 1.0f - j});
    s.vertices.push_back({0.5f + l, 0.5f - j, 0.5f + k + 1e-3f * next()});
    s.triangles.push_back({3 * i, 3 * i + 1, 3 * i + 2});
  }
  BuildOptions o;
  o.quality = BuildQuality::low;
  o.max_leaf = 5000;
  std::uint64_t want = 0;
  for (unsigned t : {1u, 2u, 3u, 4u}) {
    INFO(t << " threads");
    o.threads = t;
    const auto acc = Accel::build(s, o);
    check_invariants(s, *acc);
    CHECK(acc->bvh2().largest_leaf <= o.max_leaf);
    if (t == 1) want = acc->hash();
    else CHECK(acc->hash() == want);
  }
}

// The high-quality build's invariants: a leaf's triangles are whole file triangles with their
// prim ids, never one twice in a leaf; every non-degenerate triangle in some leaf; at most 30 %
// more references; boxes nest; each leaf's box meets its triangles' boxes (it bounds their parts).
void check_high_invariants(const Scene& scene, const Accel& acc) {
  const Bvh2& b = acc.bvh2();
  std::size_t covered = 0;
  std::vector<std::uint8_t> seen(scene.triangles.size(), 0);
  for (std::size_t li = 0; li < acc.leaves().size(); ++li) {
    const Leaf& l = acc.leaves()[li];
    REQUIRE(l.first == covered);
    REQUIRE(l.count >= 1);
    covered += l.count;
    std::vector<std::uint32_t> prims;
    for (std::uint32_t i = l.first; i < l.first + l.count; ++i) {
      const Tri& t = acc.tris()[i];
      const std::uint32_t p = tri_prim(t);
      REQUIRE(p < scene.triangles.size());
      prims.push_back(p);
      seen[p] = 1;
      const auto& f = scene.triangles[p];
      REQUIRE(t.v0[0] == scene.vertices[f[0]].x);
      REQUIRE(t.v1[1] == scene.vertices[f[1]].y);
      REQUIRE(t.v2[2] == scene.vertices[f[2]].z);
      const Box tb = tri_box(t), lb = b.leaf_boxes[li];
      for (int a = 0; a < 3; ++a) REQUIRE((lb.lo[a] <= tb.hi[a] && tb.lo[a] <= lb.hi[a]));
    }
    std::sort(prims.begin(), prims.end());
    REQUIRE(std::adjacent_find(prims.begin(), prims.end()) == prims.end());
  }
  REQUIRE(covered == acc.tris().size());
  std::size_t kept = 0;
  for (std::uint8_t s : seen) kept += s;
  REQUIRE(kept + b.degenerate == scene.triangles.size());
  REQUIRE(double(acc.tris().size()) <= 1.3 * double(kept) + 1);
  for (const auto& n : b.nodes)
    for (int k = 0; k < 2; ++k)
      if (n.child[k] != MBVH_EMPTY) REQUIRE(contains(n.box, b.box(n.child[k])));
  REQUIRE(acc.binary_stats().depth <= MBVH_BINARY_DEPTH_CAP);
  REQUIRE(b.largest_leaf <= acc.options().max_leaf);
  validate_layout(acc.mbvh4(), acc.leaves().size());
}

TEST_CASE("quality high - spatial splits keep whole triangles and are deterministic at 1 2 3 threads", "[build][quality]") {
  for (const std::string& spec : {std::string("gen:soup:8000"), mbvh_test::scene_path("sibenik.obj.zst")}) {
    INFO(spec);
    const Scene s = load_scene(spec);
    std::uint64_t hashes[3];
    for (unsigned t = 1; t <= 3; ++t) {
      BuildOptions o;
      o.quality = BuildQuality::high;
      o.threads = t;
      const auto acc = Accel::build(s, o);
      hashes[t - 1] = acc->hash();
      if (t == 2) {
        check_high_invariants(s, *acc);
        const auto med = Accel::build(s);
        CHECK(acc->tris().size() > med->tris().size());           // it split
        // and it paid off where triangles overlap (the soup is checked by the traversal tests)
        if (spec.find("sibenik") != std::string::npos) CHECK(acc->binary_stats().sah_cost < med->binary_stats().sah_cost);
        CHECK(acc->hash() != med->hash());
      }
    }
    CHECK(hashes[0] == hashes[1]);
    CHECK(hashes[0] == hashes[2]);
  }
  CHECK(parse_quality("high") == BuildQuality::high);
  CHECK_THROWS_AS(parse_quality("ultra"), Error);
}

TEST_CASE("degenerate triangles never reach a leaf - empty scenes are an error", "[build]") {
  Scene s;
  s.name = "mixed";
  s.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {2, 0, 0}, {5, 5, 5}};
  s.triangles = {{0, 1, 3}, {0, 1, 2}, {4, 4, 4}, {0, 0, 1}};  // only prim 1 has area
  const auto acc = Accel::build(s);
  REQUIRE(acc->tris().size() == 1);
  CHECK(tri_prim(acc->tris()[0]) == 1);
  CHECK(acc->bvh2().degenerate == 3);
  check_invariants(s, *acc);  // a one-leaf scene: root with one leaf and an empty slot
  const Ray r{0.25f, 0.25f, 1.0f, 0.0f, 0.0f, 0.0f, -1.0f, INFINITY};
  for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
    for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered}) {
      if (!reference_supports(l, t)) continue;
      TraceOptions o;
      o.layout = l;
      o.traversal = t;
      CHECK(trace_one(*acc, r, o).prim == 1);
    }
  Scene degenerate;
  degenerate.name = "flat";
  degenerate.vertices = {{0, 0, 0}, {1, 1, 1}, {2, 2, 2}};
  degenerate.triangles = {{0, 1, 2}};
  CHECK_THROWS_WITH(Accel::build(degenerate), Catch::Contains("flat") && Catch::Contains("no non-degenerate"));
  Scene empty;
  empty.name = "empty";
  CHECK_THROWS_AS(Accel::build(empty), Error);
}


TEST_CASE("Accel::memory counts each part's records as they are made", "[build]") {
  const Scene s = load_scene("gen:sphere:24");
  CHECK(s.memory_bytes() >= s.vertices.size() * sizeof(Vec3f) + s.triangles.size() * 12);
  const auto acc = Accel::build(s);
  const Accel::MemoryStats m0 = acc->memory();
  const Bvh2& b = acc->bvh2();
  CHECK(m0.tree == b.nodes.size() * sizeof(Bvh2::Node) + b.leaf_boxes.size() * sizeof(Box) + acc->leaves().size() * sizeof(Leaf));
  CHECK(m0.triangles == acc->tris().size() * sizeof(Tri));
  CHECK(m0.nodes == 0);
  CHECK(m0.packs == 0);
  CHECK(m0.total() == m0.tree + m0.triangles);
  // -- a layout and the packs, made on first use, are counted from then on
  acc->make_layout(Layout::mbvh4);
  const TriPacks& p = acc->tri_packs();
  const Accel::MemoryStats m1 = acc->memory();
  CHECK(m1.nodes == acc->mbvh4().nodes.size() * sizeof(Node4));
  CHECK(m1.packs == p.packs.size() * sizeof(Tri4) + p.leaves.size() * sizeof(Leaf));
  CHECK(m1.tree == m0.tree);
  // -- a leaf variant: its leaf table, layout, packs and packed nodes; its tree is not kept
  const LeafVariant& v = acc->leaf_variant(4);
  const void* packed = v.packed_nodes(Layout::mbvh8, acc->tris());
  const Accel::MemoryStats m2 = acc->memory();
  const TriPacks& vp = v.tri_packs(acc->tris());
  const std::size_t copy = packed ? v.mbvh8().nodes.size() * sizeof(Node8) : 0;
  CHECK(m2.tree == m0.tree);
  CHECK(m2.nodes == m1.nodes + v.leaves.size() * sizeof(Leaf) + v.mbvh8().nodes.size() * sizeof(Node8) + copy);
  CHECK(m2.packs == m1.packs + vp.packs.size() * sizeof(Tri4) + vp.leaves.size() * sizeof(Leaf));
  CHECK(m2.triangles == m0.triangles);
}

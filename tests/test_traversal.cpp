// SPDX-License-Identifier: MIT
// test_traversal.cpp — the reference traversals on every shared scene and the generated ones,
// 50K rays of each kind (25K on the larger scenes): stack and bitstack, MBVH2, MBVH4 and MBVH8, closest and any hit all agree
// (twins bit for bit), and a spread subset of 2,000 rays per kind agrees with the
// double-precision brute force except classified ties; stack and bitstack visit the same leaves
// in the same order; invalid rays are defined misses.
#include <catch2/catch.hpp>

#include <algorithm>
#include <bit>
#include <cstddef>
#include <cstring>
#include <cmath>
#include <limits>
#include <map>
#include <random>
#include <tuple>
#include <vector>

#include "backends/cpu/cpu_backends.h"
#include "host/core/layouts.h"
#include "host/core/trace/batch.h"
#include "host/core/trace/traverse.h"
#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "host/tools/stress.h"
#include "mbvh/config.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

// Rays a kind: every backend, layout, traversal and query traces them all and is compared ray by
// ray; the edges (shared vertices and edges, grazing and degenerate rays) are the stress suite's.
// Under the sanitizers a fifth, and a quarter as many against the brute force (its loop over every
// triangle, instrumented): more rays take no other code path there, only minutes.
constexpr std::size_t kReleaseRays = 50000;
const std::size_t kRays = mbvh_test::sanitized() ? kReleaseRays / 5 : kReleaseRays;
const std::size_t kBrute = mbvh_test::sanitized() ? 500 : 2000;
// The [heavy] scenes (Release only) trace a fifth as many: what they add to the small scenes' checks
// is their trees (deep, wide, large leaves), which every ray walks; their 2,000 rays a kind against
// the brute force stay, and no code path depends on the ray count.
constexpr std::size_t kHeavyRays = kReleaseRays / 5;
constexpr std::size_t kLeafOrderRays = 3000;

using RefOutputs = std::map<std::tuple<Layout, Traversal, Query, unsigned>, TraceOutput>;

/// The packet traversals (packet-ranged, packet-partition; MBVH2 and MBVH8 for the hybrid's single
/// rays) of every SIMD cpu backend in `grid`, with the hybrid switch on and off (every packet a
/// packet): each gives the bytes of the reference's packet_single_ray traversal on the leaves it
/// traces, but for rare order-dependent ties. `refs` caches the reference outputs by (layout,
/// traversal, query, leaf block).
void check_packets(const Accel& acc, const std::vector<Ray>& rays, const VariantGrid& grid, RefOutputs& refs) {
  for (const std::string& name : grid.backends) {
    if (name.rfind("cpu-", 0) != 0 || name == "cpu-scalar") continue;
    for (const char* hybrid : {"1", "0"}) {
      auto backend = make_backend(name, BackendOptions{}.set("cpu.packet-hybrid", hybrid));
      for (Layout l : {Layout::mbvh2, Layout::mbvh8})
        for (Traversal t : {Traversal::packet_ranged, Traversal::packet_partition})
          for (Query q : {Query::closest, Query::any}) {
            REQUIRE(backend->supports(l, t));
            const Traversal single = packet_single_ray(l, q == Query::any);  // what the hybrid traces
            const TraceOptions refo = with_leaves_of(*backend, TraceOptions{l, single, q, false});
            auto [it, fresh] = refs.try_emplace({l, single, q, refo.leaf_block});
            if (fresh) trace_reference(acc, rays, refo, it->second, 0);
            const TraceOutput& ref = it->second;
            TraceOutput got;
            backend->trace(acc, rays, TraceOptions{l, t, q, false}, got);
            INFO(name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q) << ", cpu.packet-hybrid=" << hybrid);
            CHECK(got.invalid == ref.invalid);
            // the reference's bytes on every ray but where its own answer depends on the order it
            // visits boxes in (two hits within rounding of each other at a corner, where a box's
            // slab entry and a triangle's watertight t disagree by a few ulps: the packet's order
            // may keep the other one): such a ray must be a classified tie, and rare
            std::size_t differ = 0;
            Comparison c;
            if (q == Query::closest) {
              c = compare_hit_arrays(got.hits, ref.hits, {}, oracle_settlement(acc, rays, oracle_tie_rule(acc, rays)));
              differ = rays.size() - c.bit_identical;
            } else {
              auto [ci, cfresh] = refs.try_emplace({l, Traversal::stack, Query::closest, refo.leaf_block});
              if (cfresh) trace_reference(acc, rays, TraceOptions{l, Traversal::stack, Query::closest, false, Precision::robust, refo.leaf_block}, ci->second, 0);
              c = compare_occlusion_arrays(got.occluded, ref.occluded, ci->second.hits, rays, {}, {},
                                           oracle_settlement(acc, rays, oracle_tie_rule(acc, rays)));
              for (std::size_t i = 0; i < rays.size(); ++i) differ += got.occluded[i] != ref.occluded[i];
            }
            CHECK(c.mismatches == 0);
            CHECK(differ <= std::max<std::size_t>(1, rays.size() / 10000));
            if (differ)
              std::printf("packets: %s/%s/%s/%s hybrid=%s: %zu of %zu rays differ from the %s traversal's bytes (order-dependent ties)\n",
                          name.c_str(), to_string(l), to_string(t), to_string(q), hybrid, differ, rays.size(), to_string(single));
          }
    }
  }
}

/// The MIC path (cpu.mic=1: MBVH4 nodes tested in 16 lanes on the Node4W view) of every backend
/// that has it: each MBVH4 single-ray traversal, closest and any hit, gives the reference's bytes
/// on the leaves it traces, and with statistics on the reference's counters (the same nodes, boxes
/// and leaves). On a machine without AVX-512 it prints why it is skipped.
void check_mic(const Accel& acc, const std::vector<Ray>& rays, RefOutputs& refs) {
  for (const std::string& name : mbvh_test::mic_backends()) {
    auto backend = make_backend(name, BackendOptions{}.set("cpu.mic", "1"));
    for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered, Traversal::bitstack_retest})
      for (Query q : {Query::closest, Query::any}) {
        const TraceOptions o{Layout::mbvh4, t, q, false};
        const TraceOptions refo = with_leaves_of(*backend, o);
        auto [it, fresh] = refs.try_emplace({Layout::mbvh4, t, q, refo.leaf_block});
        if (fresh) trace_reference(acc, rays, refo, it->second, 0);
        const TraceOutput& ref = it->second;
        TraceOutput got;
        backend->trace(acc, rays, o, got);
        INFO(name << " cpu.mic=1/mbvh4/" << to_string(t) << "/" << to_string(q));
        CHECK(got.invalid == ref.invalid);
        if (q == Query::closest) CHECK(std::memcmp(ref.hits.data(), got.hits.data(), rays.size() * sizeof(Hit)) == 0);
        else CHECK(ref.occluded == got.occluded);
      }
    // the counters, on a spread subset (the counted traversal runs the reference's leaf visit)
    std::vector<Ray> some;
    for (std::size_t i : spread_indices(rays.size(), kLeafOrderRays)) some.push_back(rays[i]);
    for (Traversal t : {Traversal::stack, Traversal::bitstack})
      for (Query q : {Query::closest, Query::any}) {
        const TraceOptions o{Layout::mbvh4, t, q, true};
        TraceOutput got, ref;
        backend->trace(acc, some, o, got);
        trace_reference(acc, some, with_leaves_of(*backend, o), ref, 0);
        INFO(name << " cpu.mic=1/mbvh4/" << to_string(t) << "/" << to_string(q) << " with statistics");
        REQUIRE(got.stats.size() == some.size());
        REQUIRE(ref.stats.size() == some.size());
        CHECK(std::memcmp(got.stats.data(), ref.stats.data(), some.size() * sizeof(RayStats)) == 0);
      }
  }
}

void check_scene(const std::string& spec, const BuildOptions& bo = {}, std::size_t n_rays = kRays) {
  const VariantGrid grid = mbvh_test::all_backends();
  const Scene scene = load_scene(spec);
  const auto acc = Accel::build(scene, bo);
  for (RayKind kind : {RayKind::primary, RayKind::shadow, RayKind::diffuse, RayKind::random}) {
    INFO(spec << ", " << to_string(kind) << " rays, quality " << to_string(bo.quality));
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = n_rays;
    const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
    REQUIRE(rays.size() == n_rays);

    // -- all variants against each other, any hit against closest hit, subset against brute force
    CheckOptions co;
    co.brute_rays = kBrute;
    co.grid = grid;
    // each variant's output, for the bit-for-bit comparisons below (traced once, not again)
    std::map<std::tuple<std::string, Layout, Traversal, Query>, TraceOutput> traced;
    co.on_trace = [&](const CheckVariant& v, const TraceOutput& o) {
      traced[{v.backend, v.opt.layout, v.opt.traversal, v.opt.query}] = o;
    };
    const CheckReport rep = run_check(*acc, rays, co);
    INFO(rep.table(rays));
    CHECK(rep.brute_rays == kBrute);
    // every answer of ours is clean; a peer library's genuine mismatches are measured and
    // reported, not required away (README, the embree peer; as the stress suite does): Embree's
    // robust occlusion differed on one of the hairball's 100K shadow rays of 8x8 image tiles
    for (const Comparison& c : rep.comparisons) {
      const bool peer = c.a.rfind("embree/", 0) == 0 || c.b.rfind("embree/", 0) == 0;
      if (!peer) CHECK(c.mismatches == 0);
      else if (c.mismatches)
        std::printf("peer %s vs %s: %zu genuine mismatches of %zu rays (%s, %s rays)\n", c.a.c_str(), c.b.c_str(),
                    c.mismatches, c.rays, spec.c_str(), to_string(kind));
    }
    std::size_t hits = 0;

    // -- twins are bit-identical: each bitstack and its stack twin, per layout and query
    const std::pair<Layout, Traversal> bitstacks[] = {{Layout::mbvh2, Traversal::bitstack},
                                                      {Layout::mbvh4, Traversal::bitstack},
                                                      {Layout::mbvh4, Traversal::bitstack_retest},
                                                      {Layout::mbvh8, Traversal::bitstack},
                                                      {Layout::mbvh8, Traversal::bitstack_octant}};
    for (const auto& [l, bt] : bitstacks)
      for (Query q : {Query::closest, Query::any}) {
        TraceOutput out[2];
        for (int t = 0; t < 2; ++t) {
          TraceOptions o;
          o.layout = l;
          o.query = q;
          o.traversal = t ? bt : stack_twin(bt);
          trace_reference(*acc, rays, o, out[t], 0);
        }
        if (q == Query::closest) {
          CHECK(std::memcmp(out[0].hits.data(), out[1].hits.data(), rays.size() * sizeof(Hit)) == 0);
          for (const Hit& h : out[0].hits) hits += h.prim != MBVH_MISS_PRIM;
        } else {
          CHECK(out[0].occluded == out[1].occluded);
        }
      }
    if (kind == RayKind::primary) CHECK(hits > 0);  // the camera sees the scene

    // -- every other backend gives cpu-scalar's bytes on every variant (same kernels, same order)
    //    on the leaves it traces (its own leaf policy, with_leaves_of); the reference output of
    //    each variant is computed once, for all backends
    RefOutputs refs;
    for (const std::string& name : grid.backends) {
      if (name == "cpu-scalar") continue;
      auto backend = make_backend(name);
      if (backend->peer()) continue;  // a peer library agrees up to ties: run_check above
      for (Layout l : grid.layouts)
        for (Traversal t : grid.traversals)
          for (Query q : grid.queries) {
            if (!backend->supports(l, t)) continue;
            const TraceOptions o{l, t, q, false};
            const TraceOptions refo = with_leaves_of(*backend, o);
            auto [it, fresh] = refs.try_emplace({l, t, q, refo.leaf_block});
            if (fresh) trace_reference(*acc, rays, refo, it->second, 0);
            const TraceOutput& ref = it->second;
            const auto run = traced.find({name, l, t, q});  // run_check traced it with these options
            TraceOutput got;
            if (run == traced.end()) backend->trace(*acc, rays, o, got);
            const TraceOutput& out = run == traced.end() ? got : run->second;
            INFO(name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
            REQUIRE(out.hits.size() == (q == Query::closest ? rays.size() : 0));
            if (q == Query::closest) CHECK(std::memcmp(ref.hits.data(), out.hits.data(), rays.size() * sizeof(Hit)) == 0);
            else CHECK(ref.occluded == out.occluded);
          }
    }

    // -- the packet traversals of the SIMD cpu backends: every ray's answer is its stack
    //    traversal's bytes, with the hybrid switch and with every packet traced as a packet
    check_packets(*acc, rays, grid, refs);

    // -- the MIC path of cpu-avx512 (cpu.mic): the reference's bytes and counters on MBVH4
    check_mic(*acc, rays, refs);

    // -- same leaves in the same order
    for (std::size_t i : spread_indices(rays.size(), kLeafOrderRays))
      for (const auto& [l, bt] : bitstacks)
        for (Query q : {Query::closest, Query::any}) {
          std::vector<std::int32_t> log[2];
          for (int t = 0; t < 2; ++t) {
            TraceOptions o;
            o.layout = l;
            o.query = q;
            o.traversal = t ? bt : stack_twin(bt);
            trace_one(*acc, rays[i], o, nullptr, &log[t]);
          }
          REQUIRE(log[0] == log[1]);
        }
  }
}

}  // namespace

TEST_CASE("traversal equivalence: Cornell box", "[traversal][isa]") { check_scene(mbvh_test::scene_path("cornell_box.obj.zst")); }
TEST_CASE("traversal equivalence: Cornell box (measured data)", "[traversal][isa]") {
  check_scene(mbvh_test::scene_path("cornell_box_original_data.obj.zst"));
}
TEST_CASE("traversal equivalence: Stanford bunny", "[traversal][heavy][isa]") { check_scene(mbvh_test::scene_path("bun_zipper.ply.zst"), {}, kHeavyRays); }
TEST_CASE("traversal equivalence: Sibenik", "[traversal][heavy][isa]") { check_scene(mbvh_test::scene_path("sibenik.obj.zst"), {}, kHeavyRays); }
TEST_CASE("traversal equivalence: Sponza", "[traversal][heavy][isa]") { check_scene(mbvh_test::scene_path("sponza_dabrovic.obj.zst"), {}, kHeavyRays); }
TEST_CASE("traversal equivalence: conference room", "[traversal][heavy]") { check_scene(mbvh_test::scene_path("conference.obj.zst"), {}, kHeavyRays); }
TEST_CASE("traversal equivalence: closed sphere", "[traversal][isa]") { check_scene("gen:sphere:256"); }
TEST_CASE("traversal equivalence: closed cube", "[traversal][heavy][isa]") { check_scene("gen:cube:24", {}, kHeavyRays); }
TEST_CASE("traversal equivalence: triangle soup", "[traversal][heavy]") { check_scene("gen:soup:100000", {}, kHeavyRays); }
TEST_CASE("traversal equivalence: hairball", "[traversal][heavy]") { check_scene("gen:hairball:300000", {}, kHeavyRays); }
// Every SIMD cpu backend on `rays`, on the build's own leaves (cpu.leaf-block=1), every layout,
// stack, bitstack and the ordered stack (which the SIMD backends walk two rays at a time, batch.h),
// closest and any hit: cpu-scalar's bytes (and its count of invalid rays).
// Returns how many backends ran: none where this run's backends hold no SIMD cpu backend.
// `leaf_block`: the backends' cpu.leaf-block (1: the build's leaves; above 1: a regrouped variant,
// whose nodes' leaf references locate the packs where every leaf holds at most eight).
std::size_t check_simd_cpu_bytes(const Accel& acc, const std::vector<Ray>& rays, const std::string& what,
                                 const char* leaf_block = "1") {
  std::size_t tested = 0;
  for (const std::string& name : mbvh_test::all_backends().backends) {
    if (name.rfind("cpu-", 0) != 0 || name == "cpu-scalar") continue;
    ++tested;
    auto b = make_backend(name, BackendOptions{}.set("cpu.leaf-block", leaf_block));
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
      for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::stack_ordered, Traversal::stack_octant,
                          Traversal::bitstack_octant})
        for (Query q : {Query::closest, Query::any}) {
          if (!reference_supports(l, t)) continue;
          INFO(what << ": " << name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
          const TraceOptions o{l, t, q, false};
          TraceOutput got, want;
          b->trace(acc, rays, o, got);
          trace_reference(acc, rays, with_leaves_of(*b, o), want, 0);
          CHECK(got.invalid == want.invalid);
          if (q == Query::closest) CHECK(std::memcmp(got.hits.data(), want.hits.data(), rays.size() * sizeof(Hit)) == 0);
          else CHECK(got.occluded == want.occluded);
        }
  }
  if (tested == 0) WARN("skipped: this run's backends (MBVH_TEST_BACKENDS) hold no SIMD cpu backend");
  return tested;
}

BuildOptions big_leaves() {
  BuildOptions bo;
  bo.max_leaf = 24;
  bo.traversal_cost = 12.0f;  // leaves cheap against nodes: big leaves
  return bo;
}

// The SIMD leaves test a leaf's triangles in passes of eight (two packs) and a tail of one to four:
// on builds of leaves from 5 to 24 triangles (every pass shape, partial masks of both widths; 1-4:
// the default builds' leaves), camera, shadow and diffuse rays, and rays aimed exactly at shared
// vertices and edges (exact-zero edge functions: the scalar fallback, in either half of an
// eight-wide pass), every cpu backend gives the reference's bytes.
TEST_CASE("SIMD leaves of 1 to 24 triangles: eight-wide passes and their tails give the reference's bytes", "[traversal]") {
  const Scene bunny = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(bunny, big_leaves());
  std::map<std::uint32_t, std::size_t> sizes;
  for (const Leaf& l : acc->leaves()) ++sizes[l.count];
  for (std::uint32_t n : {5u, 8u, 9u, 12u, 13u, 16u, 17u}) {
    INFO("leaves of " << n << " triangles");
    CHECK(sizes[n] > 0);
  }
  CHECK(acc->bvh2().largest_leaf > 20);
  for (RayKind kind : {RayKind::primary, RayKind::shadow, RayKind::diffuse}) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = 30000;
    const std::vector<Ray> rays = generate_rays(bunny, *acc, ro);
    check_simd_cpu_bytes(*acc, rays, std::string("bunny ") + to_string(kind));
    // regrouped in blocks of 4 (up to the build's 24): leaves too big for packed references
    check_simd_cpu_bytes(*acc, rays, std::string("bunny, leaf block 4, ") + to_string(kind), "4");
  }
  const Scene sphere = load_scene("gen:sphere:96");
  const auto closed = Accel::build(sphere, big_leaves());
  CHECK(closed->bvh2().largest_leaf > 8);
  const std::vector<Ray> features = feature_rays(sphere, inside_point(sphere), 30000, 2000, 7);
  check_simd_cpu_bytes(*closed, features, "sphere feature rays");
  // the default build regrouped in blocks of 4: packed leaf references (TraceView::packed_refs),
  // the scalar test of undecided lanes reading the packs
  const auto plain = Accel::build(sphere);
  REQUIRE(trace_view(*plain, Layout::mbvh4, true, 4, true).packed_refs);
  check_simd_cpu_bytes(*plain, features, "sphere feature rays, default build, leaf block 4", "4");
}

#ifdef MBVH_HAVE_CPU_SIMD
namespace mbvh {
extern const CpuKernels cpu_kernels_avx512;
}

// The MBVH8 ordered stack's sorted push (AVX-512, simd/kernels.h: a sorting network on the keys
// (d, slot)) against the insertion sort it replaces (stack.h, OrderedWalk: the hits but the nearest
// pushed in reverse slot order, then a stable sort farthest first), on random masks of every size
// and random distances drawn from a few values (ties, both zeros, negative entries as the fast
// mode's): the same entries in the same order, and the nearest (the smallest d, ties to the lower
// slot: the child entered at once) last.
TEST_CASE("AVX-512 sorted push of an MBVH8 node's hits: the insertion sort's order, ties included", "[traversal][isa]") {
  std::string why = "not registered";
  for (const BackendInfo& b : list_backends())
    if (b.name == "cpu-avx512") why = b.missing_hardware ? b.missing_hardware() : std::string();
  if (!why.empty()) {
    std::printf("skipped: cpu-avx512 cannot run here (%s): its sorted push is not tested on this machine\n", why.c_str());
    return;
  }
  REQUIRE(cpu_kernels_avx512.push_sorted8 != nullptr);
  struct Entry {
    std::int32_t node;
    float d;
  };
  const float values[] = {-0.0f, 0.0f, -1.5f, 0.25f, 0.25f, 1.0f, 3.0e-39f, 2.0f, 1.0e30f, -2.0f};
  std::mt19937 rng(36);
  for (int iter = 0; iter < 20000; ++iter) {
    const unsigned mask = 1u + static_cast<unsigned>(rng() % 255u);
    const int hits = std::popcount(mask);
    std::int32_t child[8];
    float d[8];
    for (int s = 0; s < 8; ++s) {
      child[s] = static_cast<std::int32_t>(rng()) ^ (s << 28);
      // a few draws from a small set (ties), the rest arbitrary floats of either sign
      d[s] = iter % 3 != 2 ? values[rng() % 10] : std::ldexp(static_cast<float>(rng() % 1000) - 500.0f, static_cast<int>(rng() % 40) - 20);
    }
    // the reference: the nearest slot entered, the others in reverse slot order, stable-sorted by d farthest first
    int q = std::countr_zero(mask);
    for (int s = q + 1; s < 8; ++s)
      if (((mask >> s) & 1u) && d[s] < d[q]) q = s;
    std::vector<Entry> want;
    for (int s = 7; s >= 0; --s)
      if (s != q && ((mask >> s) & 1u)) want.push_back(Entry{child[s], d[s]});
    for (std::size_t i = 1; i < want.size(); ++i)
      for (std::size_t j = i; j > 0 && want[j - 1].d < want[j].d; --j) std::swap(want[j - 1], want[j]);
    want.push_back(Entry{child[q], d[q]});
    Entry got[8];
    cpu_kernels_avx512.push_sorted8(got, mask, child, d);
    INFO("mask " << mask << ", iteration " << iter);
    for (int k = 0; k < hits; ++k) {
      INFO("entry " << k);
      CHECK(got[k].node == want[static_cast<std::size_t>(k)].node);
      CHECK(std::memcmp(&got[k].d, &want[static_cast<std::size_t>(k)].d, sizeof(float)) == 0);
    }
  }
}
#endif

// The SIMD cpu backends walk MBVH8 closest-hit rays two in turn on a chunk whose directions are
// coherent (batch.h's coherent_directions): a camera's chunks are, diffuse ones are not, invalid
// directions are left out of the mean; on a batch whose chunks alternate between both (some
// walked in turn, some one ray at a time) every backend gives the reference's bytes.
TEST_CASE("MBVH8 closest hit walks two rays in turn on coherent chunks: camera rays, not diffuse ones", "[traversal]") {
  const Scene bunny = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(bunny);
  std::vector<Ray> by_kind[2];
  for (int k = 0; k < 2; ++k) {
    RayGenOptions ro;
    ro.kind = k ? RayKind::diffuse : RayKind::primary;
    ro.count = 4 * kTraceChunk;
    by_kind[k] = generate_rays(bunny, *acc, ro);
    REQUIRE(by_kind[k].size() >= 4 * kTraceChunk);
    const std::span<const Ray> rays(by_kind[k]);
    for (std::size_t b = 0; b < 4 * kTraceChunk; b += kTraceChunk) {
      INFO(to_string(ro.kind) << " rays, chunk at " << b);
      CHECK(coherent_directions(rays, b, b + kTraceChunk) == (k == 0));
    }
  }
  // invalid directions (zero, NaN, infinite) are skipped; a chunk of nothing else is not coherent
  std::vector<Ray> camera(by_kind[0].begin(), by_kind[0].begin() + kTraceChunk), invalid(kTraceChunk);
  for (std::size_t i = 0; i < kTraceChunk; i += 2 * kCoherenceStride) {
    camera[i].dx = std::numeric_limits<float>::quiet_NaN();
    invalid[i].dx = (i / kCoherenceStride) % 4 == 0 ? std::numeric_limits<float>::infinity() : 0.0f;
  }
  CHECK(coherent_directions(camera, 0, camera.size()));
  CHECK_FALSE(coherent_directions(invalid, 0, invalid.size()));
  CHECK_FALSE(coherent_directions(camera, 0, 0));
  // chunks of camera rays, invalid rays among them, and of diffuse rays in turn
  std::vector<Ray> mixed;
  for (std::size_t b = 0; b < 4 * kTraceChunk; b += kTraceChunk) {
    // the first chunk: `camera` (its own rays 0..kTraceChunk); the others from their kind's rays at b
    const std::vector<Ray>& from = b / kTraceChunk % 2 ? by_kind[1] : (b ? by_kind[0] : camera);
    const auto first = from.begin() + static_cast<std::ptrdiff_t>(b);
    mixed.insert(mixed.end(), first, first + static_cast<std::ptrdiff_t>(kTraceChunk));
  }
  check_simd_cpu_bytes(*acc, mixed, "bunny, camera and diffuse chunks");
}

// The MBVH8 bitstack's backtrack climbs to the word's lowest non-zero byte in one go, and a level
// more than eight up lies in the word's upper half. On the deepest tree binning makes
// (gen:exponential: 14 MBVH8 levels at leaf block 1), rays in the triangles' plane cross every
// box and hit nothing, so each walks the whole tree and climbs from its deepest levels to the
// root: the bitstack gives its stack twin's answers and leaf order (cpu-scalar), with walks that
// go deeper than nine levels and climb more than eight in all, and every SIMD cpu backend, walking
// two rays in turn, the reference's bytes; rays crossing the plane hit a triangle part of the way
// along. (A single backtrack of more than eight levels is checked on the word alone, below.)
TEST_CASE("MBVH8 bitstack backtracks over more than eight levels: the stack twin's answers", "[traversal][bitstack]") {
  const Scene s = load_scene("gen:exponential:200");
  const auto acc = Accel::build(s);
  // triangle k spans x_k = 2^(k / 5) to x_k + w_k in the plane y = z, at heights 0 to w_k = 0.1 x_k
  std::vector<Ray> rays;
  for (int i = 0; i < 400; ++i) {
    const float c = std::exp2(-4.0f + 0.07f * static_cast<float>(i % 100));  // a height within the wider triangles
    if (i < 200) {  // in the plane: no hit
      rays.push_back(Ray{-1.0f, c, c, 0.0f, 1.0f, 0.0f, 0.0f, INFINITY});
    } else {  // crossing the plane at x = 1.01 x_k, within triangle k (and no nearer one)
      const float x = 1.01f * std::exp2(static_cast<float>(60 + i % 120) / 5.0f), e = 0.001f * c;
      rays.push_back(Ray{-1.0f, c, c + e, 0.0f, 1.0f, 0.0f, -e / (x + 1.0f), INFINITY});
    }
  }
  TraceOutput bit, twin;
  trace_reference(*acc, rays, TraceOptions{Layout::mbvh8, Traversal::bitstack, Query::closest, true}, bit, 0);
  trace_reference(*acc, rays, TraceOptions{Layout::mbvh8, Traversal::stack, Query::closest, true}, twin, 0);
  CHECK(std::memcmp(bit.hits.data(), twin.hits.data(), rays.size() * sizeof(Hit)) == 0);
  std::size_t deep = 0, hits = 0;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    CHECK(bit.stats[i].leaves == twin.stats[i].leaves);
    CHECK(bit.stats[i].nodes == twin.stats[i].nodes);
    deep += bit.stats[i].max_depth > 9 && bit.stats[i].climbs > 8;
    hits += bit.hits[i].prim != MBVH_MISS_PRIM;
  }
  CHECK(deep > 0);
  CHECK(hits > 0);
  CHECK(hits < rays.size());
  for (const std::size_t i : {std::size_t{0}, std::size_t{150}, std::size_t{250}, std::size_t{399}}) {
    std::vector<std::int32_t> log[2];
    trace_one(*acc, rays[i], TraceOptions{Layout::mbvh8, Traversal::bitstack, Query::closest, false}, nullptr, &log[0]);
    trace_one(*acc, rays[i], TraceOptions{Layout::mbvh8, Traversal::stack, Query::closest, false}, nullptr, &log[1]);
    CHECK(log[0] == log[1]);
  }
  check_simd_cpu_bytes(*acc, rays, "exponential, rays along the triangles' plane");
}

// The MBVH8 bitstack's backtrack (detail::backtrack8) against the per-level pop it replaces (drop
// empty levels a byte at a time, then take the lowest pending slot), for words whose lowest set
// bit is each of the 128 positions: every climb length from 0 to 15, the upper half's included.
TEST_CASE("MBVH8 bitstack: the one-shift backtrack is the per-level pop, at every climb length", "[traversal][bitstack]") {
  std::mt19937_64 rng(7);
  for (int p = 0; p < 128; ++p) {
    for (int k = 0; k < 64; ++k) {
      // bit p set, those below it clear, those above it random
      std::uint64_t lo = rng(), hi = rng();
      if (p < 64) {
        lo = (lo | 1) << p;
      } else {
        lo = 0;
        hi = (hi | 1) << (p - 64);
      }
      std::uint64_t rl = lo, rh = hi;
      int up = 0;
      while ((rl & 0xFF) == 0) {
        rl = (rl >> 8) | (rh << 56);
        rh >>= 8;
        ++up;
      }
      const int slot = std::countr_zero(rl & 0xFF);
      rl ^= std::uint64_t{1} << slot;
      INFO("lowest bit " << p << ", word " << hi << " " << lo);
      const detail::Backtrack8 b = detail::backtrack8(lo, hi);
      CHECK(b.up == p / 8);
      CHECK(b.up == up);
      CHECK(b.slot == slot);
      CHECK(lo == rl);
      CHECK(hi == rh);
    }
  }
}

// The octant bitstack's climb (detail::climb8) followed by its take of the lowest pending rank is
// backtrack8, on the same words.
TEST_CASE("MBVH8 octant bitstack: the climb and the take are the one-shift backtrack", "[traversal][bitstack]") {
  std::mt19937_64 rng(11);
  for (int p = 0; p < 128; ++p) {
    for (int k = 0; k < 64; ++k) {
      std::uint64_t lo = rng(), hi = rng();
      if (p < 64) {
        lo = (lo | 1) << p;
      } else {
        lo = 0;
        hi = (hi | 1) << (p - 64);
      }
      std::uint64_t bl = lo, bh = hi;
      const detail::Backtrack8 b = detail::backtrack8(bl, bh);
      INFO("lowest bit " << p << ", word " << hi << " " << lo);
      const detail::Backtrack8 c = detail::climb8(lo, hi);
      CHECK(c.up == b.up);
      CHECK(c.slot == b.slot);
      CHECK((lo & 0xFFu) != 0);
      CHECK(std::countr_zero(lo) == b.slot);
      lo &= lo - 1;
      CHECK(lo == bl);
      CHECK(hi == bh);
    }
  }
}

// The octant bitstack's ranks (K::octant_ranks) of every hit mask in octant orders of a scene's
// nodes: taken lowest rank first, they name the slots in the octant stack's pop order
// (push_octant's stack from its top).
TEST_CASE("MBVH8 octant bitstack: ranks in the octant order pop as the octant stack", "[traversal][bitstack][layout]") {
  const Scene s = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(s);
  const Mbvh8& m = acc->mbvh8();
  REQUIRE(m.nodes.size() > 100);
  const std::int32_t child[8] = {0, 1, 2, 3, 4, 5, 6, 7};
  const float d[8] = {};
  for (std::size_t i = 0; i < m.nodes.size(); i += 97)
    for (unsigned o = 0; o < 8; ++o) {
      std::uint32_t order;
      std::memcpy(&order, reinterpret_cast<const unsigned char*>(m.nodes[i].pad) + 3 * o, sizeof(order));
      for (unsigned mask = 1; mask < 256; ++mask) {
        std::int32_t stack[16];
        float dist[16];
        int top = -1;
        const unsigned sp = ScalarKernels::push_octant<false>(stack, dist, 0, mask, order, child, d, top);
        unsigned ranks = ScalarKernels::octant_ranks(mask, order);
        INFO("node " << i << ", octant " << o << ", mask " << mask);
        REQUIRE(std::popcount(ranks) == static_cast<int>(sp));
        CHECK(((order >> (21 - 3 * std::countr_zero(ranks))) & 7u) == static_cast<unsigned>(top));
        for (unsigned k = sp; k-- > 0;) {
          const int j = std::countr_zero(ranks);
          ranks &= ranks - 1;
          CHECK(static_cast<std::int32_t>((order >> (21 - 3 * j)) & 7u) == stack[k]);
        }
      }
    }
}

// The cpu backend's uncounted traversals read nodes whose leaf references locate the SIMD packs
// (TraceView::packed_refs): each decodes to its leaf's (first pack, count) in every layout, the
// references to inner nodes and the empty slots are unchanged, and a variant with a leaf of more
// than eight triangles keeps the leaf table (nullptr). The traced bytes of both paths are checked
// against the reference by the equivalence tests and the test above.
TEST_CASE("packed leaf references locate each leaf's packs; leaves over eight keep the table", "[traversal]") {
  const Scene bunny = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(bunny);
  const LeafVariant& lv = acc->leaf_variant(4);
  const TriPacks& p = lv.tri_packs(acc->tris());
  auto same = [&](std::int32_t plain, std::int32_t packed) {
    if (plain >= 0 || plain == MBVH_EMPTY) return plain == packed;
    const Leaf& l = p.leaves[static_cast<std::size_t>(~plain)];
    const Leaf d = packed_leaf(packed);  // the kernels' decoding
    return packed < 0 && d.first == l.first && d.count == l.count;
  };
  std::size_t leaf_refs = 0, bad = 0;
  const auto* k2 = static_cast<const Node2*>(lv.packed_nodes(Layout::mbvh2, acc->tris()));
  const auto* k4 = static_cast<const Node4*>(lv.packed_nodes(Layout::mbvh4, acc->tris()));
  const auto* k8 = static_cast<const Node8*>(lv.packed_nodes(Layout::mbvh8, acc->tris()));
  REQUIRE(k2 != nullptr);
  REQUIRE(k4 != nullptr);
  REQUIRE(k8 != nullptr);
  for (std::size_t i = 0; i < lv.mbvh2().nodes.size(); ++i) {
    const Node2& n = lv.mbvh2().nodes[i];
    bad += n.link[0] != k2[i].link[0] || std::memcmp(&n, &k2[i], offsetof(Node2, link)) != 0;
    for (int f = 1; f < 4; ++f) bad += !(i == 0 && f == 1 ? n.link[f] == k2[i].link[f] : same(n.link[f], k2[i].link[f]));
    for (int f = 2; f < 4; ++f) leaf_refs += n.link[f] < 0 && n.link[f] != MBVH_EMPTY;
  }
  for (std::size_t i = 0; i < lv.mbvh4().nodes.size(); ++i) {
    const Node4& n = lv.mbvh4().nodes[i];
    bad += n.parent != k4[i].parent || std::memcmp(n.lo_x, k4[i].lo_x, 6 * sizeof n.lo_x) != 0;
    for (int s = 0; s < 4; ++s) bad += !same(n.child[s], k4[i].child[s]);
    for (int s = 0; s < 3; ++s) bad += !(i == 0 ? n.sib[s] == k4[i].sib[s] : same(n.sib[s], k4[i].sib[s]));
  }
  for (std::size_t i = 0; i < lv.mbvh8().nodes.size(); ++i) {
    const Node8& n = lv.mbvh8().nodes[i];
    bad += n.parent != k8[i].parent || std::memcmp(n.lo_x, k8[i].lo_x, 6 * sizeof n.lo_x) != 0;
    for (int s = 0; s < 8; ++s) bad += !same(n.child[s], k8[i].child[s]);
  }
  CHECK(leaf_refs == lv.leaves.size());
  CHECK(bad == 0);
  // the view the cpu backend's uncounted traversals read, and the counted ones (the leaf table)
  CHECK(trace_view(*acc, Layout::mbvh8, true, 4, true).packed_refs);
  CHECK(trace_view(*acc, Layout::mbvh8, true, 4, true).n8 == k8);
  CHECK(trace_view(*acc, Layout::mbvh4, true, 4, true).n4 == k4);
  CHECK(trace_view(*acc, Layout::mbvh2, true, 4, true).n2 == k2);
  // the root's links stay MBVH_NONE (its first leaf's code is -1 too only for one triangle)
  CHECK(k2[0].link[1] == MBVH_NONE);
  CHECK((k4[0].sib[0] == MBVH_NONE && k4[0].sib[1] == MBVH_NONE && k4[0].sib[2] == MBVH_NONE));
  CHECK(p.leaves[0].count > 1);  // so a root link packed by mistake would show
  CHECK_FALSE(trace_view(*acc, Layout::mbvh8, true, 4, false).packed_refs);
  const auto big = Accel::build(bunny, big_leaves());
  const LeafVariant& bv = big->leaf_variant(4);
  REQUIRE(std::any_of(bv.leaves.begin(), bv.leaves.end(), [](const Leaf& l) { return l.count > 8; }));
  CHECK(bv.packed_nodes(Layout::mbvh8, big->tris()) == nullptr);
  CHECK_FALSE(trace_view(*big, Layout::mbvh4, true, 4, true).packed_refs);
}

// The SIMD backends validate a ray and make its constants in vector registers (prepare_ray_simd):
// the same verdict and the same bits as prepare_ray on the edges of validity.
// The scene is at 1e-9: a direction of FLT_MIN is in the range traced exactly only in a scene that
// small (check_ray_range: M / D <= 2^100).
TEST_CASE("SIMD ray set-up: the reference's verdict and bits on the edges of validity", "[traversal]") {
  const Scene s = load_scene("gen:cube:4@scale=1e-9");
  const auto acc = Accel::build(s);
  const float inf = INFINITY, nan = NAN, fmin = std::numeric_limits<float>::min();
  const float below_min = std::nextafter(fmin, 0.0f), sub = std::numeric_limits<float>::denorm_min();
  const std::vector<Ray> rays = {
      {0, 0, 0, 0, 1, 0, 0, 0},                {0, 0, 0, 0, 1, 0, 0, -0.0f},         {0, 0, 0, -0.0f, 1, 0, 0, -0.0f},
      {0, 0, 0, 0, fmin, 0, 0, inf},           {0, 0, 0, 0, below_min, 0, 0, inf},   {0, 0, 0, 0, -fmin, sub, 0, inf},
      {0, 0, 0, 0, 1, sub, -sub, inf},         {0, 0, 0, 0, 1, -1, 0, inf},          {0, 0, 0, 0, -1, 1, 0, inf},
      {0, 0, 0, 0, 0.5f, -0.5f, 0.5f, inf},    {0, 0, 0, -inf, 1, 0, 0, inf},        {0, 0, 0, 0, 1, 0, 0, -inf},
      {0, 0, 0, 0, 1, 0, 0, nan},              {0, 0, 0, 0.5f, 1, 0, 0, 0.25f},      {0, 0, 0, 0, -0.0f, -0.0f, -0.0f, inf},
      {0, 0, 0, 0, 1, inf, 0, inf},            {0, 0, 0, 0, 1, nan, 0, inf},         {0, nan, 0, 0, 1, 0, 0, inf},
      {-inf, 0, 0, 0, 1, 0, 0, inf},           {0.1f, 0.2f, 0.3f, 1, -0.0f, 1, -1, 2}, {0.1f, -0.2f, 0.3f, 0, 3, -3, 3, 1e30f},
  };
  TraceOutput ref;
  trace_reference(*acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false}, ref, 0);
  CHECK(ref.invalid == 10);  // subnormal and zero directions, NaN/inf components, tmin -inf, tmax -inf/NaN, tmin > tmax
  check_simd_cpu_bytes(*acc, rays, "edge rays");
}

// the same checks on the fast builder's trees (BuildQuality::low), fewer rays
BuildOptions low_quality() {
  BuildOptions bo;
  bo.quality = BuildQuality::low;
  return bo;
}
TEST_CASE("traversal equivalence (quality low): Stanford bunny", "[traversal][heavy][isa]") {
  check_scene(mbvh_test::scene_path("bun_zipper.ply.zst"), low_quality(), 10000);
}
TEST_CASE("traversal equivalence (quality low): Cornell box", "[traversal][heavy][isa]") {
  check_scene(mbvh_test::scene_path("cornell_box.obj.zst"), low_quality(), 10000);
}

// -- the high-quality build (spatial splits: a triangle in several leaves) traces the same answers
BuildOptions high_quality() {
  BuildOptions o;
  o.quality = BuildQuality::high;
  return o;
}
TEST_CASE("traversal equivalence with quality high: Cornell box", "[traversal][quality][heavy][isa]") {
  check_scene(mbvh_test::scene_path("cornell_box.obj.zst"), high_quality(), 5000);
}
TEST_CASE("traversal equivalence with quality high: triangle soup", "[traversal][quality][heavy][isa]") {
  check_scene("gen:soup:3000", high_quality(), 5000);
}

TEST_CASE("quality high - closest and any hit give the medium tree's answers on every backend - no duplicated or wrong prim", "[traversal][quality]") {
  const VariantGrid grid = mbvh_test::all_backends();
  for (const std::string& spec : {std::string("gen:soup:5000"), mbvh_test::scene_path("bun_zipper.ply.zst")}) {
    const Scene scene = load_scene(spec);
    const auto med = Accel::build(scene);
    const auto high = Accel::build(scene, high_quality());
    INFO(spec);
    REQUIRE(high->tris().size() > med->tris().size());  // spatial splits happened: prims repeat across leaves
    for (RayKind kind : {RayKind::diffuse, RayKind::random}) {
      RayGenOptions ro;
      ro.kind = kind;
      ro.count = 4000;
      const std::vector<Ray> rays = generate_rays(scene, *med, ro);
      for (const std::string& name : grid.backends) {
        auto backend = make_backend(name);
        if (backend->peer()) continue;  // ties differ in a peer library: run_check covers it
        for (Layout l : grid.layouts)
          for (Traversal t : grid.traversals)
            for (Query q : {Query::closest, Query::any}) {
              if (!backend->supports(l, t)) continue;
              INFO(name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q) << "/" << to_string(kind));
              const TraceOptions o{l, t, q, false};
              TraceOutput a, b;
              backend->trace(*med, rays, o, a);
              backend->trace(*high, rays, o, b);
              if (q == Query::closest) {
                std::size_t wrong = 0;
                for (std::size_t i = 0; i < rays.size(); ++i) {
                  const Hit& h = b.hits[i];
                  wrong += std::memcmp(&a.hits[i], &h, sizeof(Hit)) != 0;
                  if (h.prim != MBVH_MISS_PRIM) REQUIRE(h.prim < scene.triangles.size());
                }
                CHECK(wrong == 0);
              } else {
                CHECK(a.occluded == b.occluded);
              }
            }
      }
    }
  }
}

TEST_CASE("rays from inside a closed mesh never leak", "[traversal][isa]") {
  for (const char* spec : {"gen:sphere:200", "gen:cube:16"}) {
    const Scene s = load_scene(spec);
    const auto acc = Accel::build(s);
    RayGenOptions ro;
    ro.kind = RayKind::random;
    ro.count = 50000;
    std::vector<Ray> rays = generate_rays(s, *acc, ro);
    for (Ray& r : rays) {  // origins squeezed into the middle of the mesh, directions kept
      r.ox *= 0.4f;
      r.oy *= 0.4f;
      r.oz *= 0.4f;
    }
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
      for (Traversal t : {Traversal::stack, Traversal::bitstack})
        for (Query q : {Query::closest, Query::any}) {
          TraceOptions o{l, t, q, false};
          TraceOutput out;
          trace_reference(*acc, rays, o, out, 0);
          std::size_t leaks = 0;
          for (std::size_t i = 0; i < rays.size(); ++i)
            leaks += q == Query::any ? !out.occluded[i] : out.hits[i].prim == MBVH_MISS_PRIM;
          INFO(spec << " " << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
          CHECK(leaks == 0);
        }
  }
}

TEST_CASE("invalid rays are defined misses - signed zeros and infinite tmax are valid", "[traversal][isa]") {
  const Scene s = load_scene("gen:cube:4");
  const auto acc = Accel::build(s);
  const float nan = NAN, inf = INFINITY;
  const std::vector<Ray> invalid = {
      {nan, 0, 0, 0, 1, 0, 0, inf}, {0, 0, 0, 0, nan, 0, 0, inf},  {0, 0, 0, nan, 1, 0, 0, inf},
      {0, 0, 0, 0, 1, 0, 0, nan},   {0, 0, 0, 0, 0, 0, 0, inf},    {0, 0, 0, 0, -0.0f, 0, 0, inf},
      {inf, 0, 0, 0, 1, 0, 0, inf}, {0, 0, 0, 0, inf, 0, 0, inf},  {0, 0, 0, 0, 1e-40f, 0, 0, inf},
      {0, 0, 0, -1, 1, 0, 0, inf},  {0, 0, 0, 2, 1, 0, 0, 1},      {0, 0, 0, 0, 1, 0, 0, -inf},
      {0, 0, 0, inf, 1, 0, 0, inf},
  };
  for (const Ray& r : invalid) CHECK(brute_force(*acc, r).prim == MBVH_MISS_PRIM);
  // axis-aligned rays with +0 and -0 components from the centre hit the cube at t = 1
  const std::vector<Ray> valid = {{0, 0, 0, 0, 1, 0, -0.0f, inf},     {0, 0, 0, 0, -0.0f, -0.0f, -1, inf},
                                  {0, 0, 0, -0.0f, 0, 1, 0, inf},     {0.5f, 0.5f, 0.5f, 0, -0.0f, 0, 1, 100}};
  for (const std::string& name : mbvh_test::all_backends().backends) {
    auto backend = make_backend(name);
    for (Layout l : {Layout::mbvh2, Layout::mbvh4})
      for (Traversal t : {Traversal::stack, Traversal::bitstack, Traversal::packet_ranged, Traversal::packet_partition}) {
        if (!backend->supports(l, t)) continue;
        for (Query q : {Query::closest, Query::any}) {
          INFO(name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
          TraceOutput out;
          backend->trace(*acc, invalid, TraceOptions{l, t, q, false}, out);
          CHECK(out.invalid == invalid.size());
          for (std::size_t i = 0; i < invalid.size(); ++i) {
            if (q == Query::any) CHECK(out.occluded[i] == 0);
            else {
              CHECK(out.hits[i].prim == MBVH_MISS_PRIM);
              CHECK(std::isinf(out.hits[i].t));
            }
          }
        }
        INFO(name << "/" << to_string(l) << "/" << to_string(t));
        TraceOutput out;
        backend->trace(*acc, valid, TraceOptions{l, t, Query::closest, false}, out);
        CHECK(out.invalid == 0);
        for (std::size_t i = 0; i < valid.size(); ++i) {
          CHECK(out.hits[i].prim != MBVH_MISS_PRIM);
          const float want = i == 3 ? 0.5f : 1.0f;
          // ours are exact; a peer's own triangle test may round (Embree 3's AVX2 Pluecker test
          // can give 1.0000001, an ulp off): within 2 ulps
          if (backend->peer()) CHECK(std::fabs(out.hits[i].t - want) <= 2 * std::numeric_limits<float>::epsilon() * want);
          else CHECK(out.hits[i].t == want);
        }
      }
  }
}

TEST_CASE("statistics count work and stay out of the answers", "[traversal][isa]") {
  const Scene s = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.count = 20000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) {
    TraceOutput plain, counted, stack;
    trace_reference(*acc, rays, TraceOptions{l, Traversal::bitstack, Query::closest, false}, plain, 0);
    trace_reference(*acc, rays, TraceOptions{l, Traversal::bitstack, Query::closest, true}, counted, 0);
    trace_reference(*acc, rays, TraceOptions{l, Traversal::stack, Query::closest, true}, stack, 0);
    CHECK(std::memcmp(plain.hits.data(), counted.hits.data(), rays.size() * sizeof(Hit)) == 0);
    REQUIRE(counted.stats.size() == rays.size());
    double climbs = 0, nodes = 0;
    if (l == Layout::mbvh4) {  // bitstack-retest against its ordered-stack twin: same work, plus re-tests
      TraceOutput retest, ordered;
      trace_reference(*acc, rays, TraceOptions{l, Traversal::bitstack_retest, Query::closest, true}, retest, 0);
      trace_reference(*acc, rays, TraceOptions{l, Traversal::stack_ordered, Query::closest, true}, ordered, 0);
      double retests = 0, leaves_b = 0, leaves_cyclic = 0;
      for (std::size_t i = 0; i < rays.size(); ++i) {
        CHECK(retest.stats[i].nodes == ordered.stats[i].nodes);
        CHECK(retest.stats[i].leaves == ordered.stats[i].leaves);
        retests += retest.stats[i].retests;
        leaves_b += retest.stats[i].leaves;
        leaves_cyclic += counted.stats[i].leaves;
      }
      CHECK(retests > 0);
      CHECK(leaves_b <= leaves_cyclic);  // full distance order and culling never visit more leaves
    }
    for (std::size_t i = 0; i < rays.size(); ++i) {
      CHECK(counted.stats[i].nodes == stack.stats[i].nodes);  // same nodes, same leaves
      CHECK(counted.stats[i].leaves == stack.stats[i].leaves);
      CHECK(counted.stats[i].tris == stack.stats[i].tris);
      CHECK(stack.stats[i].climbs == 0);
      CHECK(stack.stats[i].max_depth <= (l == Layout::mbvh2   ? MBVH_STACK2_ENTRIES
                                         : l == Layout::mbvh4 ? MBVH_STACK4_ENTRIES
                                                              : MBVH_STACK8_ENTRIES));
      climbs += counted.stats[i].climbs;
      nodes += counted.stats[i].nodes;
    }
    CHECK(climbs > 0);
    CHECK(nodes > double(rays.size()));
  }

  // every backend counts the same work as the reference, ray by ray, and reports the same state
  const VariantGrid grid = mbvh_test::all_backends();
  for (const std::string& name : grid.backends) {
    auto backend = make_backend(name);
    if (backend->peer()) continue;  // a peer library has no per-ray counters
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8})
      for (Traversal t : grid.traversals)
        for (Query q : {Query::closest, Query::any}) {
          if (!backend->supports(l, t)) continue;
          INFO(name << "/" << to_string(l) << "/" << to_string(t) << "/" << to_string(q));
          const TraceOptions o{l, t, q, true};
          TraceOutput ref, got;
          trace_reference(*acc, rays, with_leaves_of(*backend, o), ref, 0);  // the leaves it traces
          backend->trace(*acc, rays, o, got);
          REQUIRE(got.stats.size() == rays.size());
          std::size_t differ = 0;
          for (std::size_t i = 0; i < rays.size(); ++i)
            differ += std::memcmp(&ref.stats[i], &got.stats[i], sizeof(RayStats)) != 0;
          CHECK(differ == 0);
          CHECK(backend->state_bytes(o) == state_bytes_per_ray(l, t));
        }
  }
  CHECK(state_bytes_per_ray(Layout::mbvh2, Traversal::stack) == 264);
  CHECK(state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack) == 12);
  CHECK(state_bytes_per_ray(Layout::mbvh2, Traversal::stack) / state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack) == 22);
  CHECK(state_bytes_per_ray(Layout::mbvh4, Traversal::stack_ordered) == 520);  // 64 (node, distance) entries
  CHECK(state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack_retest) == 12);
  CHECK_FALSE(reference_supports(Layout::mbvh2, Traversal::bitstack_retest));
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::stack_ordered) == 1032);  // 128 (node, distance) entries
  CHECK(reference_supports(Layout::mbvh8, Traversal::stack_ordered));
  CHECK(reference_supports(Layout::mbvh8, Traversal::bitstack));  // 8 pending bits per level, 128-bit word
  CHECK(reference_supports(Layout::mbvh8, Traversal::stack));      // its twin
  CHECK_FALSE(reference_supports(Layout::mbvh8, Traversal::bitstack_retest));
  CHECK(reference_supports(Layout::mbvh8, Traversal::stack_octant));  // its nodes hold the octant orders
  CHECK_FALSE(reference_supports(Layout::mbvh4, Traversal::stack_octant));
  CHECK_FALSE(reference_supports(Layout::mbvh2, Traversal::stack_octant));
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::stack_octant) == 1032);  // 128 entries and distances
  CHECK(reference_supports(Layout::mbvh8, Traversal::bitstack_octant));
  CHECK_FALSE(reference_supports(Layout::mbvh4, Traversal::bitstack_octant));
  CHECK_FALSE(reference_supports(Layout::mbvh2, Traversal::bitstack_octant));
  CHECK(stack_twin(Traversal::bitstack_octant) == Traversal::stack_octant);
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack_octant) == 24);  // node + 128-bit word + octant
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack) == 20);  // node + 128-bit word
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::stack) == 520);    // 128 int32 entries
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::stack) / state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack) >= 22);
  CHECK(state_bytes_per_ray(Layout::mbvh8, Traversal::stack_ordered) / state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack) >= 51);
}

TEST_CASE("packets of mixed rays - invalid, axis-aligned, clipped and incoherent lanes - keep the reference's answers",
          "[traversal][packet]") {
  const VariantGrid grid = mbvh_test::all_backends();
  for (const std::string& spec : {mbvh_test::scene_path("cornell_box.obj.zst"), std::string("gen:sphere:64")}) {
    INFO(spec);
    const Scene scene = load_scene(spec);
    const auto acc = Accel::build(scene);
    RayGenOptions ro;
    ro.count = 64 * 64;
    const std::vector<Ray> primary = generate_rays(scene, *acc, ro);
    ro.kind = RayKind::special;
    const std::vector<Ray> special = generate_rays(scene, *acc, ro);
    ro.kind = RayKind::random;
    const std::vector<Ray> random = generate_rays(scene, *acc, ro);
    // packets of 64 mix coherent camera rays with lanes of other sorts: a third only with
    // lanes the frustum leaves out or bounds (invalid, clipped, starting later), so the frustum
    // tests decide; a third also with axis-parallel, mixed-sign and special lanes; a third also
    // with incoherent ones
    std::vector<Ray> mixed;
    for (std::size_t i = 0; i < primary.size(); ++i) {
      Ray r = primary[i];
      const std::size_t sort = i / 64 % 3;
      switch (i % 11) {
        case 2: r.ox = NAN; break;                                           // invalid
        case 5: r.tmax = 0.5f + 0.001f * static_cast<float>(i % 97); break;  // clipped before most hits
        case 6: r.tmin = 0.01f * static_cast<float>(i % 53); break;         // starting inside the scene
        case 3: if (sort >= 1) r = special[i % special.size()]; break;      // NaN, zero, huge, degenerate
        case 7: if (sort >= 1) r.dy = (i & 1) ? 0.0f : -0.0f; break;        // an axis-parallel component
        case 8: if (sort >= 1) r.dx = -r.dx; break;                         // a mixed sign
        case 10: if (sort == 2) r = random[i]; break;                       // incoherent
        default: break;
      }
      mixed.push_back(r);
    }
    RefOutputs refs;
    check_packets(*acc, mixed, grid, refs);
    // fast precision: a packet ray's answer is the same backend's single-ray fast answer (both run
    // tri_test_simd_mt's operations), whether its packet is traced as one or ray by ray
    for (const std::string& name : grid.backends) {
      if (name.rfind("cpu-", 0) != 0 || name == "cpu-scalar") continue;
      for (const char* hybrid : {"1", "0"}) {
        auto backend = make_backend(name, BackendOptions{}.set("cpu.packet-hybrid", hybrid));
        for (Query q : {Query::closest, Query::any}) {
          TraceOptions o{Layout::mbvh8, Traversal::stack, q, false};
          o.precision = Precision::fast;
          TraceOutput single, packets;
          backend->trace(*acc, mixed, o, single);
          o.traversal = Traversal::packet;
          backend->trace(*acc, mixed, o, packets);
          INFO(name << " fast/" << to_string(q) << ", cpu.packet-hybrid=" << hybrid);
          if (q == Query::closest) CHECK(std::memcmp(single.hits.data(), packets.hits.data(), mixed.size() * sizeof(Hit)) == 0);
          else CHECK(single.occluded == packets.occluded);
        }
      }
    }
    std::size_t invalid = 0;
    for (const Ray& r : mixed) invalid += ray_valid(r) ? 0 : 1;
    CHECK(invalid > 0);  // the batch holds invalid rays (each packet does)
  }
}

TEST_CASE("cpu-avx512 traces 16-lane packets of 128 rays, partial packets too, with the reference's answers; cpu picks "
          "its ISA per query kind and gives the same bytes",
          "[traversal][packet][isa]") {
  std::string why = "not registered";
  for (const BackendInfo& b : list_backends())
    if (b.name == "cpu-avx512") why = b.missing_hardware ? b.missing_hardware() : std::string();
  if (!why.empty()) {  // an AVX2-only machine (or MBVH_CPU_ISA=avx2): skipped, saying why
    std::printf("skipped: cpu-avx512 cannot run here (%s): its 16-lane packets are not tested on this machine\n", why.c_str());
    return;
  }
  auto avx512 = make_backend("cpu-avx512");
  CHECK_THAT(avx512->describe(), Catch::Contains("packets of 128 rays (SIMD rays of 16)"));
  const Scene scene = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(scene);
  RayGenOptions ro;
  ro.count = 64 * 5 + 13;  // two whole 128-ray packets, a 64-ray and a 13-ray partial one
  const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
  RefOutputs refs;
  VariantGrid grid;
  grid.backends = {"cpu-avx512"};
  check_packets(*acc, rays, grid, refs);
  // `cpu` (kIsaTable: AVX-512 or AVX2 kernels per kind) gives cpu-avx512's bytes on every kind
  auto cpu = make_backend("cpu");
  for (Traversal t : {Traversal::packet, Traversal::stack_ordered})
    for (Query q : {Query::closest, Query::any}) {
      INFO(to_string(t) << "/" << to_string(q));
      TraceOutput a, b;
      const TraceOptions o{Layout::mbvh8, t, q, false};
      cpu->trace(*acc, rays, o, a);
      avx512->trace(*acc, rays, o, b);
      if (q == Query::closest) CHECK(std::memcmp(a.hits.data(), b.hits.data(), rays.size() * sizeof(Hit)) == 0);
      else CHECK(a.occluded == b.occluded);
    }
}

TEST_CASE("MBVH8 nodes hold each ray octant's child order, farthest first", "[traversal][layout]") {
  // the stack-octant traversal's per-node orders (mbvh_layout.h, Node8::pad): for every node and
  // octant a permutation of the eight slots, empty boxes first, then the boxes by their near corner
  // on the octant's diagonal, farthest first; the pad's last four bytes zero
  const Scene s = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(s);
  const Mbvh8& m = acc->mbvh8();
  REQUIRE(m.nodes.size() > 100);
  std::size_t ordered_pairs = 0;
  for (const Node8& n : m.nodes) {
    unsigned char bytes[sizeof(n.pad)];
    std::memcpy(bytes, n.pad, sizeof(bytes));
    CHECK((bytes[24] | bytes[25] | bytes[26] | bytes[27]) == 0);
    for (unsigned o = 0; o < 8; ++o) {
      const std::uint32_t bits = bytes[3 * o] | bytes[3 * o + 1] << 8 | static_cast<std::uint32_t>(bytes[3 * o + 2]) << 16;
      unsigned seen = 0;
      double prev = INFINITY;
      for (int k = 0; k < 8; ++k) {
        const int slot = static_cast<int>((bits >> (3 * k)) & 7u);
        seen |= 1u << slot;
        const bool empty = n.child[slot] == MBVH_EMPTY;
        const double key = empty ? INFINITY
                                 : ((o & 1u) ? -double(n.hi_x[slot]) : double(n.lo_x[slot])) +
                                       ((o & 2u) ? -double(n.hi_y[slot]) : double(n.lo_y[slot])) +
                                       ((o & 4u) ? -double(n.hi_z[slot]) : double(n.lo_z[slot]));
        CHECK(key <= prev);  // farthest first, empty slots (infinitely far) before every box
        if (!empty && k > 0 && key < prev) ++ordered_pairs;
        prev = key;
      }
      CHECK(seen == 0xFFu);
    }
  }
  CHECK(ordered_pairs > m.nodes.size());  // the orders are not the slot order
}

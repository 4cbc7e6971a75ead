// SPDX-License-Identifier: MIT
// test_quality_none.cpp — builds without a hierarchy (BuildQuality::none) and the dacrt plumbing:
// the triangles in scene order, the layout accessors refused, refit, the hash, backends that need
// a hierarchy refusing such a build, the CLI's --quality none, and a stand-in dacrt backend (a
// triangle scan over Accel::tris()) walked by for_each_variant, check, bench, rays and render.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "host/core/layouts.h"
#include "host/core/trace/scalar_kernels.h"
#include "host/core/trace/stats.h"
#include "host/tools/bench.h"
#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "host/tools/render.h"
#include "host/tools/variants.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

constexpr const char* kNoHierarchy = "this build has no hierarchy (quality none)";

BuildOptions none_options(unsigned threads = 0) {
  BuildOptions o;
  o.quality = BuildQuality::none;
  o.threads = threads;
  return o;
}

// gen:cube:4 with degenerate triangles put among its own (a repeated vertex, three collinear
// vertices): the build keeps them out.
Scene cube_with_degenerates() {
  Scene s = load_scene("gen:cube:4");
  s.name = "cube with degenerate triangles";
  const auto first = s.triangles[0];
  s.triangles.insert(s.triangles.begin() + 3, {first[0], first[0], first[1]});
  const std::uint32_t a = static_cast<std::uint32_t>(s.vertices.size());
  s.vertices.push_back({0.0f, 0.0f, 0.0f});
  s.vertices.push_back({0.5f, 0.0f, 0.0f});
  s.vertices.push_back({1.0f, 0.0f, 0.0f});
  s.triangles.insert(s.triangles.begin() + 50, {a, a + 1, a + 2});
  s.triangles.push_back({a + 2, a + 2, a + 2});
  return s;
}

// A stand-in for the dacrt backends: traces any build, one of quality none too, from its
// triangles alone (every triangle tested, the reference's leaf rule: the smaller (t, prim)),
// supports only Traversal::dacrt. Registered (needs_hierarchy false) only while a test holds a
// FakeDacrt; otherwise it "lacks hardware", so no other test lists it.
bool g_fake_on = false;
constexpr const char* kFake = "dacrt-stand-in";

class ScanBackend final : public Backend {
public:
  std::string name() const override { return kFake; }
  std::string describe() const override { return "a triangle scan standing in for dacrt (tests only)"; }
  bool supports(Layout, Traversal t) const override { return t == Traversal::dacrt; }

protected:
  void do_prepare(const Accel&, const TraceOptions&) override {}
  void trace_batch(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    TraceView v;
    v.tris = acc.tris().data();
    const Leaf all{0, static_cast<std::uint32_t>(acc.tris().size())};
    v.leaves = &all;
    v.leaf_count = 1;
    out.reset(rays.size(), opt);
    for (std::size_t i = 0; i < rays.size(); ++i) {
      RayPre r;
      if (!prepare_ray(rays[i], r)) {
        ++out.invalid;
        continue;
      }
      Hit best = miss_hit();
      float tmax = r.tmax;
      NoStats st;
      if (opt.query == Query::any) out.occluded[i] = detail::visit_leaf<true, NoStats, false>(v, ~0, r, tmax, best, st) ? 1 : 0;
      else {
        detail::visit_leaf<false, NoStats, false>(v, ~0, r, tmax, best, st);
        out.hits[i] = best;
      }
    }
  }
};

struct FakeDacrt {
  FakeDacrt() {
    BackendInfo b;
    b.name = kFake;
    b.summary = "tests only";
    b.make = [](const BackendOptions&) { return std::make_unique<ScanBackend>(); };
    b.missing_hardware = [] { return g_fake_on ? std::string() : std::string("a test's stand-in, off outside it"); };
    b.needs_hierarchy = false;
    register_backend(b);
    g_fake_on = true;
  }
  ~FakeDacrt() { g_fake_on = false; }
};

}  // namespace

TEST_CASE("quality none: the non-degenerate triangles in scene order, the bounds of a tree's root, no layout",
          "[build][quality]") {
  const Scene s = cube_with_degenerates();
  const auto flat = Accel::build(s, none_options());
  const auto tree = Accel::build(s);
  CHECK_FALSE(flat->has_hierarchy());
  CHECK(tree->has_hierarchy());
  CHECK(flat->options().quality == BuildQuality::none);
  // -- the triangles: each non-degenerate one once, in prim order, as the scene holds it
  REQUIRE(flat->tris().size() == tree->tris().size());
  CHECK(flat->degenerate_triangles() == 3);
  CHECK(flat->degenerate_triangles() == tree->degenerate_triangles());
  std::size_t k = 0;
  for (std::uint32_t p = 0; p < s.triangle_count(); ++p) {
    if (mbvh_test::zero_area(s, p)) continue;  // degenerate: kept out
    Vec3f a, b, c;
    s.triangle(p, a, b, c);
    REQUIRE(k < flat->tris().size());
    const Tri& t = flat->tris()[k++];
    INFO("prim " << p);
    CHECK(tri_prim(t) == p);
    CHECK((t.v0[0] == a.x && t.v0[1] == a.y && t.v0[2] == a.z));
    CHECK((t.v1[0] == b.x && t.v1[1] == b.y && t.v1[2] == b.z));
    CHECK((t.v2[0] == c.x && t.v2[1] == c.y && t.v2[2] == c.z));
  }
  CHECK(k == flat->tris().size());
  // -- what works as on every build
  CHECK(std::memcmp(&flat->bounds(), &tree->bounds(), sizeof(Box)) == 0);
  CHECK(flat->scene_triangles() == s.triangle_count());
  CHECK(flat->geometry_count() == 1);
  CHECK(flat->geometry_of(5).prim_id == 5);
  CHECK(flat->binary_stats().nodes == 0);
  CHECK(flat->binary_stats().leaves == 0);
  CHECK(flat->binary_stats().bytes == flat->tris().size() * sizeof(Tri));
  CHECK(flat->generation() == 0);
  CHECK(flat->hash() != tree->hash());
  // -- every layout accessor refuses, naming the way out
  // (a Catch matcher made of && holds its parts by reference: spelled out where used)
#define REFUSED Catch::Contains(kNoHierarchy) && Catch::Contains("dacrt") && Catch::Contains("low, medium or high")
  CHECK_THROWS_WITH(flat->bvh2(), REFUSED);
  CHECK_THROWS_WITH(flat->mbvh2(), REFUSED);
  CHECK_THROWS_WITH(flat->mbvh4(), REFUSED);
  CHECK_THROWS_WITH(flat->mbvh8(), REFUSED);
  CHECK_THROWS_WITH(flat->mbvh4_wide(), REFUSED);
  CHECK_THROWS_WITH(flat->make_layout(Layout::mbvh4), REFUSED);
  CHECK_THROWS_WITH(flat->tri_packs(), REFUSED);
  CHECK_THROWS_WITH(flat->leaf_variant(4), REFUSED);
  CHECK_THROWS_WITH(flat->leaves(), REFUSED);
#undef REFUSED
  // -- the build's own checks, as every quality makes them
  Scene far = load_scene("gen:cube:4");
  far.vertices[0].x = 0x1p41f;
  CHECK_THROWS_WITH(Accel::build(far, none_options()), Catch::Contains("beyond +-2^40"));
  Scene bad = load_scene("gen:cube:4");
  bad.triangles[2][1] = 100000;
  CHECK_THROWS(Accel::build(bad, none_options()));
  Scene tiny = load_scene("gen:cube:4");
  tiny.vertices.push_back({0.0f, 0.0f, 0.0f});
  tiny.vertices.push_back({0x1p-60f, 0.0f, 0.0f});
  tiny.vertices.push_back({0.0f, 0x1p-60f, 0.0f});
  const std::uint32_t v = static_cast<std::uint32_t>(tiny.vertices.size()) - 3;
  tiny.triangles.push_back({v, v + 1, v + 2});
  CHECK_THROWS_WITH(Accel::build(tiny, none_options()), Catch::Contains("kMinTriangleArea"));
  CHECK(parse_quality("none") == BuildQuality::none);
  CHECK(std::string(to_string(BuildQuality::none)) == "none");
}

TEST_CASE("quality none: the same bytes and hash at 1 2 3 threads, and from mesh views of the same triangles",
          "[build][quality]") {
  const Scene s = load_scene("gen:soup:150000");  // three chunks of the record pass
  const auto a = Accel::build(s, none_options(1));
  for (unsigned t : {2u, 3u}) {
    const auto b = Accel::build(s, none_options(t));
    CHECK(b->hash() == a->hash());
    REQUIRE(a->tris().size() == b->tris().size());
    CHECK(std::memcmp(a->tris().data(), b->tris().data(), a->tris().size() * sizeof(Tri)) == 0);
  }
  // two views, the second geometry's prim ids after the first's
  const std::size_t half = s.triangles.size() / 2;
  Scene views;
  views.add_mesh(MeshView{&s.vertices[0].x, s.vertices.size(), 12, s.triangles[0].data(), half, 12});
  views.add_mesh(MeshView{&s.vertices[0].x, s.vertices.size(), 12, s.triangles[half].data(), s.triangles.size() - half, 12});
  const auto v = Accel::build(views, none_options(2));
  CHECK(v->hash() == a->hash());
  CHECK(v->geometry_count() == 2);
  CHECK(v->geometry_of(static_cast<std::uint32_t>(half + 3)).geom_id == 1);
  CHECK(v->geometry_of(static_cast<std::uint32_t>(half + 3)).prim_id == 3);
  // refit in chunks (a chunk's edges united into the bounds): a fresh build's bytes and bounds
  Scene moved = s;
  for (Vec3f& p : moved.vertices) p = {p.x * 0.5f + 3.0f, p.y - 0.25f * std::sin(p.x), p.z * 2.0f};
  const auto r = Accel::build(s, none_options(2));
  r->refit(moved);
  const auto fresh = Accel::build(moved, none_options(1));
  CHECK(r->hash() == fresh->hash());
  CHECK(std::memcmp(&r->bounds(), &fresh->bounds(), sizeof(Box)) == 0);
}

TEST_CASE("quality none: refit recomputes the triangles, bounds and hash, bumps the generation and refuses what refit "
          "refuses", "[build][quality]") {
  const Scene s = cube_with_degenerates();
  Scene moved = s;
  for (std::size_t i = 0; i + 3 < moved.vertices.size(); ++i) {  // the degenerate triangles' own vertices stay
    Vec3f& v = moved.vertices[i];
    v.x = v.x * 1.5f + 0.25f * std::sin(3.0f * v.y);
    v.z = v.z - 0.5f;
  }
  for (unsigned threads : {1u, 2u}) {
    INFO(threads << " threads");
    const auto acc = Accel::build(s, none_options(threads));
    const std::uint64_t h0 = acc->hash();
    acc->refit(moved);
    const auto fresh = Accel::build(moved, none_options(threads));
    REQUIRE(acc->tris().size() == fresh->tris().size());
    CHECK(std::memcmp(acc->tris().data(), fresh->tris().data(), acc->tris().size() * sizeof(Tri)) == 0);
    CHECK(std::memcmp(&acc->bounds(), &fresh->bounds(), sizeof(Box)) == 0);
    CHECK(acc->hash() == fresh->hash());
    CHECK(acc->hash() != h0);
    CHECK(acc->generation() == 1);
    CHECK_FALSE(acc->has_hierarchy());
    // -- back again: the first build's bytes
    acc->refit(s);
    CHECK(acc->hash() == h0);
    CHECK(acc->generation() == 2);
  }
  // -- refusals, the Accel left as it was
  const auto acc = Accel::build(s, none_options());
  const std::uint64_t h0 = acc->hash();
  Scene fewer = s;
  fewer.triangles.pop_back();
  CHECK_THROWS_WITH(acc->refit(fewer), Catch::Contains("refit needs the scene the build was made from"));
  Scene grown = s;  // the all-equal degenerate triangle (the last) gets area
  const std::uint32_t last = grown.triangles.back()[0];
  grown.triangles.back() = {last, last - 1, last - 2};
  grown.vertices[last - 1].y = 1.0f;
  CHECK_THROWS_WITH(acc->refit(grown), Catch::Contains("kept out as degenerate has area now"));
  Scene far = s;
  far.vertices[0].x = 0x1p41f;
  CHECK_THROWS_WITH(acc->refit(far), Catch::Contains("out of the range mbvh traces exactly"));
  CHECK(acc->hash() == h0);
  CHECK(acc->generation() == 0);
}

TEST_CASE("quality none: a backend that needs a hierarchy refuses it, naming itself, and so does the reference",
          "[build][quality]") {
  const auto flat = Accel::build(load_scene("gen:sphere:16"), none_options());
  const std::vector<Ray> rays(3, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  const TraceOptions o;
  auto scalar = make_backend("cpu-scalar");
  TraceOutput out;
#define REFUSED Catch::Contains("cpu-scalar: ") && Catch::Contains(kNoHierarchy)
  CHECK_THROWS_WITH(scalar->prepare(*flat, o), REFUSED);
  CHECK_THROWS_WITH(scalar->trace(*flat, rays, o, out), REFUSED);
  CHECK_THROWS_WITH(trace_reference(*flat, rays, o, out, 1), REFUSED);
  CHECK_THROWS_WITH(trace_one(*flat, rays[0], o), REFUSED);
#undef REFUSED
  CHECK(backend_needs_hierarchy("cpu-scalar"));
  CHECK(backend_needs_hierarchy("no such backend"));
  // brute_force reads the triangles alone
  CHECK(brute_force(*flat, rays[0]).prim != MBVH_MISS_PRIM);
}

TEST_CASE("quality none: build_cached builds without touching the cache, and save refuses", "[build][quality][cache]") {
  const Scene s = load_scene("gen:cube:4");
  mbvh_test::TempDir dir;
  Accel::CacheReport rep;
  const auto acc = Accel::build_cached(s, none_options(), (dir.path / "cache").string(), &rep);
  CHECK_FALSE(acc->has_hierarchy());
  CHECK(acc->hash() == Accel::build(s, none_options())->hash());
  CHECK_FALSE(rep.loaded);
  CHECK(rep.path.empty());
  CHECK_FALSE(std::filesystem::exists(dir.path / "cache"));
  CHECK_THROWS_WITH(acc->save(dir.file("x.mbvh"), 1), Catch::Contains("quality none has no hierarchy to save"));
  CHECK_FALSE(std::filesystem::exists(dir.file("x.mbvh")));
  // a medium build of the same scene is still saved and read back (load refuses any quality past
  // high: none is never saved)
  const auto medium = Accel::build(s);
  medium->save(dir.file("m.mbvh"), 7);
  CHECK(Accel::load(dir.file("m.mbvh"), 7)->hash() == medium->hash());
}

TEST_CASE("quality none: the CLI builds none with --quality none or for dacrt backends alone, and reports it",
          "[cli][quality]") {
  const auto info = mbvh_test::run_cli("info gen:cube:4 --quality none");
  INFO(info.output);
  CHECK(info.code == 0);
  CHECK_THAT(info.output, Catch::Contains("quality none (no hierarchy)") && Catch::Contains("192 triangle records"));
  const auto json = mbvh_test::run_cli("info gen:cube:4 --quality none --json - --quiet");
  CHECK(json.code == 0);
  CHECK_THAT(json.output, Catch::Contains("\"hierarchy\": false") && Catch::Contains("\"quality\": \"none\""));
  mbvh_test::TempDir dir;
  const auto trace = mbvh_test::run_cli("trace gen:cube:4 --quality none --backend cpu-scalar --cache " + dir.file("c"));
  INFO(trace.output);
  CHECK(trace.code == 2);
  CHECK_THAT(trace.output, Catch::Contains("quality none (no hierarchy)") && Catch::Contains("not cached") &&
                               Catch::Contains("cpu-scalar: " + std::string(kNoHierarchy)));
  CHECK_FALSE(std::filesystem::exists(dir.file("c")));
  const auto bad = mbvh_test::run_cli("trace gen:cube:4 --quality nothing");
  CHECK(bad.code != 0);
  CHECK_THAT(bad.output, Catch::Contains("none"));
  const auto bb = mbvh_test::run_cli("build-bench gen:cube:4 --quality none");
  CHECK(bb.code == 2);
  CHECK_THAT(bb.output, Catch::Contains("--quality none: build-bench times hierarchies"));
  // the traversal's name, and a backend without dacrt refusing it
  CHECK(parse_traversal("dacrt") == Traversal::dacrt);
  CHECK(std::string(to_string(Traversal::dacrt)) == "dacrt");
  const auto t = mbvh_test::run_cli("trace gen:cube:4 --backend cpu-scalar --traversal dacrt");
  CHECK(t.code == 2);
  CHECK_THAT(t.output, Catch::Contains("does not support"));
}

TEST_CASE("dacrt: the reference traces it as packet_single_ray's traversal, and no cpu backend lists it",
          "[traversal][quality]") {
  const Scene s = load_scene("gen:sphere:24");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.count = 2000;
  ro.kind = RayKind::diffuse;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) {
    CHECK_FALSE(reference_supports(l, Traversal::dacrt));
    CHECK_FALSE(make_backend("cpu-scalar")->supports(l, Traversal::dacrt));
    CHECK(std::string(layout_label(TraceOptions{l, Traversal::dacrt})) == "-");
    CHECK(std::string(layout_label(TraceOptions{l, Traversal::stack})) == to_string(l));
    for (Query q : {Query::closest, Query::any}) {
      TraceOutput a, b;
      trace_reference(*acc, rays, TraceOptions{l, Traversal::dacrt, q}, a, 2);
      trace_reference(*acc, rays, TraceOptions{l, packet_single_ray(l, q == Query::any), q}, b, 2);
      CHECK(a.hits.size() == b.hits.size());
      if (!a.hits.empty()) CHECK(std::memcmp(a.hits.data(), b.hits.data(), a.hits.size() * sizeof(Hit)) == 0);
      CHECK(a.occluded == b.occluded);
      CHECK(trace_one(*acc, rays[7], TraceOptions{l, Traversal::dacrt, q}).prim ==
            trace_one(*acc, rays[7], TraceOptions{l, packet_single_ray(l, q == Query::any), q}).prim);
    }
  }
  CHECK(stack_twin(Traversal::dacrt) == Traversal::dacrt);
  CHECK(state_bytes_per_ray(Layout::mbvh4, Traversal::dacrt) == sizeof(Ray));
}

TEST_CASE("dacrt: one variant per query and precision, checked against cpu-scalar's reference variant, labelled '-'",
          "[tools][quality]") {
  FakeDacrt fake;
  CHECK_FALSE(backend_needs_hierarchy(kFake));
  VariantGrid g;
  g.backends = {"cpu-scalar", kFake};
  g.layouts = {Layout::mbvh8, Layout::mbvh4};
  g.traversals = {Traversal::stack, Traversal::dacrt, Traversal::bitstack};  // dacrt named: still once
  g.queries = {Query::closest, Query::any};
  g.precisions = {Precision::robust, Precision::exact};
  const auto backends = make_backends(g, {});
  std::size_t dacrt = 0, others = 0;
  for_each_variant(g, backends, [&](const std::string& name, Backend&, const TraceOptions& o) {
    if (name == kFake) {
      ++dacrt;
      CHECK(o.traversal == Traversal::dacrt);
      CHECK(o.layout == Layout::mbvh8);
    } else {
      CHECK(o.traversal != Traversal::dacrt);
      ++others;
    }
  });
  CHECK(dacrt == 2);  // closest and any; the stand-in has robust only
  CHECK(others == 2 * 2 * 2 * 2);
  g.traversals = {Traversal::stack};  // not named: still once
  dacrt = 0;
  for_each_variant(g, backends, [&](const std::string& name, Backend&, const TraceOptions&) { dacrt += name == kFake; });
  CHECK(dacrt == 2);

  // -- check: the stand-in against cpu-scalar's first variant, on a build with a hierarchy
  const Scene s = load_scene("gen:sphere:24");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.count = 3000;
  ro.kind = RayKind::diffuse;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  CheckOptions co;
  co.grid = g;
  co.grid.precisions = {Precision::robust};
  co.brute_rays = 200;
  const CheckReport rep = run_check(*acc, rays, co);
  CHECK(rep.ok());
  bool seen = false;
  for (const Comparison& c : rep.comparisons)
    if (c.a == std::string(kFake) + "/-/dacrt/closest" && c.b == "cpu-scalar/mbvh8/stack/closest") {
      seen = true;
      CHECK(c.rays == rays.size());
      CHECK(c.mismatches == 0);
    }
  CHECK(seen);
  CHECK_THAT(rep.table(rays), Catch::Contains(std::string(kFake) + "/-/dacrt/any"));

  // -- check on a build of quality none, any hit alone: closest hits from the stand-in itself
  const auto flat = Accel::build(s, none_options());
  CheckOptions fo;
  fo.grid.backends = {kFake};
  fo.grid.queries = {Query::any};
  fo.brute_rays = 200;
  const CheckReport frep = run_check(*flat, rays, fo);
  CHECK(frep.ok());
  CHECK(frep.comparisons.size() == 2);  // against "closest hit exists" and the brute force
}

TEST_CASE("dacrt: bench verifies a build of quality none against the reference on a temporary tree", "[tools][quality]") {
  FakeDacrt fake;
  const Scene s = load_scene("gen:sphere:16");
  const auto flat = Accel::build(s, none_options());
  BenchOptions bo;
  bo.grid.backends = {kFake};
  bo.kinds = {RayKind::primary, RayKind::shadow};
  bo.count = 1000;
  bo.passes = 5;
  bo.warmup_seconds = 0;
  bo.error_rays = 100;
  const BenchReport rep = run_bench(s, *flat, bo);
  REQUIRE(rep.records.size() == 4);  // two kinds x closest, any
  for (const BenchRecord& r : rep.records) {
    INFO(r.ray_kind << " " << r.query);
    CHECK(r.layout == "-");
    CHECK(r.traversal == "dacrt");
    CHECK(r.verified());
    CHECK(r.verify_mismatches == 0);
    CHECK(r.state_bytes_per_ray == sizeof(Ray));
  }
  CHECK_THAT(rep.table(), Catch::Contains(kFake));
}

TEST_CASE("dacrt: rays and renders from a build of quality none equal those of a medium build", "[tools][quality]") {
  FakeDacrt fake;
  const Scene s = load_scene("gen:sphere:16");
  const auto flat = Accel::build(s, none_options());
  const auto tree = Accel::build(s);
  for (RayKind k : {RayKind::primary, RayKind::random, RayKind::shadow, RayKind::diffuse, RayKind::special, RayKind::path}) {
    INFO(to_string(k));
    RayGenOptions ro;
    ro.kind = k;
    ro.count = 300;
    const std::vector<Ray> a = generate_rays(s, *flat, ro), b = generate_rays(s, *tree, ro);
    REQUIRE(a.size() == b.size());
    CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(Ray)) == 0);
  }
  auto scan = make_backend(kFake);
  auto scalar = make_backend("cpu-scalar");
  RenderOptions o;
  o.width = o.height = 16;
  o.spp = 1;
  o.bounces = 2;
  o.traversal = Traversal::dacrt;
  const RenderResult a = render(s, *flat, *scan, o);
  o.traversal = Traversal::stack;
  const RenderResult b = render(s, *tree, *scalar, o);
  REQUIRE(a.rgb.size() == b.rgb.size());
  CHECK(std::memcmp(a.rgb.data(), b.rgb.data(), a.rgb.size() * sizeof(float)) == 0);
}

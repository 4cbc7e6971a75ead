// SPDX-License-Identifier: MIT
// test_geometry.cpp — the geometry API (mbvh/geometry.h): meshes seen through the caller's strided
// buffers build the same bytes and trace the same answers as the same triangles in one owned scene
// on every backend; geometry ids map right; refit reads the caller's moved buffers; bad views and
// outputs of the wrong size are refused; the one-ray calls agree with the batch traces.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <limits>
#include <unordered_map>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/mbvh.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

/// One mesh in the caller's layout: vertices as position + normal (stride 24 bytes) and triangles
/// as three indices + a padding word (stride 16 bytes); the normals and the padding hold NaN and
/// garbage, so reading them would show.
struct CallerMesh {
  std::vector<float> vertex_records;      // x y z nx ny nz
  std::vector<std::uint32_t> index_records;  // i0 i1 i2 pad
  MeshView view() const {
    return {vertex_records.data(), vertex_records.size() / 6, 24, index_records.data(), index_records.size() / 4, 16};
  }
  void move_vertex(std::size_t v, const Vec3f& p) {
    vertex_records[6 * v + 0] = p.x, vertex_records[6 * v + 1] = p.y, vertex_records[6 * v + 2] = p.z;
  }
};

/// The triangles [lo, hi) of `s` as a mesh of its own, vertices renumbered in first-use order.
CallerMesh cut_mesh(const Scene& s, std::size_t lo, std::size_t hi) {
  CallerMesh m;
  std::unordered_map<std::uint32_t, std::uint32_t> local;
  for (std::size_t i = lo; i < hi; ++i) {
    for (std::uint32_t v : s.triangles[i]) {
      auto [it, fresh] = local.emplace(v, static_cast<std::uint32_t>(local.size()));
      if (fresh) {
        const Vec3f& p = s.vertices[v];
        m.vertex_records.insert(m.vertex_records.end(), {p.x, p.y, p.z, NAN, 1e30f, -INFINITY});
      }
      m.index_records.push_back(it->second);
    }
    m.index_records.push_back(0xDEADBEEFu);
  }
  return m;
}

/// `s` with its triangles renumbered as cut_mesh renumbers each part: the owned twin of the views.
Scene owned_twin(const std::vector<CallerMesh>& meshes) {
  Scene t;
  t.name = "owned twin";
  for (const CallerMesh& m : meshes) {
    const std::uint32_t base = static_cast<std::uint32_t>(t.vertices.size());
    for (std::size_t v = 0; v < m.vertex_records.size() / 6; ++v)
      t.vertices.push_back({m.vertex_records[6 * v], m.vertex_records[6 * v + 1], m.vertex_records[6 * v + 2]});
    for (std::size_t i = 0; i < m.index_records.size() / 4; ++i)
      t.triangles.push_back({base + m.index_records[4 * i], base + m.index_records[4 * i + 1], base + m.index_records[4 * i + 2]});
  }
  return t;
}

/// A layout and traversal the backend implements: bitstack on MBVH4 or MBVH2 where it can, else
/// the stack (a peer library answers only as mbvh4/stack).
TraceOptions options_for(const Backend& b) {
  TraceOptions o;
  for (Traversal t : {Traversal::bitstack, Traversal::stack, Traversal::dacrt})
    for (Layout l : {Layout::mbvh4, Layout::mbvh2})
      if (b.supports(l, t)) {
        o.layout = l;
        o.traversal = t;
        return o;
      }
  return o;
}

bool same_bits(float a, float b) { return std::memcmp(&a, &b, sizeof a) == 0; }

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

}  // namespace

TEST_CASE("geometry: two meshes through strided caller buffers trace as one owned scene on every backend", "[geometry]") {
  const VariantGrid grid = mbvh_test::all_backends();
  const Scene source = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const std::size_t half = source.triangles.size() / 2;
  const std::vector<CallerMesh> meshes = {cut_mesh(source, 0, half), cut_mesh(source, half, source.triangles.size())};
  Scene views;
  views.name = "two views";
  CHECK(views.add_mesh(meshes[0].view()) == 0);
  CHECK(views.add_mesh(meshes[1].view()) == 1);
  const Scene owned = owned_twin(meshes);
  REQUIRE(views.triangle_count() == owned.triangles.size());
  CHECK(views.geometry_count() == 2);

  // -- every builder makes the same bytes from the views as from the owned arrays
  for (BuildQuality q : {BuildQuality::low, BuildQuality::medium, BuildQuality::high}) {
    BuildOptions o;
    o.quality = q;
    INFO("quality " << to_string(q));
    CHECK(Accel::build(views, o)->hash() == Accel::build(owned, o)->hash());
  }
  const auto acc_v = Accel::build(views);
  const auto acc_o = Accel::build(owned);
  CHECK(acc_v->geometry_count() == 2);
  CHECK(acc_o->geometry_count() == 1);
  CHECK(views.bounds().lo.x == owned.bounds().lo.x);
  CHECK(views.bounds().hi.y == owned.bounds().hi.y);

  // -- the same answers, ray by ray: t bits, u, v, and the prim id as (geometry, triangle)
  for (RayKind kind : {RayKind::primary, RayKind::diffuse}) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = 4000;
    const std::vector<Ray> rays = generate_rays(owned, *acc_o, ro);
    for (const std::string& name : grid.backends) {
      auto backend = make_backend(name);
      if (backend->peer()) continue;  // its own BVH: agrees up to ties only (test_traversal)
      INFO(name << " " << to_string(kind) << " rays");
      const TraceOptions opt = options_for(*backend);
      TraceOutput want;
      backend->trace(*acc_o, rays, opt, want);
      std::vector<GeomHit> got(rays.size());
      intersect(*backend, *acc_v, rays, got, opt);
      std::size_t bad = 0, hits = 0;
      for (std::size_t i = 0; i < rays.size(); ++i) {
        const Hit& w = want.hits[i];
        const GeomHit& g = got[i];
        const std::uint32_t global = g.hit() ? static_cast<std::uint32_t>(views.geometry_offset(g.geom_id)) + g.prim_id : MBVH_MISS_PRIM;
        bad += !same_bits(w.t, g.t) || !same_bits(w.u, g.u) || !same_bits(w.v, g.v) || w.prim != global;
        hits += g.hit();
      }
      CHECK(bad == 0);
      CHECK(hits > rays.size() / 20);
      // occlusion and the scene-global Hit records into caller spans
      TraceOptions any = opt;
      any.query = Query::any;
      TraceOutput want_any;
      backend->trace(*acc_o, rays, any, want_any);
      std::vector<std::uint8_t> occ(rays.size(), 7);
      occluded(*backend, *acc_v, rays, occ, opt);
      CHECK(occ == want_any.occluded);
      std::vector<Hit> raw(rays.size());
      intersect(*backend, *acc_v, rays, std::span<Hit>(raw), opt);
      CHECK(std::memcmp(raw.data(), want.hits.data(), raw.size() * sizeof(Hit)) == 0);
    }
  }
}

TEST_CASE("geometry: geometry_of maps prim ids to the geometry and its triangle", "[geometry]") {
  const Scene source = generate_scene("sphere:8");
  const std::size_t n = source.triangles.size();
  const std::vector<CallerMesh> meshes = {cut_mesh(source, 0, 10), cut_mesh(source, 10, 10), cut_mesh(source, 10, n)};
  Scene s;
  for (const CallerMesh& m : meshes) s.add_mesh(m.view());
  REQUIRE(s.geometry_count() == 3);
  CHECK(s.geometry_offset(0) == 0);
  CHECK(s.geometry_offset(1) == 10);
  CHECK(s.geometry_offset(2) == 10);
  CHECK(s.geometry_offset(3) == n);
  const auto acc = Accel::build(s);
  for (std::uint32_t prim : {0u, 9u, 10u, 11u, static_cast<std::uint32_t>(n - 1)}) {
    INFO("prim " << prim);
    const GeomPrim want = prim < 10 ? GeomPrim{0, prim} : GeomPrim{2, prim - 10};  // geometry 1 is empty
    for (const GeomPrim& got : {s.geometry_of(prim), acc->geometry_of(prim)}) {
      CHECK(got.geom_id == want.geom_id);
      CHECK(got.prim_id == want.prim_id);
    }
  }
  for (std::uint32_t prim : {static_cast<std::uint32_t>(n), MBVH_MISS_PRIM}) {
    CHECK(s.geometry_of(prim).geom_id == kInvalidGeometry);
    CHECK(acc->geometry_of(prim).geom_id == kInvalidGeometry);
    CHECK(acc->geometry_of(prim).prim_id == MBVH_MISS_PRIM);
  }
  const GeomHit miss = to_geom_hit(*acc, Hit{INFINITY, 0, 0, MBVH_MISS_PRIM});
  CHECK(!miss.hit());
  CHECK(miss.prim_id == MBVH_MISS_PRIM);
  // an owned scene is geometry 0
  CHECK(source.geometry_count() == 1);
  CHECK(source.geometry_of(5).geom_id == 0);
  CHECK(source.geometry_of(5).prim_id == 5);
  CHECK(Accel::build(source)->geometry_of(7).prim_id == 7);

  // a cached build keeps the geometries (the file holds only the triangles; the scene gives the rest)
  mbvh_test::TempDir dir;
  Accel::CacheReport rep;
  Accel::build_cached(s, {}, dir.path.string(), &rep);
  CHECK(!rep.loaded);
  const auto cached = Accel::build_cached(s, {}, dir.path.string(), &rep);
  CHECK(rep.loaded);
  CHECK(cached->geometry_count() == 3);
  CHECK(cached->geometry_of(12).geom_id == 2);
  CHECK(cached->hash() == acc->hash());
  // two views hash apart from one owned scene of the same triangles; one view hashes as it
  CHECK(s.hash() != owned_twin(meshes).hash());
  Scene one;
  const CallerMesh whole = cut_mesh(source, 0, n);
  one.add_mesh(whole.view());
  CHECK(one.hash() == owned_twin({whole}).hash());
  CHECK(Accel::cache_key(s, {}) != Accel::cache_key(owned_twin(meshes), {}));
}

TEST_CASE("geometry: refit reads the vertices the caller moved in its own buffers", "[geometry]") {
  const Scene source = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const std::size_t third = source.triangles.size() / 3;
  std::vector<CallerMesh> meshes = {cut_mesh(source, 0, third), cut_mesh(source, third, source.triangles.size())};
  Scene views;
  for (const CallerMesh& m : meshes) views.add_mesh(m.view());
  auto acc = Accel::build(views);
  auto owned_acc = Accel::build(owned_twin(meshes));
  for (Layout l : {Layout::mbvh2, Layout::mbvh4}) acc->make_layout(l);
  // move every vertex in the caller's interleaved records
  for (CallerMesh& m : meshes)
    for (std::size_t v = 0; v < m.vertex_records.size() / 6; ++v) {
      const Vec3f p{m.vertex_records[6 * v], m.vertex_records[6 * v + 1], m.vertex_records[6 * v + 2]};
      m.move_vertex(v, {p.x + 0.01f * std::sin(40.0f * p.y), p.y + 0.01f * std::sin(30.0f * p.z), p.z});
    }
  const std::uint64_t h0 = acc->hash();
  acc->refit(views);
  const Scene moved = owned_twin(meshes);
  owned_acc->refit(moved);
  CHECK(acc->hash() != h0);
  CHECK(acc->hash() == owned_acc->hash());
  CHECK(acc->generation() == 1);
  auto cpu = make_backend("cpu-scalar");
  RayGenOptions ro;
  ro.count = 2000;
  const std::vector<Ray> rays = generate_rays(moved, *owned_acc, ro);
  std::vector<GeomHit> got(rays.size());
  intersect(*cpu, *acc, rays, got);
  std::vector<Hit> want(rays.size());  // a fresh build of the moved triangles: the same t, bit for bit
  intersect(*cpu, *Accel::build(moved), rays, std::span<Hit>(want));
  std::size_t bad = 0;
  for (std::size_t i = 0; i < rays.size(); ++i) bad += !same_bits(want[i].t, got[i].t);
  CHECK(bad == 0);
  // another split of the same triangles is not the scene the build was made from
  Scene other;
  const CallerMesh all = cut_mesh(moved, 0, moved.triangles.size());
  other.add_mesh(all.view());
  CHECK_THAT(error_of([&] { acc->refit(other); }), Catch::Contains("refit needs the geometries"));
  CHECK(acc->generation() == 1);
}

TEST_CASE("geometry: bad views are refused naming the geometry and the triangle", "[geometry]") {
  const Scene source = generate_scene("sphere:6");
  CallerMesh m = cut_mesh(source, 0, source.triangles.size());
  Scene s;
  s.name = "views";
  s.add_mesh(m.view());
  MeshView v = m.view();
  v.vertices = nullptr;
  CHECK_THAT(error_of([&] { s.add_mesh(v); }), Catch::Contains("views: geometry 1: the vertex pointer is null"));
  v = m.view();
  v.indices = nullptr;
  CHECK_THAT(error_of([&] { s.add_mesh(v); }), Catch::Contains("geometry 1: the index pointer is null"));
  v = m.view();
  v.vertex_stride = 8;
  CHECK_THAT(error_of([&] { s.add_mesh(v); }), Catch::Contains("geometry 1: vertex_stride is 8 bytes"));
  v = m.view();
  v.index_stride = 4;
  CHECK_THAT(error_of([&] { s.add_mesh(v); }), Catch::Contains("geometry 1: index_stride is 4 bytes"));
  CHECK(s.geometry_count() == 1);  // none of them was added
  Scene empty_ok;
  CHECK(empty_ok.add_mesh(MeshView{nullptr, 0, 12, nullptr, 0, 12}) == 0);  // null with zero counts is fine
  Scene owned = source;
  CHECK_THAT(error_of([&] { owned.add_mesh(m.view()); }), Catch::Contains("owned arrays or mesh views, not both"));

  // indices and coordinates are checked at build time (the buffers may be filled after add_mesh)
  CallerMesh second = cut_mesh(source, 0, 5);
  s.add_mesh(second.view());
  second.index_records[4 * 3 + 1] = 999;
  CHECK_THAT(error_of([&] { Accel::build(s); }),
             Catch::Contains("views: geometry 1 triangle 3") && Catch::Contains("names vertex 999, out of range"));
  second.index_records[4 * 3 + 1] = 0;
  second.vertex_records[6 * 2 + 1] = NAN;  // vertex 2's y
  CHECK_THAT(error_of([&] { Accel::build(s); }),
             Catch::Contains("geometry 1: vertex 2 of triangle") && Catch::Contains("coordinate y = nan"));
  second.vertex_records[6 * 2 + 1] = 0x1p41f;  // beyond the exactly traced range
  CHECK_THAT(error_of([&] { Accel::build(s); }),
             Catch::Contains("of vertex 2 (triangle " + std::to_string(s.geometry_offset(1)) + ", geometry 1 triangle 0) is beyond"));
  second.vertex_records[6 * 2 + 1] = 0;
  CHECK_NOTHROW(Accel::build(s));
  // refit refuses a moved vertex that is not finite, and the build stays as it was
  auto acc = Accel::build(s);
  const std::uint64_t h = acc->hash();
  second.vertex_records[6 * 0 + 2] = INFINITY;
  CHECK_THAT(error_of([&] { acc->refit(s); }), Catch::Contains("geometry 1: vertex 0 of triangle 0"));
  CHECK(acc->hash() == h);
}

TEST_CASE("geometry: caller-owned outputs of the wrong size are refused and one-ray calls agree with batches", "[geometry]") {
  const VariantGrid grid = mbvh_test::all_backends();
  const Scene source = generate_scene("sphere:16");
  const std::vector<CallerMesh> meshes = {cut_mesh(source, 0, 100), cut_mesh(source, 100, source.triangles.size())};
  Scene s;
  for (const CallerMesh& m : meshes) s.add_mesh(m.view());
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.count = 300;
  const std::vector<Ray> rays = generate_rays(owned_twin(meshes), *acc, ro);
  for (const std::string& name : grid.backends) {
    auto backend = make_backend(name);
    INFO(name);
    const TraceOptions opt = options_for(*backend);
    std::vector<GeomHit> short_hits(rays.size() - 1);
    CHECK_THAT(error_of([&] { intersect(*backend, *acc, rays, short_hits, opt); }),
               Catch::Contains("mbvh::intersect: 300 rays but the output span holds 299 hits"));
    std::vector<Hit> long_hits(rays.size() + 1);
    CHECK_THROWS_AS(intersect(*backend, *acc, rays, std::span<Hit>(long_hits), opt), Error);
    std::vector<std::uint8_t> occ_short(3);
    CHECK_THAT(error_of([&] { occluded(*backend, *acc, rays, occ_short, opt); }),
               Catch::Contains("mbvh::occluded: 300 rays but the output span holds 3 flags"));

    std::vector<GeomHit> hits(rays.size());
    std::vector<std::uint8_t> occ(rays.size());
    intersect(*backend, *acc, rays, hits, opt);
    occluded(*backend, *acc, rays, occ, opt);
    std::size_t bad = 0, geom1 = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) {
      const GeomHit one = intersect1(*backend, *acc, rays[i], opt);
      bad += !same_bits(one.t, hits[i].t) || !same_bits(one.u, hits[i].u) || !same_bits(one.v, hits[i].v) ||
             one.geom_id != hits[i].geom_id || one.prim_id != hits[i].prim_id;
      bad += occluded1(*backend, *acc, rays[i], opt) != (occ[i] != 0);
      geom1 += hits[i].geom_id == 1;
    }
    CHECK(bad == 0);
    CHECK(geom1 > 0);
  }
}

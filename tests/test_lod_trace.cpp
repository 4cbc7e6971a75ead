// SPDX-License-Identifier: MIT
// test_lod_trace.cpp — the .mlod model's traversal (host/core/lod/traverse.h, model.cpp): at full
// detail it gives cpu-scalar's answers (zero genuine mismatches, >= 99.99 % bit-identical, no leak
// out of a closed mesh, the same at 1 and 2 threads and under a small budget), and its LOD voxel
// hits keep the error bound of the quality factor.
#include <catch2/catch.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>

#include "helpers.h"
#include "host/core/lod/format.h"
#include "host/tools/check.h"
#include "host/tools/lod_check.h"
#include "host/tools/raygen.h"
#include "mbvh/accel.h"
#include "mbvh/compare.h"
#include "mbvh/lod.h"
#include "mbvh/trace.h"

using namespace mbvh;

namespace {

struct Built {
  Scene scene;
  std::unique_ptr<Accel> acc;
  std::string model;
};

// The scene, its in-core build, and its model in `dir` with small blocks (many blocks and links).
Built build_model(const std::string& spec, const mbvh_test::TempDir& dir, unsigned block_bytes = 32u << 10) {
  Built b;
  b.scene = load_scene(spec);
  b.acc = Accel::build(b.scene);
  b.model = dir.file("m.mlod");
  lod::BuildOptions bo;
  bo.block_bytes = block_bytes;
  bo.threads = 2;
  lod::build(*lod::triangles_of(b.scene), b.model, bo);
  return b;
}

std::vector<Ray> rays_of(const Built& b, RayKind kind, std::size_t count, std::uint64_t seed = 1) {
  RayGenOptions ro;
  ro.kind = kind;
  ro.count = count;
  ro.seed = seed;
  ro.threads = 2;
  return generate_rays(b.scene, *b.acc, ro);
}

lod::CacheOptions cache_options(unsigned threads, std::uint64_t budget = 0, bool sync = true) {
  lod::CacheOptions co;
  co.threads = threads;
  co.memory_budget = budget;
  co.synchronous = sync;
  co.direct_io = false;
  return co;
}

std::vector<lod::Hit> trace(lod::Model& m, const std::vector<Ray>& rays, const lod::TraceOptions& to,
                            std::span<const lod::RayCone> cones = {}) {
  std::vector<lod::Hit> h;
  m.trace(rays, cones, to, h);
  return h;
}

bool same(const lod::Hit& a, const lod::Hit& b) {
  return std::memcmp(&a.t, &b.t, 4) == 0 && std::memcmp(&a.u, &b.u, 4) == 0 && std::memcmp(&a.v, &b.v, 4) == 0 &&
         a.prim == b.prim && a.kind == b.kind && a.face == b.face && a.node == b.node;
}

std::size_t differing(const std::vector<lod::Hit>& a, const std::vector<lod::Hit>& b) {
  REQUIRE(a.size() == b.size());
  std::size_t d = 0;
  for (std::size_t i = 0; i < a.size(); ++i) d += same(a[i], b[i]) ? 0 : 1;
  return d;
}

// The model at full detail against cpu-scalar on `kinds` (through run_lod_check, `mbvh lod
// check`'s logic): zero genuine mismatches, >= 99.99 % bit-identical, no leak; and the same
// answers at 1 and 2 threads.
void check_full_detail(const std::string& spec, std::vector<RayKind> kinds, std::size_t count) {
  mbvh_test::TempDir dir;
  const Built b = build_model(spec, dir);
  auto m2 = lod::Model::open(b.model, cache_options(2));
  check_model_source(*m2, *lod::triangles_of(b.scene));
  LodCheckOptions o;
  o.kinds = kinds;
  o.count = count;
  o.brute_rays = 500;
  o.cache = cache_options(2);
  std::vector<std::vector<Ray>> rays;
  const LodCheckReport rep = run_lod_check(*m2, b.scene, *b.acc, o, &rays);
  INFO(rep.text(rays));
  CHECK(rep.failures() == 0);
  for (const LodCheckKind& k : rep.kinds) {
    CHECK(k.report.mismatches() == 0);
    CHECK(k.bit_identical_share() >= 0.9999);
    CHECK(k.leaks == 0);
  }
  auto m1 = lod::Model::open(b.model, cache_options(1));
  lod::TraceOptions to;
  to.lod = false;
  for (const auto& r : rays) {
    CHECK(differing(trace(*m1, r, to), trace(*m2, r, to)) == 0);
    to.query = Query::any;
    CHECK(differing(trace(*m1, r, to), trace(*m2, r, to)) == 0);
    to.query = Query::closest;
  }
}

// Distance in double from p to triangle s (Ericson, "Real-Time Collision Detection", 5.1.5).
double point_triangle_distance(const double p[3], const lod::Surface& s) {
  using V = std::array<double, 3>;
  const V a{s.v[0], s.v[1], s.v[2]}, b{s.v[3], s.v[4], s.v[5]}, c{s.v[6], s.v[7], s.v[8]}, P{p[0], p[1], p[2]};
  const auto sub = [](const V& x, const V& y) { return V{x[0] - y[0], x[1] - y[1], x[2] - y[2]}; };
  const auto dot = [](const V& x, const V& y) { return x[0] * y[0] + x[1] * y[1] + x[2] * y[2]; };
  const auto at = [](const V& o, const V& e1, double s1, const V& e2, double s2) {
    return V{o[0] + s1 * e1[0] + s2 * e2[0], o[1] + s1 * e1[1] + s2 * e2[1], o[2] + s1 * e1[2] + s2 * e2[2]};
  };
  const V ab = sub(b, a), ac = sub(c, a), ap = sub(P, a);
  V q;
  const double d1 = dot(ab, ap), d2 = dot(ac, ap);
  const V bp = sub(P, b);
  const double d3 = dot(ab, bp), d4 = dot(ac, bp);
  const V cp = sub(P, c);
  const double d5 = dot(ab, cp), d6 = dot(ac, cp);
  const double vc = d1 * d4 - d3 * d2, vb = d5 * d2 - d1 * d6, va = d3 * d6 - d5 * d4;
  if (d1 <= 0 && d2 <= 0) q = a;
  else if (d3 >= 0 && d4 <= d3) q = b;
  else if (vc <= 0 && d1 >= 0 && d3 <= 0) q = at(a, ab, d1 / (d1 - d3), ac, 0);
  else if (d6 >= 0 && d5 <= d6) q = c;
  else if (vb <= 0 && d2 >= 0 && d6 <= 0) q = at(a, ab, 0, ac, d2 / (d2 - d6));
  else if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    q = at(b, sub(c, b), w, ab, 0);
  } else {
    const double den = va + vb + vc;
    if (!(den != 0)) q = a;  // degenerate: a vertex is close enough for an upper bound
    else q = at(a, ab, vb / den, ac, vc / den);
  }
  const V d = sub(P, q);
  return std::sqrt(dot(d, d));
}

}  // namespace

TEST_CASE("lod: full detail gives cpu-scalar's answers on a generated model", "[lod]") {
  check_full_detail("gen:mandelbulb:64", {RayKind::primary, RayKind::shadow, RayKind::diffuse, RayKind::random}, 20000);
}

TEST_CASE("lod: full detail gives cpu-scalar's answers on a shared scene", "[lod]") {
  check_full_detail(mbvh_test::scene_path("bun_zipper.ply.zst"), {RayKind::primary, RayKind::diffuse, RayKind::path}, 20000);
}

TEST_CASE("lod: no leak out of a closed mesh at full detail", "[lod]") {
  check_full_detail("gen:sphere:64", {RayKind::inside}, 20000);
}

TEST_CASE("lod: a small budget gives the unlimited budget's full-detail answers", "[lod]") {
  mbvh_test::TempDir dir;
  const Built b = build_model("gen:mandelbulb:64", dir, 16u << 10);
  auto big = lod::Model::open(b.model, cache_options(2));
  const lod::ModelInfo in = big->info();
  REQUIRE(in.blocks > 16);
  // the pinned blocks, and room for a quarter of the others' bytes
  const std::uint64_t budget = in.pinned_bytes + std::max<std::uint64_t>(4ull * in.block_bytes, (in.raw_bytes - in.pinned_bytes) / 4);
  auto small = lod::Model::open(b.model, cache_options(2, budget));
  for (RayKind kind : {RayKind::primary, RayKind::diffuse}) {
    const std::vector<Ray> rays = rays_of(b, kind, 10000);
    lod::TraceOptions to;
    to.lod = false;
    CHECK(differing(trace(*small, rays, to), trace(*big, rays, to)) == 0);
    to.query = Query::any;
    const auto sa = trace(*small, rays, to), ba = trace(*big, rays, to);
    std::size_t occlusion_differs = 0;
    for (std::size_t i = 0; i < rays.size(); ++i) occlusion_differs += (sa[i].kind == lod::HitKind::miss) != (ba[i].kind == lod::HitKind::miss);
    CHECK(occlusion_differs == 0);
  }
  const lod::CacheStats st = small->stats();
  CHECK(st.evictions > 0);  // the budget bit: the rays were deferred and retraced
  CHECK(st.peak_bytes <= budget);
}

TEST_CASE("lod: voxel hits keep the quality factor's error bound", "[lod]") {
  mbvh_test::TempDir dir;
  const Built b = build_model("gen:mandelbulb:128", dir);
  auto m = lod::Model::open(b.model, cache_options(2));
  const Box& box = b.acc->bounds();
  const double scale = std::max({box.hi.x - box.lo.x, box.hi.y - box.lo.y, box.hi.z - box.lo.z});
  // primary rays: pixel cones of a 64-pixel-high image of the default camera (60 degrees);
  // diffuse rays: the footprint at their origin (a pixel's at the camera's distance) widened by a
  // diffuse lobe's spread
  const float pixel = static_cast<float>(2 * std::tan(30.0 * M_PI / 180) / 64);
  struct Case {
    RayKind kind;
    lod::RayCone cone;
  };
  const Case cases[] = {{RayKind::primary, {0, pixel}}, {RayKind::diffuse, {static_cast<float>(scale) * 2e-3f, 0.05f}}};
  for (const Case& c : cases) {
    const std::vector<Ray> rays = rays_of(b, c.kind, 10000);
    const std::vector<lod::RayCone> cones(rays.size(), c.cone);
    lod::TraceOptions full;
    full.lod = false;
    const auto exact = trace(*m, rays, full);
    for (float q : {0.5f, 1.0f, 2.0f}) {
      lod::TraceOptions to;
      to.quality = q;
      const auto h = trace(*m, rays, to, cones);
      std::size_t voxels = 0, violations = 0, far = 0, forced = 0, checked = 0;
      for (std::size_t i = 0; i < h.size(); ++i) {
        if (h[i].kind != lod::HitKind::voxel) continue;
        ++voxels;
        forced += h[i].forced;
        const lod::Hit& v = h[i];
        const float ext = std::max({v.box.hi.x - v.box.lo.x, v.box.hi.y - v.box.lo.y, v.box.hi.z - v.box.lo.z});
        const double w = double(c.cone.width0) + double(c.cone.spread) * v.t;
        if (!(ext <= q * (c.cone.width0 + c.cone.spread * v.t)) || !(ext <= q * w * (1 + 1e-6))) ++violations;
        // the hit point lies on the voxel's box (its entry) and the subtree's triangles inside it,
        // so the nearest is at most the box's diagonal away: <= sqrt(3) * extent <= sqrt(3) q w(t)
        if (i % 7 != 0) continue;  // a spread subset: voxel_triangles walks the subtree
        ++checked;
        const Ray& r = rays[i];
        const double p[3] = {r.ox + double(v.t) * r.dx, r.oy + double(v.t) * r.dy, r.oz + double(v.t) * r.dz};
        double nearest = INFINITY;
        for (const lod::Surface& s : m->voxel_triangles(v.node)) nearest = std::min(nearest, point_triangle_distance(p, s));
        if (!(nearest <= std::sqrt(3.0) * q * w * (1 + 1e-5) + 1e-6 * scale)) ++far;
      }
      INFO(to_string(c.kind) << " q=" << q << ": " << voxels << " voxel hits, " << checked << " checked for distance");
      CHECK(voxels > 0);
      CHECK(forced == 0);  // synchronous loading: no block was missing at the end
      CHECK(violations == 0);
      CHECK(far == 0);
      // triangle hits are exact triangles: where a ray hits a triangle with LOD, it is a triangle at full detail too
      std::size_t phantom = 0;
      for (std::size_t i = 0; i < h.size(); ++i) phantom += h[i].kind == lod::HitKind::triangle && exact[i].kind != lod::HitKind::triangle;
      CHECK(phantom == 0);
    }
    // quality 0: never a voxel, the full-detail answers
    lod::TraceOptions q0;
    q0.quality = 0;
    CHECK(differing(trace(*m, rays, q0, cones), exact) == 0);
  }
}

TEST_CASE("lod: mbvh lod check: exit 0 on a good model, 2 naming a damaged block or another source", "[lod]") {
  using mbvh_test::run_cli;
  mbvh_test::TempDir tmp;
  const std::string m = tmp.file("s.mlod");
  REQUIRE(run_cli("lod build gen:sphere:48 -o " + m + " --block 16K --threads 2").code == 0);
  const auto ok = run_cli("lod check " + m + " --against gen:sphere:48 --kinds primary,inside,shadow --count 3000 --threads 2", "", 300);
  INFO(ok.output);
  CHECK(ok.code == 0);
  CHECK(ok.output.find("result: zero genuine mismatches, no leak") != std::string::npos);
  CHECK(ok.output.find("leaks (valid rays from inside the closed mesh that hit nothing): 0") != std::string::npos);
  CHECK(ok.output.find("(100.0000 %)") != std::string::npos);
  // another source: refused before any tracing, naming both
  const auto other = run_cli("lod check " + m + " --against gen:sphere:40 --count 100", "", 300);
  INFO(other.output);
  CHECK(other.code == 2);
  CHECK(other.output.find("was built from another source") != std::string::npos);
  // a flipped byte in a block that is not pinned: named at full detail, exit 2
  std::string bytes = mbvh_test::bytes_of(m);
  lod::format::FileHeader h;
  std::memcpy(&h, bytes.data(), sizeof h);
  std::vector<lod::format::DirEntry> dir(h.blocks);
  std::memcpy(dir.data(), bytes.data() + h.directory_offset, dir.size() * sizeof(lod::format::DirEntry));
  std::uint32_t victim = UINT32_MAX;
  for (std::uint32_t b = 0; b < dir.size(); ++b)
    if (!(dir[b].flags & lod::format::kDirPinned)) victim = b;  // the last: a fine block some ray needs
  REQUIRE(victim != UINT32_MAX);
  bytes[dir[victim].offset + dir[victim].stored_bytes / 2] ^= 0x5a;
  const std::string bad = tmp.write("bad.mlod", bytes);
  const auto damaged = run_cli("lod check " + bad + " --against gen:sphere:48 --kinds random,inside --count 20000 --threads 2", "", 300);
  INFO(damaged.output);
  CHECK(damaged.code == 2);
  CHECK(damaged.output.find("block " + std::to_string(victim)) != std::string::npos);
}

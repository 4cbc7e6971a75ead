// SPDX-License-Identifier: MIT
// test_rays.cpp — ray generators (deterministic by seed, each kind where it belongs), the exact
// file formats, and secondary rays that do not re-hit their source triangle.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <filesystem>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/error.h"
#include "host/tools/raygen.h"
#include "mbvh/trace.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::TempDir;

namespace {

double len(const Ray& r) { return std::sqrt(double(r.dx) * r.dx + double(r.dy) * r.dy + double(r.dz) * r.dz); }

}  // namespace

TEST_CASE("ray generators are deterministic by seed and fit their kind", "[rays]") {
  const Scene s = load_scene(mbvh_test::scene_path("sibenik.obj.zst"));
  const auto acc = Accel::build(s);
  const Box b = acc->bounds();
  for (RayKind k : {RayKind::primary, RayKind::shadow, RayKind::diffuse, RayKind::random}) {
    INFO(to_string(k));
    RayGenOptions o;
    o.kind = k;
    o.count = 5000;
    const auto a = generate_rays(s, *acc, o);
    o.threads = 1;
    const auto a1 = generate_rays(s, *acc, o);
    o.seed = 2;
    const auto c = generate_rays(s, *acc, o);
    REQUIRE(a.size() == 5000);
    CHECK(std::memcmp(a.data(), a1.data(), a.size() * sizeof(Ray)) == 0);  // same seed, any thread count
    CHECK(std::memcmp(a.data(), c.data(), a.size() * sizeof(Ray)) != 0);
    for (const Ray& r : a) {
      REQUIRE(ray_valid(r));
      REQUIRE(std::fabs(len(r) - 1.0) < 1e-6);
      if (k == RayKind::shadow) {
        // toward the light: the end point is the light
        const Vec3f light = default_light(b);
        CHECK(std::fabs(r.ox + r.dx * r.tmax - light.x) < 1e-3f * (b.hi.x - b.lo.x));
        REQUIRE(std::isfinite(r.tmax));
      } else {
        REQUIRE(std::isinf(r.tmax));
      }
      if (k == RayKind::random)
        for (int ax = 0; ax < 3; ++ax) {
          const float o3[3] = {r.ox, r.oy, r.oz};
          const float e = b.hi[ax] - b.lo[ax];
          REQUIRE(o3[ax] >= b.lo[ax] - 0.11f * e);
          REQUIRE(o3[ax] <= b.hi[ax] + 0.11f * e);
        }
    }
  }
}

TEST_CASE("ray hit and occlusion files are exact and never left partial", "[rays][files]") {
  TempDir dir;
  const std::vector<Ray> rays = {{1, 2, 3, 0, 0, 0, 1, INFINITY}, {-1, 0.5f, 1e-30f, 0.25f, 1, -0.0f, 0, 7}};
  write_rays(dir.file("r.rays"), rays);
  CHECK(std::filesystem::file_size(dir.file("r.rays")) == 64);
  const auto back = read_rays(dir.file("r.rays"));
  REQUIRE(back.size() == 2);
  CHECK(std::memcmp(back.data(), rays.data(), 64) == 0);
  {  // byte layout: float ox, oy, oz, tmin, dx, dy, dz, tmax, little-endian
    std::ifstream f(dir.file("r.rays"), std::ios::binary);
    unsigned char bytes[32];
    f.read(reinterpret_cast<char*>(bytes), 32);
    float v;
    std::memcpy(&v, bytes + 8, 4);
    CHECK(v == 3.0f);
    std::memcpy(&v, bytes + 24, 4);
    CHECK(v == 1.0f);
  }
  const std::vector<Hit> hits = {{1.5f, 0.25f, 0.5f, 7}, {INFINITY, 0, 0, MBVH_MISS_PRIM}};
  write_hits(dir.file("h.hits"), hits);
  CHECK(std::filesystem::file_size(dir.file("h.hits")) == 32);
  const auto hb = read_hits(dir.file("h.hits"));
  CHECK(std::memcmp(hb.data(), hits.data(), 32) == 0);
  write_occlusion(dir.file("o.occ"), std::vector<std::uint8_t>{1, 0, 1});
  CHECK(read_occlusion(dir.file("o.occ")) == std::vector<std::uint8_t>{1, 0, 1});

  const std::string bad = dir.write("bad.rays", std::string(33, '\0'));
  CHECK_THROWS_WITH(read_rays(bad), Catch::Contains("bad.rays") && Catch::Contains("not a multiple of the 32-byte"));
  CHECK_THROWS_WITH(read_rays(dir.file("none.rays")), Catch::Contains("none.rays"));
  CHECK_THROWS_AS(write_hits(dir.file("no/such/dir/h.hits"), hits), Error);
  CHECK_FALSE(std::filesystem::exists(dir.file("no/such/dir/h.hits.partial")));
}

TEST_CASE("spawned secondary rays never re-hit their source triangle", "[rays]") {
  for (const char* spec : {"gen:soup:20000", "gen:sphere:128"}) {
    const Scene s = load_scene(spec);
    const auto acc = Accel::build(s);
    RayGenOptions o;
    o.count = 20000;
    // diffuse rays leave each hit point into the hemisphere: closest hit must not be the source
    o.kind = RayKind::diffuse;
    const auto rays = generate_rays(s, *acc, o);
    TraceOutput out;
    trace_reference(*acc, rays, TraceOptions{}, out, 0);
    std::size_t tiny = 0;
    for (const Hit& h : out.hits) tiny += h.prim != MBVH_MISS_PRIM && h.t < 1e-6f;
    INFO(spec);
    CHECK(tiny == 0);
  }
}

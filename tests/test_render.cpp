// SPDX-License-Identifier: MIT
// test_render.cpp — `mbvh render`: the same seed gives the same image on every backend (all of
// mbvh's answer bit for bit) and at any thread count; the normals are unit vectors; the PNG is
// a valid file whose pixels are the image's; bad requests are clear errors.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/error.h"
#include "host/tools/render.h"
#include "tests/backends.h"
#include "tests/helpers.h"

using namespace mbvh;

namespace {

RenderOptions small(RenderMode mode) {
  RenderOptions o;
  o.width = 40;
  o.height = 30;
  o.spp = 2;
  o.bounces = 3;
  o.mode = mode;
  o.seed = 7;
  return o;
}

std::uint32_t be32(const std::vector<std::uint8_t>& b, std::size_t at) {
  return (std::uint32_t(b[at]) << 24) | (std::uint32_t(b[at + 1]) << 16) | (std::uint32_t(b[at + 2]) << 8) | b[at + 3];
}

}  // namespace

TEST_CASE("render: the same seed gives the same image on every backend and thread count", "[render]") {
  const Scene s = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(s);
  for (RenderMode mode : {RenderMode::path, RenderMode::ao}) {
    RenderOptions o = small(mode);
    o.layout = Layout::mbvh2;  // a layout every backend traces
    o.traversal = Traversal::bitstack;
    auto ref_backend = make_backend("cpu-scalar");
    const RenderResult ref = render(s, *acc, *ref_backend, o);
    REQUIRE(ref.rgb.size() == std::size_t(40) * 30 * 3);
    CHECK(ref.rays > std::size_t(40) * 30 * 2);  // primary rays and more
    double sum = 0;
    for (float v : ref.rgb) sum += v;
    CHECK(sum > 0);  // the camera sees a lit scene
    for (const std::string& name : mbvh_test::all_backends().backends) {
      auto b = make_backend(name);
      if (b->peer()) continue;  // a peer library agrees up to ties only
      INFO(name << ", " << to_string(mode));
      const RenderResult got = render(s, *acc, *b, o);
      CHECK(got.rays == ref.rays);
      CHECK(std::memcmp(got.rgb.data(), ref.rgb.data(), ref.rgb.size() * sizeof(float)) == 0);
    }
    for (unsigned threads : {1u, 3u}) {
      RenderOptions t = o;
      t.threads = threads;
      BackendOptions bo;
      bo.threads = threads;
      auto b = make_backend("cpu-scalar", bo);
      const RenderResult got = render(s, *acc, *b, t);
      CHECK(std::memcmp(got.rgb.data(), ref.rgb.data(), ref.rgb.size() * sizeof(float)) == 0);
    }
    RenderOptions other = o;
    other.seed = 8;
    const RenderResult diff = render(s, *acc, *ref_backend, other);
    CHECK(std::memcmp(diff.rgb.data(), ref.rgb.data(), ref.rgb.size() * sizeof(float)) != 0);
  }
}

TEST_CASE("render: normals mode shows unit normals where the camera sees geometry", "[render]") {
  const Scene s = load_scene(mbvh_test::scene_path("cornell_box.obj.zst"));
  const auto acc = Accel::build(s);
  auto b = make_backend("cpu");
  RenderOptions o = small(RenderMode::normals);
  o.spp = 1;
  const RenderResult r = render(s, *acc, *b, o);
  CHECK(r.rays == std::size_t(40) * 30);  // primary rays only
  std::size_t seen = 0;
  for (std::size_t p = 0; p < r.rgb.size() / 3; ++p) {
    const float* c = &r.rgb[p * 3];
    if (c[0] == 0 && c[1] == 0 && c[2] == 0) continue;  // background
    ++seen;
    const double x = 2.0 * c[0] - 1, y = 2.0 * c[1] - 1, z = 2.0 * c[2] - 1;
    CHECK(std::fabs(std::sqrt(x * x + y * y + z * z) - 1.0) < 1e-5);
  }
  CHECK(seen > r.rgb.size() / 3 / 4);  // the box fills a good part of the default view
}

TEST_CASE("render: the PNG is valid and holds the image's pixels", "[render]") {
  mbvh_test::TempDir dir;
  const unsigned w = 300, h = 230;  // more than one 64 KiB stored block
  std::vector<float> rgb(std::size_t(w) * h * 3);
  for (std::size_t i = 0; i < rgb.size(); ++i) rgb[i] = float(i % 97) / 96.0f;
  const std::vector<std::uint8_t> px = to_srgb8(rgb);
  CHECK(px[0] == 0);
  CHECK(px[96] == 255);
  const std::string path = dir.file("x.png");
  write_png(path, w, h, px);
  std::ifstream f(path, std::ios::binary);
  const std::vector<std::uint8_t> b((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  REQUIRE(b.size() > 33);
  const std::uint8_t sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  CHECK(std::memcmp(b.data(), sig, 8) == 0);
  CHECK(be32(b, 8) == 13);
  CHECK(std::memcmp(&b[12], "IHDR", 4) == 0);
  CHECK(be32(b, 16) == w);
  CHECK(be32(b, 20) == h);
  // IDAT: a zlib stream of stored blocks; the scanlines inside are the pixels with filter 0
  const std::size_t idat = 8 + 25;
  REQUIRE(std::memcmp(&b[idat + 4], "IDAT", 4) == 0);
  const std::size_t zlen = be32(b, idat);
  std::size_t at = idat + 8 + 2;  // past the zlib header
  std::vector<std::uint8_t> raw;
  for (;;) {
    const bool last = b[at] & 1;
    const std::size_t len = b[at + 1] | (b[at + 2] << 8);
    CHECK(std::size_t((b[at + 3] | (b[at + 4] << 8)) ^ 0xFFFF) == len);
    raw.insert(raw.end(), b.begin() + static_cast<std::ptrdiff_t>(at + 5), b.begin() + static_cast<std::ptrdiff_t>(at + 5 + len));
    at += 5 + len;
    if (last) break;
  }
  CHECK(at + 4 == idat + 8 + zlen);  // the Adler-32 ends the stream
  REQUIRE(raw.size() == (std::size_t(w) * 3 + 1) * h);
  for (unsigned y = 0; y < h; ++y) {
    CHECK(raw[y * (w * 3 + 1)] == 0);
    CHECK(std::memcmp(&raw[y * (w * 3 + 1) + 1], &px[std::size_t(y) * w * 3], w * 3) == 0);
  }
  CHECK(std::memcmp(&b[b.size() - 8], "IEND", 4) == 0);
}

TEST_CASE("render: bad requests are clear errors", "[render]") {
  const Scene s = load_scene("gen:cube:4");
  const auto acc = Accel::build(s);
  auto vk = make_backend("cpu-scalar");
  RenderOptions o = small(RenderMode::path);
  o.width = 0;
  CHECK_THROWS_WITH(render(s, *acc, *vk, o), Catch::Contains("empty"));
  o = small(RenderMode::path);
  o.layout = Layout::mbvh8;
  o.traversal = Traversal::bitstack_retest;
  CHECK_THROWS_WITH(render(s, *acc, *vk, o), Catch::Contains("cpu-scalar") && Catch::Contains("mbvh8/bitstack-retest"));
  CHECK_THROWS_WITH(parse_render_mode("photon"), Catch::Contains("photon") && Catch::Contains("path, ao, normals"));
  mbvh_test::TempDir dir;
  auto r = mbvh_test::run_cli("render gen:cube:4 --width 16 --height 16 --spp 1 -o " + dir.file("ok.png"));
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("Mrays/s") && Catch::Contains("wrote"));
  CHECK(std::ifstream(dir.file("ok.png")).good());
  r = mbvh_test::run_cli("render gen:cube:4 --width 16 --height 16 --spp 1 -o " + dir.file("no/such/dir/x.png"));
  CHECK(r.code != 0);
  CHECK_THAT(r.output, Catch::Contains("no/such/dir/x.png"));
}

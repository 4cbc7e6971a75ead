// SPDX-License-Identifier: MIT
// test_render.cpp — `mbvh render`: the same seed gives the same image on every backend (all of
// mbvh's answer bit for bit) and at any thread count; the normals are unit vectors; the PNG is
// a valid file whose pixels, inflated by zlib, are the image's, and compressed; bad requests are
// clear errors.
#include <catch2/catch.hpp>
#include <zlib.h>

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

// A PNG's size and its inflated scanlines (filter byte, then the row), checked on the way:
// signature, IHDR first (8-bit RGB, no interlace), every chunk's CRC, IEND last.
struct Png {
  unsigned width = 0, height = 0;
  std::vector<std::uint8_t> raw;
};

Png decode_png(const std::vector<std::uint8_t>& b) {
  Png png;
  const std::uint8_t sig[8] = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  REQUIRE(b.size() > 33);
  REQUIRE(std::memcmp(b.data(), sig, 8) == 0);
  std::vector<std::uint8_t> z;  // the IDATs' zlib stream
  std::string last;
  for (std::size_t at = 8; at < b.size();) {
    REQUIRE(at + 12 <= b.size());
    const std::size_t len = be32(b, at);
    REQUIRE(at + 12 + len <= b.size());
    const std::string type(reinterpret_cast<const char*>(&b[at + 4]), 4);
    CHECK(be32(b, at + 8 + len) == crc32(crc32(0L, Z_NULL, 0), &b[at + 4], static_cast<uInt>(len + 4)));
    if (at == 8) {
      REQUIRE(type == "IHDR");
      REQUIRE(len == 13);
      png.width = be32(b, at + 8);
      png.height = be32(b, at + 12);
      CHECK(b[at + 16] == 8);  // bit depth
      CHECK(b[at + 17] == 2);  // RGB
      CHECK(b[at + 20] == 0);  // no interlace
    }
    if (type == "IDAT") z.insert(z.end(), b.begin() + static_cast<std::ptrdiff_t>(at + 8), b.begin() + static_cast<std::ptrdiff_t>(at + 8 + len));
    last = type;
    at += 12 + len;
  }
  CHECK(last == "IEND");
  uLongf size = static_cast<uLongf>((std::size_t(png.width) * 3 + 1) * png.height);
  png.raw.resize(size + 1);  // one spare byte: a stream holding more than the image fails below
  REQUIRE(uncompress(png.raw.data(), &size, z.data(), static_cast<uLong>(z.size())) == Z_OK);
  png.raw.resize(size);
  return png;
}

}  // namespace

TEST_CASE("render: the same seed gives the same image on every backend and thread count", "[render][isa]") {
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
      RenderOptions own = o;
      own.traversal = mbvh_test::own_traversal(*b, TraceOptions{o.layout, o.traversal}).traversal;
      const RenderResult got = render(s, *acc, *b, own);
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
  const unsigned w = 300, h = 230;  // more than one 64 KiB deflate block of pixels
  std::vector<float> rgb(std::size_t(w) * h * 3);
  for (std::size_t i = 0; i < rgb.size(); ++i) rgb[i] = float(i % 97) / 96.0f;
  const std::vector<std::uint8_t> px = to_srgb8(rgb);
  CHECK(px[0] == 0);
  CHECK(px[96] == 255);
  const std::string path = dir.file("x.png");
  write_png(path, w, h, px);
  std::ifstream f(path, std::ios::binary);
  const std::vector<std::uint8_t> b((std::istreambuf_iterator<char>(f)), std::istreambuf_iterator<char>());
  const Png png = decode_png(b);
  CHECK(png.width == w);
  CHECK(png.height == h);
  // the scanlines inside are the pixels with filter 0
  REQUIRE(png.raw.size() == (std::size_t(w) * 3 + 1) * h);
  for (unsigned y = 0; y < h; ++y) {
    CHECK(png.raw[y * (w * 3 + 1)] == 0);
    CHECK(std::memcmp(&png.raw[y * (w * 3 + 1) + 1], &px[std::size_t(y) * w * 3], w * 3) == 0);
  }
  CHECK(png_bytes("x.png", w, h, px) == b);  // the file holds exactly png_bytes
}

TEST_CASE("render: the PNG is compressed - smaller than stored blocks for a uniform image", "[render]") {
  const unsigned w = 256, h = 200;
  const std::vector<std::uint8_t> px(std::size_t(w) * h * 3, 180);
  const std::vector<std::uint8_t> b = png_bytes("u.png", w, h, px);
  const Png png = decode_png(b);
  REQUIRE(png.raw.size() == (std::size_t(w) * 3 + 1) * h);
  for (unsigned y = 0; y < h; ++y) {
    CHECK(png.raw[y * (w * 3 + 1)] == 0);
    CHECK(std::memcmp(&png.raw[y * (w * 3 + 1) + 1], &px[std::size_t(y) * w * 3], w * 3) == 0);
  }
  // the stored form: zlib header, 5 bytes per block of at most 65535, the bytes, Adler-32
  const std::size_t raw = png.raw.size(), blocks = (raw + 65534) / 65535;
  const std::size_t stored = 8 + (12 + 13) + (12 + 2 + 5 * blocks + raw + 4) + 12;
  INFO("PNG " << b.size() << " bytes, stored form " << stored);
  CHECK(b.size() < stored / 10);
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

// SPDX-License-Identifier: MIT
// test_render.cpp — `mbvh render`: the same seed gives the same image on every backend (all of
// mbvh's answer bit for bit) and at any thread count; the normals are unit vectors; the PNG is
// a valid file whose pixels, inflated by zlib, are the image's, and compressed; bad requests are
// clear errors.
#include <catch2/catch.hpp>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/error.h"
#include "mbvh/log.h"
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
      CHECK(camera_argument(got.camera) == camera_argument(ref.camera));  // the default camera: the same probes' answers
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

namespace {

// The spread of an image's pixel values (max - min over every channel).
float spread(const std::vector<float>& rgb) {
  const auto [lo, hi] = std::minmax_element(rgb.begin(), rgb.end());
  return *hi - *lo;
}

bool inside(const Box& b, const Vec3f& p) {
  return p.x > b.lo.x && p.x < b.hi.x && p.y > b.lo.y && p.y < b.hi.y && p.z > b.lo.z && p.z < b.hi.z;
}

}  // namespace

TEST_CASE("render: without a camera, an enclosed scene is framed from inside, an object from outside", "[render]") {
  auto cpu = make_backend("cpu");
  SECTION("a closed box: from inside, and the image is not one grey") {
    const Scene s = load_scene("gen:cube:4");
    const auto acc = Accel::build(s);
    const RenderResult r = render(s, *acc, *cpu, small(RenderMode::path));
    INFO(r.camera_rule);
    CHECK_THAT(r.camera_rule, Catch::StartsWith("inside") && Catch::Contains("walled on 6 of its 6 sides"));
    CHECK(inside(acc->bounds(), r.camera.eye));
    CHECK(spread(r.rgb) > 0.1f);
    // every primary ray of an inside view hits a wall: the normals image has no black (sky) pixel
    const RenderResult n = render(s, *acc, *cpu, small(RenderMode::normals));
    for (std::size_t p = 0; p < n.rgb.size(); p += 3) CHECK(n.rgb[p] + n.rgb[p + 1] + n.rgb[p + 2] > 0);
  }
  SECTION("an open box (a Cornell box without its front): from inside, looking in through the opening") {
    // gen:cube's walls with the +z side cut away: the triangles whose vertices all have z = max
    Scene s = load_scene("gen:cube:4");
    const Box b = s.bounds();
    std::erase_if(s.triangles, [&](const auto& t) {
      return s.vertices[t[0]].z == b.hi.z && s.vertices[t[1]].z == b.hi.z && s.vertices[t[2]].z == b.hi.z;
    });
    const auto acc = Accel::build(s);
    const RenderResult r = render(s, *acc, *cpu, small(RenderMode::path));
    INFO(r.camera_rule);
    CHECK_THAT(r.camera_rule, Catch::StartsWith("inside") && Catch::Contains("open: +z") && Catch::Contains("through its open +z side"));
    CHECK(r.camera.eye.z == b.hi.z);  // in the opening
    CHECK(r.camera.target.z == b.lo.z);  // looking at the back wall
    CHECK((r.camera.eye.x == r.camera.target.x && r.camera.eye.y == r.camera.target.y));
  }
  SECTION("single objects: from outside, default_camera as before") {
    for (const std::string& spec : {std::string("gen:sphere:32"), std::string("gen:torus:32"), mbvh_test::scene_path("bun_zipper.ply.zst")}) {
      const Scene s = load_scene(spec);
      const auto acc = Accel::build(s);
      const RenderResult r = render(s, *acc, *cpu, small(RenderMode::normals));
      INFO(spec << ": " << r.camera_rule);
      CHECK_THAT(r.camera_rule, Catch::StartsWith("outside"));
      CHECK(camera_argument(r.camera) == camera_argument(default_camera(acc->bounds())));
    }
  }
  SECTION("the program says which camera it chose, and that --camera renders the same image") {
    mbvh_test::TempDir dir;
    auto r = mbvh_test::run_cli("render gen:cube:4 --width 24 --height 16 --spp 1 -o " + dir.file("a.png"));
    INFO(r.output);
    REQUIRE(r.code == 0);
    const std::size_t at = r.output.find("--camera ");
    REQUIRE(at != std::string::npos);
    CHECK_THAT(r.output, Catch::Contains("camera: inside"));
    const std::string camera = r.output.substr(at + 9, r.output.find('\n', at) - at - 9);
    auto again = mbvh_test::run_cli("render gen:cube:4 --width 24 --height 16 --spp 1 --camera " + camera + " -o " + dir.file("b.png"));
    INFO(again.output);
    REQUIRE(again.code == 0);
    CHECK_THAT(again.output, !Catch::Contains("camera: "));
    std::ifstream a(dir.file("a.png"), std::ios::binary), b(dir.file("b.png"), std::ios::binary);
    CHECK(std::string(std::istreambuf_iterator<char>(a), {}) == std::string(std::istreambuf_iterator<char>(b), {}));
  }
}

TEST_CASE("render: the MTL's diffuse colours are the surfaces' albedos; a missing MTL still renders", "[render]") {
  // two unit quads side by side in z = 0, red on the left, blue on the right, seen head-on
  mbvh_test::TempDir dir;
  dir.write("two.mtl", "newmtl red\nKd 0.9 0.1 0.1\nnewmtl blue\nKd 0.1 0.2 0.8\n");
  // (a speck behind the camera gives the box depth: the point light, near the box's top centre, in front of the quads)
  const std::string quads = "v -1 -1 0\nv 0 -1 0\nv 0 1 0\nv -1 1 0\nv 1 -1 0\nv 1 1 0\nv 0 0 2\nv 0.01 0 2\nv 0 0.01 2\n"
                            "usemtl red\nf 1 2 3 4\nusemtl blue\nf 2 5 6 3\nf 7 8 9\n";
  RenderOptions o = small(RenderMode::path);
  o.bounces = 0;  // direct light only: a pixel is albedo x (light x cosine / distance^2), per channel
  o.has_camera = true;
  o.camera.eye = {0, 0, 1.2f};
  o.camera.target = {0, 0, 0};
  auto cpu = make_backend("cpu");
  const Scene s = load_scene(dir.write("two.obj", "mtllib two.mtl\n" + quads));
  const auto acc = Accel::build(s);
  const RenderResult r = render(s, *acc, *cpu, o);
  const auto px = [&](unsigned x, unsigned y) { return &r.rgb[(std::size_t(y) * r.width + x) * 3]; };
  const float* left = px(8, 15);
  const float* right = px(31, 15);
  INFO(left[0] << " " << left[1] << " " << left[2] << " / " << right[0] << " " << right[1] << " " << right[2]);
  REQUIRE(left[0] > 0.05f);
  REQUIRE(right[2] > 0.05f);
  CHECK(left[0] / left[1] == Approx(9.0f).epsilon(1e-4));
  CHECK(left[1] == Approx(left[2]).epsilon(1e-5));
  CHECK(right[2] / right[0] == Approx(8.0f).epsilon(1e-4));
  CHECK(right[1] / right[0] == Approx(2.0f).epsilon(1e-4));
  // without the MTL: a warning, and the same surfaces in the renderer's grey
  std::vector<std::string> log;
  const LogCallback before = set_log_callback([&log](LogLevel, const std::string& m) { log.push_back(m); });
  const Scene g = load_scene(dir.write("grey.obj", "mtllib missing.mtl\n" + quads));
  set_log_callback(before);
  REQUIRE(log.size() == 1);
  CHECK_THAT(log[0], Catch::Contains("missing.mtl"));
  const auto gacc = Accel::build(g);
  const RenderResult gr = render(g, *gacc, *cpu, o);
  const float* grey = &gr.rgb[(std::size_t(15) * gr.width + 8) * 3];
  CHECK((grey[0] > 0.05f && grey[0] == grey[1] && grey[1] == grey[2]));
  CHECK(grey[0] / left[0] == Approx(0.7f / 0.9f).epsilon(1e-4));
  // the program: the warning on standard error, the image written
  auto run = mbvh_test::run_cli("render " + dir.file("grey.obj") + " --width 16 --height 16 --spp 1 -o " + dir.file("g.png"));
  INFO(run.output);
  CHECK(run.code == 0);
  CHECK_THAT(run.output, Catch::Contains("'missing.mtl' not found") && Catch::Contains("wrote"));
}

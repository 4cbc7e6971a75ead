// test_loaders.cpp — OBJ, PLY, zstd and generated scenes: good files load exactly, malformed
// files give an error naming the file, the line and what was wrong.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <map>

#include "host/error.h"
#include "host/scene.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::TempDir;

namespace {

Scene obj(const std::string& text) { return parse_obj("t.obj", text.data(), text.size()); }
Scene ply(const std::string& text) { return parse_ply("t.ply", text.data(), text.size()); }

template <class F>
std::string error_of(F f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

std::string le32f(float f) { std::string s(4, '\0'); std::memcpy(s.data(), &f, 4); return s; }
std::string le64d(double d) { std::string s(8, '\0'); std::memcpy(s.data(), &d, 8); return s; }
std::string le32i(std::int32_t i) { std::string s(4, '\0'); std::memcpy(s.data(), &i, 4); return s; }
std::string be32f(float f) { std::string s = le32f(f); return std::string(s.rbegin(), s.rend()); }
std::string be32i(std::int32_t i) { std::string s = le32i(i); return std::string(s.rbegin(), s.rend()); }

}  // namespace

TEST_CASE("OBJ: every face form negative indices fan triangulation ignored statements", "[loader][obj]") {
  const Scene s = obj(
      "# comment\nmtllib x.mtl\no thing\ng group\nusemtl red\ns 1\n"
      "v 0 0 0\nv 1 0 0\r\nv 1 1 0\nv 0 1 0\nv 1e-006 2.5E+01 -3e0\n"
      "vt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\n"
      "f 1 2 3\n"
      "f 1/1 2/2 3/3\n"
      "f 1//1 2//1 3//1\n"
      "f 1/1/1 2/2/1 3/3/1  # trailing comment\n"
      "f -5 -4 -3\n"
      "f 1 2 3 4\n"
      "f 1 2 3 4 5\n");
  REQUIRE(s.vertices.size() == 5);
  CHECK(s.vertices[4].x == 1e-6f);
  CHECK(s.vertices[4].y == 25.0f);
  CHECK(s.vertices[4].z == -3.0f);
  REQUIRE(s.triangles.size() == 5 + 2 + 3);
  for (int i = 0; i < 5; ++i) CHECK(s.triangles[static_cast<std::size_t>(i)] == std::array<std::uint32_t, 3>{0, 1, 2});
  CHECK(s.triangles[5] == std::array<std::uint32_t, 3>{0, 1, 2});  // quad: (0,1,2), (0,2,3)
  CHECK(s.triangles[6] == std::array<std::uint32_t, 3>{0, 2, 3});
  CHECK(s.triangles[9] == std::array<std::uint32_t, 3>{0, 3, 4});
}

TEST_CASE("OBJ: malformed input names file line and problem", "[loader][obj]") {
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 0\n"); }), Catch::Contains("t.obj:4:") && Catch::Contains("index 0"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n"); }), Catch::Contains("t.obj:4:") && Catch::Contains("out of range"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nf -1 -2 -3\n"); }), Catch::Contains("t.obj:3:") && Catch::Contains("out of range"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nf 1 2\n"); }), Catch::Contains("t.obj:3:") && Catch::Contains("2 vertices"));
  CHECK_THAT(error_of([] { obj("v 0 nan 0\n"); }), Catch::Contains("t.obj:1:") && Catch::Contains("NaN"));
  CHECK_THAT(error_of([] { obj("\nv 0 0 inf\n"); }), Catch::Contains("t.obj:2:") && Catch::Contains("infinite"));
  CHECK_THAT(error_of([] { obj("v 0 1.2.3 0\n"); }), Catch::Contains("t.obj:1:") && Catch::Contains("bad number"));
  CHECK_THAT(error_of([] { obj("v 0 0\n"); }), Catch::Contains("t.obj:1:") && Catch::Contains("fewer than 3"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 x 3\n"); }), Catch::Contains("t.obj:4:") && Catch::Contains("bad vertex index"));
  CHECK_THAT(error_of([] { obj("v 0 0 1e39\n"); }), Catch::Contains("t.obj:1:"));
}

TEST_CASE("PLY: ascii with extra properties and polygon faces", "[loader][ply]") {
  const Scene s = ply(
      "ply\nformat ascii 1.0\ncomment made by hand\nelement vertex 4\nproperty float x\nproperty float y\n"
      "property float z\nproperty float confidence\nproperty float intensity\nelement face 2\n"
      "property list uchar int vertex_indices\nend_header\n"
      "0 0 0 1 0.5\n1 0 0 1 0.5\n1 1 0 1 0.5\n0 1 1e-05 1 0.5\n3 0 1 2\n4 0 1 2 3\n");
  REQUIRE(s.vertices.size() == 4);
  CHECK(s.vertices[3].z == 1e-5f);
  REQUIRE(s.triangles.size() == 3);
  CHECK(s.triangles[2] == std::array<std::uint32_t, 3>{0, 2, 3});
}

TEST_CASE("PLY: binary little- and big-endian double coordinates other elements", "[loader][ply]") {
  std::string le = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty double x\nproperty double y\n"
                   "property double z\nproperty uchar red\nelement face 1\nproperty list uchar int vertex_indices\n"
                   "element extra 1\nproperty int whatever\nend_header\n";
  for (int i = 0; i < 3; ++i) le += le64d(i) + le64d(i == 1 ? 1 : 0) + le64d(i == 2 ? 1 : 0) + std::string(1, '\x7f');
  le += std::string(1, '\x03') + le32i(0) + le32i(1) + le32i(2) + le32i(42);
  const Scene a = ply(le);
  REQUIRE(a.triangles.size() == 1);
  CHECK(a.vertices[1].x == 1.0f);
  CHECK(a.vertices[2].z == 1.0f);

  std::string be = "ply\nformat binary_big_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                   "property float z\nelement face 1\nproperty list uchar uint vertex_index\nend_header\n";
  for (int i = 0; i < 3; ++i) be += be32f(static_cast<float>(i)) + be32f(0.5f) + be32f(-2.0f);
  be += std::string(1, '\x03') + be32i(2) + be32i(1) + be32i(0);
  const Scene b = ply(be);
  REQUIRE(b.triangles.size() == 1);
  CHECK(b.triangles[0] == std::array<std::uint32_t, 3>{2, 1, 0});
  CHECK(b.vertices[2].x == 2.0f);
  CHECK(b.vertices[0].z == -2.0f);
}

TEST_CASE("PLY: malformed input names file line and problem", "[loader][ply]") {
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                           "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  CHECK_THAT(error_of([&] { ply(head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"); }), Catch::Contains("t.ply:13:") && Catch::Contains("out of range"));
  CHECK_THAT(error_of([&] { ply(head + "0 0 0\n1 0 0\n0 1 0\n2 0 1\n"); }), Catch::Contains("t.ply:13:") && Catch::Contains("2 vertices"));
  CHECK_THAT(error_of([&] { ply(head + "0 0 0\n1 0 0\n"); }), Catch::Contains("truncated"));
  CHECK_THAT(error_of([&] { ply(head + "0 0 0\n1 nan 0\n0 1 0\n3 0 1 2\n"); }), Catch::Contains("t.ply:11:") && Catch::Contains("NaN"));
  CHECK_THAT(error_of([&] { ply("ply\nformat binary_middle_endian 1.0\nend_header\n"); }), Catch::Contains("t.ply:2:") && Catch::Contains("unknown PLY format"));
  CHECK_THAT(error_of([&] { ply("PLY?\n"); }), Catch::Contains("not a PLY file"));
  CHECK_THAT(error_of([&] { ply("ply\nformat ascii 1.0\nelement vertex 1\n"); }), Catch::Contains("no end_header"));
  // a header that claims more than the file can hold is refused before allocating
  std::string huge = "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n"
                     "property float z\nend_header\n" + le32f(0) + le32f(0) + le32f(0);
  CHECK_THAT(error_of([&] { ply(huge); }), Catch::Contains("t.ply:3:") && Catch::Contains("4000000000"));
  std::string trunc = "ply\nformat binary_little_endian 1.0\nelement vertex 2\nproperty float x\nproperty float y\n"
                      "property float z\nend_header\n" + le32f(0) + le32f(0) + le32f(0) + le32f(1) + le32f(1);
  CHECK_THAT(error_of([&] { ply(trunc); }), Catch::Contains("truncated"));
  std::string nan = "ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n" + le32f(0) + le32f(NAN) + le32f(0);
  CHECK_THAT(error_of([&] { ply(nan); }), Catch::Contains("vertex 0") && Catch::Contains("NaN"));
}

TEST_CASE("zstd files load directly - a truncated one is an error", "[loader][zstd]") {
  // counts and boxes from ../shared/scenes/README.md
  struct Expect { const char* file; std::size_t vertices, triangles; float lo[3], hi[3]; };
  const Expect all[] = {
      {"cornell_box.obj.zst", 72, 36, {-1.02f, 0, -1.04f}, {1, 1.99f, 0.99f}},
      {"cornell_box_original_data.obj.zst", 76, 34, {0, 0, 0}, {556, 548.8f, 559.2f}},
      {"sibenik.obj.zst", 40981, 75284, {-20.1411f, -15.3123f, -8.4968f}, {20.1411f, 15.3f, 8.4968f}},
      {"sponza_dabrovic.obj.zst", 39999, 66454, {-17.40276f, -0.906689f, -7.798512f}, {17.41724f, 15.653312f, 7.801489f}},
      {"bun_zipper.ply.zst", 35947, 69451, {-0.0946899f, 0.0329874f, -0.0618736f}, {0.0610091f, 0.187321f, 0.0587997f}},
      {"conference.obj.zst", 194399, 331179, {-1020.13f, -2.7924f, -1055.66f}, {1685.81f, 650.293f, 668.489f}},
  };
  for (const Expect& e : all) {
    INFO(e.file);
    const Scene s = load_scene(mbvh_test::scene_path(e.file));
    CHECK(s.vertices.size() == e.vertices);
    CHECK(s.triangles.size() == e.triangles);
    Box b;
    for (const auto& v : s.vertices) b.grow(v);
    for (int a = 0; a < 3; ++a) {
      CHECK(b.lo[a] == e.lo[a]);
      CHECK(b.hi[a] == e.hi[a]);
    }
  }
  TempDir dir;
  const std::vector<char> whole = [] {
    FILE* f = std::fopen(mbvh_test::scene_path("sibenik.obj.zst").c_str(), "rb");
    std::vector<char> d(1 << 20);
    d.resize(std::fread(d.data(), 1, d.size(), f));
    std::fclose(f);
    return d;
  }();
  const std::string cut = dir.write("cut.obj.zst", std::string(whole.data(), whole.size() / 2));
  CHECK_THAT(error_of([&] { load_scene(cut); }), Catch::Contains("cut.obj.zst") && Catch::Contains("truncated zstd"));
  CHECK_THAT(error_of([&] { load_scene(dir.file("missing.obj")); }), Catch::Contains("missing.obj") && Catch::Contains("cannot open"));
  const std::string unknown = dir.write("x.stl", "solid x\n");
  CHECK_THAT(error_of([&] { load_scene(unknown); }), Catch::Contains("unknown scene format"));
}

TEST_CASE("fuzzer-found inputs are clean errors (regressions)", "[loader][fuzz]") {
  // zstd frames whose headers claim a huge content size: once a 16 GiB reserve (out of memory)
  const unsigned char huge1[] = {0x28, 0xb5, 0x2f, 0xfd, 0xb5, 0xfd, 0x89, 0x28, 0x2f, 0x89};
  const unsigned char huge2[] = {0x28, 0xb5, 0x2f, 0xfd, 0x90, 0x93, 0x86, 0x8f, 0x93, 0x86, 0xf5, 0x88, 0x1a, 0x6d};
  for (const auto& bytes : {std::vector<char>(huge1, huge1 + sizeof huge1), std::vector<char>(huge2, huge2 + sizeof huge2)}) {
    CHECK_THROWS_WITH(maybe_decompress("bomb.obj.zst", bytes), Catch::Contains("bomb.obj.zst") && Catch::Contains("zstd"));
  }
}

TEST_CASE("generated scenes: closed sphere and cube exact counts clear errors", "[loader][gen]") {
  for (const char* spec : {"gen:sphere:48", "gen:cube:8"}) {
    INFO(spec);
    const Scene s = load_scene(spec);
    // closed: every undirected edge is shared by exactly two triangles (by position for the cube)
    std::map<std::pair<std::array<float, 3>, std::array<float, 3>>, int> edges;
    auto key = [&](std::uint32_t i) { const Vec3f v = s.vertices[i]; return std::array<float, 3>{v.x, v.y, v.z}; };
    for (const auto& t : s.triangles)
      for (int k = 0; k < 3; ++k) {
        auto a = key(t[static_cast<std::size_t>(k)]), b = key(t[static_cast<std::size_t>((k + 1) % 3)]);
        if (b < a) std::swap(a, b);
        ++edges[{a, b}];
      }
    for (const auto& e : edges) REQUIRE(e.second == 2);
  }
  CHECK(load_scene("gen:sphere:48").triangles.size() == 48 * 2 * (24 - 1));
  CHECK(load_scene("gen:soup:1234:9").triangles.size() == 1234);
  CHECK(load_scene("gen:hairball:100001").triangles.size() == 100001);
  CHECK(load_scene("gen:soup:500:3").vertices[7].x == load_scene("gen:soup:500:3").vertices[7].x);
  CHECK(load_scene("gen:soup:500:3").vertices[7].x != load_scene("gen:soup:500:4").vertices[7].x);
  CHECK_THAT(error_of([] { load_scene("gen:teapot:3"); }), Catch::Contains("unknown generator 'teapot'"));
  CHECK_THAT(error_of([] { load_scene("gen:sphere:abc"); }), Catch::Contains("'abc'"));
  CHECK_THAT(error_of([] { load_scene("gen:sphere:1"); }), Catch::Contains("must be an integer in"));
}

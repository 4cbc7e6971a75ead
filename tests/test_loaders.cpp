// SPDX-License-Identifier: MIT
// test_loaders.cpp — OBJ, PLY, zstd and generated scenes: good files load exactly, malformed
// files give an error naming the file, the line and what was wrong.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <map>

#include <sys/stat.h>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/error.h"
#include "mbvh/log.h"
#include "host/tools/render.h"
#include "host/core/resources.h"
#include "mbvh/scene.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::error_of;
using mbvh_test::TempDir;

namespace {

Scene obj(const std::string& text) { return parse_obj("t.obj", text.data(), text.size()); }
Scene ply(const std::string& text) { return parse_ply("t.ply", text.data(), text.size()); }


std::string le32f(float f) { std::string s(4, '\0'); std::memcpy(s.data(), &f, 4); return s; }
std::string le64d(double d) { std::string s(8, '\0'); std::memcpy(s.data(), &d, 8); return s; }
std::string le32i(std::int32_t i) { std::string s(4, '\0'); std::memcpy(s.data(), &i, 4); return s; }
std::string be32f(float f) { std::string s = le32f(f); return std::string(s.rbegin(), s.rend()); }
std::string be32i(std::int32_t i) { std::string s = le32i(i); return std::string(s.rbegin(), s.rend()); }

// Sets MBVH_MEMORY_LIMIT for one scope.
struct MemoryLimit {
  explicit MemoryLimit(const char* value) { setenv("MBVH_MEMORY_LIMIT", value, 1); }
  ~MemoryLimit() { unsetenv("MBVH_MEMORY_LIMIT"); }
};

// A zstd frame of `blocks` RLE blocks of 128 KiB zero bytes (4 bytes each): a decompression bomb.
// With `state_size` the frame header states its content size, else the size is unknown.
std::vector<char> zstd_zeros(std::size_t blocks, bool state_size) {
  std::string f = "\x28\xb5\x2f\xfd";
  f += state_size ? '\xC0' : '\x00';  // frame header: an 8-byte content size, or none
  f += '\x38';                         // window 2^17 = 128 KiB
  const std::uint64_t content = std::uint64_t(blocks) << 17;
  if (state_size) f += std::string(reinterpret_cast<const char*>(&content), 8);
  for (std::size_t b = 0; b < blocks; ++b) {
    const std::uint32_t header = (131072u << 3) | (1u << 1) | (b + 1 == blocks ? 1u : 0u);  // size, RLE, last
    f += std::string(reinterpret_cast<const char*>(&header), 3) + '\0';
  }
  return std::vector<char>(f.begin(), f.end());
}

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

TEST_CASE("OBJ: a byte-order mark CRLF vertex w and colours read exactly - bare v or f extra values binary data and "
          "unknown statements name the line",
          "[loader][obj][reliability]") {
  // a UTF-8 byte-order mark once dropped the first vertex and shifted every index
  const std::string lf = "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 2 3 4\n";
  const Scene bom = obj("\xEF\xBB\xBF" + lf);
  REQUIRE(bom.vertices.size() == 4);
  CHECK(bom.vertices[0].x == 0.0f);
  CHECK(bom.vertices[1].x == 1.0f);
  CHECK(bom.vertices[3].z == 1.0f);
  REQUIRE(bom.triangles.size() == 2);
  CHECK(bom.triangles[1] == std::array<std::uint32_t, 3>{1, 2, 3});
  std::string crlf;
  for (char c : "\xEF\xBB\xBF" + lf) crlf += c == '\n' ? std::string("\r\n") : std::string(1, c);
  const Scene dos = obj(crlf);
  CHECK(dos.vertices.size() == 4);
  CHECK(dos.triangles == bom.triangles);
  // x y z w and x y z r g b: w and the colours are read past, not taken for the next vertex
  const Scene extra = obj("v 0 0 0 1\nv 1 0 0 0.5 0.25 1\r\nv 0 1 0 # w-less\nf 1 2 3\n");
  REQUIRE(extra.vertices.size() == 3);
  CHECK(extra.vertices[1].x == 1.0f);
  CHECK(extra.vertices[1].y == 0.0f);

  CHECK_THAT(error_of([] { obj("v 0 0 0\nv\n"); }), Catch::Contains("t.obj:2:") && Catch::Contains("fewer than 3"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nv"); }), Catch::Contains("t.obj:4:") && Catch::Contains("fewer than 3"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf\n"); }), Catch::Contains("t.obj:4:") && Catch::Contains("0 vertices"));
  CHECK_THAT(error_of([] { obj("v 0 0 0 1 1\n"); }), Catch::Contains("t.obj:1:") && Catch::Contains("5 values"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 0 0 0 1 1 1 1\n"); }), Catch::Contains("t.obj:2:") && Catch::Contains("7 values"));
  CHECK_THAT(error_of([] { obj("v 0 0 0 w\n"); }), Catch::Contains("t.obj:1:") && Catch::Contains("bad number 'w'"));
  // classic Mac line ends (CR only) made the whole file one vertex line
  CHECK_THAT(error_of([] { obj("v 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r"); }), Catch::Contains("t.obj:1:") && Catch::Contains("carriage return"));
  CHECK_THAT(error_of([] { obj("# Mac\rv 0 0 0\rv 1 0 0\rv 0 1 0\rf 1 2 3\r"); }), Catch::Contains("t.obj:1:") && Catch::Contains("carriage return"));
  // a missing space is not an unknown statement to skip
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv1 0 0\n"); }), Catch::Contains("t.obj:2:") && Catch::Contains("unknown statement 'v1'"));
  CHECK_THAT(error_of([] { obj("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nhello world\n"); }),
             Catch::Contains("t.obj:5:") && Catch::Contains("unknown statement 'hello'"));
  // binary data is an error, not "0 triangles"
  CHECK_THAT(error_of([] { obj(std::string("v 0 0 0\nv 1 0 0\n\x01\x02\0\0\xff", 21)); }), Catch::Contains("t.obj:3:") && Catch::Contains("NUL byte"));
  CHECK_THAT(error_of([] { obj(std::string("\xFF\xFEv\0 \0" "0\0", 8)); }), Catch::Contains("t.obj:1:") && Catch::Contains("UTF-16"));
  CHECK_THAT(error_of([] { obj("\x89PNG\r\n\x1a\n"); }), Catch::Contains("t.obj:1:"));
}

TEST_CASE("PLY: a byte-order mark and CRLF are read - extra header words extra values and trailing data name the line",
          "[loader][ply][reliability]") {
  const std::string head = "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                           "element face 1\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  std::string dos;
  for (char c : "\xEF\xBB\xBF" + head + body) dos += c == '\n' ? std::string("\r\n") : std::string(1, c);
  const Scene s = ply(dos);
  REQUIRE(s.vertices.size() == 3);
  CHECK(s.vertices[1].x == 1.0f);
  CHECK(s.triangles.size() == 1);
  CHECK(ply(head + body + "\n\n").triangles.size() == 1);  // blank lines at the end are fine

  auto with = [&](const std::string& from, const std::string& to) {
    std::string h = head;
    h.replace(h.find(from), from.size(), to);
    return h;
  };
  CHECK_THAT(error_of([&] { ply(with("element vertex 3", "element vertex 3 4") + body); }), Catch::Contains("t.ply:3:") && Catch::Contains("unexpected '4'"));
  CHECK_THAT(error_of([&] { ply(with("property float y", "property float y z") + body); }), Catch::Contains("t.ply:5:") && Catch::Contains("unexpected 'z'"));
  CHECK_THAT(error_of([&] { ply(with("format ascii 1.0", "format ascii 1.0 x") + body); }), Catch::Contains("t.ply:2:") && Catch::Contains("unexpected 'x'"));
  CHECK_THAT(error_of([&] { ply(with("end_header", "end_header now") + body); }), Catch::Contains("t.ply:9:") && Catch::Contains("unexpected 'now'"));
  // a value more than the header declares once shifted nothing only by luck: refused
  CHECK_THAT(error_of([&] { ply(head + "0 0 0 7\n1 0 0\n0 1 0\n3 0 1 2\n"); }),
             Catch::Contains("t.ply:10:") && Catch::Contains("vertex 0: extra value '7'"));
  CHECK_THAT(error_of([&] { ply(head + "0 0 0\n1 0 0\n0 1 0\n3 0 1 2 1\n"); }), Catch::Contains("t.ply:13:") && Catch::Contains("face 0: extra value '1'"));
  CHECK_THAT(error_of([&] { ply(head + body + "\n0 0 1\n"); }), Catch::Contains("t.ply:15:") && Catch::Contains("after the last element"));
  std::string bin = "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                    "property float z\nend_header\n";
  for (int i = 0; i < 9; ++i) bin += le32f(static_cast<float>(i));
  CHECK(ply(bin).vertices.size() == 3);
  CHECK_THAT(error_of([&] { ply(bin + le32f(9)); }), Catch::Contains("t.ply: 4 bytes of data after the last element"));
}

TEST_CASE("bounded resources: zstd bombs generated scenes and PFM headers are refused before allocating - inputs that "
          "are not regular files are refused unopened",
          "[loader][resources][reliability]") {
  // -- zstd: a stated content size is checked first; an unstated one is capped while streaming
  {
    MemoryLimit limit("4M");
    const std::vector<char> small = maybe_decompress("ok.obj.zst", zstd_zeros(8, true));  // the crafted frames are valid
    CHECK(small.size() == 8u << 17);
    CHECK(maybe_decompress("ok.obj.zst", zstd_zeros(8, false)).size() == 8u << 17);
    CHECK_THAT(error_of([] { maybe_decompress("bomb.obj.zst", zstd_zeros(256, true)); }),
               Catch::Contains("bomb.obj.zst: needs about 32 MiB") && Catch::Contains("header states") &&
                   Catch::Contains("4.0 MiB available (MBVH_MEMORY_LIMIT)"));
    CHECK_THAT(error_of([] { maybe_decompress("bomb.obj.zst", zstd_zeros(256, false)); }),
               Catch::Contains("bomb.obj.zst: needs about") && Catch::Contains("stream goes on") &&
                   Catch::Contains("MBVH_MEMORY_LIMIT"));
  }
  // -- generated scenes: estimated from their parameters before generating
  CHECK(scene_memory_estimate(400'000'000, 212'500'000) > 60ull << 30);  // about 70 GB
  CHECK(scene_memory_estimate(400'000'000, 212'500'000) < 80ull << 30);
  {
    MemoryLimit limit("64G");
    CHECK_THAT(error_of([] { load_scene("gen:hairball:400000000"); }),
               Catch::Contains("gen:hairball:400000000: needs about 6") && Catch::Contains("400000000 triangles") &&
                   Catch::Contains("64 GiB available (MBVH_MEMORY_LIMIT)"));
  }
  {
    MemoryLimit limit("1M");
    CHECK_THAT(error_of([] { load_scene("gen:soup:100000@scale=2"); }), Catch::Contains("gen:soup:100000: needs about"));
    CHECK_THAT(error_of([] { load_scene("gen:grid:100"); }), Catch::Contains("gen:grid:100: needs about"));
    CHECK(load_scene("gen:cube:2").triangles.size() == 48);  // 48 triangles fit in 1 MiB
  }
  {
    MemoryLimit limit("lots");
    CHECK_THAT(error_of([] { load_scene("gen:cube:2"); }), Catch::Contains("MBVH_MEMORY_LIMIT=lots is not a size"));
  }
  // -- files: checked against the budget by size, and by the build a parsed scene will need
  TempDir dir;
  const std::string cube = dir.write("cube.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  {
    MemoryLimit limit("16");
    CHECK_THAT(error_of([&] { load_scene(cube); }), Catch::Contains("cube.obj: needs about 60 bytes") && Catch::Contains("to hold the 3 vertices and 1 triangles"));
  }
  {
    MemoryLimit limit("100");
    CHECK_THAT(error_of([&] { load_scene(cube); }), Catch::Contains("cube.obj: needs about 296 bytes") && Catch::Contains("to build its 1 triangles"));
  }
  // -- PFM: a 20-byte header once allocated width x height x 12 bytes before reading a pixel
  const std::string pfm = dir.write("big.pfm", "PF\n4096 4096\n-1.0\n");
  unsigned w = 0, h = 0;
  CHECK_THAT(error_of([&] { read_pfm(pfm, w, h); }), Catch::Contains("big.pfm: the PFM header says 4096x4096") &&
                                                        Catch::Contains("holds 0 bytes"));
  const std::string good = dir.file("good.pfm");
  write_pfm(good, 2, 1, {1, 2, 3, 4, 5, 6});
  CHECK(read_pfm(good, w, h) == std::vector<float>{1, 2, 3, 4, 5, 6});
  std::ofstream(good, std::ios::app) << "x";
  CHECK_THAT(error_of([&] { read_pfm(good, w, h); }), Catch::Contains("holds 25 bytes"));
  // -- not regular files: refused by stat before open (a FIFO blocks open until a writer comes)
  CHECK_THAT(error_of([&] { load_scene(dir.path.string()); }), Catch::Contains("is a directory, not a regular input file"));
  // /dev/null only as an input: a scene from /dev/zero read without end before the fix
  CHECK_THAT(error_of([] { load_scene("/dev/null"); }), Catch::Contains("/dev/null: is a character device"));
  CHECK_THAT(error_of([] { read_rays("/dev/zero"); }), Catch::Contains("/dev/zero: is a character device, not a regular ray file"));
  const std::string fifo = dir.file("pipe.ply");
  REQUIRE(mkfifo(fifo.c_str(), 0600) == 0);
  CHECK_THAT(error_of([&] { load_scene(fifo); }), Catch::Contains("pipe.ply: is a FIFO"));
  CHECK_THAT(error_of([&] { read_pfm(fifo, w, h); }), Catch::Contains("pipe.ply: is a FIFO"));
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

namespace {

// A zstd frame holding `content` (at most 255 bytes) in one raw block.
std::string zstd_raw(const std::string& content) {
  REQUIRE(content.size() <= 255);
  std::string f = "\x28\xb5\x2f\xfd";
  f += '\x20';                                    // single segment, a 1-byte content size
  f += static_cast<char>(content.size());
  const std::uint32_t header = (static_cast<std::uint32_t>(content.size()) << 3) | 1u;  // size, raw, last
  return f + std::string(reinterpret_cast<const char*>(&header), 3) + content;
}

// Collects the library's log messages for one scope.
struct LogCapture {
  std::vector<std::string> lines;
  LogCallback before;
  LogCapture() : before(set_log_callback([this](LogLevel, const std::string& m) { lines.push_back(m); })) {}
  ~LogCapture() { set_log_callback(before); }
  std::string all() const {
    std::string s;
    for (const auto& l : lines) s += l + "\n";
    return s;
  }
};

}  // namespace

TEST_CASE("OBJ: usemtl gives triangles materials, mtllib's Kd their colours; missing or bad MTLs warn", "[loader][obj]") {
  TempDir dir;
  const std::string faces = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3\nusemtl red\nf 1 2 3 4\nusemtl  blue green \nf 1 3 4\nusemtl red\nf 2 3 4\n";
  SECTION("in-memory parse: names, per-triangle indices, grey, no file read") {
    const Scene s = obj("mtllib nowhere.mtl\n" + faces);
    REQUIRE(s.materials.size() == 2);
    CHECK(s.materials[0].name == "red");
    CHECK(s.materials[1].name == "blue green");
    CHECK(s.materials[1].diffuse.x == 0.7f);
    CHECK(s.triangle_materials == std::vector<std::uint32_t>{kNoMaterial, 0, 0, 1, 0});
    CHECK(obj("v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3\n").triangle_materials.empty());
  }
  SECTION("the MTL beside the OBJ, the OBJ plain and zstd-compressed, the MTL compressed too") {
    dir.write("m.mtl", "# colours\nnewmtl red\nKa 0 0 0\nKd 0.9 0.1 0.2\r\nnewmtl blue green\nKd 0.25\nnewmtl unused\nKd 1 1 1\n");
    for (const std::string& name : {std::string("a.obj"), std::string("a.obj.zst")}) {
      const std::string text = "mtllib m.mtl\n" + faces;
      LogCapture log;
      const Scene s = load_scene(dir.write(name, name == "a.obj" ? text : zstd_raw(text)));
      INFO(name << "\n" << log.all());
      CHECK(log.lines.empty());
      REQUIRE(s.materials.size() == 2);
      CHECK((s.materials[0].diffuse.x == 0.9f && s.materials[0].diffuse.y == 0.1f && s.materials[0].diffuse.z == 0.2f));
      CHECK((s.materials[1].diffuse.x == 0.25f && s.materials[1].diffuse.z == 0.25f));  // one value: grey
    }
    dir.write("z.mtl.zst", zstd_raw("newmtl red\nKd 0 0 1\n"));
    LogCapture log;
    const Scene s = load_scene(dir.write("z.obj", "mtllib z.mtl\n" + faces));
    CHECK(s.materials[0].diffuse.z == 1.0f);
    CHECK_THAT(log.all(), Catch::Contains("1 of 2 materials are in no material library") && Catch::Contains("'blue green'"));
  }
  SECTION("a missing MTL, a bad Kd and no mtllib warn, and the scene still loads grey") {
    LogCapture log;
    const Scene s = load_scene(dir.write("b.obj", "mtllib nowhere.mtl\n" + faces));
    REQUIRE(log.lines.size() == 1);
    CHECK_THAT(log.lines[0], Catch::Contains("b.obj:1") && Catch::Contains("'nowhere.mtl' not found") && Catch::Contains("grey"));
    CHECK(s.materials[0].diffuse.x == 0.7f);
    CHECK(s.triangles.size() == 5);
    dir.write("bad.mtl", "newmtl red\nKd 0.5 nan 0.5\nKd spectral x.spd\nnewmtl blue green\nKd 2 0.5 -0\n");
    log.lines.clear();
    const Scene t = load_scene(dir.write("c.obj", "mtllib bad.mtl\n" + faces));
    REQUIRE(log.lines.size() == 1);
    CHECK_THAT(log.lines[0], Catch::Contains("bad.mtl:2") && Catch::Contains("0.5 nan 0.5") && Catch::Contains("(and 1 more)"));
    CHECK(t.materials[0].diffuse.y == 0.7f);
    CHECK((t.materials[1].diffuse.x == 1.0f && t.materials[1].diffuse.y == 0.5f && t.materials[1].diffuse.z == 0.0f));  // clamped to [0, 1]
    log.lines.clear();
    load_scene(dir.write("d.obj", faces));
    REQUIRE(log.lines.size() == 1);
    CHECK_THAT(log.lines[0], Catch::Contains("names no mtllib"));
  }
}

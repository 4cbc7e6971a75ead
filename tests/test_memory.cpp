// SPDX-License-Identifier: MIT
// test_memory.cpp — memory checked before it is spent: sparse files, decompression bombs, ray counts, allocation failures.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/huge_pages.h"
#include "host/core/io/obj.h"
#include "host/core/resources.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::error_of;
using mbvh_test::TempDir;

namespace {

// Sets MBVH_MEMORY_LIMIT for one scope.
struct MemoryLimit {
  explicit MemoryLimit(const char* value) { setenv("MBVH_MEMORY_LIMIT", value, 1); }
  ~MemoryLimit() { unsetenv("MBVH_MEMORY_LIMIT"); }
};

// A sparse file: `prefix`, then zero bytes up to `size` (4 KiB on disk, whatever `size` says).
std::string sparse(const TempDir& dir, const std::string& name, const std::string& prefix, std::uint64_t size) {
  const std::string path = dir.write(name, prefix);
  REQUIRE(truncate(path.c_str(), static_cast<off_t>(size)) == 0);
  return path;
}

// zstd blocks (RFC 8878): raw bytes, or one byte repeated (RLE, 4 bytes however long).
std::string zstd_block_header(std::uint32_t size, unsigned type, bool last) {
  const std::uint32_t h = (size << 3) | (type << 1) | (last ? 1u : 0u);
  return std::string(reinterpret_cast<const char*>(&h), 3);
}
std::string raw_block(const std::string& bytes, bool last = false) { return zstd_block_header(std::uint32_t(bytes.size()), 0, last) + bytes; }
std::string rle_block(char c, std::uint32_t n, bool last = false) { return zstd_block_header(n, 1, last) + c; }
// A frame without a stated content size (window 128 KiB), of `blocks` (the last one marked last).
std::string zstd_frame(const std::string& blocks) { return std::string("\x28\xb5\x2f\xfd\x00\x38", 6) + blocks; }
// A skippable frame (magic 0x184D2A5?) holding `payload`.
std::string skippable_frame(const std::string& payload) {
  const std::uint32_t n = std::uint32_t(payload.size());
  return std::string("\x5a\x2a\x4d\x18", 4) + std::string(reinterpret_cast<const char*>(&n), 4) + payload;
}

const std::string kTriangle = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n";

// One triangle, then `lines` comment lines of 128 KiB each: 16 MiB a 128 lines, 10 bytes a line compressed.
std::string comment_bomb(std::uint32_t lines) {
  std::string blocks = raw_block(kTriangle);
  for (std::uint32_t i = 0; i < lines; ++i) blocks += raw_block("#") + rle_block('x', 131072) + raw_block("\n", i + 1 == lines);
  return zstd_frame(blocks);
}

// The mbvh program under `ulimit -v` (KiB of address space): what a machine with little memory sees.
mbvh_test::RunResult run_cli_limited(std::uint64_t kib, const std::string& args) {
  return mbvh_test::run_shell("bash -c 'ulimit -c 0; ulimit -v " + std::to_string(kib) + "; exec " + mbvh_test::cli_path() +
                              " " + args + "'");
}

}  // namespace

TEST_CASE("OBJ streamed: a file parsed in pieces split anywhere gives the scene and the errors of one buffer",
          "[reliability][memory]") {
  const std::string text =
      "\xEF\xBB\xBF# comment\r\nv 0 0 0\nv 1 0 0 1\r\nv 1 1 0 0.5 0.5 0.5\nv 0 1 0\nf 1 2 3 4\nf -4/1 -3//2 -2/3/4\n"
      "o thing\nf 5 1 2\nv 2 2 2";
  const Scene whole = parse_obj("t.obj", text.data(), text.size());
  REQUIRE(whole.triangles.size() == 4);
  for (std::size_t piece = 1; piece <= text.size(); ++piece) {
    ObjParser p("t.obj");
    for (std::size_t at = 0; at < text.size(); at += piece) p.feed(text.data() + at, std::min(piece, text.size() - at));
    const Scene s = p.finish();
    CHECK(s.vertices.size() == whole.vertices.size());
    CHECK(std::memcmp(s.vertices.data(), whole.vertices.data(), whole.vertices.size() * sizeof whole.vertices[0]) == 0);
    CHECK(s.triangles == whole.triangles);
  }
  // errors name the same line wherever the piece boundaries fall
  const std::string bad = "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2 9\nv 1 1 1\n";
  const std::string nul = std::string("v 0 0 0\n\nv 1 0") + '\0' + "\n";
  for (std::size_t piece = 1; piece <= bad.size(); ++piece) {
    ObjParser p("t.obj");
    CHECK_THAT(error_of([&] {
                 for (std::size_t at = 0; at < bad.size(); at += piece) p.feed(bad.data() + at, std::min(piece, bad.size() - at));
                 p.finish();
               }),
               Catch::Contains("t.obj:5: vertex index 9 is out of range (the file has 4 vertices)"));
    ObjParser q("t.obj");
    CHECK_THAT(error_of([&] {
                 for (std::size_t at = 0; at < nul.size(); at += piece) q.feed(nul.data() + at, std::min(piece, nul.size() - at));
                 q.finish();
               }),
               Catch::Contains("t.obj:3: a NUL byte"));
  }
}

TEST_CASE("a sparse 4 GiB OBJ file is refused at its first NUL byte, not read whole first", "[reliability][memory][sanitizer-skip]") {
  TempDir dir;
  const std::string zeros = sparse(dir, "big.obj", "", 4ull << 30);
  const std::string tail = sparse(dir, "tail.obj", kTriangle, 4ull << 30);
  {
    // before: "needs about 4.0 GiB of memory (to read the file)", or all of it read under a larger budget
    MemoryLimit limit("64M");
    CHECK_THAT(error_of([&] { load_scene(zeros); }), Catch::Contains("big.obj:1: a NUL byte"));
    CHECK_THAT(error_of([&] { load_scene(tail); }), Catch::Contains("tail.obj:5: a NUL byte"));
  }
  // the program under 1 GiB of address space: before, a 4 GiB buffer and "std::bad_alloc"
  const auto r = run_cli_limited(1 << 20, "info " + tail);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("tail.obj:5: a NUL byte") && !Catch::Contains("bad_alloc"));
}

TEST_CASE("zstd is decompressed into the parser: a bomb costs what its geometry costs - skippable frames are read",
          "[reliability][memory][sanitizer-skip]") {
  TempDir dir;
  // 512 MiB of comments after one triangle, 40 KiB compressed: loads under a 64 MiB budget (before:
  // "needs about 64 MiB ... the zstd stream goes on")
  const std::string bomb = dir.write("bomb.obj.zst", comment_bomb(4096));
  {
    MemoryLimit limit("64M");
    const Scene s = load_scene(bomb);
    CHECK(s.triangles.size() == 1);
    CHECK(s.vertices.size() == 3);
  }
  // the program under 384 MiB of address space reads it (before: a 512 MiB buffer, "std::bad_alloc")
  const auto r = run_cli_limited(384 << 10, "info " + bomb);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, !Catch::Contains("bad_alloc"));
  // one line of 1 GiB is held until it ends: refused at the budget, naming the file and the line
  std::string blocks = raw_block(kTriangle + "#");
  for (int i = 0; i < 8192; ++i) blocks += rle_block('x', 131072, i + 1 == 8192);
  const std::string long_line = dir.write("line.obj.zst", zstd_frame(blocks));
  {
    MemoryLimit limit("64M");
    CHECK_THAT(error_of([&] { load_scene(long_line); }),
               Catch::Contains("line.obj.zst: needs about") && Catch::Contains("read by line 4 and a line of") &&
                   Catch::Contains("MBVH_MEMORY_LIMIT"));
  }
  // a stream that starts with a skippable frame (before: refused as "a NUL byte"), one between frames
  const std::string skip = dir.write("skip.obj.zst", skippable_frame(std::string("meta\0data", 9)) +
                                                         zstd_frame(raw_block("v 0 0 0\nv 1 0 0\n", true)) +
                                                         skippable_frame("x") + zstd_frame(raw_block("v 0 1 0\nf 1 2 3\n", true)));
  const Scene s = load_scene(skip);
  CHECK(s.triangles.size() == 1);
  CHECK(s.vertices.size() == 3);
  CHECK(maybe_decompress("skip.obj.zst", std::vector<char>(kTriangle.begin(), kTriangle.end())).size() == kTriangle.size());
  const std::string framed = skippable_frame("meta") + zstd_frame(raw_block(kTriangle, true));
  CHECK(maybe_decompress("skip.obj.zst", std::vector<char>(framed.begin(), framed.end())).size() == kTriangle.size());
}

TEST_CASE("PLY: the counts a header declares are checked against the memory budget before allocating",
          "[reliability][memory]") {
  TempDir dir;
  // 1M vertices of zero bytes (a sparse 12 MB file): fits a 16 MiB budget to read, not to hold beside the file
  const std::string header = "ply\nformat binary_little_endian 1.0\nelement vertex 1000000\nproperty float x\n"
                             "property float y\nproperty float z\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n";
  const std::string big = sparse(dir, "big.ply", header, header.size() + 12'000'000);
  MemoryLimit limit("16M");
  CHECK_THAT(error_of([&] { load_scene(big); }),
             Catch::Contains("big.ply: needs about 23 MiB") && Catch::Contains("1000000 vertices its header declares (line 3)") &&
                 Catch::Contains("16 MiB available (MBVH_MEMORY_LIMIT)"));
}

TEST_CASE("allocation failures are errors naming what was allocated: under ulimit -v, never a bare std::bad_alloc",
          "[reliability][memory][sanitizer-skip]") {
  CHECK_THAT(error_of([] { allocating("the test's array", 123, []() -> int { throw std::bad_alloc(); }); }),
             Catch::Contains("the test's array: out of memory: allocating about 123 bytes failed"));
  CHECK(allocating("nothing", 1, [] { return 7; }) == 7);
  // the budget knows the address-space limit: refused by the estimate, before allocating
  auto r = run_cli_limited(600 << 10, "info gen:soup:3000000");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("gen:soup:3000000: needs about") && Catch::Contains("ulimit -v") &&
                           !Catch::Contains("bad_alloc"));
  // estimates told to allow a terabyte: the allocation that fails is named
  r = mbvh_test::run_shell("bash -c 'ulimit -c 0; ulimit -v " + std::to_string(600 << 10) + "; MBVH_MEMORY_LIMIT=1T exec " +
                           mbvh_test::cli_path() + " info gen:soup:3000000'");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("gen:soup:3000000") && Catch::Contains("out of memory") && !Catch::Contains("bad_alloc"));
}

TEST_CASE("ray counts, ray files and image sizes are checked against MBVH_MEMORY_LIMIT before anything is allocated",
          "[reliability][memory]") {
  TempDir dir;
  const std::string env = "MBVH_MEMORY_LIMIT=64M";
  // 2M rays need 128 MB (64 bytes a ray): refused naming the option and the limit (before: traced)
  for (const std::string& cmd : std::vector<std::string>{"trace gen:sphere:8 --count 2000000", "check gen:sphere:8 --count 2000000 --backend cpu",
                                "rays gen:sphere:8 --count 2000000 -o " + dir.file("r.rays"),
                                "bench gen:sphere:8 --count 2000000 --backend cpu",
                                "build-bench gen:sphere:8 --versus medium --versus-count 2000000 --repeats 1"}) {
    const auto r = mbvh_test::run_cli(cmd, env, 120);
    INFO(cmd);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("count 2000000: needs about 122 MiB") && Catch::Contains("2000000 rays") &&
                             Catch::Contains("64 MiB available (MBVH_MEMORY_LIMIT)"));
  }
  // a ray file by its size: 1.5M rays (48 MB, a sparse file) fit to read, not with their hits
  const std::string rays = sparse(dir, "zero.rays", "", 1'500'000ull * 32);
  auto r = mbvh_test::run_cli("trace gen:sphere:8 --rays " + rays, env, 120);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--rays " + rays + ": needs about 92 MiB") && Catch::Contains("MBVH_MEMORY_LIMIT"));
  // an image: 600 x 600 pixels of 256 bytes
  r = mbvh_test::run_cli("render gen:sphere:8 --width 600 --height 600 -o " + dir.file("i.pfm"), env, 120);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--width 600 --height 600: needs about 88 MiB") && Catch::Contains("360000 pixels") &&
                           Catch::Contains("MBVH_MEMORY_LIMIT"));
}

TEST_CASE("advise_huge_pages is a hint: any range, before or after its bytes are written, keeps them", "[memory][build]") {
  advise_huge_pages(nullptr, std::size_t(1) << 30);  // nothing to advise
  std::vector<unsigned char> small(4096, 7);
  advise_huge_pages(small.data(), small.size());  // no whole 2 MiB page inside
  CHECK(std::count(small.begin(), small.end(), 7) == 4096);
  // 9 MiB and a bit, advised at an odd start before it is written (the whole 2 MiB pages inside
  // it), then again once written: every word as written
  std::vector<std::uint32_t, build::NoInit<std::uint32_t>> big((std::size_t(9) << 20) / 4 + 3);  // not zero-filled
  advise_huge_pages(reinterpret_cast<unsigned char*>(big.data()) + 1, big.size() * 4 - 1);
  for (std::size_t i = 0; i < big.size(); ++i) big[i] = static_cast<std::uint32_t>(i * 2654435761u);
  advise_huge_pages(big.data(), big.size() * 4);
  std::size_t same = 0;
  for (std::size_t i = 0; i < big.size(); ++i) same += big[i] == static_cast<std::uint32_t>(i * 2654435761u);
  CHECK(same == big.size());
}

// SPDX-License-Identifier: MIT
// test_mtri.cpp — streamed triangle sources: gen:mandelbulb (closed, the same at any thread
// count, the sparse walk against the dense one) and the .mtri file (written streamed, read back
// as the generator's triangles, damage and truncation named), `mbvh gen`.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstring>
#include <fstream>
#include <iterator>
#include <map>
#include <tuple>

#include "host/core/gen/mandelbulb.h"
#include "host/core/io/mtri.h"
#include "host/tools/stress.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::put;
using mbvh_test::bytes_of;
using mbvh_test::error_of;
using mbvh_test::run_cli;
using mbvh_test::TempDir;

namespace {

bool run_shell_ok(const std::string& command) { return mbvh_test::run_shell(command).code == 0; }


std::vector<SourceTri> mandelbulb(std::uint32_t res, unsigned threads, bool dense = false) {
  std::vector<SourceTri> all;
  MandelbulbOptions o;
  o.res = res;
  o.threads = threads;
  o.dense = dense;
  generate_mandelbulb(o, [&](std::uint64_t first, std::span<const SourceTri> t) {
    REQUIRE(first == all.size());
    all.insert(all.end(), t.begin(), t.end());
  });
  return all;
}

// Edges by their endpoints' bits, each counted in both directions: a closed, consistently
// oriented manifold uses every directed edge exactly once and its reverse exactly once.
void require_closed(const std::vector<SourceTri>& tris) {
  using P = std::tuple<float, float, float>;
  std::map<std::pair<P, P>, int> directed;
  for (const SourceTri& t : tris)
    for (int e = 0; e < 3; ++e) {
      const float* a = t.v + 3 * e;
      const float* b = t.v + 3 * ((e + 1) % 3);
      ++directed[{P{a[0], a[1], a[2]}, P{b[0], b[1], b[2]}}];
    }
  std::size_t open = 0, repeated = 0;
  for (const auto& [edge, n] : directed) {
    const auto back = directed.find({edge.second, edge.first});
    if (back == directed.end()) ++open;
    if (n != 1) ++repeated;
  }
  CHECK(open == 0);      // every edge in two triangles ...
  CHECK(repeated == 0);  // ... exactly two, with opposite directions (outward orientation)
}

}  // namespace

TEST_CASE("mandelbulb: the inside test (origin inside, far points escape at once)", "[mtri]") {
  CHECK(mandelbulb_escape(0, 0, 0, 8) == -1);
  CHECK(mandelbulb_escape(0, 1.1, 0, 8) >= 0);
  CHECK(mandelbulb_escape(1.2, 1.2, 1.2, 8) == 0);
  CHECK(mandelbulb_escape(0, 0.5, 0, 8) == -1);  // on the polar axis (x = z = 0): no 0 * inf
}

TEST_CASE("mandelbulb: closed and outward at RES 32 and 64; no rays leak from inside", "[mtri]") {
  for (std::uint32_t res : {32u, 64u}) {
    INFO("RES " << res);
    const std::vector<SourceTri> t = mandelbulb(res, 2);
    CHECK(t.size() > 1000);
    require_closed(t);
  }
  const Scene s = load_scene("gen:mandelbulb:64");
  const auto acc = Accel::build(s);
  const std::vector<Ray> rays = feature_rays(s, Vec3f{0, 0, 0}, 40000, 20000, 3);
  for (Layout l : {Layout::mbvh2, Layout::mbvh8}) {
    TraceOutput out;
    trace_reference(*acc, rays, TraceOptions{l, Traversal::bitstack, Query::closest, false}, out, 0);
    std::size_t leaks = 0;
    for (const Hit& h : out.hits) leaks += h.prim == MBVH_MISS_PRIM;
    CHECK(leaks == 0);
  }
}

TEST_CASE("mandelbulb: the same triangles in the same order at 1 and 2 threads; sparse against dense", "[mtri]") {
  const std::vector<SourceTri> a = mandelbulb(64, 1), b = mandelbulb(64, 2);
  REQUIRE(a.size() == b.size());
  CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(SourceTri)) == 0);
  // the sparse walk finds the dense walk's surface, triangle for triangle (it is not conservative in
  // general: mandelbulb.cpp); counts recorded (docs/massive.md)
  for (std::uint32_t res : {64u, 128u}) {
    const std::vector<SourceTri> sparse = mandelbulb(res, 0), dense = mandelbulb(res, 0, true);
    INFO("RES " << res << ": sparse " << sparse.size() << ", dense " << dense.size());
    CHECK(sparse.size() == (res == 64 ? 131004u : 707880u));
    REQUIRE(sparse.size() == dense.size());
    CHECK(std::memcmp(sparse.data(), dense.data(), sparse.size() * sizeof(SourceTri)) == 0);
  }
}

TEST_CASE(".mtri: written streamed, byte-identical at 1 and 2 threads, loads as the generator's triangles", "[mtri]") {
  TempDir dir;
  const std::string a = dir.file("a.mtri"), b = dir.file("b.mtri");
  const MtriWritten wa = write_mtri("gen:mandelbulb:48", {"-o", a}, 1);
  const MtriWritten wb = write_mtri("gen:mandelbulb:48", {"-o", b}, 2);
  CHECK(wa.streamed);
  CHECK(wa.count == wb.count);
  CHECK(wa.bytes == mtri_file_bytes(wa.count));
  CHECK(bytes_of(a) == bytes_of(b));
  const Scene from_file = load_scene(a), in_core = load_scene("gen:mandelbulb:48");
  REQUIRE(from_file.triangles.size() == wa.count);
  CHECK(from_file.vertices.size() == in_core.vertices.size());
  CHECK(std::memcmp(from_file.vertices.data(), in_core.vertices.data(), in_core.vertices.size() * sizeof(Vec3f)) == 0);
  CHECK(from_file.triangles == in_core.triangles);
  const MtriReader r(a);
  CHECK(r.count() == wa.count);
  CHECK(r.hash() == wa.hash);
  const Box bounds = in_core.bounds();
  CHECK(std::memcmp(&r.bounds(), &bounds, sizeof(Box)) == 0);
  // another scene goes through the in-core path and reads back the same
  const std::string c = dir.file("c.mtri");
  write_mtri("gen:sphere:16", {"-o", c}, 0);
  const Scene sphere = load_scene("gen:sphere:16"), back = load_scene(c);
  REQUIRE(back.triangles.size() == sphere.triangles.size());
  for (std::size_t i = 0; i < back.triangles.size(); ++i) {
    Vec3f p[3], q[3];
    sphere.triangle(i, p[0], p[1], p[2]);
    back.triangle(i, q[0], q[1], q[2]);
    CHECK(std::memcmp(p, q, sizeof p) == 0);
  }
}

TEST_CASE(".mtri: a damaged block is named, a truncated file and a wrong magic or version are refused at open", "[mtri]") {
  TempDir dir;
  const std::string good = dir.file("g.mtri");
  const MtriWritten w = write_mtri("gen:mandelbulb:64", {"-o", good}, 0);
  REQUIRE(w.count * sizeof(SourceTri) > 2 * kMtriBlockBytes);  // three blocks at least
  const std::string bytes = bytes_of(good);
  auto variant = [&](const std::string& name, auto change) {
    std::string b = bytes;
    change(b);
    put(dir.file(name), b);
    return dir.file(name);
  };
  // a flipped byte in the second block: open succeeds, reading names block 1
  const std::string flipped = variant("f.mtri", [](std::string& b) { b[kMtriHeaderBytes + kMtriBlockBytes + 100] ^= 0x10; });
  const MtriReader r(flipped);
  const std::string e = error_of([&] { r.for_each_chunk([](std::uint64_t, std::span<const SourceTri>) {}); });
  CHECK_THAT(e, Catch::Contains("f.mtri: block 1 of") && Catch::Contains("is damaged"));
  CHECK_THAT(error_of([&] { load_scene(flipped); }), Catch::Contains("block 1 of"));
  // truncated (a record short, or the trailer cut): refused at open, naming both sizes
  const std::string cut = variant("t.mtri", [](std::string& b) { b.resize(b.size() - 36); });
  CHECK_THAT(error_of([&] { MtriReader x(cut); }),
             Catch::Contains("t.mtri: not a usable .mtri file: size: " + std::to_string(bytes.size() - 36) + " bytes") &&
                 Catch::Contains(std::to_string(bytes.size()) + " bytes (truncated)"));
  const std::string tiny = variant("s.mtri", [](std::string& b) { b.resize(30); });
  CHECK_THAT(error_of([&] { load_scene(tiny); }), Catch::Contains("truncated: 30 bytes"));
  const std::string longer = variant("l.mtri", [](std::string& b) { b += "x"; });
  CHECK_THAT(error_of([&] { MtriReader x(longer); }), Catch::Contains("bytes after the end"));
  // magic, version, header and table damage
  const std::string magic = variant("m.mtri", [](std::string& b) { b[3] = 'X'; });
  CHECK_THAT(error_of([&] { MtriReader x(magic); }), Catch::Contains("m.mtri: not a usable .mtri file: magic"));
  const std::string version = variant("v.mtri", [](std::string& b) { b[8] = 7; });
  CHECK_THAT(error_of([&] { MtriReader x(version); }), Catch::Contains("format version 7, this library reads 1"));
  const std::string header = variant("h.mtri", [](std::string& b) { b[30] ^= 1; });  // a bounds byte
  CHECK_THAT(error_of([&] { MtriReader x(header); }), Catch::Contains("header: its check does not match"));
  const std::string table = variant("b.mtri", [](std::string& b) { b[b.size() - 12] ^= 1; });
  CHECK_THAT(error_of([&] { MtriReader x(table); }), Catch::Contains("block table: its checksum does not match"));
}

TEST_CASE("mbvh gen: the same file at 1 and 2 threads; bad specs and paths exit 2 and name them", "[mtri][cli]") {
  TempDir dir;
  const std::string a = dir.file("a.mtri"), b = dir.file("b.mtri");
  auto r = run_cli("gen gen:mandelbulb:40 -o " + a + " --threads 1");
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("triangles") && Catch::Contains("peak resident memory"));
  REQUIRE(run_cli("gen gen:mandelbulb:40 -o " + b + " --threads 2").code == 0);
  CHECK(bytes_of(a) == bytes_of(b));
  r = run_cli("info " + a);
  CHECK(r.code == 0);
  r = run_cli("gen gen:mandelbulb:1 -o " + a);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("gen:mandelbulb:1") && Catch::Contains("must be an integer in [2, 65536]"));
  r = run_cli("gen gen:mandelbulb:40:8:9 -o " + a);
  CHECK(r.code == 2);
  r = run_cli("gen gen:mandelbulb:40 -o " + dir.file("x.obj"));
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("must be named NAME.mtri"));
  r = run_cli("gen gen:mandelbulb:40 -o " + dir.file("no/such/dir/x.mtri"));
  CHECK(r.code == 2);
  r = run_cli("gen " + a + " -o " + a);  // a copy onto its own input
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("must not replace an input"));
  CHECK(bytes_of(a) == bytes_of(b));
}

TEST_CASE("mbvh gen gen:mandelbulb:256 (acceptance B-1): 3,883,000 triangles, the same file at 1 and 2 threads", "[mtri][cli]") {
  TempDir dir;
  const std::string a = dir.file("a.mtri"), b = dir.file("b.mtri");
  auto r = run_cli("gen gen:mandelbulb:256 -o " + a + " --threads 1");
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("wrote 3883000 triangles"));
  REQUIRE(run_cli("gen gen:mandelbulb:256 -o " + b + " --threads 2").code == 0);
  CHECK(run_shell_ok("cmp -s " + a + " " + b));
  CHECK(MtriReader(a).count() == 3883000u);
}

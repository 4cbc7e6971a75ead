// SPDX-License-Identifier: MIT
// test_hostile_inputs.cpp — library misuse, loaders and CLI options under hostile input.
#include <catch2/catch.hpp>

#include "tests/helpers.h"

#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <span>
#include <thread>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

bool same_answers(const TraceOutput& a, const TraceOutput& b) {
  return a.hits.size() == b.hits.size() && a.occluded == b.occluded && a.invalid == b.invalid &&
         (a.hits.empty() || std::memcmp(a.hits.data(), b.hits.data(), a.hits.size() * sizeof(Hit)) == 0);
}

}  // namespace

TEST_CASE("hostile: several threads tracing on one backend object give the single-threaded answers",
          "[reliability][hostile]") {
  const Scene s = load_scene("gen:sphere:24");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 3000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (const std::string& name : mbvh_test::all_backends().backends) {
    INFO("backend " << name);
    auto backend = make_backend(name, BackendOptions{});
    // two option sets, so that concurrent calls also switch the backend's prepared layout and query
    const Traversal t = backend->supports(Layout::mbvh4, Traversal::stack) ? Traversal::stack
                        : backend->supports(Layout::mbvh4, Traversal::bitstack) ? Traversal::bitstack
                                                                                : Traversal::dacrt;
    const Layout other = backend->supports(Layout::mbvh2, t) ? Layout::mbvh2 : Layout::mbvh4;
    const TraceOptions opts[2] = {TraceOptions{Layout::mbvh4, t, Query::closest, false},
                                  TraceOptions{other, t, Query::any, false}};
    TraceOutput want[2];
    {
      auto fresh = make_backend(name, BackendOptions{});
      for (int k = 0; k < 2; ++k) fresh->trace(*acc, rays, opts[k], want[k]);
    }
    constexpr int kThreads = 4, kRounds = 4;
    std::vector<int> wrong(kThreads, 0);
    std::vector<std::string> errors(kThreads);
    std::vector<std::thread> pool;
    for (int i = 0; i < kThreads; ++i)
      pool.emplace_back([&, i] {
        try {
          for (int r = 0; r < kRounds; ++r) {
            const int k = (i + r) % 2;
            TraceOutput out;
            backend->trace(*acc, rays, opts[k], out);
            wrong[i] += !same_answers(out, want[k]);
          }
        } catch (const std::exception& e) {
          errors[i] = e.what();
        }
      });
    for (auto& th : pool) th.join();
    backend.reset();  // Vulkan's validation reports what it saw while tearing down
    for (int i = 0; i < kThreads; ++i) {
      INFO("thread " << i);
      CHECK(errors[i] == "");
      CHECK(wrong[i] == 0);
    }
    if (const auto info = [&] {
          for (const BackendInfo& b : list_backends())
            if (b.name == name) return b;
          return BackendInfo{};
        }();
        info.pending_problems)
      CHECK(info.pending_problems().empty());
  }
}

TEST_CASE("hostile: enum values cast from out-of-range ints are refused at every entry point, naming the argument",
          "[reliability][hostile]") {
  Scene s = load_scene("gen:cube:4");
  BuildOptions bo;
  bo.quality = static_cast<BuildQuality>(7);
  CHECK_THROWS_WITH(Accel::build(s, bo), Catch::Contains("BuildOptions::quality is 7, not a BuildQuality"));
  CHECK_THROWS_WITH(Accel::cache_key(s, bo), Catch::Contains("BuildOptions::quality is 7"));
  {
    mbvh_test::TempDir dir;
    CHECK_THROWS_WITH(Accel::build_cached(s, bo, dir.path.string()), Catch::Contains("BuildOptions::quality is 7"));
  }
  const auto acc = Accel::build(s);
  CHECK_THROWS_WITH(acc->make_layout(static_cast<Layout>(4)), Catch::Contains("the layout is 4, not a Layout"));
  // automatic (3) is resolved at the entry points taking TraceOptions; past them it is refused by name
  CHECK_THROWS_WITH(acc->make_layout(Layout::automatic), Catch::Contains("the layout is auto"));
  CHECK_THROWS_WITH(state_bytes_per_ray(Layout::mbvh4, static_cast<Traversal>(11)),
                    Catch::Contains("the traversal is 11, not a Traversal"));
  const std::vector<Ray> rays(4, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  struct Bad {
    TraceOptions opt;
    const char* says;
  };
  std::vector<Bad> bad;
  {
    TraceOptions o{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.query = static_cast<Query>(7);
    bad.push_back({o, "TraceOptions::query is 7, not a Query"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.precision = static_cast<Precision>(9);
    bad.push_back({o, "TraceOptions::precision is 9, not a Precision"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.layout = static_cast<Layout>(-1);
    bad.push_back({o, "TraceOptions::layout is -1, not a Layout"});
    o = TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false};
    o.traversal = static_cast<Traversal>(11);  // one past automatic, the last
    bad.push_back({o, "TraceOptions::traversal is 11, not a Traversal"});
  }
  for (const Bad& b : bad) {
    INFO(b.says);
    TraceOutput out;
    CHECK_THROWS_WITH(trace_reference(*acc, rays, b.opt, out, 1), Catch::Contains(b.says));
    CHECK_THROWS_WITH(trace_one(*acc, rays[0], b.opt), Catch::Contains(b.says));
    for (const std::string& name : mbvh_test::all_backends().backends) {
      INFO("backend " << name);
      auto backend = make_backend(name);
      CHECK_THROWS_WITH(backend->trace(*acc, rays, b.opt, out), Catch::Contains(name + ": ") && Catch::Contains(b.says));
      CHECK_THROWS_WITH(backend->prepare(*acc, b.opt), Catch::Contains(b.says));
    }
  }
}

TEST_CASE("hostile: library messages name the scene (an unnamed one as such) and the argument, never a CLI option",
          "[reliability][hostile]") {
  Scene s;
  s.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  s.triangles = {{0, 1, 5}};
  CHECK(s.display_name() == "scene (unnamed)");
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): triangle 0 names vertex 5"));
  s.triangles = {{0, 1, 2}};
  s.vertices[1].x = 1e13f;  // beyond the exactly traced range
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): coordinate"));
  s.vertices = {{0, 0, 0}, {1e-12f, 0, 0}, {0, 1e-12f, 0}};  // below the smallest scene scale
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): "));
  s.vertices = {{0, 0, 0}, {0, 0, 0}, {0, 0, 0}};
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("scene (unnamed): the scene has no non-degenerate triangle"));
  s.name = "mine.obj";
  CHECK_THROWS_WITH(Accel::build(s), Catch::StartsWith("mine.obj: "));
  // a cache directory that is a file: named as the BVH cache directory, not as the CLI's --cache
  mbvh_test::TempDir dir;
  const std::string file = dir.write("plain", "x");
  const Scene cube = load_scene("gen:cube:2");
  try {
    Accel::build_cached(cube, {}, file);
    FAIL("build_cached took a file for its directory");
  } catch (const Error& e) {
    const std::string what = e.what();
    INFO(what);
    CHECK(what.find("--") == std::string::npos);
    CHECK(what.find(file) != std::string::npos);
    CHECK(what.find("BVH cache directory") != std::string::npos);
  }
#ifdef MBVH_HAVE_EMBREE
  auto embree = make_backend("embree");
  const auto acc = Accel::build(cube);
  TraceOutput out;
  const std::vector<Ray> rays(1, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});
  try {
    embree->trace(*acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest, false, Precision::exact}, out);
    FAIL("embree traced Precision::exact");
  } catch (const Error& e) {
    const std::string what = e.what();
    INFO(what);
    CHECK(what.find("--") == std::string::npos);
    CHECK(what.find("Precision::robust") != std::string::npos);
  }
#endif
}

#include "mbvh/rays.h"

namespace {

std::string error_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const Error& e) {
    return e.what();
  }
  return "(no error)";
}

const std::string kPlyHead = "ply\nformat ascii 1.0\n";

}  // namespace

TEST_CASE("hostile: an ascii PLY decimal gives the OBJ reader's float - rounded once, not through double",
          "[reliability][hostile][ply]") {
  mbvh_test::TempDir dir;
  // just above the midpoint 1 + 2^-24 of two floats: through double it lands on the midpoint and
  // rounds to even (1.0); parsed straight to float it is the float above
  const char* x = "1.0000000596046448";
  const std::string obj = dir.write("a.obj", std::string("v ") + x + " 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n");
  const std::string ply = dir.write("a.ply", kPlyHead + "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
                                             "element face 1\nproperty list uchar int vertex_indices\nend_header\n" +
                                             x + " 0 0\n0 1 0\n0 0 1\n3 0 1 2\n");
  const Scene a = load_scene(obj), b = load_scene(ply);
  CHECK(a.vertices[0].x == std::nextafter(1.0f, 2.0f));
  CHECK(std::memcmp(&a.vertices[0].x, &b.vertices[0].x, 4) == 0);
}

TEST_CASE("hostile: PLY headers that declare something twice are refused naming the line - faces may come first",
          "[reliability][hostile][ply]") {
  mbvh_test::TempDir dir;
  const std::string vtx = "element vertex 3\nproperty float x\nproperty float y\nproperty float z\n";
  const std::string face = "element face 1\nproperty list uchar int vertex_indices\n";
  const std::string data = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const std::string twice_x = dir.write("x.ply", kPlyHead + "element vertex 3\nproperty float x\nproperty float x\n"
                                                            "property float y\nproperty float z\n" + face + "end_header\n");
  CHECK_THAT(error_of([&] { load_scene(twice_x); }), Catch::Contains("x.ply:5:") && Catch::Contains("'x'") &&
                                                         Catch::Contains("declared a second time"));
  const std::string two_lists =
      dir.write("l.ply", kPlyHead + vtx + face + "property list uchar int vertex_index\nend_header\n");
  CHECK_THAT(error_of([&] { load_scene(two_lists); }), Catch::Contains("l.ply:9:") && Catch::Contains("second vertex index list"));
  const std::string two_elems = dir.write("e.ply", kPlyHead + vtx + vtx + face + "end_header\n");
  CHECK_THAT(error_of([&] { load_scene(two_elems); }), Catch::Contains("e.ply:7:") && Catch::Contains("element 'vertex' declared a second time"));
  // the face element before the vertex element is legal PLY: it loads
  const std::string first = dir.write("f.ply", kPlyHead + face + vtx + "end_header\n3 0 1 2\n0 0 0\n1 0 0\n0 1 0\n");
  const Scene s = load_scene(first);
  REQUIRE(s.triangles.size() == 1);
  CHECK(s.triangles[0] == std::array<std::uint32_t, 3>{0, 1, 2});
  CHECK(s.vertices.size() == 3);
  CHECK(s.vertices[1].x == 1.0f);
  const std::string bad = dir.write("g.ply", kPlyHead + face + vtx + "end_header\n3 0 1 7\n0 0 0\n1 0 0\n0 1 0\n");
  CHECK_THAT(error_of([&] { load_scene(bad); }), Catch::Contains("g.ply:10:") && Catch::Contains("face 0: vertex index 7 is out of range (3 vertices)"));
  // no end_header: the data line is named as data, not as an unknown keyword
  const std::string noend = dir.write("n.ply", kPlyHead + vtx + face + data);
  CHECK_THAT(error_of([&] { load_scene(noend); }), Catch::Contains("n.ply:9:") && Catch::Contains("no end_header before the data"));
}

TEST_CASE("hostile: generator specs with an extra parameter or an empty modifier are refused naming the spec",
          "[reliability][hostile]") {
  CHECK_THAT(error_of([] { load_scene("gen:sphere:8:junk"); }), Catch::Contains("gen:sphere:8:junk") && Catch::Contains("'junk'"));
  CHECK_THAT(error_of([] { load_scene("gen:soup:10:1:2"); }), Catch::Contains("gen:soup:10:1:2") && Catch::Contains("at most 2"));
  CHECK_THAT(error_of([] { load_scene("gen:sphere:8@"); }), Catch::Contains("gen:sphere:8@") && Catch::Contains("bad modifier '@'"));
  CHECK_THAT(error_of([] { load_scene("gen:sphere:8@scale=2@"); }), Catch::Contains("bad modifier '@'"));
  CHECK_THAT(error_of([] { load_scene("gen:sphere:8@@scale=2"); }), Catch::Contains("bad modifier '@'"));
  CHECK(load_scene("gen:sphere:8@scale=2@offset=1").triangle_count() > 0);
  CHECK(load_scene("gen:soup:10:3").triangle_count() == 10);
}

TEST_CASE("hostile: ray, hit and occlusion files refuse other formats and non-finite rays", "[reliability][hostile][rays]") {
  mbvh_test::TempDir dir;
  const std::string pad(64, '\x01');
  const struct { const char* name; std::string head; const char* says; } foreign[] = {
      {"png", std::string("\x89PNG\r\n\x1a\n", 8), "a PNG image"},
      {"zst", std::string("\x28\xB5\x2F\xFD", 4), "zstd"},
      {"skip", std::string("\x50\x2A\x4D\x18", 4), "zstd"},
      {"gz", std::string("\x1F\x8B\x08\x00", 4), "gzip"},
      {"cache", std::string("MBVHBVH\0", 8), "BVH cache"},
      {"ply", "ply\n", "a PLY scene"},
      {"pfm", "PF\n", "a PFM image"},
  };
  for (const auto& f : foreign) {
    INFO(f.name);
    const std::string path = dir.write(std::string(f.name) + ".rays", f.head + pad.substr(0, 64 - f.head.size()));
    CHECK_THAT(error_of([&] { read_rays(path); }), Catch::Contains(path) && Catch::Contains(f.says));
    CHECK_THAT(error_of([&] { read_hits(path); }), Catch::Contains(f.says));
    CHECK_THAT(error_of([&] { read_occlusion(path); }), Catch::Contains(f.says));
  }
  const std::string text = dir.write("t.rays", std::string(64, 'a'));
  CHECK_THAT(error_of([&] { read_rays(text); }), Catch::Contains("a text file"));
  std::vector<Ray> rays(3, Ray{0, 0, 5, 0, 0, 0, -1, INFINITY});  // tmax = +inf: fine
  write_rays(dir.file("ok.rays"), rays);
  CHECK(read_rays(dir.file("ok.rays")).size() == 3);
  rays[1].dy = NAN;
  write_rays(dir.file("nan.rays"), rays);
  CHECK_THAT(error_of([&] { read_rays(dir.file("nan.rays")); }), Catch::Contains("ray 1 has direction y = nan"));
  rays[1].dy = 0;
  rays[2].tmin = INFINITY;
  write_rays(dir.file("inf.rays"), rays);
  CHECK_THAT(error_of([&] { read_rays(dir.file("inf.rays")); }), Catch::Contains("ray 2 has tmin = inf"));
  rays[2].tmin = 0;
  rays[0].tmax = -INFINITY;
  CHECK_THAT(error_of([&] { rays_from_bytes("mem", reinterpret_cast<const char*>(rays.data()), rays.size() * sizeof(Ray)); }),
             Catch::Contains("mem: ray 0 has tmax = -inf"));
  const std::vector<std::uint8_t> occ{0, 1, 7};
  write_occlusion(dir.file("o.occ"), occ);
  CHECK_THAT(error_of([&] { read_occlusion(dir.file("o.occ")); }), Catch::Contains("byte 2 is 7"));
}

TEST_CASE("hostile: the CLI refuses foreign ray files, empty lists and bad backend settings with exit 2, naming them",
          "[reliability][hostile][cli]") {
  using mbvh_test::run_cli;
  mbvh_test::TempDir dir;
  // a PNG of a multiple of 32 bytes is not traced as rays
  const std::string png = dir.write("image.png", std::string("\x89PNG\r\n\x1a\n", 8) + std::string(56, '\x02'));
  auto r = run_cli("trace gen:cube:4 --rays " + png);
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("a PNG image, not a ray file") != std::string::npos);
  // a hit file of the same scene (misses are NaN bits in a ray's tmax) neither
  const std::string hits = dir.file("h.hits");
  REQUIRE(run_cli("trace gen:cube:4 --count 64 --kind random -o " + hits).code == 0);
  r = run_cli("trace gen:cube:4 --rays " + hits);
  INFO(r.output);
  CHECK(r.code == 2);
  // empty list items
  r = run_cli("bench gen:cube:4 --count 10 --backend ,");
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("--backend ',': an empty name") != std::string::npos);
  r = run_cli("check gen:cube:4 --count 10 --kinds ,");
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("--kinds ','") != std::string::npos);
  // a bad option value exits 2 like every usage error (CLI11's validation included)
  r = run_cli("trace gen:cube:4 --count abc");
  CHECK(r.code == 2);
  CHECK(run_cli("--version").code == 0);
#ifdef MBVH_HAVE_EMBREE
  r = run_cli("trace gen:cube:4 --count 10 --backend embree --set embree.quality=bogus");
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("embree.quality='bogus'") != std::string::npos);
#endif
#ifdef MBVH_HAVE_VULKAN
  r = run_cli("trace gen:cube:4 --count 10 --backend vulkan --set vulkan.max-binding-bytes=1");
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("vulkan.max-binding-bytes") != std::string::npos);
  const std::string icd = dir.write("trunc.json", "{\n  \"file_format_version\" : \"1.0.0\",\n  \"ICD\": {\n    \"library_path\": \"libvulkan_lvp.so\",");
  r = run_cli("trace gen:cube:4 --count 10 --backend vulkan", "VK_ICD_FILENAMES=" + icd);
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK(r.output.find("the driver manifest " + icd) != std::string::npos);
#endif
}

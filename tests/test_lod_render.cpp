// SPDX-License-Identifier: MIT
// test_lod_render.cpp — rendering out-of-core models (render.h's lod::Model overload, `mbvh render
// MODEL.mlod`): issue 35's B-6 (quality 0 with synchronous loading is the in-core image, byte for
// byte), B-7 (the budget is a hard cap over a camera path; a budget under the minimum is refused
// naming it) and B-8 (an asynchronous frame, once loading has settled, is the synchronous one).
#include <catch2/catch.hpp>

#include <cstring>
#include <regex>

#include "helpers.h"
#include "host/tools/camera_path.h"
#include "host/tools/image.h"
#include "host/tools/render.h"
#include "host/tools/resident.h"
#include "mbvh/backend.h"
#include "mbvh/lod.h"

using namespace mbvh;
using mbvh_test::TempDir;

namespace {

// gen:mandelbulb:64 (131,004 triangles) built into `path` with blocks of `block` raw bytes.
void build_model(const std::string& spec, const std::string& path, unsigned block) {
  const auto src = lod::open_triangles(spec);
  lod::BuildOptions bo;
  bo.block_bytes = block;
  bo.threads = 2;
  lod::build(*src, path, bo);
}

bool same_bits(const std::vector<float>& a, const std::vector<float>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(float)) == 0;
}

RenderOptions small_options(RenderMode mode, unsigned bounces) {
  RenderOptions o;
  o.width = 48;
  o.height = 36;
  o.spp = 1;
  o.mode = mode;
  o.bounces = bounces;
  return o;
}

}  // namespace

TEST_CASE("lod render: quality 0 with synchronous loading is the in-core image, byte for byte (B-6)", "[lod][render]") {
  TempDir dir;
  const std::string spec = "gen:mandelbulb:64", path = dir.file("m.mlod");
  build_model(spec, path, 64u << 10);
  REQUIRE(lod::is_model_file(path));
  const Scene s = load_scene(spec);
  const auto acc = Accel::build(s);
  auto cpu = make_backend("cpu");
  lod::CacheOptions co;
  co.synchronous = true;
  const auto model = lod::Model::open(path, co);
  // the default camera and light depend on the bounds
  for (int k = 0; k < 3; ++k) {
    CHECK(model->bounds().lo[k] == acc->bounds().lo[k]);
    CHECK(model->bounds().hi[k] == acc->bounds().hi[k]);
  }
  const Camera cam = default_camera(acc->bounds());
  for (const auto& [mode, bounces] : {std::pair{RenderMode::path, 0u}, std::pair{RenderMode::path, 8u},
                                      std::pair{RenderMode::ao, 0u}, std::pair{RenderMode::normals, 0u}}) {
    for (bool given : {true, false}) {  // an explicit camera, and the one frame_scene picks
      INFO(to_string(mode) << ", " << bounces << " bounces, " << (given ? "--camera" : "framed"));
      RenderOptions o = small_options(mode, bounces);
      o.has_camera = given;
      o.camera = cam;
      const RenderResult core = render(s, *acc, *cpu, o);
      ModelRenderOptions mo;
      mo.lod = true;
      mo.quality = 0;
      const RenderResult got = render(*model, o, mo);
      model->end_frame();
      CHECK(camera_argument(got.camera) == camera_argument(core.camera));
      CHECK(got.rays == core.rays);
      CHECK(got.voxel_hits == 0);
      CHECK(same_bits(got.rgb, core.rgb));
      double sum = 0;
      for (float v : got.rgb) sum += v;
      CHECK(sum > 0);
    }
  }
  // full detail (--lod off) is the in-core image too
  RenderOptions o = small_options(RenderMode::path, 8);
  ModelRenderOptions off;
  off.lod = false;
  CHECK(same_bits(render(*model, o, off).rgb, render(s, *acc, *cpu, o).rgb));

  // the command line: `mbvh render m.mlod --lod --lod-quality 0 --lod-sync` and `mbvh render gen:...`
  const std::string common = " --camera " + camera_argument(cam) + " --width 40 --height 30 --spp 1 --mode path";
  for (const std::string bounces : {" --bounces 0", ""}) {
    const auto a = mbvh_test::run_cli("render " + path + " --lod --lod-quality 0 --lod-sync --pfm " + dir.file("a.pfm") +
                                      " -o " + dir.file("a.png") + common + bounces, "", 120);
    INFO(a.output);
    REQUIRE(a.code == 0);
    const auto b = mbvh_test::run_cli("render " + spec + " --pfm " + dir.file("b.pfm") + " -o " + dir.file("b.png") +
                                      common + bounces, "", 120);
    INFO(b.output);
    REQUIRE(b.code == 0);
    CHECK(mbvh_test::bytes_of(dir.file("a.pfm")) == mbvh_test::bytes_of(dir.file("b.pfm")));
    CHECK(!mbvh_test::bytes_of(dir.file("a.pfm")).empty());
  }
}

TEST_CASE("lod render: the budget is a hard cap over a camera path (B-7)", "[lod][render]") {
  TempDir dir;
  const std::string path = dir.file("m.mlod");
  build_model("gen:mandelbulb:64", path, 16u << 10);
  lod::ModelInfo info;
  {
    const auto probe = lod::Model::open(path, {});
    info = probe->info();
  }
  // a quarter of the model, or the least it opens with
  const std::uint64_t minimum = info.pinned_bytes + 2ull * info.block_bytes;
  const std::uint64_t budget = std::max(minimum, info.raw_bytes / 4);
  INFO("raw " << info.raw_bytes << ", pinned " << info.pinned_bytes << ", budget " << budget);
  REQUIRE(info.raw_bytes >= 3 * budget);  // the model is at least 3x its budget: eviction must happen

  MemoryProbe mem;
  mem.start();
  lod::CacheOptions co;
  co.memory_budget = budget;
  co.threads = 2;
  const auto model = lod::Model::open(path, co);
  // 10 frames around the model and closer in: every frame asks for more than the budget holds
  const Box b = model->bounds();
  std::vector<Camera> cams = orbit_path(b, 10);
  for (std::size_t k = 0; k < cams.size(); ++k) {  // every other frame from half the distance
    if (k % 2 == 0) continue;
    const Vec3f c = b.center();
    cams[k].eye = Vec3f{c.x + 0.5f * (cams[k].eye.x - c.x), c.y + 0.5f * (cams[k].eye.y - c.y), c.z + 0.5f * (cams[k].eye.z - c.z)};
  }
  RenderOptions o = small_options(RenderMode::path, 0);
  o.width = 96;
  o.height = 72;
  o.has_camera = true;
  ModelRenderOptions mo;
  mo.quality = 0;  // no voxel is accepted: every block the rays reach is asked for
  std::uint64_t loads = 0;
  for (const Camera& c : cams) {
    o.camera = c;
    render(*model, o, mo);
    model->end_frame();
    model->wait_idle();
    const lod::CacheStats st = model->stats();
    CHECK(st.budget == budget);
    CHECK(st.peak_bytes <= budget);
    CHECK(st.resident_bytes <= budget);
    loads = st.loads;
  }
  const lod::CacheStats st = model->stats();
  CHECK(loads > 0);
  CHECK(st.evictions > 0);
  CHECK(st.peak_bytes <= budget);
  // the process holds the budget and the renderer's buffers, not the model
  if (const std::int64_t extra = mem.peak_extra(); extra >= 0) CHECK(std::uint64_t(extra) <= budget + (64ull << 20));

  // the command line: per-frame statistics, and a budget under the minimum refused naming it
  const std::string camera_file = dir.write("path.txt", "# two views\n" + camera_argument(cams[0]) + "\n" +
                                                            camera_argument(cams[1]) + "\n\n" + camera_argument(cams[2]) + "\n");
  const auto r = mbvh_test::run_cli("render " + path + " --lod --lod-quality 0 --memory " + std::to_string(budget) +
                                    " --frames 4 --camera-path " + camera_file + " --width 64 --height 48 --spp 1" +
                                    " --mode path --bounces 0 --stats-json " + dir.file("s.json") + " -o " +
                                    dir.file("s.png"), "", 120);
  INFO(r.output);
  REQUIRE(r.code == 0);
  const std::string json = mbvh_test::bytes_of(dir.file("s.json"));
  CHECK(json.find("\"peak_bytes\"") != std::string::npos);
  CHECK(json.find("\"evictions\"") != std::string::npos);
  CHECK(json.find("\"median_seconds\"") != std::string::npos);
  std::size_t frames = 0;
  for (std::size_t at = 0; (at = json.find("\"frame\":", at)) != std::string::npos; ++at) ++frames;
  CHECK(frames == 4);
  const auto low = mbvh_test::run_cli("render " + path + " --lod --memory " + std::to_string(minimum / 2) + " -o " +
                                      dir.file("x.png"), "", 60);
  CHECK(low.code == 2);
  CHECK(low.output.find("minimum") != std::string::npos);
  CHECK(!std::filesystem::exists(dir.file("x.png")));
  // options that need a model, on a scene; and a malformed camera path
  const auto scene = mbvh_test::run_cli("render gen:sphere:8 --memory 64M -o " + dir.file("y.png"), "", 60);
  CHECK(scene.code == 2);
  CHECK(scene.output.find(".mlod") != std::string::npos);
  const std::string bad = dir.write("bad.txt", "1,2,3,0,0,0\n1,2,x,0,0,0\n");
  const auto badr = mbvh_test::run_cli("render " + path + " --camera-path " + bad + " -o " + dir.file("z.png"), "", 60);
  CHECK(badr.code == 2);
  CHECK(badr.output.find("bad.txt:2") != std::string::npos);
}

TEST_CASE("lod render: an asynchronous frame equals the synchronous one once loading settles (B-8)", "[lod][render]") {
  TempDir dir;
  const std::string path = dir.file("m.mlod");
  build_model("gen:mandelbulb:64", path, 16u << 10);
  RenderOptions o = small_options(RenderMode::path, 1);
  o.width = 64;
  o.height = 48;
  ModelRenderOptions mo;  // LOD on, quality 1
  lod::CacheOptions sync;
  sync.synchronous = true;
  const auto ms = lod::Model::open(path, sync);
  o.camera = default_camera(ms->bounds());
  o.has_camera = true;
  const RenderResult want = render(*ms, o, mo);
  CHECK(want.voxel_hits > 0);  // the test is about LOD: voxels are hit

  const auto ma = lod::Model::open(path, {});  // asynchronous loading, no eviction
  bool settled = false;
  for (int frame = 0; frame < 100 && !settled; ++frame) {
    const std::uint64_t misses = ma->stats().misses;
    const RenderResult got = render(*ma, o, mo);
    const bool complete = ma->stats().misses == misses;  // no ray of this frame found a block missing
    ma->end_frame();
    ma->wait_idle();
    CHECK(ma->stats().pending == 0);
    if (complete) {
      settled = true;
      CHECK(got.forced_voxels == 0);
      CHECK(same_bits(got.rgb, want.rgb));
    }
  }
  CHECK(settled);
  // the first frame, with only the pinned blocks, needed more (else the test shows nothing)
  CHECK(ma->stats().loads > 0);
}

TEST_CASE("lod render: voxel hits shade like surfaces (finite, lit, unit normals facing the eye)", "[lod][render]") {
  TempDir dir;
  const std::string path = dir.file("m.mlod");
  build_model("gen:mandelbulb:64", path, 16u << 10);
  lod::CacheOptions co;
  co.synchronous = true;
  const auto model = lod::Model::open(path, co);
  ModelRenderOptions coarse;
  coarse.quality = 16;  // coarse voxels wherever the footprint allows
  RenderOptions o = small_options(RenderMode::normals, 0);
  o.has_camera = true;
  o.camera = default_camera(model->bounds());
  const RenderResult n = render(*model, o, coarse);
  REQUIRE(n.voxel_hits > 0);
  // every pixel the model covers holds 0.5 (n + 1) of a unit normal
  std::size_t covered = 0;
  for (std::size_t p = 0; p < n.rgb.size(); p += 3) {
    const float x = 2 * n.rgb[p] - 1, y = 2 * n.rgb[p + 1] - 1, z = 2 * n.rgb[p + 2] - 1;
    if (n.rgb[p] == 0 && n.rgb[p + 1] == 0 && n.rgb[p + 2] == 0) continue;
    ++covered;
    CHECK(std::fabs(x * x + y * y + z * z - 1) < 1e-4f);
  }
  CHECK(covered > 0);
  // path mode: a finite image, and voxel points lit by the light (their shadow rays leave their box)
  RenderOptions p = small_options(RenderMode::path, 1);
  p.has_camera = true;
  p.camera = o.camera;
  ModelRenderOptions full;
  full.lod = false;
  const RenderResult lodded = render(*model, p, coarse), exact = render(*model, p, full);
  REQUIRE(lodded.voxel_hits > 0);
  double sum_lod = 0, sum_exact = 0;
  for (float v : lodded.rgb) {
    CHECK(std::isfinite(v));
    sum_lod += v;
  }
  for (float v : exact.rgb) sum_exact += v;
  // the same light reaches about as much of the model: within a factor 2 of full detail's
  CHECK(sum_lod > 0.5 * sum_exact);
  CHECK(sum_lod < 2.0 * sum_exact);
}

TEST_CASE("lod render: camera path files and orbits", "[lod][render]") {
  TempDir dir;
  const std::string f = dir.write("p.txt", "# a path\n\n1,2,3,0,0,0\n 4 , 5 , 6 , 0 , 1 , 0 , 45 \r\n");
  const std::vector<Camera> c = read_camera_path(f);
  REQUIRE(c.size() == 2);
  CHECK(c[0].eye.x == 1.0f);
  CHECK(c[0].fov_deg == 60.0f);
  CHECK(c[1].target.y == 1.0f);
  CHECK(c[1].fov_deg == 45.0f);
  CHECK_THAT(mbvh_test::error_of([&] { read_camera_path(dir.write("a.txt", "1,2,3,0,0\n")); }),
             Catch::Contains("a.txt:1") && Catch::Contains("5 numbers"));
  CHECK_THAT(mbvh_test::error_of([&] { read_camera_path(dir.write("b.txt", "1,2,3,0,0,0\n1,2,3,1,2,3\n")); }),
             Catch::Contains("b.txt:2"));
  CHECK_THAT(mbvh_test::error_of([&] { read_camera_path(dir.write("c.txt", "1,2,3,0,0,0,nan\n")); }), Catch::Contains("c.txt:1"));
  CHECK_THAT(mbvh_test::error_of([&] { read_camera_path(dir.write("d.txt", "# nothing\n")); }), Catch::Contains("no camera"));
  CHECK_THAT(mbvh_test::error_of([&] { read_camera_path(dir.file("missing.txt")); }), Catch::Contains("missing.txt"));
  Box b;
  b.grow(Vec3f{-1, -2, -1});
  b.grow(Vec3f{1, 2, 3});
  const std::vector<Camera> orbit = orbit_path(b, 4);
  REQUIRE(orbit.size() == 4);
  CHECK(camera_argument(orbit[0]) == camera_argument(default_camera(b)));
  const Vec3f ctr = b.center();
  const auto radius = [&](const Camera& k) { return std::hypot(k.eye.x - ctr.x, k.eye.z - ctr.z); };
  for (const Camera& k : orbit) {
    CHECK(k.eye.y == orbit[0].eye.y);
    CHECK(std::fabs(radius(k) - radius(orbit[0])) < 1e-4f * radius(orbit[0]));
    CHECK(camera_problem(k).empty());
  }
  // half way round: the eye opposite the first
  CHECK(std::fabs((orbit[2].eye.x - ctr.x) + (orbit[0].eye.x - ctr.x)) < 1e-4f);
}

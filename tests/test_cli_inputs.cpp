// SPDX-License-Identifier: MIT
// test_cli_inputs.cpp — the `mbvh` program checks every number it is given: a value outside an
// option's range is an error naming the option (no wrap-around, no allocator or stoull message),
// a camera that cannot make rays is an error naming --camera while one looking straight down
// renders, and the embree peer reports rays it cannot take instead of aborting.
#include <catch2/catch.hpp>

#include <set>
#include <string>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/config.h"
#include "host/tools/raygen.h"
#include "host/tools/render.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::run_cli;
using mbvh_test::TempDir;

namespace {

// `mbvh ARGS` fails, its message naming `option`, and none of the messages that name nothing.
void require_refused(const std::string& args, const std::string& option) {
  const auto r = run_cli(args);
  INFO("mbvh " << args << "\n" << r.output);
  CHECK(r.code != 0);
  CHECK(r.code != -1);  // exited, not killed by a signal
  CHECK_THAT(r.output, Catch::Contains(option));
  for (const char* nameless : {"vector::reserve", "bad_alloc", "stoull", "Could not convert"})
    CHECK_THAT(r.output, !Catch::Contains(nameless));
}

}  // namespace

TEST_CASE("mbvh checks every numeric option's range and names the option", "[cli][inputs]") {
  TempDir dir;
  const std::string t = "trace gen:sphere:8 ";
  require_refused(t + "--count -1", "--count");
  require_refused(t + "--count 0", "--count");
  require_refused(t + "--count 99999999999999999", "--count");
  require_refused(t + "--count 100 --seed -1", "--seed");
  require_refused(t + "--count 100 --seed 12x", "--seed");
  require_refused(t + "--count 100 --threads -1", "--threads");
  require_refused(t + "--count 100 --threads 536870912", "--threads");
  require_refused(t + "--count 100 --max-leaf 0", "--max-leaf");
  require_refused(t + "--count 100 --leaf-block 0", "--leaf-block");
  require_refused("rays gen:sphere:8 --count -5 -o " + dir.file("r.rays"), "--count");
  require_refused("check gen:sphere:8 --count 100 --brute -5", "--brute");
  require_refused("check gen:sphere:8 --count 100 --brute abc", "--brute");
  const std::string b = "bench gen:sphere:8 --count 100 --layout mbvh4 --traversal stack --query closest ";
  require_refused(b + "--warmup nan", "--warmup");
  require_refused(b + "--warmup -1", "--warmup");
  require_refused(b + "--passes 0", "--passes");
  require_refused(b + "--error-rays -1", "--error-rays");
  require_refused("bench gen:sphere:8 --count -1", "--count");
  const std::string png = " -o " + dir.file("x.png");
  require_refused("render gen:sphere:8 --width -1" + png, "--width");
  require_refused("render gen:sphere:8 --width 0" + png, "--width");
  require_refused("render gen:sphere:8 --height 70000" + png, "--height");
  require_refused("render gen:sphere:8 --spp 0" + png, "--spp");
  require_refused("render gen:sphere:8 --bounces -1" + png, "--bounces");
  require_refused("render gen:sphere:8 --seed -1" + png, "--seed");
  require_refused("render gen:sphere:8 --width 65536 --height 65536 --spp 1" + png, "--width 65536 --height 65536");
  // generator parameters and modifiers: the spec is named
  require_refused("info gen:sphere:-1", "gen:sphere:-1");
  require_refused("info gen:sphere:8@scale=3e38@offset=3e38", "gen:sphere:8@scale=3e38@offset=3e38");
  // the largest thread count is taken
  const auto r = run_cli(t + "--count 100 --threads 1024");
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("1024 thread(s)"));
}

TEST_CASE("mbvh refuses a camera that cannot make rays and names --camera - straight down renders", "[cli][inputs]") {
  TempDir dir;
  for (const char* cam : {"1,2,3,1,2,3", "nan,0,3,0,0,0", "0,0,inf,0,0,0", "0,0,1e39,0,0,0", "0,0,3,0,0,0,0",
                          "0,0,3,0,0,0,180", "0,0,3,0,0,0,-20"}) {
    require_refused(std::string("trace gen:sphere:8 --count 100 --camera ") + cam, "--camera");
    require_refused(std::string("render gen:sphere:8 --width 8 --height 8 --spp 1 --camera ") + cam + " -o " +
                        dir.file("x.png"),
                    "--camera");
  }
  require_refused("bench gen:sphere:8 --count 100 --camera 1,2,3,1,2,3", "--camera 1,2,3,1,2,3: the eye equals the target");
  require_refused("rays gen:sphere:8 --count 100 --camera 0,0,0,0,0,0 -o " + dir.file("r.rays"), "--camera");
  // a view along the up vector: every ray valid, the sphere in the middle
  auto r = run_cli("trace gen:sphere:16 --count 400 --camera 0,5,0,0,0,0");
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("hits, 0 invalid") && !Catch::Contains(" 0 hits"));
  const std::string pfm = dir.file("down.pfm");
  r = run_cli("render gen:sphere:16 --mode normals --width 16 --height 16 --spp 1 --camera 0,5,0,0,0,0 -o " +
              dir.file("down.png") + " --pfm " + pfm);
  CHECK(r.code == 0);
  unsigned w = 0, h = 0;
  const std::vector<float> rgb = read_pfm(pfm, w, h);
  REQUIRE(rgb.size() == 16 * 16 * 3);
  std::set<float> values(rgb.begin(), rgb.end());
  CHECK(values.size() > 10);  // the sphere's normals, not one colour everywhere
}

#ifdef MBVH_HAVE_EMBREE
TEST_CASE("the embree peer never aborts mbvh - trace and check and render and bench report rays beyond Embree's range",
          "[cli][inputs]") {
  TempDir dir;
  const std::vector<Ray> rays{Ray{0, 0, 5, 0, 0, 0, -1, INFINITY}, Ray{0, 0, 5, 0, -2e18f, 0, 0, INFINITY}};
  const std::string file = dir.file("far.rays");
  write_rays(file, rays);
  for (const std::string& cmd : {"trace gen:sphere:8 --backend embree --traversal stack --rays " + file,
                                 "trace gen:sphere:8 --backend embree --traversal stack --query any --rays " + file,
                                 "check gen:sphere:8 --backend cpu-scalar,embree --layout mbvh4 --traversal stack --rays " + file}) {
    const auto r = run_cli(cmd);
    INFO(cmd << "\n" << r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("embree: ray 1 has direction x = -2e+18") && Catch::Contains("1.844e18"));
  }
  // a camera beyond Embree's range is beyond the range traced exactly (check_ray_range): its
  // primary rays are refused before Embree sees them, by render and bench alike
  for (const std::string& cmd :
       {"render gen:sphere:8 --backend embree --width 4 --height 4 --spp 1 --camera 0,0,1e19,0,0,0 -o " + dir.file("e.png"),
        std::string("bench gen:sphere:8 --backend embree --layout mbvh4 --traversal stack --kinds primary --count 100 "
                    "--camera 0,0,1e19,0,0,0")}) {
    const auto r = run_cli(cmd);
    INFO(cmd << "\n" << r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("ray 0 (origin 0 0 1e+19") && Catch::Contains("leaves the range traced exactly"));
  }
}
#endif

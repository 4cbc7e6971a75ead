// SPDX-License-Identifier: MIT
// test_cache.cpp — the BVH cache (Accel::save / load / build_cached, `--cache DIR`): a cached build
// traces exactly as the build it came from; a damaged, truncated or mismatched file is detected,
// never traced, and rebuilt.
#include <catch2/catch.hpp>

#include <cstring>
#include <filesystem>
#include <fstream>

#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "host/tools/raygen.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::TempDir;

namespace {

std::vector<Hit> trace_all(const Accel& acc, const std::vector<Ray>& rays) {
  auto backend = make_backend("cpu-scalar");
  TraceOutput out;
  backend->trace(acc, rays, TraceOptions{Layout::mbvh4, Traversal::bitstack}, out);
  return out.hits;
}

std::string file_bytes(const std::string& p) {
  std::ifstream f(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

void write_file(const std::string& p, const std::string& bytes) { std::ofstream(p, std::ios::binary) << bytes; }

}  // namespace

TEST_CASE("BVH cache - a cached build is the build - damaged or mismatched files are rebuilt", "[cache]") {
  TempDir dir;
  const Scene s = load_scene("gen:soup:20000:3");
  BuildOptions opt;
  opt.threads = 2;
  Accel::CacheReport first, second;
  const auto built = Accel::build_cached(s, opt, dir.file("c"), &first);
  CHECK_FALSE(first.loaded);
  CHECK(first.problem.empty());
  REQUIRE(std::filesystem::is_regular_file(first.path));
  const auto loaded = Accel::build_cached(s, opt, dir.file("c"), &second);
  CHECK(second.loaded);
  CHECK(second.path == first.path);
  CHECK(loaded->hash() == built->hash());
  CHECK(loaded->binary_stats().sah_cost == built->binary_stats().sah_cost);
  CHECK(loaded->mbvh4().stats.nodes == built->mbvh4().stats.nodes);
  RayGenOptions ro;
  ro.count = 5000;
  const std::vector<Ray> rays = generate_rays(s, *built, ro);
  const std::vector<Hit> a = trace_all(*built, rays), b = trace_all(*loaded, rays);
  REQUIRE(a.size() == b.size());
  CHECK(std::memcmp(a.data(), b.data(), a.size() * sizeof(Hit)) == 0);

  // thread count is not part of the key; options that shape the tree are
  BuildOptions three = opt;
  three.threads = 3;
  CHECK(Accel::cache_key(s, three) == Accel::cache_key(s, opt));
  BuildOptions leafy = opt;
  leafy.max_leaf = 4;
  CHECK(Accel::cache_key(s, leafy) != Accel::cache_key(s, opt));
  BuildOptions low = opt;
  low.quality = BuildQuality::low;
  CHECK(Accel::cache_key(s, low) != Accel::cache_key(s, opt));
  BuildOptions high = opt;
  high.quality = BuildQuality::high;
  CHECK(Accel::cache_key(s, high) != Accel::cache_key(s, opt));
  {  // a high-quality build (prims repeated across leaves) round-trips with its quality
    Accel::CacheReport h1, h2;
    const auto hb = Accel::build_cached(s, high, dir.file("h"), &h1);
    const auto hl = Accel::build_cached(s, high, dir.file("h"), &h2);
    CHECK(h2.loaded);
    CHECK(hl->hash() == hb->hash());
    CHECK(hl->options().quality == BuildQuality::high);
    CHECK(hl->tris().size() > built->tris().size());
    const std::vector<Hit> c = trace_all(*hl, rays);
    CHECK(std::memcmp(a.data(), c.data(), a.size() * sizeof(Hit)) == 0);
  }
  Scene moved = s;
  moved.vertices[0].x += 1.0f;
  CHECK(Accel::cache_key(moved, opt) != Accel::cache_key(s, opt));

  const std::string good = file_bytes(first.path);
  const std::uint64_t key = Accel::cache_key(s, opt);
  SECTION("a flipped byte anywhere is detected") {
    for (std::size_t at : {std::size_t(3), std::size_t(40), good.size() / 2, good.size() - 20, good.size() - 1}) {
      std::string bad = good;
      bad[at] = static_cast<char>(bad[at] ^ 0x10);
      write_file(first.path, bad);
      INFO("byte " << at);
      CHECK_THROWS_AS(Accel::load(first.path, key), Error);
      Accel::CacheReport r;
      const auto again = Accel::build_cached(s, opt, dir.file("c"), &r);
      CHECK_FALSE(r.loaded);
      CHECK_THAT(r.problem, Catch::Contains(first.path) && Catch::Contains("not a usable BVH cache file"));
      CHECK(again->hash() == built->hash());
      CHECK(Accel::load(first.path, key)->hash() == built->hash());  // replaced by a good one
    }
  }
  SECTION("truncated and empty files are detected") {
    for (std::size_t keep : {std::size_t(0), std::size_t(10), good.size() / 3, good.size() - 8}) {
      write_file(first.path, good.substr(0, keep));
      INFO("kept " << keep << " bytes");
      CHECK_THROWS_WITH(Accel::load(first.path, key), Catch::Contains("truncated") || Catch::Contains("checksum") ||
                                                          Catch::Contains("does not match"));
    }
  }
  SECTION("a file of another scene or options is refused by its key") {
    CHECK_THROWS_WITH(Accel::load(first.path, key + 1), Catch::Contains("another scene"));
  }
  SECTION("a directory where the file should be is an error, not a crash") {
    std::filesystem::remove(first.path);
    std::filesystem::create_directory(first.path);
    CHECK_THROWS_AS(Accel::build_cached(s, opt, dir.file("c")), Error);
  }
}

namespace {

// `mbvh trace SPEC --cache` twice (built once, then read back, the same hits), then with one bit
// of the cache file flipped: the checksum catches it and the BVH is rebuilt, the same hits again.
void cache_roundtrip(const std::string& spec) {
  TempDir dir;
  const std::string cache = dir.file("cache");
  const std::string trace = "trace " + spec + " --count 2000 --cache " + cache + " -o ";
  auto r = mbvh_test::run_cli(trace + dir.file("a.hits"));
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("BVH built in") && Catch::Contains("cached in"));
  r = mbvh_test::run_cli(trace + dir.file("b.hits"));
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("BVH read from the cache"));
  CHECK_THAT(r.output, !Catch::Contains("BVH built in"));
  CHECK(file_bytes(dir.file("a.hits")) == file_bytes(dir.file("b.hits")));
  std::string file;
  for (const auto& e : std::filesystem::directory_iterator(cache)) file = e.path().string();
  std::string bytes = file_bytes(file);
  bytes[bytes.size() / 2] = static_cast<char>(bytes[bytes.size() / 2] ^ 1);
  write_file(file, bytes);
  r = mbvh_test::run_cli(trace + dir.file("c.hits"));
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("warning") && Catch::Contains("checksum") && Catch::Contains("BVH built in"));
  CHECK(file_bytes(dir.file("a.hits")) == file_bytes(dir.file("c.hits")));
}

}  // namespace

TEST_CASE("mbvh --cache builds once and reports a damaged cache file", "[cache][cli]") {
  cache_roundtrip("gen:hairball:20000");
}

// At the size a user meets: a 5M-triangle scene traced twice with --cache builds once,
// and a damaged cache file is detected (slow: the Release stage only)
TEST_CASE("mbvh --cache on a 5M-triangle hairball builds once and detects a damaged file", "[cache][cli][large][heavy]") {
  cache_roundtrip("gen:hairball:5000000");
}

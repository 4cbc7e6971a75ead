// SPDX-License-Identifier: MIT
// test_cache_safety.cpp — the BVH cache under hostile use: links, crafted and colliding entries, concurrent writers, sizes checked before allocating.
#include <catch2/catch.hpp>

#include <sys/stat.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>

#include "host/core/layouts.h"
#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::put;
using mbvh_test::bytes_of;
using mbvh_test::run_cli;
using mbvh_test::TempDir;

namespace {

// The one entry in a cache directory.
std::string entry_in(const std::string& dir) {
  std::string e;
  for (const auto& d : std::filesystem::directory_iterator(dir))
    if (d.path().extension() == ".mbvh") e = d.path().string();
  return e;
}

// Two quads side by side (4 triangles), and a variant with one vertex moved (another scene).
std::string quads_obj(float shift) {
  std::string s = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 2 0 0.5\nv 3 0 0.5\nv 3 1 0.5\nv 2 1 ";
  s += std::to_string(0.5f + shift) + "\nf 1 2 3\nf 1 3 4\nf 5 6 7\nf 5 7 8\n";
  return s;
}

// -- the entry's layout (cache.cpp): header, nodes, leaf boxes, leaves, triangles, checksum
struct Entry {
  std::string b;
  std::uint64_t count(int k) const {  // 0 nodes, 1 leaf boxes, 2 leaves, 3 triangles
    std::uint64_t v;
    std::memcpy(&v, b.data() + 48 + 8 * k, 8);
    return v;
  }
  std::size_t seg(int s) const {  // offset of segment s (0 header .. 4 triangles, 5 checksum)
    const std::size_t sz[4] = {sizeof(Bvh2::Node), sizeof(Box), sizeof(Leaf), sizeof(Tri)};
    std::size_t body = 0;
    for (int k = 0; k < 4; ++k) body += count(k) * sz[k];
    std::size_t off = b.size() - 8 - body;  // the header's size
    if (s == 0) return 0;
    for (int k = 0; k < s - 1; ++k) off += count(k) * sz[k];
    return off;
  }
  Bvh2::Node node(std::size_t i) const {
    Bvh2::Node n;
    std::memcpy(&n, b.data() + seg(1) + i * sizeof n, sizeof n);
    return n;
  }
  void set_node(std::size_t i, const Bvh2::Node& n) { std::memcpy(b.data() + seg(1) + i * sizeof n, &n, sizeof n); }
  Box leaf_box(std::size_t i) const {
    Box x;
    std::memcpy(&x, b.data() + seg(2) + i * sizeof x, sizeof x);
    return x;
  }
  void set_leaf_box(std::size_t i, const Box& x) { std::memcpy(b.data() + seg(2) + i * sizeof x, &x, sizeof x); }
  Tri tri(std::size_t i) const {
    Tri t;
    std::memcpy(&t, b.data() + seg(4) + i * sizeof t, sizeof t);
    return t;
  }
  void set_tri(std::size_t i, const Tri& t) { std::memcpy(b.data() + seg(4) + i * sizeof t, &t, sizeof t); }
  // Recomputes the checksum, as anyone can: the crafted entry passes it.
  void reseal() {
    std::vector<std::pair<std::uint64_t, std::uint64_t>> segs;
    for (int s = 0; s < 5; ++s) segs.push_back({seg(s), seg(s + 1) - seg(s)});
    const std::uint64_t end = b.size() - 8, block = 1u << 20;
    std::vector<std::uint64_t> h((end + block - 1) / block);
    for (std::uint64_t i = 0; i < h.size(); ++i) {
      std::uint64_t sum = i;
      for (const auto& [o, n] : segs) {
        const std::uint64_t lo = std::max(i * block, o), hi = std::min(i * block + block, o + n);
        if (lo < hi) sum = hash_bytes(b.data() + lo, hi - lo, sum);
      }
      h[i] = sum;
    }
    const std::uint64_t sum = hash_bytes(h.data(), h.size() * 8);
    std::memcpy(b.data() + end, &sum, 8);
  }
};

std::vector<Hit> trace_all(const Accel& acc, const std::vector<Ray>& rays, Layout layout) {
  auto backend = make_backend("cpu-scalar");
  TraceOutput out;
  backend->trace(acc, rays, TraceOptions{layout, Traversal::stack}, out);
  return out.hits;
}

}  // namespace

// -- 1. no write (or read) through a link at an entry's name

TEST_CASE("cache: a symbolic link at the entry's name is replaced, never followed", "[reliability][cache-safety][cli]") {
  TempDir dir;
  const std::string scene = dir.write("victim.obj", quads_obj(0)), cache = dir.file("c"), rays = dir.file("r.rays");
  REQUIRE(run_cli("rays " + scene + " --count 500 -o " + rays).code == 0);
  REQUIRE(run_cli("trace " + scene + " --rays " + rays + " -o " + dir.file("want.hits")).code == 0);
  auto r = run_cli("trace " + scene + " --count 10 --cache " + cache + " -o " + dir.file("x.hits"));
  REQUIRE(r.code == 0);
  const std::string entry = entry_in(cache);
  REQUIRE_FALSE(entry.empty());
  const std::string scene_bytes = bytes_of(scene), ray_bytes = bytes_of(rays);
  for (const std::string& victim : {scene, rays}) {
    INFO("link to " << victim);
    std::filesystem::remove(entry);
    std::filesystem::create_symlink(victim, entry);
    r = run_cli("trace " + scene + " --rays " + rays + " --cache " + cache + " -o " + dir.file("got.hits"));
    INFO(r.output);
    CHECK(r.code == 0);
    CHECK_THAT(r.output, Catch::Contains("symbolic link") && Catch::Contains(entry));
    CHECK((bytes_of(scene) == scene_bytes));  // the targets untouched
    CHECK((bytes_of(rays) == ray_bytes));
    CHECK_FALSE(std::filesystem::is_symlink(entry));  // the link is replaced by the entry
    CHECK(std::filesystem::is_regular_file(entry));
    CHECK((bytes_of(dir.file("got.hits")) == bytes_of(dir.file("want.hits"))));
  }
}

TEST_CASE("cache: Accel::load refuses a link; the writer replaces a link it does not follow", "[reliability][cache-safety]") {
  TempDir dir;
  const Scene s = load_scene("gen:soup:300:1");
  Accel::CacheReport rep;
  Accel::build_cached(s, {}, dir.file("c"), &rep);
  const std::string victim = dir.write("victim", "precious");
  const std::string good = bytes_of(rep.path);
  std::filesystem::remove(rep.path);
  put(dir.file("real.mbvh"), good);
  std::filesystem::create_symlink(dir.file("real.mbvh"), rep.path);
  CHECK_THROWS_WITH(Accel::load(rep.path, Accel::cache_key(s, {})), Catch::Contains("symbolic link"));
  std::filesystem::remove(rep.path);
  std::filesystem::create_symlink(victim, rep.path);
  Accel::CacheReport again;
  Accel::build_cached(s, {}, dir.file("c"), &again);
  CHECK_FALSE(again.loaded);
  CHECK_THAT(again.problem, Catch::Contains("symbolic link"));
  CHECK((bytes_of(victim) == "precious"));
  CHECK((bytes_of(rep.path) == good));
}

// -- 2. the entry is none of the command's files

TEST_CASE("cache: an entry that is an input or an output of the command is an error before any work",
          "[reliability][cache-safety][cli]") {
  TempDir dir;
  const std::string scene = dir.write("s.obj", quads_obj(0)), cache = dir.file("c"), rays = dir.file("r.rays");
  REQUIRE(run_cli("rays " + scene + " --count 200 -o " + rays).code == 0);
  REQUIRE(run_cli("trace " + scene + " --count 10 --cache " + cache + " -o " + dir.file("x.hits")).code == 0);
  const std::string entry = entry_in(cache);
  REQUIRE_FALSE(entry.empty());
  SECTION("-o names the entry the run reads") {
    const std::string before = bytes_of(entry);
    const auto r = run_cli("trace " + scene + " --rays " + rays + " --cache " + cache + " -o " + entry);
    INFO(r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains(entry) && Catch::Contains("BVH cache entry"));
    CHECK((bytes_of(entry) == before));
  }
  SECTION("the entry is a hard link to --rays") {
    std::filesystem::remove(entry);
    std::filesystem::create_hard_link(rays, entry);
    const std::string before = bytes_of(rays);
    const auto r = run_cli("trace " + scene + " --rays " + rays + " --cache " + cache + " -o " + dir.file("h.hits"));
    INFO(r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains(entry) && Catch::Contains(rays));
    CHECK((bytes_of(rays) == before));
    CHECK_FALSE(std::filesystem::exists(dir.file("h.hits")));
  }
}

// -- 3. a crafted entry with a valid checksum: detected, rebuilt, the right answers

TEST_CASE("cache: a crafted entry whose root's first child is empty is rebuilt, not traced (was SIGSEGV)",
          "[reliability][cache-safety][cli]") {
  TempDir dir;
  const std::string scene = dir.write("q.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n"), cache = dir.file("c");
  REQUIRE(run_cli("trace " + scene + " --count 500 -o " + dir.file("want.hits")).code == 0);
  REQUIRE(run_cli("trace " + scene + " --count 10 --cache " + cache + " -o " + dir.file("x.hits")).code == 0);
  const std::string path = entry_in(cache);
  Entry e{bytes_of(path)};
  REQUIRE(e.count(0) == 1);  // one triangle: a one-leaf root
  Bvh2::Node root = e.node(0);
  REQUIRE(root.child[1] == MBVH_EMPTY);
  std::swap(root.child[0], root.child[1]);
  e.set_node(0, root);
  e.reseal();
  put(path, e.b);
  for (const char* layout : {"mbvh4", "mbvh8", "mbvh2"}) {
    INFO(layout);
    const auto r = run_cli(std::string("trace ") + scene + " --count 500 --layout " + layout + " --cache " + cache + " -o " +
                           dir.file("got.hits"));
    INFO(r.output);
    REQUIRE(r.code == 0);
    CHECK((bytes_of(dir.file("got.hits")) == bytes_of(dir.file("want.hits"))));
    put(path, e.b);  // crafted again for the next layout
  }
  const auto r = run_cli("trace " + scene + " --count 10 --cache " + cache + " -o " + dir.file("y.hits"));
  CHECK_THAT(r.output, Catch::Contains("warning") && Catch::Contains(path) && Catch::Contains("empty"));
}

TEST_CASE("cache: two different scenes on one key: the second is never traced from the first's BVH",
          "[reliability][cache-safety][cli]") {
  TempDir dir;
  const std::string a = dir.write("a.obj", quads_obj(0)), b = dir.write("b.obj", quads_obj(0.25f));
  const std::string ca = dir.file("ca"), cb = dir.file("cb");
  REQUIRE(run_cli("trace " + a + " --count 10 --cache " + ca + " -o " + dir.file("x.hits")).code == 0);
  REQUIRE(run_cli("trace " + b + " --count 10 --cache " + cb + " -o " + dir.file("x.hits")).code == 0);
  const std::string ea = entry_in(ca), eb = entry_in(cb);
  // the collision: A's entry under B's key (the key field rewritten, the checksum recomputed)
  Entry e{bytes_of(ea)};
  const std::string bb = bytes_of(eb);
  std::memcpy(e.b.data() + 32, bb.data() + 32, 8);
  e.reseal();
  put(eb, e.b);
  REQUIRE(run_cli("trace " + b + " --count 2000 --kind random -o " + dir.file("want.hits")).code == 0);
  const auto r = run_cli("trace " + b + " --count 2000 --kind random --cache " + cb + " -o " + dir.file("got.hits"));
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("warning") && Catch::Contains("not the scene's triangle"));
  CHECK((bytes_of(dir.file("got.hits")) == bytes_of(dir.file("want.hits"))));
}

TEST_CASE("cache: crafted entries with valid checksums are named, rebuilt and never traced", "[reliability][cache-safety]") {
  TempDir dir;
  const Scene s = load_scene("gen:soup:3000:7");
  BuildOptions opt;
  opt.threads = 2;
  Accel::CacheReport first;
  const auto built = Accel::build_cached(s, opt, dir.file("c"), &first);
  const std::string good = bytes_of(first.path);
  RayGenOptions ro;
  ro.count = 3000;
  ro.kind = RayKind::random;
  const std::vector<Ray> rays = generate_rays(s, *built, ro);
  const std::vector<Hit> want = trace_all(*built, rays, Layout::mbvh4);

  struct Craft {
    const char* name;
    const char* says;
    std::function<void(Entry&)> apply;
  };
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const std::vector<Craft> crafts = {
      {"a moved triangle", "not the scene's triangle",
       [](Entry& e) {
         Tri t = e.tri(5);
         for (int k = 0; k < 3; ++k) t.v0[k] = 0.5f * (t.v0[k] + t.v1[k]);
         e.set_tri(5, t);
       }},
      {"a shrunk leaf box", "outside the box",
       [](Entry& e) {
         Box x = e.leaf_box(3);
         x.hi.x = x.lo.x;
         e.set_leaf_box(3, x);
       }},
      {"a NaN coordinate", "not the scene's triangle",
       [nan](Entry& e) {
         Tri t = e.tri(7);
         t.v1[1] = nan;
         e.set_tri(7, t);
       }},
      {"a 1e30 coordinate", "not the scene's triangle",
       [](Entry& e) {
         Tri t = e.tri(9);
         t.v2[2] = 1e30f;
         e.set_tri(9, t);
       }},
      {"a NaN box", "box",
       [nan](Entry& e) {
         Bvh2::Node n = e.node(1);
         n.box.lo.y = nan;
         e.set_node(1, n);
       }},
      {"a bad parent link", "parent link",
       [](Entry& e) {
         Bvh2::Node n = e.node(4);
         n.parent = 2;
         e.set_node(4, n);
       }},
      {"a wrong height", "height",
       [](Entry& e) {
         Bvh2::Node n = e.node(0);
         n.height += 1;
         e.set_node(0, n);
       }},
      {"two leaves sharing triangles", "leaf",
       [](Entry& e) {
         Leaf l;
         std::memcpy(&l, e.b.data() + e.seg(3) + 8, 8);  // leaf 1 takes leaf 0's range
         std::memcpy(e.b.data() + e.seg(3) + 8, e.b.data() + e.seg(3), 8);
       }},
  };
  for (const Craft& c : crafts) {
    INFO(c.name);
    Entry e{good};
    c.apply(e);
    e.reseal();
    put(first.path, e.b);
    Accel::CacheReport r;
    const auto acc = Accel::build_cached(s, opt, dir.file("c"), &r);
    CHECK_FALSE(r.loaded);
    CHECK_THAT(r.problem, Catch::Contains(first.path) && Catch::Contains(c.says));
    CHECK(acc->hash() == built->hash());
    for (Layout l : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) {
      const std::vector<Hit> got = trace_all(*acc, rays, l);
      REQUIRE(got.size() == want.size());
      CHECK(std::memcmp(got.data(), want.data(), got.size() * sizeof(Hit)) == 0);
    }
    CHECK((bytes_of(first.path) == good));  // replaced by the build's own entry
  }
}

TEST_CASE("cache: builds of every quality load back as checked entries", "[reliability][cache-safety]") {
  TempDir dir;
  for (const char* spec : {"gen:soup:1:1", "gen:soup:2:2", "gen:soup:9:3", "gen:soup:5000:4", "gen:hairball:3000"})
    for (BuildQuality q : {BuildQuality::low, BuildQuality::medium, BuildQuality::high}) {
      INFO(spec << " " << to_string(q));
      const Scene s = load_scene(spec);
      BuildOptions opt;
      opt.quality = q;
      Accel::CacheReport a, b;
      const auto built = Accel::build_cached(s, opt, dir.file("c"), &a);
      const auto loaded = Accel::build_cached(s, opt, dir.file("c"), &b);
      CHECK(b.loaded);
      CHECK(b.problem.empty());
      CHECK(loaded->hash() == built->hash());
      CHECK(std::memcmp(&loaded->bounds(), &built->bounds(), sizeof(Box)) == 0);
      CHECK(loaded->binary_stats().sah_cost == built->binary_stats().sah_cost);
    }
}

TEST_CASE("cache: a damaged entry in a directory that cannot be written says it was damaged",
          "[reliability][cache-safety]") {
  if (::geteuid() == 0) return;  // root writes into read-only directories: nothing to test
  TempDir dir;
  const Scene s = load_scene("gen:soup:300:1");
  Accel::CacheReport rep;
  Accel::build_cached(s, {}, dir.file("c"), &rep);
  std::string b = bytes_of(rep.path);
  b[b.size() / 2] ^= 1;
  put(rep.path, b);
  ::chmod(dir.file("c").c_str(), 0555);
  CHECK_THROWS_WITH(Accel::build_cached(s, {}, dir.file("c")),
                    Catch::Contains("checksum") && Catch::Contains("cannot be replaced"));
  ::chmod(dir.file("c").c_str(), 0755);
}

// -- 4. concurrent writers of one entry

TEST_CASE("cache: concurrent runs sharing one --cache directory all succeed", "[reliability][cache-safety][cli]") {
  TempDir dir;
  for (int round = 0; round < 8; ++round) {
    const std::string cache = dir.file("c" + std::to_string(round));
    std::string cmd;
    for (int k = 0; k < 4; ++k)
      cmd += "( " + mbvh_test::cli_path() + " trace gen:soup:20000:3 --threads 1 --count 100 --cache " + cache + " -o " +
             dir.file("h" + std::to_string(round) + "_" + std::to_string(k)) + " >/dev/null 2>" +
             dir.file("e" + std::to_string(k)) + " || echo FAILED $(cat " + dir.file("e" + std::to_string(k)) + ") ) & ";
    const auto r = mbvh_test::run_shell(cmd + "wait");
    INFO("round " << round << ": " << r.output);
    CHECK(r.output.find("FAILED") == std::string::npos);
  }
}

// -- 5. sizes checked before anything is allocated; the library's own words

TEST_CASE("cache: an entry's counts are bounded by the scene before anything is allocated", "[reliability][cache-safety]") {
  TempDir dir;
  const Scene s = load_scene("gen:soup:300:1");
  Accel::CacheReport rep;
  Accel::build_cached(s, {}, dir.file("c"), &rep);
  Entry e{bytes_of(rep.path)};
  // a sparse gigabyte whose header claims it all as triangle records: refused by the counts
  const std::uint64_t tris = (std::uint64_t(1) << 30) / sizeof(Tri);
  std::memcpy(e.b.data() + 72, &tris, 8);
  put(rep.path, e.b.substr(0, e.seg(1)));
  REQUIRE(::truncate(rep.path.c_str(), off_t(1) << 30) == 0);
  Accel::CacheReport r;
  Accel::build_cached(s, {}, dir.file("c"), &r);
  CHECK_FALSE(r.loaded);
  CHECK_THAT(r.problem, Catch::Contains("do not fit a scene of 300 triangles"));
  CHECK(std::filesystem::file_size(rep.path) < (std::uint64_t(1) << 20));  // replaced
}

TEST_CASE("cache: library messages name the cache directory, not a CLI option", "[reliability][cache-safety]") {
  TempDir dir;
  const std::string file = dir.write("f", "x");
  const Scene s = load_scene("gen:soup:30:1");
  CHECK_THROWS_WITH(Accel::build_cached(s, {}, file), Catch::StartsWith("BVH cache directory " + file));
}

TEST_CASE("cache: build-bench refuses --cache", "[reliability][cache-safety][cli]") {
  const auto r = run_cli("build-bench gen:soup:100:1 --cache /tmp/nowhere-mbvh");
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--cache") && Catch::Contains("build-bench"));
}

// Issue 30, "an optional size bound with eviction": CacheOptions::max_bytes / --cache-max-size.
TEST_CASE("cache: a size bound removes the least recently used entries - a hit counts as a use - nothing else in the directory",
          "[reliability][cache-safety]") {
  TempDir dir, outside;
  const std::string cache = dir.file("c");
  std::filesystem::create_directories(cache);
  // what the bound must never count or remove: a user's file, an entry-like name in upper case, a
  // link named as an entry (to a file outside)
  const std::string victim = outside.write("victim.txt", "keep me");
  put(cache + "/notes.txt", std::string(1 << 16, 'n'));
  put(cache + "/ABCDEF0123456789.mbvh", std::string(1 << 16, 'u'));
  REQUIRE(::symlink(victim.c_str(), (cache + "/0123456789abcdef.mbvh").c_str()) == 0);
  const Scene a = load_scene("gen:sphere:12"), b = load_scene("gen:sphere:14"), c = load_scene("gen:sphere:16"),
              d = load_scene("gen:sphere:18");
  const auto path_of = [&](const Scene& s) {
    Accel::CacheReport r;
    Accel::build_cached(s, {}, Accel::CacheOptions{cache, {}, 0}, &r);
    return r.path;
  };
  const std::string pa = path_of(a), pb = path_of(b), pc = path_of(c);
  // a oldest, then b, then c; a hit on a makes it the most recent
  const auto age = [](const std::string& p, int seconds_ago) {
    const auto t = std::filesystem::file_time_type::clock::now() - std::chrono::seconds(seconds_ago);
    std::filesystem::last_write_time(p, t);
  };
  age(pa, 400), age(pb, 300), age(pc, 200);
  Accel::CacheReport ra;
  Accel::build_cached(a, {}, Accel::CacheOptions{cache, {}, 0}, &ra);
  REQUIRE(ra.loaded);
  const auto size = [](const std::string& p) { return std::filesystem::file_size(p); };
  // d written under a bound that holds a, c and d: b, now the least recently used, goes
  Accel::CacheReport rd;
  const auto sa = size(pa), sb = size(pb), sc = size(pc);
  const std::uint64_t bound = sa + sc + 2 * sc;  // d (sphere 18) is below 2x c's size
  const auto acc = Accel::build_cached(d, {}, Accel::CacheOptions{cache, {}, bound}, &rd);
  INFO("sizes " << sa << " " << sb << " " << sc << " " << size(rd.path) << ", bound " << bound);
  REQUIRE(size(rd.path) < 2 * sc);
  CHECK(rd.evicted == 1);
  CHECK(rd.evicted_bytes == sb);
  CHECK_FALSE(std::filesystem::exists(pb));
  CHECK(std::filesystem::exists(pa));
  CHECK(std::filesystem::exists(pc));
  CHECK(std::filesystem::exists(rd.path));
  CHECK(bytes_of(victim) == "keep me");
  CHECK(std::filesystem::is_symlink(cache + "/0123456789abcdef.mbvh"));
  CHECK(std::filesystem::file_size(cache + "/notes.txt") == (1u << 16));
  CHECK(std::filesystem::file_size(cache + "/ABCDEF0123456789.mbvh") == (1u << 16));
  // a bound below one entry keeps only the entry just used
  Accel::CacheReport r1;
  Accel::build_cached(c, {}, Accel::CacheOptions{cache, {}, 1}, &r1);
  CHECK(r1.loaded);
  CHECK(r1.evicted == 2);
  CHECK(std::filesystem::exists(pc));
  CHECK_FALSE(std::filesystem::exists(pa));
  CHECK_FALSE(std::filesystem::exists(rd.path));
  CHECK(bytes_of(victim) == "keep me");
}

TEST_CASE("cache: --cache-max-size bounds the directory; a bad size or one without --cache exits 2 naming it",
          "[reliability][cache-safety][cli]") {
  TempDir dir;
  const std::string cache = dir.file("c");
  for (const char* spec : {"gen:sphere:12", "gen:sphere:14"}) {
    const auto r = run_cli(std::string("info ") + spec + " --cache " + cache);
    REQUIRE(r.code == 0);
  }
  const auto r = run_cli("info gen:sphere:16 --cache " + cache + " --cache-max-size 1K");
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("removed 2 least recently used entries") && Catch::Contains("--cache-max-size 1K"));
  std::size_t entries = 0;
  for (const auto& e : std::filesystem::directory_iterator(cache)) entries += e.path().extension() == ".mbvh";
  CHECK(entries == 1);
  const auto bad = run_cli("info gen:sphere:16 --cache " + cache + " --cache-max-size 12Q");
  CHECK(bad.code == 2);
  CHECK_THAT(bad.output, Catch::Contains("'12Q' is not a size"));
  const auto alone = run_cli("info gen:sphere:16 --cache-max-size 1G");
  CHECK(alone.code == 2);
  CHECK_THAT(alone.output, Catch::Contains("--cache-max-size") && Catch::Contains("--cache"));
}

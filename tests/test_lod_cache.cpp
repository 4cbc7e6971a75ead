// SPDX-License-Identifier: MIT
// test_lod_cache.cpp — the block cache of .mlod models (host/core/lod/cache.h) on synthetic files
// written from format.h (tests/lod_fixture.h): what opening refuses (each message naming the
// field), damaged blocks (recorded, never resident, thrown at full detail), the budget (peak <=
// budget over many frames of random requests from several threads, LRU eviction that never drops
// a pinned block or one with a resident child), the minimum budget, asynchronous and synchronous
// loading, the bandwidth cap, and `mbvh lod info`.
#include <catch2/catch.hpp>

#include <atomic>
#include <chrono>
#include <cstdlib>
#include <random>
#include <thread>

#include "host/core/lod/cache.h"
#include "mbvh/lod.h"
#include "mbvh/error.h"
#include "tests/helpers.h"
#include "tests/lod_fixture.h"

using namespace mbvh;
using namespace mbvh::lod;
using namespace mbvh::lod::format;
using mbvh_test::error_of;
using mbvh_test::TempDir;

namespace {

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

std::string write_model(const TempDir& dir, const std::string& name, const mbvh_test::SynthOptions& o = {}) {
  return dir.write(name, mbvh_test::make_mlod(o).bytes);
}

mbvh_test::SynthOptions tree(unsigned fan, unsigned levels) {
  mbvh_test::SynthOptions o;
  o.parent = mbvh_test::block_tree(fan, levels);
  return o;
}

CacheOptions budgeted(std::uint64_t budget, bool sync = false) {
  CacheOptions c;
  c.memory_budget = budget;
  c.synchronous = sync;
  c.io_threads = 2;
  return c;
}

/// get() down the chain root -> b, as a traversal reaches b: stops at the first block not resident
/// (requested then). Returns whether b was resident.
bool walk_to(BlockCache& c, std::uint32_t b) {
  std::vector<std::uint32_t> chain;
  for (std::uint32_t x = b;; x = c.directory()[x].parent_block) {
    chain.push_back(x);
    if (x == c.header().root_block) break;
  }
  for (auto it = chain.rbegin(); it != chain.rend(); ++it)
    if (!c.get(*it)) return false;
  return true;
}

/// The cache's rules, seen from outside: pinned blocks resident, every resident block's parent
/// resident, the bytes within the budget and equal to the resident blocks' sum.
void require_rules(const BlockCache& c) {
  const auto& dir = c.directory();
  std::uint64_t bytes = 0, blocks = 0;
  for (std::uint32_t b = 0; b < dir.size(); ++b) {
    if (dir[b].flags & kDirPinned) REQUIRE(c.resident(b));
    if (!c.resident(b)) continue;
    bytes += dir[b].raw_bytes, ++blocks;
    if (b != c.header().root_block) REQUIRE(c.resident(dir[b].parent_block));
  }
  const CacheStats s = c.stats();
  REQUIRE(s.peak_bytes <= s.budget);
  REQUIRE(s.resident_bytes <= s.budget);
  REQUIRE(s.resident_bytes == bytes);
  REQUIRE(s.resident_blocks == blocks);
}

}  // namespace

TEST_CASE("lod cache: a valid model opens, its pinned blocks resident and checked", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(3, 2);
  o.pin_depth = 1;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const std::string path = dir.write("m.mlod", m.bytes);
  BlockCache c(path, {});
  CHECK(c.directory().size() == 13);
  CHECK(c.albedos().size() == 2);
  CHECK(c.budget() == m.header.raw_bytes);
  const CacheStats s = c.stats();
  CHECK(s.pinned_bytes == m.header.pinned_bytes);
  CHECK(s.resident_blocks == 4);  // the root and its 3 children
  CHECK(s.peak_bytes == s.pinned_bytes);
  CHECK(s.loads == 0);
  CHECK(s.bytes_read >= m.header.pinned_blocks);
  for (std::uint32_t b = 0; b < 13; ++b) CHECK(c.resident(b) == (b < 4));
  const std::byte* root = c.get(0);
  REQUIRE(root);
  CHECK(std::memcmp(root, m.raw[0].data(), m.raw[0].size()) == 0);
  CHECK((std::string(c.io_mode()) == "O_DIRECT" || std::string(c.io_mode()) == "posix_fadvise(DONTNEED)"));
  CacheOptions cached;
  cached.direct_io = false;
  CHECK(std::string(BlockCache(path, cached).io_mode()) == "page cache");

  const ModelFile f = read_model_file(path);
  CHECK(std::memcmp(&f.header, &m.header, sizeof f.header) == 0);
  CHECK(f.directory.size() == 13);
  const ModelInfo i = model_info(path, f.header);
  CHECK(i.blocks == 13);
  CHECK(i.pinned_blocks == 4);
  CHECK(i.triangles == m.header.triangles);
  CHECK(minimum_budget(f.header) == std::min<std::uint64_t>(m.header.pinned_bytes + 2 * m.header.block_bytes, m.header.raw_bytes));
}

TEST_CASE("lod cache: opening refuses a damaged, truncated or extended file, naming the field", "[lod]") {
  TempDir dir;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(tree(2, 2));
  const std::string good = m.bytes;
  const auto refused = [&](const std::string& bytes) {
    const std::string path = dir.write("bad.mlod", bytes);
    const std::string a = error_of([&] { BlockCache(path, {}); });
    const std::string b = error_of([&] { read_model_file(path); });
    CHECK(a == b);  // lod info reads what the cache reads
    CHECK(has(a, path));
    return a;
  };
  CHECK(has(refused(good.substr(0, good.size() - 100)), "file_bytes"));
  CHECK(has(refused(good.substr(0, good.size() - 100)), "truncated"));
  CHECK(has(refused(good + "x"), "bytes after the end"));
  CHECK(has(refused(good.substr(0, 100)), "truncated"));
  CHECK(has(refused(""), "truncated"));
  std::string s = good;
  s[0] ^= 1;
  CHECK(has(refused(s), "magic"));
  s = good;
  s[offsetof(FileHeader, version)] ^= 4;
  CHECK(has(refused(s), "version"));
  s = good;
  s[offsetof(FileHeader, nodes)] ^= 1;  // any other header byte: the header's checksum
  CHECK(has(refused(s), "checksum"));
  s = good;
  s[offsetof(FileHeader, checksum) + 3] ^= 0x10;
  CHECK(has(refused(s), "checksum"));
  s = good;
  s[kHeaderBytes - 1] ^= 1;  // the header's zero padding
  CHECK(has(refused(s), "header padding"));
  s = good;
  s[m.header.directory_offset + 5] ^= 2;
  CHECK(has(refused(s), "directory: its checksum"));
  s = good;
  s[m.header.file_bytes - 1] ^= 2;  // the directory's checksum itself
  CHECK(has(refused(s), "directory: its checksum"));
  s = good;
  s[kHeaderBytes + 1] ^= 1;
  CHECK(has(refused(s), "albedo table"));
}

TEST_CASE("lod cache: opening refuses inconsistent fields (with valid checksums), before allocating", "[lod]") {
  TempDir dir;
  const auto refused = [&](std::function<void(FileHeader&, std::vector<DirEntry>&)> tamper) {
    mbvh_test::SynthOptions o = tree(2, 2);
    o.tamper = std::move(tamper);
    const std::string path = write_model(dir, "bad.mlod", o);
    const std::string e = error_of([&] { BlockCache(path, {}); });
    CHECK(has(e, path));
    return e;
  };
  CHECK(has(refused([](FileHeader& h, auto&) { h.node_bytes = 72; }), "node_bytes: 72"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.tri_bytes = 36; }), "tri_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.header_bytes = 512; }), "header_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.codec = 2; }), "codec"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.blocks = 1ull << 60; }), "blocks"));  // refused, not allocated
  CHECK(has(refused([](FileHeader& h, auto&) { h.albedos = 0xffffffffu; }), "albedos"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.block_bytes = 0xffffffffu; }), "block_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.root_block = 99; }), "root_block"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.directory_offset += 8; }), "directory_offset"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.directory_bytes += 32; }), "directory_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.raw_bytes += 1; }), "raw_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.pinned_bytes += 1; }), "pinned_bytes"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.tri_records = h.triangles + 1; }), "tri_records"));
  CHECK(has(refused([](FileHeader& h, auto&) { h.bounds[0] = NAN; }), "bounds"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].offset += 16; }), "directory entry 3: offset"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].offset = 1ull << 50; }), "directory entry 3: offset"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].stored_bytes = 0; }), "directory entry 3: offset"));
  CHECK(has(refused([](FileHeader& h, std::vector<DirEntry>& d) { d[3].raw_bytes = h.block_bytes + 1; }),
            "directory entry 3: raw_bytes"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].parent_block = 1000; }), "directory entry 3: parent_block"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].parent_block = 4; }), "not above"));  // 4 is at depth 2 too
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].depth = 0; }), "directory entry 3: depth"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[0].flags = 0; }), "the root block must be"));
  CHECK(has(refused([](auto&, std::vector<DirEntry>& d) { d[3].flags = 4; }), "flags"));
  CHECK(has(refused([](FileHeader& h, std::vector<DirEntry>& d) {  // a pinned block under an unpinned one
          d[3].flags = kDirPinned;
          ++h.pinned_blocks;
          h.pinned_bytes += d[3].raw_bytes;
        }),
        "its parent block 1 is not"));
}

TEST_CASE("lod cache: a damaged block is recorded, never resident, and named at full detail", "[lod]") {
  TempDir dir;
  mbvh_test::SynthModel m = mbvh_test::make_mlod(tree(2, 2));  // 0; 1 2; 3 4 5 6
  std::string s = m.bytes;
  s[m.directory[1].offset + m.directory[1].stored_bytes / 2] ^= 0x40;  // inside block 1's compressed bytes
  const std::string path = dir.write("m.mlod", s);
  {
    BlockCache c(path, budgeted(0));  // opens: the damage is found when block 1 is loaded
    CHECK(!c.get(1));
    CHECK(!c.get(2));
    CHECK(c.fetch_requested(false));
    CHECK(c.damaged() == std::vector<std::uint32_t>{1});
    CHECK(has(c.damage(1), "block 1"));
    CHECK(has(c.damage(1), "damaged"));
    CHECK(c.damage(2).empty());
    CHECK(!c.resident(1));
    CHECK(c.resident(2));
    CHECK(!c.get(1));  // not requested again ...
    CHECK(c.stats().pending == 0);
    const std::string e = error_of([&] { c.fetch_requested(true); });  // ... but named at full detail
    CHECK(has(e, path));
    CHECK(has(e, "block 1"));
    require_rules(c);
  }
  {
    BlockCache c(path, budgeted(0));
    CHECK(!c.get(1));
    const std::string e = error_of([&] { c.fetch_requested(true); });
    CHECK(has(e, "block 1 (depth 1"));
    CHECK(!c.resident(1));
  }
  {  // asynchronously: the same record
    BlockCache c(path, budgeted(0));
    CHECK(!c.get(1));
    c.end_frame();
    c.wait_idle();
    CHECK(c.damaged() == std::vector<std::uint32_t>{1});
    CHECK(!c.resident(1));
  }
  // a pinned block damaged: the file does not open
  s = m.bytes;
  s[m.directory[0].offset + 3] ^= 0x01;
  CHECK(has(error_of([&] { BlockCache(dir.write("p.mlod", s), {}); }), "block 0"));
}

TEST_CASE("lod cache: a block with a valid checksum but a broken structure is damaged (check_block)", "[lod]") {
  TempDir dir;
  const auto damage_of = [&](std::function<void(std::string&)> edit) {
    mbvh_test::SynthOptions o = tree(2, 1);
    o.tamper_block = [&](std::uint32_t b, std::string& raw) {
      if (b == 1) edit(raw);
    };
    BlockCache c(write_model(dir, "m.mlod", o), budgeted(0));
    CHECK(!c.get(1));
    c.fetch_requested(false);
    CHECK(!c.resident(1));
    return c.damage(1);
  };
  const auto head = [](std::string& raw) -> BlockHead* { return reinterpret_cast<BlockHead*>(raw.data()); };
  const auto node = [](std::string& raw, std::size_t i) -> Node* {
    return reinterpret_cast<Node*>(raw.data() + sizeof(BlockHead) + i * sizeof(Node));
  };
  CHECK(has(damage_of([&](std::string& r) { head(r)->magic = 0; }), "magic"));
  CHECK(has(damage_of([&](std::string& r) { head(r)->index = 2; }), "index"));
  CHECK(has(damage_of([&](std::string& r) { head(r)->treelets = 0; }), "treelets"));
  CHECK(has(damage_of([&](std::string& r) { head(r)->tris += 1; }), "size"));
  // A leaf past the block's triangles; an inner reference to itself (a cycle); one node twice (a DAG).
  CHECK(has(damage_of([&](std::string& r) { node(r, 1)->aux[1] = 1000; }), "leaf"));
  CHECK(has(damage_of([&](std::string& r) { node(r, 0)->ref[1] = kRefInner | 0; }), "not a treelet root"));
  CHECK(has(damage_of([&](std::string& r) {
          Node* n = node(r, 1);
          n->ref[0] = n->ref[1] = kRefInner | 1;
        }),
        "node 1: child 0: node 1 is referenced twice"));
  CHECK(has(damage_of([&](std::string& r) { node(r, 0)->lo[1][0] = NAN; }), "box"));
  CHECK(has(damage_of([&](std::string& r) { node(r, 0)->aux[1] = 7; }), "voxel 7"));
  // Block 1 is a leaf block (no links); a triangle with a prim id beyond the model's.
  CHECK(has(damage_of([&](std::string& r) {
          const std::uint32_t big = 1u << 30;
          std::memcpy(r.data() + block_layout(*head(r)).tris + 12, &big, 4);
        }),
        "prim id"));
  // A link in the root block to a treelet root block 1 does not have.
  {
    mbvh_test::SynthOptions o = tree(2, 1);
    o.tamper_block = [](std::uint32_t b, std::string& raw) {
      if (b != 0) return;
      BlockHead h;
      std::memcpy(&h, raw.data(), sizeof h);
      Link k{1, 5};
      std::memcpy(raw.data() + block_layout(h).links, &k, sizeof k);
    };
    BlockCache c(write_model(dir, "l.mlod", o), budgeted(0));
    CHECK(!c.get(1));
    CHECK(!c.get(2));
    c.fetch_requested(false);
    CHECK(has(c.damage(1), "names node 5 of block 1"));
    CHECK(c.resident(2));
  }
  // The root block's links must name its child blocks.
  {
    mbvh_test::SynthOptions o = tree(2, 2);
    o.tamper_block = [](std::uint32_t b, std::string& raw) {
      if (b != 0) return;
      BlockHead h;
      std::memcpy(&h, raw.data(), sizeof h);
      Link k{3, 0};  // a grandchild
      std::memcpy(raw.data() + block_layout(h).links, &k, sizeof k);
    };
    CHECK(has(error_of([&] { BlockCache(write_model(dir, "g.mlod", o), {}); }), "link 0: block 3 is not a child block"));
  }
}

TEST_CASE("lod cache: the minimum budget is refused below, named in bytes and MiB", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(4, 2);
  o.tris_per_leaf = 20;
  o.block_bytes = 8 << 10;  // the builder's cap, above every block here
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const std::string path = dir.write("m.mlod", m.bytes);
  const std::uint64_t minimum = m.header.pinned_bytes + 2 * (8 << 10);
  REQUIRE(minimum < m.header.raw_bytes);
  const std::string e = error_of([&] { BlockCache(path, budgeted(minimum - 1)); });
  CHECK(has(e, path));
  CHECK(has(e, std::to_string(minimum) + " bytes"));
  CHECK(has(e, "MiB"));
  CHECK_NOTHROW(BlockCache(path, budgeted(minimum)));
  // A model whose blocks all fit in less: its raw bytes are the minimum.
  const mbvh_test::SynthModel small = mbvh_test::make_mlod(tree(1, 1));
  CHECK(minimum_budget(small.header) == std::min<std::uint64_t>(small.header.raw_bytes, small.header.pinned_bytes + 2 * small.header.block_bytes));
  CHECK_NOTHROW(BlockCache(dir.write("s.mlod", small.bytes), budgeted(small.header.raw_bytes)));
}

TEST_CASE("lod cache: asynchronous loads land after end_frame + wait_idle; synchronous ones at end_frame", "[lod]") {
  TempDir dir;
  const std::string path = write_model(dir, "m.mlod", tree(3, 2));  // 0; 1..3; 4..12
  {
    BlockCache c(path, budgeted(0));
    for (std::uint32_t b = 1; b <= 3; ++b) CHECK(!c.get(b));
    CHECK(!c.get(1));  // deduplicated
    CHECK(c.stats().misses == 4);
    CHECK(c.stats().pending == 3);
    c.end_frame();
    c.wait_idle();
    for (std::uint32_t b = 1; b <= 3; ++b) CHECK(c.resident(b));
    CHECK(c.stats().loads == 3);
    CHECK(c.stats().pending == 0);
    for (std::uint32_t b = 4; b <= 12; ++b) CHECK(!c.get(b));
    c.end_frame();
    c.wait_idle();
    for (std::uint32_t b = 4; b <= 12; ++b) CHECK(c.resident(b));
    require_rules(c);
  }
  {
    BlockCache c(path, budgeted(0, true));
    CHECK(!c.get(2));
    c.end_frame();  // synchronous: loaded now
    CHECK(c.resident(2));
    CHECK(c.get(2));
    CHECK(c.stats().pending == 0);
  }
  {  // a block whose parent is not resident is dropped (the parent comes first) and asked again later
    BlockCache c(path, budgeted(0));
    CHECK(!c.get(4));  // its parent 1 is not resident
    CHECK(!c.fetch_requested(false));
    CHECK(!c.resident(4));
    CHECK(walk_to(c, 4) == false);  // requests 1
    CHECK(c.fetch_requested(false));
    CHECK(walk_to(c, 4) == false);  // now requests 4
    CHECK(c.fetch_requested(false));
    CHECK(walk_to(c, 4));
    require_rules(c);
  }
}

TEST_CASE("lod cache: the budget holds over many frames of random requests from several threads", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(4, 3);  // 85 blocks
  o.tris_per_leaf = 20;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const std::string path = dir.write("m.mlod", m.bytes);
  const std::uint32_t n = static_cast<std::uint32_t>(m.directory.size());
  for (const bool sync : {false, true}) {
    INFO((sync ? "synchronous" : "asynchronous"));
    const std::uint64_t budget = minimum_budget(m.header) + 6 * m.header.block_bytes;
    REQUIRE(budget < m.header.raw_bytes / 3);
    BlockCache c(path, budgeted(budget, sync));
    std::atomic<std::uint64_t> hits{0};
    for (int frame = 0; frame < 60; ++frame) {
      std::vector<std::thread> tracers;
      for (unsigned t = 0; t < 3; ++t)
        tracers.emplace_back([&, t] {
          std::mt19937 rng(static_cast<unsigned>(frame * 7 + t));
          // a working set that moves: blocks near a frame-dependent centre
          const std::uint32_t centre = static_cast<std::uint32_t>(frame * 5) % n;
          for (int i = 0; i < 40; ++i) {
            const std::uint32_t b = (centre + static_cast<std::uint32_t>(rng() % 12)) % n;
            if (walk_to(c, b)) ++hits;
          }
        });
      for (std::thread& t : tracers) t.join();
      c.end_frame();
      if (frame % 3 == 0) c.wait_idle();  // otherwise loads run on into the next frame's gets
      REQUIRE(c.stats().peak_bytes <= budget);
    }
    c.wait_idle();
    require_rules(c);
    const CacheStats s = c.stats();
    CHECK(s.loads > 0);
    CHECK(s.evictions > 0);
    CHECK(hits > 0);
    CHECK(s.peak_bytes <= budget);
    CHECK(s.peak_bytes > s.pinned_bytes);
  }
}

TEST_CASE("lod cache: a full-detail fetch evicts least recently used blocks and says when requests do not fit", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(6, 1);
  o.tris_per_leaf = 30;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const std::uint64_t budget = minimum_budget(m.header);  // the root + 2 blocks
  REQUIRE(budget < m.header.raw_bytes);
  BlockCache c(dir.write("m.mlod", m.bytes), budgeted(budget));
  for (std::uint32_t b = 1; b <= 6; ++b) c.get(b);
  CHECK(!c.fetch_requested(false));  // at most two of the six fit at once
  std::uint32_t resident = 0;
  for (std::uint32_t b = 1; b <= 6; ++b) resident += c.resident(b);
  CHECK(resident >= 1);
  CHECK(resident <= 2);
  CHECK(c.stats().peak_bytes <= budget);
  // Each block in turn: loaded by evicting the least recently used.
  for (int round = 0; round < 2; ++round)
    for (std::uint32_t b = 1; b <= 6; ++b) {
      if (!c.get(b)) CHECK(c.fetch_requested(true));
      CHECK(c.get(b));
      c.end_frame();
    }
  CHECK(c.stats().evictions >= 6);
  CHECK(c.stats().peak_bytes <= budget);
  require_rules(c);
  // The least recently used goes first: 5 and 6 were used last; asking for 1 evicts 5.
  REQUIRE(c.resident(5));
  REQUIRE(c.resident(6));
  c.get(6);
  c.get(1);
  CHECK(c.fetch_requested(true));
  CHECK(c.resident(1));
  CHECK(c.resident(6));
  CHECK(!c.resident(5));
}

TEST_CASE("lod cache: eviction never drops a block whose child block is resident", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(2, 2);  // 0; 1 2; 3 4 (under 1) 5 6 (under 2)
  o.tris_per_leaf = 30;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const auto& d = m.directory;
  // Room for 0, 1 and 3, and 2 only once something goes.
  const std::uint64_t budget = d[0].raw_bytes + d[1].raw_bytes + d[3].raw_bytes + d[2].raw_bytes - 1;
  REQUIRE(budget >= minimum_budget(m.header));
  BlockCache c(dir.write("m.mlod", m.bytes), budgeted(budget));
  while (!walk_to(c, 3)) REQUIRE(c.fetch_requested(true));
  c.end_frame();
  CHECK(c.get(3));  // 3 used in this frame and 1 not: 1 is the least recently used, but 3 hangs under it
  c.end_frame();
  while (!walk_to(c, 2)) REQUIRE(c.fetch_requested(true));
  CHECK(c.resident(2));
  CHECK(c.resident(1));
  CHECK(!c.resident(3));
  CHECK(c.stats().evictions == 1);
  require_rules(c);
  while (!walk_to(c, 5)) REQUIRE(c.fetch_requested(true));  // 1 may go now: it has no resident child
  require_rules(c);
  CHECK(c.stats().peak_bytes <= budget);
}

TEST_CASE("lod cache: the bandwidth cap: N bytes at B bytes/s take at least N/B seconds", "[lod]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(8, 1);
  o.tris_per_leaf = 40;
  const std::string path = write_model(dir, "m.mlod", o);
  for (const bool direct : {true, false}) {
    CacheOptions co = budgeted(0);
    co.direct_io = direct;
    co.io_bandwidth = 200 << 10;  // 200 KiB/s
    const auto t0 = std::chrono::steady_clock::now();
    BlockCache c(path, co);
    for (std::uint32_t b = 1; b <= 8; ++b) c.get(b);
    c.end_frame();
    c.wait_idle();
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    const CacheStats s = c.stats();
    CHECK(s.loads == 8);
    REQUIRE(s.bytes_read > 8 * 100);
    INFO(c.io_mode() << ": " << s.bytes_read << " bytes in " << seconds << " s");
    CHECK(seconds >= double(s.bytes_read) / double(co.io_bandwidth));  // a lower bound only
  }
}

TEST_CASE("lod info: the header's counts and sizes, as text and JSON; a damaged file exits 2 naming the field", "[lod][cli]") {
  TempDir dir;
  mbvh_test::SynthOptions o = tree(3, 2);
  o.pin_depth = 1;
  const mbvh_test::SynthModel m = mbvh_test::make_mlod(o);
  const std::string path = dir.write("m.mlod", m.bytes);
  const mbvh_test::RunResult r = mbvh_test::run_cli("lod info " + path);
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK(has(r.output, "blocks           13"));
  CHECK(has(r.output, "pinned           4 blocks"));
  CHECK(has(r.output, "1234abcd5678ef90"));
  CHECK(has(r.output, "compression ratio"));
  const mbvh_test::RunResult j = mbvh_test::run_cli("lod info " + path + " --json - --quiet");
  INFO(j.output);
  CHECK(j.code == 0);
  const std::uint64_t minimum = minimum_budget(m.header);
  CHECK(has(j.output, "\"blocks\": 13"));
  CHECK(has(j.output, "\"pinned_bytes\": " + std::to_string(m.header.pinned_bytes)));
  CHECK(has(j.output, "\"minimum_budget\": " + std::to_string(minimum)));
  CHECK(has(j.output, "\"raw_bytes\": " + std::to_string(m.header.raw_bytes)));
  CHECK(has(j.output, "\"triangles\": " + std::to_string(m.header.triangles)));
  const std::string cut = dir.write("cut.mlod", m.bytes.substr(0, m.bytes.size() - 8));
  const mbvh_test::RunResult e = mbvh_test::run_cli("lod info " + cut);
  CHECK(e.code == 2);
  CHECK(has(e.output, cut));
  CHECK(has(e.output, "file_bytes"));
}

// Writes the fuzz target's seeds (tests/fuzz/corpus/mlod) when MBVH_LOD_SEED_DIR is set.
TEST_CASE("write the fuzz-mlod seeds", "[.lod-seeds]") {
  const char* out = std::getenv("MBVH_LOD_SEED_DIR");
  if (!out) return;
  mbvh_test::SynthOptions a = tree(2, 2);
  a.tris_per_leaf = 1;
  const mbvh_test::SynthModel ma = mbvh_test::make_mlod(a);
  mbvh_test::put(std::string(out) + "/tree-2-2.mlod", ma.bytes);
  mbvh_test::put(std::string(out) + "/raw-root-block.bin", ma.raw[0]);  // the fuzz target's check_block input
  mbvh_test::SynthOptions b;
  b.albedos = 0;
  mbvh_test::put(std::string(out) + "/root-only.mlod", mbvh_test::make_mlod(b).bytes);
}

// -- on a model the builder made (host/core/lod/build.cpp)

TEST_CASE("lod cache: a built model: every block loads and passes check_block; the header's counts are the blocks' sums", "[lod]") {
  TempDir dir;
  const auto src = lod::open_triangles("gen:mandelbulb:48", 2);
  lod::BuildOptions bo;
  bo.memory_budget = 12u << 20;  // bucketed
  bo.block_bytes = 16 << 10;
  bo.threads = 2;
  bo.temp_dir = dir.path.string();
  const std::string path = dir.file("m.mlod");
  const lod::BuildReport rep = lod::build(*src, path, bo);
  REQUIRE(rep.blocks > 20);
  const ModelFile f = read_model_file(path);
  const FileHeader& h = f.header;
  CHECK(h.blocks == rep.blocks);
  CHECK(h.pinned_bytes == rep.pinned_bytes);
  {  // budget 0: everything, coarse first
    BlockCache c(path, budgeted(0));
    for (unsigned round = 0; round <= 64; ++round) {
      bool all = true;
      for (std::uint32_t b = 0; b < h.blocks; ++b) all = c.get(b) && all;
      if (all) break;
      c.fetch_requested(true);
    }
    std::uint64_t nodes = 0, voxels = 0, links = 0, treelets = 0, tris = 0;
    for (std::uint32_t b = 0; b < h.blocks; ++b) {
      const std::byte* p = c.get(b);
      REQUIRE(p);
      BlockHead hd;
      std::memcpy(&hd, p, sizeof hd);
      nodes += hd.nodes, voxels += hd.voxels, links += hd.links, treelets += hd.treelets, tris += hd.tris;
    }
    CHECK(nodes == h.nodes);
    CHECK(voxels == h.voxels);
    CHECK(links == h.links);
    CHECK(treelets == h.treelets);
    CHECK(tris == h.tri_records);
    CHECK(links + 1 == treelets);  // every treelet but the root's is reached by one link
    CHECK(c.damaged().empty());
    CHECK(c.stats().resident_bytes == h.raw_bytes);
    CHECK(c.stats().peak_bytes == h.raw_bytes);
  }
  {  // a small budget, random walks in a window that moves over the blocks, as a camera would
    const std::uint64_t budget = minimum_budget(h) + 4 * h.block_bytes;
    BlockCache c(path, budgeted(budget));
    std::mt19937 rng(3);
    for (int frame = 0; frame < 40; ++frame) {
      const std::uint64_t centre = std::uint64_t(frame) * h.blocks / 40;
      for (int i = 0; i < 30; ++i) walk_to(c, static_cast<std::uint32_t>((centre + rng() % 6) % h.blocks));
      c.end_frame();
      c.wait_idle();
      require_rules(c);
    }
    CHECK(c.stats().evictions > 0);
    CHECK(c.stats().peak_bytes <= budget);
  }
}

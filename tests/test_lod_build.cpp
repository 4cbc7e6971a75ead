// SPDX-License-Identifier: MIT
// test_lod_build.cpp — the .mlod builder (mbvh/lod.h lod::build, `mbvh lod build`): the file read
// back with format.h alone (header, checksums, directory, every block decompressed and walked),
// every non-degenerate triangle exactly once with its vertices, bounds = Accel::bounds(), the same
// bytes at 1 and 2 threads, voxel normals on a sphere, albedos, refusals without a partial file.
#include <catch2/catch.hpp>

#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <set>

#include "host/core/io/mtri.h"
#include "host/core/layouts.h"
#include "host/core/lod/cache.h"
#include "host/core/lod/format.h"
#include "host/core/lod/voxel.h"
#include "mbvh/accel.h"
#include "mbvh/error.h"
#include "mbvh/lod.h"
#include "tests/helpers.h"

using namespace mbvh;
namespace fmt = mbvh::lod::format;
using mbvh_test::bytes_of;
using mbvh_test::error_of;
using mbvh_test::run_cli;
using mbvh_test::TempDir;

namespace {

struct VoxelSeen {
  fmt::Voxel v;
  Box box;
};

// A .mlod file read with format.h alone, every structural rule checked (REQUIREs).
struct Parsed {
  fmt::FileHeader h{};
  std::vector<fmt::DirEntry> dir;
  std::vector<Vec3f> albedos;
  std::vector<std::pair<std::uint32_t, Tri>> tris;  // (albedo index, record) of every leaf triangle
  std::vector<VoxelSeen> voxels;
  std::uint64_t nodes = 0, links = 0, treelets = 0, raw = 0, pinned = 0, pinned_blocks = 0;
  unsigned deepest = 0;
};

Parsed parse(const std::string& path) {
  const std::string f = bytes_of(path);
  Parsed p;
  REQUIRE(f.size() >= fmt::kHeaderBytes);
  std::memcpy(&p.h, f.data(), sizeof p.h);
  const fmt::FileHeader& h = p.h;
  REQUIRE(std::memcmp(h.magic, fmt::kMagic, 8) == 0);
  REQUIRE(h.version == fmt::kVersion);
  REQUIRE(h.header_bytes == fmt::kHeaderBytes);
  REQUIRE(h.node_bytes == 64);
  REQUIRE(h.voxel_bytes == 32);
  REQUIRE(h.link_bytes == 8);
  REQUIRE(h.tri_bytes == 48);
  REQUIRE(h.codec == fmt::kCodecZstd);
  REQUIRE(h.checksum == hash_bytes(&h, offsetof(fmt::FileHeader, checksum)));
  REQUIRE(h.file_bytes == f.size());
  REQUIRE(f.size() % fmt::kAlign == 0);
  // -- albedos
  REQUIRE(h.albedo_offset == fmt::kHeaderBytes);
  p.albedos.resize(h.albedos);
  std::memcpy(p.albedos.data(), f.data() + h.albedo_offset, h.albedos * sizeof(Vec3f));
  std::uint64_t asum;
  std::memcpy(&asum, f.data() + h.albedo_offset + h.albedos * sizeof(Vec3f), 8);
  REQUIRE(asum == hash_bytes(p.albedos.data(), h.albedos * sizeof(Vec3f), h.checksum));
  // -- directory
  REQUIRE(h.directory_offset % fmt::kAlign == 0);
  REQUIRE(h.directory_bytes == h.blocks * sizeof(fmt::DirEntry) + 8);
  REQUIRE(h.directory_offset + h.directory_bytes <= f.size());
  p.dir.resize(h.blocks);
  std::memcpy(p.dir.data(), f.data() + h.directory_offset, h.blocks * sizeof(fmt::DirEntry));
  std::uint64_t dsum;
  std::memcpy(&dsum, f.data() + h.directory_offset + h.blocks * sizeof(fmt::DirEntry), 8);
  REQUIRE(dsum == hash_bytes(p.dir.data(), h.blocks * sizeof(fmt::DirEntry), h.checksum));
  REQUIRE(h.root_block < h.blocks);
  REQUIRE(p.dir[h.root_block].depth == 0);
  REQUIRE(p.dir[h.root_block].parent_block == h.root_block);
  REQUIRE((p.dir[h.root_block].flags & fmt::kDirPinned));
  // -- blocks: decompressed, checked and walked from the root through the links
  std::vector<std::vector<char>> raw(h.blocks);
  for (std::uint32_t b = 0; b < h.blocks; ++b) {
    const fmt::DirEntry& d = p.dir[b];
    REQUIRE(d.offset % fmt::kAlign == 0);
    REQUIRE(d.offset >= h.albedo_offset + fmt::kAlign);
    REQUIRE(d.offset + d.stored_bytes <= h.directory_offset);
    REQUIRE(d.raw_bytes <= h.block_bytes);
    raw[b].resize(d.raw_bytes);
    const std::size_t got = ZSTD_decompress(raw[b].data(), d.raw_bytes, f.data() + d.offset, d.stored_bytes);
    REQUIRE(got == d.raw_bytes);
    REQUIRE(d.checksum == hash_bytes(raw[b].data(), d.raw_bytes, b));
    if (b != h.root_block) {
      REQUIRE(d.parent_block < h.blocks);
      REQUIRE(d.parent_block < b);  // parents first in the directory
      REQUIRE(d.depth == p.dir[d.parent_block].depth + 1);
      if (d.flags & fmt::kDirPinned) REQUIRE((p.dir[d.parent_block].flags & fmt::kDirPinned));
    }
    if (d.flags & fmt::kDirPinned) p.pinned += d.raw_bytes, ++p.pinned_blocks;
    p.raw += d.raw_bytes;
  }
  std::vector<std::set<std::uint32_t>> roots_linked(h.blocks);
  std::uint64_t voxel_count = 0;
  for (std::uint32_t b = 0; b < h.blocks; ++b) {
    fmt::BlockHead bh;
    REQUIRE(raw[b].size() >= sizeof bh);
    std::memcpy(&bh, raw[b].data(), sizeof bh);
    REQUIRE(bh.magic == fmt::kBlockMagic);
    REQUIRE(bh.index == b);
    REQUIRE(bh.reserved == 0);
    REQUIRE(bh.treelets >= 1);
    REQUIRE(bh.treelets <= bh.nodes);
    const fmt::BlockLayout l = fmt::block_layout(bh);
    REQUIRE(l.end == raw[b].size());
    std::vector<fmt::Node> nodes(bh.nodes);
    std::memcpy(nodes.data(), raw[b].data() + l.nodes, bh.nodes * sizeof(fmt::Node));
    std::vector<fmt::Voxel> vox(bh.voxels);
    std::memcpy(vox.data(), raw[b].data() + l.voxels, bh.voxels * sizeof(fmt::Voxel));
    std::vector<fmt::Link> lk(bh.links);
    std::memcpy(lk.data(), raw[b].data() + l.links, bh.links * sizeof(fmt::Link));
    std::vector<Tri> tris(bh.tris);
    std::memcpy(tris.data(), raw[b].data() + l.tris, bh.tris * sizeof(Tri));
    std::vector<int> referenced(bh.nodes, 0), tri_used(bh.tris, 0), vox_used(bh.voxels, 0), link_used(bh.links, 0);
    for (std::uint32_t n = 0; n < bh.nodes; ++n)
      for (int s = 0; s < 2; ++s) {
        const std::uint32_t ref = nodes[n].ref[s], kind = ref & fmt::kRefKind, idx = ref & fmt::kRefIndex;
        Box cb;
        cb.lo = {nodes[n].lo[s][0], nodes[n].lo[s][1], nodes[n].lo[s][2]};
        cb.hi = {nodes[n].hi[s][0], nodes[n].hi[s][1], nodes[n].hi[s][2]};
        if (kind == fmt::kRefEmpty) {
          REQUIRE(cb.empty());
          continue;
        }
        REQUIRE_FALSE(cb.empty());
        if (kind == fmt::kRefLeaf) {
          REQUIRE(std::uint64_t(idx) + nodes[n].aux[s] <= bh.tris);
          REQUIRE(nodes[n].aux[s] >= 1);
          for (std::uint32_t i = idx; i < idx + nodes[n].aux[s]; ++i) {
            ++tri_used[i];
            const Tri& t = tris[i];
            for (const float* v : {t.v0, t.v1, t.v2})  // the triangle lies in its leaf's box
              for (int a = 0; a < 3; ++a) REQUIRE((v[a] >= cb.lo[a] && v[a] <= cb.hi[a]));
          }
          continue;
        }
        REQUIRE(nodes[n].aux[s] < bh.voxels);
        ++vox_used[nodes[n].aux[s]];
        p.voxels.push_back({vox[nodes[n].aux[s]], cb});
        p.deepest = std::max(p.deepest, vox[nodes[n].aux[s]].depth);
        if (kind == fmt::kRefInner) {
          REQUIRE(idx < bh.nodes);
          REQUIRE(idx >= bh.treelets);  // roots are reached through links only
          REQUIRE(idx > n);
          ++referenced[idx];
          // the child's own children lie in its box
          for (int c = 0; c < 2; ++c)
            if ((nodes[idx].ref[c] & fmt::kRefKind) != fmt::kRefEmpty)
              for (int a = 0; a < 3; ++a) REQUIRE((nodes[idx].lo[c][a] >= cb.lo[a] && nodes[idx].hi[c][a] <= cb.hi[a]));
        } else {
          REQUIRE(kind == fmt::kRefLink);
          REQUIRE(idx < bh.links);
          ++link_used[idx];
          const fmt::Link& k = lk[idx];
          REQUIRE(k.block < h.blocks);
          REQUIRE(p.dir[k.block].parent_block == b);
          roots_linked[k.block].insert(k.node);
        }
      }
    for (std::uint32_t n = 0; n < bh.nodes; ++n) REQUIRE(referenced[n] == (n < bh.treelets ? 0 : 1));
    for (int u : tri_used) REQUIRE(u == 1);
    for (int u : vox_used) REQUIRE(u == 1);
    for (int u : link_used) REQUIRE(u == 1);
    for (const Tri& t : tris) {
      std::uint32_t alb, zero;
      std::memcpy(&alb, &t.v1[3], 4);
      std::memcpy(&zero, &t.v2[3], 4);
      REQUIRE(zero == 0);
      p.tris.push_back({alb, t});
    }
    p.nodes += bh.nodes;
    p.links += bh.links;
    p.treelets += bh.treelets;
    voxel_count += bh.voxels;
  }
  // every treelet root of every block but the root block is linked exactly once (from its parent)
  for (std::uint32_t b = 0; b < h.blocks; ++b) {
    fmt::BlockHead bh;
    std::memcpy(&bh, raw[b].data(), sizeof bh);
    if (b == h.root_block) {
      REQUIRE(bh.treelets == 1);
      REQUIRE(roots_linked[b].empty());
      continue;
    }
    REQUIRE(roots_linked[b].size() == bh.treelets);
    REQUIRE(*roots_linked[b].rbegin() == bh.treelets - 1);
  }
  REQUIRE(h.nodes == p.nodes);
  REQUIRE(h.voxels == voxel_count);
  REQUIRE(h.links == p.links);
  REQUIRE(h.treelets == p.treelets);
  REQUIRE(h.tri_records == p.tris.size());
  REQUIRE(h.raw_bytes == p.raw);
  REQUIRE(h.pinned_bytes == p.pinned);
  REQUIRE(h.pinned_blocks == p.pinned_blocks);
  REQUIRE(h.pinned_bytes <= std::max<std::uint64_t>(h.block_bytes, h.raw_bytes / 256) + p.dir[h.root_block].raw_bytes);
  return p;
}

std::uint32_t prim_of(const Tri& t) {
  std::uint32_t id;
  std::memcpy(&id, &t.v0[3], 4);
  return id;
}

// Every non-degenerate triangle of `s` exactly once, with its vertices' bits.
void require_every_triangle_once(const Parsed& p, const Scene& s) {
  std::vector<int> seen(s.triangle_count(), 0);
  for (const auto& [alb, t] : p.tris) {
    const std::uint32_t id = prim_of(t);
    REQUIRE(id < s.triangle_count());
    ++seen[id];
    Vec3f a, b, c;
    s.triangle(id, a, b, c);
    const float want[9] = {a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z};
    const float got[9] = {t.v0[0], t.v0[1], t.v0[2], t.v1[0], t.v1[1], t.v1[2], t.v2[0], t.v2[1], t.v2[2]};
    REQUIRE(std::memcmp(want, got, sizeof want) == 0);
  }
  std::size_t missing = 0, doubled = 0, degenerate_in = 0;
  for (std::size_t i = 0; i < seen.size(); ++i) {
    const bool zero = mbvh_test::zero_area(s, i);
    if (zero && seen[i]) ++degenerate_in;
    if (!zero && seen[i] == 0) ++missing;
    if (seen[i] > 1) ++doubled;
  }
  CHECK(missing == 0);
  CHECK(doubled == 0);
  CHECK(degenerate_in == 0);
}

void require_bounds(const Parsed& p, const Scene& s) {
  const auto acc = Accel::build(s);
  const Box& b = acc->bounds();
  const float want[6] = {b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z};
  REQUIRE(std::memcmp(want, p.h.bounds, sizeof want) == 0);
}

bool dir_empty(const std::filesystem::path& d) { return std::filesystem::is_empty(d); }

}  // namespace

TEST_CASE("lod build: an in-core model (one bucket), read back with format.h", "[lod]") {
  TempDir tmp;
  const Scene s = load_scene("gen:mandelbulb:32");
  const auto src = lod::triangles_of(s);
  lod::BuildOptions o;
  o.memory_budget = std::uint64_t(1) << 30;
  o.block_bytes = 16 << 10;
  o.threads = 2;
  const std::string out = tmp.file("m.mlod");
  const lod::BuildReport r = lod::build(*src, out, o);
  REQUIRE(r.buckets == 1);
  const Parsed p = parse(out);
  CHECK(p.h.triangles == s.triangle_count());
  CHECK(r.triangles == s.triangle_count());
  CHECK(r.nodes == p.h.nodes);
  CHECK(r.blocks == p.h.blocks);
  CHECK(r.file_bytes == p.h.file_bytes);
  CHECK(r.raw_bytes == p.h.raw_bytes);
  CHECK(r.pinned_bytes == p.h.pinned_bytes);
  CHECK(p.h.blocks > 3);  // a 16K block holds a few hundred triangles
  CHECK(p.h.block_bytes == o.block_bytes);
  CHECK(p.h.albedos == 0);
  CHECK(p.h.source_hash == src->hash());
  CHECK(p.h.depth == r.depth);
  CHECK(p.deepest <= p.h.depth);
  // an in-core build is the scene's own Accel: its node count (the root's record is in the file too)
  const auto acc = Accel::build(s);
  CHECK(p.h.nodes == acc->bvh2().nodes.size());
  CHECK(p.h.depth == acc->bvh2().nodes[0].height);
  require_every_triangle_once(p, s);
  require_bounds(p, s);
  for (const auto& [alb, t] : p.tris) REQUIRE(alb == 0);
  // the root's voxels count every triangle below them
  std::uint64_t top = 0;
  for (const VoxelSeen& v : p.voxels)
    if (v.v.depth == 1) top += v.v.triangles;
  std::uint64_t root_leaf_tris = 0;  // a root child that is a leaf has no voxel
  CHECK(top + root_leaf_tris <= p.h.tri_records);
  CHECK(top > p.h.tri_records / 2);
}

TEST_CASE("lod build: bucketed within a small budget, every triangle once, the same bytes at 1 and 2 threads",
          "[lod]") {
  TempDir tmp;
  const std::string mtri = tmp.file("m.mtri");
  const MtriWritten w = write_mtri("gen:mandelbulb:64", OutputTarget{"", mtri}, 2);
  const auto src = lod::open_triangles(mtri);
  CHECK(src->count() == w.count);
  CHECK(src->hash() == w.hash);
  // the generator streamed as a source has the .mtri file's hash
  CHECK(lod::open_triangles("gen:mandelbulb:64", 2)->hash() == w.hash);
  lod::BuildOptions o;
  o.memory_budget = 14u << 20;
  o.block_bytes = 32 << 10;
  o.temp_dir = tmp.path.string();
  o.threads = 1;
  const lod::BuildReport r1 = lod::build(*src, tmp.file("a.mlod"), o);
  o.threads = 2;
  const lod::BuildReport r2 = lod::build(*src, tmp.file("b.mlod"), o);
  REQUIRE(r1.buckets >= 4);
  CHECK(r1.buckets == r2.buckets);
  const std::string a = bytes_of(tmp.file("a.mlod")), b = bytes_of(tmp.file("b.mlod"));
  REQUIRE(a.size() == r1.file_bytes);
  CHECK((a == b));
  // only the two models are left: the bucket file is gone
  std::set<std::string> names;
  for (const auto& e : std::filesystem::directory_iterator(tmp.path)) names.insert(e.path().filename().string());
  CHECK(names == std::set<std::string>{"a.mlod", "b.mlod", "m.mtri"});
  const Parsed p = parse(tmp.file("a.mlod"));
  CHECK(p.h.source_hash == w.hash);
  const Scene s = load_scene(mtri);
  require_every_triangle_once(p, s);
  require_bounds(p, s);
  CHECK(p.h.depth >= 3);
  // the top tree's voxels: its root's two children hold every triangle between them
  std::uint64_t top = 0;
  for (const VoxelSeen& v : p.voxels)
    if (v.v.depth == 1) top += v.v.triangles;
  CHECK(top == p.h.tri_records);
  // the in-core build of the same source differs (one bucket) but holds the same triangles
  o.memory_budget = std::uint64_t(1) << 30;
  const lod::BuildReport r3 = lod::build(*src, tmp.file("c.mlod"), o);
  CHECK(r3.buckets == 1);
  CHECK(parse(tmp.file("c.mlod")).h.tri_records == p.h.tri_records);
}

TEST_CASE("lod build: the block cache opens a bucketed model and loads every block, checked", "[lod]") {
  TempDir tmp;
  const Scene s = load_scene("gen:mandelbulb:48");
  lod::BuildOptions o;
  o.memory_budget = 12u << 20;
  o.block_bytes = 16 << 10;
  o.threads = 2;
  o.temp_dir = tmp.path.string();
  const lod::BuildReport r = lod::build(*lod::triangles_of(s), tmp.file("m.mlod"), o);
  REQUIRE(r.buckets > 1);
  lod::CacheOptions co;
  co.memory_budget = 0;  // the whole model
  co.io_threads = 2;
  lod::BlockCache c(tmp.file("m.mlod"), co);
  CHECK(c.header().blocks == r.blocks);
  // breadth-first by directory depth: a block is requested once its parent is resident
  const auto& dir = c.directory();
  unsigned max_depth = 0;
  for (const auto& d : dir) max_depth = std::max<unsigned>(max_depth, d.depth);
  for (unsigned depth = 1; depth <= max_depth; ++depth) {
    for (std::uint32_t b = 0; b < dir.size(); ++b)
      if (dir[b].depth == depth) c.get(b);
    CHECK(c.fetch_requested(true));  // check_block on every block: throws naming a broken one
  }
  for (std::uint32_t b = 0; b < dir.size(); ++b) CHECK(c.get(b) != nullptr);
  CHECK(c.damaged().empty());
}

TEST_CASE("lod build: voxel faces on a sphere face out of the sphere, coloured by the materials", "[lod]") {
  TempDir tmp;
  Scene s = load_scene("gen:sphere:48");
  // two materials: the upper half red, the rest without a material (the renderer's grey)
  s.materials = {Material{"red", Vec3f{0.9f, 0.1f, 0.1f}}};
  s.triangle_materials.assign(s.triangle_count(), kNoMaterial);
  for (std::size_t i = 0; i < s.triangle_count(); ++i) {
    Vec3f a, b, c;
    s.triangle(i, a, b, c);
    if (a.z + b.z + c.z > 0) s.triangle_materials[i] = 0;
  }
  const auto src = lod::triangles_of(s);
  REQUIRE(src->albedos().size() == 2);
  lod::BuildOptions o;
  o.memory_budget = std::uint64_t(1) << 30;
  o.block_bytes = 16 << 10;
  o.threads = 2;
  lod::build(*src, tmp.file("s.mlod"), o);
  const Parsed p = parse(tmp.file("s.mlod"));
  REQUIRE(p.h.albedos == 2);
  CHECK(p.albedos[0].x == 0.9f);
  CHECK(p.albedos[1].x == 0.7f);
  for (const auto& [alb, t] : p.tris) REQUIRE(alb == (s.triangle_materials[prim_of(t)] == 0 ? 0u : 1u));
  require_every_triangle_once(p, s);
  const Box sb = s.bounds();
  const Vec3f c = sb.center();
  std::size_t checked = 0, bad = 0, colour_bad = 0;
  for (const VoxelSeen& v : p.voxels) {
    if (v.v.triangles > 64) continue;  // small patches: nearly flat
    const Vec3f m = v.box.center();
    Vec3f d{m.x - c.x, m.y - c.y, m.z - c.z};
    const float len = std::sqrt(d.x * d.x + d.y * d.y + d.z * d.z);
    d = {d.x / len, d.y / len, d.z / len};
    for (int f = 0; f < 6; ++f) {
      const int axis = f / 2;
      const float sign = f % 2 ? 1.0f : -1.0f;
      const float facing = d[axis] * sign;
      if (std::fabs(facing) < 0.4f) continue;
      // the outward normal turned to face out of face f
      const float turn = facing > 0 ? 1.0f : -1.0f;
      const Vec3f n = lod::decode_normal(v.v.face[f] & 0xffff);
      const float dot = turn * (n.x * d.x + n.y * d.y + n.z * d.z);
      ++checked;
      if (dot < 0.9f) ++bad;        // within 26 degrees
      REQUIRE(n[axis] * sign > 0);  // a face's normal always points out of it
      const Vec3f col = lod::decode_rgb565(v.v.face[f] >> 16);
      const bool upper = v.box.lo.z > c.z, lower = v.box.hi.z < c.z;
      if ((upper && std::fabs(col.x - 0.9f) > 0.02f) || (lower && std::fabs(col.x - 0.7f) > 0.02f)) ++colour_bad;
    }
  }
  CHECK(checked > 500);
  CHECK(bad == 0);
  CHECK(colour_bad == 0);
}

TEST_CASE("lod build: refusals name the option, leave no file and no temporary", "[lod]") {
  TempDir tmp;
  const std::string out = tmp.file("x.mlod");
  const Scene sphere = load_scene("gen:sphere:16");
  lod::BuildOptions o;
  o.temp_dir = tmp.path.string();
  o.threads = 2;
  o.block_bytes = 16 << 10;
  // a budget below what compressing blocks needs
  o.memory_budget = 1 << 20;
  CHECK_THAT(error_of([&] { lod::build(*lod::triangles_of(sphere), out, o); }),
             Catch::Contains("--memory") && Catch::Contains("raise --memory to at least"));
  // 20000 copies of one triangle in one cell: more than a bucket of this budget holds
  Scene dup;
  dup.name = "dup";
  for (int i = 0; i < 20000; ++i) {
    const auto v = static_cast<std::uint32_t>(dup.vertices.size());
    dup.vertices.push_back({0, 0, 0});
    dup.vertices.push_back({1, 0, 0});
    dup.vertices.push_back({0, 1, 0});
    dup.triangles.push_back({v, v + 1, v + 2});
  }
  for (std::size_t i = 0; i < sphere.triangle_count(); ++i) {
    Vec3f a, b, c;
    sphere.triangle(i, a, b, c);
    const auto v = static_cast<std::uint32_t>(dup.vertices.size());
    for (const Vec3f& x : {a, b, c}) dup.vertices.push_back({x.x * 10 + 20, x.y * 10, x.z * 10});
    dup.triangles.push_back({v, v + 1, v + 2});
  }
  o.memory_budget = 8u << 20;
  CHECK_THAT(
      error_of([&] { lod::build(*lod::triangles_of(dup), out, o); }),
      Catch::Contains("dup: 20000 triangles have their centroids in one cell") && Catch::Contains("raise --memory"));
  // with room, they build; with the depth capped at 2 the leaves hold thousands of triangles:
  // such a leaf's node gets a block of its own, larger than --block, and the header says so
  {
    o.memory_budget = std::uint64_t(1) << 30;
    o.tree.depth_cap = 2;
    const std::string big = tmp.file("dup.mlod");
    lod::build(*lod::triangles_of(dup), big, o);
    const Parsed p = parse(big);
    CHECK(p.h.block_bytes > 1000 * sizeof(Tri));
    CHECK(p.h.block_bytes > o.block_bytes);
    require_every_triangle_once(p, dup);
    std::filesystem::remove(big);
    o.tree.depth_cap = MBVH_BINARY_DEPTH_CAP;
  }
  // a triangle too small to trace, named by its prim id
  Scene tiny = sphere;
  tiny.name = "tiny";
  tiny.vertices.push_back({0, 0, 0});
  tiny.vertices.push_back({1e-20f, 0, 0});
  tiny.vertices.push_back({0, 1e-20f, 0});
  const auto n = static_cast<std::uint32_t>(tiny.vertices.size());
  tiny.triangles.push_back({n - 3, n - 2, n - 1});
  o.memory_budget = std::uint64_t(1) << 30;
  CHECK_THAT(error_of([&] { lod::build(*lod::triangles_of(tiny), out, o); }),
             Catch::Contains("tiny: triangle " + std::to_string(tiny.triangle_count() - 1) + " has area"));
  // options
  o.block_bytes = 1000;
  CHECK_THAT(error_of([&] { lod::build(*lod::triangles_of(sphere), out, o); }), Catch::Contains("--block"));
  o.block_bytes = 16 << 10;
  o.tree.quality = BuildQuality::high;
  CHECK_THAT(error_of([&] { lod::build(*lod::triangles_of(sphere), out, o); }), Catch::Contains("--quality high"));
  CHECK_FALSE(std::filesystem::exists(out));
  CHECK(dir_empty(tmp.path));
  // a damaged .mtri is named and leaves nothing either
  const std::string mtri = tmp.file("s.mtri");
  write_mtri("gen:sphere:64", OutputTarget{"", mtri}, 1);
  std::string bytes = bytes_of(mtri);
  bytes[200] ^= 1;
  mbvh_test::put(mtri, bytes);
  o.tree.quality = BuildQuality::medium;
  CHECK_THAT(error_of([&] { lod::build(*lod::open_triangles(mtri), out, o); }),
             Catch::Contains("block 0") && Catch::Contains("damaged"));
  CHECK_FALSE(std::filesystem::exists(out));
  std::filesystem::remove(mtri);
  CHECK(dir_empty(tmp.path));
}

// A source the builder knows nothing more of than TriangleSource says: no box without a pass.
class PlainSource final : public lod::TriangleSource {
 public:
  explicit PlainSource(const Scene& s) : s_(s) {}
  std::string name() const override { return "plain"; }
  std::uint64_t count() const override { return s_.triangle_count(); }
  std::uint64_t hash() const override { return 42; }
  void for_each_chunk(const ChunkFn& fn) const override {
    std::vector<SourceTri> chunk;
    for (std::size_t i = 0; i < s_.triangle_count(); ++i) {
      Vec3f a, b, c;
      s_.triangle(i, a, b, c);
      chunk.push_back({{a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z}});
      if (chunk.size() == 1000 || i + 1 == s_.triangle_count()) {
        fn(i + 1 - chunk.size(), chunk);
        chunk.clear();
      }
    }
  }

 private:
  const Scene& s_;
};

TEST_CASE("lod build: a source without a known box gets a bounds pass, and the same blocks", "[lod]") {
  TempDir tmp;
  const Scene s = load_scene("gen:mandelbulb:32");
  lod::BuildOptions o;
  o.memory_budget = 10u << 20;
  o.block_bytes = 16 << 10;
  o.threads = 2;
  o.temp_dir = tmp.path.string();
  const lod::BuildReport a = lod::build(PlainSource(s), tmp.file("a.mlod"), o);
  const lod::BuildReport b = lod::build(*lod::triangles_of(s), tmp.file("b.mlod"), o);
  REQUIRE(a.buckets > 1);
  CHECK(a.buckets == b.buckets);
  const Parsed pa = parse(tmp.file("a.mlod")), pb = parse(tmp.file("b.mlod"));
  CHECK(pa.h.source_hash == 42);
  REQUIRE(pa.dir.size() == pb.dir.size());
  for (std::size_t i = 0; i < pa.dir.size(); ++i) CHECK(pa.dir[i].checksum == pb.dir[i].checksum);
  require_every_triangle_once(pa, s);
}

TEST_CASE("lod build: the command", "[lod][cli]") {
  TempDir tmp;
  const auto ok =
      run_cli("lod build gen:mandelbulb:32 -o " + tmp.file("m.mlod") + " --memory 12M --block 32K --threads 2");
  CHECK(ok.code == 0);
  CHECK_THAT(ok.output, Catch::Contains("triangles in") && Catch::Contains("buckets") &&
                            Catch::Contains("peak resident memory") && Catch::Contains("compression"));
  const Parsed p = parse(tmp.file("m.mlod"));
  CHECK(p.h.blocks > 1);
  const auto named = run_cli("lod build gen:sphere:8 -o " + tmp.file("m.obj"));
  CHECK(named.code == 2);
  CHECK_THAT(named.output, Catch::Contains("NAME.mlod"));
  const auto small = run_cli("lod build gen:sphere:8 -o " + tmp.file("s.mlod") + " --memory 1M");
  CHECK(small.code == 2);
  CHECK_THAT(small.output, Catch::Contains("--memory"));
  const auto block = run_cli("lod build gen:sphere:8 -o " + tmp.file("s.mlod") + " --block 1K");
  CHECK(block.code == 2);
  CHECK_THAT(block.output, Catch::Contains("--block"));
  const auto temp = run_cli("lod build gen:sphere:8 -o " + tmp.file("s.mlod") + " --temp " + tmp.file("none"));
  CHECK(temp.code == 2);
  CHECK_THAT(temp.output, Catch::Contains("--temp"));
  CHECK_FALSE(std::filesystem::exists(tmp.file("s.mlod")));
}

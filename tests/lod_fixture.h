// SPDX-License-Identifier: MIT
// lod_fixture.h — small synthetic .mlod files written straight from format.h, for the block
// cache's tests and the fuzz target's seeds: a tree of blocks (a root block linking to child
// blocks that link to grandchildren, ...), each block a chain of inner nodes with leaves of random
// triangles and one link per child block, zstd-compressed and checksummed as the format says.
// Hooks let a test damage a raw block before it is compressed, or the header and directory
// before their checksums are made (a consistent file that is wrong in one field).
#pragma once
#include <zstd.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <random>
#include <stdexcept>
#include <string>
#include <vector>

#include "host/core/layouts.h"  // hash_bytes
#include "host/core/lod/format.h"

namespace mbvh_test {

struct SynthOptions {
  std::vector<std::uint32_t> parent = {0};  ///< parent[b]; block 0 is the root (its own parent)
  unsigned tris_per_leaf = 3;
  unsigned extra_nodes = 1;   ///< inner nodes beyond one per link
  unsigned pin_depth = 0;     ///< blocks at directory depth <= this are pinned
  std::uint32_t albedos = 2;
  std::uint64_t seed = 1;
  std::uint32_t block_bytes = 0;  ///< 0: the largest raw block
  /// Changes block b's raw bytes before its checksum and compression (the checksum matches them).
  std::function<void(std::uint32_t b, std::string& raw)> tamper_block;
  /// Changes the header and directory before their checksums are made.
  std::function<void(mbvh::lod::format::FileHeader&, std::vector<mbvh::lod::format::DirEntry>&)> tamper;
};

struct SynthModel {
  std::string bytes;
  mbvh::lod::format::FileHeader header{};
  std::vector<mbvh::lod::format::DirEntry> directory;
  std::vector<std::string> raw;  ///< each block's raw bytes
};

/// parent[] of a complete tree of blocks: `fan` children a block, `levels` levels below the root.
inline std::vector<std::uint32_t> block_tree(unsigned fan, unsigned levels) {
  std::vector<std::uint32_t> parent = {0};
  std::size_t first = 0, count = 1;
  for (unsigned l = 0; l < levels; ++l) {
    const std::size_t next = parent.size();
    for (std::size_t p = first; p < first + count; ++p)
      for (unsigned k = 0; k < fan; ++k) parent.push_back(static_cast<std::uint32_t>(p));
    first = next;
    count = parent.size() - next;
  }
  return parent;
}

inline SynthModel make_mlod(const SynthOptions& o) {
  using namespace mbvh::lod::format;
  const std::uint32_t nb = static_cast<std::uint32_t>(o.parent.size());
  std::vector<std::vector<std::uint32_t>> children(nb);
  std::vector<std::uint16_t> depth(nb, 0);
  for (std::uint32_t b = 1; b < nb; ++b) {
    children[o.parent[b]].push_back(b);
    depth[b] = static_cast<std::uint16_t>(depth[o.parent[b]] + 1);  // parents come first in parent[]
  }
  std::mt19937_64 rng(o.seed);
  std::uniform_real_distribution<float> coord(-1.0f, 1.0f);
  SynthModel m;
  m.raw.resize(nb);
  std::uint64_t prim = 0, nodes = 0, voxels = 0, links = 0;
  float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (std::uint32_t b = 0; b < nb; ++b) {
    const std::uint32_t nc = static_cast<std::uint32_t>(children[b].size());
    const std::uint32_t m_nodes = std::max<std::uint32_t>(1, nc) + o.extra_nodes;
    std::vector<Node> ns(m_nodes);
    std::vector<Voxel> vs;
    std::vector<Link> ls;
    std::vector<mbvh::Tri> ts;
    const auto leaf = [&](float* blo, float* bhi) {
      const std::uint32_t first = static_cast<std::uint32_t>(ts.size());
      for (int k = 0; k < 3; ++k) blo[k] = INFINITY, bhi[k] = -INFINITY;
      for (unsigned t = 0; t < o.tris_per_leaf; ++t) {
        mbvh::Tri tri{};
        float* rows[3] = {tri.v0, tri.v1, tri.v2};
        for (float* r : rows)
          for (int k = 0; k < 3; ++k) {
            r[k] = coord(rng);
            blo[k] = std::min(blo[k], r[k]), bhi[k] = std::max(bhi[k], r[k]);
            lo[k] = std::min(lo[k], r[k]), hi[k] = std::max(hi[k], r[k]);
          }
        const std::uint32_t id = static_cast<std::uint32_t>(prim++), alb = o.albedos ? id % o.albedos : 0;
        std::memcpy(&tri.v0[3], &id, 4);
        std::memcpy(&tri.v1[3], &alb, 4);
        ts.push_back(tri);
      }
      return first;
    };
    const auto voxel = [&]() {
      Voxel v{};
      for (int f = 0; f < 6; ++f) v.face[f] = static_cast<std::uint32_t>(rng());
      v.triangles = 1;
      v.depth = 1;
      vs.push_back(v);
      return static_cast<std::uint32_t>(vs.size() - 1);
    };
    for (std::uint32_t i = 0; i < m_nodes; ++i) {
      Node& n = ns[i];
      for (int c = 0; c < 2; ++c) {
        const bool is_link = c == 0 && i < nc, is_inner = c == 1 && i + 1 < m_nodes;
        if (is_link) {
          n.ref[c] = kRefLink | static_cast<std::uint32_t>(ls.size());
          ls.push_back(Link{children[b][i], 0});
          n.aux[c] = voxel();
        } else if (is_inner) {
          n.ref[c] = kRefInner | (i + 1);
          n.aux[c] = voxel();
        } else {
          n.ref[c] = kRefLeaf | leaf(n.lo[c], n.hi[c]);
          n.aux[c] = o.tris_per_leaf;
          continue;
        }
        for (int k = 0; k < 3; ++k) n.lo[c][k] = -1, n.hi[c][k] = 1;
      }
    }
    BlockHead hd{};
    hd.magic = kBlockMagic;
    hd.index = b;
    hd.nodes = m_nodes;
    hd.voxels = static_cast<std::uint32_t>(vs.size());
    hd.links = static_cast<std::uint32_t>(ls.size());
    hd.tris = static_cast<std::uint32_t>(ts.size());
    hd.treelets = 1;
    const BlockLayout l = block_layout(hd);
    std::string& raw = m.raw[b];
    raw.assign(l.end, '\0');
    std::memcpy(raw.data(), &hd, sizeof hd);
    std::memcpy(raw.data() + l.nodes, ns.data(), ns.size() * sizeof(Node));
    if (!vs.empty()) std::memcpy(raw.data() + l.voxels, vs.data(), vs.size() * sizeof(Voxel));
    if (!ls.empty()) std::memcpy(raw.data() + l.links, ls.data(), ls.size() * sizeof(Link));
    std::memcpy(raw.data() + l.tris, ts.data(), ts.size() * sizeof(mbvh::Tri));
    if (o.tamper_block) o.tamper_block(b, raw);
    nodes += hd.nodes, voxels += hd.voxels, links += hd.links;
  }
  // -- the file: header, albedos, blocks, directory
  FileHeader& h = m.header;
  std::memcpy(h.magic, kMagic, 8);
  h.version = kVersion;
  h.header_bytes = static_cast<std::uint32_t>(kHeaderBytes);
  h.node_bytes = sizeof(Node), h.voxel_bytes = sizeof(Voxel), h.link_bytes = sizeof(Link), h.tri_bytes = sizeof(mbvh::Tri);
  h.triangles = prim + 1;  // one degenerate triangle, not in a leaf
  h.tri_records = prim;
  h.nodes = nodes, h.voxels = voxels, h.links = links, h.blocks = nb, h.treelets = nb;
  for (int k = 0; k < 3; ++k) h.bounds[k] = lo[k], h.bounds[3 + k] = hi[k];
  std::size_t largest = 0;
  for (const std::string& r : m.raw) largest = std::max(largest, r.size());
  h.block_bytes = o.block_bytes ? o.block_bytes : static_cast<std::uint32_t>(largest);
  h.codec = kCodecZstd;
  h.depth = 3;
  h.albedos = o.albedos;
  h.source_hash = 0x1234abcd5678ef90ull;
  h.options_hash = 7;
  h.library_version = 1;
  h.root_block = 0;
  h.root_node = 0;
  std::string file(kHeaderBytes, '\0');
  std::vector<float> alb;
  for (std::uint32_t i = 0; i < o.albedos; ++i) alb.insert(alb.end(), {0.1f * float(i % 10), 0.5f, 0.9f});
  h.albedo_offset = kHeaderBytes;
  file.append(reinterpret_cast<const char*>(alb.data()), alb.size() * sizeof(float));
  file.append(8, '\0');  // the albedo checksum, made below
  const std::size_t albedo_sum_at = file.size() - 8;
  file.resize(align_up(file.size()), '\0');
  m.directory.resize(nb);
  for (std::uint32_t b = 0; b < nb; ++b) {
    const std::string& raw = m.raw[b];
    std::string z(ZSTD_compressBound(raw.size()), '\0');
    const std::size_t zn = ZSTD_compress(z.data(), z.size(), raw.data(), raw.size(), 3);
    if (ZSTD_isError(zn)) throw std::runtime_error("zstd");
    DirEntry& e = m.directory[b];
    e.offset = file.size();
    e.stored_bytes = static_cast<std::uint32_t>(zn);
    e.raw_bytes = static_cast<std::uint32_t>(raw.size());
    e.checksum = mbvh::hash_bytes(raw.data(), raw.size(), b);
    e.parent_block = o.parent[b];
    e.depth = depth[b];
    e.flags = depth[b] <= o.pin_depth ? kDirPinned : 0;
    if (e.flags) h.pinned_blocks++, h.pinned_bytes += e.raw_bytes;
    h.raw_bytes += e.raw_bytes;
    file.append(z.data(), zn);
    file.resize(align_up(file.size()), '\0');
  }
  h.directory_offset = file.size();
  h.directory_bytes = nb * sizeof(DirEntry) + 8;
  h.file_bytes = h.directory_offset + h.directory_bytes;
  if (o.tamper) o.tamper(h, m.directory);
  h.checksum = mbvh::hash_bytes(&h, offsetof(FileHeader, checksum));
  const std::uint64_t asum = mbvh::hash_bytes(alb.data(), alb.size() * sizeof(float), h.checksum);
  std::memcpy(file.data() + albedo_sum_at, &asum, 8);
  file.append(reinterpret_cast<const char*>(m.directory.data()), nb * sizeof(DirEntry));
  const std::uint64_t dsum = mbvh::hash_bytes(m.directory.data(), nb * sizeof(DirEntry), h.checksum);
  file.append(reinterpret_cast<const char*>(&dsum), 8);
  std::memcpy(file.data(), &h, sizeof h);
  m.bytes = std::move(file);
  return m;
}

}  // namespace mbvh_test

// SPDX-License-Identifier: MIT
// format.h — the .mlod file (mbvh/lod.h; docs/massive.md): what the builder (build.cpp) writes and
// the model (model.cpp) reads. Little-endian; every region starts on a 4 KiB boundary (O_DIRECT).
//
//   header      4096 B: FileHeader, zero-padded
//   albedos     FileHeader::albedos x 3 floats (linear RGB), then a u64 hash_bytes of them
//               seeded with the header's checksum; padded to 4 KiB
//   blocks      each block compressed alone (zstd), padded to 4 KiB
//   directory   FileHeader::blocks x DirEntry, then a u64 checksum: hash_bytes of the entries
//               seeded with the header's checksum (at directory_offset, 4 KiB aligned)
//
// A raw (decompressed) block: BlockHead, then `nodes` Node, `voxels` Voxel, `links` Link, then
// `tris` Tri at the next multiple of 16 bytes. The first `treelets` nodes are the roots of the
// block's treelets (a Link names one of them). The hierarchy is a binary BVH whose inner nodes
// hold their two children's boxes (Aila & Laine 2009's layout): a child is an inner node of the
// same block, a leaf (a range of the block's triangles), a link to a treelet root in another
// block, or empty. Inner and link children carry an LOD voxel, stored in the parent's block, so a
// missing child block is replaced by its voxel (the finest LOD resident).
#pragma once
#include <cstdint>
#include <cstring>

#include "mbvh/mbvh_layout.h"

namespace mbvh::lod::format {

inline constexpr char kMagic[8] = {'M', 'B', 'V', 'H', 'L', 'O', 'D', '\0'};
inline constexpr std::uint32_t kVersion = 1;
inline constexpr std::uint64_t kAlign = 4096;
inline constexpr std::uint64_t kHeaderBytes = 4096;
inline constexpr std::uint32_t kCodecZstd = 1;
inline constexpr std::uint32_t kBlockMagic = 0x424f4c4du;  // "MLOB"

inline constexpr std::uint64_t align_up(std::uint64_t x, std::uint64_t a = kAlign) { return (x + a - 1) / a * a; }

struct FileHeader {
  char magic[8];
  std::uint32_t version;        // kVersion
  std::uint32_t header_bytes;   // kHeaderBytes
  std::uint32_t node_bytes, voxel_bytes, link_bytes, tri_bytes;  // 64, 32, 8, 48
  std::uint64_t triangles;      // the source's (degenerate ones included)
  std::uint64_t tri_records;    // triangles in leaves (the non-degenerate ones)
  std::uint64_t nodes, voxels, links, blocks, treelets;
  float bounds[6];              // lo xyz, hi xyz: the non-degenerate triangles' (= Accel::bounds())
  std::uint32_t block_bytes;    // the largest raw block allowed by the build
  std::uint32_t codec;          // kCodecZstd
  std::uint32_t depth;          // the deepest leaf, binary levels below the root
  std::uint32_t albedos;        // albedo table entries (0: the renderer's default for every triangle)
  std::uint64_t source_hash;    // TriangleSource::hash
  std::uint64_t options_hash;   // of the build options that shape the file (not threads, not budget)
  std::uint32_t library_version;  // MBVH_VERSION_* as major << 16 | minor << 8 | patch
  std::uint32_t root_block;     // the block of the root treelet (pinned)
  std::uint32_t root_node;      // its node index there (< that block's treelets)
  std::uint32_t pinned_blocks;
  std::uint64_t pinned_bytes;   // raw bytes of the pinned blocks
  std::uint64_t raw_bytes;      // raw bytes of all blocks
  std::uint64_t albedo_offset;  // kHeaderBytes
  std::uint64_t directory_offset, directory_bytes;  // entries + the u64 checksum
  std::uint64_t file_bytes;     // the whole file
  std::uint64_t checksum;       // hash_bytes of the bytes of this struct before this field
};

inline constexpr std::uint16_t kDirPinned = 1;

struct DirEntry {
  std::uint64_t offset;          // of the compressed bytes in the file (4 KiB aligned)
  std::uint32_t stored_bytes;    // compressed bytes
  std::uint32_t raw_bytes;       // decompressed bytes
  std::uint64_t checksum;        // hash_bytes of the raw bytes, seeded with the block's index
  std::uint32_t parent_block;    // the block holding the link to this block's treelets (root: itself)
  std::uint16_t depth;           // links from the root block (root block: 0)
  std::uint16_t flags;           // kDirPinned
};
static_assert(sizeof(DirEntry) == 32);

struct BlockHead {
  std::uint32_t magic;           // kBlockMagic
  std::uint32_t index;           // this block's index in the directory
  std::uint32_t nodes, voxels, links, tris, treelets;
  std::uint32_t reserved;        // 0
};
static_assert(sizeof(BlockHead) == 32);

/// Child references (Node::ref): the kind in the top two bits.
inline constexpr std::uint32_t kRefInner = 0u << 30;  // index of a node in this block
inline constexpr std::uint32_t kRefLeaf = 1u << 30;   // index of the first triangle in this block; aux: count
inline constexpr std::uint32_t kRefLink = 2u << 30;   // index of a link in this block
inline constexpr std::uint32_t kRefEmpty = 3u << 30;  // no child (a root with one leaf child); its box is empty
inline constexpr std::uint32_t kRefKind = 3u << 30;
inline constexpr std::uint32_t kRefIndex = ~kRefKind;
inline constexpr std::uint32_t kNoVoxel = 0xffffffffu;

/// An inner node: its two children's boxes and references. aux: a leaf child's triangle count;
/// an inner or link child's voxel index in this block (kNoVoxel: none).
struct Node {
  float lo[2][3];
  float hi[2][3];
  std::uint32_t ref[2];
  std::uint32_t aux[2];
};
static_assert(sizeof(Node) == 64);

/// An LOD voxel: the box of the child it stands for (kept in the node's child box), and what the
/// subtree looks like through each face: face f = 2 axis + (0: the -axis face, 1: the +axis face).
/// face[f]: low 16 bits an octahedral unit normal (two snorm8: x, y of Cigolle et al. 2014's
/// encoding), high 16 bits an RGB565 albedo; both averaged over the subtree's triangles weighted
/// by area x |n . face direction|, each triangle's normal turned to face out of f.
struct Voxel {
  std::uint32_t face[6];
  std::uint32_t triangles;  // in the subtree (saturating)
  std::uint32_t depth;      // of the child it stands for (the root's children: 1)
};
static_assert(sizeof(Voxel) == 32);

/// A child in another block: the block and the treelet root's node index there.
struct Link {
  std::uint32_t block;
  std::uint32_t node;
};
static_assert(sizeof(Link) == 8);

// Tri (mbvh_layout.h) as the builder left it: v0[3] the prim id bits, v1[3] the albedo index bits
// (0 when the table is empty), v2[3] 0.

/// Byte offsets of a raw block's arrays.
struct BlockLayout {
  std::uint64_t nodes, voxels, links, tris, end;
};
inline BlockLayout block_layout(const BlockHead& h) {
  BlockLayout l;
  l.nodes = sizeof(BlockHead);
  l.voxels = l.nodes + std::uint64_t(h.nodes) * sizeof(Node);
  l.links = l.voxels + std::uint64_t(h.voxels) * sizeof(Voxel);
  l.tris = (l.links + std::uint64_t(h.links) * sizeof(Link) + 15) / 16 * 16;
  l.end = l.tris + std::uint64_t(h.tris) * sizeof(Tri);
  return l;
}

}  // namespace mbvh::lod::format

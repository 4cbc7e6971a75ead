// SPDX-License-Identifier: MIT
// hash.cpp — the build's content hash (Accel::hash): hash_bytes over a byte range, and hash_build
// over a build's nodes, leaves and triangles in fixed blocks hashed side by side.
#include <algorithm>
#include <cstring>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"

namespace mbvh {

std::uint64_t hash_bytes(const void* p, std::size_t n, std::uint64_t h) {
  // FNV-1a's step over 64-bit words in four interleaved lanes, the lanes then folded in order,
  // then the tail's bytes: the lanes' multiplies are independent and overlap, where byte-by-byte
  // FNV-1a waits on one chain of multiplies per byte.
  const unsigned char* b = static_cast<const unsigned char*>(p);
  constexpr std::uint64_t prime = 0x100000001b3ull;
  std::uint64_t lane[4] = {h, h ^ 1, h ^ 2, h ^ 3};
  std::size_t i = 0;
  for (; i + 32 <= n; i += 32)
    for (int k = 0; k < 4; ++k) {
      std::uint64_t w;
      std::memcpy(&w, b + i + 8 * k, 8);
      lane[k] = (lane[k] ^ w) * prime;
      lane[k] ^= lane[k] >> 29;
    }
  for (int k = 0; k < 4; ++k) h = ((h ^ lane[k]) * prime) ^ (lane[k] >> 31);
  for (; i < n; ++i) h = (h ^ b[i]) * prime;
  return h;
}

namespace build {

std::uint64_t hash_build(const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned threads,
                         const std::uint64_t* tri_hashes) {
  struct Block {
    const unsigned char* p;
    std::size_t n;
  };
  std::vector<Block> blocks;
  auto add = [&](const void* p, std::size_t n) {
    const unsigned char* c = static_cast<const unsigned char*>(p);
    for (std::size_t o = 0; o < n; o += kHashBlock) blocks.push_back({c + o, std::min(kHashBlock, n - o)});
  };
  add(b.nodes.data(), b.nodes.size() * sizeof(Bvh2::Node));
  add(leaves.data(), leaves.size() * sizeof(Leaf));
  const std::size_t given = tri_hashes ? blocks.size() : std::size_t(-1);  // the triangles' blocks from here
  add(tris.data(), tris.size() * sizeof(Tri));
  std::vector<std::uint64_t> h(blocks.size());
  parallel_for(std::min(given, blocks.size()), 4, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t i = lo; i < hi; ++i) h[i] = hash_bytes(blocks[i].p, blocks[i].n);
  });
  for (std::size_t i = given; i < blocks.size(); ++i) h[i] = tri_hashes[i - given];
  return hash_bytes(h.data(), h.size() * sizeof(std::uint64_t));
}

}  // namespace build

}  // namespace mbvh

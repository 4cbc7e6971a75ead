// SPDX-License-Identifier: MIT
// sources.h — what the .mlod builder (build.cpp) asks of the triangle sources of source.cpp beyond
// mbvh/lod.h's TriangleSource: a box known without a pass, and the .mtri content hash of a stream.
#pragma once
#include <cstdint>
#include <optional>
#include <span>
#include <vector>

#include "mbvh/lod.h"

namespace mbvh::lod {

/// A box holding every vertex of `src` when the source knows one without a pass over its
/// triangles (a .mtri file's header, the Mandelbulb generator's grid, an in-core scene); nullopt
/// for any other TriangleSource (the builder then makes a pass for it).
std::optional<Box> known_bounds(const TriangleSource& src);

/// The content hash a .mtri file of the same triangles records (mtri.h: hash_bytes of each 1 MiB
/// block of the 36-byte records seeded with the block's index, then of that table seeded with
/// the count), computed as the triangles stream by; 1 MiB of staging and 8 bytes a MiB.
class ContentHasher {
 public:
  ContentHasher();
  void add(std::span<const SourceTri> tris);
  std::uint64_t count() const { return count_; }
  /// The hash of everything added (call once, at the end).
  std::uint64_t finish();

 private:
  void flush();
  std::vector<char> block_;
  std::size_t used_ = 0;
  std::vector<std::uint64_t> table_;
  std::uint64_t count_ = 0;
};

}  // namespace mbvh::lod

// SPDX-License-Identifier: MIT
// mtri.h — the .mtri file: a streamed triangle soup, written without holding it and read in
// checksummed chunks (the out-of-core builder's input; docs/massive.md).
//
// File (little-endian):
//   header   64 B: "MBVHTRI\0", u32 format version (1), u32 flags (0: records are 36 B; bit 0,
//            rgba per triangle, is reserved), u64 triangle count, Box bounds (6 floats: lo, hi),
//            u64 content hash (hash_bytes of the block table, seeded with the count), u64 header
//            check (hash_bytes of the 56 bytes before it)
//   records  count x 36 B: float v[9] (three vertices)
//   table    one u64 per 1 MiB block of the record bytes (the last may be shorter):
//            hash_bytes of the block's bytes, seeded with the block's index
//   trailer  u64 checksum: hash_bytes of the table, seeded with the header check
// So: a damaged header or table is refused at open, a damaged block is named by its index when it
// is read, and a truncated or extended file is refused at open by its size against the count.
#pragma once
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "host/core/io/output.h"
#include "host/core/source.h"
#include "mbvh/scene.h"

namespace mbvh {

inline constexpr char kMtriMagic[8] = {'M', 'B', 'V', 'H', 'T', 'R', 'I', '\0'};
inline constexpr std::uint32_t kMtriVersion = 1;
inline constexpr std::uint64_t kMtriHeaderBytes = 64;
inline constexpr std::uint64_t kMtriBlockBytes = std::uint64_t(1) << 20;

/// The size of a .mtri file of `count` triangles.
std::uint64_t mtri_file_bytes(std::uint64_t count);

/// Writes a .mtri file as triangles come: records go to a temporary beside the target through a
/// 1 MiB buffer (StreamedOutput), the header is patched in last, and finish() renames the
/// temporary into place. Memory: the buffer and 8 bytes a block. Destroyed without finish(), it
/// leaves the target untouched.
class MtriWriter {
public:
  explicit MtriWriter(const OutputTarget& to);
  ~MtriWriter();
  /// Appends triangles (any coordinates are kept as they are; the generators write finite ones).
  void add(std::span<const SourceTri> tris);
  /// Writes the table, the trailer and the header, then commits the file.
  void finish();
  std::uint64_t count() const { return count_; }
  const Box& bounds() const { return bounds_; }
  std::uint64_t hash() const { return hash_; }   ///< the content hash (after finish)
  std::uint64_t bytes() const { return bytes_; }  ///< the file's size (after finish)

private:
  void flush_block();
  StreamedOutput out_;
  std::vector<char> block_;
  std::vector<std::uint64_t> table_;
  std::uint64_t count_ = 0, hash_ = 0, bytes_ = 0;
  Box bounds_;
};

/// A .mtri file opened for streaming. Opening checks the header (magic, version, flags, its
/// check), the size against the count and the block table against the trailer, and throws Error
/// naming the path and what is wrong; it reads 64 bytes and the table (8 bytes a MiB).
class MtriReader {
public:
  explicit MtriReader(const std::string& path);
  ~MtriReader();
  MtriReader(const MtriReader&) = delete;
  MtriReader& operator=(const MtriReader&) = delete;
  std::uint64_t count() const { return count_; }
  const Box& bounds() const { return bounds_; }
  std::uint64_t hash() const { return hash_; }
  std::uint64_t bytes() const { return size_; }
  /// Calls fn(first triangle, triangles) over every triangle in order, a block (1 MiB) at a time,
  /// checking each block against the table as it is read; may be called again. Throws Error
  /// naming the path and the block (its index and triangle range) whose checksum fails, a
  /// triangle with a non-finite coordinate, and bounds that differ from the header's.
  void for_each_chunk(const ChunkFn& fn) const;

private:
  std::string path_;
  int fd_ = -1;
  std::uint64_t size_ = 0, count_ = 0, hash_ = 0;
  Box bounds_;
  std::vector<std::uint64_t> table_;
};

/// What write_mtri wrote.
struct MtriWritten {
  std::uint64_t count = 0, bytes = 0, hash = 0;
  Box bounds;
  bool streamed = false;          ///< generated or copied chunk by chunk (else loaded in core first)
  std::uint64_t buffer_bytes = 0; ///< the generator's largest slab of triangles held at once
};

/// Writes the triangles of `source` to the .mtri file `to`: a plain gen:mandelbulb spec is
/// generated straight into the file slab by slab (the same bytes at any `threads`), a .mtri file
/// is copied chunk by chunk (checked as it is read), and any other scene or gen: spec is loaded
/// in core (load_scene, with its memory check) and written in prim id order. Throws Error naming
/// the source or the output; the target is untouched on failure.
MtriWritten write_mtri(const std::string& source, const OutputTarget& to, unsigned threads);

/// Whether these first bytes are a .mtri file's.
bool is_mtri(const void* head, std::size_t size);

/// An owned scene of a .mtri file's triangles (append_triangles: vertices not shared), after the
/// memory check of any load (the scene and one build of it within the budget) made before
/// allocating. Throws Error as MtriReader, and when the file has more triangles than a scene holds.
Scene load_mtri(const std::string& path);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// cache.h — the software memory manager of a .mlod model (the thesis' ch. 5: blocks loaded
// asynchronously under a fixed budget; docs/massive.md): the file's header and directory checked
// at open, the pinned top blocks loaded then, and the other blocks decompressed on request under a
// hard budget of decompressed bytes (pinned + resident + being loaded <= budget at every instant).
//
// Rules the traversal (traverse.cpp) relies on:
// - get() never blocks and never evicts: a pointer it returns stays valid until the next
//   end_frame() or fetch_requested() call, which the caller makes only while no trace runs.
// - A block is only ever made resident while its parent block is resident, and eviction never
//   drops a block whose child block is resident (a child is only reachable through its parent),
//   nor a pinned block.
#pragma once
#include <atomic>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "host/core/lod/format.h"
#include "mbvh/lod.h"

namespace mbvh::lod {

class BlockCache {
public:
  /// Opens `path`: reads and checks the header (magic, version, record sizes, its checksum), the
  /// albedo table and the directory (checksum; every entry in the file, aligned, parent before
  /// child, raw bytes <= block_bytes), and refuses a budget below the minimum (pinned bytes + 2 x
  /// block_bytes), naming it. Then loads the pinned blocks (synchronously, checked). Throws Error
  /// naming the path and the field or block.
  BlockCache(const std::string& path, const CacheOptions& opt);
  ~BlockCache();
  BlockCache(const BlockCache&) = delete;
  BlockCache& operator=(const BlockCache&) = delete;

  const std::string& path() const;
  const format::FileHeader& header() const;
  const std::vector<format::DirEntry>& directory() const;
  const std::vector<Vec3f>& albedos() const;
  const CacheOptions& options() const;

  /// The raw bytes of block b if it is resident (marking it used in this frame), else nullptr,
  /// and b is requested (deduplicated; coarse blocks load first). Thread-safe, lock-free on
  /// the resident path. A damaged block (its checksum failed when it was loaded) is never
  /// resident: get() returns nullptr for it and it is never requested again.
  const std::byte* get(std::uint32_t b);

  /// Loads every block requested since the last call (coarse first: smaller directory depth),
  /// synchronously on the calling thread and the I/O threads, evicting least recently used
  /// unpinned blocks without a resident child to make room; a request that cannot fit even then
  /// stays unloaded (returns false if any did, or if a request's parent block was not resident:
  /// such a request is dropped). Only while no trace runs. Throws Error naming a damaged block
  /// when `throw_on_damage` (full detail): one found damaged now, or one that get() was asked
  /// for since the last call (a damaged block is never requested, so a full-detail loop would
  /// otherwise wait for it forever); otherwise records it (damaged()).
  bool fetch_requested(bool throw_on_damage);

  /// Ends a frame: advances the LRU stamp, hands this frame's requests to the I/O threads in
  /// priority order (synchronous mode: fetch_requested(false)), evicts to make room for them.
  /// Only while no trace runs.
  void end_frame();
  /// Returns when no request is pending (loaded, or refused for the budget).
  void wait_idle();

  CacheStats stats() const;
  std::vector<std::uint32_t> damaged() const;
  /// Whether block b is resident now (pinned included), without marking or requesting it: for
  /// tests and reports.
  bool resident(std::uint32_t b) const;
  /// Why block b is damaged (the Error's text), "" if it is not.
  std::string damage(std::uint32_t b) const;
  /// How blocks are read: "O_DIRECT" (the page cache bypassed), "posix_fadvise(DONTNEED)" (the
  /// filesystem refused O_DIRECT: read through the page cache, then dropped from it) or "page
  /// cache" (CacheOptions::direct_io false).
  const char* io_mode() const;
  /// The budget in force: CacheOptions::memory_budget, or the file's raw bytes for 0.
  std::uint64_t budget() const;

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Checks a raw block's structure against its directory entry and the header (head fields, sizes,
/// every reference, link and voxel index in range, leaf ranges within the block's triangles,
/// links to blocks whose parent is this block). So that no file can make a traversal loop or
/// blow up: every non-root node is referenced by exactly one child reference and a treelet root
/// by none, every link by exactly one, no two links name the same (block, node); also: child
/// boxes finite with lo <= hi (empty children excepted), BlockHead::reserved 0, prim ids
/// < FileHeader::triangles, albedo indices < FileHeader::albedos (0 without a table), Tri v2[3] 0,
/// finite vertices. (That a link's node is < the linked block's treelets is checked when that
/// block is loaded, its parent being resident then.) Throws Error naming `path`, the block and
/// the field. O(block).
void check_block(const std::string& path, const format::FileHeader& h, const std::vector<format::DirEntry>& dir,
                 std::uint32_t b, const std::byte* raw, std::size_t bytes);

/// The largest block_bytes a reader accepts: a header asking more is refused before allocating.
inline constexpr std::uint64_t kMaxBlockBytes = 1ull << 30;

/// A .mlod file's header, albedo table and directory, checked as BlockCache's constructor checks
/// them (it uses this), without loading any block: for `mbvh lod info`. Throws Error naming the
/// path and the field or directory entry. Allocates O(file size) at most.
struct ModelFile {
  format::FileHeader header{};
  std::vector<format::DirEntry> directory;
  std::vector<Vec3f> albedos;
};
ModelFile read_model_file(const std::string& path);

/// The smallest budget a cache of this file accepts: the pinned bytes + 2 x block_bytes (the
/// pinned top, one block resident below it and one being loaded), or the file's raw bytes when
/// those are fewer (everything fits).
std::uint64_t minimum_budget(const format::FileHeader& h);

/// The header's counts and sizes as Model::info reports them.
ModelInfo model_info(const std::string& path, const format::FileHeader& h);

}  // namespace mbvh::lod

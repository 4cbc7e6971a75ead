// SPDX-License-Identifier: MIT
// cache.cpp — the software memory manager of a .mlod model (cache.h; docs/massive.md, "The memory
// manager"): the thesis' ch. 5 (Áfra 2012) loads "the necessary details asynchronously" through
// "a custom, purely software-based memory manager"; its policy is not published, so this is ours:
// a hard budget of decompressed bytes (pinned + resident + reserved for loads in flight), LRU by
// frame stamp, never a pinned block nor one with a resident (or loading) child block, eviction
// only between frames, and a lock-free resident path (an atomic pointer and stamp per block).
#include "host/core/lod/cache.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>
#include <zstd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstring>
#include <deque>
#include <functional>
#include <map>
#include <mutex>
#include <new>
#include <queue>
#include <thread>
#include <tuple>
#include <utility>

#include "host/core/layouts.h"  // hash_bytes
#include "host/core/resources.h"
#include "mbvh/error.h"

namespace mbvh::lod {

using namespace format;

namespace block_cache_detail {  // named, not anonymous: BlockCache::Impl holds its types (-Wsubobject-linkage in unity builds)

std::string num(std::uint64_t x) { return std::to_string(x); }

void read_exactly(int fd, const std::string& path, void* dst, std::uint64_t bytes, std::uint64_t off) {
  char* d = static_cast<char*>(dst);
  while (bytes > 0) {
    const ssize_t got = ::pread(fd, d, bytes, static_cast<off_t>(off));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) throw Error(path + ": read failed at byte " + num(off) + ": " + std::strerror(errno));
    if (got == 0) throw Error(path + ": the file ended at byte " + num(off) + " while it was read (truncated meanwhile?)");
    d += got;
    off += static_cast<std::uint64_t>(got);
    bytes -= static_cast<std::uint64_t>(got);
  }
}

std::uint64_t header_checksum(const FileHeader& h) { return hash_bytes(&h, offsetof(FileHeader, checksum)); }

struct Fd {
  int fd = -1;
  Fd() = default;
  explicit Fd(int f) : fd(f) {}
  Fd(Fd&& o) noexcept : fd(std::exchange(o.fd, -1)) {}
  Fd& operator=(Fd&& o) noexcept {
    std::swap(fd, o.fd);
    return *this;
  }
  ~Fd() {
    if (fd >= 0) ::close(fd);
  }
};

/// Opens `path` read-only after checking it is a regular file; returns its size in `size`.
Fd open_file(const std::string& path, std::uint64_t& size) {
  regular_file_size(path, "model");  // a FIFO or device is refused unopened
  Fd f(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (f.fd < 0) throw Error(path + ": cannot be opened: " + std::strerror(errno));
  struct stat st {};
  if (::fstat(f.fd, &st) != 0) throw Error(path + ": cannot be inspected: " + std::strerror(errno));
  if (!S_ISREG(st.st_mode)) throw Error(path + ": not a regular file");
  size = static_cast<std::uint64_t>(st.st_size);
  return f;
}

/// Reads and checks the header, the albedo table and the directory from an open file.
ModelFile read_checked(int fd, const std::string& path, std::uint64_t size) {
  const std::string bad = path + ": not a usable .mlod file: ";
  ModelFile m;
  FileHeader& h = m.header;
  // -- the header: its own fields first, so that a damaged byte is named where it can be
  if (size < kHeaderBytes)
    throw Error(bad + "truncated: " + num(size) + " bytes, less than the " + num(kHeaderBytes) + "-byte header");
  std::vector<char> head(kHeaderBytes);
  read_exactly(fd, path, head.data(), kHeaderBytes, 0);
  std::memcpy(&h, head.data(), sizeof h);
  if (std::memcmp(h.magic, kMagic, 8) != 0) throw Error(bad + "magic: no \"MBVHLOD\" header");
  if (h.version != kVersion)
    throw Error(bad + "version: format version " + num(h.version) + ", this library reads " + num(kVersion));
  if (h.checksum != header_checksum(h)) throw Error(bad + "checksum: the header's checksum does not match (the header is damaged)");
  if (std::any_of(head.begin() + sizeof h, head.end(), [](char c) { return c != 0; }))
    throw Error(bad + "header padding: bytes " + num(sizeof h) + ".." + num(kHeaderBytes) + " are not zero (the header is damaged)");
  if (h.header_bytes != kHeaderBytes) throw Error(bad + "header_bytes: " + num(h.header_bytes) + ", expected " + num(kHeaderBytes));
  const auto record = [&](const char* field, std::uint32_t got, std::size_t want) {
    if (got != want)
      throw Error(bad + field + ": " + num(got) + ", this library's record is " + num(want) + " bytes");
  };
  record("node_bytes", h.node_bytes, sizeof(Node));
  record("voxel_bytes", h.voxel_bytes, sizeof(Voxel));
  record("link_bytes", h.link_bytes, sizeof(Link));
  record("tri_bytes", h.tri_bytes, sizeof(Tri));
  if (h.codec != kCodecZstd) throw Error(bad + "codec: " + num(h.codec) + ", this library reads " + num(kCodecZstd) + " (zstd)");
  if (h.file_bytes != size)
    throw Error(bad + "file_bytes: the header says " + num(h.file_bytes) + " bytes, the file has " + num(size) +
                (size < h.file_bytes ? " (truncated)" : " (bytes after the end)"));
  // -- the header's fields against each other and the file's size (so nothing below allocates
  //    more than the file holds)
  if (h.blocks == 0) throw Error(bad + "blocks: 0 (a model has at least its root block)");
  if (h.blocks > size / sizeof(DirEntry))
    throw Error(bad + "blocks: " + num(h.blocks) + ", more directory entries than a " + num(size) + "-byte file holds");
  if (h.directory_bytes != h.blocks * sizeof(DirEntry) + 8)
    throw Error(bad + "directory_bytes: " + num(h.directory_bytes) + ", but " + num(h.blocks) + " blocks take " +
                num(h.blocks * sizeof(DirEntry) + 8));
  if (h.directory_offset % kAlign != 0 || h.directory_offset < kHeaderBytes || h.directory_offset > size ||
      h.directory_bytes > size - h.directory_offset)
    throw Error(bad + "directory_offset: " + num(h.directory_offset) + " (" + num(h.directory_bytes) +
                " bytes) is not a 4 KiB aligned region within the file's " + num(size) + " bytes");
  if (h.albedo_offset != kHeaderBytes) throw Error(bad + "albedo_offset: " + num(h.albedo_offset) + ", expected " + num(kHeaderBytes));
  if (h.albedos > (h.directory_offset - kHeaderBytes) / 12 ||
      kHeaderBytes + std::uint64_t(h.albedos) * 12 + 8 > h.directory_offset)
    throw Error(bad + "albedos: " + num(h.albedos) + " entries do not fit before the directory at byte " + num(h.directory_offset));
  if (h.root_block >= h.blocks) throw Error(bad + "root_block: " + num(h.root_block) + ", but the file has " + num(h.blocks) + " blocks");
  if (h.pinned_blocks == 0 || h.pinned_blocks > h.blocks)
    throw Error(bad + "pinned_blocks: " + num(h.pinned_blocks) + ", expected 1.." + num(h.blocks));
  if (h.block_bytes < sizeof(BlockHead) || h.block_bytes > kMaxBlockBytes)
    throw Error(bad + "block_bytes: " + num(h.block_bytes) + ", expected " + num(sizeof(BlockHead)) + ".." + num(kMaxBlockBytes));
  if (h.triangles > 0xffffffffull)
    throw Error(bad + "triangles: " + num(h.triangles) + ", more than 32-bit prim ids name (4294967295)");
  if (h.tri_records > h.triangles)
    throw Error(bad + "tri_records: " + num(h.tri_records) + ", more than the " + num(h.triangles) + " triangles");
  for (int k = 0; k < 6; ++k)
    if (!std::isfinite(h.bounds[k])) throw Error(bad + "bounds: not finite");
  if (h.tri_records > 0 && (h.bounds[0] > h.bounds[3] || h.bounds[1] > h.bounds[4] || h.bounds[2] > h.bounds[5]))
    throw Error(bad + "bounds: lo > hi");
  // -- the albedo table
  {
    std::vector<float> a(std::size_t(h.albedos) * 3 + 2);  // + the u64 checksum
    read_exactly(fd, path, a.data(), std::uint64_t(h.albedos) * 12 + 8, h.albedo_offset);
    std::uint64_t sum;
    std::memcpy(&sum, a.data() + std::size_t(h.albedos) * 3, 8);
    if (hash_bytes(a.data(), std::size_t(h.albedos) * 12, h.checksum) != sum)
      throw Error(bad + "albedo table: its checksum does not match (the table is damaged)");
    m.albedos.resize(h.albedos);
    for (std::size_t i = 0; i < h.albedos; ++i) {
      m.albedos[i] = Vec3f{a[3 * i], a[3 * i + 1], a[3 * i + 2]};
      if (!std::isfinite(a[3 * i]) || !std::isfinite(a[3 * i + 1]) || !std::isfinite(a[3 * i + 2]))
        throw Error(bad + "albedo table: entry " + num(i) + " is not finite");
    }
  }
  // -- the directory
  std::vector<DirEntry>& dir = m.directory;
  dir.resize(h.blocks);
  read_exactly(fd, path, dir.data(), h.blocks * sizeof(DirEntry), h.directory_offset);
  std::uint64_t sum;
  read_exactly(fd, path, &sum, 8, h.directory_offset + h.blocks * sizeof(DirEntry));
  if (hash_bytes(dir.data(), dir.size() * sizeof(DirEntry), h.checksum) != sum)
    throw Error(bad + "directory: its checksum does not match (the directory is damaged)");
  const std::uint64_t blocks_at = align_up(kHeaderBytes + std::uint64_t(h.albedos) * 12 + 8);
  std::uint64_t raw = 0, pinned = 0, pinned_n = 0;
  for (std::uint64_t b = 0; b < dir.size(); ++b) {
    const DirEntry& e = dir[b];
    const auto at = [&] { return bad + "directory entry " + num(b) + ": "; };  // made on a failure only
    if (e.offset % kAlign != 0 || e.offset < blocks_at || e.offset > h.directory_offset || e.stored_bytes == 0 ||
        e.stored_bytes > h.directory_offset - e.offset)
      throw Error(at() + "offset: bytes " + num(e.offset) + ".." + num(e.offset + e.stored_bytes) +
                  " are not a 4 KiB aligned, non-empty region between the albedo table (ends at " + num(blocks_at) +
                  ") and the directory (at " + num(h.directory_offset) + ")");
    if (e.raw_bytes < sizeof(BlockHead) || e.raw_bytes > h.block_bytes)
      throw Error(at() + "raw_bytes: " + num(e.raw_bytes) + ", expected " + num(sizeof(BlockHead)) + ".." + num(h.block_bytes) +
                  " (block_bytes)");
    if (e.parent_block >= h.blocks) throw Error(at() + "parent_block: " + num(e.parent_block) + ", but the file has " + num(h.blocks) + " blocks");
    if ((e.flags & ~kDirPinned) != 0) throw Error(at() + "flags: " + num(e.flags) + ", unknown bits");
    if (b == h.root_block) {
      if (e.parent_block != b || e.depth != 0 || !(e.flags & kDirPinned))
        throw Error(at() + "the root block must be its own parent, at depth 0 and pinned");
    } else if (e.depth == 0 || e.parent_block == b) {
      throw Error(at() + "depth: 0 or its own parent, but it is not the root block (" + num(h.root_block) + ")");
    }
    raw += e.raw_bytes;
    if (e.flags & kDirPinned) pinned += e.raw_bytes, ++pinned_n;
  }
  for (std::uint64_t b = 0; b < dir.size(); ++b) {  // parents coarser, pinned blocks' parents pinned
    const DirEntry& e = dir[b];
    const DirEntry& p = dir[e.parent_block];
    if (b == h.root_block) continue;
    if (p.depth >= e.depth)
      throw Error(bad + "directory entry " + num(b) + ": parent_block " + num(e.parent_block) + " is at depth " + num(p.depth) +
                  ", not above this block's " + num(e.depth));
    if ((e.flags & kDirPinned) && !(p.flags & kDirPinned))
      throw Error(bad + "directory entry " + num(b) + ": pinned, but its parent block " + num(e.parent_block) + " is not");
  }
  if (raw != h.raw_bytes) throw Error(bad + "raw_bytes: the header says " + num(h.raw_bytes) + ", the directory's blocks hold " + num(raw));
  if (pinned != h.pinned_bytes)
    throw Error(bad + "pinned_bytes: the header says " + num(h.pinned_bytes) + ", the directory's pinned blocks hold " + num(pinned));
  if (pinned_n != h.pinned_blocks)
    throw Error(bad + "pinned_blocks: the header says " + num(h.pinned_blocks) + ", the directory pins " + num(pinned_n));
  return m;
}

template <class T>
T load_at(const std::byte* p, std::uint64_t off) {
  T t;
  std::memcpy(&t, p + off, sizeof t);
  return t;
}

std::uint32_t bits(float f) {
  std::uint32_t u;
  std::memcpy(&u, &f, 4);
  return u;
}

// -- buffers: 4 KiB aligned (O_DIRECT's rule; a block's records need 16)

struct FreeAligned {
  void operator()(std::byte* p) const { ::operator delete[](p, std::align_val_t{kAlign}); }
};
using Buffer = std::unique_ptr<std::byte[], FreeAligned>;
Buffer aligned_buffer(std::uint64_t bytes) {
  return Buffer(static_cast<std::byte*>(::operator new[](std::max<std::uint64_t>(bytes, 1), std::align_val_t{kAlign})));
}

enum class IoMode : int { direct = 0, fadvise = 1, cached = 2 };

}  // namespace block_cache_detail
using namespace block_cache_detail;

// -- the checks of one block

void check_block(const std::string& path, const FileHeader& h, const std::vector<DirEntry>& dir, std::uint32_t b,
                 const std::byte* raw, std::size_t bytes) {
  const std::string bad = path + ": block " + num(b) + ": ";
  if (b >= dir.size()) throw Error(bad + "no such block (the file has " + num(dir.size()) + ")");
  if (bytes != dir[b].raw_bytes) throw Error(bad + "size: " + num(bytes) + " bytes, the directory says " + num(dir[b].raw_bytes));
  if (bytes < sizeof(BlockHead)) throw Error(bad + "size: " + num(bytes) + " bytes, less than its head");
  const BlockHead hd = load_at<BlockHead>(raw, 0);
  if (hd.magic != kBlockMagic) throw Error(bad + "magic: not a block head");
  if (hd.index != b) throw Error(bad + "index: the head says block " + num(hd.index));
  if (hd.reserved != 0) throw Error(bad + "reserved: " + num(hd.reserved) + ", expected 0");
  if (hd.treelets == 0 || hd.treelets > hd.nodes)
    throw Error(bad + "treelets: " + num(hd.treelets) + ", expected 1.." + num(hd.nodes) + " (its nodes)");
  const BlockLayout l = block_layout(hd);
  if (l.end != bytes)
    throw Error(bad + "size: its " + num(hd.nodes) + " nodes, " + num(hd.voxels) + " voxels, " + num(hd.links) + " links and " +
                num(hd.tris) + " triangles take " + num(l.end) + " bytes, the block has " + num(bytes));
  std::vector<std::uint8_t> node_refs(hd.nodes), link_refs(hd.links);
  const auto voxel_ok = [&](std::uint32_t v) { return v == kNoVoxel || v < hd.voxels; };
  for (std::uint32_t i = 0; i < hd.nodes; ++i) {
    const Node n = load_at<Node>(raw, l.nodes + std::uint64_t(i) * sizeof(Node));
    // messages are made only on a failure: this runs on every block the cache loads
    for (int c = 0; c < 2; ++c) {
      const std::uint32_t kind = n.ref[c] & kRefKind, idx = n.ref[c] & kRefIndex, aux = n.aux[c];
      const auto ch = [&] { return bad + "node " + num(i) + ": child " + num(c) + ": "; };
      if (kind == kRefEmpty) continue;
      for (int k = 0; k < 3; ++k)
        if (!std::isfinite(n.lo[c][k]) || !std::isfinite(n.hi[c][k]) || n.lo[c][k] > n.hi[c][k])
          throw Error(ch() + "box: not finite or lo > hi");
      if (kind == kRefInner) {
        if (idx < hd.treelets || idx >= hd.nodes)
          throw Error(ch() + "inner node " + num(idx) + ", expected " + num(hd.treelets) + ".." + num(hd.nodes - 1) +
                      " (not a treelet root)");
        if (++node_refs[idx] > 1) throw Error(ch() + "node " + num(idx) + " is referenced twice");
        if (!voxel_ok(aux)) throw Error(ch() + "voxel " + num(aux) + ", but the block has " + num(hd.voxels));
      } else if (kind == kRefLeaf) {
        if (aux == 0 || idx > hd.tris || aux > hd.tris - idx)
          throw Error(ch() + "leaf: triangles " + num(idx) + " +" + num(aux) + ", but the block has " + num(hd.tris));
      } else {  // link
        if (idx >= hd.links) throw Error(ch() + "link " + num(idx) + ", but the block has " + num(hd.links));
        if (++link_refs[idx] > 1) throw Error(ch() + "link " + num(idx) + " is referenced twice");
        if (!voxel_ok(aux)) throw Error(ch() + "voxel " + num(aux) + ", but the block has " + num(hd.voxels));
      }
    }
  }
  for (std::uint32_t i = hd.treelets; i < hd.nodes; ++i)
    if (node_refs[i] != 1) throw Error(bad + "node " + num(i) + ": no child reference names it");
  std::vector<std::uint64_t> targets(hd.links);  // block << 32 | node
  for (std::uint32_t i = 0; i < hd.links; ++i) {
    const Link k = load_at<Link>(raw, l.links + std::uint64_t(i) * sizeof(Link));
    const auto at = [&] { return bad + "link " + num(i) + ": "; };
    if (link_refs[i] != 1) throw Error(at() + "no child reference names it");
    if (k.block >= dir.size() || k.block == b || dir[k.block].parent_block != b)
      throw Error(at() + "block " + num(k.block) + " is not a child block of this block (its directory entry names another parent)");
    targets[i] = std::uint64_t(k.block) << 32 | k.node;
  }
  std::sort(targets.begin(), targets.end());
  if (std::adjacent_find(targets.begin(), targets.end()) != targets.end())
    throw Error(bad + "links: two links name the same treelet");
  const std::uint64_t albedos = std::max<std::uint64_t>(h.albedos, 1);
  for (std::uint32_t i = 0; i < hd.tris; ++i) {
    const Tri t = load_at<Tri>(raw, l.tris + std::uint64_t(i) * sizeof(Tri));
    const auto at = [&] { return bad + "triangle " + num(i) + ": "; };
    const float* r[3] = {t.v0, t.v1, t.v2};
    for (const float* v : r)
      for (int k = 0; k < 3; ++k)
        if (!std::isfinite(v[k])) throw Error(at() + "a vertex is not finite");
    if (bits(t.v0[3]) >= h.triangles) throw Error(at() + "prim id " + num(bits(t.v0[3])) + ", but the model has " + num(h.triangles) + " triangles");
    if (bits(t.v1[3]) >= albedos)
      throw Error(at() + "albedo index " + num(bits(t.v1[3])) + ", but the albedo table has " + num(h.albedos) + " entries");
    if (bits(t.v2[3]) != 0) throw Error(at() + "v2[3]: not 0");
  }
}

ModelFile read_model_file(const std::string& path) {
  std::uint64_t size = 0;
  const Fd f = open_file(path, size);
  return read_checked(f.fd, path, size);
}

std::uint64_t minimum_budget(const FileHeader& h) {
  return std::min(h.pinned_bytes + 2 * std::uint64_t(h.block_bytes), h.raw_bytes);
}

ModelInfo model_info(const std::string& path, const FileHeader& h) {
  ModelInfo i;
  i.path = path;
  i.version = h.version;
  i.triangles = h.triangles;
  i.nodes = h.nodes;
  i.voxels = h.voxels;
  i.blocks = h.blocks;
  i.tri_records = h.tri_records;
  i.albedos = h.albedos;
  i.raw_bytes = h.raw_bytes;
  i.file_bytes = h.file_bytes;
  i.pinned_bytes = h.pinned_bytes;
  i.pinned_blocks = h.pinned_blocks;
  i.block_bytes = h.block_bytes;
  i.depth = h.depth;
  i.source_hash = h.source_hash;
  i.bounds.lo = Vec3f{h.bounds[0], h.bounds[1], h.bounds[2]};
  i.bounds.hi = Vec3f{h.bounds[3], h.bounds[4], h.bounds[5]};
  return i;
}

// -- the cache

namespace block_cache_detail {

enum class State : std::uint8_t { absent, queued, loading, resident, damaged };

struct Slot {
  // The lock-free side, read by get() on the trace threads.
  std::atomic<const std::byte*> ptr{nullptr};  // resident: its raw bytes (release on publish)
  std::atomic<std::uint64_t> stamp{0};         // the frame it was last used in
  std::atomic<bool> requested{false};          // requested, queued, loading, resident or damaged
  std::atomic<bool> damaged{false};
  // Under Impl::mu.
  State state = State::absent;
  std::uint32_t holds = 0;  // child blocks resident, queued or loading, and requests waiting on this block
  Buffer data;
};

/// One loader's reusable state: the read buffer (aligned for O_DIRECT) and a zstd context.
struct Scratch {
  Buffer buf;
  std::uint64_t cap = 0;
  ZSTD_DCtx* dctx = nullptr;
  Scratch() : dctx(ZSTD_createDCtx()) {
    if (!dctx) throw std::bad_alloc();
  }
  ~Scratch() { ZSTD_freeDCtx(dctx); }
  Scratch(const Scratch&) = delete;
  Scratch& operator=(const Scratch&) = delete;
  std::byte* at_least(std::uint64_t n) {
    if (n > cap) {
      buf = aligned_buffer(n);
      cap = n;
    }
    return buf.get();
  }
};

/// A block whose load failed for a reason other than damage (memory): not recorded as damaged.
struct Transient {
  std::string what;
};

}  // namespace block_cache_detail
using namespace block_cache_detail;

struct BlockCache::Impl {
  std::string path;
  CacheOptions opt;
  FileHeader h{};
  std::vector<DirEntry> dir;
  std::vector<Vec3f> albedos;
  std::uint64_t budget = 0;
  Fd file, direct;
  std::atomic<int> mode{int(IoMode::cached)};
  std::unique_ptr<Slot[]> slots;
  std::atomic<std::uint64_t> frame{1};
  std::atomic<std::uint64_t> misses{0};
  std::atomic<std::uint64_t> damaged_asked{0};  // 1 + a damaged block get() was asked for; 0: none

  mutable std::mutex req_mu;  // the requests get() records
  std::vector<std::uint32_t> requests;

  mutable std::mutex mu;  // everything below, and Slot's mutex side
  std::condition_variable work_cv, idle_cv;
  std::deque<std::uint32_t> queue;
  unsigned in_flight = 0;
  bool stop = false;
  std::uint64_t pinned_bytes = 0, pinned_blocks = 0, resident_bytes = 0, resident_blocks = 0, reserved = 0, peak = 0;
  std::uint64_t loads = 0, evictions = 0, bytes_read = 0;
  std::map<std::uint32_t, std::string> damage;
  std::vector<std::uint32_t> damaged_order;

  std::mutex bw_mu;  // the emulated disk
  std::chrono::steady_clock::time_point busy_until{};

  Scratch caller;  // the thread of the constructor and fetch_requested
  std::vector<std::thread> threads;

  // -- reading one block (no lock held)

  /// Sleeps until an emulated disk of opt.io_bandwidth bytes/s, busy with the reads before this
  /// one, would have delivered `n` more bytes: over any interval the bytes read never exceed the
  /// rate (plus one read), and an idle disk earns no credit.
  void throttle(std::uint64_t n) {
    if (opt.io_bandwidth == 0) return;
    using clock = std::chrono::steady_clock;
    const auto take = std::chrono::duration_cast<clock::duration>(std::chrono::duration<double>(double(n) / double(opt.io_bandwidth)));
    clock::time_point done;
    {
      const std::lock_guard<std::mutex> lk(bw_mu);
      done = busy_until = std::max(clock::now(), busy_until) + take;
    }
    std::this_thread::sleep_until(done);
  }

  /// The stored bytes of block b in s's buffer; returns the bytes transferred.
  std::uint64_t read_stored(std::uint32_t b, Scratch& s) {
    const DirEntry& e = dir[b];
    if (mode.load(std::memory_order_relaxed) == int(IoMode::direct)) {
      // O_DIRECT: aligned offset, length and buffer; blocks are padded to 4 KiB in the file and
      // the directory (4 KiB aligned) follows them, so the aligned length stays in the file.
      const std::uint64_t len = align_up(e.stored_bytes);
      std::byte* d = s.at_least(len);
      std::uint64_t got = 0;
      while (got < len) {
        const ssize_t r = ::pread(direct.fd, d + got, len - got, static_cast<off_t>(e.offset + got));
        if (r < 0 && errno == EINTR) continue;
        if (r < 0 && errno == EINVAL && got == 0) {  // the filesystem refuses O_DIRECT reads
          mode.store(int(IoMode::fadvise), std::memory_order_relaxed);
          return read_stored(b, s);
        }
        if (r < 0) throw Error(path + ": block " + num(b) + ": read failed at byte " + num(e.offset + got) + ": " + std::strerror(errno));
        if (r == 0) break;  // the file's end: only the padding is missing
        got += static_cast<std::uint64_t>(r);
      }
      if (got < e.stored_bytes) throw Error(path + ": block " + num(b) + ": the file ended while it was read (truncated meanwhile?)");
      throttle(got);
      return got;
    }
    std::byte* d = s.at_least(e.stored_bytes);
    read_exactly(file.fd, path, d, e.stored_bytes, e.offset);
    if (mode.load(std::memory_order_relaxed) == int(IoMode::fadvise))
      ::posix_fadvise(file.fd, static_cast<off_t>(e.offset), static_cast<off_t>(e.stored_bytes), POSIX_FADV_DONTNEED);
    throttle(e.stored_bytes);
    return e.stored_bytes;
  }

  /// Reads, decompresses and checks block b (its parent resident); throws Error naming the block
  /// when it is damaged, Transient when memory ran out.
  Buffer load(std::uint32_t b, Scratch& s) {
    const DirEntry& e = dir[b];
    const std::string bad = path + ": block " + num(b) + " (depth " + num(e.depth) + ", file bytes " + num(e.offset) + ".." +
                            num(e.offset + e.stored_bytes) + ") is damaged: ";
    const std::uint64_t got = read_stored(b, s);
    {
      const std::lock_guard<std::mutex> lk(mu);
      bytes_read += got;
    }
    const std::byte* src = s.buf.get();
    const unsigned long long content = ZSTD_getFrameContentSize(src, e.stored_bytes);
    if (content == ZSTD_CONTENTSIZE_ERROR || content == ZSTD_CONTENTSIZE_UNKNOWN)
      throw Error(bad + "its compressed bytes are not a zstd frame of known size");
    if (content != e.raw_bytes)
      throw Error(bad + "its zstd frame holds " + num(content) + " bytes, the directory says " + num(e.raw_bytes));
    Buffer out;
    try {
      out = aligned_buffer(e.raw_bytes);
    } catch (const std::bad_alloc&) {
      throw Transient{path + ": block " + num(b) + ": out of memory for its " + num(e.raw_bytes) + " bytes"};
    }
    std::byte* const raw = out.get();
    const std::size_t n = ZSTD_decompressDCtx(s.dctx, raw, e.raw_bytes, src, e.stored_bytes);
    if (ZSTD_isError(n)) throw Error(bad + "zstd: " + ZSTD_getErrorName(n));
    if (n != e.raw_bytes) throw Error(bad + "it decompresses to " + num(n) + " bytes, the directory says " + num(e.raw_bytes));
    if (hash_bytes(raw, e.raw_bytes, b) != e.checksum) throw Error(bad + "its checksum does not match");
    check_block(path, h, dir, b, raw, e.raw_bytes);
    // The links into this block (its parent is resident: held) name its treelet roots.
    const std::uint32_t treelets = load_at<BlockHead>(raw, 0).treelets;
    if (b == h.root_block) {
      if (h.root_node >= treelets)
        throw Error(path + ": not a usable .mlod file: root_node: " + num(h.root_node) + ", but the root block has " + num(treelets) +
                    " treelet roots");
    } else {
      const std::byte* p = slots[e.parent_block].ptr.load(std::memory_order_acquire);
      if (p) {
        const BlockHead ph = load_at<BlockHead>(p, 0);
        const BlockLayout pl = block_layout(ph);
        for (std::uint32_t i = 0; i < ph.links; ++i) {
          const Link k = load_at<Link>(p, pl.links + std::uint64_t(i) * sizeof(Link));
          if (k.block == b && k.node >= treelets)
            throw Error(path + ": block " + num(e.parent_block) + ": link " + num(i) + " names node " + num(k.node) + " of block " +
                        num(b) + ", which has " + num(treelets) + " treelet roots");
        }
      }
    }
    return out;
  }

  // -- the accounting (under mu)

  std::uint64_t used() const { return pinned_bytes + resident_bytes + reserved; }

  void note_peak() { peak = std::max(peak, used()); }

  /// The loaded (or failed) block b: published, or recorded damaged; the reservation released.
  void finish(std::uint32_t b, Buffer buf, const std::string& error, bool transient) {
    Slot& s = slots[b];
    const DirEntry& e = dir[b];
    reserved -= e.raw_bytes;
    if (buf) {
      s.data = std::move(buf);
      s.state = State::resident;
      resident_bytes += e.raw_bytes;
      ++resident_blocks;
      ++loads;
      s.stamp.store(frame.load(std::memory_order_relaxed), std::memory_order_relaxed);
      s.ptr.store(s.data.get(), std::memory_order_release);
      note_peak();
      return;
    }
    --slots[e.parent_block].holds;
    if (transient) {
      s.state = State::absent;
      s.requested.store(false, std::memory_order_relaxed);
      return;
    }
    s.state = State::damaged;
    s.damaged.store(true, std::memory_order_relaxed);
    if (damage.emplace(b, error).second) damaged_order.push_back(b);
  }

  void evict(std::uint32_t b) {
    Slot& s = slots[b];
    s.ptr.store(nullptr, std::memory_order_release);
    s.state = State::absent;
    s.data.reset();
    s.requested.store(false, std::memory_order_relaxed);
    resident_bytes -= dir[b].raw_bytes;
    --resident_blocks;
    ++evictions;
    --slots[dir[b].parent_block].holds;
  }

  /// Eviction candidates, least recently used first (then finer first): resident, unpinned, no
  /// resident/queued/loading child block and no request waiting on them; with `before` != 0,
  /// only those not used in a frame >= before.
  struct Lru {
    using Key = std::tuple<std::uint64_t, int, std::uint32_t>;  // stamp, -depth, block
    std::priority_queue<Key, std::vector<Key>, std::greater<Key>> heap;
    bool built = false;
  };
  bool evictable(std::uint32_t b, std::uint64_t before) const {
    const Slot& s = slots[b];
    return s.state == State::resident && !(dir[b].flags & kDirPinned) && s.holds == 0 &&
           (before == 0 || s.stamp.load(std::memory_order_relaxed) < before);
  }
  void push(Lru& lru, std::uint32_t b) {
    lru.heap.emplace(slots[b].stamp.load(std::memory_order_relaxed), -int(dir[b].depth), b);
  }
  bool evict_one(Lru& lru, std::uint64_t before) {
    if (!lru.built) {
      for (std::uint32_t b = 0; b < dir.size(); ++b)
        if (evictable(b, before)) push(lru, b);
      lru.built = true;
    }
    while (!lru.heap.empty()) {
      const std::uint32_t b = std::get<2>(lru.heap.top());
      lru.heap.pop();
      if (!evictable(b, before)) continue;  // held since the heap was made
      const std::uint32_t p = dir[b].parent_block;
      evict(b);
      if (evictable(p, before)) push(lru, p);
      return true;
    }
    return false;
  }

  /// Hands the requests recorded since the last call to the loaders, coarse first, reserving
  /// each one's raw bytes (evicting for it as `before` allows). Returns whether every request
  /// was queued.
  bool plan(std::uint64_t before) {
    std::vector<std::uint32_t> batch;
    {
      const std::lock_guard<std::mutex> lk(req_mu);
      batch.swap(requests);
    }
    std::sort(batch.begin(), batch.end(), [&](std::uint32_t a, std::uint32_t b) {
      return dir[a].depth != dir[b].depth ? dir[a].depth < dir[b].depth : a < b;
    });
    bool all = true;
    std::vector<std::uint32_t> held;
    for (std::uint32_t b : batch) {  // each request holds its parent block, so that no eviction below drops it
      Slot& s = slots[b];
      if (s.state != State::absent) continue;
      if (slots[dir[b].parent_block].state != State::resident) {  // reached only through its parent: dropped
        s.requested.store(false, std::memory_order_relaxed);
        all = false;
        continue;
      }
      ++slots[dir[b].parent_block].holds;
      held.push_back(b);
    }
    Lru lru;
    for (std::uint32_t b : held) {
      const std::uint64_t raw = dir[b].raw_bytes;
      while (used() + raw > budget && evict_one(lru, before)) {
      }
      if (used() + raw > budget) {  // refused for the budget; requested again when still needed
        --slots[dir[b].parent_block].holds;
        slots[b].requested.store(false, std::memory_order_relaxed);
        all = false;
        continue;
      }
      reserved += raw;  // before reading: pinned + resident + reserved <= budget at every instant
      note_peak();
      slots[b].state = State::queued;
      queue.push_back(b);
    }
    if (!queue.empty()) work_cv.notify_all();
    return all;
  }

  /// Drops the queued loads that no trace wanted in the frame that ended (`ended`): a moving
  /// view's old requests, which would hold the I/O threads while the blocks the view needs now
  /// wait; their reservations and parent holds are released, and a trace that reaches one again
  /// requests it again. Asynchronous frames only (under mu).
  void drop_stale(std::uint64_t ended) {
    std::deque<std::uint32_t> keep;
    for (const std::uint32_t b : queue) {
      Slot& s = slots[b];
      if (s.stamp.load(std::memory_order_relaxed) == ended) {
        keep.push_back(b);
        continue;
      }
      reserved -= dir[b].raw_bytes;
      --slots[dir[b].parent_block].holds;
      s.state = State::absent;
      s.requested.store(false, std::memory_order_relaxed);
    }
    queue.swap(keep);
  }

  /// Loads one queued block on this thread; false when the queue is empty. `lk` holds mu.
  bool run_one(std::unique_lock<std::mutex>& lk, Scratch& s) {
    if (queue.empty()) return false;
    const std::uint32_t b = queue.front();
    queue.pop_front();
    slots[b].state = State::loading;
    ++in_flight;
    lk.unlock();
    Buffer buf;
    std::string error;
    bool transient = false;
    try {
      buf = load(b, s);
    } catch (const Error& e) {
      error = e.what();
    } catch (const Transient& t) {
      error = t.what, transient = true;
    } catch (const std::bad_alloc&) {
      error = path + ": block " + num(b) + ": out of memory", transient = true;
    }
    lk.lock();
    finish(b, std::move(buf), error, transient);
    --in_flight;
    if (queue.empty() && in_flight == 0) idle_cv.notify_all();
    return true;
  }

  void worker() {
    std::unique_ptr<Scratch> s;
    std::unique_lock<std::mutex> lk(mu);
    for (;;) {
      work_cv.wait(lk, [&] { return stop || !queue.empty(); });
      if (stop) return;
      if (!s) {
        lk.unlock();
        try {
          s = std::make_unique<Scratch>();
        } catch (const std::bad_alloc&) {
        }
        lk.lock();
        if (!s) continue;  // retried at the next wake; the caller's fetch_requested loads meanwhile
      }
      run_one(lk, *s);
    }
  }

  void wait_idle_locked(std::unique_lock<std::mutex>& lk) {
    idle_cv.wait(lk, [&] { return queue.empty() && in_flight == 0; });
  }
};

BlockCache::BlockCache(const std::string& path, const CacheOptions& opt) : impl_(std::make_unique<Impl>()) {
  Impl& m = *impl_;
  m.path = path;
  m.opt = opt;
  std::uint64_t size = 0;
  m.file = open_file(path, size);
  ModelFile mf = read_checked(m.file.fd, path, size);
  m.h = mf.header;
  m.dir = std::move(mf.directory);
  m.albedos = std::move(mf.albedos);
  // -- the budget
  m.budget = opt.memory_budget ? opt.memory_budget : m.h.raw_bytes;
  const std::uint64_t minimum = minimum_budget(m.h);
  if (m.budget < minimum) {
    char mib[32];
    std::snprintf(mib, sizeof mib, "%.1f", double(minimum) / double(1 << 20));
    throw Error(path + ": the memory budget " + num(m.budget) + " bytes is below this model's minimum of " + num(minimum) +
                " bytes (" + mib + " MiB: its " + num(m.h.pinned_blocks) + " pinned blocks' " + num(m.h.pinned_bytes) +
                " bytes + 2 x block_bytes " + num(m.h.block_bytes) + ")");
  }
  // -- how blocks are read
  if (opt.direct_io) {
    m.direct = Fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_DIRECT));
    m.mode = int(m.direct.fd >= 0 ? IoMode::direct : IoMode::fadvise);
  }
  m.slots = std::make_unique<Slot[]>(m.dir.size());
  // -- the pinned blocks, parents first, checked (a damaged one refuses the file)
  std::vector<std::uint32_t> pinned;
  for (std::uint32_t b = 0; b < m.dir.size(); ++b)
    if (m.dir[b].flags & kDirPinned) pinned.push_back(b);
  std::stable_sort(pinned.begin(), pinned.end(), [&](std::uint32_t a, std::uint32_t b) { return m.dir[a].depth < m.dir[b].depth; });
  for (std::uint32_t b : pinned) {
    Buffer buf;
    try {
      buf = m.load(b, m.caller);
    } catch (const Transient& t) {
      throw_out_of_memory(t.what, m.dir[b].raw_bytes);
    }
    Slot& s = m.slots[b];
    s.data = std::move(buf);
    s.state = State::resident;
    s.requested.store(true, std::memory_order_relaxed);
    s.ptr.store(s.data.get(), std::memory_order_release);
    m.pinned_bytes += m.dir[b].raw_bytes;
    ++m.pinned_blocks;
    if (b != m.h.root_block) ++m.slots[m.dir[b].parent_block].holds;
  }
  m.peak = m.used();
  const unsigned n = std::clamp(opt.io_threads, 1u, 64u);
  try {
    for (unsigned i = 0; i < n; ++i) m.threads.emplace_back([&m] { m.worker(); });
  } catch (...) {
    {
      const std::lock_guard<std::mutex> lk(m.mu);
      m.stop = true;
    }
    m.work_cv.notify_all();
    for (std::thread& t : m.threads) t.join();
    throw;
  }
}

BlockCache::~BlockCache() {
  Impl& m = *impl_;
  {
    const std::lock_guard<std::mutex> lk(m.mu);
    m.stop = true;
  }
  m.work_cv.notify_all();
  for (std::thread& t : m.threads) t.join();
}

const std::string& BlockCache::path() const { return impl_->path; }
const format::FileHeader& BlockCache::header() const { return impl_->h; }
const std::vector<format::DirEntry>& BlockCache::directory() const { return impl_->dir; }
const std::vector<Vec3f>& BlockCache::albedos() const { return impl_->albedos; }
const CacheOptions& BlockCache::options() const { return impl_->opt; }
std::uint64_t BlockCache::budget() const { return impl_->budget; }

const char* BlockCache::io_mode() const {
  switch (IoMode(impl_->mode.load(std::memory_order_relaxed))) {
    case IoMode::direct: return "O_DIRECT";
    case IoMode::fadvise: return "posix_fadvise(DONTNEED)";
    case IoMode::cached: break;
  }
  return "page cache";
}

const std::byte* BlockCache::get(std::uint32_t b) {
  Impl& m = *impl_;
  if (b >= m.dir.size()) return nullptr;
  Slot& s = m.slots[b];
  const std::byte* p = s.ptr.load(std::memory_order_acquire);
  const std::uint64_t f = m.frame.load(std::memory_order_relaxed);
  if (p) {
    if (s.stamp.load(std::memory_order_relaxed) != f) s.stamp.store(f, std::memory_order_relaxed);
    return p;
  }
  m.misses.fetch_add(1, std::memory_order_relaxed);
  if (s.damaged.load(std::memory_order_relaxed)) {
    m.damaged_asked.store(std::uint64_t(b) + 1, std::memory_order_relaxed);
    return nullptr;
  }
  // a missing block's stamp: the last frame a trace wanted it (end_frame drops queued loads
  // nobody wanted in the frame that ended)
  if (s.stamp.load(std::memory_order_relaxed) != f) s.stamp.store(f, std::memory_order_relaxed);
  if (!s.requested.exchange(true, std::memory_order_acq_rel)) {
    const std::lock_guard<std::mutex> lk(m.req_mu);
    m.requests.push_back(b);
  }
  return nullptr;
}

bool BlockCache::fetch_requested(bool throw_on_damage) {
  Impl& m = *impl_;
  std::unique_lock<std::mutex> lk(m.mu);
  const std::size_t damaged_before = m.damaged_order.size();
  const bool all = m.plan(0);
  while (m.run_one(lk, m.caller)) {
  }
  m.wait_idle_locked(lk);
  if (throw_on_damage) {
    if (m.damaged_order.size() > damaged_before) throw Error(m.damage.at(m.damaged_order[damaged_before]));
    const std::uint64_t asked = m.damaged_asked.exchange(0, std::memory_order_relaxed);
    if (asked) throw Error(m.damage.at(std::uint32_t(asked - 1)));
  } else {
    m.damaged_asked.store(0, std::memory_order_relaxed);
  }
  return all;
}

void BlockCache::end_frame() {
  Impl& m = *impl_;
  const std::uint64_t ended = m.frame.fetch_add(1, std::memory_order_relaxed);
  if (m.opt.synchronous) {
    fetch_requested(false);
    return;
  }
  const std::lock_guard<std::mutex> lk(m.mu);
  m.drop_stale(ended);
  m.plan(ended);  // blocks used in the frame that ended stay: no churn within a working set
}

void BlockCache::wait_idle() {
  Impl& m = *impl_;
  std::unique_lock<std::mutex> lk(m.mu);
  m.wait_idle_locked(lk);
}

CacheStats BlockCache::stats() const {
  const Impl& m = *impl_;
  CacheStats s;
  std::uint64_t requests = 0;
  {
    const std::lock_guard<std::mutex> lk(m.req_mu);
    requests = m.requests.size();
  }
  const std::lock_guard<std::mutex> lk(m.mu);
  s.budget = m.budget;
  s.resident_bytes = m.pinned_bytes + m.resident_bytes;
  s.peak_bytes = m.peak;
  s.pinned_bytes = m.pinned_bytes;
  s.loads = m.loads;
  s.evictions = m.evictions;
  s.misses = m.misses.load(std::memory_order_relaxed);
  s.pending = requests + m.queue.size() + m.in_flight;
  s.bytes_read = m.bytes_read;
  s.resident_blocks = m.pinned_blocks + m.resident_blocks;
  return s;
}

bool BlockCache::resident(std::uint32_t b) const {
  return b < impl_->dir.size() && impl_->slots[b].ptr.load(std::memory_order_acquire) != nullptr;
}

std::vector<std::uint32_t> BlockCache::damaged() const {
  const std::lock_guard<std::mutex> lk(impl_->mu);
  return impl_->damaged_order;
}

std::string BlockCache::damage(std::uint32_t b) const {
  const std::lock_guard<std::mutex> lk(impl_->mu);
  const auto it = impl_->damage.find(b);
  return it == impl_->damage.end() ? std::string() : it->second;
}

}  // namespace mbvh::lod

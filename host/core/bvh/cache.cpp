// SPDX-License-Identifier: MIT
// cache.cpp — the BVH cache: Accel::save / Accel::load / Accel::build_cached. A build is kept as
// one file holding the binary tree, its leaves and leaf-ordered triangles (the layouts are made
// from them on first use, as after a build), keyed by a content hash of the triangles and of every
// build option that shapes the tree (and the library version: a newer builder makes other trees).
// The file is versioned and checksummed; a file that is truncated, corrupt, of another format
// version or of another scene or options is detected before anything is traced from it.
//
// File (native little-endian, 8-byte aligned):
//   header  "MBVHBVH\0", u32 format version, u32 record sizes (node, box, leaf, tri), u64 key,
//           u64 Accel::hash(), counts (nodes, leaf boxes, leaves, triangles), the scene's triangle
//           count, tree facts (forced leaves, largest leaf, degenerate), bounds, binary statistics,
//           build options
//   arrays  nodes, leaf boxes, leaves, triangles (every record size a multiple of 8: no padding)
//   u64     checksum of every byte before it: the bytes cut into 1 MiB blocks, and also at the
//           segment boundaries; hash_bytes (layouts.h) chained over each block's pieces; then
//           hash_bytes of the blocks' hashes in order. Blocks are read and checked in parallel,
//           straight into the build's arrays (format 4; 3 hashed the segments in one chain).
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <sys/types.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <cstdio>
#include <cstring>
#include <atomic>
#include <chrono>
#include <filesystem>
#include <type_traits>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/cache_check.h"
#include "host/core/layouts.h"
#include "mbvh/error.h"
#include "host/core/io/output.h"
#include "host/core/enum_check.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "mbvh/version.h"

namespace mbvh {

namespace {

constexpr char kMagic[8] = {'M', 'B', 'V', 'H', 'B', 'V', 'H', '\0'};
constexpr std::uint32_t kFormatVersion = 4;  // 2: the build quality in the key and header; 3: hash_bytes; 4: blocks
// Bumped when a builder makes other bytes from the same scene and options (the key changes, so
// a file of the older builder is not taken for this one's tree). 1: the medium build's
// partition into a second record array (same splits, another leaf order); 2: the high build's
// reinsertion (reinsert.cpp); 3: the high build's choice of the tree without spatial splits
// where its SAH is lower (sbvh.cpp build_high); 4: the binned SAH's bins per node, min(bins,
// 4 + count / 20) (binned_sah.cpp).
constexpr std::uint32_t kTreeRevision = 4;

struct Header {
  char magic[8];
  std::uint32_t version;
  std::uint32_t sizes[4];  // Bvh2::Node, Box, Leaf, Tri
  std::uint32_t pad0;
  std::uint64_t key;
  std::uint64_t accel_hash;
  std::uint64_t nodes, leaf_boxes, leaves, tris;
  std::uint64_t scene_triangles, forced_leaves, largest_leaf, degenerate;
  Box bounds;
  std::uint64_t st_nodes, st_leaves, st_bytes;
  double st_sah, st_build_ms;
  std::uint32_t st_depth, st_bits;
  std::uint32_t max_leaf, bins, leaf_block, depth_cap;
  float traversal_cost;
  std::uint32_t quality;  // BuildQuality
};
static_assert(std::is_trivially_copyable_v<Header>);
static_assert(sizeof(Header) % 8 == 0);

template <class T>
void append(std::string& out, const T* p, std::size_t count) {
  out.append(reinterpret_cast<const char*>(p), count * sizeof(T));
  out.append((8 - out.size() % 8) % 8, '\0');
}

// The file's bytes before the checksum, as segments: [offset, offset + bytes) of the file.
struct Segment {
  std::uint64_t offset, bytes;
};
constexpr std::uint64_t kBlock = 1u << 20;

// Calls fn(segment index, file offset, bytes) for the pieces of block `i` (its bytes, cut at
// segment boundaries), in file order.
template <class Fn>
void for_each_piece(const std::vector<Segment>& segs, std::uint64_t i, Fn&& fn) {
  const std::uint64_t a = i * kBlock, b = a + kBlock;
  for (std::size_t s = 0; s < segs.size(); ++s) {
    const std::uint64_t lo = std::max(a, segs[s].offset), hi = std::min(b, segs[s].offset + segs[s].bytes);
    if (lo < hi) fn(s, lo, hi - lo);
  }
}

std::uint64_t block_count(const std::vector<Segment>& segs) {
  const std::uint64_t end = segs.back().offset + segs.back().bytes;
  return (end + kBlock - 1) / kBlock;
}

std::string hex(std::uint64_t v) {
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
  return b;
}

}  // namespace

std::uint64_t Accel::cache_key(const Scene& scene, const BuildOptions& opt) {
  check_enum(opt.quality, "Accel::cache_key: " + scene.display_name(), "BuildOptions::quality");
  std::uint64_t h = hash_bytes(MBVH_VERSION_STRING, sizeof(MBVH_VERSION_STRING), kFormatVersion);
  h = hash_bytes(&kTreeRevision, sizeof kTreeRevision, h);
  if (scene.meshes().empty()) {
    h = hash_bytes(scene.vertices.data(), scene.vertices.size() * sizeof(Vec3f), h);
    h = hash_bytes(scene.triangles.data(), scene.triangles.size() * sizeof(scene.triangles[0]), h);
  } else {  // the views' content (Scene::hash) and their triangle counts
    const std::uint64_t content = scene.hash();
    h = hash_bytes(&content, sizeof content, h);
    for (std::size_t g = 0; g <= scene.geometry_count(); ++g) {
      const std::uint64_t o = scene.geometry_offset(g);
      h = hash_bytes(&o, sizeof o, h);
    }
  }
  // every option that shapes the tree, after Accel::build's clamping; not threads (the bytes do
  // not depend on them) and not progress
  const std::uint32_t o[4] = {std::max(opt.max_leaf, 1u), std::clamp(opt.bins, 2u, 64u), std::max(opt.leaf_block, 1u),
                              std::clamp(opt.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP))};
  h = hash_bytes(o, sizeof o, h);
  const std::uint32_t q = static_cast<std::uint32_t>(opt.quality);
  h = hash_bytes(&q, sizeof q, h);
  return hash_bytes(&opt.traversal_cost, sizeof(float), h);
}

void Accel::save(const std::string& path, std::uint64_t key) const {
  if (!has_hierarchy())
    throw Error(path + ": a build of quality none has no hierarchy to save (it is remade in O(n) from the scene: "
                "Accel::build)");
  Header hd{};
  std::memcpy(hd.magic, kMagic, 8);
  hd.version = kFormatVersion;
  hd.sizes[0] = sizeof(Bvh2::Node);
  hd.sizes[1] = sizeof(Box);
  hd.sizes[2] = sizeof(Leaf);
  hd.sizes[3] = sizeof(Tri);
  hd.key = key;
  hd.accel_hash = hash();
  hd.nodes = impl_->bvh2_.nodes.size();
  hd.leaf_boxes = impl_->bvh2_.leaf_boxes.size();
  hd.leaves = impl_->leaves_.size();
  hd.tris = impl_->tris_.size();
  hd.scene_triangles = impl_->scene_triangles_;
  hd.forced_leaves = impl_->bvh2_.forced_leaves;
  hd.largest_leaf = impl_->bvh2_.largest_leaf;
  hd.degenerate = impl_->bvh2_.degenerate;
  hd.bounds = impl_->bounds_;
  hd.st_nodes = impl_->binary_stats_.nodes;
  hd.st_leaves = impl_->binary_stats_.leaves;
  hd.st_bytes = impl_->binary_stats_.bytes;
  hd.st_sah = impl_->binary_stats_.sah_cost;
  hd.st_build_ms = 0;  // not kept: an entry's bytes are a function of the build alone (concurrent writers write equal files)
  hd.st_depth = impl_->binary_stats_.depth;
  hd.st_bits = impl_->binary_stats_.bitstack_bits;
  hd.max_leaf = impl_->opt_.max_leaf;
  hd.bins = impl_->opt_.bins;
  hd.leaf_block = impl_->opt_.leaf_block;
  hd.depth_cap = impl_->opt_.depth_cap;
  hd.traversal_cost = impl_->opt_.traversal_cost;
  hd.quality = static_cast<std::uint32_t>(impl_->opt_.quality);
  static_assert(sizeof(Header) % 8 == 0 && sizeof(Bvh2::Node) % 8 == 0 && sizeof(Box) % 8 == 0 &&
                sizeof(Leaf) % 8 == 0 && sizeof(Tri) % 8 == 0, "records are whole 8-byte words: no padding");
  std::string out;
  out.reserve(sizeof hd + hd.nodes * sizeof(Bvh2::Node) + hd.leaf_boxes * sizeof(Box) + hd.leaves * sizeof(Leaf) +
              hd.tris * sizeof(Tri) + 64);
  std::vector<Segment> segs;
  auto segment = [&out, &segs](const auto* p, std::size_t count) {
    segs.push_back({out.size(), count * sizeof(*p)});
    append(out, p, count);
  };
  segment(&hd, 1);
  segment(impl_->bvh2_.nodes.data(), impl_->bvh2_.nodes.size());
  segment(impl_->bvh2_.leaf_boxes.data(), impl_->bvh2_.leaf_boxes.size());
  segment(impl_->leaves_.data(), impl_->leaves_.size());
  segment(impl_->tris_.data(), impl_->tris_.size());
  std::vector<std::uint64_t> h(block_count(segs));
  parallel_for(h.size(), 1, impl_->opt_.threads, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t i = lo; i < hi; ++i) {
      std::uint64_t sum = i;
      for_each_piece(segs, i, [&](std::size_t, std::uint64_t off, std::uint64_t n) { sum = hash_bytes(out.data() + off, n, sum); });
      h[i] = sum;
    }
  });
  const std::uint64_t sum = hash_bytes(h.data(), h.size() * sizeof(std::uint64_t));
  append(out, &sum, 1);
  // never through a link at the entry's name; other writers of the same entry write the same bytes
  const OutputWrite w{{"BVH cache entry", path, false, /*follow_links=*/false, /*shared=*/true}, out.data(), out.size()};
  write_outputs({&w, 1});
}

std::unique_ptr<Accel> Accel::load(const std::string& path, std::uint64_t key) { return load_entry(path, key, nullptr); }

std::unique_ptr<Accel> Accel::load_entry(const std::string& path, std::uint64_t key, const Scene* scene) {
  auto bad = [&path](const std::string& why) { return Error(path + ": not a usable BVH cache file: " + why); };
  // -- the file: read straight into the build's arrays (no staging copy of the file), block by
  //    block in parallel: page faults and copies are most of a load's time. Never through a
  //    link: O_NOFOLLOW.
  struct Fd {
    int fd;
    ~Fd() {
      if (fd >= 0) ::close(fd);
    }
  } f{::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW | O_NONBLOCK)};
  if (f.fd < 0) {
    if (errno == ELOOP) throw bad("a symbolic link (a cache entry is never read through a link)");
    throw bad(std::string("cannot be opened: ") + std::strerror(errno));
  }
  struct stat fst {};
  if (::fstat(f.fd, &fst) != 0) throw bad(std::string("cannot be inspected: ") + std::strerror(errno));
  if (!S_ISREG(fst.st_mode)) throw bad("not a regular file");
  const std::uint64_t size = static_cast<std::uint64_t>(fst.st_size);
  if (size < sizeof(Header) + 8) throw bad("truncated (" + std::to_string(size) + " bytes)");
  auto read_at = [&](void* dst, std::uint64_t bytes, std::uint64_t off) {
    char* d = static_cast<char*>(dst);
    while (bytes > 0) {
      const ssize_t got = ::pread(f.fd, d, bytes, static_cast<off_t>(off));
      if (got < 0 && errno == EINTR) continue;
      if (got <= 0) throw bad("cannot be read");
      d += got;
      off += static_cast<std::uint64_t>(got);
      bytes -= static_cast<std::uint64_t>(got);
    }
  };
  // -- the header: magic, version, record sizes, and counts bounded by the file and the scene
  Header hd;
  read_at(&hd, sizeof hd, 0);
  if (std::memcmp(hd.magic, kMagic, 8) != 0) throw bad("no mbvh BVH cache header");
  if (hd.version != kFormatVersion)
    throw bad("format version " + std::to_string(hd.version) + ", this library reads " + std::to_string(kFormatVersion));
  if (hd.sizes[0] != sizeof(Bvh2::Node) || hd.sizes[1] != sizeof(Box) || hd.sizes[2] != sizeof(Leaf) ||
      hd.sizes[3] != sizeof(Tri))
    throw bad("written by a build with other record sizes");
  const std::uint64_t limit = size;  // every count is bounded by the file it came from
  if (hd.nodes > limit || hd.leaf_boxes > limit || hd.leaves > limit || hd.tris > limit) throw bad("counts out of range");
  // quality none is never saved (Accel::save): a file that says so is not one of ours
  if (hd.quality > static_cast<std::uint32_t>(BuildQuality::high)) throw bad("unknown build quality");
  // ... and by the scene's triangles, before anything is allocated: a build holds at most one
  // record per triangle (SBVH: 1.3 per triangle), at most one leaf per record and fewer inner nodes
  if (scene) {
    const std::uint64_t n = scene->triangle_count();
    const std::uint64_t max_tris = hd.quality == static_cast<std::uint32_t>(BuildQuality::high) ? 2 * n : n;
    if (hd.scene_triangles != n)
      throw bad("made for " + std::to_string(hd.scene_triangles) + " triangles, the scene has " + std::to_string(n));
    if (hd.tris > max_tris || hd.leaves > hd.tris || hd.leaf_boxes != hd.leaves || hd.nodes > std::max<std::uint64_t>(hd.leaves, 1))
      throw bad("its counts (" + std::to_string(hd.nodes) + " nodes, " + std::to_string(hd.leaves) + " leaves, " +
                std::to_string(hd.tris) + " triangle records) do not fit a scene of " + std::to_string(n) + " triangles");
  }
  std::vector<Segment> segs{{0, sizeof hd}};
  for (std::uint64_t bytes : {hd.nodes * sizeof(Bvh2::Node), hd.leaf_boxes * sizeof(Box), hd.leaves * sizeof(Leaf),
                              hd.tris * sizeof(Tri)})
    segs.push_back({segs.back().offset + segs.back().bytes, bytes});
  const std::uint64_t need = segs.back().offset + segs.back().bytes + 8;
  if (need != size) throw bad("size " + std::to_string(size) + " does not match its counts (" + std::to_string(need) + "): truncated or damaged");

  // -- the arrays, sized by the counts, read and checksummed block by block on the pool
  require_memory(path, size, "the BVH cache file");
  std::unique_ptr<Accel> acc(new Accel());
  try {
    acc->impl_->bvh2_.nodes.resize(hd.nodes);
    acc->impl_->bvh2_.leaf_boxes.resize(hd.leaf_boxes);
    acc->impl_->leaves_.resize(hd.leaves);
    acc->impl_->tris_.resize(hd.tris);
  } catch (const std::bad_alloc&) {
    throw bad("out of memory allocating its " + std::to_string(size) + " bytes");
  }
  char* const dst[5] = {reinterpret_cast<char*>(&hd), reinterpret_cast<char*>(acc->impl_->bvh2_.nodes.data()),
                        reinterpret_cast<char*>(acc->impl_->bvh2_.leaf_boxes.data()),
                        reinterpret_cast<char*>(acc->impl_->leaves_.data()), reinterpret_cast<char*>(acc->impl_->tris_.data())};
  if (hd.degenerate > hd.scene_triangles || hd.tris < hd.scene_triangles - hd.degenerate)
    throw bad("triangle counts are inconsistent");
  std::vector<std::uint64_t> block_hash(block_count(segs));
  std::atomic<bool> bad_prim{false};
  parallel_for(block_hash.size(), 1, 0, [&](std::size_t lo, std::size_t hi, unsigned) {
    for (std::size_t i = lo; i < hi; ++i) {
      std::uint64_t sum = i;
      for_each_piece(segs, i, [&](std::size_t s, std::uint64_t off, std::uint64_t n) {
        char* d = dst[s] + (off - segs[s].offset);
        if (s > 0) read_at(d, n, off);  // the header is read already
        sum = hash_bytes(d, n, sum);
        if (s == 4 && n > 0) {
          // every triangle's prim id (row 0's w: bytes 12..15 of the record) names a triangle of the
          // scene, checked while the bytes are hot (the traversals index the scene by it). The id's
          // four bytes start 4 past an 8-byte boundary, so they never straddle a block's edge: each
          // record's id is checked in exactly one piece.
          const std::uint64_t rel = off - segs[s].offset;
          for (std::uint64_t r = rel / sizeof(Tri); r <= (rel + n - 1) / sizeof(Tri); ++r) {
            const std::uint64_t at = r * sizeof(Tri) + 12;
            if (at < rel || at + 4 > rel + n) continue;
            std::uint32_t prim;
            std::memcpy(&prim, dst[s] + at, 4);
            if (prim >= hd.scene_triangles) bad_prim = true;
          }
        }
      });
      block_hash[i] = sum;
    }
  });
  std::uint64_t stored;
  read_at(&stored, 8, size - 8);
  if (hash_bytes(block_hash.data(), block_hash.size() * sizeof(std::uint64_t)) != stored) throw bad("checksum mismatch (truncated or damaged)");
  if (bad_prim) throw bad("a triangle names a prim id beyond the scene's " + std::to_string(hd.scene_triangles) + " triangles");
  if (hd.key != key) throw bad("made for another scene, build options or library version (key " + hex(hd.key) + ", wanted " + hex(key) + ")");
  // -- the build's state and statistics, from the header
  acc->impl_->bvh2_.forced_leaves = hd.forced_leaves;
  acc->impl_->bvh2_.largest_leaf = hd.largest_leaf;
  acc->impl_->bvh2_.degenerate = hd.degenerate;
  acc->impl_->bounds_ = acc->impl_->bvh2_.nodes[0].box;  // never the header's: the tree's, checked below
  acc->impl_->scene_triangles_ = hd.scene_triangles;
  acc->impl_->geometry_offsets_ = {0, hd.scene_triangles};
  // the hash is computed from the loaded bytes on first use (Accel::hash), not read from the header
  LayoutStats& st = acc->impl_->binary_stats_;
  st.layout = "binary";
  st.nodes = hd.st_nodes;
  st.leaves = hd.st_leaves;
  st.bytes = hd.st_bytes;
  st.sah_cost = hd.st_sah;
  st.build_ms = hd.st_build_ms;
  st.depth = hd.st_depth;
  st.bitstack_bits = hd.st_bits;
  acc->impl_->opt_.max_leaf = hd.max_leaf;
  acc->impl_->opt_.bins = hd.bins;
  acc->impl_->opt_.leaf_block = hd.leaf_block;
  acc->impl_->opt_.depth_cap = hd.depth_cap;
  acc->impl_->opt_.traversal_cost = hd.traversal_cost;
  acc->impl_->opt_.quality = static_cast<BuildQuality>(hd.quality);

  // -- structure, as a build leaves it (cache_check.h): the checksum catches damage, this a file
  //    whose checksum was recomputed over a broken tree
  const Bvh2& b = acc->impl_->bvh2_;
  if (const std::string why = build::check_tree(b, acc->impl_->leaves_, acc->impl_->tris_.size()); !why.empty())
    throw bad(why);
  if (st.nodes != b.nodes.size() || st.leaves != acc->impl_->leaves_.size() || st.depth != b.nodes[0].height ||
      st.bitstack_bits != st.depth || hd.forced_leaves > st.leaves)
    throw bad("its statistics do not match its tree");
  std::size_t largest = 0;
  for (const Leaf& l : acc->impl_->leaves_) largest = std::max<std::size_t>(largest, l.count);
  acc->impl_->bvh2_.largest_leaf = largest;
  st.bytes = b.nodes.size() * sizeof(Bvh2::Node) + acc->impl_->leaves_.size() * (sizeof(Leaf) + sizeof(Box)) +
             acc->impl_->tris_.size() * sizeof(Tri);
  return acc;
}

namespace {

std::string normalised(const std::string& path) {
  std::error_code ec;
  const auto p = std::filesystem::weakly_canonical(path, ec);
  return ec ? path : p.string();
}

// The entry's name, spelled without following a link at its last component.
std::string entry_name(const std::string& path) {
  const std::filesystem::path p(path);
  return (std::filesystem::path(normalised(p.parent_path().empty() ? "." : p.parent_path().string())) / p.filename()).string();
}

// True for a name the cache writes: 16 lower-case hex digits and ".mbvh" (never a temporary,
// a user's file or a link's name in the directory).
bool is_entry_name(const std::string& name) {
  if (name.size() != 21 || name.compare(16, 5, ".mbvh") != 0) return false;
  for (int i = 0; i < 16; ++i)
    if (!std::isxdigit(static_cast<unsigned char>(name[i])) || std::isupper(static_cast<unsigned char>(name[i]))) return false;
  return true;
}

// The size bound (CacheOptions::max_bytes): the least recently used entries (by modification time;
// a hit touches its entry) are removed until the directory's entries total at most `max_bytes`.
// Only regular files named as entries are counted or removed (lstat: a link is neither); `keep`,
// the entry this call used, stays even when it alone exceeds the bound. Another process removing
// the same entry first is fine; an entry another process has open stays readable (POSIX unlink).
void evict(const std::string& dir, const std::string& keep, std::uint64_t max_bytes, Accel::CacheReport& rep) {
  struct Entry {
    std::int64_t mtime_ns;
    std::uint64_t bytes;
    std::string path;
  };
  std::vector<Entry> entries;
  std::uint64_t total = 0;
  std::error_code ec;
  for (auto it = std::filesystem::directory_iterator(dir, ec); !ec && it != std::filesystem::directory_iterator(); it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (!is_entry_name(name)) continue;
    struct stat st {};
    if (::lstat(it->path().c_str(), &st) != 0 || !S_ISREG(st.st_mode)) continue;
    total += static_cast<std::uint64_t>(st.st_size);
    if (name == keep) continue;
    entries.push_back({std::int64_t(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec, static_cast<std::uint64_t>(st.st_size),
                       it->path().string()});
  }
  std::sort(entries.begin(), entries.end(), [](const Entry& a, const Entry& b) {
    return a.mtime_ns != b.mtime_ns ? a.mtime_ns < b.mtime_ns : a.path < b.path;
  });
  for (const Entry& e : entries) {
    if (total <= max_bytes) break;
    if (::unlink(e.path.c_str()) == 0 || errno == ENOENT) {
      total -= e.bytes;
      ++rep.evicted;
      rep.evicted_bytes += e.bytes;
    }
  }
}

}  // namespace

std::unique_ptr<Accel> Accel::build_cached(const Scene& scene, const BuildOptions& opt, const std::string& dir,
                                           CacheReport* report) {
  return build_cached(scene, opt, CacheOptions{dir, {}, 0}, report);
}

std::unique_ptr<Accel> Accel::build_cached(const Scene& scene, const BuildOptions& opt, const CacheOptions& cache,
                                           CacheReport* report) {
  const std::string& dir = cache.dir;
  CacheReport rep;
  if (opt.quality == BuildQuality::none) {
    // no hierarchy: built in O(n), no dearer than reading and checking an entry; DIR untouched
    auto acc = build(scene, opt);
    if (report) *report = rep;
    return acc;
  }
  if (dir.empty()) throw Error("BVH cache directory: empty path");
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  if (!std::filesystem::is_directory(dir))
    throw Error("BVH cache directory " + dir + ": not a directory and cannot be made one" + (ec ? ": " + ec.message() : ""));
  const std::uint64_t key = cache_key(scene, opt);
  rep.path = (std::filesystem::path(dir) / (hex(key) + ".mbvh")).string();
  // -- the entry is none of the command's own files (inputs, outputs): by inode where both exist,
  //    else by name (an output not written yet)
  struct stat es {};
  const bool exists = ::lstat(rep.path.c_str(), &es) == 0;
  const bool is_link = exists && S_ISLNK(es.st_mode);
  const std::string name = entry_name(rep.path);
  for (const std::string& other : cache.other_files) {
    if (other.empty() || other == "-") continue;
    struct stat os {};
    const bool same = exists && !is_link && ::stat(other.c_str(), &os) == 0 ? os.st_dev == es.st_dev && os.st_ino == es.st_ino
                                                                            : normalised(other) == name;
    if (same)
      throw Error("BVH cache entry " + rep.path + " is " + other + ", a file this command also reads or writes; use another "
                  "cache directory");
  }
  // -- read it: never through a link (a link there is left unread and replaced by the entry)
  std::unique_ptr<Accel> acc;
  if (is_link) {
    rep.problem = rep.path + ": a symbolic link, not a BVH cache file; not followed (its target is left untouched)";
  } else if (exists) {
    try {
      const auto t0 = std::chrono::steady_clock::now();
      acc = load_entry(rep.path, key, &scene);
      // the triangle records are the scene's, and the options the caller's (the key holds them)
      Impl& im = *acc->impl_;
      Box bounds;
      const std::string why = build::check_records(scene, im.bvh2_, im.leaves_, im.tris_, im.opt_.quality == BuildQuality::high,
                                                   im.bvh2_.degenerate, opt.threads, bounds);
      if (!why.empty()) throw Error(rep.path + ": not a usable BVH cache file: " + why);
      if (std::memcmp(&bounds, &im.bvh2_.nodes[0].box, sizeof(Box)) != 0)
        throw Error(rep.path + ": not a usable BVH cache file: its root box is not the box of its triangles");
      if (im.opt_.quality != opt.quality) throw Error(rep.path + ": not a usable BVH cache file: made with another build quality");
      const BuildQuality q = im.opt_.quality;
      im.opt_ = opt;
      im.opt_.quality = q;
      im.opt_.depth_cap = std::clamp(opt.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP));
      im.opt_.max_leaf = std::max(opt.max_leaf, 1u);
      im.binary_stats_.sah_cost = build::sah_of_binary(im.bvh2_, im.leaves_, im.opt_.traversal_cost, im.opt_.threads);
      im.binary_stats_.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
      rep.loaded = true;
      ::utimensat(AT_FDCWD, rep.path.c_str(), nullptr, AT_SYMLINK_NOFOLLOW);  // recently used (the size bound's order); may fail read-only
    } catch (const Error& e) {
      acc.reset();
      rep.problem = e.what();  // rebuilt and replaced below
    }
  }
  if (!acc) {
    acc = build(scene, opt);
    acc->impl_->opt_.threads = opt.threads;
    try {
      acc->save(rep.path, key);
    } catch (const Error& e) {
      if (rep.problem.empty()) throw;
      throw Error(rep.problem + "; rebuilt, and it cannot be replaced: " + e.what());
    }
  }
  if (cache.max_bytes) evict(dir, std::filesystem::path(rep.path).filename().string(), cache.max_bytes, rep);
  acc->impl_->opt_.threads = opt.threads;
  acc->impl_->opt_.progress = opt.progress;
  acc->impl_->geometry_offsets_.resize(scene.geometry_count() + 1);  // a loaded build knows only its triangle count
  for (std::size_t g = 0; g <= scene.geometry_count(); ++g) acc->impl_->geometry_offsets_[g] = scene.geometry_offset(g);
  if (report) *report = rep;
  return acc;
}

}  // namespace mbvh

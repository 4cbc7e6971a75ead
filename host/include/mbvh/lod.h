// SPDX-License-Identifier: MIT
// lod.h — massive models out of core (the thesis' chapter 5; Áfra, "Interactive ray tracing of
// large models using voxel hierarchies", CGF 31(1), 2012): a hierarchy over any number of
// triangles with an LOD voxel on its inner nodes, cut into treelets packed in blocks that are
// compressed alone (zstd), built within a memory budget into a `.mlod` file, and traced through a
// software memory manager that keeps a hard budget of decompressed blocks.
//
// The hierarchy is mbvh's binary BVH (the one builder, run on buckets of the model that fit the
// budget, under a top over the buckets), not the paper's kd-tree: the voxel of a node is the
// node's own box, so hitting it costs nothing beyond the box test already made (the paper's
// argument for voxels that fill their node), no triangle is referenced twice, and at full detail
// the answers are the exact contract's (docs/massive.md says why, with the measurements).
//
// Part of the core library (mbvh::core); include <mbvh/lod.h>.
#pragma once
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "mbvh/geometry.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"

namespace mbvh {

/// One streamed triangle: three float vertices (x, y, z each), 36 bytes, a .mtri record.
struct SourceTri {
  float v[9];
};
static_assert(sizeof(SourceTri) == 36);

/// What a stream calls for each chunk: the index (prim id) of its first triangle, and the triangles.
using ChunkFn = std::function<void(std::uint64_t first, std::span<const SourceTri> tris)>;

namespace lod {

/// Triangles streamed in chunks, never all in memory at once: a .mtri file, a gen: spec made on
/// the fly, or an in-core Scene (small models, tests). Prim ids are the stream's order.
class TriangleSource {
public:
  virtual ~TriangleSource() = default;
  virtual std::string name() const = 0;      ///< for messages: the path or spec
  virtual std::uint64_t count() const = 0;   ///< triangles (degenerate ones included)
  virtual std::uint64_t hash() const = 0;    ///< a content hash (the .mlod records it)
  /// Calls fn over every triangle in prim id order, in chunks; may be called again (the builder
  /// makes several passes). Throws Error naming the source on damaged input.
  virtual void for_each_chunk(const ChunkFn& fn) const = 0;
  /// The albedo table (linear RGB) and triangle `prim`'s entry in it; an empty table: every
  /// triangle has the renderer's default albedo. Random access: only sources that hold their
  /// materials in core (a Scene) have a table.
  virtual std::vector<Vec3f> albedos() const { return {}; }
  virtual std::uint32_t albedo_index(std::uint64_t /*prim*/) const { return 0; }
};

/// A .mtri file (checked as it streams), a gen:mandelbulb spec (generated on every pass, the same
/// bytes every time), or any other scene file or gen: spec (loaded in core, with its memory
/// check). Throws Error naming the path or spec.
std::unique_ptr<TriangleSource> open_triangles(const std::string& path_or_spec, unsigned threads = 0);
/// The triangles of an in-core scene (kept by reference: the scene must outlive the source).
std::unique_ptr<TriangleSource> triangles_of(const Scene& scene);

struct BuildOptions {
  std::uint64_t memory_budget = 0;  ///< peak bytes the build may hold; 0: memory_budget() (resources)
  unsigned threads = 0;             ///< 0: every hardware thread; the file does not depend on it
  unsigned block_bytes = 256u << 10;  ///< the largest uncompressed block
  int zstd_level = 3;
  std::string temp_dir;             ///< bucket files of the out-of-core passes; "": beside the output
  mbvh::BuildOptions tree;          ///< the bucket builds' options (threads from `threads`)
  std::function<void(const std::string& phase, double fraction)> progress;
};

/// What build wrote.
struct BuildReport {
  std::uint64_t triangles = 0;   ///< of the source
  std::uint64_t nodes = 0, voxels = 0, blocks = 0, treelets = 0, buckets = 0;
  std::uint64_t raw_bytes = 0, file_bytes = 0, pinned_bytes = 0;
  unsigned depth = 0;            ///< the deepest leaf, in binary levels
  double seconds = 0;
};

/// Builds the model of `src` into `out_path` (a .mlod, written through a temporary and renamed
/// into place: never a partial file) within opt.memory_budget: when the triangles and one build
/// of them do not fit, streaming passes cut the model into spatial buckets (Morton order of the
/// centroids) that do, each built in core with mbvh's builder. The same bytes at any thread count.
/// Throws Error naming the source, the option or the output.
BuildReport build(const TriangleSource& src, const std::string& out_path, const BuildOptions& opt);

/// Where a model's blocks are cached, decompressed. The budget is a hard cap: pinned blocks +
/// resident blocks + blocks being loaded never exceed it.
struct CacheOptions {
  std::uint64_t memory_budget = 0;  ///< 0: the whole file's raw bytes (no eviction)
  unsigned io_threads = 1;
  std::uint64_t io_bandwidth = 0;   ///< bytes/s read cap (an emulated disk); 0: none
  bool direct_io = true;            ///< bypass the OS page cache (O_DIRECT, else POSIX_FADV_DONTNEED)
  bool synchronous = false;         ///< missing blocks are loaded before the rays that need them finish
  unsigned threads = 0;             ///< tracing threads (0: every hardware thread)
};

/// A ray's footprint: the width of its cone at distance t is width0 + spread * t (a pixel cone for
/// primary rays: width0 0, spread the pixel's angle; secondary rays inherit the width at their origin).
struct RayCone {
  float width0 = 0, spread = 0;
};

struct TraceOptions {
  Query query = Query::closest;
  bool lod = true;     ///< false: full detail (every needed block is loaded), the exact contract's answers
  float quality = 1;   ///< accept a voxel when its box's largest extent <= quality * footprint at its entry
};

enum class HitKind : std::uint8_t { miss = 0, triangle = 1, voxel = 2 };

/// One answer. A triangle hit is mbvh's Hit (t, u, v, prim); a voxel hit is at the entry distance
/// of the node's box, through face `face` (0 -x, 1 +x, 2 -y, 3 +y, 4 -z, 5 +z).
struct Hit {
  float t = INFINITY, u = 0, v = 0;
  std::uint32_t prim = MBVH_MISS_PRIM;  ///< triangle: its prim id; otherwise MBVH_MISS_PRIM
  HitKind kind = HitKind::miss;
  std::uint8_t face = 0;
  std::uint16_t depth = 0;     ///< voxel: its node's depth (the root's children: 1)
  bool forced = false;         ///< voxel: taken because the finer block was not resident
  Vec3f normal{};              ///< voxel: its face's unit normal (facing out of the face)
  Vec3f albedo{};              ///< triangle: its albedo; voxel: its face's colour
  Box box;                     ///< voxel: its node's box
  std::uint64_t node = 0;      ///< voxel: a node id (voxel_triangles)
  mbvh::Hit plain() const { return mbvh::Hit{t, u, v, prim}; }
};

/// A triangle hit's three vertices (x, y, z each), copied while its block was resident, so that
/// shading gives the in-core renderer's bits.
struct Surface {
  float v[9];
};

struct CacheStats {
  std::uint64_t budget = 0, resident_bytes = 0, peak_bytes = 0, pinned_bytes = 0;
  std::uint64_t loads = 0, evictions = 0, misses = 0, pending = 0, bytes_read = 0;
  std::uint64_t resident_blocks = 0;
};

/// What `mbvh lod info` prints: the header's counts and sizes.
struct ModelInfo {
  std::string path;
  std::uint32_t version = 0;
  std::uint64_t triangles = 0, nodes = 0, voxels = 0, blocks = 0, tri_records = 0, albedos = 0;
  std::uint64_t raw_bytes = 0, file_bytes = 0, pinned_bytes = 0, pinned_blocks = 0;
  std::uint32_t block_bytes = 0, depth = 0;
  std::uint64_t source_hash = 0;
  Box bounds;
};

class Model {
public:
  /// Opens a .mlod file: checks the header and directory (Error naming the path and the field),
  /// the budget against the pinned blocks (Error naming the minimum), and loads the pinned blocks.
  static std::unique_ptr<Model> open(const std::string& path, const CacheOptions& opt = {});
  virtual ~Model() = default;
  /// Traces a batch (on CacheOptions::threads). `cones` has one entry per ray or is empty (no
  /// footprint: full detail for every ray). `surfaces`, if set, gets each triangle hit's vertices.
  /// Throws Error naming a damaged block met at full detail; with LOD a damaged block is treated
  /// as missing (stats().damaged, and damaged_blocks()).
  virtual void trace(std::span<const Ray> rays, std::span<const RayCone> cones, const TraceOptions& opt,
                     std::vector<Hit>& out, std::vector<Surface>* surfaces = nullptr) = 0;
  /// Ends a frame: the LRU stamp advances, this frame's requests go to the I/O threads (coarse
  /// first) and blocks are evicted to make room. Eviction happens only here.
  virtual void end_frame() = 0;
  /// Returns when no request is pending (loads done or refused for the budget).
  virtual void wait_idle() = 0;
  virtual CacheStats stats() const = 0;
  virtual ModelInfo info() const = 0;
  virtual const Box& bounds() const = 0;  ///< equals Accel::bounds() of the same triangles
  virtual std::uint64_t triangles() const = 0;
  virtual std::vector<Vec3f> albedos() const = 0;
  /// The blocks found damaged so far (their index), for reports.
  virtual std::vector<std::uint32_t> damaged_blocks() const = 0;
  /// The triangles under a voxel hit's node (Hit::node), loading what it needs: for tests of the
  /// LOD error bound. Small subtrees only.
  virtual std::vector<Surface> voxel_triangles(std::uint64_t node) = 0;
};

/// Whether `path` is a .mlod file (by its magic, not its name).
bool is_model_file(const std::string& path);

}  // namespace lod
}  // namespace mbvh

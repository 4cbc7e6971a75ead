// SPDX-License-Identifier: MIT
// accel.h — one build of a scene: the binned-SAH binary BVH and, on demand and cached, the
// MBVH2 and MBVH4 layouts every backend traces. Leaves and leaf-ordered triangles are shared by
// all layouts, so a leaf reference means the same triangles everywhere.
#pragma once
#include <cstdint>
#include <functional>
#include <memory>
#include <utility>
#include <type_traits>
#include <new>
#include <span>
#include <string>
#include <vector>

#include "mbvh/scene.h"
#include "mbvh/mbvh_layout.h"

namespace mbvh {

/// Allocator of cache-line (64-byte) aligned arrays: a 128-byte MBVH4 node then spans two cache
/// lines, not three, and a leaf's triangles start on a line.
template <class T>
struct CacheAligned {
  using value_type = T;
  static constexpr std::align_val_t align{64};
  CacheAligned() = default;
  template <class U>
  CacheAligned(const CacheAligned<U>&) {}
  T* allocate(std::size_t n) { return static_cast<T*>(::operator new(n * sizeof(T), align)); }
  void deallocate(T* p, std::size_t) { ::operator delete(p, align); }
  /// Value-initialises, except Tri, Node4 and Node8: a triangle array and the collapse's wide
  /// node arrays are sized and then every word written by parallel passes (build, refit,
  /// collapse), which then also first touch their pages, instead of one thread zeroing them
  /// beforehand (the first touch of a page is the costly part; it is done in parallel this way).
  template <class U, class... Args>
  void construct(U* p, Args&&... args) {
    if constexpr (sizeof...(Args) == 0 && (std::is_same_v<U, Tri> || std::is_same_v<U, Node4> || std::is_same_v<U, Node8>))
      ::new (static_cast<void*>(p)) U;
    else ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
  template <class U>
  bool operator==(const CacheAligned<U>&) const { return true; }
};
template <class T>
using AlignedVector = std::vector<T, CacheAligned<T>>;

/// The build's private structures (host/core/layouts.h): a user never needs them; the backends
/// of this repository read them through the accessors below (their types are incomplete here).
struct Bvh2;
struct Mbvh2;
struct Mbvh4;
struct Mbvh8;
struct Mbvh4Wide;
struct TriPacks;
struct LeafVariant;


/// The node layouts; automatic ("auto"): the layout the backend traces fastest for the query
/// (TraceOptions, resolve_options in backend.h), resolved before anything is built or traced.
enum class Layout { mbvh2, mbvh4, mbvh8, automatic };
const char* to_string(Layout l);
Layout parse_layout(const std::string& s);  ///< throws Error on an unknown name

/// The coordinate range traced exactly under DESIGN.md's numerical contract (measured on closed
/// spheres with every ray kind against the double brute force: exact from 1e-12 to 1e13, lost hits
/// from 1e-13 and 1e14 on, as the watertight test's products of three coordinates leave the float
/// range). Accel::build refuses a scene whose non-degenerate triangles reach beyond ±kMaxCoordinate
/// or whose largest coordinate magnitude is below kMinSceneScale: rescale such a scene.
constexpr float kMaxCoordinate = 0x1p40f;   // 1.1e12
constexpr float kMinSceneScale = 0x1p-36f;  // 1.5e-11
/// The smallest triangle area traced exactly: the watertight test's float products of a
/// triangle's edges underflow below it, and a ray passes through the triangle to whatever lies
/// behind (measured beside a unit triangle: hits lost from an area of 2^-145 on, none at 2^-110
/// and above on any backend). Accel::build and Accel::refit refuse a triangle whose area is
/// below it but not zero (a zero-area triangle is degenerate: kept out of the leaves, never hit).
constexpr float kMinTriangleArea = 0x1p-110f;  // 7.7e-34
/// A ray's share of the range. The watertight test divides by the direction's largest component
/// D (its sheared z), so its products scale as M^3 / D, where M = max(the scene's largest
/// coordinate S, the origin's largest coordinate), and t as M / D: a direction of 1e37 or 1e-37
/// leaves the float range as a scene at 1e30 does. Measured on closed spheres at both ends of the
/// range and at unit scale, primary, diffuse, shadow and random rays with directions scaled by
/// 2^k, against the double brute force: hits lost from M^3 / D = 2^135 and S^3 / D = 2^-124.6 on
/// (none at 2^133 and 2^-122.6), and at unit scale from M / D = 2^124 (none at 2^122.4). A traced
/// ray must keep M^3 / D <= kMaxRayCube, S^3 / D >= kMinRayCube, M / D <= kMaxRayRatio and
/// S / D >= 1 / kMaxRayRatio; Backend::trace, trace_reference and trace_one refuse one that does
/// not (check_ray_range). In a scene Accel::build accepts, a unit direction from an origin within
/// 4x the scene's largest coordinate never leaves them.
constexpr double kMaxRayCube = 0x1p128;
constexpr double kMinRayCube = 0x1p-116;
constexpr double kMaxRayRatio = 0x1p100;

/// Which builder makes the binary BVH (`--quality`). low, medium and high produce the same
/// structures (Bvh2, leaves, leaf-ordered triangles), so every layout and backend traces any of
/// them. With `high` a triangle may sit in more than one leaf (never twice in one; up to 10 % more
/// references), for fewer node visits and triangle tests per ray.
/// `none` builds no hierarchy, for the backends that trace without one (BackendInfo::
/// needs_hierarchy false: dacrt, divide-and-conquer ray tracing). Scene::validate, the coordinate
/// range checks, the kMinTriangleArea check and the degenerate filter run exactly as in every
/// build; tris() holds the non-degenerate triangles in scene (prim) order; bounds(), hash(),
/// generation(), scene_triangles(), geometry_of(), binary_stats() (0 nodes and leaves) and refit()
/// work. The layout accessors (bvh2() to mbvh4_wide(), make_layout, tri_packs, leaf_variant,
/// leaves) throw Error: a backend that needs a hierarchy refuses such a build (Backend::prepare,
/// Backend::trace), and so do trace_one and trace_reference. O(n), no sort. Appended last: the
/// cache header stores the value (a none build is never cached; build_cached, save).
enum class BuildQuality {
  low,     ///< Morton-code LBVH (Karras 2012): several times faster to build, slower to trace
  medium,  ///< binned SAH (Wald 2007): the default
  high,    ///< spatial splits (SBVH, Stich et al. 2009; sbvh.cpp), then reinsertion (Meister & Bittner 2018; reinsert.cpp);
           ///< the same without spatial splits where that reaches the lower SAH (sbvh.cpp build_high)
  none,    ///< no hierarchy: the triangles alone, for the dacrt backends (see above)
};
const char* to_string(BuildQuality q);
BuildQuality parse_quality(const std::string& s);  ///< throws Error on an unknown name

/// Memory kept between builds, for a caller that rebuilds (an animation rebuilding each frame):
/// set BuildOptions::context to one and Accel::build takes its working arrays (the primitive
/// records, the builder's node arenas) from it and gives them back
/// when it returns, and the build's output arrays (binary nodes, leaf boxes, leaf table,
/// triangle records, MBVH4 nodes) come from it too and go back to it when that Accel is
/// destroyed. A rebuild then writes memory that is already mapped instead of faulting in fresh
/// pages (on a virtual machine the first touch of a 4 KiB page costs microseconds). The tree is
/// the same bytes with or without a context, at any thread count, whatever was built in it before.
/// Retained memory: at most one build's working arrays and one build's output arrays, each the
/// largest built with it since the last release(): 32 bytes per triangle plus the node block (96
/// bytes per triangle: room for two 48-byte nodes a record, of which only the nodes made are
/// touched), and the outputs' size (Accel::memory(), without layouts other than MBVH4). Without a
/// context, or after release(), a build frees its memory to the allocator, which returns it to
/// the system once the freed heap has grown by about two builds. Thread-safe: concurrent builds
/// may share one context (each takes what it holds at its start; the others allocate). Keep it in
/// a std::shared_ptr (BuildOptions::context): every Accel built with it holds a reference, so it
/// lives as long as they do.
class BuildContext {
public:
  BuildContext();
  ~BuildContext();
  BuildContext(const BuildContext&) = delete;
  BuildContext& operator=(const BuildContext&) = delete;
  /// Bytes of the arrays it holds now (their capacity), not counting those lent to a live build
  /// or Accel.
  std::size_t retained_bytes() const;
  /// Frees what it holds now (arrays lent out come back later, unless released again then).
  void release();
  struct Impl;  ///< host/core/bvh/builder.h
  Impl& impl() const { return *impl_; }  ///< internal (the builders)
private:
  std::unique_ptr<Impl> impl_;
};

struct BuildOptions {
  unsigned threads = 0;         ///< 0: every hardware thread; the result does not depend on it
  unsigned max_leaf = 8;        ///< largest leaf the SAH may choose (the depth cap may force bigger)
  unsigned bins = 32;           ///< SAH bins per axis, the most a node gets (one of n records: min(bins, 4 + n / 20))
  /// Triangles one leaf test costs as one in the SAH: a leaf of n triangles costs ceil(n / B)
  /// (Embree's SAH "blocks"). 1, the default, prices every triangle: the build all backends share.
  /// 4 prices four-wide SIMD leaves for every backend: fewer, fuller leaves, 10-20 % slower on the
  /// OpenCL and Vulkan backends, which test a leaf's triangles one by one. The SIMD cpu backends
  /// regroup the default build's leaves for themselves instead (TraceOptions::leaf_block;
  /// docs/backends.md, "The cpu backend").
  unsigned leaf_block = 1;
  unsigned depth_cap = MBVH_BINARY_DEPTH_CAP;  ///< binary leaf depth limit (root children: 1)
  float traversal_cost = 1.0f;  ///< SAH cost of one node visit, relative to one triangle test
  BuildQuality quality = BuildQuality::medium;  ///< the builder (BuildQuality)
  std::function<void(double)> progress;  ///< if set, called with the fraction done (any thread)
  /// If set, memory kept between builds (BuildContext above); it never changes the tree.
  std::shared_ptr<BuildContext> context;
};

/// Statistics of one layout (binary tree, MBVH2 or MBVH4).
struct LayoutStats {
  std::string layout;
  std::size_t nodes = 0;         ///< inner-node records
  std::size_t leaves = 0;
  unsigned depth = 0;            ///< levels below the root of the deepest leaf
  double sah_cost = 0;           ///< sum over nodes of area/root area * cost (node visit 1, triangle 1)
  std::size_t bytes = 0;         ///< node records (+ leaves and triangles for the binary tree)
  double build_ms = 0;
  /// The binary build's phases, ms (binary stats only): records (boxes, degenerate triangles,
  /// range check), tree (binning and partition; or, for quality low, Morton codes, splits and the
  /// Bvh2 written by the LBVH itself), flatten (the Bvh2, except for quality low, and the
  /// leaf-ordered triangles), stats (the hash is computed on first use: Accel::hash).
  double phase_ms[4] = {0, 0, 0, 0};
  unsigned bitstack_bits = 0;    ///< bits of the bitstack word the deepest path needs
};

/// An acceleration structure. Build once with Accel::build; layouts are made on first use
/// (thread-safe) and kept.
class Accel {
public:
  /// Builds the binary BVH (with BuildQuality::none: only the triangle records, no hierarchy;
  /// O(n), parallel). Throws Error if the scene has no non-degenerate triangle, fails
  /// Scene::validate (a vertex index out of range, a NaN or infinite vertex) or
  /// `opt.traversal_cost` is negative or not finite, or if its coordinates leave the exactly traced
  /// range (kMaxCoordinate, kMinSceneScale); other options are clamped to what works
  /// (threads to kMaxThreads, bins to 2..64, max_leaf and leaf_block to at least 1).
  /// Cost: O(n log n), parallel over `opt.threads`; the bytes do not depend on the thread count.
  static std::unique_ptr<Accel> build(const Scene& scene, const BuildOptions& opt = {});

  /// The BVH cache (host/core/bvh/cache.cpp). build_cached returns the build of `scene` with `opt`
  /// from DIR/<key>.mbvh when that file holds it, else builds and writes it there (atomically, by
  /// a rename over the entry's name; DIR is made if missing). An entry is never read or written
  /// through a symbolic link: a link at the entry's name is left unread and replaced by the entry
  /// (its target untouched). A file that is truncated, damaged, of another format version, made for
  /// other triangles, options or library version, or not exactly the tree and triangle records a
  /// build makes of this scene (cache_check.h: every reference, empty slot, parent link, height,
  /// box and leaf range; every record compared with the scene's triangle) is never traced from: it
  /// is rebuilt and replaced, and `report->problem` says what was wrong. Concurrent calls with one
  /// DIR (threads or processes) are safe. Throws Error when DIR cannot be made, when the entry is
  /// one of `other_files` (same file, by inode or path), when the file cannot be written (saying
  /// what was wrong with the old one, if anything), and as build does. Cost of a hit: reading the
  /// file and O(triangles) checks, far less than a build. With BuildQuality::none it builds
  /// without reading or writing DIR (the report's path stays empty): that build is O(n), no dearer
  /// than reading and checking an entry would be.
  struct CacheOptions {
    std::string dir;  ///< the cache directory
    /// The files the calling command reads or writes (scene, rays, outputs): an entry that is one
    /// of them is an error before anything is read or written.
    std::vector<std::string> other_files;
    /// A size bound on the directory, 0 for none: after the entry is read or written, the least
    /// recently used other entries (by modification time; a hit touches its entry) are removed
    /// until the directory's entries (regular files named <16 hex digits>.mbvh; nothing else in
    /// DIR is counted or removed) total at most max_bytes. The entry just used is always kept.
    std::uint64_t max_bytes = 0;
  };
  struct CacheReport {
    std::string path;     ///< the cache file
    bool loaded = false;  ///< true: read from the file; false: built (and written)
    std::string problem;  ///< why an existing file was not used, or empty
    std::size_t evicted = 0;            ///< entries removed for CacheOptions::max_bytes
    std::uint64_t evicted_bytes = 0;    ///< their bytes
  };
  static std::unique_ptr<Accel> build_cached(const Scene& scene, const BuildOptions& opt, const CacheOptions& cache,
                                             CacheReport* report = nullptr);
  /// build_cached with CacheOptions{dir}.
  static std::unique_ptr<Accel> build_cached(const Scene& scene, const BuildOptions& opt, const std::string& dir,
                                             CacheReport* report = nullptr);
  /// The cache key: a content hash of the scene's vertices and triangles, the options that shape
  /// the tree (not threads) and the library version.
  static std::uint64_t cache_key(const Scene& scene, const BuildOptions& opt);
  /// Writes this build to `path` (atomically, through a temporary) under `key`. Throws Error for
  /// a build of quality none (it has no tree to keep; rebuilding it is O(n)).
  void save(const std::string& path, std::uint64_t key) const;
  /// Reads a build written by save; throws Error naming the path and what is wrong when the file
  /// is a symbolic link (never followed), truncated, damaged (checksum), of another format version
  /// or record size, of another key, or not a well-formed tree (build::check_tree). Its triangle
  /// records are checked against a scene only by build_cached. O(file size).
  static std::unique_ptr<Accel> load(const std::string& path, std::uint64_t key);

  ~Accel();
  /// False for a build of BuildQuality::none: then bvh2(), mbvh2(), mbvh4(), mbvh8(),
  /// mbvh4_wide(), make_layout(), tri_packs(), leaf_variant() and leaves() throw Error ("this
  /// build has no hierarchy (quality none) ..."); tris() and the rest work.
  bool has_hierarchy() const;
  const Bvh2& bvh2() const;
  const Mbvh2& mbvh2() const;   ///< MBVH2 layout (Aila–Laine nodes with links), made on first use
  const Mbvh4& mbvh4() const;   ///< MBVH4 layout (depth-aware SAH-guided collapse), made on first use
  const Mbvh8& mbvh8() const;   ///< MBVH8 layout (the same collapse, eight wide), made on first use
  const Mbvh4Wide& mbvh4_wide() const;  ///< its 16-wide view (OpenCL, TRAVERSAL.md §8), made on first use
  void make_layout(Layout l) const;  ///< makes layout `l` now (its accessor above), not on first trace
  const TriPacks& tri_packs() const;  ///< the leaves as SIMD packs, made on first use
  /// The build with its leaves regrouped for leaf tests of `block` (2 to 64) triangles at a time
  /// (TraceOptions::leaf_block above 1; host/core/layouts.h), made on first use and kept;
  /// thread-safe. refit() drops the variants: the next trace that asks for one regroups the
  /// refit tree again (O(nodes), the collapse and packs: conference about 20 ms), and may choose
  /// other leaves, as the boxes moved.
  const LeafVariant& leaf_variant(unsigned block) const;
  /// The triangle records: leaf-ordered (a spatial-split build may hold a triangle more than
  /// once), or with quality none the non-degenerate triangles once each in scene order. Every
  /// record's prim id is its triangle's (tri_prim).
  const AlignedVector<Tri>& tris() const;
  const std::vector<Leaf>& leaves() const;
  /// Triangles of the scene kept out of the build as degenerate (zero area).
  std::size_t degenerate_triangles() const;
  const Box& bounds() const;
  std::size_t scene_triangles() const;
  /// Geometries of the scene it was built from (Scene::geometry_count(); 1 after Accel::load).
  std::size_t geometry_count() const;
  /// Scene::geometry_of of the scene it was built from (kept by the build: the scene and the
  /// caller's buffers need not outlive it). O(log geometries).
  GeomPrim geometry_of(std::uint32_t prim) const;
  const LayoutStats& binary_stats() const;
  const BuildOptions& options() const;
  /// 64-bit hash of the build's bytes (nodes, leaves, triangles; quality none: its triangles);
  /// equal across thread counts.
  /// Changes when refit() moves a vertex. Computed on the first call (thread-safe; O(bytes),
  /// parallel over options().threads) and kept: a build that is only traced never pays for it.
  std::uint64_t hash() const;
  /// The bytes a build holds, by part: the records of each array it keeps, counting only what
  /// has been made so far (layouts, packs and leaf variants are made on first use, by a trace or
  /// the accessors). Not the scene: the caller's (Scene::memory_bytes).
  struct MemoryStats {
    /// The binary trees: the build's (nodes, leaf boxes, leaf table), which refit, the layouts'
    /// collapse, hash() and save() read, and each leaf variant's regrouped one.
    std::size_t tree = 0;
    /// The traced node records: MBVH2/4/8, the 16-wide view, the leaf variants' layouts, their
    /// leaf tables and the copies whose leaf references locate the packs.
    std::size_t nodes = 0;
    std::size_t triangles = 0;  ///< the triangle records (tris(), 48 bytes each)
    std::size_t packs = 0;      ///< the SIMD leaf packs (160 bytes per four triangles; the `fast` precision's copy as much again, once a fast trace made it) and their leaf tables
    std::size_t total() const { return tree + nodes + triangles + packs; }
  };
  /// This build's MemoryStats. O(leaf variants); not concurrently with a call that makes a layout,
  /// packs or a leaf variant (a trace's first preparation, the accessors above) or with refit().
  MemoryStats memory() const;
  /// Starts at 0 and is bumped by every refit(): a backend that copied the build to a device
  /// re-uploads it when (&accel, hash(), generation()) changes since its last prepare().
  std::uint64_t generation() const;

  /// Refits the build to new vertex positions with the same topology (quality none: recomputes
  /// the triangles and bounds(), with the same checks and refusals): `moved` must be the scene
  /// this Accel was built from (the same triangles, the same vertex indices, the same meshes with
  /// the same triangle counts) with vertices moved; a scene of views is read through them, so the
  /// caller may move the vertices in its own buffers and refit with the same Scene.
  /// Recomputes, in place and from the float vertices exactly as the build does, the leaf-ordered
  /// triangles, every leaf box, every binary node box bottom-up, and the boxes of every layout and
  /// pack already made (MBVH2/4/8, the 16-wide view, the SIMD packs; leaf variants are dropped and
  /// remade on next use, see leaf_variant); the topology (nodes, leaves,
  /// the triangles' leaf order) is kept, so traversal stays exact but may do more work than a
  /// rebuild's tree (boxes grow as vertices move apart). Updates hash(), the SAH costs and bumps
  /// generation(). O(triangles + nodes), parallel over options().threads, the same bytes at any
  /// thread count. Throws Error (leaving the Accel unchanged) if the triangle count or the
  /// geometries' triangle counts differ,
  /// Scene::validate fails, a coordinate leaves the exactly traced range, or a triangle the build
  /// kept out as degenerate now has area (it is in no leaf: rebuild instead).
  /// Not thread-safe: no trace or layout access may run concurrently.
  void refit(const Scene& moved);
  double last_refit_ms() const;  ///< wall time of the last refit()
private:
  Accel();
  /// load, with the counts in the header bounded by `scene`'s triangle count (when given) before
  /// anything is allocated.
  static std::unique_ptr<Accel> load_entry(const std::string& path, std::uint64_t key, const Scene* scene);
  void drop_leaf_variants();  ///< refit: forget the leaf variants (remade on next use)
  /// Throws the Error of a build without a hierarchy (quality none), naming accessor `what`.
  void require_hierarchy(const char* what) const;
  void refit_triangles(const Scene& moved);  ///< refit of a build without a hierarchy (refit.cpp)
  struct Impl;  ///< host/core/layouts.h
  std::unique_ptr<Impl> impl_;
};

}  // namespace mbvh

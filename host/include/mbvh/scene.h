// SPDX-License-Identifier: MIT
// scene.h — a triangle scene (float vertices, uint32 triangles, or views of the caller's meshes)
// and how to get one: OBJ, PLY (optionally zstd-compressed) or a built-in generator named
// "gen:NAME:PARAMS".
#pragma once
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <vector>

namespace mbvh {

struct Vec3f {
  float x = 0, y = 0, z = 0;
  float operator[](int a) const { return a == 0 ? x : (a == 1 ? y : z); }
  float& operator[](int a) { return a == 0 ? x : (a == 1 ? y : z); }
};

/// Axis-aligned box; an empty box has lo = +inf, hi = -inf.
struct Box {
  Vec3f lo{INFINITY, INFINITY, INFINITY};
  Vec3f hi{-INFINITY, -INFINITY, -INFINITY};
  void grow(const Vec3f& p) {
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  void grow(const Box& b) {
    lo = {std::min(lo.x, b.lo.x), std::min(lo.y, b.lo.y), std::min(lo.z, b.lo.z)};
    hi = {std::max(hi.x, b.hi.x), std::max(hi.y, b.hi.y), std::max(hi.z, b.hi.z)};
  }
  bool empty() const { return !(lo.x <= hi.x); }
  Vec3f center() const { return {0.5f * (lo.x + hi.x), 0.5f * (lo.y + hi.y), 0.5f * (lo.z + hi.z)}; }
  Vec3f extent() const { return {hi.x - lo.x, hi.y - lo.y, hi.z - lo.z}; }
  /// Half the surface area (the SAH only needs ratios); 0 for an empty box. Inline: the builders
  /// and collapses call it per node.
  float half_area() const {
    if (empty()) return 0.0f;
    const Vec3f e = extent();
    return e.x * e.y + e.y * e.z + e.z * e.x;
  }
};

/// The geometry that holds prim id `prim`, from the geometries' prim offsets (`count` + 1
/// ascending entries, offsets[0] = 0; geometry g holds [offsets[g], offsets[g + 1])). Requires
/// prim < offsets[count]. O(log count).
inline std::size_t geometry_index(const std::uint64_t* offsets, std::size_t count, std::uint64_t prim) {
  return static_cast<std::size_t>(std::upper_bound(offsets, offsets + count + 1, prim) - offsets) - 1;
}

/// A view of one caller-owned triangle mesh (mbvh/geometry.h has the rules): vertex v is the
/// three floats x, y, z at byte offset v * vertex_stride from `vertices` (so positions may sit
/// inside interleaved vertex records); triangle t is the three uint32 vertex indices at byte
/// offset t * index_stride from `indices`. Nothing is copied: the builders read through the view.
/// Neither pointer needs more than byte alignment.
struct MeshView {
  const float* vertices = nullptr;
  std::size_t vertex_count = 0;
  std::size_t vertex_stride = 12;  ///< bytes between vertices, >= 12
  const std::uint32_t* indices = nullptr;
  std::size_t triangle_count = 0;
  std::size_t index_stride = 12;   ///< bytes between triangles, >= 12

  /// Vertex v (v < vertex_count, unchecked).
  Vec3f vertex(std::size_t v) const {
    Vec3f p;
    std::memcpy(&p, reinterpret_cast<const unsigned char*>(vertices) + v * vertex_stride, sizeof p);
    return p;
  }
  /// The vertex indices of triangle t (t < triangle_count, unchecked).
  std::array<std::uint32_t, 3> triangle(std::size_t t) const {
    std::array<std::uint32_t, 3> i;
    std::memcpy(i.data(), reinterpret_cast<const unsigned char*>(indices) + t * index_stride, sizeof i);
    return i;
  }
};

/// The most triangles one scene may hold (32-bit references with room for the leaf encoding).
constexpr std::uint64_t kMaxTriangles = 0x7FFFFFF0u;

/// The invalid geometry id: the geometry of a miss (MBVH_MISS_PRIM) or of no triangle.
constexpr std::uint32_t kInvalidGeometry = 0xFFFFFFFFu;

/// A triangle named by its geometry (mesh) and its index within that mesh.
struct GeomPrim {
  std::uint32_t geom_id = kInvalidGeometry;
  std::uint32_t prim_id = 0xFFFFFFFFu;  ///< MBVH_MISS_PRIM when geom_id is kInvalidGeometry
};

/// A surface material read from an OBJ file's MTL library (`newmtl` NAME with its `Kd`).
struct Material {
  std::string name;                 ///< the `usemtl` name
  Vec3f diffuse{0.7f, 0.7f, 0.7f};  ///< linear RGB albedo in [0, 1]: the MTL's Kd, grey when it has none
};

/// The material index of a triangle that has none (faces before the OBJ file's first `usemtl`).
constexpr std::uint32_t kNoMaterial = 0xFFFFFFFFu;

/// A scene: either owned arrays (vertices, triangles: what the loaders and generators produce) or
/// views of the caller's meshes (add_mesh), never both. Owned: triangle i is the i-th triangle of
/// the file after fan-triangulating polygons as (0, k, k+1), its prim id is i, and the scene is
/// geometry 0. Views: mesh g's triangles are the prim ids [offset_g, offset_g + count_g) in the
/// order the meshes were added (offset_0 = 0), which is what every backend reports; geometry_of
/// turns such an id back into (geometry, triangle of that geometry). Copying a Scene copies its
/// views, not the caller's buffers they point to.
struct Scene {
  std::string name;                              ///< the path or generator spec it came from
  /// `name`, or "scene (unnamed)" when it is empty: what the library's messages call the scene.
  std::string display_name() const { return name.empty() ? std::string("scene (unnamed)") : name; }
  std::vector<Vec3f> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;
  /// Materials of an owned scene loaded from OBJ: every `usemtl` name in first-use order, with
  /// its diffuse colour from the `mtllib` files (load_scene reads them). Empty for PLY and
  /// generated scenes. Neither materials nor triangle_materials are part of hash() or of a build.
  std::vector<Material> materials;
  /// Per triangle of an owned scene: its index into `materials` (kNoMaterial: none); empty when
  /// the file names no material, else exactly triangles.size() entries.
  std::vector<std::uint32_t> triangle_materials;

  /// Adds a view of a caller-owned mesh and returns its geometry id (0, 1, ... in call order).
  /// The view's buffers are not copied: they must stay alive and unchanged while anything reads
  /// the scene's triangles (validate, bounds, hash, triangle, Accel::build and build_cached until
  /// they return, Accel::refit until it returns). Throws Error (naming the geometry id) if
  /// `triangles` is not empty, a pointer is null with a nonzero count, a stride is below 12 bytes
  /// or the scene would exceed 2^31 - 16 triangles. Indices and coordinates are checked by
  /// validate (so the buffers may be filled after this call). O(1).
  std::uint32_t add_mesh(const MeshView& mesh);
  /// The views added by add_mesh, in geometry id order (empty for an owned scene).
  const std::vector<MeshView>& meshes() const { return meshes_; }
  /// Geometries: the number of views, or 1 for an owned scene.
  std::size_t geometry_count() const { return meshes_.empty() ? 1 : meshes_.size(); }
  /// Prim ids of geometry g start here (g <= geometry_count(); g = geometry_count(): the total).
  std::size_t geometry_offset(std::size_t g) const {
    return meshes_.empty() ? (g == 0 ? 0 : triangles.size()) : static_cast<std::size_t>(offsets_[g]);
  }
  /// Triangles of every geometry together: the prim ids are 0 .. triangle_count() - 1.
  std::size_t triangle_count() const { return meshes_.empty() ? triangles.size() : static_cast<std::size_t>(offsets_.back()); }
  /// (geometry id, index within it) of a prim id; {kInvalidGeometry, MBVH_MISS_PRIM} for
  /// MBVH_MISS_PRIM or any id >= triangle_count(). O(log geometries).
  GeomPrim geometry_of(std::uint32_t prim) const;
  /// The three vertices of triangle `prim` (prim < triangle_count(), indices valid: validate()).
  void triangle(std::size_t prim, Vec3f& a, Vec3f& b, Vec3f& c) const {
    if (meshes_.empty()) {
      const auto& t = triangles[prim];
      a = vertices[t[0]], b = vertices[t[1]], c = vertices[t[2]];
      return;
    }
    const std::size_t g = mesh_of(prim);
    const MeshView& m = meshes_[g];
    const auto t = m.triangle(prim - static_cast<std::size_t>(offsets_[g]));
    a = m.vertex(t[0]), b = m.vertex(t[1]), c = m.vertex(t[2]);
  }
  /// Bytes the scene's own arrays hold (their capacity): an owned scene's vertices and triangles;
  /// for a scene of views, the view records only (the caller's buffers are the caller's). O(1).
  std::size_t memory_bytes() const {
    return vertices.capacity() * sizeof(Vec3f) + triangles.capacity() * sizeof(triangles[0]) +
           meshes_.capacity() * sizeof(MeshView) + offsets_.capacity() * sizeof(std::uint64_t);
  }
  /// Throws Error (naming the scene, the geometry when it has views, the triangle and the index
  /// or coordinate) if a triangle names a vertex that does not exist or uses a vertex with a NaN
  /// or infinite coordinate. Unused vertices are not looked at. O(triangles).
  void validate() const;
  Box bounds() const;                            ///< box of the vertices used by triangles (requires validate())
  /// 64-bit content hash of vertices and triangles (word-wise FNV-1a in chunks), for build caching and reports. A
  /// scene of views hashes each mesh's positions and indices (not the bytes between them); one
  /// view hashes as the owned scene with the same vertices and triangles.
  std::uint64_t hash() const;

private:
  /// The view holding prim (meshes_ not empty, prim < triangle_count()).
  std::size_t mesh_of(std::size_t prim) const;
  std::vector<MeshView> meshes_;
  std::vector<std::uint64_t> offsets_{0};  ///< prim id of each view's first triangle, then the total
};

/// Loads a scene from a path (.obj, .ply, optionally .zst-compressed; .mtri, a streamed triangle
/// file, read in checked blocks with 3 vertices a triangle) or a generator spec
/// ("gen:sphere:64", "gen:soup:100000:7", "gen:hairball:1000000", "gen:exponential:200",
/// "gen:cube:16", "gen:mandelbulb:128"). An OBJ file's materials get their diffuse colours from the MTL files its
/// `mtllib` lines name (a missing or bad MTL is a warning through log_message, never an error:
/// those materials stay grey). Throws Error naming the file, line and what was wrong on malformed input, and
/// naming the path or spec and the estimate when the scene and one build of it would not fit in
/// the memory budget (MBVH_MEMORY_LIMIT, else the available memory), checked before allocating wherever the size is known first
/// (file and decompressed sizes, PLY counts, generator parameters). An input that is not a
/// regular file (directory, FIFO, device) is refused unopened.
Scene load_scene(const std::string& path_or_spec);

/// Parsers on an in-memory buffer (already decompressed); `name` is used in error messages.
/// parse_obj keeps the `usemtl` names as grey materials and reads no MTL file.
/// Neither drops or shifts geometry silently: a leading UTF-8 byte-order mark is skipped, CRLF
/// line ends are accepted, and anything else they cannot read exactly is an Error naming the
/// line (see the notes atop host/core/io/obj.cpp and host/core/io/ply.cpp).
Scene parse_obj(const std::string& name, const char* data, std::size_t size);
Scene parse_ply(const std::string& name, const char* data, std::size_t size);

/// Reads a whole file, transparently decompressing zstd (by magic number). Throws Error on a path
/// that is not a regular file (unopened) and on a file or decompressed size beyond the memory budget (MBVH_MEMORY_LIMIT).
std::vector<char> read_file(const std::string& path);
/// Decompresses `data` if it starts with the zstd magic number, else returns it unchanged;
/// `name` is used in error messages. Throws Error on a corrupt or truncated stream, and when the
/// frame header's content size (before decompressing) or the output so far exceeds the memory budget.
std::vector<char> maybe_decompress(const std::string& name, std::vector<char> data);

/// Builds a generated scene from "NAME:PARAMS" (the part after "gen:"). Throws Error on bad
/// parameters, and before generating when the memory its size needs exceeds the memory budget.
Scene generate_scene(const std::string& spec);
/// One line per generator, for --help texts.
std::string generator_help();

}  // namespace mbvh

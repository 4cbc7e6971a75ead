// SPDX-License-Identifier: MIT
// scene.h — a triangle scene (float vertices, uint32 triangles) and how to get one: OBJ, PLY
// (optionally zstd-compressed) or a built-in generator named "gen:NAME:PARAMS".
#pragma once
#include <array>
#include <cmath>
#include <cstdint>
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
  void grow(const Vec3f& p);
  void grow(const Box& b);
  bool empty() const { return !(lo.x <= hi.x); }
  Vec3f center() const { return {0.5f * (lo.x + hi.x), 0.5f * (lo.y + hi.y), 0.5f * (lo.z + hi.z)}; }
  Vec3f extent() const { return {hi.x - lo.x, hi.y - lo.y, hi.z - lo.z}; }
  /// Half the surface area (the SAH only needs ratios); 0 for an empty box.
  float half_area() const;
};

/// A scene: vertices and triangles. Triangle i is the i-th triangle of the file after
/// fan-triangulating polygons as (0, k, k+1): its prim id is i.
struct Scene {
  std::string name;                              ///< the path or generator spec it came from
  std::vector<Vec3f> vertices;
  std::vector<std::array<std::uint32_t, 3>> triangles;

  std::size_t triangle_count() const { return triangles.size(); }
  /// Throws Error (naming the scene, the triangle and the index or coordinate) if a triangle
  /// names a vertex that does not exist or uses a vertex with a NaN or infinite coordinate.
  /// Unused vertices are not looked at. O(triangles).
  void validate() const;
  Box bounds() const;                            ///< box of the vertices used by triangles (requires validate())
  /// 64-bit content hash of vertices and triangles (FNV-1a), for build caching and reports.
  std::uint64_t hash() const;
};

/// Loads a scene from a path (.obj, .ply, optionally .zst-compressed) or a generator spec
/// ("gen:sphere:64", "gen:soup:100000:7", "gen:hairball:1000000", "gen:exponential:200",
/// "gen:cube:16"). Throws Error naming the file, line and what was wrong on malformed input, and
/// naming the path or spec and the estimate when the scene and one build of it would not fit in
/// memory_budget() (host/resources.h), checked before allocating wherever the size is known first
/// (file and decompressed sizes, PLY counts, generator parameters). An input that is not a
/// regular file (directory, FIFO, device) is refused unopened.
Scene load_scene(const std::string& path_or_spec);

/// Parsers on an in-memory buffer (already decompressed); `name` is used in error messages.
/// Neither drops or shifts geometry silently: a leading UTF-8 byte-order mark is skipped, CRLF
/// line ends are accepted, and anything else they cannot read exactly is an Error naming the
/// line (see the notes atop host/core/io/obj.cpp and host/core/io/ply.cpp).
Scene parse_obj(const std::string& name, const char* data, std::size_t size);
Scene parse_ply(const std::string& name, const char* data, std::size_t size);

/// Reads a whole file, transparently decompressing zstd (by magic number). Throws Error on a path
/// that is not a regular file (unopened) and on a file or decompressed size beyond memory_budget().
std::vector<char> read_file(const std::string& path);
/// Decompresses `data` if it starts with the zstd magic number, else returns it unchanged;
/// `name` is used in error messages. Throws Error on a corrupt or truncated stream, and when the
/// frame header's content size (before decompressing) or the output so far exceeds memory_budget().
std::vector<char> maybe_decompress(const std::string& name, std::vector<char> data);

/// Builds a generated scene from "NAME:PARAMS" (the part after "gen:"). Throws Error on bad
/// parameters, and before generating when scene_memory_estimate() of its size exceeds memory_budget().
Scene generate_scene(const std::string& spec);
/// One line per generator, for --help texts.
std::string generator_help();

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// scene.cpp — Box and Scene helpers (the caller's mesh views among them) and load_scene: dispatch
// by "gen:" prefix or file content.
#include "mbvh/scene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>

#include "mbvh/error.h"
#include "host/core/io/input.h"
#include "host/core/io/mtl.h"
#include "host/core/io/mtri.h"
#include "host/core/io/obj.h"
#include "host/core/layouts.h"  // hash_bytes
#include "host/core/resources.h"

namespace mbvh {

std::uint32_t Scene::add_mesh(const MeshView& m) {
  const std::string who = display_name() + ": geometry " + std::to_string(meshes_.size());
  if (!triangles.empty())
    throw Error(who + ": add_mesh on a scene with owned triangles; a scene holds owned arrays or mesh views, not both");
  if (!m.vertices && m.vertex_count > 0)
    throw Error(who + ": the vertex pointer is null but vertex_count is " + std::to_string(m.vertex_count));
  if (!m.indices && m.triangle_count > 0)
    throw Error(who + ": the index pointer is null but triangle_count is " + std::to_string(m.triangle_count));
  if (m.vertex_stride < 12)
    throw Error(who + ": vertex_stride is " + std::to_string(m.vertex_stride) + " bytes; it must be at least 12 (x, y, z)");
  if (m.index_stride < 12)
    throw Error(who + ": index_stride is " + std::to_string(m.index_stride) + " bytes; it must be at least 12 (three uint32)");
  if (m.triangle_count > kMaxTriangles - offsets_.back())
    throw Error(who + ": " + std::to_string(m.triangle_count) + " more triangles exceed the " + std::to_string(kMaxTriangles) +
                " a scene may hold (32-bit prim ids)");
  meshes_.push_back(m);
  offsets_.push_back(offsets_.back() + m.triangle_count);
  return static_cast<std::uint32_t>(meshes_.size() - 1);
}

std::size_t Scene::mesh_of(std::size_t prim) const {
  return geometry_index(offsets_.data(), meshes_.size(), prim);
}

GeomPrim Scene::geometry_of(std::uint32_t prim) const {
  if (prim >= triangle_count()) return {};
  if (meshes_.empty()) return {0, prim};
  const std::size_t g = mesh_of(prim);
  return {static_cast<std::uint32_t>(g), static_cast<std::uint32_t>(prim - offsets_[g])};
}

namespace {

std::string coordinate_text(float c) {
  char value[32];
  std::snprintf(value, sizeof value, "%g", static_cast<double>(c));
  return value;
}

}  // namespace

void Scene::validate() const {
  const std::string who = display_name();
  if (!meshes_.empty()) {
    if (!triangles.empty()) throw Error(who + ": the scene has both owned triangles and mesh views; use one or the other");
    for (std::size_t g = 0; g < meshes_.size(); ++g) {
      const MeshView& m = meshes_[g];
      const std::string geom = who + ": geometry " + std::to_string(g);
      for (std::size_t i = 0; i < m.triangle_count; ++i) {
        const auto t = m.triangle(i);
        for (int k = 0; k < 3; ++k) {
          const std::uint32_t v = t[k];
          if (v >= m.vertex_count)
            throw Error(geom + " triangle " + std::to_string(i) + " (prim " + std::to_string(offsets_[g] + i) + ") names vertex " +
                        std::to_string(v) + ", out of range (the geometry has " + std::to_string(m.vertex_count) + " vertices)");
          const Vec3f p = m.vertex(v);
          for (int a = 0; a < 3; ++a)
            if (!std::isfinite(p[a]))
              throw Error(geom + ": vertex " + std::to_string(v) + " of triangle " + std::to_string(i) + " (prim " +
                          std::to_string(offsets_[g] + i) + ") has coordinate " + "xyz"[a] + " = " + coordinate_text(p[a]) +
                          "; vertices must be finite");
        }
      }
    }
    return;
  }
  for (std::size_t i = 0; i < triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t v = triangles[i][k];
      if (v >= vertices.size())
        throw Error(who + ": triangle " + std::to_string(i) + " names vertex " + std::to_string(v) + ", out of range (the scene has " +
                    std::to_string(vertices.size()) + " vertices)");
      const Vec3f& p = vertices[v];
      for (int a = 0; a < 3; ++a)
        if (!std::isfinite(p[a]))
          throw Error(who + ": vertex " + std::to_string(v) + " of triangle " + std::to_string(i) + " has coordinate " + "xyz"[a] +
                      " = " + coordinate_text(p[a]) + "; vertices must be finite");
    }
}

Box Scene::bounds() const {
  Box b;
  if (meshes_.empty()) {
    for (const auto& t : triangles)
      for (std::uint32_t v : t) b.grow(vertices[v]);
    return b;
  }
  for (const MeshView& m : meshes_)
    for (std::size_t i = 0; i < m.triangle_count; ++i)
      for (std::uint32_t v : m.triangle(i)) b.grow(m.vertex(v));
  return b;
}

std::uint64_t Scene::hash() const {
  // hash_bytes (word-wise) over chunks of kChunk records: a view's records are packed into a
  // chunk first, so one view hashes as the owned arrays holding the same vertices and triangles
  static constexpr std::size_t kChunk = std::size_t(1) << 14;
  std::uint64_t h = 0xcbf29ce484222325ull;
  auto chunks = [&h](const auto* p, std::size_t n) {
    for (std::size_t i = 0; i < n; i += kChunk) h = hash_bytes(p + i, std::min(kChunk, n - i) * sizeof(*p), h);
  };
  if (meshes_.empty()) {
    chunks(vertices.data(), vertices.size());
    chunks(triangles.data(), triangles.size());
    return h;
  }
  std::vector<Vec3f> vb;
  std::vector<std::array<std::uint32_t, 3>> tb;
  for (const MeshView& m : meshes_) {
    if (meshes_.size() > 1) {  // where one mesh ends and the next begins
      const std::uint64_t counts[2] = {m.vertex_count, m.triangle_count};
      h = hash_bytes(counts, sizeof counts, h);
    }
    for (std::size_t v0 = 0; v0 < m.vertex_count; v0 += kChunk) {
      vb.resize(std::min(kChunk, m.vertex_count - v0));
      for (std::size_t j = 0; j < vb.size(); ++j) vb[j] = m.vertex(v0 + j);
      chunks(vb.data(), vb.size());
    }
    for (std::size_t t0 = 0; t0 < m.triangle_count; t0 += kChunk) {
      tb.resize(std::min(kChunk, m.triangle_count - t0));
      for (std::size_t j = 0; j < tb.size(); ++j) tb[j] = m.triangle(t0 + j);
      chunks(tb.data(), tb.size());
    }
  }
  return h;
}

static bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

Scene load_scene(const std::string& path) try {
  if (path.rfind("gen:", 0) == 0) {
    Scene s = generate_scene(path.substr(4));
    s.name = path;
    return s;
  }
  std::string base = ends_with(path, ".zst") ? path.substr(0, path.size() - 4) : path;
  std::transform(base.begin(), base.end(), base.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  // -- a .mtri file (by its name or its magic): streamed in checked blocks, never compressed
  if (!ends_with(path, ".zst") && ends_with(base, ".mtri")) {
    Scene s = load_mtri(path);
    s.name = path;
    return s;
  }
  // -- an OBJ file is parsed as it streams in (decompressed as it is read), so it costs what its
  // geometry costs, never its size; a PLY file is read whole (its size checked before reading)
  bool ply = ends_with(base, ".ply");
  Scene s;
  if (!ply) {
    const bool obj = ends_with(base, ".obj");
    std::string head;  // the first bytes, until the format is known: a "ply" magic after an optional BOM
    std::optional<ObjParser> parser;
    auto decide = [&] {
      const std::size_t bom = head.size() >= 3 && std::memcmp(head.data(), "\xEF\xBB\xBF", 3) == 0 ? 3 : 0;
      ply = head.size() >= bom + 3 && std::memcmp(head.data() + bom, "ply", 3) == 0;
      if (ply) return false;
      if (head.size() >= 6 && std::memcmp(head.data(), kMtriMagic, 6) == 0)
        throw Error(path + ": a .mtri file (by its magic) under another name; name it NAME.mtri");
      if (!obj) throw Error(path + ": unknown scene format (expected .obj, .ply, optionally .zst, or gen:NAME:PARAMS)");
      parser.emplace(path);
      parser->feed(head.data(), head.size());
      return true;
    };
    stream_file(path, [&](const char* data, std::size_t size) {
      if (parser) {
        parser->feed(data, size);
        return true;
      }
      const std::size_t take = std::min<std::size_t>(size, 6 - head.size());
      head.append(data, take);
      if (head.size() < 6) return true;
      if (!decide()) return false;
      parser->feed(data + take, size - take);
      return true;
    });
    if (!parser && !ply) decide();  // a file shorter than 6 bytes
    if (!ply) {
      s = parser->finish();
      read_materials(s, path, parser->material_libraries());
    }
  }
  if (ply) {
    std::vector<char> data = read_file(path);
    s = parse_ply(path, data.data(), data.size());
  }
  // -- the build comes next in every command: refuse it here rather than run out of memory there
  require_memory(path, loading_build_estimate(s.triangles.size(), s.vertices.size()),
                 (build_share() == 1 ? std::string("to build its ") : "to build 1/" + std::to_string(build_share()) + " of its ") +
                     std::to_string(s.triangles.size()) + " triangles");
  return s;
} catch (const std::bad_alloc&) {  // the scene's arrays or a PLY file's bytes: named, the amount unknown
  throw_out_of_memory(path + ": loading the scene", 0);
}

}  // namespace mbvh

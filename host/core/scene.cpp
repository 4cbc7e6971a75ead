// SPDX-License-Identifier: MIT
// scene.cpp — Box and Scene helpers and load_scene: dispatch by "gen:" prefix or file content.
#include "mbvh/scene.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "mbvh/error.h"
#include "host/core/resources.h"

namespace mbvh {

void Box::grow(const Vec3f& p) {
  lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
  hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
}

void Box::grow(const Box& b) {
  lo = {std::min(lo.x, b.lo.x), std::min(lo.y, b.lo.y), std::min(lo.z, b.lo.z)};
  hi = {std::max(hi.x, b.hi.x), std::max(hi.y, b.hi.y), std::max(hi.z, b.hi.z)};
}

float Box::half_area() const {
  if (empty()) return 0.0f;
  const Vec3f e = extent();
  return e.x * e.y + e.y * e.z + e.z * e.x;
}

void Scene::validate() const {
  const std::string who = name.empty() ? std::string("scene") : name;
  for (std::size_t i = 0; i < triangles.size(); ++i)
    for (int k = 0; k < 3; ++k) {
      const std::uint32_t v = triangles[i][k];
      if (v >= vertices.size())
        throw Error(who + ": triangle " + std::to_string(i) + " names vertex " + std::to_string(v) + ", out of range (the scene has " +
                    std::to_string(vertices.size()) + " vertices)");
      const Vec3f& p = vertices[v];
      for (int a = 0; a < 3; ++a)
        if (!std::isfinite(p[a])) {
          char value[32];
          std::snprintf(value, sizeof value, "%g", static_cast<double>(p[a]));
          throw Error(who + ": vertex " + std::to_string(v) + " of triangle " + std::to_string(i) + " has coordinate " + "xyz"[a] +
                      " = " + value + "; vertices must be finite");
        }
    }
}

Box Scene::bounds() const {
  Box b;
  for (const auto& t : triangles)
    for (std::uint32_t v : t) b.grow(vertices[v]);
  return b;
}

std::uint64_t Scene::hash() const {
  std::uint64_t h = 0xcbf29ce484222325ull;
  auto mix = [&h](const void* p, std::size_t n) {
    const unsigned char* b = static_cast<const unsigned char*>(p);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 0x100000001b3ull;
  };
  mix(vertices.data(), vertices.size() * sizeof(Vec3f));
  mix(triangles.data(), triangles.size() * sizeof(triangles[0]));
  return h;
}

static bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

Scene load_scene(const std::string& path) {
  if (path.rfind("gen:", 0) == 0) {
    Scene s = generate_scene(path.substr(4));
    s.name = path;
    return s;
  }
  std::vector<char> data = read_file(path);
  std::string base = ends_with(path, ".zst") ? path.substr(0, path.size() - 4) : path;
  std::transform(base.begin(), base.end(), base.begin(), [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  const std::size_t bom = data.size() >= 3 && std::memcmp(data.data(), "\xEF\xBB\xBF", 3) == 0 ? 3 : 0;
  const bool ply_magic = data.size() >= bom + 3 && std::memcmp(data.data() + bom, "ply", 3) == 0;
  Scene s;
  if (ends_with(base, ".ply") || ply_magic) s = parse_ply(path, data.data(), data.size());
  else if (ends_with(base, ".obj")) s = parse_obj(path, data.data(), data.size());
  else throw Error(path + ": unknown scene format (expected .obj, .ply, optionally .zst, or gen:NAME:PARAMS)");
  // -- the build comes next in every command: refuse it here rather than run out of memory there
  data = {};
  require_memory(path, build_memory_estimate(s.triangles.size(), s.vertices.size()),
                 "to build its " + std::to_string(s.triangles.size()) + " triangles");
  return s;
}

}  // namespace mbvh

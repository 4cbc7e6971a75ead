// SPDX-License-Identifier: MIT
// raygen.cpp — ray generators (camera, shadow, diffuse, random, inside, special, path rays) and
// the error-bound spawn of secondary rays.
#include "host/tools/raygen.h"
#include "host/tools/render.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <memory>
#include <numbers>

#include "mbvh/error.h"
#include "host/core/random.h"
#include "host/core/resources.h"
#include "host/tools/stress.h"
#include "mbvh/trace.h"

namespace mbvh {

const char* to_string(RayKind k) {
  switch (k) {
    case RayKind::primary: return "primary";
    case RayKind::shadow: return "shadow";
    case RayKind::diffuse: return "diffuse";
    case RayKind::random: return "random";
    case RayKind::inside: return "inside";
    case RayKind::special: return "special";
    case RayKind::path: return "path";
  }
  return "?";
}

RayKind parse_ray_kind(const std::string& s) {
  for (RayKind k : {RayKind::primary, RayKind::shadow, RayKind::diffuse, RayKind::random, RayKind::inside, RayKind::special,
                    RayKind::path})
    if (s == to_string(k)) return k;
  throw Error("unknown ray kind '" + s + "' (known: primary, shadow, diffuse, random, inside, special, path)");
}

namespace {

struct V3 {
  double x, y, z;
};
V3 d3(const Vec3f& v) { return {v.x, v.y, v.z}; }
V3 operator-(V3 a, V3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
V3 operator+(V3 a, V3 b) { return {a.x + b.x, a.y + b.y, a.z + b.z}; }
V3 operator*(V3 a, double s) { return {a.x * s, a.y * s, a.z * s}; }
double dot(V3 a, V3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
V3 cross(V3 a, V3 b) { return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x}; }
V3 normalize(V3 a) { return a * (1.0 / std::sqrt(dot(a, a))); }
Vec3f f3(V3 a) { return {static_cast<float>(a.x), static_cast<float>(a.y), static_cast<float>(a.z)}; }

Ray make_ray(const Vec3f& o, V3 d, float tmax) {
  const Vec3f df = f3(d);
  return Ray{o.x, o.y, o.z, 0.0f, df.x, df.y, df.z, tmax};
}

}  // namespace

std::string camera_problem(const Camera& c) {
  const auto finite = [](const Vec3f& v) { return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z); };
  if (!finite(c.eye)) return "the eye is not finite";
  if (!finite(c.target)) return "the target is not finite";
  if (!finite(c.up)) return "the up vector is not finite";
  const V3 view = d3(c.target) - d3(c.eye);
  if (dot(view, view) == 0) return "the eye equals the target (no view direction)";
  if (!std::isfinite(dot(view, view))) return "the eye is too far from the target";
  if (dot(d3(c.up), d3(c.up)) == 0) return "the up vector is zero";
  if (!(c.fov_deg > 0 && c.fov_deg < 180)) return "the field of view must be in (0, 180) degrees";
  return "";
}

Ray camera_ray(const Camera& c, double px, double py, double aspect) {
  const V3 eye = d3(c.eye);
  const V3 fwd = normalize(d3(c.target) - eye);
  V3 side = cross(fwd, normalize(d3(c.up)));
  if (dot(side, side) < 1e-18) {  // looking along up: the axis least aligned with the view
    const double a[3] = {std::fabs(fwd.x), std::fabs(fwd.y), std::fabs(fwd.z)};
    const int k = a[2] <= a[0] && a[2] <= a[1] ? 2 : (a[0] <= a[1] ? 0 : 1);
    side = cross(fwd, V3{k == 0 ? 1.0 : 0.0, k == 1 ? 1.0 : 0.0, k == 2 ? 1.0 : 0.0});
  }
  const V3 right = normalize(side);
  const V3 up = cross(right, fwd);
  const double h = std::tan(c.fov_deg * std::numbers::pi / 360.0);
  const V3 d = normalize(fwd + right * ((2 * px - 1) * h * aspect) + up * ((1 - 2 * py) * h));
  return make_ray(c.eye, d, INFINITY);
}

namespace {

// In double: the normal facing against `in`, and a cosine-weighted direction about it.
V3 facing_normal_d(const Vec3f& a, const Vec3f& b, const Vec3f& c, V3 in) {
  V3 n = normalize(cross(d3(b) - d3(a), d3(c) - d3(a)));
  if (dot(n, in) > 0) n = n * -1.0;
  return n;
}

V3 cosine_direction_d(V3 n, double r1, double r2) {
  const V3 t1 = normalize(std::fabs(n.x) > 0.5 ? cross(n, V3{0, 1, 0}) : cross(n, V3{1, 0, 0}));
  const V3 t2 = cross(n, t1);
  const double rr = std::sqrt(r1), phi = 2 * std::numbers::pi * r2;
  return normalize(t1 * (rr * std::cos(phi)) + t2 * (rr * std::sin(phi)) + n * std::sqrt(std::max(0.0, 1 - r1)));
}


}  // namespace

Vec3f facing_normal(const Vec3f& a, const Vec3f& b, const Vec3f& c, const Vec3f& incoming) {
  return f3(facing_normal_d(a, b, c, d3(incoming)));
}

Vec3f cosine_direction(const Vec3f& n, double r1, double r2) { return f3(cosine_direction_d(d3(n), r1, r2)); }

void tri_vertices(const Scene& s, std::uint32_t prim, Vec3f& a, Vec3f& b, Vec3f& c) { s.triangle(prim, a, b, c); }

Camera default_camera(const Box& b) {
  Camera c;
  const Vec3f ctr = b.center(), e = b.extent();
  const double radius = 0.5 * std::sqrt(double(e.x) * e.x + double(e.y) * e.y + double(e.z) * e.z);
  const V3 dir = normalize(V3{0.45, 0.35, 1.0});
  const double dist = radius / std::sin(c.fov_deg * std::numbers::pi / 360.0);
  c.target = ctr;
  c.eye = f3(d3(ctr) + dir * dist);
  return c;
}

Vec3f default_light(const Box& b) {
  const Vec3f c = b.center(), e = b.extent();
  return {c.x + 0.05f * e.x, c.y + 0.45f * e.y, c.z + 0.05f * e.z};
}

Ray spawn_ray(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2, float u, float v, const Vec3f& dir, float tmax) {
  const float b0 = 1.0f - u - v;
  const float P[3][3] = {{p0.x, p0.y, p0.z}, {p1.x, p1.y, p1.z}, {p2.x, p2.y, p2.z}};
  constexpr float g7 = 7 * 0x1p-24f / (1 - 7 * 0x1p-24f);
  float p[3], err[3];
  for (int a = 0; a < 3; ++a) {
    p[a] = b0 * P[0][a] + u * P[1][a] + v * P[2][a];
    err[a] = g7 * (std::fabs(b0 * P[0][a]) + std::fabs(u * P[1][a]) + std::fabs(v * P[2][a]));
  }
  V3 n = normalize(cross(d3(p1) - d3(p0), d3(p2) - d3(p0)));
  const double off = std::fabs(n.x) * err[0] + std::fabs(n.y) * err[1] + std::fabs(n.z) * err[2];
  if (dot(n, d3(dir)) < 0) n = n * -1.0;
  const double nn[3] = {n.x, n.y, n.z};
  Vec3f o;
  for (int a = 0; a < 3; ++a) {
    float q = static_cast<float>(p[a] + off * nn[a]);
    if (nn[a] > 0) q = std::nextafter(q, INFINITY);
    else if (nn[a] < 0) q = std::nextafter(q, -INFINITY);
    o[a] = q;
  }
  return Ray{o.x, o.y, o.z, 0.0f, dir.x, dir.y, dir.z, tmax};
}

bool shadow_ray(const Scene& scene, const Hit& h, const Vec3f& light, Ray& out) {
  Vec3f a, b, c;
  tri_vertices(scene, h.prim, a, b, c);
  const float b0 = 1.0f - h.u - h.v;
  const V3 p{b0 * a.x + h.u * b.x + h.v * c.x, b0 * a.y + h.u * b.y + h.v * c.y, b0 * a.z + h.u * b.z + h.v * c.z};
  const V3 to = d3(light) - p;
  const double dist = std::sqrt(dot(to, to));
  if (!(dist > 0)) return false;
  out = spawn_ray(a, b, c, h.u, h.v, f3(to * (1.0 / dist)), static_cast<float>(dist));
  return true;
}

std::vector<Ray> image_rays(const Camera& cam, unsigned width, unsigned height, std::uint64_t seed) {
  constexpr unsigned kTile = 8;
  Rng rng(seed * 4 + static_cast<std::uint64_t>(RayKind::primary));
  std::vector<Ray> rays;
  rays.reserve(std::size_t(width) * height);
  const double aspect = double(width) / double(height);
  for (unsigned ty = 0; ty < height; ty += kTile)
    for (unsigned tx = 0; tx < width; tx += kTile)
      for (unsigned y = ty; y < std::min(ty + kTile, height); ++y)
        for (unsigned x = tx; x < std::min(tx + kTile, width); ++x) {
          const double px = (x + rng.uniform_d()) / width, py = (y + rng.uniform_d()) / height;
          rays.push_back(camera_ray(cam, px, py, aspect));
        }
  return rays;
}

std::vector<Ray> generate_rays(const Scene& scene, const Accel& acc, const RayGenOptions& opt) try {
  if (!acc.has_hierarchy() && opt.kind != RayKind::primary && opt.kind != RayKind::random && opt.kind != RayKind::inside) {
    // rays from hits (shadow, diffuse, path; special probes the scene) are found by the reference
    // traversals, which need a hierarchy: a build of quality none generates them through a
    // temporary medium build of the same scene with its options, freed on return (the same
    // triangles and bounds: the same rays)
    BuildOptions bo = acc.options();
    bo.quality = BuildQuality::medium;
    bo.progress = nullptr;
    const std::unique_ptr<Accel> with_tree = Accel::build(scene, bo);
    return generate_rays(scene, *with_tree, opt);
  }
  const Box bounds = acc.bounds();
  const Camera cam = opt.has_camera ? opt.camera : default_camera(bounds);
  if (const std::string p = camera_problem(cam); !p.empty()) throw Error("camera: " + p);
  if (opt.kind == RayKind::inside) {
    const Vec3f inside = inside_point(scene);
    std::vector<Ray> r = feature_rays(scene, inside, opt.count / 2, 0, opt.seed);
    const std::vector<Ray> rest = feature_rays(scene, inside, 0, opt.count - std::min(opt.count, r.size()), opt.seed);
    r.insert(r.end(), rest.begin(), rest.end());
    return r;
  }
  if (opt.kind == RayKind::special) return special_rays(scene, acc, opt.count, opt.seed);
  if (opt.kind == RayKind::path)
    return path_tracer_rays(scene, acc, opt.count, opt.seed, opt.has_camera ? &opt.camera : nullptr, opt.threads);
  std::vector<Ray> rays;
  rays.reserve(opt.count);
  Rng rng(opt.seed * 4 + static_cast<std::uint64_t>(opt.kind));
  // primary rays: a square image of at least `count` pixels, one jittered sample per pixel, in
  // 8x8 tiles (rows of tiles, each tile row by row), the order a tiled renderer traces: 64
  // consecutive rays are one tile, the cpu backend's packet (MBVH_PACKET_RAYS)
  constexpr std::size_t kTile = 8;
  if (opt.kind == RayKind::primary) {
    std::size_t w = static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(std::max<std::size_t>(opt.count, 1)))));
    w = (w + kTile - 1) / kTile * kTile;
    for (std::size_t i = 0; i < opt.count; ++i) {
      const std::size_t tile = i / (kTile * kTile), in = i % (kTile * kTile);
      const std::size_t x = tile % (w / kTile) * kTile + in % kTile, y = tile / (w / kTile) * kTile + in / kTile;
      const double px = (static_cast<double>(x) + rng.uniform_d()) / static_cast<double>(w);
      const double py = (static_cast<double>(y) + rng.uniform_d()) / static_cast<double>(w);
      rays.push_back(camera_ray(cam, px, py));
    }
    return rays;
  }
  if (opt.kind == RayKind::random) {
    const Vec3f lo = bounds.lo, e = bounds.extent();
    for (std::size_t i = 0; i < opt.count; ++i) {
      Vec3f o;
      for (int a = 0; a < 3; ++a) o[a] = static_cast<float>(lo[a] - 0.1 * e[a] + 1.2 * e[a] * rng.uniform_d());
      const double z = 2 * rng.uniform_d() - 1, phi = 2 * std::numbers::pi * rng.uniform_d();
      const double s = std::sqrt(std::max(0.0, 1 - z * z));
      rays.push_back(make_ray(o, V3{s * std::cos(phi), s * std::sin(phi), z}, INFINITY));
    }
    return rays;
  }
  // -- shadow and diffuse: from hit points of primary rays at jittered pixels of the same tiled
  // image (8x8 tiles, as above; passes over it until there are enough hits), in that order: the
  // secondary rays of a tiled renderer, whose neighbours start at neighbouring points
  const Vec3f light = default_light(bounds);
  TraceOptions topt;
  topt.layout = Layout::mbvh4;
  topt.traversal = Traversal::stack;
  std::size_t tried = 0;
  const std::size_t w = (static_cast<std::size_t>(std::ceil(std::sqrt(static_cast<double>(std::max<std::size_t>(opt.count, 1))))) +
                         kTile - 1) / kTile * kTile;
  while (rays.size() < opt.count) {
    const std::size_t batch = std::max<std::size_t>(4096, (opt.count - rays.size()) * 2);
    std::vector<Ray> prim(batch);
    for (std::size_t i = 0; i < batch; ++i) {
      const std::size_t j = (tried + i) % (w * w);
      const std::size_t tile = j / (kTile * kTile), in = j % (kTile * kTile);
      const std::size_t x = tile % (w / kTile) * kTile + in % kTile, y = tile / (w / kTile) * kTile + in / kTile;
      const double px = (static_cast<double>(x) + rng.uniform_d()) / static_cast<double>(w);
      prim[i] = camera_ray(cam, px, (static_cast<double>(y) + rng.uniform_d()) / static_cast<double>(w));
    }
    TraceOutput out;
    trace_reference(acc, prim, topt, out, opt.threads);
    for (std::size_t i = 0; i < batch && rays.size() < opt.count; ++i) {
      const Hit& h = out.hits[i];
      const double r1 = rng.uniform_d(), r2 = rng.uniform_d();  // drawn for every ray: deterministic
      if (h.prim == MBVH_MISS_PRIM) continue;
      if (opt.kind == RayKind::shadow) {
        if (Ray r; shadow_ray(scene, h, light, r)) rays.push_back(r);
      } else {
        Vec3f a, b, c;
        tri_vertices(scene, h.prim, a, b, c);
        // cosine-weighted direction about the normal facing the incoming ray
        const V3 n = facing_normal_d(a, b, c, V3{prim[i].dx, prim[i].dy, prim[i].dz});
        rays.push_back(spawn_ray(a, b, c, h.u, h.v, f3(cosine_direction_d(n, r1, r2)), INFINITY));
      }
    }
    tried += batch;
    if (rays.empty() && tried >= 1u << 20)
      throw Error(scene.name + ": the camera sees no geometry; no " + to_string(opt.kind) + " rays can start from hits");
  }
  return rays;
} catch (const std::bad_alloc&) {  // the rays (and the generator's own arrays): named
  throw_out_of_memory(std::to_string(opt.count) + " generated " + to_string(opt.kind) + " rays", opt.count * sizeof(Ray));
}

}  // namespace mbvh

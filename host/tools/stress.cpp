// SPDX-License-Identifier: MIT
// stress.cpp — stress rays (see stress.h).
#include "host/tools/stress.h"

#include <cmath>
#include <limits>

#include "host/core/random.h"
#include "mbvh/trace.h"

namespace mbvh {
namespace {

Ray toward(const Vec3f& o, const Vec3f& target, float tmax = INFINITY) {
  return Ray{o.x, o.y, o.z, 0.0f, target.x - o.x, target.y - o.y, target.z - o.z, tmax};
}

Vec3f mid(const Vec3f& a, const Vec3f& b) { return {0.5f * (a.x + b.x), 0.5f * (a.y + b.y), 0.5f * (a.z + b.z)}; }

Vec3f random_dir(Rng& rng) {
  const double z = 2 * rng.uniform_d() - 1, phi = 6.283185307179586 * rng.uniform_d();
  const double s = std::sqrt(std::max(0.0, 1 - z * z));
  return {static_cast<float>(s * std::cos(phi)), static_cast<float>(s * std::sin(phi)), static_cast<float>(z)};
}

}  // namespace

Vec3f inside_point(const Scene& scene) {
  const Box b = scene.bounds();
  Vec3f c = b.center();
  // torus (major radius 1, minor 0.35, box 2.7 wide): on the core circle, at x = 1
  if (scene.name.find("gen:torus") != std::string::npos) c.x = b.lo.x + (b.hi.x - b.lo.x) * (2.35f / 2.7f);
  return c;
}

std::vector<Ray> feature_rays(const Scene& scene, const Vec3f& inside, std::size_t max_features, std::size_t random,
                              std::uint64_t seed) {
  std::vector<Ray> rays;
  const std::size_t n = scene.triangle_count();
  const std::size_t step = std::max<std::size_t>(1, (n * 4) / std::max<std::size_t>(max_features, 1));
  for (std::size_t i = 0; i < n && rays.size() < max_features; i += step) {
    Vec3f a, b, c;
    scene.triangle(i, a, b, c);
    rays.push_back(toward(inside, a));          // a shared vertex
    rays.push_back(toward(inside, mid(a, b)));  // shared edge midpoints
    rays.push_back(toward(inside, mid(b, c)));
    rays.push_back(toward(inside, mid(c, a)));
  }
  Rng rng(seed);
  for (std::size_t i = 0; i < random; ++i) {
    const Vec3f d = random_dir(rng);
    rays.push_back(Ray{inside.x, inside.y, inside.z, 0.0f, d.x, d.y, d.z, INFINITY});
  }
  return rays;
}

std::vector<Ray> special_rays(const Scene& scene, const Accel& acc, std::size_t count, std::uint64_t seed) {
  std::vector<Ray> rays;
  Rng rng(seed);
  const Box b = acc.bounds();
  const Vec3f c = b.center(), e = b.extent();
  const float inf = INFINITY, nan = std::numeric_limits<float>::quiet_NaN(), den = 1e-40f;
  const std::size_t per = std::max<std::size_t>(1, count / 8);
  auto inside_box = [&]() {
    return Vec3f{b.lo.x + e.x * rng.uniform(), b.lo.y + e.y * rng.uniform(), b.lo.z + e.z * rng.uniform()};
  };
  // -- axis-aligned rays with +0 / -0 components, from outside the box and from inside it
  for (std::size_t i = 0; i < per; ++i) {
    const int axis = static_cast<int>(i % 3);
    const float sign = (i / 3) % 2 ? -1.0f : 1.0f;
    const float z0 = (i / 6) % 2 ? -0.0f : 0.0f;
    Vec3f o = inside_box();
    if ((i / 12) % 2) o[axis] = sign > 0 ? b.lo[axis] - e[axis] : b.hi[axis] + e[axis];
    Vec3f d{z0, z0, z0};
    d[axis] = sign;
    rays.push_back(Ray{o.x, o.y, o.z, 0.0f, d.x, d.y, d.z, inf});
  }
  // -- denormal direction components
  for (std::size_t i = 0; i < per; ++i) {
    const Vec3f o = inside_box();
    Vec3f d = random_dir(rng);
    d[static_cast<int>(i % 3)] = (i % 2 ? -den : den);
    if (i % 5 == 0) d[static_cast<int>((i + 1) % 3)] = -den;
    rays.push_back(Ray{o.x, o.y, o.z, 0.0f, d.x, d.y, d.z, inf});
  }
  // -- rays in a triangle's plane, from outside it toward a point of it, and along its edges
  for (std::size_t i = 0; i < per && scene.triangle_count() > 0; ++i) {
    Vec3f p0, p1, p2;
    scene.triangle(static_cast<std::size_t>(rng.next() % scene.triangle_count()), p0, p1, p2);
    const Vec3f m = mid(p1, p2);
    if (i % 2) {
      const Vec3f o{p0.x + (p0.x - m.x), p0.y + (p0.y - m.y), p0.z + (p0.z - m.z)};  // beyond p0 in the plane
      rays.push_back(toward(o, m));
    } else {
      rays.push_back(toward(p0, p1));  // along an edge, from its vertex
    }
  }
  // -- rays along the faces of the scene box (origin in a face plane, direction within it)
  for (std::size_t i = 0; i < per; ++i) {
    const int axis = static_cast<int>(i % 3);
    Vec3f o = inside_box();
    o[axis] = (i / 3) % 2 ? b.hi[axis] : b.lo[axis];
    Vec3f d = random_dir(rng);
    d[axis] = (i / 6) % 2 ? -0.0f : 0.0f;
    if (d.x == 0 && d.y == 0 && d.z == 0) d[(axis + 1) % 3] = 1.0f;
    rays.push_back(Ray{o.x, o.y, o.z, 0.0f, d.x, d.y, d.z, inf});
  }
  // -- huge and infinite tmax, long directions, through the centre
  for (std::size_t i = 0; i < per; ++i) {
    const Vec3f d = random_dir(rng);
    const float far = 2.0f * (e.x + e.y + e.z + 1.0f);
    const Vec3f o{c.x - d.x * far, c.y - d.y * far, c.z - d.z * far};
    const float tmax = i % 3 == 0 ? inf : (i % 3 == 1 ? std::numeric_limits<float>::max() : 1e30f);
    const float scale = i % 4 == 0 ? 1e18f : 1.0f;  // a long direction vector
    rays.push_back(Ray{o.x, o.y, o.z, 0.0f, d.x * scale, d.y * scale, d.z * scale, tmax});
  }
  // -- tmin = tmax exactly at a hit (the closed interval counts), and tmax just short of it
  {
    std::vector<Ray> probe;
    for (std::size_t i = 0; i < per; ++i) {
      const Vec3f d = random_dir(rng);
      probe.push_back(Ray{c.x, c.y, c.z, 0.0f, d.x, d.y, d.z, inf});
    }
    TraceOutput out;
    trace_reference(acc, probe, TraceOptions{}, out, 1);
    for (std::size_t i = 0; i < probe.size(); ++i) {
      Ray r = probe[i];
      if (out.hits[i].prim == MBVH_MISS_PRIM) continue;
      r.tmin = r.tmax = out.hits[i].t;
      rays.push_back(r);
      r.tmin = 0.0f;
      r.tmax = std::nextafter(out.hits[i].t, 0.0f);
      rays.push_back(r);
    }
  }
  // -- invalid rays: defined misses
  const Ray bad[] = {{c.x, c.y, c.z, 2.0f, 1, 0, 0, 1.0f},  {nan, c.y, c.z, 0, 1, 0, 0, inf},
                     {c.x, c.y, c.z, 0, nan, 1, 0, inf},   {c.x, c.y, c.z, 0, 0, 0, 0, inf},
                     {inf, c.y, c.z, 0, -1, 0, 0, inf},    {c.x, c.y, c.z, 0, inf, 1, 0, inf},
                     {c.x, c.y, c.z, -1.0f, 1, 0, 0, inf}, {c.x, c.y, c.z, 0, den, -den, den, inf},
                     {c.x, c.y, c.z, 0, 1, 0, 0, nan},     {c.x, c.y, c.z, inf, 1, 0, 0, inf}};
  for (std::size_t i = 0; i < per; ++i) rays.push_back(bad[i % (sizeof bad / sizeof bad[0])]);
  return rays;
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// raygen.h — ray generators (primary, shadow, diffuse, random; deterministic by seed), the
// error-bound spawn helper for secondary rays (the files are mbvh/rays.h).
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/rays.h"
#include "mbvh/scene.h"

namespace mbvh {

/// path: the rays of the path tracer's bounces (render.h path_tracer_rays), the thesis' workload.
enum class RayKind { primary, shadow, diffuse, random, inside, special, path };
const char* to_string(RayKind k);
RayKind parse_ray_kind(const std::string& s);  ///< throws Error on an unknown name

/// A pinhole camera. The default frames the scene's box from the front-right-above.
struct Camera {
  Vec3f eye, target, up{0, 1, 0};
  float fov_deg = 60.0f;
};
Camera default_camera(const Box& bounds);
/// Why `c` cannot make rays, "" if it can: a NaN or infinite eye, target or up, eye = target, a
/// zero up vector, or fov_deg outside (0, 180). (A view along `up` is fine: camera_ray picks
/// another up vector.)
std::string camera_problem(const Camera& c);
/// The point light of shadow rays: near the top of the box, centred.
Vec3f default_light(const Box& bounds);
/// The primary ray through image position (px, py) in [0,1)^2 (y down), from the eye, tmax = inf.
/// `aspect` (width / height) widens the horizontal field; the vertical one is fov_deg. A view
/// parallel to `up` (looking straight down or up) takes the coordinate axis least aligned with the
/// view as its up vector. Requires camera_problem(c) == "".
Ray camera_ray(const Camera& c, double px, double py, double aspect = 1.0);
/// Unit geometric normal of triangle (a, b, c), flipped to face against `incoming`.
Vec3f facing_normal(const Vec3f& a, const Vec3f& b, const Vec3f& c, const Vec3f& incoming);
/// The vertices of the scene's triangle `prim` (a file prim id, as in Hit::prim).
void tri_vertices(const Scene& s, std::uint32_t prim, Vec3f& a, Vec3f& b, Vec3f& c);
/// Cosine-weighted direction about unit normal n from two uniform numbers in [0, 1).
Vec3f cosine_direction(const Vec3f& n, double r1, double r2);

struct RayGenOptions {
  RayKind kind = RayKind::primary;
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  bool has_camera = false;  ///< use `camera` instead of default_camera
  Camera camera;
  unsigned threads = 0;
};

/// Generates `count` rays (inside: up to count/2 aimed at vertices and edge midpoints of a closed
/// generated mesh from inside_point, the rest random from there; special: stress.h's special
/// rays, about `count`). Shadow and diffuse rays start at hit points of primary rays (traced
/// with the reference traversal), offset by the hit point's rounding-error bound. On a build
/// without a hierarchy (BuildQuality::none) the rays that need traced hits (shadow, diffuse,
/// special, path) come from a temporary medium build of `scene`, made and freed here: the same
/// rays. Throws Error if the camera sees no geometry or has a camera_problem.
std::vector<Ray> generate_rays(const Scene& scene, const Accel& acc, const RayGenOptions& opt);

/// The shadow ray of closest hit `h` (not a miss) on `scene`'s triangle: from the hit point
/// (spawn_ray's offset) toward `light`, tmax the distance to it. False (out untouched) when the
/// point is the light.
bool shadow_ray(const Scene& scene, const Hit& h, const Vec3f& light, Ray& out);

/// Primary rays of a width x height image from `cam` (the horizontal field widened by the
/// aspect), one jittered sample per pixel, in 8x8 tiles (rows of tiles, each tile row by row;
/// partial tiles at the right and bottom edges), deterministic by seed. Requires
/// camera_problem(cam) == "" and width, height >= 1.
std::vector<Ray> image_rays(const Camera& cam, unsigned width, unsigned height, std::uint64_t seed);

/// pbrt-v4-style secondary ray: the hit point on triangle (p0, p1, p2) at barycentrics (u, v),
/// its origin pushed off the surface along the geometric normal by the point's error bound
/// γ(7)·Σ|b_i·P_i|, to the side `dir` leaves from, then rounded away one more ulp.
Ray spawn_ray(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2, float u, float v, const Vec3f& dir, float tmax);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// geometry.h — the geometry API: several caller-owned meshes in one scene (Scene::add_mesh with
// MeshView, mbvh/scene.h), hits that name the geometry and the triangle within it (GeomHit),
// traces that write into the caller's buffers, and one-ray calls.
//
//   mbvh::register_builtin_backends();  // once per program (mbvh/backends.h)
//   mbvh::Scene scene;
//   const std::uint32_t floor = scene.add_mesh({pos, 4, 24, idx, 2, 16});  // stride 24: x y z nx ny nz
//   auto accel = mbvh::Accel::build(scene);  // reads the views; after it returns they may go
//   auto cpu = mbvh::make_backend("cpu");
//   mbvh::GeomHit h = mbvh::intersect1(*cpu, *accel, ray);  // h.geom_id == floor, h.prim_id in 0..1
//
// Lifetime:
//  - A Scene keeps the MeshView it is given, not a copy of the buffers. The buffers must stay
//    alive, and unchanged, while anything reads the scene's triangles: Scene::validate, bounds,
//    hash, triangle, and Accel::build / build_cached / cache_key / refit until they return.
//  - An Accel holds its own copy of the triangles (in the build's leaf order) and the geometries'
//    prim-id ranges: once Accel::build returns, the caller's buffers may be changed or freed and
//    the Accel (and Accel::geometry_of) still traces and maps hits. Scene::geometry_of needs only
//    the Scene object, not the buffers.
//  - Refit: move the vertices in the caller's buffers (same indices, same counts), then call
//    Accel::refit(scene) with the same Scene; the buffers must be alive during that call.
//
// Thread safety:
//  - Scene::add_mesh modifies the scene: nothing else may use that Scene at the same time. Reading
//    a scene (validate, hash, triangle, geometry_of, building from it) may happen on several
//    threads at once; the caller must not write its buffers meanwhile.
//  - An Accel may be traced from several threads at once (not during refit, which may not run
//    concurrently with anything on that Accel).
//  - A Backend is used by one thread at a time: the calls below run `backend.trace`, so give each
//    thread its own Backend (make_backend) or serialise. The calls stage the backend's answers in a
//    per-thread buffer that they reuse (it keeps the size of the largest batch traced on that
//    thread: 16 bytes a ray for hits, 1 byte for occlusion), so repeated calls do not allocate.
//
// Errors: every function throws mbvh::Error (never exits), as the rest of the library.
#pragma once
#include <cmath>
#include <cstdint>
#include <span>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"

namespace mbvh {

/// A closest hit named by geometry: t along the ray, the barycentrics u, v of vertices 1 and 2 of
/// the triangle (as Hit), the geometry id (Scene::add_mesh's return value; 0 for an owned scene)
/// and the triangle's index within that geometry. A miss: t = +inf, u = v = 0,
/// geom_id = kInvalidGeometry, prim_id = MBVH_MISS_PRIM.
struct GeomHit {
  float t = INFINITY, u = 0, v = 0;
  std::uint32_t geom_id = kInvalidGeometry;
  std::uint32_t prim_id = MBVH_MISS_PRIM;
  bool hit() const { return geom_id != kInvalidGeometry; }
};

/// A backend's hit (its prim id global to the scene) as a GeomHit of the build's geometries
/// (Accel::geometry_of). O(log geometries).
GeomHit to_geom_hit(const Accel& accel, const Hit& hit);

/// Closest hits of `rays` into the caller's `hits` (one per ray, in ray order) on `backend`, with
/// `opt`'s layout, traversal and precision (its query and stats are ignored: closest, none).
/// Throws Error if hits.size() != rays.size(), and as Backend::trace does (e.g. a layout or
/// traversal the backend does not implement). The answers are those of Backend::trace, so they
/// are bit-identical across mbvh's backends.
void intersect(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<GeomHit> hits,
               const TraceOptions& opt = {});
/// As above with the scene-global prim ids of Hit (the .hits file's records).
void intersect(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<Hit> hits,
               const TraceOptions& opt = {});
/// Any-hit queries of `rays` into the caller's `occluded` (1 = some triangle in [tmin, tmax],
/// else 0), one byte per ray in ray order; `opt` as for intersect. Throws Error if
/// occluded.size() != rays.size(), and as Backend::trace does.
void occluded(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<std::uint8_t> occluded,
              const TraceOptions& opt = {});

/// One ray's closest hit: intersect on a batch of one. Convenient, not fast: each call takes the
/// backend's lock and its set-up (a dispatch on a device backend). For one ray per call from the
/// caller's threads, make a RayQuery once (Backend::ray_query, mbvh/backend.h: no lock, no
/// allocation per call) and map its Hit with to_geom_hit; or batch rays.
GeomHit intersect1(Backend& backend, const Accel& accel, const Ray& ray, const TraceOptions& opt = {});
/// Whether one ray is occluded: occluded on a batch of one.
bool occluded1(Backend& backend, const Accel& accel, const Ray& ray, const TraceOptions& opt = {});

}  // namespace mbvh

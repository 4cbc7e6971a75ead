// SPDX-License-Identifier: MIT
// instance.h — instancing: a two-level scene of instances (a built mesh, an affine transform, a
// ray mask) under a top-level BVH over the instances' world boxes, traced one ray at a time or in
// batches on a SIMD cpu backend's single-ray kernels; hits name the instance, the geometry and
// the triangle. docs/library.md ("Instancing") has the how-to, docs/accuracy.md the contract.
//
//   auto cpu = mbvh::make_backend("cpu");
//   std::shared_ptr<const mbvh::Accel> bunny = mbvh::Accel::build(mbvh::load_scene("bunny.ply"));
//   std::vector<mbvh::Instance> inst = {{0, mbvh::Affine::translation(2, 0, 0)},
//                                       {0, mbvh::Affine::rotation(0, 1, 0, 1.57f), 0x2}};
//   mbvh::InstanceScene scene = mbvh::InstanceScene::build(*cpu, {bunny}, inst);
//   mbvh::InstanceHit h = scene.intersect(ray);        // h.inst_id, h.geom_id, h.prim_id, h.t
//   bool blocked = scene.occluded(shadow_ray, 0x1);    // instances with mask & 0x1 only
//   scene.set_transform(1, mbvh::Affine::translation(0, 3, 0));
//   scene.refit();                                      // before the next trace
//
// The exact contract across the transform: an instance's answer for a world ray is, bit for bit,
// the backend's exact answer (RayQuery, Woop et al. 2013's watertight test) for the object-space
// ray object_ray() specifies (the float rounding of the double inverse transform of the world
// ray; tmin and tmax unchanged: with an affine map and an unnormalised direction the ray
// parameter t is the same in both spaces, so t is reported as is, in world units of the world
// ray). The scene's answer is the smallest such t over the instances whose mask meets the ray's,
// equal t to the smaller instance index (then, within one instance, the smaller prim id). The
// top level never culls an instance that answer needs (its boxes are widened by a bound on the
// transform's rounding). Against the same triangles flattened to world space, answers differ only
// where that rounding decides (a hit within the rays' displacement of a triangle's edge):
// compare_flattened classifies such differences as ties and counts any other as a mismatch.
#pragma once
#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"

namespace mbvh {

/// An affine transform, object to world: world = L p + t, stored row-major as three rows
/// (L00 L01 L02 t0), (L10 L11 L12 t1), (L20 L21 L22 t2). The helpers compute in double and round
/// each entry to float once.
struct Affine {
  float m[12] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0};

  static Affine identity() { return {}; }
  static Affine translation(float x, float y, float z);
  static Affine scale(float x, float y, float z);
  /// A rotation by `radians` about the axis (x, y, z) (normalised here; a zero axis throws Error).
  static Affine rotation(float x, float y, float z, float radians);
  /// The composition: (a * b) p = a (b p).
  friend Affine operator*(const Affine& a, const Affine& b);
  /// L p + t in double, rounded to float once per coordinate: how flatten() places a vertex.
  Vec3f apply(const Vec3f& p) const;
};

/// The instance id of a miss.
constexpr std::uint32_t kInvalidInstance = 0xFFFFFFFFu;

/// One instance: which mesh (an index into InstanceScene::build's meshes), where (object to
/// world), and its ray mask: a ray traced with mask `m` skips the instance when (mask & m) == 0.
struct Instance {
  std::uint32_t mesh = 0;
  Affine transform;
  std::uint32_t mask = 0xFFFFFFFFu;
};

/// A closest hit of an instanced scene: t along the world ray (the ray's own parameter, see the
/// contract above), the barycentrics u, v of vertices 1 and 2 of the triangle (as Hit: affine maps
/// keep them), the instance (its index in the scene), the geometry within the instance's mesh
/// (Accel::geometry_of; 0 for a mesh of one geometry) and the triangle's index within that
/// geometry. A miss: t = +inf, u = v = 0, inst_id = kInvalidInstance, geom_id = kInvalidGeometry,
/// prim_id = MBVH_MISS_PRIM. 24 bytes.
struct InstanceHit {
  float t = INFINITY, u = 0, v = 0;
  std::uint32_t inst_id = kInvalidInstance;
  std::uint32_t geom_id = kInvalidGeometry;
  std::uint32_t prim_id = MBVH_MISS_PRIM;
  bool hit() const { return inst_id != kInvalidInstance; }
};

/// Answers of a batch, in ray order: closest hit fills `hits`, any hit `occluded` (1 = occluded).
struct InstanceOutput {
  std::vector<InstanceHit> hits;
  std::vector<std::uint8_t> occluded;
  std::size_t invalid = 0;  ///< rays rejected as invalid (ray_valid false: defined misses)
};

/// Statistics of the top level.
struct InstanceStats {
  std::size_t instances = 0, meshes = 0;
  std::size_t nodes = 0, leaves = 0;  ///< top-level binary nodes and leaves
  double build_ms = 0;                ///< the last build or rebuild of the top level
  double refit_ms = 0;                ///< the last refit
};

/// A two-level scene. Movable, not copyable. Any number of threads may trace one scene at once
/// (intersect, occluded, trace); set_transform, set_mask, refit and rebuild may not run
/// concurrently with anything on it.
class InstanceScene {
public:
  /// Builds the top level over `instances` of `meshes` (each built once, shared by every instance
  /// naming it) and prepares `backend`'s single-ray query on each mesh (Backend::ray_query, its
  /// default options: only the SIMD cpu backends have one, any other backend is refused by
  /// ray_query's Error). The top level is a binned-SAH BVH (the builder of Accel::build) over the
  /// instances' world boxes, one instance a leaf where the SAH allows. Throws Error naming the
  /// value for: a null mesh, a mesh without a hierarchy (BuildQuality::none), an instance whose
  /// mesh index is out of range, a transform with a NaN or infinite entry, a singular or
  /// ill-conditioned one (condition number of L above kMaxInstanceCondition), a world box beyond
  /// kMaxCoordinate, more than 2^31 instances. Zero instances is a scene that every ray misses.
  /// The meshes must not be refit while the scene uses them. Cost: O(instances log instances) and
  /// one ray_query per mesh (its first preparation of a layout).
  static InstanceScene build(Backend& backend, std::vector<std::shared_ptr<const Accel>> meshes,
                             std::vector<Instance> instances, unsigned threads = 0);
  InstanceScene(InstanceScene&&) noexcept;
  InstanceScene& operator=(InstanceScene&&) noexcept;
  ~InstanceScene();

  /// The closest hit of a world ray among the instances whose mask meets `mask` (the contract
  /// atop this header). An invalid ray is a miss. Throws Error for a ray whose object-space twin
  /// leaves an instance mesh's exactly traced range (RayQuery), and after set_transform or
  /// set_mask until refit or rebuild. No lock, no allocation.
  InstanceHit intersect(const Ray& ray, std::uint32_t mask = 0xFFFFFFFFu) const;
  /// Whether a triangle of an instance whose mask meets `mask` lies in [tmin, tmax].
  bool occluded(const Ray& ray, std::uint32_t mask = 0xFFFFFFFFu) const;
  /// A batch on the scene's threads: closest or any hit per `query`, each ray traced with
  /// masks[i] (Ray has no room for a mask: its 32-byte record is the file format and the device
  /// layout), or with all bits set when `masks` is empty. Throws Error if masks is neither empty
  /// nor one per ray, and as intersect does.
  void trace(std::span<const Ray> rays, Query query, InstanceOutput& out,
             std::span<const std::uint32_t> masks = {}) const;

  /// Moves instance i (Error for i out of range or a transform build would refuse). The top
  /// level is stale until refit() or rebuild(): a trace before that throws Error.
  void set_transform(std::size_t i, const Affine& transform);
  /// Sets instance i's mask (the top level keeps each subtree's union of masks: refit updates it).
  void set_mask(std::size_t i, std::uint32_t mask);
  /// Recomputes the instances' world boxes and the top level's boxes and masks bottom-up, keeping
  /// its topology: O(instances). Answers stay exact; a tree whose instances moved far may visit
  /// more nodes than a rebuild's.
  void refit();
  /// Builds the top level again over the current transforms: O(instances log instances).
  void rebuild();

  std::size_t instance_count() const;
  const Instance& instance(std::size_t i) const;  ///< Error for i out of range
  std::size_t mesh_count() const;
  const Accel& mesh(std::size_t m) const;  ///< Error for m out of range
  /// The union of the instances' world boxes (the corners of each mesh's box transformed in
  /// double, rounded outwards); empty for zero instances.
  Box bounds() const;
  InstanceStats stats() const;
  /// The ray the instance's mesh is traced with for world ray `ray` (the contract): with
  /// L^-1 the inverse of L in double, origin = float(L^-1 (o - t)), direction = float(L^-1 d),
  /// each product and sum in double and rounded to float once; tmin and tmax as the world ray's.
  Ray object_ray(std::size_t i, const Ray& ray) const;

  /// The scene as one owned Scene in world space: instance i's triangle p becomes prim
  /// flat_offset(i) + p (p the mesh's prim id, Accel-wide), its vertices Affine::apply of the
  /// mesh's float vertices (degenerate triangles, kept out of the mesh's build, stay degenerate).
  /// Cost: three vertices a triangle, 48 bytes, before any build of it.
  Scene flatten() const;
  /// Instance i's first prim id in flatten(): the mesh triangle counts of instances 0 .. i-1.
  std::uint64_t flat_offset(std::size_t i) const;
  /// A hit's prim id in flatten(), or MBVH_MISS_PRIM for a miss.
  std::uint64_t flat_prim(const InstanceHit& h) const;

private:
  struct Impl;
  explicit InstanceScene(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// The largest condition number (infinity norm of L times that of L^-1) a transform may have:
/// the object-space ray's rounding, scaled by it, is what the top level's boxes are widened by.
constexpr double kMaxInstanceCondition = 0x1p20;

/// Compares instanced answers `inst` with answers `flat` on `flat_scene` (= scene.flatten(), e.g.
/// brute_force on its build, or a backend's trace) ray by ray with compare_hits, and classifies
/// a difference compare_hits calls a mismatch as a tie when the transform's rounding explains it:
/// the nearer of the two hits lies, in world space, within
///   2 |d(t)| + 2^-21 (t |dir| + |P|)
/// of an edge of its triangle, where P is the world ray's point at that t and d(t) the distance
/// at t between the world ray and the object-space ray mapped back (in double), or the hit lies
/// within a relative 2^-18 of tmin or tmax. Anything else stays a mismatch. Throws Error unless
/// rays, inst and flat have one size.
Comparison compare_flattened(const InstanceScene& scene, const Scene& flat_scene, std::span<const Ray> rays,
                             std::span<const InstanceHit> inst, std::span<const Hit> flat);

}  // namespace mbvh

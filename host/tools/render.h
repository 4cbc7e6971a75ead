// SPDX-License-Identifier: MIT
// render.h — `mbvh render`: the thesis' end-to-end workload, a wavefront path tracer on any
// backend (generate a batch of rays, trace it on the backend, shade on the host, next bounce),
// plus ambient-occlusion and normals modes. The images are written by image.h.
#pragma once
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/lod.h"
#include "host/tools/framing.h"
#include "host/tools/image.h"
#include "host/tools/raygen.h"
#include "mbvh/scene.h"

namespace mbvh {

enum class RenderMode { path, ao, normals };
const char* to_string(RenderMode m);
RenderMode parse_render_mode(const std::string& s);  ///< throws Error on an unknown name

struct RenderOptions {
  unsigned width = 512, height = 512;
  unsigned spp = 4;       ///< samples per pixel (one sample pass each)
  unsigned bounces = 8;   ///< path mode: diffuse bounces after the primary hit
  RenderMode mode = RenderMode::path;
  std::uint64_t seed = 1;
  bool has_camera = false;  ///< `camera` instead of the scene's framing (framing.h frame_scene)
  Camera camera;
  bool has_light = false;   ///< `light` instead of default_light(bounds)
  Vec3f light;
  Layout layout = Layout::automatic;        ///< automatic: resolved per query by the backend (resolve_options)
  Traversal traversal = Traversal::automatic;
  unsigned threads = 0;   ///< host shading threads (0 = all)
  Precision precision = Precision::robust;  ///< the backend's accuracy mode
  /// If set (width x height x 3 linear floats), the RMSE of the running mean against it after
  /// every sample pass: RenderResult::curve (image error against time).
  const std::vector<float>* reference = nullptr;
  /// If set, every closest-hit ray the renderer traces (all bounces, in order) is appended: the
  /// `path` ray kind of the benchmark.
  std::vector<Ray>* capture = nullptr;
  /// If set, only the pixels of these 8x8 tiles are rendered (tile t: column t % tiles_x(width),
  /// row t / tiles_x(width)), in this order; the other pixels stay 0. Every pixel's value is the
  /// one a whole render gives it (mbvh-mpi: each rank renders its tiles).
  const std::vector<std::uint32_t>* tiles = nullptr;
  /// If set, traces every batch instead of backend.trace: mbvh-mpi's collective trace over the
  /// ranks' parts of the scene. It is then called the same number of times whatever the batch
  /// sizes (empty batches too): once for the camera's probe rays without a camera, then for every
  /// sample pass, per bounce, one closest-hit batch and one any-hit batch (normals: the first
  /// closest-hit batch only; ao: one bounce).
  std::function<void(std::span<const Ray>, const TraceOptions&, TraceOutput&)> tracer;
  /// If set, the scene's bounds (framing, light, AO radius) instead of acc.bounds(): with
  /// `tracer`, `acc` may hold a part of the scene.
  const Box* bounds = nullptr;
};

/// The 8x8 tiles across an image `width` pixels wide (RenderOptions::tiles).
inline unsigned tiles_x(unsigned width) { return (width + 7) / 8; }
/// The 8x8 tiles of a width x height image.
inline std::uint32_t tile_count(unsigned width, unsigned height) { return tiles_x(width) * ((height + 7) / 8); }

/// One point of the image-error-against-time curve.
struct CurvePoint {
  unsigned spp = 0;
  double trace_seconds = 0, total_seconds = 0;  ///< so far, the RMSE computation left out
  double rmse = 0;                              ///< of the mean of `spp` samples against the reference
};

struct RenderResult {
  unsigned width = 0, height = 0;
  std::vector<float> rgb;          ///< linear radiance, 3 floats per pixel, row by row from the top
  std::size_t rays = 0;            ///< rays traced over all bounces (closest and shadow/AO rays)
  double trace_seconds = 0;        ///< time inside Backend::trace
  double total_seconds = 0;        ///< the whole render, shading and ray generation included
  std::vector<CurvePoint> curve;   ///< with RenderOptions::reference: one point per sample pass
  std::uint64_t voxel_hits = 0;    ///< lod::Model: closest hits on LOD voxels (all bounces)
  std::uint64_t forced_voxels = 0; ///< lod::Model: those taken because a finer block was not resident
  Camera camera;                   ///< the camera rendered from: the given one or the scene's framing
  std::string camera_rule;         ///< without a given camera: how frame_scene chose it (Framing::rule)
  double mrays_per_s() const { return trace_seconds > 0 ? static_cast<double>(rays) / trace_seconds * 1e-6 : 0; }
};

/// Renders `scene` (built as `acc`) on `backend`, from opt.camera or, without one, the camera
/// frame_scene picks (its probe rays traced on `backend`, not counted in RenderResult::rays).
/// Lambertian surfaces (albedo: the triangle's material's diffuse colour, else grey 0.7), a point light
/// at default_light with shadow rays (any hit) and a sky for rays that leave the scene. Every
/// random number depends only on (seed, pixel, sample, bounce), and every pixel's samples are
/// summed in sample order, so the same seed gives the same image on every backend whose answers
/// are bit-identical (all of mbvh's), at any thread count. `progress(done, total)` after each
/// sample pass. Throws Error for an empty image or a backend that lacks the layout/traversal.
RenderResult render(const Scene& scene, const Accel& acc, Backend& backend, const RenderOptions& opt,
                    const std::function<void(unsigned, unsigned)>& progress = {});

/// How a lod::Model is traced (mbvh/lod.h TraceOptions).
struct ModelRenderOptions {
  bool lod = true;     ///< false: full detail (every needed block loaded), the exact contract's answers
  float quality = 1;   ///< a voxel is accepted when its box's largest extent <= quality * the ray's footprint
};

/// Renders an out-of-core model (mbvh/lod.h) with the same shading, sampling and determinism
/// rules as the in-core render (RenderOptions' layout, traversal, precision and tracer do not
/// apply; its tracing threads are the model's CacheOptions::threads). Every ray carries a cone
/// (lod::RayCone): primary rays a pixel's (width 0 at the eye, spread 2 tan(fov/2) / height);
/// secondary rays start with their parent's footprint at the hit point, shadow rays keep it
/// (a cylinder), AO and diffuse rays widen it by 0.2 rad. A triangle hit shades as in core (its
/// vertices copied by the model, its albedo from the model's table, else grey 0.7), so at quality 0
/// with synchronous loading (or with `lod` false) the image is the in-core render's, byte for
/// byte. A voxel hit shades with its face's normal turned to face the ray and its face's colour at
/// o + t d; its secondary rays start there, pushed off the face by 1e-5 of the point's largest
/// coordinate, and skip their first quality x the footprint at the hit (tmin: the hierarchy's
/// boxes overlap, so the point often lies inside a neighbouring voxel). Without a camera, frame_scene's probes are traced at full detail. The default
/// light and AO radius come from model.bounds() (= Accel::bounds() of the same triangles). Does
/// not call Model::end_frame (the caller ends each frame). Throws Error for an empty image, a
/// negative or non-finite quality, or what Model::trace throws.
RenderResult render(lod::Model& model, const RenderOptions& opt, const ModelRenderOptions& mo,
                    const std::function<void(unsigned, unsigned)>& progress = {});

/// The rays of the path tracer's bounces (closest-hit continuation rays of every bounce, primary
/// rays included) from 1-spp renders with the reference traversal (cpu-scalar), about `count` of them (at least
/// 1): the thesis' workload as a benchmark ray kind. Deterministic by seed.
std::vector<Ray> path_tracer_rays(const Scene& scene, const Accel& acc, std::size_t count, std::uint64_t seed,
                                  const Camera* camera, unsigned threads);
/// Root-mean-square difference of two images of the same size (linear values).
double rmse(const std::vector<float>& a, const std::vector<float>& b);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// render.cpp — the wavefront renderer of `mbvh render` (render.h); its images are written by image.cpp.
// Path mode is the thesis' workload (Áfra, 2014: an 8-bounce diffuse path tracer over ray
// batches): every bounce traces one batch of continuation rays (closest hit) and one batch of
// shadow rays (any hit) on the chosen backend; shading, sampling and accumulation run on the host.
// The same renderer draws an out-of-core lod::Model (the thesis' ch. 5): tracing and the surface
// lookup go through HitSource, whose two implementations are an in-core scene on a backend and
// the model (rays with cones; triangle hits shade as in core, voxel hits from their face).
#include "host/tools/render.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <numbers>

#include "mbvh/error.h"
#include "host/core/parallel.h"
#include "host/core/random.h"

namespace mbvh {

const char* to_string(RenderMode m) {
  switch (m) {
    case RenderMode::path: return "path";
    case RenderMode::ao: return "ao";
    case RenderMode::normals: return "normals";
  }
  return "?";
}

RenderMode parse_render_mode(const std::string& s) {
  if (s == "path") return RenderMode::path;
  if (s == "ao") return RenderMode::ao;
  if (s == "normals") return RenderMode::normals;
  throw Error("unknown render mode '" + s + "' (known: path, ao, normals)");
}

namespace {

constexpr float kAlbedo = 0.7f;
using lod::RayCone;

struct Rgb {
  float r = 0, g = 0, b = 0;
};

// The sky a ray sees when it leaves the scene: white-blue, brighter towards +y.
Rgb sky(const Ray& ray) {
  const float len = std::sqrt(ray.dx * ray.dx + ray.dy * ray.dy + ray.dz * ray.dz);
  const float t = 0.5f * (ray.dy / len + 1.0f);
  const float k = 0.35f + 0.45f * t;
  return {0.85f * k, 0.92f * k, 1.0f * k};
}

// One path (or one AO / normals sample) in flight: its pixel, throughput and random stream.
struct Path {
  std::uint32_t pixel;
  Rgb thr;
  Rng rng;
};

Rng path_rng(std::uint64_t seed, std::size_t pixel, unsigned sample) {
  Rng h(seed);
  return Rng(h.next() ^ (static_cast<std::uint64_t>(pixel) * 0x9E3779B97F4A7C15ull) ^
             (static_cast<std::uint64_t>(sample) << 40));
}

// The cones of secondary rays on a lod::Model (RayCone; the design's B1 step 6): every secondary
// ray starts with the footprint its parent ray had at the hit point (width0); shadow rays keep it
// (spread 0: a cylinder towards the point light), AO and diffuse rays widen it by these angles
// (radians). The design brief puts AO cones at 0.1-0.3 rad and diffuse ones no finer ("low LODs
// suffice for GI", Áfra 2012); 0.2 rad for both is the middle of that range.
constexpr float kAoSpread = 0.2f;
constexpr float kDiffuseSpread = 0.2f;
// A voxel hit's secondary rays start at o + t*d pushed along the voxel's facing normal by this
// fraction of the largest coordinate magnitude of the point and of the ray's origin (about 84
// float ulps of it): beyond the rounding of o + t*d, so the ray leaves the face it hit.
constexpr float kVoxelOffset = 1e-5f;
// ... and skip their first kVoxelSkip * quality * w, w the footprint at the hit. The hierarchy's
// boxes overlap (a BVH's siblings do; the paper's kd-tree cells did not), so the point of a voxel
// hit often lies inside a neighbouring voxel's box, which a ray starting there would hit at once
// (self-occlusion: voxel surfaces too dark). A voxel the secondary ray accepts near its origin has
// a largest extent E <= quality * (w + spread * t) and is left within sqrt(3) E: skipping
// 3 quality w would leave every such box behind, but also drops occlusion the LOD does resolve
// (too bright); 1 quality w, the size of the voxels the footprint accepts, keeps AO closest to
// full detail's (docs/massive.md, "Rendering a model", has the comparison).
constexpr float kVoxelSkip = 1.0f;
// A closest hit as the shader sees it: the same for a triangle of an in-core scene, a triangle of a
// lod::Model (its vertices copied while its block was resident) and a model's LOD voxel.
struct Surface {
  Vec3f a, b, c, n, p;  ///< triangle (voxel: unused), normal facing the incoming ray, hit point
  Rgb albedo;           ///< its material's diffuse colour, or grey
  float t = 0, u = 0, v = 0;
  bool voxel = false;
  float origin_scale = 0;  ///< voxel: the largest coordinate magnitude of the point and the ray's origin
  float skip = 0;          ///< voxel: the tmin of its secondary rays (kVoxelSkip), set by the renderer

  /// A secondary ray from this surface: spawn_ray's error-bound offset on a triangle; on a voxel
  /// the point pushed off the face by kVoxelOffset (the ray leaves its box: a direction on the
  /// normal's side of the face never re-enters the box behind it), tmin `skip`.
  Ray spawn(const Vec3f& dir, float tmax) const {
    if (!voxel) return spawn_ray(a, b, c, u, v, dir, tmax);
    const float off = kVoxelOffset * origin_scale;
    const float s = n.x * dir.x + n.y * dir.y + n.z * dir.z < 0 ? -off : off;
    return Ray{p.x + s * n.x, p.y + s * n.y, p.z + s * n.z, std::min(skip, tmax), dir.x, dir.y, dir.z, tmax};
  }
};

Surface triangle_surface(const Vec3f& a, const Vec3f& b, const Vec3f& c, const Rgb& albedo, const Ray& ray, float t,
                         float u, float v) {
  Surface f;
  f.a = a;
  f.b = b;
  f.c = c;
  f.albedo = albedo;
  f.n = facing_normal(f.a, f.b, f.c, Vec3f{ray.dx, ray.dy, ray.dz});
  const float b0 = 1.0f - u - v;
  for (int k = 0; k < 3; ++k) f.p[k] = b0 * f.a[k] + u * f.b[k] + v * f.c[k];
  f.t = t;
  f.u = u;
  f.v = v;
  return f;
}

// Where the renderer's rays are traced and its surfaces looked up: an in-core scene on a backend
// (CoreSource) or an out-of-core lod::Model (ModelSource). One shading code path over both.
class HitSource {
public:
  virtual ~HitSource() = default;
  /// Whether closest() and any() use the rays' cones (the renderer tracks them only then).
  virtual bool wants_cones() const = 0;
  /// The framing probes' closest hits (frame_scene): the exact answers.
  virtual void probe(std::span<const Ray> rays, std::vector<Hit>& hits) = 0;
  /// Traces a closest-hit batch; hit(i) and surface(i, ray) then describe ray i's answer.
  virtual void closest(std::span<const Ray> rays, std::span<const RayCone> cones) = 0;
  virtual bool hit(std::size_t i) const = 0;
  virtual Surface surface(std::size_t i, const Ray& ray) const = 0;
  /// Traces an any-hit batch: one flag per ray.
  virtual void any(std::span<const Ray> rays, std::span<const RayCone> cones, std::vector<std::uint8_t>& occluded) = 0;
};

// An in-core scene built as `acc`, traced on `backend` (or RenderOptions::tracer).
class CoreSource final : public HitSource {
public:
  CoreSource(const Scene& scene, const Accel& acc, Backend& backend, const RenderOptions& opt)
      : scene_(scene), acc_(acc), backend_(backend), opt_(opt) {}
  bool wants_cones() const override { return false; }
  void probe(std::span<const Ray> rays, std::vector<Hit>& hits) override {
    TraceOutput out;
    trace_batch(rays, TraceOptions{opt_.layout, opt_.traversal, Query::closest, false, opt_.precision}, out);
    hits = std::move(out.hits);
  }
  void closest(std::span<const Ray> rays, std::span<const RayCone>) override { trace_batch(rays, options(Query::closest), hits_); }
  bool hit(std::size_t i) const override { return hits_.hits[i].prim != MBVH_MISS_PRIM; }
  Surface surface(std::size_t i, const Ray& ray) const override {
    const Hit& h = hits_.hits[i];
    Vec3f a, b, c;
    tri_vertices(scene_, h.prim, a, b, c);
    Rgb albedo{kAlbedo, kAlbedo, kAlbedo};
    if (scene_.triangle_materials.size() == scene_.triangle_count())
      if (const std::uint32_t m = scene_.triangle_materials[h.prim]; m < scene_.materials.size())
        albedo = Rgb{scene_.materials[m].diffuse.x, scene_.materials[m].diffuse.y, scene_.materials[m].diffuse.z};
    return triangle_surface(a, b, c, albedo, ray, h.t, h.u, h.v);
  }
  void any(std::span<const Ray> rays, std::span<const RayCone>, std::vector<std::uint8_t>& occluded) override {
    trace_batch(rays, options(Query::any), occ_);
    occluded.swap(occ_.occluded);
  }

private:
  TraceOptions options(Query q) const {
    TraceOptions o;
    o.layout = opt_.layout;
    o.traversal = opt_.traversal;
    o.query = q;
    o.precision = opt_.precision;
    return o;
  }
  // The backend's trace, or RenderOptions::tracer (a collective call: made for empty batches too).
  void trace_batch(std::span<const Ray> rays, const TraceOptions& o, TraceOutput& out) {
    if (opt_.tracer) opt_.tracer(rays, o, out);
    else backend_.trace(acc_, rays, o, out);
  }

  const Scene& scene_;
  const Accel& acc_;
  Backend& backend_;
  const RenderOptions& opt_;
  TraceOutput hits_, occ_;
};

// An out-of-core model (mbvh/lod.h), traced with the rays' cones. A triangle hit shades as in
// core (its vertices from lod::Surface, its albedo from the model's table); a voxel hit with its
// face's normal turned to face the ray, its face's colour and the point o + t*d.
class ModelSource final : public HitSource {
public:
  ModelSource(lod::Model& model, const ModelRenderOptions& mo)
      : model_(model), mo_(mo), grey_(model.albedos().empty()) {}
  std::uint64_t voxel_hits = 0, forced_voxels = 0;  ///< closest hits on voxels, and those forced by a missing block

  bool wants_cones() const override { return mo_.lod; }
  void probe(std::span<const Ray> rays, std::vector<Hit>& hits) override {
    lod::TraceOptions o;
    o.lod = false;  // the exact answers: the camera does not depend on what is resident
    model_.trace(rays, {}, o, lhits_);
    hits.resize(lhits_.size());
    for (std::size_t i = 0; i < lhits_.size(); ++i) hits[i] = lhits_[i].plain();
  }
  void closest(std::span<const Ray> rays, std::span<const RayCone> cones) override {
    model_.trace(rays, mo_.lod ? cones : std::span<const RayCone>{}, options(Query::closest), lhits_, &surfaces_);
    for (const lod::Hit& h : lhits_)
      if (h.kind == lod::HitKind::voxel) {
        ++voxel_hits;
        forced_voxels += h.forced;
      }
  }
  bool hit(std::size_t i) const override { return lhits_[i].kind != lod::HitKind::miss; }
  Surface surface(std::size_t i, const Ray& ray) const override {
    const lod::Hit& h = lhits_[i];
    const Rgb albedo = grey_ ? Rgb{kAlbedo, kAlbedo, kAlbedo} : Rgb{h.albedo.x, h.albedo.y, h.albedo.z};
    if (h.kind == lod::HitKind::triangle) {
      const float* v = surfaces_[i].v;
      return triangle_surface(Vec3f{v[0], v[1], v[2]}, Vec3f{v[3], v[4], v[5]}, Vec3f{v[6], v[7], v[8]}, albedo, ray,
                              h.t, h.u, h.v);
    }
    Surface f;
    f.voxel = true;
    f.t = h.t;
    f.albedo = albedo;
    const bool flip = h.normal.x * ray.dx + h.normal.y * ray.dy + h.normal.z * ray.dz > 0;
    f.n = flip ? Vec3f{-h.normal.x, -h.normal.y, -h.normal.z} : h.normal;
    float scale = 0;
    for (int k = 0; k < 3; ++k) {
      const float o = k == 0 ? ray.ox : k == 1 ? ray.oy : ray.oz;
      const float d = k == 0 ? ray.dx : k == 1 ? ray.dy : ray.dz;
      f.p[k] = o + h.t * d;
      scale = std::max({scale, std::fabs(f.p[k]), std::fabs(o)});
    }
    f.origin_scale = scale;
    return f;
  }
  void any(std::span<const Ray> rays, std::span<const RayCone> cones, std::vector<std::uint8_t>& occluded) override {
    model_.trace(rays, mo_.lod ? cones : std::span<const RayCone>{}, options(Query::any), ahits_);
    occluded.resize(ahits_.size());
    for (std::size_t i = 0; i < ahits_.size(); ++i) occluded[i] = ahits_[i].kind != lod::HitKind::miss;
  }

private:
  lod::TraceOptions options(Query q) const {
    lod::TraceOptions o;
    o.query = q;
    o.lod = mo_.lod;
    o.quality = mo_.quality;
    return o;
  }

  lod::Model& model_;
  const ModelRenderOptions& mo_;
  bool grey_;  ///< the model has no albedo table: every surface is the default grey
  std::vector<lod::Hit> lhits_, ahits_;
  std::vector<lod::Surface> surfaces_;
};

// The options every renderer checks, whatever traces its rays.
void check_options(const RenderOptions& opt) {
  if (opt.width == 0 || opt.height == 0) throw Error("render: the image is empty (width and height must be > 0)");
  if (opt.spp == 0) throw Error("render: --spp must be at least 1");
  if (opt.reference && opt.reference->size() != static_cast<std::size_t>(opt.width) * opt.height * 3)
    throw Error("render: the reference image is not " + std::to_string(opt.width) + "x" + std::to_string(opt.height));
}

class Renderer {
public:
  /// `bounds`: the scene's (framing, light, AO radius); `quality`: the LOD quality of a model's
  /// voxels (0: none), which sets how far their secondary rays skip (kVoxelSkip).
  Renderer(HitSource& src, const Box& bounds, const RenderOptions& opt, float quality = 0)
      : src_(src), opt_(opt), quality_(quality) {
    if (opt.has_camera) cam_ = opt.camera;
    else {
      const Framing f = frame_scene(bounds, [this](const std::vector<Ray>& rays, std::vector<Hit>& hits) { src_.probe(rays, hits); });
      cam_ = f.camera;
      res_.camera_rule = f.rule;
    }
    res_.camera = cam_;
    if (const std::string p = camera_problem(cam_); !p.empty()) throw Error("render: camera: " + p);
    light_ = opt.has_light ? opt.light : default_light(bounds);
    const Vec3f e = bounds.extent();
    diag2_ = e.x * e.x + e.y * e.y + e.z * e.z;
    light_power_ = 0.08f * diag2_;  // lights the scene at about half its diagonal
    ao_radius_ = 0.1f * std::sqrt(diag2_);
    // the angle a pixel subtends at the eye (the vertical field over the image's height): the
    // spread of the primary rays' cones
    pixel_angle_ = static_cast<float>(2.0 * std::tan(double(cam_.fov_deg) * std::numbers::pi / 360.0) / opt.height);
  }

  /// The pixels in the order their paths are traced: 8x8 tiles, rows of tiles, each tile row by
  /// row (clipped at the image's edges), as tiled renderers trace them: 64 consecutive camera rays
  /// are one tile, a packet of the cpu backend's packet traversals (MBVH_PACKET_RAYS), and the
  /// shadow and next rays keep the order of their paths.
  /// With RenderOptions::tiles, the pixels of those tiles in their order.
  static std::vector<std::uint32_t> tile_order(unsigned w, unsigned h, const std::vector<std::uint32_t>* tiles) {
    constexpr unsigned kTile = 8;
    std::vector<std::uint32_t> order;
    const std::uint32_t count = tile_count(w, h);
    auto add_tile = [&](std::uint32_t t) {
      if (t >= count)
        throw Error("render: tile " + std::to_string(t) + " is not one of the image's " + std::to_string(count) + " tiles");
      const unsigned tx = (t % tiles_x(w)) * kTile, ty = (t / tiles_x(w)) * kTile;
      for (unsigned y = ty; y < std::min(h, ty + kTile); ++y)
        for (unsigned x = tx; x < std::min(w, tx + kTile); ++x) order.push_back(y * w + x);
    };
    if (tiles) {
      for (std::uint32_t t : *tiles) add_tile(t);
    } else {
      order.reserve(static_cast<std::size_t>(w) * h);
      for (std::uint32_t t = 0; t < count; ++t) add_tile(t);
    }
    return order;
  }

  RenderResult run(const std::function<void(unsigned, unsigned)>& progress) {
    tile_order_ = tile_order(opt_.width, opt_.height, opt_.tiles);
    const auto t0 = std::chrono::steady_clock::now();
    res_.width = opt_.width;
    res_.height = opt_.height;
    const std::size_t pixels = static_cast<std::size_t>(opt_.width) * opt_.height;
    res_.rgb.assign(pixels * 3, 0.0f);
    double excluded = 0;  // seconds spent on the error curve
    for (unsigned s = 0; s < opt_.spp; ++s) {
      sample_pass(s);
      if (opt_.reference) {
        const auto c0 = std::chrono::steady_clock::now();
        const double elapsed = std::chrono::duration<double>(c0 - t0).count() - excluded;
        std::vector<float> mean(res_.rgb);
        for (float& v : mean) v /= static_cast<float>(s + 1);
        res_.curve.push_back(CurvePoint{s + 1, res_.trace_seconds, elapsed, rmse(mean, *opt_.reference)});
        excluded += std::chrono::duration<double>(std::chrono::steady_clock::now() - c0).count();
      }
      if (progress) progress(s + 1, opt_.spp);
    }
    for (float& v : res_.rgb) v /= static_cast<float>(opt_.spp);
    res_.total_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() - excluded;
    return std::move(res_);
  }

private:
  void trace_closest(const std::vector<Ray>& rays, const std::vector<RayCone>& cones) {
    if (opt_.capture) opt_.capture->insert(opt_.capture->end(), rays.begin(), rays.end());
    const auto t0 = std::chrono::steady_clock::now();
    src_.closest(rays, cones);
    res_.trace_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    res_.rays += rays.size();
  }

  void trace_any(const std::vector<Ray>& rays, const std::vector<RayCone>& cones, std::vector<std::uint8_t>& occluded) {
    const auto t0 = std::chrono::steady_clock::now();
    src_.any(rays, cones, occluded);
    res_.trace_seconds += std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    res_.rays += rays.size();
  }

  void add(std::uint32_t pixel, const Rgb& c) {
    float* p = &res_.rgb[static_cast<std::size_t>(pixel) * 3];
    p[0] += c.r;
    p[1] += c.g;
    p[2] += c.b;
  }

  // Runs fn(i) for i in [0, n) on the host threads; each i touches only its own path and pixel.
  template <class F>
  void for_each(std::size_t n, F&& fn) {
    parallel_for(n, 4096, opt_.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) fn(i);
    });
  }

  void sample_pass(unsigned sample) {
    const std::size_t pixels = tile_order_.size();  // all of them, or those of RenderOptions::tiles
    const double aspect = double(opt_.width) / double(opt_.height);
    const bool with_cones = src_.wants_cones();
    std::vector<Path> paths(pixels, Path{0, {1, 1, 1}, Rng(0)});
    std::vector<Ray> rays(pixels);
    // the cone of each ray of `rays` (with_cones only): primary rays, a pixel's cone from the eye
    std::vector<RayCone> cones(with_cones ? pixels : 0, RayCone{0.0f, pixel_angle_});
    for_each(pixels, [&](std::size_t i) {
      Path& p = paths[i];
      const std::uint32_t pixel = tile_order_[i];
      p.pixel = pixel;
      p.rng = path_rng(opt_.seed, pixel, sample);
      const double px = (double(pixel % opt_.width) + p.rng.uniform_d()) / opt_.width;
      const double py = (double(pixel / opt_.width) + p.rng.uniform_d()) / opt_.height;
      rays[i] = camera_ray(cam_, px, py, aspect);
    });
    const unsigned bounces = opt_.mode == RenderMode::path ? opt_.bounces + 1 : 1;
    std::vector<std::uint8_t> occluded;
    std::vector<Ray> next, shadow;
    std::vector<RayCone> next_cones, shadow_cones;
    std::vector<Path> next_paths;
    std::vector<Rgb> direct;
    // with a collective tracer every rank makes the same calls, so no early end on an empty batch
    const bool collective = static_cast<bool>(opt_.tracer);
    for (unsigned bounce = 0; bounce < bounces && (collective || !rays.empty()); ++bounce) {
      trace_closest(rays, cones);
      const std::size_t n = rays.size();
      if (opt_.mode == RenderMode::normals) {
        for_each(n, [&](std::size_t i) {
          if (!src_.hit(i)) return;
          const Surface f = src_.surface(i, rays[i]);
          add(paths[i].pixel, Rgb{0.5f * (f.n.x + 1), 0.5f * (f.n.y + 1), 0.5f * (f.n.z + 1)});
        });
        return;
      }
      // -- secondary rays of every live path: shadow / AO ray and (path mode) the next bounce
      shadow.resize(n);
      next.resize(n);
      direct.resize(n);
      if (with_cones) {
        shadow_cones.resize(n);
        next_cones.resize(n);
      }
      std::vector<std::uint8_t> alive(n, 0), lit(n, 0);  // lit: has a shadow / AO ray
      for_each(n, [&](std::size_t i) {
        Path& p = paths[i];
        if (!src_.hit(i)) {
          if (opt_.mode == RenderMode::ao) add(p.pixel, Rgb{1, 1, 1});
          else {
            const Rgb s = sky(rays[i]);
            add(p.pixel, Rgb{p.thr.r * s.r, p.thr.g * s.g, p.thr.b * s.b});
          }
          return;
        }
        Surface f = src_.surface(i, rays[i]);
        // the footprint at the hit point: the width every secondary ray's cone starts from
        const float width = with_cones ? cones[i].width0 + cones[i].spread * f.t : 0.0f;
        if (f.voxel) f.skip = kVoxelSkip * quality_ * width;
        const double r1 = p.rng.uniform_d(), r2 = p.rng.uniform_d();
        if (opt_.mode == RenderMode::ao) {
          shadow[i] = f.spawn(cosine_direction(f.n, r1, r2), ao_radius_);
          if (with_cones) shadow_cones[i] = RayCone{width, kAoSpread};
          direct[i] = Rgb{1, 1, 1};
          lit[i] = 1;
          return;
        }
        // direct light from the point light, if it is above the surface
        const Vec3f to{light_.x - f.p.x, light_.y - f.p.y, light_.z - f.p.z};
        const float d2 = to.x * to.x + to.y * to.y + to.z * to.z;
        const float d = std::sqrt(d2);
        const float cosl = (to.x * f.n.x + to.y * f.n.y + to.z * f.n.z) / d;
        if (cosl > 0 && d > 0) {
          shadow[i] = f.spawn(Vec3f{to.x / d, to.y / d, to.z / d}, d);
          if (with_cones) shadow_cones[i] = RayCone{width, 0.0f};  // a cylinder towards the point light
          // per channel, the products in the order of the grey renderer's (the same grey images, bit for bit)
          const auto lambert = [&](float albedo) { return albedo / std::numbers::pi_v<float> * light_power_ * cosl / d2; };
          direct[i] = Rgb{p.thr.r * lambert(f.albedo.r), p.thr.g * lambert(f.albedo.g), p.thr.b * lambert(f.albedo.b)};
          lit[i] = 1;
        }
        // the next bounce: cosine-weighted, throughput times the albedo (Lambertian)
        next[i] = f.spawn(cosine_direction(f.n, r1, r2), INFINITY);
        if (with_cones) next_cones[i] = RayCone{width, kDiffuseSpread};
        p.thr = Rgb{p.thr.r * f.albedo.r, p.thr.g * f.albedo.g, p.thr.b * f.albedo.b};
        alive[i] = 1;
      });
      // -- the shadow / AO rays, compacted (in path order), traced as one any-hit batch
      std::vector<std::uint32_t> lit_paths;
      std::vector<Ray> lit_rays;
      std::vector<RayCone> lit_cones;
      for (std::size_t i = 0; i < n; ++i)
        if (lit[i]) {
          lit_paths.push_back(static_cast<std::uint32_t>(i));
          lit_rays.push_back(shadow[i]);
          if (with_cones) lit_cones.push_back(shadow_cones[i]);
        }
      if (collective || !lit_rays.empty()) trace_any(lit_rays, lit_cones, occluded);
      for_each(lit_paths.size(), [&](std::size_t k) {
        if (!occluded[k]) add(paths[lit_paths[k]].pixel, direct[lit_paths[k]]);
      });
      if (opt_.mode == RenderMode::ao || bounce + 1 == bounces) return;
      // -- compact the live paths (in path order: deterministic)
      next_paths.clear();
      std::vector<Ray> live;
      std::vector<RayCone> live_cones;
      for (std::size_t i = 0; i < n; ++i)
        if (alive[i]) {
          next_paths.push_back(paths[i]);
          live.push_back(next[i]);
          if (with_cones) live_cones.push_back(next_cones[i]);
        }
      paths.swap(next_paths);
      rays.swap(live);
      cones.swap(live_cones);
    }
  }

  HitSource& src_;
  const RenderOptions& opt_;
  Camera cam_;
  Vec3f light_;
  float diag2_ = 1, light_power_ = 1, ao_radius_ = 1;
  float pixel_angle_ = 0;
  float quality_ = 0;
  RenderResult res_;
  std::vector<std::uint32_t> tile_order_;  ///< tile_order(), made by run
};

}  // namespace

std::vector<Ray> path_tracer_rays(const Scene& scene, const Accel& acc, std::size_t count, std::uint64_t seed,
                                  const Camera* camera, unsigned threads) {
  BackendOptions bo;
  bo.threads = threads;
  const auto tracer = make_backend("cpu-scalar", bo);  // the reference traversals
  std::vector<Ray> rays;
  RenderOptions o;
  // about 3 closest-hit rays per pixel over the bounces (the count is measured below anyway)
  o.width = o.height = std::max(1u, static_cast<unsigned>(std::sqrt(static_cast<double>(std::max<std::size_t>(count, 1)) / 3.0)));
  o.spp = 1;
  o.threads = threads;
  o.capture = &rays;
  // the benchmark's rays keep the outside framing they were recorded with (not frame_scene's)
  o.has_camera = true;
  o.camera = camera ? *camera : default_camera(acc.bounds());
  for (std::uint64_t pass = 0; rays.size() < std::max<std::size_t>(count, 1); ++pass) {
    o.seed = seed + pass;
    render(scene, acc, *tracer, o);
  }
  rays.resize(std::max<std::size_t>(count, 1));
  return rays;
}

double rmse(const std::vector<float>& a, const std::vector<float>& b) {
  if (a.size() != b.size()) throw Error("rmse: images of different sizes");
  double sum = 0;
  for (std::size_t i = 0; i < a.size(); ++i) sum += (double(a[i]) - b[i]) * (double(a[i]) - b[i]);
  return a.empty() ? 0.0 : std::sqrt(sum / static_cast<double>(a.size()));
}

RenderResult render(const Scene& scene, const Accel& acc, Backend& backend, const RenderOptions& asked,
                    const std::function<void(unsigned, unsigned)>& progress) {
  // an automatic layout or traversal: the backend's fastest closest-hit pair, for every bounce
  RenderOptions opt = asked;
  TraceOptions t;
  t.layout = opt.layout;
  t.traversal = opt.traversal;
  t = resolve_options(backend, t);
  opt.layout = t.layout;
  opt.traversal = t.traversal;
  check_options(opt);
  if (!backend.supports_precision(opt.precision))
    throw Error("render: backend '" + backend.name() + "' has no '" + to_string(opt.precision) + "' precision");
  if (!backend.supports(opt.layout, opt.traversal))
    throw Error("render: backend '" + backend.name() + "' has no " + to_string(opt.layout) + "/" +
                to_string(opt.traversal) + " traversal");
  CoreSource src(scene, acc, backend, opt);
  Renderer r(src, opt.bounds ? *opt.bounds : acc.bounds(), opt);
  return r.run(progress);
}

RenderResult render(lod::Model& model, const RenderOptions& opt, const ModelRenderOptions& mo,
                    const std::function<void(unsigned, unsigned)>& progress) {
  check_options(opt);
  if (opt.tracer) throw Error("render: a lod::Model is traced by itself (RenderOptions::tracer is for in-core scenes)");
  if (!(mo.quality >= 0) || !std::isfinite(mo.quality))
    throw Error("render: --lod-quality " + std::to_string(mo.quality) + " is not a finite number >= 0");
  ModelSource src(model, mo);
  Renderer r(src, opt.bounds ? *opt.bounds : model.bounds(), opt, mo.lod ? mo.quality : 0.0f);
  RenderResult res = r.run(progress);
  res.voxel_hits = src.voxel_hits;
  res.forced_voxels = src.forced_voxels;
  return res;
}

}  // namespace mbvh

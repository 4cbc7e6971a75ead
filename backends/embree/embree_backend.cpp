// SPDX-License-Identifier: MIT
// embree_backend.cpp — the `embree` peer backend: Embree 3's robust single-ray queries
// (rtcIntersect1 / rtcOccluded1 with RTC_SCENE_FLAG_ROBUST) on the same triangles and rays, so
// `mbvh bench` times it side by side with the other backends in one run and the tests use it as a
// second, independent witness. Built when Debian's libembree-dev is installed.
//
// Embree builds its own BVH from the build's leaf-ordered triangles (degenerate ones are not
// there, as in every layout); its primitive index maps back to the file's prim id. It answers
// under the label mbvh4/stack (Embree's single-ray kernels traverse a wide BVH with a stack), with
// its own triangle test, so its answers agree with cpu-scalar's up to classified ties rather than
// bit for bit (Backend::peer), and it has no per-ray counters.
//
// Embree accepts only rays and vertices whose coordinates lie within ±1.844e18 (its FLT_LARGE;
// Debian's build asserts `ray.valid()` and aborts the process on any other ray): such a ray,
// valid by mbvh's numerical contract, is an Error naming it, never handed to Embree.
#include <embree3/rtcore.h>

#include <algorithm>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <mutex>
#include <span>
#include <vector>

#include "backends/common/build_stamp.h"
#include "backends/embree/embree_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"

namespace mbvh {
namespace {

/// Embree's FLT_LARGE: the largest coordinate magnitude of a ray origin or direction it accepts
/// (RayK::valid) and of a vertex it builds (isvalid, strictly below).
constexpr float kEmbreeLarge = 1.844e18f;

/// Whether Embree accepts the ray's origin and direction (RayK::valid without the t checks, which
/// prepare_ray's valid rays pass).
bool within_embree(const Ray& r) {
  return std::fabs(r.ox) <= kEmbreeLarge && std::fabs(r.oy) <= kEmbreeLarge && std::fabs(r.oz) <= kEmbreeLarge &&
         std::fabs(r.dx) <= kEmbreeLarge && std::fabs(r.dy) <= kEmbreeLarge && std::fabs(r.dz) <= kEmbreeLarge;
}

/// "origin x = 2e+18": the first of a ray's origin and direction components beyond kEmbreeLarge,
/// "" if none.
std::string beyond_embree(const Ray& r) {
  const float c[6] = {r.ox, r.oy, r.oz, r.dx, r.dy, r.dz};
  for (int k = 0; k < 6; ++k)
    if (!(std::fabs(c[k]) <= kEmbreeLarge)) {
      char text[64];
      std::snprintf(text, sizeof text, "%s %c = %g", k < 3 ? "origin" : "direction", "xyz"[k % 3], static_cast<double>(c[k]));
      return text;
    }
  return "";
}

// The embree.quality setting, refused by its name when it is none of low, medium, high.
BuildQuality embree_quality(const BackendOptions& o) {
  const std::string v = o.get("embree.quality", "medium");
  for (BuildQuality q : {BuildQuality::low, BuildQuality::medium, BuildQuality::high})
    if (v == to_string(q)) return q;
  throw Error("backend setting embree.quality='" + v + "': expected low, medium or high (Embree's own build quality)");
}

class EmbreeBackend final : public Backend {
public:
  explicit EmbreeBackend(const BackendOptions& o)
      : threads_(resolve_threads(o.threads)), quality_(embree_quality(o)),
        packet_(static_cast<unsigned>(o.get_size("embree.packet", 8))), coherent_(o.get_flag("embree.coherent")) {
    if (packet_ != 4 && packet_ != 8 && packet_ != 16)
      throw Error("backend setting embree.packet=" + o.get("embree.packet") + ": Embree's packets hold 4, 8 or 16 rays");
    const std::string config = "threads=" + std::to_string(threads_);
    device_ = rtcNewDevice(config.c_str());
    if (!device_)
      throw Error("embree: rtcNewDevice(\"" + config + "\") failed: " + error_name(rtcGetDeviceError(nullptr)));
    rtcSetDeviceErrorFunction(device_, &on_error, this);
  }
  ~EmbreeBackend() override {
    for (RTCScene sc : scene_)
      if (sc) rtcReleaseScene(sc);
    if (device_) rtcReleaseDevice(device_);
  }
  EmbreeBackend(const EmbreeBackend&) = delete;
  EmbreeBackend& operator=(const EmbreeBackend&) = delete;

  std::string name() const override { return "embree"; }
  std::string describe() const override {
    return std::string("embree: Embree ") + RTC_VERSION_STRING +
           " robust mode (RTC_SCENE_FLAG_ROBUST; --precision fast: its default mode), its own BVH (build quality " +
           to_string(quality_) + "), rtcIntersect1/rtcOccluded1 (packet: rtcIntersect" + std::to_string(packet_) + "/rtcOccluded" +
           std::to_string(packet_) + "), " + std::to_string(threads_) + " thread(s)";
  }
  /// robust: Embree's robust mode (RTC_SCENE_FLAG_ROBUST); fast: Embree's default mode (the flag
  /// off: faster box and triangle tests that may miss an edge), the peer of mbvh's fast mode.
  /// exact is mbvh's own contract: refused.
  bool supports_precision(Precision p) const override { return p != Precision::exact; }
  /// Its single-ray queries as mbvh4/stack; its packet queries (rtcIntersect4/8/16,
  /// rtcOccluded4/8/16 on consecutive rays, `embree.packet`) as mbvh4/packet: Embree's own BVH
  /// and traversals either way.
  bool supports(Layout l, Traversal t) const override {
    return l == Layout::mbvh4 && (t == Traversal::stack || t == Traversal::packet);
  }
  bool peer() const override { return true; }
  /// Embree's stack is internal: not reported.
  std::size_t state_bytes(const TraceOptions&) const override { return 0; }

  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    const int mode = opt.precision == Precision::fast ? 1 : 0;
    if (committed_.stale(acc)) {  // both modes' scenes are stale
      for (RTCScene& sc : scene_) {
        if (sc) rtcReleaseScene(sc);
        sc = nullptr;
      }
      committed_ = {};
    }
    if (scene_[mode]) return;
    // a high-quality build repeats a split triangle in several leaves: Embree gets each prim once
    // (the same triangles as from any other build), in the build's leaf order
    const auto& all = acc.tris();
    std::vector<Tri> unique;
    const bool repeats = all.size() + acc.bvh2().degenerate > acc.scene_triangles();
    if (repeats) {
      std::vector<std::uint8_t> seen(acc.scene_triangles(), 0);
      for (const Tri& t : all)
        if (!seen[tri_prim(t)]) {
          seen[tri_prim(t)] = 1;
          unique.push_back(t);
        }
    }
    const std::span<const Tri> tris = repeats ? std::span<const Tri>(unique) : std::span<const Tri>(all.data(), all.size());
    prims_.resize(tris.size());
    RTCScene scene = rtcNewScene(device_);
    rtcSetSceneFlags(scene, mode == 0 ? RTC_SCENE_FLAG_ROBUST : RTC_SCENE_FLAG_NONE);
    const RTCBuildQuality q = quality_ == BuildQuality::low    ? RTC_BUILD_QUALITY_LOW
                              : quality_ == BuildQuality::high ? RTC_BUILD_QUALITY_HIGH
                                                               : RTC_BUILD_QUALITY_MEDIUM;
    rtcSetSceneBuildQuality(scene, q);  // HIGH: Embree's spatial-split (SBVH) builder
    RTCGeometry g = rtcNewGeometry(device_, RTC_GEOMETRY_TYPE_TRIANGLE);
    rtcSetGeometryBuildQuality(g, q);
    auto* v = static_cast<float*>(
        rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 3 * tris.size()));
    auto* idx = static_cast<unsigned*>(
        rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), tris.size()));
    if (!v || !idx) {
      rtcReleaseGeometry(g);
      rtcReleaseScene(scene);
      raise("rtcSetNewGeometryBuffer");
    }
    for (std::size_t i = 0; i < tris.size(); ++i) {
      const float* rows[3] = {tris[i].v0, tris[i].v1, tris[i].v2};
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a)
          if (!(std::fabs(rows[k][a]) < kEmbreeLarge)) {  // Embree would leave the triangle out
            rtcReleaseGeometry(g);
            rtcReleaseScene(scene);
            throw Error("embree: triangle " + std::to_string(tri_prim(tris[i])) + " has a coordinate " +
                        std::to_string(rows[k][a]) + " beyond the +-1.844e18 Embree builds (trace it on another backend)");
          }
      for (int k = 0; k < 3; ++k)
        for (int a = 0; a < 3; ++a) v[9 * i + 3 * k + a] = rows[k][a];
      for (int k = 0; k < 3; ++k) idx[3 * i + k] = static_cast<unsigned>(3 * i + k);
      prims_[i] = tri_prim(tris[i]);
    }
    rtcCommitGeometry(g);
    rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    rtcCommitScene(scene);
    scene_[mode] = scene;
    raise("rtcCommitScene");
    committed_.mark(acc);
  }

  void trace_batch(const Accel&, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    RTCScene scene = scene_[opt.precision == Precision::fast ? 1 : 0];
    const bool any = opt.query == Query::any;
    out.reset(rays.size(), opt);  // Embree writes hits only: every other ray stays a miss
    std::vector<std::size_t> invalid(threads_, 0);         // per worker
    std::vector<std::size_t> too_large(threads_, SIZE_MAX);  // per worker: the first ray Embree refuses
    if (opt.traversal == Traversal::packet) {
      parallel_for(rays.size(), kTraceChunk, threads_, [&](std::size_t b, std::size_t e, unsigned worker) {
        if (packet_ == 4) trace_packets<RTCRayHit4, RTCRay4, 4>(scene, rays, b, e, any, out, invalid[worker], too_large[worker]);
        else if (packet_ == 16) trace_packets<RTCRayHit16, RTCRay16, 16>(scene, rays, b, e, any, out, invalid[worker], too_large[worker]);
        else trace_packets<RTCRayHit8, RTCRay8, 8>(scene, rays, b, e, any, out, invalid[worker], too_large[worker]);
      });
    } else parallel_for(rays.size(), kTraceChunk, threads_, [&](std::size_t b, std::size_t e, unsigned worker) {
      RTCIntersectContext ctx;
      rtcInitIntersectContext(&ctx);
      for (std::size_t i = b; i < e; ++i) {
        const Ray& r = rays[i];
        RayPre p;
        if (!prepare_ray(r, p)) {  // the numerical contract's invalid rays: defined misses
          ++invalid[worker];
          continue;
        }
        if (!within_embree(r)) {
          too_large[worker] = std::min(too_large[worker], i);  // reported below, never traced
          continue;
        }
        RTCRayHit rh{};
        rh.ray.org_x = r.ox;
        rh.ray.org_y = r.oy;
        rh.ray.org_z = r.oz;
        rh.ray.tnear = p.tmin;
        rh.ray.dir_x = r.dx;
        rh.ray.dir_y = r.dy;
        rh.ray.dir_z = r.dz;
        rh.ray.tfar = r.tmax;
        rh.ray.mask = 0xFFFFFFFFu;
        rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
        rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
        if (any) {
          rtcOccluded1(scene, &ctx, &rh.ray);
          out.occluded[i] = rh.ray.tfar == -INFINITY ? 1 : 0;
        } else {
          rtcIntersect1(scene, &ctx, &rh);
          if (rh.hit.geomID != RTC_INVALID_GEOMETRY_ID)
            out.hits[i] = Hit{rh.ray.tfar, rh.hit.u, rh.hit.v, prims_[rh.hit.primID]};
        }
      }
    });
    for (std::size_t n : invalid) out.invalid += n;
    raise(opt.traversal == Traversal::packet ? (any ? "rtcOccluded4/8/16" : "rtcIntersect4/8/16") : (any ? "rtcOccluded1" : "rtcIntersect1"));
    if (const std::size_t first = *std::min_element(too_large.begin(), too_large.end()); first != SIZE_MAX)
      throw Error("embree: ray " + std::to_string(first) + " has " + beyond_embree(rays[first]) +
                  ", beyond the +-1.844e18 Embree accepts for ray origins and directions (trace it on another backend)");
  }

private:
  static void query(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRayHit4& rh) { rtcIntersect4(valid, sc, c, &rh); }
  static void query(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRayHit8& rh) { rtcIntersect8(valid, sc, c, &rh); }
  static void query(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRayHit16& rh) { rtcIntersect16(valid, sc, c, &rh); }
  static void occluded(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRay4& r) { rtcOccluded4(valid, sc, c, &r); }
  static void occluded(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRay8& r) { rtcOccluded8(valid, sc, c, &r); }
  static void occluded(RTCScene sc, RTCIntersectContext* c, const int* valid, RTCRay16& r) { rtcOccluded16(valid, sc, c, &r); }

  /// rays[b, e) as Embree packets of W consecutive rays (the invalid ones and those Embree
  /// refuses as inactive lanes); with Embree's coherent flag where `embree.coherent` asks for it.
  template <class RH, class R, int W>
  void trace_packets(RTCScene scene, std::span<const Ray> rays, std::size_t b, std::size_t e, bool any, TraceOutput& out,
                     std::size_t& invalid, std::size_t& too_large) {
    RTCIntersectContext plain, coherent;
    rtcInitIntersectContext(&plain);
    rtcInitIntersectContext(&coherent);
    coherent.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;
    for (std::size_t i = b; i < e; i += W) {
      bool tiny = false;  // a direction component below FLT_MIN (zero or subnormal) in an active lane
      alignas(64) int valid[W];
      alignas(64) RH rh{};
      for (int l = 0; l < W; ++l) {
        const std::size_t k = i + static_cast<std::size_t>(l);
        valid[l] = 0;  // an inactive lane: a finite ray of no length
        rh.ray.dir_x[l] = rh.ray.dir_y[l] = rh.ray.dir_z[l] = 1.0f;
        rh.ray.tfar[l] = -INFINITY;
        rh.hit.geomID[l] = RTC_INVALID_GEOMETRY_ID;
        if (k >= e) continue;
        const Ray& r = rays[k];
        RayPre p;
        if (!prepare_ray(r, p)) {
          ++invalid;
          continue;
        }
        if (!within_embree(r)) {
          too_large = std::min(too_large, k);
          continue;
        }
        valid[l] = -1;
        tiny = tiny || !(std::fabs(r.dx) >= FLT_MIN && std::fabs(r.dy) >= FLT_MIN && std::fabs(r.dz) >= FLT_MIN);
        rh.ray.org_x[l] = r.ox;
        rh.ray.org_y[l] = r.oy;
        rh.ray.org_z[l] = r.oz;
        rh.ray.tnear[l] = p.tmin;
        rh.ray.dir_x[l] = r.dx;
        rh.ray.dir_y[l] = r.dy;
        rh.ray.dir_z[l] = r.dz;
        rh.ray.tfar[l] = r.tmax;
        rh.ray.mask[l] = 0xFFFFFFFFu;
        rh.hit.instID[0][l] = RTC_INVALID_GEOMETRY_ID;
      }
      // Embree's coherent traversal stops on an assertion (`child != BVH::emptyNode`, Debian's
      // 3.13.5) for a packet with a subnormal direction component: such packets go without it
      RTCIntersectContext* ctx = coherent_ && !tiny ? &coherent : &plain;
      if (any) {
        occluded(scene, ctx, valid, rh.ray);
        for (int l = 0; l < W && i + static_cast<std::size_t>(l) < e; ++l)
          out.occluded[i + static_cast<std::size_t>(l)] = valid[l] && rh.ray.tfar[l] == -INFINITY ? 1 : 0;
      } else {
        query(scene, ctx, valid, rh);
        for (int l = 0; l < W && i + static_cast<std::size_t>(l) < e; ++l)
          if (valid[l] && rh.hit.geomID[l] != RTC_INVALID_GEOMETRY_ID)
            out.hits[i + static_cast<std::size_t>(l)] = Hit{rh.ray.tfar[l], rh.hit.u[l], rh.hit.v[l], prims_[rh.hit.primID[l]]};
      }
    }
  }

  static std::string error_name(RTCError e) {
    switch (e) {
      case RTC_ERROR_NONE: return "RTC_ERROR_NONE";
      case RTC_ERROR_UNKNOWN: return "RTC_ERROR_UNKNOWN";
      case RTC_ERROR_INVALID_ARGUMENT: return "RTC_ERROR_INVALID_ARGUMENT";
      case RTC_ERROR_INVALID_OPERATION: return "RTC_ERROR_INVALID_OPERATION";
      case RTC_ERROR_OUT_OF_MEMORY: return "RTC_ERROR_OUT_OF_MEMORY";
      case RTC_ERROR_UNSUPPORTED_CPU: return "RTC_ERROR_UNSUPPORTED_CPU";
      case RTC_ERROR_CANCELLED: return "RTC_ERROR_CANCELLED";
      default: return "RTCError " + std::to_string(static_cast<int>(e));
    }
  }

  static void on_error(void* self, RTCError code, const char* str) {
    auto* b = static_cast<EmbreeBackend*>(self);
    const std::lock_guard<std::mutex> lock(b->error_mutex_);
    if (b->error_.empty()) b->error_ = error_name(code) + (str ? std::string(": ") + str : "");
  }

  /// Throws the first error Embree reported since the last check, naming the call.
  void raise(const char* call) {
    std::string e;
    {
      const std::lock_guard<std::mutex> lock(error_mutex_);
      e.swap(error_);
    }
    if (!e.empty()) throw Error(std::string("embree: ") + call + " failed: " + e);
  }

  unsigned threads_;
  BuildQuality quality_;
  unsigned packet_;  ///< embree.packet: rays per packet query (4, 8 or 16)
  bool coherent_;    ///< embree.coherent
  RTCDevice device_ = nullptr;
  RTCScene scene_[2] = {nullptr, nullptr};  // robust mode, default (fast) mode
  BuildStamp committed_;  // the build of the committed scenes
  std::vector<std::uint32_t> prims_;  // Embree primID -> the file's prim id
  std::mutex error_mutex_;
  std::string error_;
};

}  // namespace

void register_embree_backend() {
  BackendInfo info;
  info.name = "embree";
  info.summary = "peer: Embree 3 robust rtcIntersect1/rtcOccluded1 (and packets: rtcIntersect8/rtcOccluded8) on the same triangles and rays";
  info.make = [](const BackendOptions& o) -> std::unique_ptr<Backend> { return std::make_unique<EmbreeBackend>(o); };
  info.settings = {{"embree.quality", "Embree's own build quality: low, medium (the default) or high "
                                      "(rtcSetSceneBuildQuality; `--quality`)"},
                   {"embree.packet", "rays per packet query of --traversal packet: 4, 8 (the default) or 16 "
                                     "(rtcIntersect4/8/16, rtcOccluded4/8/16)"},
                   {"embree.coherent", "packet queries with Embree's coherent flag (RTC_INTERSECT_CONTEXT_FLAG_COHERENT): 1 or 0 (the default)"}};
  register_backend(std::move(info));
}

}  // namespace mbvh

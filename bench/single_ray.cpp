// SPDX-License-Identifier: MIT
// single_ray.cpp — `mbvh-single-ray-bench SCENE [RAYS] [REPEATS]`: the per-call cost of one ray
// from the caller's threads. mbvh's single-ray query (Backend::ray_query on `cpu`: RayQuery::
// intersect / occluded) beside Embree 3's rtcIntersect1 / rtcOccluded1 (robust mode,
// RTC_SCENE_FLAG_ROBUST, build quality medium, as the embree peer backend builds it) on the same
// triangles and rays, and, for reference, the lock-taking batch-of-one call (mbvh::intersect1 /
// occluded1 through Backend::trace) and the batch trace on one worker. Primary and diffuse rays as
// closest hit, shadow rays as any hit. 1 and 2 caller threads: each thread makes every call of the
// set (starting at a different ray), so "2 threads / 1" is the throughput ratio
// 2 * time(1 thread) / time(2 threads). Every timing is the median of REPEATS passes, mbvh and
// Embree interleaved within each pass. Before timing, the query's answers are checked against the
// batch trace (bit for bit) and Embree's against mbvh's (agreement up to ties; counted).
// Prints a Markdown table (ns per call) on stdout. CAMERA: eye x,y,z,target x,y,z (default: framing
// the scene), as bench/scenes.sh gives the interior views.
#include <embree3/rtcore.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <thread>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/backends.h"
#include "mbvh/mbvh.h"

using namespace mbvh;
using Clock = std::chrono::steady_clock;

namespace {

/// Embree's scene of the build's triangles (leaf order); prims[i]: the prim id of its triangle i.
RTCScene embree_scene(RTCDevice dev, const Accel& acc, std::vector<std::uint32_t>& prims) {
  const auto& tris = acc.tris();
  prims.resize(tris.size());
  RTCScene scene = rtcNewScene(dev);
  rtcSetSceneFlags(scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scene, RTC_BUILD_QUALITY_MEDIUM);
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_MEDIUM);
  auto* v = static_cast<float*>(
      rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 3 * tris.size()));
  auto* idx = static_cast<unsigned*>(
      rtcSetNewGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), tris.size()));
  for (std::size_t i = 0; i < tris.size(); ++i) {
    const float* rows[3] = {tris[i].v0, tris[i].v1, tris[i].v2};
    for (int k = 0; k < 3; ++k) {
      for (int a = 0; a < 3; ++a) v[9 * i + 3 * k + a] = rows[k][a];
      idx[3 * i + k] = static_cast<unsigned>(3 * i + k);
    }
    std::memcpy(&prims[i], &tris[i].v0[3], 4);  // a record's prim id (tri_prim)
  }
  rtcCommitGeometry(g);
  rtcAttachGeometry(scene, g);
  rtcReleaseGeometry(g);
  rtcCommitScene(scene);
  return scene;
}

/// One Embree call as a user makes it: the RTCRayHit filled from the ray, then rtcIntersect1 (or
/// rtcOccluded1). Returns the primitive index or -1 (closest), 1 / 0 (any).
inline long embree_one(RTCScene scene, const std::vector<std::uint32_t>& prims, const Ray& r, bool any) {
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRayHit rh;
  rh.ray.org_x = r.ox;
  rh.ray.org_y = r.oy;
  rh.ray.org_z = r.oz;
  rh.ray.tnear = r.tmin;
  rh.ray.dir_x = r.dx;
  rh.ray.dir_y = r.dy;
  rh.ray.dir_z = r.dz;
  rh.ray.time = 0;
  rh.ray.tfar = r.tmax;
  rh.ray.mask = 0xFFFFFFFFu;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  if (any) {
    rtcOccluded1(scene, &ctx, &rh.ray);
    return rh.ray.tfar == -INFINITY ? 1 : 0;
  }
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(scene, &ctx, &rh);
  return rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? -1 : long(prims[rh.hit.primID]);
}

/// Wall seconds of `threads` threads each calling f(ray) on every ray of `rays` (thread t from ray
/// t * n / threads on), started together.
template <class F>
double timed(const std::vector<Ray>& rays, unsigned threads, F f) {
  std::atomic<unsigned> ready{0};
  std::atomic<bool> go{false};
  std::atomic<long> sink{0};
  std::vector<std::thread> pool;
  for (unsigned t = 0; t < threads; ++t)
    pool.emplace_back([&, t] {
      const std::size_t n = rays.size(), first = t * n / threads;
      ++ready;
      while (!go.load(std::memory_order_acquire)) {
      }
      long s = 0;
      for (std::size_t k = 0; k < n; ++k) {
        std::size_t i = first + k;
        if (i >= n) i -= n;
        s += f(rays[i]);
      }
      sink += s;
    });
  while (ready.load() < threads) std::this_thread::yield();
  const auto t0 = Clock::now();
  go.store(true, std::memory_order_release);
  for (std::thread& th : pool) th.join();
  const double s = std::chrono::duration<double>(Clock::now() - t0).count();
  if (sink.load() == 42424242) std::printf(" ");  // keeps the calls
  return s;
}

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

}  // namespace

int main(int argc, char** argv) try {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s SCENE [RAYS=200000] [REPEATS=7] [CAMERA=ex,ey,ez,tx,ty,tz]\n", argv[0]);
    return 2;
  }
  const std::string spec = argv[1];
  const std::size_t count = argc > 2 ? std::strtoul(argv[2], nullptr, 10) : 200000;
  const int repeats = argc > 3 ? std::max(1, std::atoi(argv[3])) : 7;
  Camera camera;
  const bool has_camera = argc > 4;
  if (has_camera &&
      std::sscanf(argv[4], "%f,%f,%f,%f,%f,%f", &camera.eye.x, &camera.eye.y, &camera.eye.z, &camera.target.x,
                  &camera.target.y, &camera.target.z) != 6) {
    std::fprintf(stderr, "error: CAMERA '%s' is not ex,ey,ez,tx,ty,tz\n", argv[4]);
    return 2;
  }
  register_builtin_backends();
  const Scene scene = load_scene(spec);
  const auto acc = Accel::build(scene);
  BackendOptions one;
  one.threads = 1;  // the batch column: one worker
  auto cpu = make_backend("cpu", one);
  const RayQuery q = cpu->ray_query(*acc);
  RTCDevice dev = rtcNewDevice("threads=2");
  std::vector<std::uint32_t> prims;
  RTCScene escene = embree_scene(dev, *acc, prims);
  std::printf("scene %s%s%s: %zu triangles; mbvh %s, query %s/%s (closest) %s/%s (any), leaf block %u; Embree %s robust; %zu rays a kind, median of %d\n\n",
              spec.c_str(), has_camera ? ", camera " : "", has_camera ? argv[4] : "", acc->tris().size(), q.backend().c_str(), to_string(q.options(Query::closest).layout),
              to_string(q.options(Query::closest).traversal), to_string(q.options(Query::any).layout),
              to_string(q.options(Query::any).traversal), q.options(Query::closest).leaf_block, RTC_VERSION_STRING, count,
              repeats);
  std::printf("| rays | query | mbvh 1 thr ns | embree 1 thr ns | mbvh/embree time 1 thr | mbvh 2 thr ns | embree 2 thr ns | mbvh/embree time 2 thr | mbvh 2 thr / 1 | embree 2 thr / 1 | intersect1 (lock) 1 thr ns | batch 1 thr ns | checks |\n");
  std::printf("| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |\n");
  for (RayKind kind : {RayKind::primary, RayKind::diffuse, RayKind::shadow}) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = count;
    ro.seed = 3;
    ro.has_camera = has_camera;
    ro.camera = camera;
    const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
    const bool any = kind == RayKind::shadow;
    const std::size_t n = rays.size();
    // -- checks: the query against the batch (bit for bit), Embree against mbvh (up to ties)
    TraceOutput batch;
    cpu->trace(*acc, rays, q.options(any ? Query::any : Query::closest), batch);
    std::size_t differ = 0, embree_differ = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (any) {
        const bool o = q.occluded(rays[i]);
        differ += o != (batch.occluded[i] != 0);
        embree_differ += embree_one(escene, prims, rays[i], true) != (o ? 1 : 0);
      } else {
        const Hit h = q.intersect(rays[i]);
        differ += std::memcmp(&h, &batch.hits[i], sizeof(Hit)) != 0;
        embree_differ += embree_one(escene, prims, rays[i], false) != (h.prim == MBVH_MISS_PRIM ? -1 : long(h.prim));
      }
    }
    if (differ != 0) {
      std::fprintf(stderr, "error: %zu rays of the query differ from the batch trace\n", differ);
      return 1;
    }
    const auto mine = [&](const Ray& r) -> long { return any ? long(q.occluded(r)) : long(q.intersect(r).prim); };
    const auto theirs = [&](const Ray& r) -> long { return embree_one(escene, prims, r, any); };
    std::vector<double> m1, e1, m2, e2, lock1, b1;
    const std::vector<Ray> few(rays.begin(), rays.begin() + std::min<std::size_t>(n, 20000));
    for (int rep = 0; rep < repeats; ++rep) {
      m1.push_back(timed(rays, 1, mine) / double(n));
      e1.push_back(timed(rays, 1, theirs) / double(n));
      m2.push_back(timed(rays, 2, mine) / double(n));
      e2.push_back(timed(rays, 2, theirs) / double(n));
      lock1.push_back(timed(few, 1, [&](const Ray& r) -> long {
                        return any ? long(occluded1(*cpu, *acc, r)) : long(intersect1(*cpu, *acc, r).prim_id);
                      }) / double(few.size()));
      TraceOutput out;
      const auto t0 = Clock::now();
      cpu->trace(*acc, rays, q.options(any ? Query::any : Query::closest), out);
      b1.push_back(std::chrono::duration<double>(Clock::now() - t0).count() / double(n));
    }
    const double M1 = median(m1) * 1e9, E1 = median(e1) * 1e9, M2 = median(m2) * 1e9, E2 = median(e2) * 1e9;
    // 2 threads: each made n calls in the wall time; ns per call of the pair = wall / (2 n)
    std::printf("| %s | %s | %.1f | %.1f | %.2f | %.1f | %.1f | %.2f | %.2f× | %.2f× | %.1f | %.1f | query = batch on %zu rays; Embree differs on %zu (ties) |\n",
                to_string(kind), any ? "any" : "closest", M1, E1, M1 / E1, M2 / 2, E2 / 2, M2 / E2, 2 * M1 / M2,
                2 * E1 / E2, median(lock1) * 1e9, median(b1) * 1e9, n, embree_differ);
    std::fflush(stdout);
  }
  rtcReleaseScene(escene);
  rtcReleaseDevice(dev);
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 2;
}

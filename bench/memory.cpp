// SPDX-License-Identifier: MIT
// memory.cpp — `mbvh-memory-bench PEER SCENE [RAYS]`: the resident memory one peer's acceleration
// structure costs on SCENE, in a process of its own (bench/memory.sh runs the peers side by side
// and takes medians). PEER:
//   mbvh        Accel::build with the default BuildOptions, then the cpu backend's batch traces
//               with TraceOptions{} (closest, then any hit): what those traces prepare (the
//               layout, the leaf variant, its packs) is made by the first one;
//   mbvh-query  the same build, then Backend::ray_query with its defaults (both queries);
//   embree      Embree 3, robust mode, build quality medium (as the embree peer backend builds
//               it), one triangle mesh on the scene's own vertex and index arrays
//               (rtcSetSharedGeometryBuffer: Embree keeps no copy), rtcIntersect1 / rtcOccluded1.
// What is measured, from /proc/self/status: the scene and RAYS random rays (origins in the
// scene's box, uniform directions) are made first; then freed heap is returned (malloc_trim) and
// the peak is reset (clear_refs), and that VmRSS is the base. build_peak: VmHWM above the base
// at the end of the build (mbvh: Accel::build and the first trace's preparation, i.e. everything
// until the traced structure exists; Embree: rtcCommitScene), build_held: VmRSS above the base
// then; trace_peak / trace_held: the same after both queries traced every ray (with the output
// arrays, 17 bytes a ray). Prints one JSON object on stdout; for mbvh also Accel::memory().
#include <embree3/rtcore.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <memory>
#include <random>
#include <string>
#include <vector>

#include "host/tools/resident.h"
#include "mbvh/backends.h"
#include "mbvh/mbvh.h"

using namespace mbvh;

namespace {

// RAYS rays from uniform points of the scene's box in uniform directions, tmax infinite.
std::vector<Ray> random_rays(const Scene& scene, std::size_t n) {
  const Box b = scene.bounds();
  std::mt19937_64 rng(7);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<Ray> rays(n);
  for (Ray& r : rays) {
    r.ox = b.lo.x + u(rng) * (b.hi.x - b.lo.x);
    r.oy = b.lo.y + u(rng) * (b.hi.y - b.lo.y);
    r.oz = b.lo.z + u(rng) * (b.hi.z - b.lo.z);
    const float z = 2 * u(rng) - 1, phi = 6.2831853f * u(rng), s = std::sqrt(std::max(0.0f, 1 - z * z));
    r.dx = s * std::cos(phi);
    r.dy = s * std::sin(phi);
    r.dz = z;
    r.tmin = 0;
    r.tmax = INFINITY;
  }
  return rays;
}

struct Sample {
  std::int64_t peak = 0, held = 0;
};

Sample sample(const MemoryProbe& m) { return {m.peak_extra(), m.rss_now() - m.base}; }

// -- mbvh: the build, then the default traces (batch or single-ray query)
std::string run_mbvh(const Scene& scene, const std::vector<Ray>& rays, bool query, MemoryProbe& m, Sample& build,
                     Sample& trace) {
  m.start();
  const std::unique_ptr<Accel> acc = Accel::build(scene);
  auto cpu = make_backend("cpu");
  std::size_t hits = 0;
  TraceOutput closest, any;
  if (query) {
    const RayQuery q = cpu->ray_query(*acc);
    build = sample(m);
    for (const Ray& r : rays) hits += (q.intersect(r).prim != MBVH_MISS_PRIM) + q.occluded(r);
  } else {
    TraceOptions to;
    cpu->prepare(*acc, to);
    to.query = Query::any;
    cpu->prepare(*acc, to);
    build = sample(m);
    cpu->trace(*acc, rays, TraceOptions{}, closest);
    cpu->trace(*acc, rays, to, any);
    for (std::size_t i = 0; i < rays.size(); ++i) hits += (closest.hits[i].prim != MBVH_MISS_PRIM) + any.occluded[i];
  }
  trace = sample(m);
  const Accel::MemoryStats ms = acc->memory();
  char buf[256];
  std::snprintf(buf, sizeof buf,
                "\"hits\": %zu, \"accel\": {\"tree\": %zu, \"nodes\": %zu, \"triangles\": %zu, \"packs\": %zu, "
                "\"total\": %zu}",
                hits, ms.tree, ms.nodes, ms.triangles, ms.packs, ms.total());
  return buf;
}

// -- Embree: robust, medium, the scene's arrays shared; the same queries ray by ray
std::string run_embree(const Scene& scene, const std::vector<Ray>& rays, MemoryProbe& m, Sample& build, Sample& trace) {
  if (!scene.meshes().empty()) throw Error("the embree peer here reads an owned scene (a file or generator)");
  m.start();
  RTCDevice dev = rtcNewDevice(nullptr);
  RTCScene es = rtcNewScene(dev);
  rtcSetSceneFlags(es, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(es, RTC_BUILD_QUALITY_MEDIUM);
  RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
  rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_MEDIUM);
  // Embree may read 16 bytes from a vertex (one float past the last): main reserves it
  if (scene.vertices.capacity() < scene.vertices.size() + 1) throw Error("the scene's vertex array lacks Embree's padding");
  rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, scene.vertices.data(), 0, sizeof(Vec3f),
                             scene.vertices.size());
  rtcSetSharedGeometryBuffer(g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, scene.triangles.data(), 0,
                             3 * sizeof(std::uint32_t), scene.triangles.size());
  rtcCommitGeometry(g);
  rtcAttachGeometry(es, g);
  rtcReleaseGeometry(g);
  rtcCommitScene(es);
  build = sample(m);
  std::vector<Hit> hits_out(rays.size());
  std::vector<std::uint8_t> occ(rays.size());
  std::size_t hits = 0;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRayHit rh{};
    rh.ray.org_x = r.ox, rh.ray.org_y = r.oy, rh.ray.org_z = r.oz, rh.ray.tnear = r.tmin;
    rh.ray.dir_x = r.dx, rh.ray.dir_y = r.dy, rh.ray.dir_z = r.dz, rh.ray.tfar = r.tmax;
    rh.ray.mask = 0xFFFFFFFFu;
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    RTCRay shadow = rh.ray;
    rtcIntersect1(es, &ctx, &rh);
    hits_out[i] = {rh.ray.tfar, rh.hit.u, rh.hit.v, rh.hit.geomID == RTC_INVALID_GEOMETRY_ID ? MBVH_MISS_PRIM : rh.hit.primID};
    rtcOccluded1(es, &ctx, &shadow);
    occ[i] = shadow.tfar == -INFINITY;
    hits += (hits_out[i].prim != MBVH_MISS_PRIM) + occ[i];
  }
  trace = sample(m);
  rtcReleaseScene(es);
  rtcReleaseDevice(dev);
  return "\"hits\": " + std::to_string(hits);
}

}  // namespace

int main(int argc, char** argv) try {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s mbvh|mbvh-query|embree SCENE [RAYS=100000]\n", argv[0]);
    return 2;
  }
  const std::string peer = argv[1], spec = argv[2];
  const std::size_t count = argc > 3 ? std::strtoul(argv[3], nullptr, 10) : 100000;
  if (peer != "mbvh" && peer != "mbvh-query" && peer != "embree") throw Error("unknown peer '" + peer + "'");
  register_builtin_backends();
  Scene scene = load_scene(spec);
  scene.vertices.reserve(scene.vertices.size() + 1);  // Embree's slack (run_embree), for both peers alike
  const std::vector<Ray> rays = random_rays(scene, count);
  MemoryProbe m;
  if (!m.on) throw Error("cannot reset the peak resident size (/proc/self/clear_refs)");
  const std::int64_t before = m.rss_now();
  Sample build, trace;
  const std::string more =
      peer == "embree" ? run_embree(scene, rays, m, build, trace) : run_mbvh(scene, rays, peer == "mbvh-query", m, build, trace);
  const std::size_t scene_bytes = scene.memory_bytes();
  std::printf("{\"peer\": \"%s\", \"scene\": \"%s\", \"triangles\": %zu, \"vertices\": %zu, \"scene_bytes\": %zu, "
              "\"rays\": %zu, \"base_rss\": %lld, \"build_peak\": %lld, \"build_held\": %lld, \"trace_peak\": %lld, "
              "\"trace_held\": %lld, %s}\n",
              peer.c_str(), spec.c_str(), scene.triangle_count(), scene.vertices.size(), scene_bytes, rays.size(),
              static_cast<long long>(before), static_cast<long long>(build.peak), static_cast<long long>(build.held),
              static_cast<long long>(trace.peak), static_cast<long long>(trace.held), more.c_str());
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 2;
}

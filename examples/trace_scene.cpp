// SPDX-License-Identifier: MIT
// trace_scene.cpp — the README's library example: a scene from the caller's arrays, one build,
// closest hits and occlusion on the fastest verified backend (`cpu`), the answer checked. It links
// mbvh::cpu (the cpu backends alone: no OpenCL, Vulkan or Embree library) or mbvh::mbvh (every
// backend of the build; mbvh::register_builtin_backends() registers them all).
#include <cmath>
#include <cstdio>
#include <vector>

#include <mbvh/backends.h>  // register_cpu_backends (mbvh::cpu), register_builtin_backends (mbvh::mbvh)
#include <mbvh/mbvh.h>      // Scene, Accel, Ray, Hit, backends; errors are mbvh::Error

int main() {
  mbvh::register_cpu_backends();  // cpu, cpu-scalar, dacrt (every backend: register_builtin_backends)
  mbvh::Scene scene;  // a unit square at z = 0, two triangles (or: mbvh::load_scene("scene.obj.zst"))
  scene.vertices = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  scene.triangles = {{0, 1, 2}, {0, 2, 3}};
  auto accel = mbvh::Accel::build(scene);  // build once; every backend and layout traces it
  auto cpu = mbvh::make_backend("cpu");    // the best SIMD ISA of this machine
  std::vector<mbvh::Ray> rays;             // origin, tmin, direction, tmax
  for (float x : {0.25f, 0.75f, 1.5f}) rays.push_back({x, 0.5f, 1, 0, 0, 0, -1, INFINITY});
  mbvh::TraceOutput hits, shadow;
  cpu->trace(*accel, rays, {}, hits);  // the defaults: this backend's fastest exact traversal
  cpu->trace(*accel, rays, {.query = mbvh::Query::any}, shadow);
  std::printf("mbvh %s, %s\n", mbvh::version(), cpu->describe().c_str());
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const mbvh::Hit& h = hits.hits[i];
    if (h.prim == MBVH_MISS_PRIM) std::printf("ray %zu: miss, occluded %d\n", i, shadow.occluded[i]);
    else std::printf("ray %zu: triangle %u at t = %g, occluded %d\n", i, h.prim, h.t, shadow.occluded[i]);
  }
  const bool ok = hits.hits[0].prim == 1 && hits.hits[1].prim == 0 && hits.hits[0].t == 1.0f &&
                  hits.hits[2].prim == MBVH_MISS_PRIM && shadow.occluded[0] && !shadow.occluded[2];
  return ok ? 0 : 1;
}

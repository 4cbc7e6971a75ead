/* SPDX-License-Identifier: MIT */
/* trace_c.c — examples/trace_scene.cpp through the C API (mbvh/mbvh_c.h, C99): a unit square
 * from the caller's arrays (read in place, not copied), one build, closest hits and occlusion on
 * `cpu`, the answers checked; and one error, reported as every failure is. Build: CMake
 * `target_link_libraries(app PRIVATE mbvh::c)`, or `cc app.c $(pkg-config --cflags --libs mbvh_c)`. */
#include <math.h>
#include <stdio.h>
#include <string.h>

#include <mbvh/mbvh_c.h>

/* Prints the failure of `call` and tells main to stop. */
static int failed(mbvh_status status, const char* call) {
  if (status == MBVH_OK) return 0;
  fprintf(stderr, "%s: %s: %s\n", call, mbvh_status_string(status), mbvh_last_error());
  return 1;
}

int main(void) {
  /* a unit square at z = 0, two triangles; vertex records of position and normal (24 bytes) */
  static const float vertices[4][6] = {{0, 0, 0, 0, 0, 1}, {1, 0, 0, 0, 0, 1}, {1, 1, 0, 0, 0, 1}, {0, 1, 0, 0, 0, 1}};
  static const uint32_t indices[2][3] = {{0, 1, 2}, {0, 2, 3}};
  mbvh_ray rays[3]; /* origin, tmin, direction, tmax: straight down onto the square */
  const float x[3] = {0.25f, 0.75f, 1.5f};
  mbvh_hit hits[3];
  uint8_t occluded[3];
  mbvh_scene* scene = NULL;
  mbvh_accel* accel = NULL;
  mbvh_backend* cpu = NULL;
  mbvh_backend* none = NULL;
  mbvh_trace_options any;
  const char* description = "";
  int ok = 0, i;

  for (i = 0; i < 3; ++i) {
    const mbvh_ray r = {x[i], 0.5f, 1, 0, 0, 0, -1, INFINITY};
    rays[i] = r;
  }
  mbvh_trace_options_init(&any);
  any.query = MBVH_QUERY_ANY;
  if (failed(mbvh_scene_create(&scene), "mbvh_scene_create") ||
      failed(mbvh_scene_add_mesh(scene, &vertices[0][0], 4, sizeof vertices[0], &indices[0][0], 2, sizeof indices[0], NULL),
             "mbvh_scene_add_mesh") ||
      failed(mbvh_accel_build(scene, NULL, &accel), "mbvh_accel_build") || /* the arrays may go after this */
      failed(mbvh_backend_create("cpu", 0, NULL, 0, &cpu), "mbvh_backend_create") || /* the best SIMD ISA here */
      failed(mbvh_backend_describe(cpu, &description), "mbvh_backend_describe") ||
      failed(mbvh_trace(cpu, accel, rays, 3, NULL, hits, NULL), "mbvh_trace") || /* closest hits: the defaults */
      failed(mbvh_trace(cpu, accel, rays, 3, &any, NULL, occluded), "mbvh_trace"))
    goto done;
  printf("mbvh %s (C API %u), %s\n", mbvh_version(), mbvh_c_api_version(), description);
  for (i = 0; i < 3; ++i) {
    if (hits[i].prim == MBVH_MISS) printf("ray %d: miss, occluded %d\n", i, occluded[i]);
    else printf("ray %d: triangle %u at t = %g, occluded %d\n", i, (unsigned)hits[i].prim, (double)hits[i].t, occluded[i]);
  }
  ok = hits[0].prim == 1 && hits[1].prim == 0 && hits[0].t == 1.0f && hits[2].prim == MBVH_MISS && occluded[0] == 1 &&
       occluded[2] == 0;
  /* a failure: a status and the message, which names what was wrong; nothing is thrown */
  if (mbvh_backend_create("no-such-backend", 0, NULL, 0, &none) != MBVH_ERROR || none != NULL ||
      strstr(mbvh_last_error(), "unknown backend 'no-such-backend'") == NULL)
    ok = 0;
  printf("a failed call reports: %s\n", mbvh_last_error());
done:
  mbvh_backend_release(cpu); /* NULL is fine */
  mbvh_accel_release(accel);
  mbvh_scene_release(scene);
  if (!ok) fprintf(stderr, "trace_c: wrong answers\n");
  return ok ? 0 : 1;
}

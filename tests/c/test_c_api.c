/* SPDX-License-Identifier: MIT */
/* test_c_api.c — the C API (mbvh/mbvh_c.h) from C99: scenes from the caller's interleaved
 * arrays, a shared scene file and a generator; builds, the BVH cache and refit; every backend of
 * the library that starts here, bit for bit against cpu-scalar (the peer and the dacrt backends
 * up to classified ties); the bytes of `mbvh trace` (MBVH_CLI_PATH); and every error path.
 *
 *   test_c_api            everything
 *   test_c_api backends   the backends only (ctest reruns it with AVX-512 turned off)
 *
 * Environment: MBVH_TEST_BACKENDS (comma-separated names) narrows the backends, as for the C++
 * tests; MBVH_C_TEST_EXPECT_SKIP=NAME fails the test unless backend NAME is skipped as missing
 * hardware. Exit status 0 when every check passed. */
#define _POSIX_C_SOURCE 200809L /* mkdtemp, rmdir, unlink */
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include <mbvh/mbvh_c.h>

#ifndef MBVH_SCENES_DIR
#error "MBVH_SCENES_DIR: the shared scenes (CMakeLists.txt)"
#endif
#ifndef MBVH_CLI_PATH
#error "MBVH_CLI_PATH: the mbvh program (CMakeLists.txt)"
#endif

/* -- checks */

static int g_checks = 0, g_failures = 0;

static int check(int ok, const char* what, const char* file, int line) {
  ++g_checks;
  if (!ok) {
    ++g_failures;
    fprintf(stderr, "%s:%d: FAILED: %s\n  last error: %s\n", file, line, what, mbvh_last_error());
  }
  return ok;
}

static int check_status(mbvh_status got, mbvh_status want, const char* call, const char* file, int line) {
  ++g_checks;
  if (got != want) {
    ++g_failures;
    fprintf(stderr, "%s:%d: FAILED: %s returned %s, expected %s\n  last error: %s\n", file, line, call,
            mbvh_status_string(got), mbvh_status_string(want), mbvh_last_error());
    return 0;
  }
  return 1;
}

/* the last error holds `part` (strstr) */
static int check_message(const char* part, const char* file, int line) {
  ++g_checks;
  if (strstr(mbvh_last_error(), part) == NULL) {
    ++g_failures;
    fprintf(stderr, "%s:%d: FAILED: the last error does not name '%s'\n  last error: %s\n", file, line, part,
            mbvh_last_error());
    return 0;
  }
  return 1;
}

static int check_fails(mbvh_status got, mbvh_status want, const char* part, const char* call, const char* file, int line) {
  return check_status(got, want, call, file, line) && check_message(part, file, line);
}

#define CHECK(cond) check((cond), #cond, __FILE__, __LINE__)
#define CHECK_OK(call) check_status((call), MBVH_OK, #call, __FILE__, __LINE__)
#define CHECK_STATUS(call, want) check_status((call), (want), #call, __FILE__, __LINE__)
#define CHECK_MESSAGE(part) check_message((part), __FILE__, __LINE__)
/* a failing call: its status, and a message that names `part` */
#define CHECK_FAILS(call, want, part) check_fails((call), (want), (part), #call, __FILE__, __LINE__)

/* -- helpers */

static char g_dir[] = "/tmp/mbvh-c-api-XXXXXX"; /* this run's files */

/* g_dir/name into buf */
static const char* temp_path(char* buf, size_t size, const char* name) {
  snprintf(buf, size, "%s/%s", g_dir, name);
  return buf;
}

static int write_file(const char* path, const void* data, size_t bytes) {
  FILE* f = fopen(path, "wb");
  int ok = f != NULL && fwrite(data, 1, bytes, f) == bytes;
  if (f && fclose(f) != 0) ok = 0;
  return ok;
}

/* Reads exactly `bytes` bytes (the file must hold no more). */
static int read_file(const char* path, void* data, size_t bytes) {
  FILE* f = fopen(path, "rb");
  int ok = f != NULL && fread(data, 1, bytes, f) == bytes && fgetc(f) == EOF;
  if (f) fclose(f);
  return ok;
}

/* A deterministic generator: xorshift32, floats in [0, 1). */
static uint32_t g_rng = 0x9E3779B9u;
static float uniform(void) {
  g_rng ^= g_rng << 13;
  g_rng ^= g_rng >> 17;
  g_rng ^= g_rng << 5;
  return (float)(g_rng >> 8) * (1.0f / 16777216.0f);
}

/* `count` rays from a sphere around the box (twice its half diagonal) toward random points of the
 * box's middle half; every other ray ends at its point (tmax = 1: the direction is not
 * normalised), the others have no far limit. */
static void make_rays(const float lower[3], const float upper[3], mbvh_ray* rays, size_t count) {
  float center[3], half[3], radius = 0;
  size_t i;
  int a;
  for (a = 0; a < 3; ++a) {
    center[a] = 0.5f * (lower[a] + upper[a]);
    half[a] = 0.5f * (upper[a] - lower[a]);
    radius += half[a] * half[a];
  }
  radius = 2.0f * sqrtf(radius);
  for (i = 0; i < count; ++i) {
    float d[3], len2, scale, origin[3], target[3];
    do {  /* a direction uniform on the sphere: rejection in the cube */
      for (a = 0; a < 3; ++a) d[a] = 2.0f * uniform() - 1.0f;
      len2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2];
    } while (len2 > 1.0f || len2 < 1e-4f);
    scale = radius / sqrtf(len2);
    for (a = 0; a < 3; ++a) {
      origin[a] = center[a] + d[a] * scale;
      target[a] = center[a] + (uniform() - 0.5f) * half[a];
    }
    rays[i].ox = origin[0], rays[i].oy = origin[1], rays[i].oz = origin[2], rays[i].tmin = 0;
    rays[i].dx = target[0] - origin[0], rays[i].dy = target[1] - origin[1], rays[i].dz = target[2] - origin[2];
    rays[i].tmax = i % 2 ? 1.0f : INFINITY;
  }
}

static mbvh_trace_options trace_options(mbvh_query query, unsigned leaf_block) {
  mbvh_trace_options o;
  mbvh_trace_options_init(&o);
  o.query = query;
  o.leaf_block = leaf_block;
  return o;
}

/* Closest hits and occlusion of `rays` on `b` with `o` (its query replaced). */
static int trace_both(mbvh_backend* b, const mbvh_accel* accel, const mbvh_ray* rays, size_t count,
                      mbvh_trace_options o, mbvh_hit* hits, uint8_t* occluded) {
  o.query = MBVH_QUERY_CLOSEST;
  if (!CHECK_OK(mbvh_trace(b, accel, rays, count, &o, hits, NULL))) return 0;
  o.query = MBVH_QUERY_ANY;
  return CHECK_OK(mbvh_trace(b, accel, rays, count, &o, NULL, occluded));
}

/* -- classified ties (mbvh/compare.h's rules): two correct traversals in another order may
 * answer a ray differently only there */

static uint32_t ulp_distance(float a, float b) {
  int32_t ia, ib;
  memcpy(&ia, &a, sizeof ia);
  memcpy(&ib, &b, sizeof ib);
  if (ia < 0) ia = INT32_MIN - ia;
  if (ib < 0) ib = INT32_MIN - ib;
  return ia > ib ? (uint32_t)ia - (uint32_t)ib : (uint32_t)ib - (uint32_t)ia;
}
static int on_edge(const mbvh_hit* h) {
  const float w = 1.0f - h->u - h->v;
  return h->u <= 1e-5f || h->v <= 1e-5f || w <= 1e-5f;
}
/* 0: equal, 1: a tie, 2: a mismatch */
static int compare_hit(const mbvh_hit* a, const mbvh_hit* b) {
  const mbvh_hit* nearer = a->t <= b->t ? a : b;
  if (a->prim == b->prim) return 0;
  if (a->prim != MBVH_MISS && b->prim != MBVH_MISS && ulp_distance(a->t, b->t) <= 4) return 1;
  return nearer->prim != MBVH_MISS && on_edge(nearer) ? 1 : 2;
}
static int compare_occlusion(uint8_t a, uint8_t b, const mbvh_hit* closest, const mbvh_ray* ray) {
  if (a == b) return 0;
  if (closest->prim != MBVH_MISS &&
      (on_edge(closest) || ulp_distance(closest->t, ray->tmin) <= 4 || ulp_distance(closest->t, ray->tmax) <= 4))
    return 1;
  return 2;
}

/* -- the library */

static void test_library(void) {
  CHECK(strcmp(mbvh_last_error(), "") == 0); /* nothing failed yet on this thread */
  CHECK(strcmp(mbvh_version(), MBVH_VERSION_STRING) == 0);
  CHECK(mbvh_c_api_version() == MBVH_C_API_VERSION);
  CHECK(strcmp(mbvh_status_string(MBVH_OK), "MBVH_OK") == 0);
  CHECK(strcmp(mbvh_status_string(MBVH_ERROR_MISSING_HARDWARE), "MBVH_ERROR_MISSING_HARDWARE") == 0);
  CHECK(strcmp(mbvh_status_string((mbvh_status)99), "unknown status") == 0);
  CHECK(sizeof(mbvh_ray) == 32 && sizeof(mbvh_hit) == 16);
}

/* -- a scene of the caller's meshes: interleaved vertices, padded index records */

/* position, normal, uv: 32 bytes a vertex */
typedef struct vertex {
  float x, y, z, nx, ny, nz, s, t;
} vertex;

static void test_scene_from_arrays(void) {
  /* mesh 0: the unit square at z = 0; mesh 1: one triangle at z = 2 over the square's x > 1 half */
  vertex square[4] = {{0, 0, 0, 0, 0, 1, 0, 0}, {1, 0, 0, 0, 0, 1, 1, 0}, {1, 1, 0, 0, 0, 1, 1, 1}, {0, 1, 0, 0, 0, 1, 0, 1}};
  const uint32_t square_idx[2][4] = {{0, 1, 2, 7}, {0, 2, 3, 7}}; /* 16-byte records: a padding word */
  vertex roof[3] = {{1, 0, 2, 0, 0, 1, 0, 0}, {3, 0, 2, 0, 0, 1, 0, 0}, {1, 3, 2, 0, 0, 1, 0, 0}};
  const uint32_t roof_idx[3] = {0, 1, 2};
  mbvh_ray rays[3];
  const float xs[3] = {0.25f, 0.75f, 1.5f};
  mbvh_hit hits[3];
  uint8_t occluded[3];
  mbvh_scene* scene = NULL;
  mbvh_accel* accel = NULL;
  mbvh_backend* ref = NULL;
  uint32_t geom = 99, prim = 99;
  size_t n = 0;
  float lo[3], hi[3];
  int i;

  for (i = 0; i < 3; ++i) {
    const mbvh_ray r = {xs[i], 0.5f, 5, 0, 0, 0, -1, INFINITY};
    rays[i] = r;
  }
  if (!CHECK_OK(mbvh_scene_create(&scene)) || !CHECK_OK(mbvh_backend_create("cpu-scalar", 1, NULL, 0, &ref))) goto done;
  CHECK_OK(mbvh_scene_add_mesh(scene, &square[0].x, 4, sizeof(vertex), &square_idx[0][0], 2, sizeof square_idx[0], &geom));
  CHECK(geom == 0);
  CHECK_OK(mbvh_scene_add_mesh(scene, &roof[0].x, 3, sizeof(vertex), roof_idx, 1, 12, &geom));
  CHECK(geom == 1);
  CHECK_OK(mbvh_scene_triangle_count(scene, &n));
  CHECK(n == 3);
  CHECK_OK(mbvh_scene_geometry_count(scene, &n));
  CHECK(n == 2);
  CHECK_OK(mbvh_scene_bounds(scene, lo, hi));
  CHECK(lo[0] == 0 && lo[1] == 0 && lo[2] == 0 && hi[0] == 3 && hi[1] == 3 && hi[2] == 2);
  if (!CHECK_OK(mbvh_accel_build(scene, NULL, &accel))) goto done;
  CHECK_OK(mbvh_accel_triangle_count(accel, &n));
  CHECK(n == 3);
  CHECK_OK(mbvh_accel_bounds(accel, lo, hi));
  CHECK(lo[0] == 0 && hi[0] == 3 && hi[2] == 2);
  if (!trace_both(ref, accel, rays, 3, trace_options(MBVH_QUERY_CLOSEST, 0), hits, occluded)) goto done;
  /* the square's triangle 1 (x < y side) and 0; the roof (prim 2 = mesh 1's triangle 0) at t = 3 */
  CHECK(hits[0].prim == 1 && hits[0].t == 5.0f && hits[1].prim == 0 && hits[2].prim == 2 && hits[2].t == 3.0f);
  CHECK(occluded[0] == 1 && occluded[1] == 1 && occluded[2] == 1);
  CHECK_OK(mbvh_accel_geometry_of(accel, hits[2].prim, &geom, &prim));
  CHECK(geom == 1 && prim == 0);
  CHECK_OK(mbvh_accel_geometry_of(accel, hits[0].prim, &geom, &prim));
  CHECK(geom == 0 && prim == 1);
  CHECK_OK(mbvh_accel_geometry_of(accel, MBVH_MISS, &geom, &prim));
  CHECK(geom == MBVH_INVALID_GEOMETRY && prim == MBVH_MISS);

  /* refit: the square moved up in the caller's buffer, the same scene */
  for (i = 0; i < 4; ++i) square[i].z = 1.0f;
  if (!CHECK_OK(mbvh_accel_refit(accel, scene))) goto done;
  CHECK_OK(mbvh_trace(ref, accel, rays, 3, NULL, hits, NULL));
  CHECK(hits[0].prim == 1 && hits[0].t == 4.0f && hits[2].t == 3.0f);
  /* a refit that fails (a NaN vertex) leaves the accel as it was */
  square[2].z = NAN;
  CHECK_FAILS(mbvh_accel_refit(accel, scene), MBVH_ERROR, "vertices must be finite");
  /* the accel holds its own triangles: the caller's buffers may change after the build */
  for (i = 0; i < 4; ++i) square[i].x = NAN;
  memset(hits, 0, sizeof hits);
  CHECK_OK(mbvh_trace(ref, accel, rays, 3, NULL, hits, NULL));
  CHECK(hits[0].prim == 1 && hits[0].t == 4.0f && hits[1].prim == 0 && hits[2].t == 3.0f);
  /* the scene's bounds read the buffers again: the NaN is found */
  CHECK_FAILS(mbvh_scene_bounds(scene, lo, hi), MBVH_ERROR, "vertices must be finite");
done:
  mbvh_backend_release(ref);
  mbvh_accel_release(accel);
  mbvh_scene_release(scene);
}

/* -- loaded scenes, generators, the cache */

static void count_progress(double fraction, void* user) {
  if (fraction >= 0.0 && fraction <= 1.0) ++*(int*)user;
}

static void test_loaded_scenes(void) {
  mbvh_scene* file = NULL;
  mbvh_scene* gen = NULL;
  mbvh_accel* fresh = NULL;
  mbvh_accel* built = NULL;
  mbvh_accel* read = NULL;
  mbvh_backend* ref = NULL;
  mbvh_build_options bo;
  const char* path = NULL;
  const char* problem = NULL;
  char cache_dir[256] = "", entry[512] = "";
  int loaded = -1, progress = 0;
  size_t n = 0;
  float lo[3], hi[3];
  mbvh_ray rays[512];
  mbvh_hit a[512], b[512];
  const float v[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
  const uint32_t t[3] = {0, 1, 2};

  if (!CHECK_OK(mbvh_scene_load(MBVH_SCENES_DIR "/cornell_box.obj.zst", &file)) ||
      !CHECK_OK(mbvh_scene_load("gen:sphere:16", &gen)) || !CHECK_OK(mbvh_backend_create("cpu-scalar", 0, NULL, 0, &ref)))
    goto done;
  CHECK_OK(mbvh_scene_triangle_count(file, &n));
  CHECK(n > 10);
  CHECK_OK(mbvh_scene_geometry_count(file, &n));
  CHECK(n == 1);
  CHECK_OK(mbvh_scene_triangle_count(gen, &n));
  CHECK(n > 100);
  CHECK_OK(mbvh_scene_bounds(gen, lo, hi));
  CHECK(lo[0] < hi[0] && lo[1] < hi[1] && lo[2] < hi[2]);
  /* a loaded scene owns its triangles: it takes no view */
  CHECK_FAILS(mbvh_scene_add_mesh(file, v, 3, 12, t, 1, 12, NULL), MBVH_ERROR, "owned triangles");
  CHECK_OK(mbvh_scene_triangle_count(file, &n));

  /* the cache: built and written, then read back; the same answers as a build without it */
  mbvh_build_options_init(&bo);
  bo.progress = count_progress;
  bo.progress_user = &progress;
  if (!CHECK_OK(mbvh_accel_build(file, &bo, &fresh))) goto done;
  CHECK(progress > 0);
  CHECK_OK(mbvh_accel_cache_report(fresh, &loaded, &path, &problem));
  CHECK(loaded == 0 && strcmp(path, "") == 0 && strcmp(problem, "") == 0);
  bo.cache_dir = temp_path(cache_dir, sizeof cache_dir, "cache");
  bo.progress = NULL;
  if (!CHECK_OK(mbvh_accel_build(file, &bo, &built))) goto done;
  CHECK_OK(mbvh_accel_cache_report(built, &loaded, &path, &problem));
  CHECK(loaded == 0 && strstr(path, cache_dir) == path && strcmp(problem, "") == 0);
  snprintf(entry, sizeof entry, "%s", path);
  if (!CHECK_OK(mbvh_accel_build(file, &bo, &read))) goto done;
  CHECK_OK(mbvh_accel_cache_report(read, &loaded, &path, &problem));
  CHECK(loaded == 1 && strcmp(path, entry) == 0);
  CHECK_OK(mbvh_accel_bounds(read, lo, hi));
  make_rays(lo, hi, rays, 512);
  CHECK_OK(mbvh_trace(ref, fresh, rays, 512, NULL, a, NULL));
  CHECK_OK(mbvh_trace(ref, read, rays, 512, NULL, b, NULL));
  CHECK(memcmp(a, b, sizeof a) == 0);
done:
  mbvh_accel_release(fresh);
  mbvh_accel_release(built);
  mbvh_accel_release(read);
  mbvh_backend_release(ref);
  mbvh_scene_release(file);
  mbvh_scene_release(gen);
  if (entry[0]) unlink(entry);
  if (cache_dir[0]) rmdir(cache_dir);
}

/* -- every backend here, and the program's bytes */

#define RAYS 4096

/* MBVH_TEST_BACKENDS (comma-separated) lists `name`, or is unset */
static int backend_selected(const char* name) {
  const char* only = getenv("MBVH_TEST_BACKENDS");
  const size_t len = strlen(name);
  const char* p = only;
  if (!only || !*only) return 1;
  while ((p = strstr(p, name)) != NULL) {
    if ((p == only || p[-1] == ',') && (p[len] == ',' || p[len] == '\0')) return 1;
    p += len;
  }
  return 0;
}

/* `mbvh trace` on the same scene, rays and backend writes what mbvh_trace wrote, byte for byte */
static void check_cli(const char* name, const char* precision, const char* scene, const char* rays_file,
                      const mbvh_hit* hits, const uint8_t* occluded) {
  static mbvh_hit cli_hits[RAYS];
  static uint8_t cli_occluded[RAYS];
  char out[512], command[2048];
  int q;
  for (q = 0; q < 2; ++q) {
    temp_path(out, sizeof out, q ? "cli.occlusion" : "cli.hits");
    snprintf(command, sizeof command, "'%s' trace '%s' --rays '%s' --backend %s --precision %s --query %s --quiet -o '%s'",
             MBVH_CLI_PATH, scene, rays_file, name, precision, q ? "any" : "closest", out);
    if (!CHECK(system(command) == 0)) {
      fprintf(stderr, "  command: %s\n", command);
      continue;
    }
    if (q == 0) CHECK(read_file(out, cli_hits, sizeof cli_hits) && memcmp(cli_hits, hits, sizeof cli_hits) == 0);
    else CHECK(read_file(out, cli_occluded, sizeof cli_occluded) && memcmp(cli_occluded, occluded, sizeof cli_occluded) == 0);
    unlink(out);
  }
}

typedef struct answers {
  mbvh_hit hits[RAYS];
  uint8_t occluded[RAYS];
} answers;

/* `got` against `want` up to classified ties; the count of ties, or -1 on a genuine mismatch */
static int compare_answers(const char* name, const answers* got, const answers* want, const mbvh_ray* rays) {
  int ties = 0, i, v;
  for (i = 0; i < RAYS; ++i) {
    v = compare_hit(&got->hits[i], &want->hits[i]);
    if (v == 0) v = compare_occlusion(got->occluded[i], want->occluded[i], &want->hits[i], &rays[i]);
    if (v == 2) {
      fprintf(stderr, "%s: ray %d: prim %u t %.9g occluded %d, the reference prim %u t %.9g occluded %d\n", name, i,
              (unsigned)got->hits[i].prim, (double)got->hits[i].t, got->occluded[i], (unsigned)want->hits[i].prim,
              (double)want->hits[i].t, want->occluded[i]);
      return -1;
    }
    ties += v;
  }
  return ties;
}

static void test_backends(int with_cli) {
  static const char scene_path[] = MBVH_SCENES_DIR "/bun_zipper.ply.zst";
  static mbvh_ray rays[RAYS];
  static answers ref1, ref, got; /* the reference with the build's own leaves; with the backend's; the backend's */
  const char* expect_skip = getenv("MBVH_C_TEST_EXPECT_SKIP");
  int expected_skipped = 0, traced = 0;
  mbvh_scene* scene = NULL;
  mbvh_accel* accel = NULL;
  mbvh_accel* flat = NULL; /* quality none, as `mbvh trace` builds for a dacrt backend */
  mbvh_backend* scalar = NULL;
  mbvh_build_options none;
  char rays_file[512];
  float lo[3], hi[3];
  size_t count = mbvh_backend_count(), i;

  CHECK(count >= 4); /* cpu-scalar, cpu-avx2, cpu-avx512, cpu at least */
  CHECK(mbvh_backend_name(count) == NULL);
  if (!CHECK_OK(mbvh_scene_load(scene_path, &scene)) || !CHECK_OK(mbvh_accel_build(scene, NULL, &accel)) ||
      !CHECK_OK(mbvh_backend_create("cpu-scalar", 0, NULL, 0, &scalar)))
    goto done;
  mbvh_build_options_init(&none);
  none.quality = MBVH_BUILD_QUALITY_NONE;
  if (!CHECK_OK(mbvh_accel_build(scene, &none, &flat))) goto done;
  CHECK_OK(mbvh_accel_bounds(accel, lo, hi));
  make_rays(lo, hi, rays, RAYS);
  if (!trace_both(scalar, accel, rays, RAYS, trace_options(MBVH_QUERY_CLOSEST, 1), ref1.hits, ref1.occluded)) goto done;
  temp_path(rays_file, sizeof rays_file, "bunny.rays");
  CHECK(write_file(rays_file, rays, sizeof rays)); /* raw 32-byte records: a .rays file */

  for (i = 0; i < count; ++i) {
    const char* name = mbvh_backend_name(i);
    const char* runs_as = "";
    const char* description = "";
    mbvh_backend* b = NULL;
    mbvh_trace_options o = trace_options(MBVH_QUERY_CLOSEST, 0), d;
    mbvh_status s;
    int peer = 0, dacrt, ties;
    if (!CHECK(name != NULL)) continue;
    /* the backend that must be skipped is tried whatever MBVH_TEST_BACKENDS says: it traces nothing */
    if (!backend_selected(name) && !(expect_skip && strcmp(expect_skip, name) == 0)) {
      printf("backend %s left out: not in MBVH_TEST_BACKENDS\n", name);
      continue;
    }
    s = mbvh_backend_create(name, 0, NULL, 0, &b);
    if (s == MBVH_ERROR_MISSING_HARDWARE) {
      printf("backend %s skipped: %s\n", name, mbvh_last_error());
      CHECK(b == NULL && strstr(mbvh_last_error(), name) != NULL);
      if (expect_skip && strcmp(expect_skip, name) == 0) expected_skipped = 1;
      continue;
    }
    if (!CHECK_OK(s)) continue; /* built and its hardware here: it must start */
    CHECK_OK(mbvh_backend_runs_as(b, &runs_as));
    CHECK_OK(mbvh_backend_describe(b, &description));
    CHECK_OK(mbvh_backend_is_peer(b, &peer));
    CHECK_OK(mbvh_backend_resolve(b, &o));
    CHECK(o.layout != MBVH_LAYOUT_DEFAULT && o.traversal != MBVH_TRAVERSAL_DEFAULT && o.leaf_block >= 1);
    dacrt = o.traversal == MBVH_TRAVERSAL_DACRT;
    printf("backend %s (runs as %s; MBVH%d, traversal %d, leaf block %u): %s\n", name, runs_as, (int)o.layout,
           (int)o.traversal, o.leaf_block, description);
    /* the defaults (what mbvh_trace does without options); a peer without robust precision (tinybvh:
     * not watertight) refuses them with an error naming the precision, and is traced in its own */
    d = trace_options(MBVH_QUERY_CLOSEST, 0);
    if (peer && mbvh_trace(b, accel, rays, 1, &d, got.hits, NULL) != MBVH_OK) {
      printf("backend %s refuses the default precision: %s\n", name, mbvh_last_error());
      CHECK(strstr(mbvh_last_error(), "precision") != NULL);
      d.precision = MBVH_PRECISION_FAST;
    }
    if (!trace_both(b, dacrt ? flat : accel, rays, RAYS, d, got.hits, got.occluded)) {
      mbvh_backend_release(b);
      continue;
    }
    ++traced;
    if (!peer && !dacrt) {
      /* bit for bit: cpu-scalar traced with the options this backend resolved them to */
      if (trace_both(scalar, accel, rays, RAYS, o, ref.hits, ref.occluded)) {
        CHECK(memcmp(got.hits, ref.hits, sizeof got.hits) == 0);
        CHECK(memcmp(got.occluded, ref.occluded, sizeof got.occluded) == 0);
      }
      /* and with the build's own leaves every backend gives the same bits */
      if (trace_both(b, accel, rays, RAYS, trace_options(MBVH_QUERY_CLOSEST, 1), ref.hits, ref.occluded)) {
        CHECK(memcmp(ref1.hits, ref.hits, sizeof ref.hits) == 0);
        CHECK(memcmp(ref1.occluded, ref.occluded, sizeof ref.occluded) == 0);
      }
    } else {
      /* another visit order (dacrt) or BVH (a peer): the reference's answers up to classified ties */
      ties = compare_answers(name, &got, &ref1, rays);
      printf("backend %s: %d classified ties in %d rays\n", name, ties, RAYS);
      CHECK(ties >= 0 && ties <= RAYS / 100);
    }
    if (with_cli)
      check_cli(name, d.precision == MBVH_PRECISION_FAST ? "fast" : "robust", scene_path, rays_file, got.hits, got.occluded);
    mbvh_backend_release(b);
  }
  CHECK(traced >= 2);
  if (expect_skip && !CHECK(expected_skipped)) fprintf(stderr, "  backend %s was not skipped as missing hardware\n", expect_skip);
  unlink(rays_file);
done:
  mbvh_backend_release(scalar);
  mbvh_accel_release(accel);
  mbvh_accel_release(flat);
  mbvh_scene_release(scene);
}

/* -- every error path; each leaves the objects it was given as they were */

static void test_errors(void) {
  const float v[12] = {0, 0, 0, 1, 0, 0, 1, 1, 0, 0, 1, 0};
  const uint32_t t[6] = {0, 1, 2, 0, 2, 3};
  const uint32_t bad_t[3] = {0, 1, 9};
  static const char* const unknown_setting[2] = {"cpu.no-such-setting", "1"};
  static const char* const bad_value[2] = {"cpu.leaf-block", "banana"};
  static const char* const null_value[2] = {"cpu.leaf-block", NULL};
  mbvh_scene* scene = (mbvh_scene*)&g_checks; /* not NULL: the failures below must set it to NULL */
  mbvh_scene* bad = NULL;
  mbvh_scene* other = NULL;
  mbvh_accel* accel = NULL;
  mbvh_accel* none = NULL;
  mbvh_backend* b = NULL;
  mbvh_backend* missing = NULL;
  mbvh_build_options bo;
  mbvh_trace_options o;
  mbvh_ray rays[8];
  mbvh_hit hits[8], before[8];
  uint8_t occluded[8];
  char path[512];
  const char* text = NULL;
  size_t n = 0;
  int i, supported = -1;
  static const char obj[] = "v 0 0 0\nv 1 0 0\nv 0 1 zero\nf 1 2 3\n";

  /* scenes */
  CHECK_FAILS(mbvh_scene_create(NULL), MBVH_ERROR_INVALID_ARGUMENT, "mbvh_scene_create: scene is NULL");
  CHECK_FAILS(mbvh_scene_load(NULL, &scene), MBVH_ERROR_INVALID_ARGUMENT, "path_or_spec is NULL");
  CHECK(scene == NULL);
  CHECK_FAILS(mbvh_scene_load("/nonexistent/mbvh-c-api/missing.obj", &scene), MBVH_ERROR,
              "/nonexistent/mbvh-c-api/missing.obj");
  CHECK(scene == NULL);
  temp_path(path, sizeof path, "bad.obj");
  CHECK(write_file(path, obj, sizeof obj - 1));
  CHECK_FAILS(mbvh_scene_load(path, &scene), MBVH_ERROR, path); /* names the file */
  CHECK_MESSAGE(":3"); /* and the line */
  unlink(path);
  CHECK_FAILS(mbvh_scene_load("gen:no-such-generator:3", &scene), MBVH_ERROR, "no-such-generator");
  if (!CHECK_OK(mbvh_scene_create(&scene))) return;
  CHECK_FAILS(mbvh_scene_add_mesh(NULL, v, 4, 12, t, 2, 12, NULL), MBVH_ERROR_INVALID_ARGUMENT, "scene is NULL");
  CHECK_FAILS(mbvh_scene_add_mesh(scene, v, 4, 8, t, 2, 12, NULL), MBVH_ERROR_INVALID_ARGUMENT, "vertex_stride = 8");
  CHECK_FAILS(mbvh_scene_add_mesh(scene, v, 4, 12, t, 2, 4, NULL), MBVH_ERROR_INVALID_ARGUMENT, "index_stride = 4");
  CHECK_FAILS(mbvh_scene_add_mesh(scene, NULL, 4, 12, t, 2, 12, NULL), MBVH_ERROR_INVALID_ARGUMENT, "vertices is NULL");
  CHECK_FAILS(mbvh_scene_add_mesh(scene, v, 4, 12, NULL, 2, 12, NULL), MBVH_ERROR_INVALID_ARGUMENT, "indices is NULL");
  CHECK_OK(mbvh_scene_triangle_count(scene, &n)); /* the failed calls added nothing */
  CHECK(n == 0);
  CHECK_FAILS(mbvh_scene_triangle_count(scene, NULL), MBVH_ERROR_INVALID_ARGUMENT, "count is NULL");
  CHECK_FAILS(mbvh_scene_bounds(NULL, NULL, NULL), MBVH_ERROR_INVALID_ARGUMENT, "scene is NULL");
  /* a successful call leaves the last error as it was */
  CHECK_OK(mbvh_scene_add_mesh(scene, v, 4, 12, t, 2, 12, NULL));
  CHECK_MESSAGE("mbvh_scene_bounds: scene is NULL");
  /* a vertex index out of range: found by the build, naming it */
  CHECK_OK(mbvh_scene_create(&bad));
  CHECK_OK(mbvh_scene_add_mesh(bad, v, 4, 12, bad_t, 1, 12, NULL));
  CHECK_FAILS(mbvh_accel_build(bad, NULL, &accel), MBVH_ERROR, "names vertex 9");
  CHECK(accel == NULL);

  /* build options */
  mbvh_build_options_init(&bo);
  CHECK_FAILS(mbvh_accel_build(NULL, &bo, &accel), MBVH_ERROR_INVALID_ARGUMENT, "scene is NULL");
  CHECK_FAILS(mbvh_accel_build(scene, &bo, NULL), MBVH_ERROR_INVALID_ARGUMENT, "accel is NULL");
  bo.struct_size = 0;
  CHECK_FAILS(mbvh_accel_build(scene, &bo, &accel), MBVH_ERROR_INVALID_ARGUMENT, "mbvh_build_options_init");
  mbvh_build_options_init(&bo);
  bo.quality = (mbvh_build_quality)7;
  CHECK_FAILS(mbvh_accel_build(scene, &bo, &accel), MBVH_ERROR_INVALID_ARGUMENT, "options->quality = 7");
  CHECK(accel == NULL);
  if (!CHECK_OK(mbvh_accel_build(scene, NULL, &accel))) goto done;
  mbvh_build_options_init(&bo);
  bo.quality = MBVH_BUILD_QUALITY_NONE;
  CHECK_OK(mbvh_accel_build(scene, &bo, &none));
  /* a refit with other triangles leaves the accel as it was */
  CHECK_OK(mbvh_scene_create(&other));
  CHECK_OK(mbvh_scene_add_mesh(other, v, 4, 12, t, 1, 12, NULL));
  CHECK_FAILS(mbvh_accel_refit(accel, other), MBVH_ERROR, "triangle");
  CHECK_FAILS(mbvh_accel_refit(NULL, other), MBVH_ERROR_INVALID_ARGUMENT, "accel is NULL");
  CHECK_OK(mbvh_accel_triangle_count(accel, &n));
  CHECK(n == 2);

  /* backends */
  CHECK(mbvh_backend_name((size_t)-1) == NULL);
  CHECK_MESSAGE("past the last backend");
  CHECK_FAILS(mbvh_backend_create(NULL, 0, NULL, 0, &b), MBVH_ERROR_INVALID_ARGUMENT, "name is NULL");
  CHECK_FAILS(mbvh_backend_create("no-such-backend", 0, NULL, 0, &b), MBVH_ERROR, "unknown backend 'no-such-backend'");
  CHECK_MESSAGE("cpu-scalar"); /* the message lists the known ones */
  CHECK(b == NULL);
  CHECK_FAILS(mbvh_backend_create("cpu-scalar", 0, unknown_setting, 1, &b), MBVH_ERROR, "cpu.no-such-setting");
  CHECK_FAILS(mbvh_backend_create("cpu-scalar", 0, bad_value, 1, &b), MBVH_ERROR, "banana");
  CHECK_FAILS(mbvh_backend_create("cpu-scalar", 0, null_value, 1, &b), MBVH_ERROR_INVALID_ARGUMENT, "settings[1] is NULL");
  CHECK_FAILS(mbvh_backend_create("cpu-scalar", 0, NULL, 1, &b), MBVH_ERROR_INVALID_ARGUMENT, "settings is NULL");
  CHECK(b == NULL);
  if (!CHECK_OK(mbvh_backend_create("cpu-scalar", 0, NULL, 0, &b))) goto done;
  CHECK_FAILS(mbvh_backend_describe(b, NULL), MBVH_ERROR_INVALID_ARGUMENT, "description is NULL");
  CHECK_FAILS(mbvh_backend_describe(NULL, &text), MBVH_ERROR_INVALID_ARGUMENT, "backend is NULL");
  CHECK_FAILS(mbvh_backend_supports(b, (mbvh_layout)3, MBVH_TRAVERSAL_STACK, &supported), MBVH_ERROR_INVALID_ARGUMENT,
              "layout = 3");
  CHECK_OK(mbvh_backend_supports(b, MBVH_LAYOUT_MBVH2, MBVH_TRAVERSAL_BITSTACK_RETEST, &supported));
  CHECK(supported == 0); /* bitstack-retest is MBVH4's only */
  CHECK_OK(mbvh_backend_supports(b, MBVH_LAYOUT_DEFAULT, MBVH_TRAVERSAL_DEFAULT, &supported));
  CHECK(supported == 1);

  /* tracing */
  for (i = 0; i < 8; ++i) {
    const mbvh_ray r = {0.1f + 0.1f * (float)i, 0.5f, 1, 0, 0, 0, -1, INFINITY};
    rays[i] = r;
  }
  if (!CHECK_OK(mbvh_trace(b, accel, rays, 8, NULL, before, NULL))) goto done;
  for (i = 0; i < 8; ++i) CHECK(before[i].prim != MBVH_MISS && before[i].t == 1.0f);
  rays[5].dy = NAN;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, NULL, hits, NULL), MBVH_ERROR, "ray 5");
  CHECK_MESSAGE("direction y");
  rays[5].dy = 0;
  rays[6].oz = INFINITY;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, NULL, hits, NULL), MBVH_ERROR, "ray 6");
  rays[6].oz = 1;
  CHECK_OK(mbvh_trace(b, accel, rays, 8, NULL, hits, NULL)); /* the backend traces on after a refusal */
  CHECK(memcmp(hits, before, sizeof hits) == 0);
  CHECK_MESSAGE("ray 6"); /* still the last failure's message */
  CHECK_FAILS(mbvh_trace(NULL, accel, rays, 8, NULL, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "backend is NULL");
  CHECK_FAILS(mbvh_trace(b, NULL, rays, 8, NULL, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "accel is NULL");
  CHECK_FAILS(mbvh_trace(b, accel, NULL, 8, NULL, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "rays is NULL");
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, NULL, NULL, occluded), MBVH_ERROR_INVALID_ARGUMENT, "hits");
  o = trace_options(MBVH_QUERY_ANY, 0);
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "occluded");
  CHECK_OK(mbvh_trace(b, accel, NULL, 0, &o, NULL, NULL)); /* nothing to trace */
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.layout = (mbvh_layout)3;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "layout = 3");
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.traversal = (mbvh_traversal)99;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "traversal = 99");
  o.traversal = (mbvh_traversal)(MBVH_TRAVERSAL_BITSTACK_OCTANT + 1); /* one past the last value */
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "traversal = 11");
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.layout = MBVH_LAYOUT_MBVH8;
  o.traversal = MBVH_TRAVERSAL_BITSTACK_OCTANT; /* the last value: accepted, the default's answers */
  CHECK_OK(mbvh_trace(b, accel, rays, 8, &o, hits, NULL));
  CHECK(memcmp(hits, before, sizeof hits) == 0);
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.query = (mbvh_query)2;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "options->query = 2");
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.precision = (mbvh_precision)-1;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "options->precision = -1");
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.struct_size = sizeof o + 8; /* a newer header's struct: refused, not half read */
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR_INVALID_ARGUMENT, "mbvh_trace_options_init");
  o = trace_options(MBVH_QUERY_CLOSEST, 65);
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR, "65");
  o = trace_options(MBVH_QUERY_CLOSEST, 0);
  o.layout = MBVH_LAYOUT_MBVH2;
  o.traversal = MBVH_TRAVERSAL_BITSTACK_RETEST;
  CHECK_FAILS(mbvh_trace(b, accel, rays, 8, &o, hits, NULL), MBVH_ERROR, "bitstack-retest");
  /* a build without a hierarchy: only the dacrt backends trace it */
  CHECK_FAILS(mbvh_trace(b, none, rays, 8, NULL, hits, NULL), MBVH_ERROR, "hierarchy");
  CHECK_OK(mbvh_trace(b, accel, rays, 8, NULL, hits, NULL));
  CHECK(memcmp(hits, before, sizeof hits) == 0);
  /* a backend this machine cannot run, where there is one: skipped by status, naming why */
  if (mbvh_backend_create("cpu-avx512", 0, NULL, 0, &missing) == MBVH_ERROR_MISSING_HARDWARE) {
    CHECK(missing == NULL);
    CHECK_MESSAGE("cpu-avx512");
  }
  mbvh_backend_release(missing);
done:
  mbvh_backend_release(b);
  mbvh_accel_release(accel);
  mbvh_accel_release(none);
  mbvh_scene_release(scene);
  mbvh_scene_release(bad);
  mbvh_scene_release(other);
  /* releasing NULL does nothing */
  mbvh_scene_release(NULL);
  mbvh_accel_release(NULL);
  mbvh_backend_release(NULL);
}

/* The log callback gets the library's messages: the device the vulkan backend chose (said once per
 * device in a process, so this runs before any other test makes a backend); none after NULL. */
static int g_log_lines = 0;
static void count_device_lines(int level, const char* message, void* user) {
  CHECK(level == 1 && user == &g_log_lines);
  if (strstr(message, "vulkan: Vulkan device ") == message) ++g_log_lines;
}

static void test_log_callback(void) {
  mbvh_backend* b = NULL;
  mbvh_set_log_callback(count_device_lines, &g_log_lines);
  const mbvh_status st = mbvh_backend_create("vulkan", 1, NULL, 0, &b);
  if (st == MBVH_OK) CHECK(g_log_lines == 1);
  else printf("c api: the log callback's device line not checked: vulkan cannot start here (%s)\n", mbvh_last_error());
  mbvh_backend_release(b);
  mbvh_set_log_callback(NULL, NULL);
}

int main(int argc, char** argv) {
  const int backends_only = argc > 1 && strcmp(argv[1], "backends") == 0;
  if (argc > 1 && !backends_only) {
    fprintf(stderr, "usage: %s [backends]\n", argv[0]);
    return 2;
  }
  if (!mkdtemp(g_dir)) {
    perror("mkdtemp");
    return 1;
  }
  test_library();
  if (!backends_only) {
    test_log_callback();
    test_scene_from_arrays();
    test_loaded_scenes();
    test_errors();
  }
  test_backends(!backends_only);
  rmdir(g_dir);
  printf("c api: %d checks, %d failed\n", g_checks, g_failures);
  return g_failures ? 1 : 0;
}

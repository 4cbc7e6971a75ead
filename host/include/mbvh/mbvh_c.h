/* SPDX-License-Identifier: MIT */
/* mbvh_c.h — mbvh's C API (plain C99; also valid C++): opaque handles, status codes and a
 * per-thread error message, no exception across the boundary, the caller's buffers read in place.
 * The base for bindings in other languages (Rust, C#, Julia, Python's ctypes). Library: libmbvh_c,
 * a shared library holding the C++ library and every backend of the build, exporting only the
 * mbvh_* functions below (CMake: mbvh::c; pkg-config: mbvh_c). docs/library.md, "The C API".
 *
 *   mbvh_scene* scene;  mbvh_accel* accel;  mbvh_backend* cpu;
 *   mbvh_scene_create(&scene);
 *   mbvh_scene_add_mesh(scene, positions, 4, 12, indices, 2, 12, NULL);  // views, not copies
 *   mbvh_accel_build(scene, NULL, &accel);    // after it returns the caller's buffers may go
 *   mbvh_backend_create("cpu", 0, NULL, 0, &cpu);
 *   if (mbvh_trace(cpu, accel, rays, n, NULL, hits, NULL) != MBVH_OK)  // closest hits, in ray order
 *     fprintf(stderr, "%s\n", mbvh_last_error());
 *   mbvh_backend_release(cpu); mbvh_accel_release(accel); mbvh_scene_release(scene);
 *
 * Errors. Every function that can fail returns an mbvh_status; MBVH_OK is 0. On failure
 * mbvh_last_error() gives the message (an mbvh::Error's text unchanged: it names the file, line,
 * ray, setting or backend), output handles are set to NULL and the objects passed in are as they
 * were before the call (a failed add_mesh adds no mesh; a failed trace leaves the backend usable;
 * the output arrays' contents are then unspecified). No C++ exception leaves the library.
 *
 * Lifetimes. Each handle is released by its own mbvh_*_release (NULL is accepted). Handles are
 * independent: an accel holds its own copy of the triangles, so the scene (and the caller's mesh
 * buffers) may be released once mbvh_accel_build returns; a backend may trace any accel.
 * Strings returned by a handle's functions live as long as the handle; mbvh_backend_name's and
 * mbvh_version's as long as the library; mbvh_last_error's until the next failing call on the
 * same thread.
 *
 * Zero-copy. mbvh_scene_add_mesh keeps pointers to the caller's vertex and index buffers, not
 * copies: they must stay alive and unchanged until mbvh_accel_build (or mbvh_accel_refit, or
 * another call that reads the scene's triangles: triangle_count excepted) returns. mbvh_trace
 * reads the rays in place and writes the answers into the caller's arrays (staged in a buffer of
 * the calling thread that is reused, so repeated traces do not allocate).
 *
 * Threads. A scene may be read by several threads at once (builds, bounds) but not while
 * mbvh_scene_add_mesh changes it. An accel may be traced from several threads at once, never
 * during mbvh_accel_refit. A backend handle may be used from several threads: its calls run one
 * at a time (one backend per thread traces in parallel; a cpu backend spreads each call over its
 * own worker threads anyway). mbvh_last_error is per thread.
 */
#ifndef MBVH_C_H
#define MBVH_C_H

#include <stddef.h>
#include <stdint.h>

#include "mbvh/version.h" /* MBVH_VERSION_MAJOR, _MINOR, _PATCH, MBVH_VERSION_STRING */

/* The version of this C API: bumped by every change to it. An addition keeps programs built
 * against an older header working; an incompatible change also bumps MBVH_VERSION_MAJOR (the
 * shared library's soname carries the major and minor version). mbvh_c_api_version() returns the
 * linked library's: a program needs mbvh_c_api_version() >= the MBVH_C_API_VERSION it was built
 * with. */
#define MBVH_C_API_VERSION 1

#if defined(_WIN32)
#if defined(MBVH_C_BUILD)
#define MBVH_C_API __declspec(dllexport)
#else
#define MBVH_C_API __declspec(dllimport)
#endif
#elif defined(__GNUC__)
#define MBVH_C_API __attribute__((visibility("default")))
#else
#define MBVH_C_API
#endif

#ifdef __cplusplus
extern "C" {
#endif

/* -- handles (opaque) */
typedef struct mbvh_scene mbvh_scene;     /* triangles: a loaded file or generator, or views of the caller's meshes */
typedef struct mbvh_accel mbvh_accel;     /* one build of a scene (the BVH every backend and layout traces) */
typedef struct mbvh_backend mbvh_backend; /* a tracing backend: cpu, cpu-scalar, dacrt, opencl, vulkan, embree... */

/* -- status codes. Enums are int-sized. */
typedef enum mbvh_status {
  MBVH_OK = 0,
  MBVH_ERROR_INVALID_ARGUMENT = 1, /* a NULL pointer, an enum value or stride out of range, an options struct not made by its init function */
  MBVH_ERROR = 2,                  /* mbvh refused the input or failed: a bad file, scene, ray, setting or name, a device failure */
  MBVH_ERROR_MISSING_HARDWARE = 3, /* mbvh_backend_create: the backend is built but this machine lacks its hardware (AVX-512) */
  MBVH_ERROR_OUT_OF_MEMORY = 4,
  MBVH_ERROR_UNKNOWN = 5           /* an unexpected internal failure (its message says what) */
} mbvh_status;

/* -- trace options (the values of the C++ API's Layout, Traversal, Query, Precision) */
typedef enum mbvh_layout {
  MBVH_LAYOUT_DEFAULT = 0, /* what `mbvh trace` picks: the layout the backend traces fastest (with the traversal, if named) */
  MBVH_LAYOUT_MBVH2 = 2,
  MBVH_LAYOUT_MBVH4 = 4,
  MBVH_LAYOUT_MBVH8 = 8
} mbvh_layout;

typedef enum mbvh_traversal {
  MBVH_TRAVERSAL_DEFAULT = 0, /* what `mbvh trace` picks: the backend's fastest exact traversal for the query (on the
                                 layout, if named): docs/library.md, "Defaults"; mbvh_backend_resolve says which */
  MBVH_TRAVERSAL_STACK = 1,
  MBVH_TRAVERSAL_BITSTACK = 2,        /* the stackless bitstack traversal (Afra & Szirmay-Kalos 2014) */
  MBVH_TRAVERSAL_STACK_ORDERED = 3,   /* MBVH4 and MBVH8 */
  MBVH_TRAVERSAL_BITSTACK_RETEST = 4, /* MBVH4 only */
  MBVH_TRAVERSAL_PACKET_RANGED = 5,   /* the cpu backends' coherent packets */
  MBVH_TRAVERSAL_PACKET_PARTITION = 6,
  MBVH_TRAVERSAL_PACKET = 7,
  MBVH_TRAVERSAL_DACRT = 8,           /* divide-and-conquer, no hierarchy (the dacrt backends) */
  MBVH_TRAVERSAL_STACK_OCTANT = 9,    /* MBVH8 only: the children pushed in the ray octant's order */
  MBVH_TRAVERSAL_BITSTACK_OCTANT = 10 /* MBVH8 only: the bitstack in the ray octant's order */
} mbvh_traversal;

typedef enum mbvh_query {
  MBVH_QUERY_CLOSEST = 0, /* the closest hit of each ray: an mbvh_hit per ray */
  MBVH_QUERY_ANY = 1      /* occlusion: a byte per ray, 1 when some triangle lies in [tmin, tmax] */
} mbvh_query;

typedef enum mbvh_precision {
  MBVH_PRECISION_ROBUST = 0, /* the default: watertight triangles, conservative boxes, the same bits on every backend */
  MBVH_PRECISION_EXACT = 1,  /* robust, required (a backend that cannot promise it refuses it: embree) */
  MBVH_PRECISION_FAST = 2    /* Moller-Trumbore and plain slabs: faster, not bit-identical across backends */
} mbvh_precision;

typedef enum mbvh_build_quality {
  MBVH_BUILD_QUALITY_LOW = 0,    /* Morton-code LBVH: fast to build, slower to trace */
  MBVH_BUILD_QUALITY_MEDIUM = 1, /* binned SAH: the default */
  MBVH_BUILD_QUALITY_HIGH = 2,   /* spatial splits (SBVH) */
  MBVH_BUILD_QUALITY_NONE = 3    /* no hierarchy: the triangles alone, for the dacrt backends only */
} mbvh_build_quality;

/* -- rays and hits: the records of the C++ API (mbvh::Ray, mbvh::Hit) and of the .rays / .hits
 * files, byte for byte (little-endian on the machines mbvh runs on). */
typedef struct mbvh_ray {
  float ox, oy, oz, tmin; /* origin; hits with t < tmin do not count */
  float dx, dy, dz, tmax; /* direction (any length: t is in its units); tmax may be INFINITY */
} mbvh_ray;               /* 32 bytes */

typedef struct mbvh_hit {
  float t, u, v; /* distance along the ray; barycentrics of vertices 1 and 2: p = (1-u-v) v0 + u v1 + v v2 */
  uint32_t prim; /* the triangle's id in the scene (mbvh_accel_geometry_of names its mesh), MBVH_MISS for none */
} mbvh_hit;      /* 16 bytes; a miss: t = +inf, u = v = 0, prim = MBVH_MISS */

#define MBVH_MISS 0xFFFFFFFFu             /* mbvh_hit::prim of a miss */
#define MBVH_INVALID_GEOMETRY 0xFFFFFFFFu /* mbvh_accel_geometry_of: the geometry of a miss */

/* -- options structs: made by their init function (inline, so struct_size is the size this
 * program was compiled with), then changed field by field. A NULL options pointer means the
 * defaults. The library refuses a struct_size it does not know (MBVH_ERROR_INVALID_ARGUMENT). */
typedef struct mbvh_build_options {
  size_t struct_size;          /* sizeof(mbvh_build_options) */
  unsigned threads;            /* build threads, 0: every hardware thread (the result does not depend on it) */
  mbvh_build_quality quality;  /* MBVH_BUILD_QUALITY_MEDIUM */
  unsigned max_leaf;           /* 8: the largest leaf the SAH may choose */
  unsigned leaf_block;         /* 1: triangles one leaf test costs as one in the SAH */
  const char* cache_dir;       /* NULL; else keep the build in this directory and read it back when the
                                  triangles and options match (a damaged or mismatched file is rebuilt) */
  uint64_t cache_max_bytes;    /* 0: no bound; else the cache directory's least recently used entries go */
  void (*progress)(double fraction, void* user); /* NULL; else called with the fraction done, from any thread */
  void* progress_user;         /* passed to progress */
} mbvh_build_options;

static inline void mbvh_build_options_init(mbvh_build_options* o) {
  if (!o) return;
  o->struct_size = sizeof(mbvh_build_options);
  o->threads = 0;
  o->quality = MBVH_BUILD_QUALITY_MEDIUM;
  o->max_leaf = 8;
  o->leaf_block = 1;
  o->cache_dir = NULL;
  o->cache_max_bytes = 0;
  o->progress = NULL;
  o->progress_user = NULL;
}

typedef struct mbvh_trace_options {
  size_t struct_size;       /* sizeof(mbvh_trace_options) */
  mbvh_layout layout;       /* MBVH_LAYOUT_DEFAULT */
  mbvh_traversal traversal; /* MBVH_TRAVERSAL_DEFAULT */
  mbvh_query query;         /* MBVH_QUERY_CLOSEST */
  mbvh_precision precision; /* MBVH_PRECISION_ROBUST */
  unsigned leaf_block;      /* 0: the backend's choice (4 on the SIMD cpu backends, else 1); 1: the build's own
                               leaves, which every backend traces to the same bits; at most 64 */
} mbvh_trace_options;

static inline void mbvh_trace_options_init(mbvh_trace_options* o) {
  if (!o) return;
  o->struct_size = sizeof(mbvh_trace_options);
  o->layout = MBVH_LAYOUT_DEFAULT;
  o->traversal = MBVH_TRAVERSAL_DEFAULT;
  o->query = MBVH_QUERY_CLOSEST;
  o->precision = MBVH_PRECISION_ROBUST;
  o->leaf_block = 0;
}

/* -- the library */
MBVH_C_API const char* mbvh_version(void);     /* the linked library's "MAJOR.MINOR.PATCH" */
MBVH_C_API unsigned mbvh_c_api_version(void);  /* the linked library's MBVH_C_API_VERSION */
/* The message of the last failed call on this thread; "" when none failed. */
MBVH_C_API const char* mbvh_last_error(void);
/* The status's name ("MBVH_ERROR_INVALID_ARGUMENT"); "unknown status" for another value. */
MBVH_C_API const char* mbvh_status_string(mbvh_status status);
/* Where the library's messages go (the device a backend chose; mbvh/log.h): the library never
 * writes to standard output or error. callback(level, message, user) gets each message, one line
 * without a newline, level 0 debug, 1 info, 2 warning; it may be called from any thread, from
 * several at once, and once more by a thread that took it just before it was replaced. NULL (the
 * default) drops them. */
typedef void (*mbvh_log_callback)(int level, const char* message, void* user);
MBVH_C_API void mbvh_set_log_callback(mbvh_log_callback callback, void* user);

/* -- scenes */
/* A scene from a file (.obj, .ply, optionally .zst-compressed) or a generator spec ("gen:sphere:64",
 * "gen:soup:100000:7", "gen:hairball:1000000", "gen:cube:16"). MBVH_ERROR names the file, line and
 * what was wrong. The scene owns its triangles (mbvh_scene_add_mesh refuses it). */
MBVH_C_API mbvh_status mbvh_scene_load(const char* path_or_spec, mbvh_scene** scene);
/* An empty scene, for mbvh_scene_add_mesh. */
MBVH_C_API mbvh_status mbvh_scene_create(mbvh_scene** scene);
/* Adds a view of the caller's mesh (no copy; the lifetime rule atop this file). Vertex i is the
 * three floats x, y, z at byte offset i * vertex_stride from `vertices` (positions may sit inside
 * interleaved records); triangle j is three uint32 vertex indices at byte offset j * index_stride
 * from `indices`. Strides are at least 12 bytes; no alignment beyond a byte is needed. Its
 * triangles get the scene's next prim ids, in order; `geom_id` (may be NULL) gets the mesh's id:
 * 0, 1, ... in call order. Indices and coordinates are checked by the build, so the buffers may
 * be filled after this call. MBVH_ERROR_INVALID_ARGUMENT: a NULL pointer with a nonzero count, a
 * stride below 12; MBVH_ERROR: a scene from mbvh_scene_load, more than 2^31 - 16 triangles. */
MBVH_C_API mbvh_status mbvh_scene_add_mesh(mbvh_scene* scene, const float* vertices, size_t vertex_count,
                                           size_t vertex_stride, const uint32_t* indices, size_t triangle_count,
                                           size_t index_stride, uint32_t* geom_id);
MBVH_C_API mbvh_status mbvh_scene_triangle_count(const mbvh_scene* scene, size_t* count);
MBVH_C_API mbvh_status mbvh_scene_geometry_count(const mbvh_scene* scene, size_t* count); /* meshes; 1 for a loaded scene */
/* The box of the vertices the triangles use (lower > upper for a scene without triangles); checks
 * the triangles first (MBVH_ERROR on an index out of range or a NaN or infinite vertex). O(triangles). */
MBVH_C_API mbvh_status mbvh_scene_bounds(const mbvh_scene* scene, float lower[3], float upper[3]);
MBVH_C_API void mbvh_scene_release(mbvh_scene* scene);

/* -- builds */
/* Builds the BVH of `scene` (options NULL: the defaults), or with options->cache_dir reads it
 * from that directory when an entry holds this build, else builds and writes it there. MBVH_ERROR:
 * no triangle with area, a vertex index out of range, a NaN or infinite coordinate, coordinates
 * outside the range traced exactly (docs: accuracy), a cache directory that cannot be written. */
MBVH_C_API mbvh_status mbvh_accel_build(const mbvh_scene* scene, const mbvh_build_options* options, mbvh_accel** accel);
/* Refits the build to moved vertices (same triangles and meshes: move them in the caller's
 * buffers and pass the same scene): new boxes, the same tree; O(triangles). Nothing may trace
 * `accel` meanwhile. On failure the accel is unchanged. */
MBVH_C_API mbvh_status mbvh_accel_refit(mbvh_accel* accel, const mbvh_scene* scene);
MBVH_C_API mbvh_status mbvh_accel_triangle_count(const mbvh_accel* accel, size_t* count); /* the scene's */
MBVH_C_API mbvh_status mbvh_accel_bounds(const mbvh_accel* accel, float lower[3], float upper[3]);
/* The mesh (its mbvh_scene_add_mesh id; 0 for a loaded scene) and the triangle within it of prim
 * id `prim`; MBVH_INVALID_GEOMETRY and MBVH_MISS for MBVH_MISS or an id past the last. Either
 * output may be NULL. O(log meshes). */
MBVH_C_API mbvh_status mbvh_accel_geometry_of(const mbvh_accel* accel, uint32_t prim, uint32_t* geom_id,
                                              uint32_t* prim_in_geom);
/* With a cache_dir: `loaded` 1 when the build was read from the cache, 0 when built (and
 * written); `path` the entry's file; `problem` why an existing entry was not used, or "".
 * Without: 0, "", "". Any output may be NULL. */
MBVH_C_API mbvh_status mbvh_accel_cache_report(const mbvh_accel* accel, int* loaded, const char** path,
                                               const char** problem);
MBVH_C_API void mbvh_accel_release(mbvh_accel* accel);

/* -- backends */
/* The backends this library has (built in; some may lack their hardware here), by index
 * 0 .. count - 1, in registration order: cpu-scalar, cpu-avx2, cpu-avx512, cpu, dacrt, ...
 * mbvh_backend_name returns NULL (MBVH_ERROR_INVALID_ARGUMENT) for an index past the last. */
MBVH_C_API size_t mbvh_backend_count(void);
MBVH_C_API const char* mbvh_backend_name(size_t index);
/* Starts backend `name` with `threads` CPU workers (0: every hardware thread) and `setting_count`
 * settings given as NAME, VALUE pairs in `settings` (2 * setting_count strings, e.g.
 * {"opencl.device", "0:0", "vulkan.validation", "1"}; `mbvh devices` lists each backend's).
 * MBVH_ERROR: an unknown name (the message lists the known ones), an unknown setting or a bad
 * value, a device that fails; MBVH_ERROR_MISSING_HARDWARE: this machine lacks what the backend
 * needs (the message says what; skip it). */
MBVH_C_API mbvh_status mbvh_backend_create(const char* name, unsigned threads, const char* const* settings,
                                           size_t setting_count, mbvh_backend** backend);
/* One line: ISA, device and driver. */
MBVH_C_API mbvh_status mbvh_backend_describe(const mbvh_backend* backend, const char** description);
/* The backend it runs as: its own name, or for an alias the one it stands for here (cpu: cpu-avx512). */
MBVH_C_API mbvh_status mbvh_backend_runs_as(const mbvh_backend* backend, const char** name);
/* 1 for a peer library (embree): its own BVH, so its answers agree with mbvh's up to ties (the
 * same distance on another triangle, a hit on a shared edge), not bit for bit. */
MBVH_C_API mbvh_status mbvh_backend_is_peer(const mbvh_backend* backend, int* peer);
/* Whether it traces this layout and traversal (DEFAULT values resolved as a closest-hit mbvh_trace does). */
MBVH_C_API mbvh_status mbvh_backend_supports(const mbvh_backend* backend, mbvh_layout layout, mbvh_traversal traversal,
                                             int* supported);
/* Replaces the DEFAULT layout and traversal and a leaf_block of 0 in `options` by what mbvh_trace
 * traces with this backend. */
MBVH_C_API mbvh_status mbvh_backend_resolve(const mbvh_backend* backend, mbvh_trace_options* options);
MBVH_C_API void mbvh_backend_release(mbvh_backend* backend);

/* -- tracing */
/* Traces `count` rays on `backend` through `accel` (options NULL: the defaults: what
 * `mbvh trace` does, which writes the same bytes). Closest hit (options->query
 * MBVH_QUERY_CLOSEST) writes `hits[0 .. count)`; any hit writes `occluded[0 .. count)` (1 or 0);
 * the other array is not used and may be NULL. The rays are read in place; each ray's values must
 * be finite (tmax may be +INFINITY): MBVH_ERROR names the first ray that is not. MBVH_ERROR too for
 * a layout, traversal or precision the backend lacks, a build without a hierarchy on a backend that
 * needs one, a ray outside the range traced exactly. With count 0 nothing is read or written. */
MBVH_C_API mbvh_status mbvh_trace(mbvh_backend* backend, const mbvh_accel* accel, const mbvh_ray* rays, size_t count,
                                  const mbvh_trace_options* options, mbvh_hit* hits, uint8_t* occluded);

#ifdef __cplusplus
}
#endif

#endif /* MBVH_C_H */

// SPDX-License-Identifier: MIT
// mbvh_c.cpp — the C API (mbvh/mbvh_c.h) over the C++ library: each function runs its body in
// `guarded`, which turns every exception into a status and the thread's error message, so none
// crosses into C. Public headers only (tests/consumer/include_rules.sh): the C API is a user of
// the library like any other.
#include "mbvh/mbvh_c.h"

#include <cstddef>
#include <cstring>
#include <memory>
#include <mutex>
#include <new>
#include <span>
#include <stdexcept>
#include <string>
#include <type_traits>
#include <utility>
#include <vector>

#include "mbvh/backends.h"
#include "mbvh/mbvh.h"

// The handles: what the C side sees as opaque structs.
struct mbvh_scene {
  mbvh::Scene scene;
};
struct mbvh_accel {
  std::unique_ptr<mbvh::Accel> accel;
  mbvh::Accel::CacheReport cache;  ///< empty without a cache directory
};
struct mbvh_backend {
  std::unique_ptr<mbvh::Backend> backend;
  std::string runs_as, description;  ///< kept: their pointers are handed out for the handle's life
};

// The records are the C++ API's byte for byte: mbvh_trace passes the caller's arrays on as
// mbvh::Ray and mbvh::Hit spans.
static_assert(sizeof(mbvh_ray) == 32 && sizeof(mbvh_ray) == sizeof(mbvh::Ray));
static_assert(offsetof(mbvh_ray, ox) == offsetof(mbvh::Ray, ox) && offsetof(mbvh_ray, oy) == offsetof(mbvh::Ray, oy) &&
              offsetof(mbvh_ray, oz) == offsetof(mbvh::Ray, oz) && offsetof(mbvh_ray, tmin) == offsetof(mbvh::Ray, tmin) &&
              offsetof(mbvh_ray, dx) == offsetof(mbvh::Ray, dx) && offsetof(mbvh_ray, dy) == offsetof(mbvh::Ray, dy) &&
              offsetof(mbvh_ray, dz) == offsetof(mbvh::Ray, dz) && offsetof(mbvh_ray, tmax) == offsetof(mbvh::Ray, tmax));
static_assert(alignof(mbvh_ray) == alignof(mbvh::Ray));
static_assert(sizeof(mbvh_hit) == 16 && sizeof(mbvh_hit) == sizeof(mbvh::Hit));
static_assert(offsetof(mbvh_hit, t) == offsetof(mbvh::Hit, t) && offsetof(mbvh_hit, u) == offsetof(mbvh::Hit, u) &&
              offsetof(mbvh_hit, v) == offsetof(mbvh::Hit, v) && offsetof(mbvh_hit, prim) == offsetof(mbvh::Hit, prim));
static_assert(alignof(mbvh_hit) == alignof(mbvh::Hit));
static_assert(MBVH_MISS == MBVH_MISS_PRIM && MBVH_INVALID_GEOMETRY == mbvh::kInvalidGeometry);
// Enum fields are read as int (read_enum): a C enum is int-sized on every ABI mbvh supports.
static_assert(sizeof(mbvh_layout) == sizeof(int) && sizeof(mbvh_traversal) == sizeof(int) &&
              sizeof(mbvh_query) == sizeof(int) && sizeof(mbvh_precision) == sizeof(int) &&
              sizeof(mbvh_build_quality) == sizeof(int) && sizeof(mbvh_status) == sizeof(int));
// mbvh_traversal is mbvh::Traversal plus one (0: DEFAULT).
static_assert(MBVH_TRAVERSAL_STACK == 1 + static_cast<int>(mbvh::Traversal::stack) &&
              MBVH_TRAVERSAL_BITSTACK == 1 + static_cast<int>(mbvh::Traversal::bitstack) &&
              MBVH_TRAVERSAL_STACK_ORDERED == 1 + static_cast<int>(mbvh::Traversal::stack_ordered) &&
              MBVH_TRAVERSAL_BITSTACK_RETEST == 1 + static_cast<int>(mbvh::Traversal::bitstack_retest) &&
              MBVH_TRAVERSAL_PACKET_RANGED == 1 + static_cast<int>(mbvh::Traversal::packet_ranged) &&
              MBVH_TRAVERSAL_PACKET_PARTITION == 1 + static_cast<int>(mbvh::Traversal::packet_partition) &&
              MBVH_TRAVERSAL_PACKET == 1 + static_cast<int>(mbvh::Traversal::packet) &&
              MBVH_TRAVERSAL_DACRT == 1 + static_cast<int>(mbvh::Traversal::dacrt) &&
              MBVH_TRAVERSAL_STACK_OCTANT == 1 + static_cast<int>(mbvh::Traversal::stack_octant) &&
              MBVH_TRAVERSAL_BITSTACK_OCTANT == 1 + static_cast<int>(mbvh::Traversal::bitstack_octant));
static_assert(MBVH_C_API_VERSION == 1, "a new version of the API: accept the sizes of every published options struct");

namespace {

// The failures the C layer finds itself, each with its status.
struct InvalidArgument : std::runtime_error {
  using std::runtime_error::runtime_error;
};
struct MissingHardware : std::runtime_error {
  using std::runtime_error::runtime_error;
};

// The message of the thread's last failed call. `g_message` points into `g_text`, or at a
// literal when recording the message itself ran out of memory.
thread_local std::string g_text;
thread_local const char* g_message = "";

mbvh_status fail(mbvh_status status, const char* message) noexcept {
  try {
    g_text = message;
    g_message = g_text.c_str();
  } catch (...) {
    g_message = "out of memory (recording an error message)";
  }
  return status;
}

// Runs `body`, catching everything: the status of what it threw, MBVH_OK if nothing.
template <class F>
mbvh_status guarded(const char* fn, F&& body) noexcept {
  try {
    body();
    return MBVH_OK;
  } catch (const InvalidArgument& e) {
    return fail(MBVH_ERROR_INVALID_ARGUMENT, e.what());
  } catch (const MissingHardware& e) {
    return fail(MBVH_ERROR_MISSING_HARDWARE, e.what());
  } catch (const mbvh::Error& e) {
    return fail(MBVH_ERROR, e.what());
  } catch (const std::bad_alloc&) {
    try {
      return fail(MBVH_ERROR_OUT_OF_MEMORY, (std::string(fn) + ": out of memory").c_str());
    } catch (...) {
      return fail(MBVH_ERROR_OUT_OF_MEMORY, "out of memory");
    }
  } catch (const std::exception& e) {
    try {
      return fail(MBVH_ERROR_UNKNOWN, (std::string(fn) + ": internal error: " + e.what()).c_str());
    } catch (...) {
      return fail(MBVH_ERROR_UNKNOWN, e.what());
    }
  } catch (...) {
    return fail(MBVH_ERROR_UNKNOWN, "internal error: an exception of unknown type");
  }
}

[[noreturn]] void invalid(const char* fn, const std::string& what) { throw InvalidArgument(std::string(fn) + ": " + what); }

template <class T>
void require(const char* fn, const T* p, const char* name) {
  if (!p) invalid(fn, std::string(name) + " is NULL");
}

// Sets an output handle to NULL first, so it is NULL after any failure.
template <class T>
T** output(const char* fn, T** out, const char* name) {
  require(fn, out, name);
  *out = nullptr;
  return out;
}

// An enum field's value as int: a C caller may store any int there, which a C++ enum need not hold.
template <class E>
int read_enum(const E& field) {
  static_assert(std::is_enum_v<E> && sizeof(E) == sizeof(int));
  int v = 0;
  std::memcpy(&v, &field, sizeof v);
  return v;
}

[[noreturn]] void bad_enum(const char* fn, const char* field, int value, const char* valid) {
  invalid(fn, std::string(field) + " = " + std::to_string(value) + " is none of " + valid);
}

// The DEFAULT values stay automatic (TraceOptions' defaults): resolved against a backend (resolve).
struct Variant {
  mbvh::TraceOptions opt;
};

Variant to_variant(const char* fn, int layout, int traversal) {
  Variant v;
  switch (layout) {
    case MBVH_LAYOUT_DEFAULT: v.opt.layout = mbvh::Layout::automatic; break;
    case MBVH_LAYOUT_MBVH2: v.opt.layout = mbvh::Layout::mbvh2; break;
    case MBVH_LAYOUT_MBVH4: v.opt.layout = mbvh::Layout::mbvh4; break;
    case MBVH_LAYOUT_MBVH8: v.opt.layout = mbvh::Layout::mbvh8; break;
    default:
      bad_enum(fn, "layout", layout, "MBVH_LAYOUT_DEFAULT (0), MBVH_LAYOUT_MBVH2 (2), MBVH_LAYOUT_MBVH4 (4), MBVH_LAYOUT_MBVH8 (8)");
  }
  if (traversal < MBVH_TRAVERSAL_DEFAULT || traversal > MBVH_TRAVERSAL_BITSTACK_OCTANT)
    bad_enum(fn, "traversal", traversal, "the mbvh_traversal values, MBVH_TRAVERSAL_DEFAULT (0) to MBVH_TRAVERSAL_BITSTACK_OCTANT (10)");
  v.opt.traversal = traversal == MBVH_TRAVERSAL_DEFAULT ? mbvh::Traversal::automatic
                                                        : static_cast<mbvh::Traversal>(traversal - 1);  // the orders match (the asserts above)
  return v;
}

// What mbvh_trace and `mbvh trace` trace when no layout or traversal is named: the backend's
// fastest exact traversal for the query (mbvh::resolve_options).
void resolve(const mbvh::Backend& b, Variant& v) { v.opt = mbvh::resolve_options(b, v.opt); }

// Every published size of an options struct (MBVH_C_API_VERSION 1: one).
template <class T>
void check_struct_size(const char* fn, const char* name, const char* init, const T& o) {
  if (o.struct_size != sizeof(T))
    invalid(fn, std::string(name) + "->struct_size = " + std::to_string(o.struct_size) + ", which no version of " +
                    name + " has (this library's: " + std::to_string(sizeof(T)) + "): initialise it with " + init);
}

Variant to_variant(const char* fn, const mbvh_trace_options* o) {
  if (!o) return {};
  check_struct_size(fn, "options", "mbvh_trace_options_init", *o);
  Variant v = to_variant(fn, read_enum(o->layout), read_enum(o->traversal));
  switch (const int q = read_enum(o->query)) {
    case MBVH_QUERY_CLOSEST: v.opt.query = mbvh::Query::closest; break;
    case MBVH_QUERY_ANY: v.opt.query = mbvh::Query::any; break;
    default: bad_enum(fn, "options->query", q, "MBVH_QUERY_CLOSEST (0), MBVH_QUERY_ANY (1)");
  }
  switch (const int p = read_enum(o->precision)) {
    case MBVH_PRECISION_ROBUST: v.opt.precision = mbvh::Precision::robust; break;
    case MBVH_PRECISION_EXACT: v.opt.precision = mbvh::Precision::exact; break;
    case MBVH_PRECISION_FAST: v.opt.precision = mbvh::Precision::fast; break;
    default: bad_enum(fn, "options->precision", p, "MBVH_PRECISION_ROBUST (0), MBVH_PRECISION_EXACT (1), MBVH_PRECISION_FAST (2)");
  }
  v.opt.leaf_block = o->leaf_block;
  mbvh::check_leaf_block(v.opt, fn);
  return v;
}

mbvh::BuildOptions to_build_options(const char* fn, const mbvh_build_options& o) {
  check_struct_size(fn, "options", "mbvh_build_options_init", o);
  mbvh::BuildOptions bo;
  bo.threads = o.threads;
  switch (const int q = read_enum(o.quality)) {
    case MBVH_BUILD_QUALITY_LOW: bo.quality = mbvh::BuildQuality::low; break;
    case MBVH_BUILD_QUALITY_MEDIUM: bo.quality = mbvh::BuildQuality::medium; break;
    case MBVH_BUILD_QUALITY_HIGH: bo.quality = mbvh::BuildQuality::high; break;
    case MBVH_BUILD_QUALITY_NONE: bo.quality = mbvh::BuildQuality::none; break;
    default:
      bad_enum(fn, "options->quality", q,
               "MBVH_BUILD_QUALITY_LOW (0), MBVH_BUILD_QUALITY_MEDIUM (1), MBVH_BUILD_QUALITY_HIGH (2), MBVH_BUILD_QUALITY_NONE (3)");
  }
  bo.max_leaf = o.max_leaf;
  bo.leaf_block = o.leaf_block;
  if (o.progress) bo.progress = [f = o.progress, user = o.progress_user](double done) { f(done, user); };
  return bo;
}

// The backends are registered once, before the first call that needs them; the names of those
// this library has are kept for mbvh_backend_name (they live as long as the library).
const std::vector<std::string>& backend_names() {
  static std::once_flag once;
  static std::vector<std::string> names;
  std::call_once(once, [] {
    mbvh::register_builtin_backends();
    std::vector<std::string> built;
    for (const mbvh::BackendInfo& b : mbvh::list_backends())
      if (b.make) built.push_back(b.name);
    names = std::move(built);
  });
  return names;
}

// Why this machine cannot run backend `name` (BackendInfo::missing_hardware), or "".
std::string missing_hardware(const std::string& name) {
  for (const mbvh::BackendInfo& b : mbvh::list_backends())
    if (b.name == name) return b.make && b.missing_hardware ? b.missing_hardware() : std::string();
  return {};
}

void copy3(const mbvh::Vec3f& p, float out[3]) { out[0] = p.x, out[1] = p.y, out[2] = p.z; }

}  // namespace

extern "C" {

const char* mbvh_version(void) { return mbvh::version(); }
unsigned mbvh_c_api_version(void) { return MBVH_C_API_VERSION; }
const char* mbvh_last_error(void) { return g_message; }

void mbvh_set_log_callback(mbvh_log_callback callback, void* user) {
  if (!callback) {
    mbvh::set_log_callback({});
    return;
  }
  mbvh::set_log_callback([callback, user](mbvh::LogLevel level, const std::string& m) {
    callback(static_cast<int>(level), m.c_str(), user);
  });
}

const char* mbvh_status_string(mbvh_status status) {
  switch (read_enum(status)) {
    case MBVH_OK: return "MBVH_OK";
    case MBVH_ERROR_INVALID_ARGUMENT: return "MBVH_ERROR_INVALID_ARGUMENT";
    case MBVH_ERROR: return "MBVH_ERROR";
    case MBVH_ERROR_MISSING_HARDWARE: return "MBVH_ERROR_MISSING_HARDWARE";
    case MBVH_ERROR_OUT_OF_MEMORY: return "MBVH_ERROR_OUT_OF_MEMORY";
    case MBVH_ERROR_UNKNOWN: return "MBVH_ERROR_UNKNOWN";
    default: return "unknown status";
  }
}

// -- scenes

mbvh_status mbvh_scene_load(const char* path_or_spec, mbvh_scene** scene) {
  static const char fn[] = "mbvh_scene_load";
  return guarded(fn, [&] {
    output(fn, scene, "scene");
    require(fn, path_or_spec, "path_or_spec");
    auto s = std::make_unique<mbvh_scene>();
    s->scene = mbvh::load_scene(path_or_spec);
    *scene = s.release();
  });
}

mbvh_status mbvh_scene_create(mbvh_scene** scene) {
  static const char fn[] = "mbvh_scene_create";
  return guarded(fn, [&] {
    output(fn, scene, "scene");
    *scene = new mbvh_scene;
  });
}

mbvh_status mbvh_scene_add_mesh(mbvh_scene* scene, const float* vertices, size_t vertex_count, size_t vertex_stride,
                                const uint32_t* indices, size_t triangle_count, size_t index_stride, uint32_t* geom_id) {
  static const char fn[] = "mbvh_scene_add_mesh";
  return guarded(fn, [&] {
    require(fn, scene, "scene");
    if (!vertices && vertex_count) invalid(fn, "vertices is NULL with vertex_count " + std::to_string(vertex_count));
    if (!indices && triangle_count) invalid(fn, "indices is NULL with triangle_count " + std::to_string(triangle_count));
    if (vertex_stride < 12)
      invalid(fn, "vertex_stride = " + std::to_string(vertex_stride) + " bytes: at least 12 (x, y, z as floats)");
    if (index_stride < 12)
      invalid(fn, "index_stride = " + std::to_string(index_stride) + " bytes: at least 12 (three uint32 indices)");
    const std::uint32_t id = scene->scene.add_mesh({vertices, vertex_count, vertex_stride, indices, triangle_count, index_stride});
    if (geom_id) *geom_id = id;
  });
}

mbvh_status mbvh_scene_triangle_count(const mbvh_scene* scene, size_t* count) {
  static const char fn[] = "mbvh_scene_triangle_count";
  return guarded(fn, [&] {
    require(fn, scene, "scene");
    require(fn, count, "count");
    *count = scene->scene.triangle_count();
  });
}

mbvh_status mbvh_scene_geometry_count(const mbvh_scene* scene, size_t* count) {
  static const char fn[] = "mbvh_scene_geometry_count";
  return guarded(fn, [&] {
    require(fn, scene, "scene");
    require(fn, count, "count");
    *count = scene->scene.geometry_count();
  });
}

mbvh_status mbvh_scene_bounds(const mbvh_scene* scene, float lower[3], float upper[3]) {
  static const char fn[] = "mbvh_scene_bounds";
  return guarded(fn, [&] {
    require(fn, scene, "scene");
    require(fn, lower, "lower");
    require(fn, upper, "upper");
    scene->scene.validate();  // bounds() reads the triangles' vertices through their indices
    const mbvh::Box b = scene->scene.bounds();
    copy3(b.lo, lower);
    copy3(b.hi, upper);
  });
}

void mbvh_scene_release(mbvh_scene* scene) { delete scene; }

// -- builds

mbvh_status mbvh_accel_build(const mbvh_scene* scene, const mbvh_build_options* options, mbvh_accel** accel) {
  static const char fn[] = "mbvh_accel_build";
  return guarded(fn, [&] {
    output(fn, accel, "accel");
    require(fn, scene, "scene");
    mbvh_build_options defaults;
    mbvh_build_options_init(&defaults);
    const mbvh_build_options& o = options ? *options : defaults;
    const mbvh::BuildOptions bo = to_build_options(fn, o);
    auto a = std::make_unique<mbvh_accel>();
    if (o.cache_dir)
      a->accel = mbvh::Accel::build_cached(scene->scene, bo, mbvh::Accel::CacheOptions{o.cache_dir, {}, o.cache_max_bytes},
                                           &a->cache);
    else
      a->accel = mbvh::Accel::build(scene->scene, bo);
    *accel = a.release();
  });
}

mbvh_status mbvh_accel_refit(mbvh_accel* accel, const mbvh_scene* scene) {
  static const char fn[] = "mbvh_accel_refit";
  return guarded(fn, [&] {
    require(fn, accel, "accel");
    require(fn, scene, "scene");
    accel->accel->refit(scene->scene);
  });
}

mbvh_status mbvh_accel_triangle_count(const mbvh_accel* accel, size_t* count) {
  static const char fn[] = "mbvh_accel_triangle_count";
  return guarded(fn, [&] {
    require(fn, accel, "accel");
    require(fn, count, "count");
    *count = accel->accel->scene_triangles();
  });
}

mbvh_status mbvh_accel_bounds(const mbvh_accel* accel, float lower[3], float upper[3]) {
  static const char fn[] = "mbvh_accel_bounds";
  return guarded(fn, [&] {
    require(fn, accel, "accel");
    require(fn, lower, "lower");
    require(fn, upper, "upper");
    copy3(accel->accel->bounds().lo, lower);
    copy3(accel->accel->bounds().hi, upper);
  });
}

mbvh_status mbvh_accel_geometry_of(const mbvh_accel* accel, uint32_t prim, uint32_t* geom_id, uint32_t* prim_in_geom) {
  static const char fn[] = "mbvh_accel_geometry_of";
  return guarded(fn, [&] {
    require(fn, accel, "accel");
    const mbvh::GeomPrim g = accel->accel->geometry_of(prim);
    if (geom_id) *geom_id = g.geom_id;
    if (prim_in_geom) *prim_in_geom = g.prim_id;
  });
}

mbvh_status mbvh_accel_cache_report(const mbvh_accel* accel, int* loaded, const char** path, const char** problem) {
  static const char fn[] = "mbvh_accel_cache_report";
  return guarded(fn, [&] {
    require(fn, accel, "accel");
    if (loaded) *loaded = accel->cache.loaded ? 1 : 0;
    if (path) *path = accel->cache.path.c_str();
    if (problem) *problem = accel->cache.problem.c_str();
  });
}

void mbvh_accel_release(mbvh_accel* accel) { delete accel; }

// -- backends

size_t mbvh_backend_count(void) {
  size_t n = 0;
  guarded("mbvh_backend_count", [&] { n = backend_names().size(); });
  return n;
}

const char* mbvh_backend_name(size_t index) {
  static const char fn[] = "mbvh_backend_name";
  const char* name = nullptr;
  guarded(fn, [&] {
    const std::vector<std::string>& names = backend_names();
    if (index >= names.size())
      invalid(fn, "index " + std::to_string(index) + " is past the last backend (mbvh_backend_count: " +
                      std::to_string(names.size()) + ")");
    name = names[index].c_str();
  });
  return name;
}

mbvh_status mbvh_backend_create(const char* name, unsigned threads, const char* const* settings, size_t setting_count,
                                mbvh_backend** backend) {
  static const char fn[] = "mbvh_backend_create";
  return guarded(fn, [&] {
    output(fn, backend, "backend");
    require(fn, name, "name");
    if (!settings && setting_count) invalid(fn, "settings is NULL with setting_count " + std::to_string(setting_count));
    mbvh::BackendOptions bo;
    bo.threads = threads;
    for (std::size_t i = 0; i < 2 * setting_count; i += 2) {
      if (!settings[i] || !settings[i + 1])
        invalid(fn, "settings[" + std::to_string(settings[i] ? i + 1 : i) + "] is NULL (settings are NAME, VALUE pairs)");
      bo.set(settings[i], settings[i + 1]);
    }
    backend_names();  // registers the backends
    auto h = std::make_unique<mbvh_backend>();
    try {
      h->backend = mbvh::make_backend(name, bo);
    } catch (const mbvh::Error& e) {
      if (!missing_hardware(name).empty()) throw MissingHardware(e.what());
      throw;
    }
    h->runs_as = h->backend->runs_as();
    h->description = h->backend->describe();
    *backend = h.release();
  });
}

mbvh_status mbvh_backend_describe(const mbvh_backend* backend, const char** description) {
  static const char fn[] = "mbvh_backend_describe";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    *output(fn, description, "description") = backend->description.c_str();
  });
}

mbvh_status mbvh_backend_runs_as(const mbvh_backend* backend, const char** name) {
  static const char fn[] = "mbvh_backend_runs_as";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    *output(fn, name, "name") = backend->runs_as.c_str();
  });
}

mbvh_status mbvh_backend_is_peer(const mbvh_backend* backend, int* peer) {
  static const char fn[] = "mbvh_backend_is_peer";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    require(fn, peer, "peer");
    *peer = backend->backend->peer() ? 1 : 0;
  });
}

mbvh_status mbvh_backend_supports(const mbvh_backend* backend, mbvh_layout layout, mbvh_traversal traversal,
                                  int* supported) {
  static const char fn[] = "mbvh_backend_supports";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    require(fn, supported, "supported");
    Variant v = to_variant(fn, read_enum(layout), read_enum(traversal));
    try {
      resolve(*backend->backend, v);  // DEFAULT: as a closest-hit mbvh_trace resolves it
    } catch (const mbvh::Error&) {
      *supported = 0;  // no pair fits: a layout on which the backend has no traversal
      return;
    }
    *supported = backend->backend->supports(v.opt.layout, v.opt.traversal) ? 1 : 0;
  });
}

mbvh_status mbvh_backend_resolve(const mbvh_backend* backend, mbvh_trace_options* options) {
  static const char fn[] = "mbvh_backend_resolve";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    require(fn, options, "options");
    Variant v = to_variant(fn, options);
    resolve(*backend->backend, v);
    mbvh_trace_options r = *options;
    r.layout = v.opt.layout == mbvh::Layout::mbvh2 ? MBVH_LAYOUT_MBVH2
               : v.opt.layout == mbvh::Layout::mbvh8 ? MBVH_LAYOUT_MBVH8 : MBVH_LAYOUT_MBVH4;
    r.traversal = static_cast<mbvh_traversal>(static_cast<int>(v.opt.traversal) + 1);
    r.leaf_block = backend->backend->leaf_block(v.opt);
    *options = r;
  });
}

void mbvh_backend_release(mbvh_backend* backend) { delete backend; }

// -- tracing

mbvh_status mbvh_trace(mbvh_backend* backend, const mbvh_accel* accel, const mbvh_ray* rays, size_t count,
                       const mbvh_trace_options* options, mbvh_hit* hits, uint8_t* occluded) {
  static const char fn[] = "mbvh_trace";
  return guarded(fn, [&] {
    require(fn, backend, "backend");
    require(fn, accel, "accel");
    Variant v = to_variant(fn, options);
    if (count == 0) return;
    require(fn, rays, "rays");
    const bool any = v.opt.query == mbvh::Query::any;
    if (any) require(fn, occluded, "occluded (any-hit query)");
    else require(fn, hits, "hits (closest-hit query)");
    resolve(*backend->backend, v);
    // in place: the caller's records are mbvh::Ray and mbvh::Hit byte for byte (the asserts above)
    const std::span<const mbvh::Ray> r(reinterpret_cast<const mbvh::Ray*>(rays), count);
    mbvh::check_ray_values(fn, r);
    if (any)
      mbvh::occluded(*backend->backend, *accel->accel, r, std::span<std::uint8_t>(occluded, count), v.opt);
    else
      mbvh::intersect(*backend->backend, *accel->accel, r, std::span<mbvh::Hit>(reinterpret_cast<mbvh::Hit*>(hits), count),
                      v.opt);
  });
}

}  // extern "C"

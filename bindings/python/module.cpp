// SPDX-License-Identifier: MIT
// module.cpp — mbvh._mbvh, the compiled part of the Python module `mbvh` (pybind11): scenes that
// view the caller's numpy arrays without a copy, builds, and traces on every backend of this build
// that return numpy arrays whose bytes are the program's .hits and occlusion records. The GIL is
// released while loading, building and tracing. The mesh helpers a trimesh or Open3D user expects
// are Python, in mbvh/__init__.py. Only the public headers: the bindings sit beside the program.
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>
#include <map>
#include <memory>
#include <mutex>
#include <shared_mutex>
#include <optional>
#include <string>
#include <vector>

#include <mbvh/backends.h>
#include <mbvh/mbvh.h>

namespace py = pybind11;

namespace {

using namespace mbvh;

// -- arrays in

std::string shape_of(const py::array& a) {
  std::string s = "(";
  for (py::ssize_t i = 0; i < a.ndim(); ++i) s += (i ? ", " : "") + std::to_string(a.shape(i));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

std::string dtype_of(const py::array& a) { return py::str(a.dtype()).cast<std::string>(); }

bool is_dtype(const py::array& a, char kind, py::ssize_t size) {
  return a.dtype().kind() == kind && a.dtype().itemsize() == size && a.dtype().byteorder() != '>';
}

// The array `o` as a numpy array (no copy of one already), or TypeError naming `what`.
py::array as_array(const py::handle& o, const char* what) {
  if (!py::isinstance<py::array>(o))
    throw py::type_error(std::string(what) + ": expected a numpy array, got " + py::str(py::type::of(o)).cast<std::string>());
  return py::reinterpret_borrow<py::array>(o);
}

// Rows of `cols` values of 4 bytes each, the values of a row adjacent (the row stride may be
// larger: an interleaved record). Checks the dtype (float32, or uint32 / int32 for indices) and
// the shape; TypeError / ValueError name `what` and say how to get such an array.
void check_rows(const py::array& a, const char* what, std::size_t cols, bool indices) {
  const bool dtype_ok = indices ? (is_dtype(a, 'u', 4) || is_dtype(a, 'i', 4)) : is_dtype(a, 'f', 4);
  const char* want = indices ? "uint32 (or int32)" : "float32";
  const char* np_type = indices ? "np.uint32" : "np.float32";
  if (!dtype_ok)
    throw py::type_error(std::string(what) + ": expected dtype " + want + ", got " + dtype_of(a) +
                         " (no conversion is made silently: pass np.ascontiguousarray(" + what + ", dtype=" + np_type +
                         ")" + (std::strcmp(what, "rays") ? ", or copy=True" : "") + ")");
  if (a.ndim() != 2 || a.shape(1) != static_cast<py::ssize_t>(cols))
    throw py::value_error(std::string(what) + ": expected shape (N, " + std::to_string(cols) + "), got " + shape_of(a));
  if (a.shape(0) > 0 && (a.strides(1) != 4 || a.strides(0) < static_cast<py::ssize_t>(4 * cols)))
    throw py::value_error(std::string(what) + ": the array is not contiguous (strides " + std::to_string(a.strides(0)) +
                          ", " + std::to_string(a.strides(1)) + " bytes; each row's " + std::to_string(cols) +
                          " values must be adjacent): pass np.ascontiguousarray(" + what + ")");
}

// The rays of an (N, 8) float32 C-contiguous array (the project's 32-byte ray record: origin,
// tmin, direction, tmax), read in place: no copy. Their values are checked by check_values.
std::span<const Ray> rays_of(const py::array& a) {
  check_rows(a, "rays", 8, false);
  if (a.shape(0) > 0 && a.strides(0) != 32)
    throw py::value_error("rays: the array is not C-contiguous (row stride " + std::to_string(a.strides(0)) +
                          " bytes, a ray record is 32): pass np.ascontiguousarray(rays)");
  return {static_cast<const Ray*>(a.data()), static_cast<std::size_t>(a.shape(0))};
}

// NaN or infinite values (tmax = +inf excepted) are a ValueError naming the ray. Called with the
// GIL released, on the call's threads (a pass over the rays).
void check_values(std::span<const Ray> rays, unsigned threads) {
  try {
    check_ray_values("rays", rays, nullptr, threads);
  } catch (const Error& e) {
    throw py::value_error(e.what());
  }
}

// -- arrays out: a vector's storage handed to numpy (no copy of the results)

template <class T>
py::array give_to_numpy(std::vector<T>&& v, std::vector<py::ssize_t> shape) {
  auto* owner = new std::vector<T>(std::move(v));
  py::capsule base(owner, [](void* p) { delete static_cast<std::vector<T>*>(p); });
  return py::array_t<T>(shape, owner->data(), base);
}

// -- scenes

struct PyScene {
  Scene scene;
  py::object vertices, triangles;  ///< the caller's arrays a view reads (kept alive with the scene)

  std::size_t vertex_count() const {
    return scene.meshes().empty() ? scene.vertices.size() : scene.meshes()[0].vertex_count;
  }
};

py::array converted(const py::handle& o, const char* dtype) {
  return py::module_::import("numpy").attr("ascontiguousarray")(o, dtype);
}

std::unique_ptr<PyScene> scene_from_arrays(const py::object& v_in, const py::object& t_in, bool copy) {
  auto s = std::make_unique<PyScene>();
  py::array v, t;
  if (copy) {
    v = converted(v_in, "float32");
    const py::array t_any = converted(t_in, nullptr);
    if (t_any.dtype().kind() == 'i' || t_any.dtype().kind() == 'u') {
      py::module_ np = py::module_::import("numpy");
      if (t_any.size() > 0 && (np.attr("min")(t_any).cast<double>() < 0 || np.attr("max")(t_any).cast<double>() > 4294967295.0))
        throw py::value_error("triangles: a vertex index is negative or above 2^32 - 1");
    } else if (t_any.size() > 0) {
      throw py::type_error("triangles: expected integer vertex indices, got dtype " + dtype_of(t_any));
    }
    t = converted(t_any, "uint32");
  } else {
    v = as_array(v_in, "vertices");
    t = as_array(t_in, "triangles");
  }
  check_rows(v, "vertices", 3, false);
  check_rows(t, "triangles", 3, true);
  MeshView m;
  m.vertices = static_cast<const float*>(v.data());
  m.vertex_count = static_cast<std::size_t>(v.shape(0));
  m.vertex_stride = static_cast<std::size_t>(v.shape(0) ? v.strides(0) : 12);
  m.indices = static_cast<const std::uint32_t*>(t.data());
  m.triangle_count = static_cast<std::size_t>(t.shape(0));
  m.index_stride = static_cast<std::size_t>(t.shape(0) ? t.strides(0) : 12);
  s->scene.name = "numpy arrays";
  s->scene.add_mesh(m);
  s->scene.validate();
  s->vertices = v;
  s->triangles = t;
  return s;
}

std::unique_ptr<PyScene> load(const std::string& path) {
  auto s = std::make_unique<PyScene>();
  py::gil_scoped_release nogil;
  s->scene = load_scene(path);
  return s;
}

// An owned scene's vertices or triangles as an (N, 3) numpy view that keeps the scene alive.
py::array owned_view(const py::object& self, std::vector<Vec3f>& v) {
  return py::array_t<float>({static_cast<py::ssize_t>(v.size()), py::ssize_t(3)}, v.empty() ? nullptr : &v[0].x, self);
}
py::array owned_view(const py::object& self, std::vector<std::array<std::uint32_t, 3>>& t) {
  return py::array_t<std::uint32_t>({static_cast<py::ssize_t>(t.size()), py::ssize_t(3)}, t.empty() ? nullptr : t[0].data(), self);
}

// -- builds and traces

struct PyAccel {
  std::unique_ptr<Accel> acc;
  py::object scene;  ///< the PyScene it was built from (refit, the mesh helpers)
  std::mutex mutex;  ///< guards `backends` (the backends themselves serialise their calls)
  /// Traces share the build, refit changes it (Accel::refit: no trace may run meanwhile); taken
  /// with the GIL released, so a thread waiting for it never blocks the interpreter.
  std::shared_mutex use;
  std::map<std::string, std::unique_ptr<Backend>> backends;

  // The backend `name` with these threads and settings, made on first use and kept: a device
  // backend's set-up and upload are paid once per build, not per call.
  Backend& backend(const std::string& name, unsigned threads, const std::map<std::string, std::string>& settings) {
    std::string key = name + '\n' + std::to_string(threads);
    for (const auto& [k, v] : settings) key += '\n' + k + '=' + v;
    std::lock_guard<std::mutex> lock(mutex);
    auto it = backends.find(key);
    if (it == backends.end()) {
      BackendOptions o;
      o.threads = threads;
      o.settings = settings;
      it = backends.emplace(key, make_backend(name, o)).first;
    }
    return *it->second;
  }
};

struct Variant {
  std::string backend = "cpu";
  std::string query = "closest";
  unsigned threads = 0;
  std::optional<std::string> layout, traversal;
  std::string precision = "robust";
  std::map<std::string, std::string> settings;
  bool stats = false;
};

// The backend and options of a call; layout and traversal default as `mbvh trace` does (the
// backend's fastest, resolve_options), so the answers are the program's byte for byte.
std::pair<Backend*, TraceOptions> resolve(PyAccel& a, const Variant& v) {
  Backend& b = a.backend(v.backend, v.threads, v.settings);
  TraceOptions o;
  o.query = parse_query(v.query);
  o.precision = parse_precision(v.precision);
  o.stats = v.stats;
  if (v.traversal) o.traversal = parse_traversal(*v.traversal);
  if (v.layout) o.layout = parse_layout(*v.layout);
  return {&b, resolve_options(b, o)};
}

py::object results(TraceOutput&& out, const TraceOptions& o) {
  const auto n = static_cast<py::ssize_t>(o.query == Query::any ? out.occluded.size() : out.hits.size());
  py::array r = o.query == Query::any ? give_to_numpy(std::move(out.occluded), {n}) : give_to_numpy(std::move(out.hits), {n});
  if (!o.stats) return r;
  return py::make_tuple(r, give_to_numpy(std::move(out.stats), {n}));
}

py::object trace(PyAccel& a, const py::handle& rays_in, const Variant& v) {
  const std::span<const Ray> rays = rays_of(as_array(rays_in, "rays"));
  auto [b, o] = resolve(a, v);
  TraceOutput out;
  {
    py::gil_scoped_release nogil;
    std::shared_lock<std::shared_mutex> lock(a.use);
    b->trace(*a.acc, rays, o, out);
    // Every ray check_values refuses (a NaN or an infinity) is one every backend traces as an
    // invalid ray (a defined miss, counted): only a batch with invalid rays needs the pass that
    // tells a NaN from a degenerate ray (a zero direction, tmin > tmax), which is not an error.
    if (out.invalid > 0) check_values(rays, v.threads);
  }
  return results(std::move(out), o);
}

py::dict bench(PyAccel& a, const py::handle& rays_in, const Variant& v, unsigned repeat) {
  const std::span<const Ray> rays = rays_of(as_array(rays_in, "rays"));
  auto [b, o] = resolve(a, v);
  std::vector<double> seconds;
  {
    py::gil_scoped_release nogil;
    check_values(rays, v.threads);
    std::shared_lock<std::shared_mutex> lock(a.use);
    b->prepare(*a.acc, o);
    {
      TraceOutput warm;
      b->trace(*a.acc, rays, o, warm);  // warm: caches, the workers, a device's pipeline
    }
    for (unsigned i = 0; i < std::max(1u, repeat); ++i) {
      TraceOutput out;  // fresh, as a trace() caller's: its first touch is part of the time
      const auto t0 = std::chrono::steady_clock::now();
      b->trace(*a.acc, rays, o, out);
      seconds.push_back(std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count());
    }
  }
  std::vector<double> sorted = seconds;
  std::sort(sorted.begin(), sorted.end());
  const double median = sorted.size() % 2 ? sorted[sorted.size() / 2]
                                          : 0.5 * (sorted[sorted.size() / 2 - 1] + sorted[sorted.size() / 2]);
  py::dict d;
  d["backend"] = v.backend;
  d["runs_as"] = b->runs_as();
  d["describe"] = b->describe();
  d["layout"] = layout_label(o);
  d["traversal"] = to_string(o.traversal);
  d["query"] = to_string(o.query);
  d["rays"] = rays.size();
  d["seconds"] = seconds;
  d["median_seconds"] = median;
  d["mrays_per_s"] = median > 0 ? double(rays.size()) / median * 1e-6 : 0.0;
  return d;
}

py::dict comparison(const Comparison& c) {
  py::dict d;
  d["rays"] = c.rays;
  d["bit_identical"] = c.bit_identical;
  d["equal"] = c.equal;
  d["ties"] = c.ties;
  d["mismatches"] = c.mismatches;
  d["first_mismatches"] = c.first_mismatches;
  return d;
}

// Each backend's answers against the reference traversal (cpu-scalar) of the same options, ray by
// ray, differences classified by mbvh/compare.h's tie rules as `mbvh check` does; `brute` rays
// of the reference also against the double-precision brute force.
py::list check(PyAccel& a, const py::handle& rays_in, std::optional<std::vector<std::string>> names, const Variant& v,
               std::size_t brute) {
  const std::span<const Ray> rays = rays_of(as_array(rays_in, "rays"));
  {
    py::gil_scoped_release nogil;
    check_values(rays, v.threads);
  }
  const std::vector<std::string> list = names ? *names : runnable_backends();
  py::list report;
  for (const std::string& name : list) {
    Variant vb = v;
    vb.backend = name;
    auto [b, o] = resolve(a, vb);
    py::dict d;
    {
      py::gil_scoped_release nogil;
      std::shared_lock<std::shared_mutex> lock(a.use);
      TraceOutput out, ref, ref_closest;
      b->trace(*a.acc, rays, o, out);
      TraceOptions ro = with_leaves_of(*b, o);
      trace_reference(*a.acc, rays, ro, ref, v.threads);
      Comparison c;
      if (o.query == Query::closest) {
        c = compare_hit_arrays(out.hits, ref.hits);
      } else {
        ro.query = Query::closest;
        trace_reference(*a.acc, rays, ro, ref_closest, v.threads);
        c = compare_occlusion_arrays(out.occluded, ref.occluded, ref_closest.hits, rays);
      }
      py::gil_scoped_acquire gil;
      d = comparison(c);
    }
    d["backend"] = name;
    d["runs_as"] = b->runs_as();
    d["traversal"] = to_string(o.traversal);
    d["layout"] = layout_label(o);
    report.append(d);
  }
  if (brute > 0) {
    const std::size_t n = std::min(brute, rays.size());
    TraceOptions ro;
    ro.query = Query::closest;
    ro.traversal = Traversal::stack;
    std::vector<Hit> oracle(n);
    TraceOutput ref;
    {
      py::gil_scoped_release nogil;
      std::shared_lock<std::shared_mutex> lock(a.use);
      trace_reference(*a.acc, rays.first(n), ro, ref, v.threads);
      for (std::size_t i = 0; i < n; ++i) oracle[i] = brute_force(*a.acc, rays[i]);
    }
    py::dict d = comparison(compare_hit_arrays(ref.hits, oracle));
    d["backend"] = "cpu-scalar vs brute force (double)";
    d["runs_as"] = "cpu-scalar";
    d["traversal"] = to_string(ro.traversal);
    d["layout"] = to_string(ro.layout);
    report.append(d);
  }
  return report;
}

std::unique_ptr<PyAccel> build(const py::object& scene_obj, const std::string& quality, unsigned threads,
                               std::optional<std::string> cache_dir, unsigned max_leaf, unsigned bins) {
  PyScene& s = scene_obj.cast<PyScene&>();
  BuildOptions o;
  o.quality = parse_quality(quality);
  o.threads = threads;
  o.max_leaf = max_leaf;
  o.bins = bins;
  auto a = std::make_unique<PyAccel>();
  {
    py::gil_scoped_release nogil;
    a->acc = cache_dir ? Accel::build_cached(s.scene, o, *cache_dir) : Accel::build(s.scene, o);
  }
  a->scene = scene_obj;
  return a;
}

// mbvh.set_log: the library's messages to a Python callable. The callable is held by a shared_ptr
// whose last owner may be a thread without the GIL (a copy the library took while logging), so
// its deleter takes the GIL; the old callback is swapped out with the GIL released (a thread
// logging may wait for the GIL while the library's log lock is free: mbvh/log.h) and dropped
// with it held.
void set_log(const py::object& fn) {
  LogCallback cb;
  if (!fn.is_none()) {
    if (!PyCallable_Check(fn.ptr())) throw py::type_error("set_log: expected a callable or None");
    std::shared_ptr<py::object> held(new py::object(fn), [](py::object* p) {
      py::gil_scoped_acquire gil;
      delete p;
    });
    cb = [held](LogLevel level, const std::string& message) {
      py::gil_scoped_acquire gil;
      try {
        (*held)(to_string(level), message);
      } catch (py::error_already_set& e) {
        e.discard_as_unraisable("mbvh log callback");
      }
    };
  }
  LogCallback old;
  {
    py::gil_scoped_release nogil;
    old = set_log_callback(std::move(cb));
  }
}

const char* const kTraceDoc = R"(Traces rays, an (N, 8) float32 C-contiguous array of the project's ray records
(origin x y z, tmin, direction x y z, tmax; a .rays file's bytes), read in place without a copy.
query="closest" returns a structured array of dtype HIT_DTYPE (t, u, v, prim; 16 bytes a ray,
a .hits file's bytes; a miss has prim = MISS and t = inf); query="any" returns a uint8 array
(1: occluded), an occlusion file's bytes. With stats=True, a tuple (answers, per-ray counters).
backend: a name of backends(); threads: CPU workers (0: every core); layout and traversal default
as `mbvh trace` does: the backend's fastest exact traversal for the query ("auto"; e.g. cpu: MBVH8
ordered stack for closest hit, MBVH8 octant stack for any hit). The GIL is released while tracing.)";

}  // namespace

PYBIND11_MODULE(_mbvh, m) {
  m.doc() = "mbvh: exact BVH ray tracing on CPU SIMD, OpenCL and Vulkan (compiled part; import mbvh)";
  PYBIND11_NUMPY_DTYPE(mbvh::Hit, t, u, v, prim);
  PYBIND11_NUMPY_DTYPE(mbvh::RayStats, nodes, box_tests, leaves, tris, climbs, retests, max_depth, lane_ops, group_ops);
  register_builtin_backends();
  static py::exception<Error> error(m, "Error", PyExc_RuntimeError);
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const Error& e) {
      error(e.what());
    } catch (const std::bad_alloc&) {
      PyErr_SetString(PyExc_MemoryError, "mbvh: out of memory");
    }
  });
  m.attr("__version__") = version();
  m.attr("MISS") = py::int_(MBVH_MISS_PRIM);
  m.attr("HIT_DTYPE") = py::dtype::of<Hit>();
  m.attr("STATS_DTYPE") = py::dtype::of<RayStats>();

  m.def("set_log", &set_log, py::arg("callback"),
        "Where the library's messages go (the device a backend chose): callback(level, message) with level \"debug\",\n"
        "\"info\" or \"warning\", called from any thread with the GIL taken; None (the default) drops them. The\n"
        "library never writes to standard output or error.");
  // at exit, the callback goes before the interpreter does
  py::module_::import("atexit").attr("register")(py::cpp_function([] { set_log(py::none()); }));
  m.def("backends", [](bool runnable) {
    if (runnable) return runnable_backends();
    std::vector<std::string> names;
    for (const BackendInfo& b : list_backends())
      if (b.make) names.push_back(b.name);
    return names;
  }, py::arg("runnable") = false,
  "The backends of this build by name (runnable=True: only those that can start on this machine, each once).");

  py::class_<PyScene>(m, "Scene", "A triangle mesh: vertices (N, 3) float32 and triangles (M, 3) uint32.")
      .def(py::init(&scene_from_arrays), py::arg("vertices"), py::arg("triangles"), py::kw_only(), py::arg("copy") = false,
           "A scene viewing the caller's arrays: vertices (N, 3) float32, triangles (M, 3) uint32 (or int32) vertex\n"
           "indices, each row's values adjacent (a row stride above 12 bytes is fine). No copy is made and the\n"
           "scene keeps the arrays alive; a build reads them (refit after changing vertices in place). Another\n"
           "dtype or layout is a TypeError / ValueError unless copy=True, which converts (copies) them.")
      .def_property_readonly("vertices", [](py::object self) -> py::object {
        PyScene& s = self.cast<PyScene&>();
        return s.vertices ? s.vertices : owned_view(self, s.scene.vertices);
      }, "The vertices, (N, 3) float32 (the caller's array for a scene of arrays).")
      .def_property_readonly("triangles", [](py::object self) -> py::object {
        PyScene& s = self.cast<PyScene&>();
        return s.triangles ? s.triangles : owned_view(self, s.scene.triangles);
      }, "The triangles' vertex indices, (M, 3) uint32.")
      .def_property_readonly("triangle_count", [](const PyScene& s) { return s.scene.triangle_count(); })
      .def_property_readonly("vertex_count", &PyScene::vertex_count)
      .def_property_readonly("name", [](const PyScene& s) { return s.scene.display_name(); })
      .def_property_readonly("bounds", [](const PyScene& s) {
        const Box b = s.scene.bounds();
        return py::make_tuple(py::make_tuple(b.lo.x, b.lo.y, b.lo.z), py::make_tuple(b.hi.x, b.hi.y, b.hi.z));
      }, "((xmin, ymin, zmin), (xmax, ymax, zmax)) of the vertices triangles use.")
      .def("hash", [](const PyScene& s) { return s.scene.hash(); }, "The scene's 64-bit content hash (the cache key's part).")
      .def("_mesh_addresses", [](const PyScene& s) {
        if (s.scene.meshes().empty()) return py::make_tuple(0, 0);
        const MeshView& v = s.scene.meshes()[0];
        return py::make_tuple(reinterpret_cast<std::uintptr_t>(v.vertices), reinterpret_cast<std::uintptr_t>(v.indices));
      }, "The addresses the scene's view reads (tests: no copy was made).")
      .def("__repr__", [](const PyScene& s) {
        return "<mbvh.Scene '" + s.scene.display_name() + "': " + std::to_string(s.scene.triangle_count()) + " triangles>";
      });

  m.def("load", &load, py::arg("path"),
        "Loads a scene: .obj or .ply, optionally zstd-compressed (.obj.zst), or a generator spec (\"gen:sphere:64\").");

  py::class_<PyAccel>(m, "_Accel")
      .def_property_readonly("scene", [](const PyAccel& a) { return a.scene; })
      .def_property_readonly("triangle_count", [](const PyAccel& a) { return a.acc->scene_triangles(); })
      .def_property_readonly("degenerate_triangles", [](const PyAccel& a) { return a.acc->degenerate_triangles(); })
      .def_property_readonly("quality", [](const PyAccel& a) { return std::string(to_string(a.acc->options().quality)); })
      .def_property_readonly("has_hierarchy", [](const PyAccel& a) { return a.acc->has_hierarchy(); })
      .def("hash", [](const PyAccel& a) { return a.acc->hash(); })
      .def("refit", [](PyAccel& a) {
        PyScene& s = a.scene.cast<PyScene&>();
        py::gil_scoped_release nogil;
        std::unique_lock<std::shared_mutex> lock(a.use);
        a.acc->refit(s.scene);
      }, "Refits the build to its scene's vertices after they were changed in place (waits for traces to finish).")
      .def("trace", [](PyAccel& a, const py::handle& rays, const std::string& backend, const std::string& query,
                       unsigned threads, std::optional<std::string> layout, std::optional<std::string> traversal,
                       const std::string& precision, std::map<std::string, std::string> settings, bool stats) {
        return trace(a, rays, {backend, query, threads, layout, traversal, precision, std::move(settings), stats});
      }, py::arg("rays"), py::arg("backend") = "cpu", py::arg("query") = "closest", py::arg("threads") = 0,
         py::arg("layout") = py::none(), py::arg("traversal") = py::none(), py::arg("precision") = "robust",
         py::arg("settings") = std::map<std::string, std::string>{}, py::arg("stats") = false, kTraceDoc)
      .def("bench", [](PyAccel& a, const py::handle& rays, const std::string& backend, const std::string& query,
                       unsigned threads, std::optional<std::string> layout, std::optional<std::string> traversal,
                       const std::string& precision, std::map<std::string, std::string> settings, unsigned repeat) {
        return bench(a, rays, {backend, query, threads, layout, traversal, precision, std::move(settings), false}, repeat);
      }, py::arg("rays"), py::arg("backend") = "cpu", py::arg("query") = "closest", py::arg("threads") = 0,
         py::arg("layout") = py::none(), py::arg("traversal") = py::none(), py::arg("precision") = "robust",
         py::arg("settings") = std::map<std::string, std::string>{}, py::arg("repeat") = 5)
      .def("check", [](PyAccel& a, const py::handle& rays, std::optional<std::vector<std::string>> backends,
                       const std::string& query, unsigned threads, std::optional<std::string> layout,
                       std::optional<std::string> traversal, const std::string& precision,
                       std::map<std::string, std::string> settings, std::size_t brute) {
        return check(a, rays, backends, {"", query, threads, layout, traversal, precision, std::move(settings), false}, brute);
      }, py::arg("rays"), py::arg("backends") = py::none(), py::arg("query") = "closest", py::arg("threads") = 0,
         py::arg("layout") = py::none(), py::arg("traversal") = py::none(), py::arg("precision") = "robust",
         py::arg("settings") = std::map<std::string, std::string>{}, py::arg("brute") = 0)
      .def("_ray_address", [](const PyAccel&, const py::handle& rays) {
        return reinterpret_cast<std::uintptr_t>(rays_of(as_array(rays, "rays")).data());
      }, "The address trace() reads the rays from (tests: no copy is made).");

  m.def("_build", &build, py::arg("scene"), py::arg("quality") = "medium", py::arg("threads") = 0,
        py::arg("cache_dir") = py::none(), py::arg("max_leaf") = 8, py::arg("bins") = 32);
}

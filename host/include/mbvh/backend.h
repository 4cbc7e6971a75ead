// SPDX-License-Identifier: MIT
// backend.h — the one interface every tracing backend implements (cpu-scalar, cpu, opencl,
// vulkan, embree) and the registry that makes them by name. The core includes no backend: a
// program registers the backends it links (mbvh/backends.h).
#pragma once
#include <cstddef>
#include <functional>
#include <cmath>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/trace.h"

namespace mbvh {

/// What every backend takes, plus the settings of one backend by name. Settings belong to their
/// backend: each declares its own (BackendInfo::settings, listed by `mbvh devices`), named
/// FAMILY.NAME after the backend family (the registry name up to its first '-'):
///   opencl.device, opencl.mapping                  (opencl, opencl-wide, opencl-lane)
///   vulkan.device, vulkan.validation, vulkan.staging, vulkan.max-binding-bytes   (vulkan)
///   embree.quality                                 (the embree peer)
/// One BackendOptions may carry the settings of several families (make_backend gives each
/// backend its own); make_backend refuses a name of an unknown family, or one its own family
/// does not declare, naming the known ones.
struct BackendOptions {
  unsigned threads = 0;  ///< CPU workers (0 = every hardware thread)
  std::map<std::string, std::string> settings;  ///< FAMILY.NAME -> value (see above)

  /// Sets a setting (chainable): BackendOptions{}.set("opencl.device", "1:0").
  BackendOptions& set(const std::string& name, const std::string& value) {
    settings[name] = value;
    return *this;
  }
  /// The value of a setting, or `fallback` when it is not set.
  std::string get(const std::string& name, const std::string& fallback = "") const;
  /// A boolean setting: "1", "true", "on", "yes" or "0", "false", "off", "no"; `fallback` when
  /// not set. Throws Error naming the setting on any other value.
  bool get_flag(const std::string& name, bool fallback = false) const;
  /// A byte count or other unsigned setting (decimal); `fallback` when not set. Throws Error
  /// naming the setting on anything else.
  std::size_t get_size(const std::string& name, std::size_t fallback = 0) const;
};

/// One setting a backend declares: its full name (FAMILY.NAME) and what it does, for help texts.
struct BackendSetting {
  std::string name;
  std::string help;
};

/// What a backend's single-ray query runs (Backend::ray_query_kernels): one function per query,
/// and the state they read, made once. The functions may be called from any number of threads at
/// once: they read `state` (and the Accel it points into) only.
struct RayQueryKernels {
  Hit (*closest)(const void* state, const Ray& ray) = nullptr;
  bool (*any)(const void* state, const Ray& ray) = nullptr;
  std::shared_ptr<const void> state;
};

/// A prepared, immutable single-ray query: one closest-hit or any-hit ray per call from the
/// caller's own threads, with no lock, no allocation and no set-up per call (Backend::ray_query
/// makes it, once). Each call is one range check (a few compares; see below) and one call through
/// a function pointer into the backend's kernel, which reads the Accel's layout and leaves, resolved
/// when the query was made. Any number of threads may call one query (or several queries on one
/// Accel) at once; copies share the prepared state.
///
///   auto cpu = mbvh::make_backend("cpu");
///   const mbvh::RayQuery q = cpu->ray_query(*accel);  // once: resolves the layout, leaves, ISA kernels
///   mbvh::Hit h = q.intersect(ray);                   // from any thread, any number at once
///   bool blocked = q.occluded(shadow_ray);
///
/// Answers: intersect() gives, bit for bit, the Hit that Backend::trace of that backend writes for
/// the ray with options(Query::closest), occluded() the flag it writes with options(Query::any).
/// An invalid ray (ray_valid false) is a defined miss (not occluded). A ray outside the range traced
/// exactly (check_ray_range) throws Error naming it, as Backend::trace does: the call tests the ray
/// against bounds precomputed from the scene's largest coordinate S (about ten operations: origin
/// components within max(S, min(2^16 S, 2^41)) and the direction's largest component within the
/// band that allows), and only a ray that fails that quick test takes the full check_ray_range.
///
/// Lifetime: the query points into the Accel (its layout, leaves and triangles): the Accel must
/// outlive it and must not be refit while it is used (refit drops the leaf variants the query
/// reads): make a new query after a refit. The Backend object may go; the query does not use it.
class RayQuery {
public:
  RayQuery() = default;  ///< empty: intersect and occluded throw Error (valid() is false)
  /// The ray's closest hit (a miss: prim MBVH_MISS_PRIM, t = +inf).
  Hit intersect(const Ray& ray) const {
    check(ray);
    return closest_(state_, ray);
  }
  /// Whether some triangle lies in [tmin, tmax] along the ray.
  bool occluded(const Ray& ray) const {
    check(ray);
    return any_(state_, ray);
  }
  /// The options whose Backend::trace output the query's answers equal, bit for bit: layout,
  /// traversal, precision and the leaf block resolved (with_leaves_of), query `q`.
  const TraceOptions& options(Query q) const { return q == Query::any ? any_opt_ : closest_opt_; }
  /// The backend that made it (its runs_as() name, e.g. "cpu-avx512").
  const std::string& backend() const { return who_; }
  bool valid() const { return closest_ != nullptr; }

private:
  friend class Backend;
  /// The quick range test: true for a ray surely inside the exactly traced range (or with a NaN,
  /// which the kernel answers as an invalid ray: a defined miss).
  void check(const Ray& r) const {
    const auto mx = [](float a, float b) { return a > b ? a : b; };  // a NaN may go either way: see above
    const float mo = mx(mx(std::fabs(r.ox), std::fabs(r.oy)), std::fabs(r.oz));
    const float d = mx(mx(std::fabs(r.dx), std::fabs(r.dy)), std::fabs(r.dz));
    if (!(mo <= o_max_ && d >= d_lo_ && d <= d_hi_)) [[unlikely]]
      check_slow(r);
  }
  /// The full check_ray_range of one ray (throws Error for a ray out of range); throws Error for
  /// an empty query. No allocation unless it throws.
  void check_slow(const Ray& r) const;

  Hit (*closest_)(const void*, const Ray&) = nullptr;
  bool (*any_)(const void*, const Ray&) = nullptr;
  const void* state_ = nullptr;
  float o_max_ = -1, d_lo_ = INFINITY, d_hi_ = -INFINITY;  // empty: every ray takes check_slow
  const Accel* accel_ = nullptr;
  std::shared_ptr<const void> keep_;  ///< owns state_
  TraceOptions closest_opt_, any_opt_;
  std::string who_;        ///< backend()
  std::string who_check_;  ///< check_slow's name for check_ray_range, made once
};

class Backend {
public:
  virtual ~Backend() = default;
  /// Registry name, e.g. "cpu-scalar".
  virtual std::string name() const = 0;
  /// One line: ISA, device and driver strings, for logs and benchmark records.
  virtual std::string describe() const = 0;
  /// Whether this backend implements the layout / traversal pair.
  virtual bool supports(Layout layout, Traversal traversal) const = 0;
  /// Whether this backend implements the accuracy mode (TraceOptions::precision); mbvh's own
  /// backends implement all three, a peer library only its own robust queries.
  virtual bool supports_precision(Precision p) const { return p == Precision::robust; }
  /// Makes the backend ready to trace `acc` with these options (uploads only the layout needed;
  /// repeated calls with the same build are free). Called by trace() if not done before.
  /// Checks `opt` first (check_trace_options, naming this backend), and refuses a build without a
  /// hierarchy (BuildQuality::none) unless the backend's BackendInfo::needs_hierarchy is false.
  void prepare(const Accel& acc, const TraceOptions& opt);
  /// Traces `rays`, filling `out` in ray order (TraceOutput). Throws Error on failure. First, for
  /// every backend alike: checks `opt` (check_trace_options), refuses a layout / traversal pair
  /// or a precision the backend lacks (supports, supports_precision), a build without a hierarchy
  /// when the backend needs one (as prepare) and a ray outside the exactly
  /// traced range (check_ray_range), each Error naming this backend; then prepares (prepare) and
  /// sizes `out`; an empty batch ends there. One backend object may be used from several threads:
  /// its prepare and trace calls take the object's lock, so they run one at a time (a CPU backend
  /// still spreads each call over its workers); for calls that overlap, use one backend object
  /// per thread.
  void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out);
  /// A single-ray query on `acc` (RayQuery): made once, then called from any number of the
  /// caller's threads with no lock and no allocation. `opt`'s layout, traversal, precision and leaf
  /// block are traced for both queries (its query field is ignored). Without `opt`: the fastest exact
  /// single-ray traversals of this path, default_ray_query_options (closest hit: MBVH8 ordered
  /// stack; any hit: MBVH8 bitstack). Checks as trace does (options, supports, precision, a build
  /// without a hierarchy), then refuses, naming this backend: statistics (`opt.stats`: the query
  /// counts nothing; trace a batch for them), a packet traversal and dacrt (they trace batches of
  /// rays; their single-ray answers are packet_single_ray's traversal: ask for that), and a backend
  /// without a single-ray path (only the SIMD cpu backends have one: cpu, cpu-avx2, cpu-avx512).
  /// Prepares the build as trace does (the layout, the leaves' packs; kept by the Accel). Cost:
  /// prepare's once, then O(1).
  RayQuery ray_query(const Accel& acc, const TraceOptions& opt);
  RayQuery ray_query(const Accel& acc);
  /// The instruction set the traversal runs on a CPU backend ("scalar", "avx2", "avx512"); ""
  /// for a device backend or a library that picks its own (the device line says more).
  virtual std::string isa() const { return ""; }
  /// The registered backend this one runs as here: its own name, or for an alias (`cpu`,
  /// `opencl`) the backend it stands for on this machine and device (`cpu-avx512`, `opencl-lane`).
  virtual std::string runs_as() const { return name(); }
  /// A peer library (embree): its own BVH and triangle test, so its answers agree with
  /// cpu-scalar's up to classified ties (not bit for bit), and it has no per-ray counters.
  virtual bool peer() const { return false; }
  /// Device time of the last trace() call: the summed execution time of its trace kernels'
  /// dispatches (every batch), in seconds, by the device's own clock (OpenCL event profiling,
  /// Vulkan timestamps); excludes ray uploads, hit downloads and host copies. Negative when the
  /// backend does not measure it (CPU backends, a device without timestamps) or has not traced.
  double last_device_seconds() const { return device_seconds_; }
  /// The leaf block (TraceOptions::leaf_block) this backend traces for `opt`: opt.leaf_block where
  /// it has leaf variants and it is set, else its own choice; a backend without variants traces
  /// the build's own leaves (1) whatever is asked. Compare a backend with the reference at this
  /// value (with_leaves_of).
  virtual unsigned leaf_block(const TraceOptions&) const { return 1; }
  /// The layout / traversal pairs this backend traces, fastest first for query `q`, measured per
  /// backend and ISA (docs/library.md, "Defaults"): what Layout::automatic and Traversal::automatic
  /// resolve to (resolve_options takes the first pair that fits what the options fix). Exact
  /// traversals only, no packet traversal (they pay off on coherent batches alone: ask for them).
  /// The default: the SIMD cpu backends' order (MBVH8 ordered stack for closest hit, MBVH8 bitstack
  /// for any hit, then the rest), of which resolve_options skips the pairs this backend lacks.
  virtual std::vector<std::pair<Layout, Traversal>> fastest(Query q) const;
  /// Bytes of traversal state per ray for these options (TRAVERSAL.md §5).
  virtual std::size_t state_bytes(const TraceOptions& opt) const { return state_bytes_per_ray(opt.layout, opt.traversal); }

protected:
  /// What prepare() does, with `opt` checked and the object's lock held.
  virtual void do_prepare(const Accel& acc, const TraceOptions& opt) = 0;
  /// What trace() does after its common part: traces a non-empty batch, with `opt` checked and
  /// supported, its leaf_block the one this backend traces (with_leaves_of), the build prepared
  /// (do_prepare), `out` sized for `rays` (TraceOutput::resize_for: contents unspecified; a
  /// backend that does not write every ray's answer resets it) and the object's lock held (so
  /// never prepare or trace from here: the lock is not recursive).
  virtual void trace_batch(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) = 0;
  /// The kernels of a single-ray query tracing `closest` and `any` (checked, supported, leaf block
  /// resolved, the build prepared for both): what ray_query wraps. Called without the object's
  /// lock. The default throws Error: this backend has no single-ray path.
  virtual RayQueryKernels ray_query_kernels(const Accel& acc, const TraceOptions& closest, const TraceOptions& any);
  /// Sets last_device_seconds() for the trace in progress (trace() clears it to -1 first).
  void set_device_seconds(double s) { device_seconds_ = s; }

private:
  /// ray_query's checks of one query's options, each Error naming this backend.
  void check_ray_query_options(const Accel& acc, const TraceOptions& opt);
  /// ray_query with `closest` and `any` (their query fields set here).
  RayQuery make_ray_query(const Accel& acc, TraceOptions closest, TraceOptions any);
  std::mutex mutex_;  ///< serialises prepare and trace on one object (its device state, its caches)
  double device_seconds_ = -1;  ///< last_device_seconds()
};

/// The options Backend::ray_query(acc) traces for query `q`: the fastest exact single-ray
/// traversals measured (docs/benchmarks.md, "Single rays from the caller's threads"): closest hit
/// the MBVH8 ordered stack, any hit the MBVH8 bitstack; robust precision, the backend's own leaf
/// block.
TraceOptions default_ray_query_options(Query q);

/// `opt` with its automatic layout and traversal (TraceOptions' defaults) replaced by what `b`
/// traces fastest for opt.query: the first pair of b.fastest(opt.query) that b supports and that
/// keeps whichever of the two `opt` names (a named layout with an automatic traversal: the fastest
/// traversal b has on that layout; a named traversal with an automatic layout: the fastest layout
/// b has it on). Unchanged when both are named. When no pair fits (a layout on which b has no
/// traversal), the automatic one becomes MBVH4 or stack, which trace then refuses naming what b
/// has. Backend::trace, prepare and ray_query call it first; call it to learn what they trace
/// (reports, comparisons with the reference).
TraceOptions resolve_options(const Backend& b, TraceOptions opt);

/// `opt` resolved for `b` (resolve_options) with leaf_block set to what `b` traces for it: the
/// options the reference (cpu-scalar, trace_reference) must trace to give `b`'s answers bit for bit.
inline TraceOptions with_leaves_of(const Backend& b, TraceOptions opt) {
  opt = resolve_options(b, opt);
  opt.leaf_block = b.leaf_block(opt);
  return opt;
}

using BackendFactory = std::function<std::unique_ptr<Backend>(const BackendOptions&)>;

struct BackendInfo {
  std::string name;
  std::string summary;
  BackendFactory make;        ///< empty when the backend is not built into this binary
  std::string unavailable;    ///< why it is not built (when `make` is empty)
  /// If set and it returns a reason, this machine lacks the hardware the backend needs (e.g.
  /// AVX-512): tests skip it and say why. Any other failure to start is an error.
  std::function<std::string()> missing_hardware;
  /// Set when this name is another backend under a second name (`cpu` = the best ISA build):
  /// tests run the backend once, under its own name.
  std::string alias_of;
  /// If set, lists the devices this backend can run on (one line each; `mbvh devices`).
  std::function<std::vector<std::string>()> devices;
  /// If set, takes the problems the backend's diagnostics raised where they could not be thrown
  /// (Vulkan validation messages while tearing down); the CLI and the tests fail on any.
  std::function<std::vector<std::string>()> pending_problems;
  /// The settings this backend reads (BackendOptions::settings).
  std::vector<BackendSetting> settings;
  /// Whether the backend traces a build's hierarchy (its layouts). False for a backend that traces
  /// from Accel::tris() and bounds() alone (dacrt): it also traces a build of BuildQuality::none,
  /// which every other backend refuses (Backend::prepare, Backend::trace), and a CLI command whose
  /// every backend has it false builds with quality none unless --quality says otherwise.
  bool needs_hierarchy = true;
};

/// Adds a backend to the registry (a later registration of the same name replaces it).
void register_backend(BackendInfo info);
/// Every backend known to this binary, built or not, in registration order.
std::vector<BackendInfo> list_backends();
/// The backends that can start on this machine, each once under its own name, in registration
/// order: built into this binary, its hardware there (BackendInfo::missing_hardware), and not a
/// second name of another (BackendInfo::alias_of: `cpu` is listed as the ISA backend it stands
/// for). A listed backend that then fails to start has a fault (a driver, a device), not missing
/// hardware. `left_out`, if given, gets "NAME: why" for every other registered name. Starts none.
std::vector<std::string> runnable_backends(std::vector<std::string>* left_out = nullptr);
/// BackendInfo::needs_hierarchy of the registered backend `name` (false if the backend an alias
/// stands for has it false); true for a name not registered.
bool backend_needs_hierarchy(const std::string& name);
/// Makes a backend by name; throws Error naming the known backends, or saying why a known
/// backend is not built or cannot start, or naming a setting of `opt` that no backend of its
/// family declares (BackendOptions).
std::unique_ptr<Backend> make_backend(const std::string& name, const BackendOptions& opt = {});

}  // namespace mbvh

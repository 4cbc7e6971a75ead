// SPDX-License-Identifier: MIT
// backend.h — the one interface every tracing backend implements (cpu-scalar, cpu, opencl,
// vulkan, embree) and the registry that makes them by name. The core includes no backend: a
// program registers the backends it links (mbvh/backends.h).
#pragma once
#include <cstddef>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
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
  /// Sets last_device_seconds() for the trace in progress (trace() clears it to -1 first).
  void set_device_seconds(double s) { device_seconds_ = s; }

private:
  std::mutex mutex_;  ///< serialises prepare and trace on one object (its device state, its caches)
  double device_seconds_ = -1;  ///< last_device_seconds()
};

/// `opt` with leaf_block set to what `b` traces for it: the options the reference (cpu-scalar,
/// trace_reference) must trace to give `b`'s answers bit for bit.
inline TraceOptions with_leaves_of(const Backend& b, TraceOptions opt) {
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
/// The layout a caller that names none traces with traversal `t` on `b`: MBVH4, or MBVH2 where
/// `b` has no MBVH4 traversal of that kind (vulkan). The CLI's and the bindings' default.
Layout default_layout(const Backend& b, Traversal t);
/// Whether dacrt is the only traversal `b` has (on any layout): a caller that names no traversal
/// then traces dacrt (the CLI's and the bindings' default), else bitstack.
bool only_dacrt(const Backend& b);
/// The traversal a caller that names none traces on `b`: dacrt where that is b's only traversal
/// (only_dacrt), else bitstack (the stackless traversal of Afra & Szirmay-Kalos) where b has it on
/// default_layout(b, bitstack), else stack (the embree peer). The CLI's and the bindings' default.
Traversal default_traversal(const Backend& b);
/// Makes a backend by name; throws Error naming the known backends, or saying why a known
/// backend is not built or cannot start, or naming a setting of `opt` that no backend of its
/// family declares (BackendOptions).
std::unique_ptr<Backend> make_backend(const std::string& name, const BackendOptions& opt = {});

}  // namespace mbvh

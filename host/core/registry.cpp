// SPDX-License-Identifier: MIT
// registry.cpp — the backend registry: names to factories. The core registers nothing: the
// program (or the user) registers the backends it links (mbvh/backends.h).
#include <algorithm>
#include <charconv>
#include <cmath>
#include <mutex>

#include "mbvh/backend.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

std::vector<BackendInfo>& table() {
  static std::vector<BackendInfo> t;
  return t;
}

std::recursive_mutex& table_mutex() {
  static std::recursive_mutex m;
  return m;
}

}  // namespace

void register_backend(BackendInfo info) {
  std::lock_guard<std::recursive_mutex> lock(table_mutex());
  for (auto& b : table())
    if (b.name == info.name) {
      b = std::move(info);
      return;
    }
  table().push_back(std::move(info));
}

std::vector<BackendInfo> list_backends() {
  std::lock_guard<std::recursive_mutex> lock(table_mutex());
  return table();
}

bool backend_needs_hierarchy(const std::string& name) {
  std::lock_guard<std::recursive_mutex> lock(table_mutex());
  std::string n = name;
  for (int hops = 0; hops < 8; ++hops) {  // an alias (BackendInfo::alias_of) as the backend it stands for
    const auto it = std::find_if(table().begin(), table().end(), [&](const BackendInfo& b) { return b.name == n; });
    if (it == table().end()) return true;
    if (!it->needs_hierarchy || it->alias_of.empty() || it->alias_of == n) return it->needs_hierarchy;
    n = it->alias_of;
  }
  return true;
}

namespace {

// Throws Error naming `b` when `acc` has no hierarchy (quality none) and b needs one
// (BackendInfo::needs_hierarchy of its name, or of the backend an alias runs as; a backend not in
// the registry is taken to need one). Free for a build with a hierarchy.
void refuse_flat_build(const Backend& b, const Accel& acc) {
  if (acc.has_hierarchy() || !backend_needs_hierarchy(b.name())) return;
  if (const std::string as = b.runs_as(); as != b.name() && !backend_needs_hierarchy(as)) return;
  throw Error(b.name() + ": this build has no hierarchy (quality none): only a backend that traces without one "
              "(dacrt) traces it; build with quality low, medium or high to trace it on " + b.name());
}

}  // namespace

std::vector<std::pair<Layout, Traversal>> Backend::fastest(Query q) const {
  // measured on the SIMD cpu backends (docs/library.md, "Defaults"): MBVH8 first, closest hit with
  // the ordered stack (as Backend::ray_query's default), any hit with the octant stack (two rays
  // in turn: a batch's walk; Backend::ray_query's single rays keep the bitstack); then the rest,
  // MBVH4 before MBVH2, the stacks before the bitstacks (the device backends' order), dacrt last
  if (q == Query::any)
    return {{Layout::mbvh8, Traversal::stack_octant},  {Layout::mbvh8, Traversal::bitstack},
            {Layout::mbvh8, Traversal::stack},
            {Layout::mbvh4, Traversal::stack},         {Layout::mbvh4, Traversal::bitstack},
            {Layout::mbvh8, Traversal::stack_ordered}, {Layout::mbvh4, Traversal::stack_ordered},
            {Layout::mbvh2, Traversal::stack},         {Layout::mbvh2, Traversal::bitstack},
            {Layout::mbvh4, Traversal::bitstack_retest}, {Layout::mbvh8, Traversal::bitstack_octant},
            {Layout::mbvh4, Traversal::dacrt}};
  return {{Layout::mbvh8, Traversal::stack_ordered}, {Layout::mbvh8, Traversal::stack},
          {Layout::mbvh4, Traversal::stack_ordered}, {Layout::mbvh4, Traversal::stack},
          {Layout::mbvh8, Traversal::bitstack},      {Layout::mbvh4, Traversal::bitstack},
          {Layout::mbvh2, Traversal::stack},         {Layout::mbvh2, Traversal::bitstack},
          {Layout::mbvh8, Traversal::stack_octant}, {Layout::mbvh4, Traversal::bitstack_retest},
          {Layout::mbvh8, Traversal::bitstack_octant}, {Layout::mbvh4, Traversal::dacrt}};
}

TraceOptions resolve_options(const Backend& b, TraceOptions opt) {
  if (opt.layout != Layout::automatic && opt.traversal != Traversal::automatic) return opt;
  return resolve_by(b.fastest(opt.query), [&b](Layout l, Traversal t) { return b.supports(l, t); }, opt, b.name());
}

void Backend::prepare(const Accel& acc, const TraceOptions& asked) {
  check_trace_options(asked, name());
  const TraceOptions opt = resolve_options(*this, asked);
  refuse_flat_build(*this, acc);
  std::lock_guard<std::mutex> lock(mutex_);
  do_prepare(acc, opt);
}

namespace {

constexpr Layout kLayouts[] = {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8};
constexpr Traversal kTraversals[] = {Traversal::stack,         Traversal::bitstack,         Traversal::stack_ordered,
                                     Traversal::bitstack_retest, Traversal::packet_ranged, Traversal::packet_partition,
                                     Traversal::packet,        Traversal::dacrt,            Traversal::stack_octant,
                                     Traversal::bitstack_octant};
constexpr Precision kPrecisions[] = {Precision::robust, Precision::exact, Precision::fast};

// The names of `all` that `keep` holds for, comma-separated.
template <class T, std::size_t N, class Keep>
std::string names_of(const T (&all)[N], Keep keep) {
  std::string list;
  for (T x : all)
    if (keep(x)) list += (list.empty() ? "" : ", ") + std::string(to_string(x));
  return list;
}

// Throws Error when `b` lacks opt's layout / traversal pair or its precision, naming what it has.
void refuse_unsupported(const Backend& b, const TraceOptions& opt) {
  if (!b.supports(opt.layout, opt.traversal)) {
    const std::string there = names_of(kTraversals, [&](Traversal t) { return b.supports(opt.layout, t); });
    const std::string layouts = names_of(kLayouts, [&](Layout l) {
      return names_of(kTraversals, [&](Traversal t) { return b.supports(l, t); }) != "";
    });
    throw Error(b.name() + ": traversal '" + to_string(opt.traversal) + "' is not implemented for " +
                to_string(opt.layout) + (there.empty() ? " (its layouts: " + layouts : " (its traversals there: " + there) +
                ")");
  }
  if (!b.supports_precision(opt.precision))
    throw Error(b.name() + ": precision '" + to_string(opt.precision) + "' is not available (its precisions: " +
                names_of(kPrecisions, [&](Precision p) { return b.supports_precision(p); }) + ")");
}

}  // namespace

void Backend::trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& asked, TraceOutput& out) {
  // -- checks, each naming this backend; an automatic layout or traversal resolved
  check_trace_options(asked, name());
  const TraceOptions opt = resolve_options(*this, asked);
  refuse_unsupported(*this, opt);
  refuse_flat_build(*this, acc);
  check_ray_range(acc, rays, name());
  // -- the build prepared, the output sized; then the backend's own part
  std::lock_guard<std::mutex> lock(mutex_);
  device_seconds_ = -1;
  const TraceOptions o = with_leaves_of(*this, opt);
  do_prepare(acc, o);
  out.resize_for(rays.size(), o);
  if (rays.empty()) return;
  trace_batch(acc, rays, o, out);
}

TraceOptions default_ray_query_options(Query q) {
  TraceOptions o;
  o.layout = Layout::mbvh8;
  // the fastest measured on one thread (bench/results/single-ray-2026-12-04): of the best single-ray
  // traversal's speed, closest hit the MBVH8 ordered stack 0.97 (geometric mean over 12 rows), any
  // hit the MBVH8 bitstack 0.99
  o.traversal = q == Query::any ? Traversal::bitstack : Traversal::stack_ordered;
  o.query = q;
  return o;
}

RayQueryKernels Backend::ray_query_kernels(const Accel&, const TraceOptions&, const TraceOptions&) {
  throw Error(name() + ": no single-ray query (Backend::ray_query): only the SIMD cpu backends (cpu, cpu-avx2, "
              "cpu-avx512) have one; trace batches of rays on " + name());
}

namespace {

// x rounded to a float toward +inf (Up) or -inf: the float bounds of the quick range test, so a
// float that passes them passes the double comparisons of check_ray_range.
template <bool Up>
float round_to_float(double x) {
  float f = static_cast<float>(x);
  if (Up ? double(f) < x : double(f) > x) f = std::nextafter(f, Up ? INFINITY : -INFINITY);
  return f;
}

}  // namespace

void Backend::check_ray_query_options(const Accel& acc, const TraceOptions& opt) {
  check_trace_options(opt, name());
  refuse_unsupported(*this, opt);
  refuse_flat_build(*this, acc);
  if (opt.stats)
    throw Error(name() + ": a single-ray query counts no statistics (TraceOptions::stats): trace a batch for them");
  if (is_packet(opt.traversal) || is_dacrt(opt.traversal))
    throw Error(name() + ": traversal '" + to_string(opt.traversal) + "' traces batches of rays, not one ray per call; a "
                "single ray's answer there is its single-ray traversal's: ask for '" +
                to_string(packet_single_ray(opt.layout, false)) + "' (closest hit) or '" +
                to_string(packet_single_ray(opt.layout, true)) + "' (any hit)");
}

RayQuery Backend::make_ray_query(const Accel& acc, TraceOptions c, TraceOptions a) {
  check_ray_query_options(acc, c);
  check_ray_query_options(acc, a);
  c.query = Query::closest;  // first: a backend's own leaf block may depend on the query
  a.query = Query::any;
  c = with_leaves_of(*this, c);
  a = with_leaves_of(*this, a);
  prepare(acc, c);
  prepare(acc, a);
  RayQueryKernels k = ray_query_kernels(acc, c, a);
  if (!k.closest || !k.any || !k.state) throw Error(name() + ": its single-ray query kernels are missing");
  RayQuery q;
  q.closest_ = k.closest;
  q.any_ = k.any;
  q.state_ = k.state.get();
  q.keep_ = std::move(k.state);
  q.accel_ = &acc;
  q.closest_opt_ = c;
  q.any_opt_ = a;
  q.who_ = runs_as();
  q.who_check_ = q.who_ + " (RayQuery)";
  // the quick range test: every origin component within O = max(S, min(2^16 S, 2^41)) (S: the
  // scene's largest coordinate) makes check_ray_range's M = max(S, the origin's) at most O, and its
  // bounds then hold for every direction whose largest component D lies in [d_lo, d_hi], d_lo from
  // O (M^3 and M / D grow with M; the products round monotonically) and d_hi from S. O is far
  // beyond the scene (a camera or light outside it) yet keeps d_lo below 2^-4 in every scene
  // Accel::build accepts (S <= 2^40).
  const Box& box = acc.bounds();
  const double S = box.empty() ? 0.0
                               : std::max({std::fabs(box.lo.x), std::fabs(box.lo.y), std::fabs(box.lo.z),
                                           std::fabs(box.hi.x), std::fabs(box.hi.y), std::fabs(box.hi.z)});
  if (!(S > 0)) {  // check_ray_range accepts every ray
    q.o_max_ = INFINITY;
    q.d_lo_ = 0;
    q.d_hi_ = INFINITY;
  } else {
    const double S3 = S * S * S;
    const double O = std::max(S, std::min(S * 0x1p16, 0x1p41));  // a power of two times a float: exact
    q.o_max_ = static_cast<float>(O);
    q.d_lo_ = round_to_float<true>(std::max(O * O * O / kMaxRayCube, O / kMaxRayRatio));
    q.d_hi_ = round_to_float<false>(std::min(S3 / kMinRayCube, S * kMaxRayRatio));
  }
  return q;
}

RayQuery Backend::ray_query(const Accel& acc, const TraceOptions& opt) {
  TraceOptions c = opt, a = opt;
  c.query = Query::closest;
  a.query = Query::any;
  return make_ray_query(acc, resolve_options(*this, c), resolve_options(*this, a));
}

RayQuery Backend::ray_query(const Accel& acc) {
  return make_ray_query(acc, default_ray_query_options(Query::closest), default_ray_query_options(Query::any));
}

void RayQuery::check_slow(const Ray& r) const {
  if (!accel_) throw Error("RayQuery: an empty query (made by its default constructor): make one with Backend::ray_query");
  check_ray_range(*accel_, std::span<const Ray>(&r, 1), who_check_);
}

std::string BackendOptions::get(const std::string& name, const std::string& fallback) const {
  const auto it = settings.find(name);
  return it == settings.end() ? fallback : it->second;
}

bool BackendOptions::get_flag(const std::string& name, bool fallback) const {
  const auto it = settings.find(name);
  if (it == settings.end()) return fallback;
  for (const char* t : {"1", "true", "on", "yes"})
    if (it->second == t) return true;
  for (const char* f : {"0", "false", "off", "no"})
    if (it->second == f) return false;
  throw Error("backend setting " + name + "='" + it->second + "': expected 1, true, on, yes or 0, false, off, no");
}

std::size_t BackendOptions::get_size(const std::string& name, std::size_t fallback) const {
  const auto it = settings.find(name);
  if (it == settings.end()) return fallback;
  const std::string& v = it->second;
  std::size_t n = 0;
  const auto [end, ec] = std::from_chars(v.data(), v.data() + v.size(), n);
  if (v.empty() || ec != std::errc() || end != v.data() + v.size())
    throw Error("backend setting " + name + "='" + v + "': expected an unsigned decimal number");
  return n;
}

namespace {

// "opencl-wide" -> "opencl": a backend's family, the prefix of its settings' names
std::string family_of(const std::string& name) { return name.substr(0, name.find('-')); }

// Every setting of `opt` names a registered family, and those of `b`'s family are b's own.
void check_settings(const BackendInfo& b, const BackendOptions& opt, const std::vector<BackendInfo>& all) {
  for (const auto& [key, value] : opt.settings) {
    const std::size_t dot = key.find('.');
    const std::string family = key.substr(0, dot);
    bool known = false;
    for (const BackendInfo& x : all) known |= family_of(x.name) == family;
    if (dot == std::string::npos || dot + 1 == key.size() || !known)
      throw Error("backend setting '" + key + "': settings are named FAMILY.NAME after a registered backend family " +
                  "(e.g. opencl.device, vulkan.validation)");
    if (family != family_of(b.name)) continue;  // another family's: not this backend's concern
    bool declared = false;
    std::string names;
    for (const BackendSetting& s : b.settings) {
      declared |= s.name == key;
      names += (names.empty() ? "" : ", ") + s.name;
    }
    if (!declared)
      throw Error("backend '" + b.name + "' has no setting '" + key + "' (its settings: " + (names.empty() ? "none" : names) + ")");
  }
}

}  // namespace

std::vector<std::string> runnable_backends(std::vector<std::string>* left_out) {
  std::vector<std::string> names;
  const auto leave = [&](const BackendInfo& b, const std::string& why) {
    if (left_out) left_out->push_back(b.name + ": " + why);
  };
  for (const BackendInfo& b : list_backends()) {
    if (!b.make) leave(b, "not built: " + b.unavailable);
    else if (!b.alias_of.empty()) leave(b, "stands for " + b.alias_of + " here (listed under that name)");
    else if (const std::string why = b.missing_hardware ? b.missing_hardware() : ""; !why.empty()) leave(b, why);
    else names.push_back(b.name);
  }
  return names;
}

std::unique_ptr<Backend> make_backend(const std::string& name, const BackendOptions& opt) {
  const std::vector<BackendInfo> all = list_backends();
  for (const BackendInfo& b : all) {
    if (b.name != name) continue;
    if (!b.make) throw Error("backend '" + name + "' is not available in this build: " + b.unavailable);
    check_settings(b, opt, all);
    return b.make(opt);
  }
  std::string known;
  for (const BackendInfo& b : list_backends()) known += (known.empty() ? "" : ", ") + b.name;
  if (known.empty())
    throw Error("unknown backend '" + name + "': no backend is registered (link mbvh::mbvh and call "
                "mbvh::register_builtin_backends(), or a backend's own register function; mbvh/backends.h)");
  throw Error("unknown backend '" + name + "' (known: " + known + ")");
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// reference.cpp — the scalar reference traversals over ray batches (one instantiation per
// layout x traversal x query x statistics); the brute-force oracle is brute_force.cpp.
#include <algorithm>
#include <atomic>
#include <charconv>
#include <cmath>
#include <cstdio>

#include "mbvh/error.h"
#include "host/core/enum_check.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "host/core/trace/batch.h"
#include "host/core/trace/ray_range.h"
#include "mbvh/trace.h"

namespace mbvh {

Traversal stack_twin(Traversal t) {
  if (t == Traversal::bitstack) return Traversal::stack;
  if (t == Traversal::bitstack_retest) return Traversal::stack_ordered;
  if (t == Traversal::bitstack_octant) return Traversal::stack_octant;
  if (is_packet(t)) return Traversal::stack;
  return t;  // a stack traversal, or dacrt (no twin)
}

bool reference_supports(Layout layout, Traversal traversal) {
  if (is_packet(traversal)) return true;  // the stack traversal of `layout`, ray by ray
  // dacrt is the dacrt backends' own: cpu-scalar and the SIMD cpu backends (whose supports() this
  // is) do not list it, though trace_reference traces it as packet_single_ray's traversal
  if (is_dacrt(traversal)) return false;
  if (layout == Layout::mbvh8) return traversal != Traversal::bitstack_retest;  // no bitstack-retest on MBVH8
  // MBVH8 only (its nodes hold the octant orders)
  if (traversal == Traversal::stack_octant || traversal == Traversal::bitstack_octant) return false;
  return layout == Layout::mbvh4 || traversal == Traversal::stack || traversal == Traversal::bitstack;
}

std::size_t state_bytes_per_ray(Layout layout, Traversal traversal) {
  check_enum(layout, "state_bytes_per_ray", "the layout");
  check_enum(traversal, "state_bytes_per_ray", "the traversal");
  // dacrt: the 32-byte ray record its recursion permutes in place (the backend's state_bytes
  // counts its side arrays too)
  if (is_dacrt(traversal)) return sizeof(Ray);
  // packets (backends/cpu/packet/traverse.h): a stack of MBVH_STACK2_ENTRIES entries of (node, range or
  // count, a group list and one 8-lane mask per group), shared by the packet's rays
  if (is_packet(traversal)) {
    constexpr std::size_t groups = MBVH_PACKET_RAYS / 8;
    return (MBVH_STACK2_ENTRIES * (4 + 4 + 2 * groups) + 4 + 4) / MBVH_PACKET_RAYS;
  }
  // MBVH8 bitstack: node + a 128-bit word (8 pending-slot bits per level, bitstack.h)
  if (traversal == Traversal::bitstack && layout == Layout::mbvh8) return 4 + 16;
  // MBVH8 octant bitstack: the same, and the ray's octant (the order's offset in Node8::pad)
  if (traversal == Traversal::bitstack_octant) return 4 + 16 + 4;
  if (traversal == Traversal::bitstack || traversal == Traversal::bitstack_retest) return 4 + 8;
  const std::size_t entries = layout == Layout::mbvh2   ? MBVH_STACK2_ENTRIES
                              : layout == Layout::mbvh4 ? MBVH_STACK4_ENTRIES
                                                        : MBVH_STACK8_ENTRIES;
  // (node, distance) or node; stack-octant keeps the distances in a second array
  const std::size_t entry = traversal == Traversal::stack_ordered || traversal == Traversal::stack_octant ? 8 : 4;
  return entries * entry + 4 + 4;
}

bool ray_valid(const Ray& ray) {
  RayPre p;
  return prepare_ray(ray, p);
}

void check_ray_range(const Accel& acc, std::span<const Ray> rays, const std::string& who) {
  check_ray_range(acc.bounds(), rays, who);
}

void check_ray_range(const Box& box, std::span<const Ray> rays, const std::string& who) {
  if (box.empty()) return;  // no triangle to hit
  const double S = std::max({std::fabs(box.lo.x), std::fabs(box.lo.y), std::fabs(box.lo.z), std::fabs(box.hi.x),
                             std::fabs(box.hi.y), std::fabs(box.hi.z)});
  if (!(S > 0)) return;
  const double S3 = S * S * S;
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const Ray& r = rays[i];
    const double D = std::max({std::fabs(r.dx), std::fabs(r.dy), std::fabs(r.dz)});
    const double M = std::max({S, double(std::fabs(r.ox)), double(std::fabs(r.oy)), double(std::fabs(r.oz))});
    // NaN and infinite values fail no comparison here: such a ray is invalid, tested below
    if (!(M * M * M > kMaxRayCube * D || S3 < kMinRayCube * D || M > kMaxRayRatio * D || S * kMaxRayRatio < D)) continue;
    if (!ray_valid(r)) continue;  // a defined miss
    const auto f = [](double v) {  // the shortest spelling that reads back as the float
      char b[32];
      const auto end = std::to_chars(b, b + sizeof b, static_cast<float>(v)).ptr;
      return std::string(b, end);
    };
    const auto p2 = [](double v, const char* format) {  // v as a power of two
      char b[32];
      std::snprintf(b, sizeof b, format, std::log2(v));
      return std::string(b);
    };
    const auto value = [&](double v) { return p2(v, "2^%.1f"); };
    const auto limit = [&](double v) { return p2(v, "2^%g"); };
    throw Error(who + ": ray " + std::to_string(i) + " (origin " + f(r.ox) + " " + f(r.oy) + " " + f(r.oz) + ", direction " +
                f(r.dx) + " " + f(r.dy) + " " + f(r.dz) + ") leaves the range traced exactly in this scene: with D = " + f(D) +
                " its direction's largest component, S = " + f(S) + " the scene's largest coordinate and M = " + f(M) +
                " the larger of S and the origin's, M^3/D = " + value(M * M * M / D) + " must be at most " +
                limit(kMaxRayCube) + ", S^3/D = " + value(S3 / D) + " at least " + limit(kMinRayCube) + ", M/D = " +
                value(M / D) + " at most " + limit(kMaxRayRatio) + " and S/D = " + value(S / D) + " at least " +
                limit(1 / kMaxRayRatio) + " (mbvh/accel.h, kMaxRayCube); scale the direction by a power of two nearer "
                "unit length (t, tmin and tmax scale inversely) or move the origin nearer the scene");
  }
}

void throw_trace_output_out_of_memory(std::size_t n, const TraceOptions& opt) {
  const std::uint64_t each = (opt.query == Query::any ? 1 : sizeof(Hit)) + (opt.stats ? sizeof(RayStats) : 0);
  throw_out_of_memory("the trace results of " + std::to_string(n) + " rays", std::uint64_t(n) * each);
}

void check_leaf_block(const TraceOptions& opt, const std::string& who) {
  if (opt.leaf_block > 64)
    throw Error(who + ": leaf block " + std::to_string(opt.leaf_block) +
                " is out of range (TraceOptions::leaf_block: 0 for the backend's own, or 1 to 64)");
}

void check_trace_options(const TraceOptions& opt, const std::string& who) {
  check_enum_or_auto(opt.layout, who, "TraceOptions::layout");
  check_enum_or_auto(opt.traversal, who, "TraceOptions::traversal");
  check_enum(opt.query, who, "TraceOptions::query");
  check_enum(opt.precision, who, "TraceOptions::precision");
  check_leaf_block(opt, who);
}

std::vector<std::pair<Layout, Traversal>> reference_fastest(Query q) {
  // measured (docs/library.md, "Defaults"): the scalar kernels trace MBVH4 with the ordered stack
  // fastest, for any hit too (its nearer-first order finds an occluder sooner)
  if (q == Query::any)
    return {{Layout::mbvh4, Traversal::stack_ordered}, {Layout::mbvh2, Traversal::bitstack},
            {Layout::mbvh4, Traversal::stack},         {Layout::mbvh4, Traversal::bitstack},
            {Layout::mbvh8, Traversal::stack_ordered}, {Layout::mbvh8, Traversal::stack},
            {Layout::mbvh8, Traversal::bitstack},      {Layout::mbvh2, Traversal::stack},
            {Layout::mbvh4, Traversal::bitstack_retest}};
  return {{Layout::mbvh4, Traversal::stack_ordered}, {Layout::mbvh8, Traversal::stack_ordered},
          {Layout::mbvh4, Traversal::stack},         {Layout::mbvh8, Traversal::stack},
          {Layout::mbvh4, Traversal::bitstack},      {Layout::mbvh8, Traversal::bitstack},
          {Layout::mbvh2, Traversal::stack},         {Layout::mbvh2, Traversal::bitstack},
          {Layout::mbvh4, Traversal::bitstack_retest}};
}

TraceOptions resolve_by(const std::vector<std::pair<Layout, Traversal>>& ranking,
                        const std::function<bool(Layout, Traversal)>& supports, TraceOptions opt, const std::string& who) {
  const bool any_layout = opt.layout == Layout::automatic, any_traversal = opt.traversal == Traversal::automatic;
  if (!any_layout && !any_traversal) return opt;
  check_trace_options(opt, who);
  const auto fits = [&](Layout l, Traversal t) {
    return (any_layout || l == opt.layout) && (any_traversal || t == opt.traversal) && supports(l, t);
  };
  for (const auto& [l, t] : ranking)
    if (fits(l, t)) {
      opt.layout = l;
      opt.traversal = t;
      return opt;
    }
  // a pair the ranking leaves out (a traversal named with an automatic layout: dacrt, a packet
  // traversal): the first layout that has it
  if (!any_traversal)
    for (const Layout l : {Layout::mbvh8, Layout::mbvh4, Layout::mbvh2})
      if (supports(l, opt.traversal)) {
        opt.layout = l;
        return opt;
      }
  // nothing fits: the automatic field takes the pair's old default (MBVH4, stack), which the
  // caller's support check then refuses by name as any pair the backend lacks
  if (any_layout) opt.layout = Layout::mbvh4;
  if (any_traversal) opt.traversal = Traversal::stack;
  return opt;
}

// The reference traces opt's pair (an automatic one resolved by reference_fastest): one
// reference_supports, or dacrt (as packet_single_ray's traversal, whose answers dacrt gives up to
// classified ties); on a build with a hierarchy. Returns the options it traces.
static TraceOptions require_supported(const Accel& acc, TraceOptions opt) {
  check_trace_options(opt, "cpu-scalar");
  opt = resolve_by(reference_fastest(opt.query),
                   [](Layout l, Traversal t) { return is_dacrt(t) || reference_supports(l, t); }, opt, "cpu-scalar");
  if (!acc.has_hierarchy())
    throw Error("cpu-scalar: this build has no hierarchy (quality none): only the dacrt backend traces it; build with "
                "quality low, medium or high");
  if (!is_dacrt(opt.traversal) && !reference_supports(opt.layout, opt.traversal))
    throw Error(std::string("traversal '") + to_string(opt.traversal) + "' is not defined for layout " + to_string(opt.layout) +
                " (bitstack-retest is an MBVH4 traversal; MBVH2 has no ordered stack)");
  return opt;
}

template <class K>
static Hit trace_one_with(const TraceView& v, RayPre& r, const TraceOptions& opt, RayStats* stats,
                          std::vector<std::int32_t>* leaf_log) {
  if constexpr (K::fast) relax_ray(r);
  const bool any = opt.query == Query::any;
  if (stats || leaf_log) {
    CountStats st;
    st.leaf_log = leaf_log;
    const Hit h = any ? dispatch<true, K>(v, r, opt.layout, opt.traversal, st) : dispatch<false, K>(v, r, opt.layout, opt.traversal, st);
    if (stats) *stats = st.s;
    return h;
  }
  NoStats st;
  return any ? dispatch<true, K>(v, r, opt.layout, opt.traversal, st) : dispatch<false, K>(v, r, opt.layout, opt.traversal, st);
}

Hit trace_one(const Accel& acc, const Ray& ray, const TraceOptions& asked, RayStats* stats,
              std::vector<std::int32_t>* leaf_log) {
  const TraceOptions opt = require_supported(acc, asked);
  check_ray_range(acc, std::span<const Ray>(&ray, 1), "cpu-scalar");
  RayPre r;
  if (!prepare_ray(ray, r)) return miss_hit();
  const TraceView v = trace_view(acc, opt.layout, false, opt.leaf_block);
  return opt.precision == Precision::fast ? trace_one_with<ScalarKernelsT<true>>(v, r, opt, stats, leaf_log)
                                          : trace_one_with<ScalarKernels>(v, r, opt, stats, leaf_log);
}

void trace_reference(const Accel& acc, std::span<const Ray> rays, const TraceOptions& asked, TraceOutput& out,
                     unsigned threads, const std::function<void(std::size_t)>& progress) {
  const TraceOptions opt = require_supported(acc, asked);
  check_ray_range(acc, rays, "cpu-scalar");
  if (opt.precision == Precision::fast) trace_parallel<ScalarKernelsT<true>>(acc, rays, opt, out, threads, progress);
  else trace_parallel<ScalarKernels>(acc, rays, opt, out, threads, progress);
}

}  // namespace mbvh

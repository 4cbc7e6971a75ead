// SPDX-License-Identifier: MIT
// check.h — cross-checking: run every chosen backend x layout x traversal x query on the same
// rays, compare them ray by ray with each other and with the double-precision brute force, and
// classify every difference (compare.h).
#pragma once
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "host/tools/variants.h"
#include "mbvh/trace.h"

namespace mbvh {

struct CheckVariant {
  std::string backend;
  TraceOptions opt;
  std::string label() const;  ///< "cpu-scalar/mbvh4/bitstack/closest"
};

struct CheckOptions {
  VariantGrid grid;
  std::size_t brute_rays = 2000;  ///< rays spread over the batch checked by brute force (SIZE_MAX: all)
  unsigned threads = 0;
  BackendOptions backend;  ///< device choices (threads come from `threads`)
  /// Called with each variant's output as soon as it is traced (before any comparison): a caller
  /// that checks more of the same outputs (the tests' bit-for-bit comparisons) reads them here
  /// instead of tracing every variant again.
  std::function<void(const CheckVariant&, const TraceOutput&)> on_trace;
};

struct CheckReport {
  std::size_t rays = 0, invalid = 0, brute_rays = 0;
  std::vector<Comparison> comparisons;  ///< every pair compared, labels in Comparison::a / b
  std::size_t mismatches() const;
  bool ok() const { return mismatches() == 0; }
  /// A readable table, and the first genuine mismatches with their rays.
  std::string table(std::span<const Ray> rays) const;
};

/// Runs the check. The first variant of each query is the reference the others are compared
/// with; twins (stack vs bitstack of one backend and layout) are reported bit for bit; any hit
/// is compared with closest hit (occluded = a closest hit exists) and both with brute force.
/// Closest hits for that come from the first closest variant, else from trace_reference, or on a
/// build without a hierarchy (quality none) from the first any variant's backend asked for
/// closest hits. Labels show dacrt's layout as "-".
/// Pairs a backend does not support (bitstack-retest on MBVH2) are skipped. Throws Error if a backend
/// cannot start or no requested variant is supported.
CheckReport run_check(const Accel& acc, std::span<const Ray> rays, const CheckOptions& opt,
                      const std::function<void(const std::string&)>& log = {});

/// The oracle's tie rule for comparisons with brute_force (answer a, oracle b): a tie when a's
/// prim, evaluated in double on the same ray, lies at the oracle's distance within 4 ulp
/// (coplanar overlapping triangles: equal t that float arithmetic cannot resolve), or when only
/// one side hits, or both on other prims, within 4 ulp of the ray's tmin or tmax (the closed
/// interval's ends: the nearer hit at tmin, the farther at tmax), or when
/// either hit is ill-conditioned: the ray lies in the triangle's plane within the rounding of
/// its own direction, or the hit point lies within 16 ulps (of the coordinates) of an edge.
TieRule oracle_tie_rule(const Accel& acc, std::span<const Ray> rays);
/// True when hit `h` lies on a triangle whose plane holds `ray` within the rounding of the ray's
/// own direction: hit and miss are both right there (the run-time-vs-error benchmark skips such
/// answers; a leak through an edge is not one of them).
std::function<bool(const Ray&, const Hit&)> in_plane_rule(const Accel& acc);
/// For two float answers that differ beyond the tie rules: brute-forces the ray and returns true
/// (a tie) when each answer equals the oracle's or is a tie with it under `oracle` (the rule
/// oracle_tie_rule made for the same rays): both are legitimate.
TieRule oracle_settlement(const Accel& acc, std::span<const Ray> rays, TieRule oracle);

/// Indices of `k` rays spread evenly over n (all when k >= n).
std::vector<std::size_t> spread_indices(std::size_t n, std::size_t k);

}  // namespace mbvh

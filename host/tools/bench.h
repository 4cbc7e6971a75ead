// SPDX-License-Identifier: MIT
// bench.h — the benchmark protocol of DESIGN.md (first cut): for every backend x layout x
// traversal x query x ray kind, verify against the reference, warm up, time >= 5 passes, report
// the median speed (million rays per second) with its spread, the traversal state per ray and the work per ray.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "host/tools/raygen.h"
#include "host/tools/variants.h"
#include "mbvh/trace.h"

namespace mbvh {

struct BenchOptions {
  VariantGrid grid;
  std::vector<RayKind> kinds{RayKind::primary, RayKind::diffuse};
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  unsigned passes = 5;
  double warmup_seconds = 0.25;  ///< untimed passes before the timed ones, at least one
  unsigned threads = 0;
  BackendOptions backend;  ///< device choices (threads come from `threads`)
  /// Also time every variant on one thread, each 1-thread pass right after an N-thread pass (a
  /// ratio taken side by side, not across runs): BenchRecord::thread_scaling.
  bool scaling = false;
  /// Rays per kind (spread over the batch) whose closest hits are also compared with the
  /// double-precision brute force: BenchRecord::error_* (0: none).
  std::size_t error_rays = 0;
  /// Per backend and traversal, only the first layout of grid.layouts the backend has (e.g.
  /// mbvh4,mbvh2: MBVH4 where there is one, else MBVH2).
  bool first_layout = false;
  bool has_camera = false;  ///< primary rays (and the secondary rays built on them) from `camera`
  Camera camera;
};

struct BenchRecord {
  std::string scene, backend, isa, device, layout, traversal, query, ray_kind, precision;
  std::size_t rays = 0;
  unsigned threads = 0, passes = 0;
  double mrays_per_s = 0, mrays_min = 0, mrays_max = 0;  ///< median and spread over the passes
  /// Median over the passes of rays / the backend's device time (Backend::last_device_seconds:
  /// the trace kernels alone, no transfers); 0 where the backend does not measure it (JSON null).
  double device_mrays_per_s = 0;
  std::size_t state_bytes_per_ray = 0;
  unsigned leaf_block = 1;  ///< the leaves the backend traced (Backend::leaf_block; 1: the build's own)
  double peak_state_bytes_per_ray = 0;  ///< mean over rays of the state actually used
  double nodes_per_ray = 0, box_tests_per_ray = 0, leaves_per_ray = 0, tris_per_ray = 0, climbs_per_ray = 0;
  /// Packet traversals: the share of SIMD lanes doing an active ray's work (RayStats::lane_ops
  /// over group_ops); -1 for single-ray traversals.
  double simd_utilisation = -1;
  /// Histograms of the work per ray, power-of-two buckets: bucket 0 counts rays with 0, bucket
  /// k >= 1 rays with [2^(k-1), 2^k) (trailing empty buckets dropped).
  std::vector<std::uint64_t> hist_nodes, hist_leaves, hist_tris, hist_climbs;
  std::size_t verify_mismatches = 0;    ///< genuine mismatches against the reference (robust, all rays)
  std::size_t error_rays = 0;           ///< closest hits compared with the brute force (BenchOptions::error_rays)
  std::size_t error_mismatches = 0;     ///< of those, genuine mismatches (compare.h's tie rules, as `mbvh check`)
  /// of those, wrong answers by compare.h's stricter wrong_answer (a miss beside an edge counts),
  /// rays lying in a hit triangle's plane left out (check.h in_plane_rule)
  std::size_t wrong_answers = 0;
  /// `inside` rays (from inside a closed mesh: every one must hit) that missed: leaks.
  std::size_t leaks = 0;
  double ratio_vs_stack = 0;            ///< speed of this record / its stack twin (bitstack rows)
  /// speed of this record / the `cpu` backend's on the same variant; for dacrt (no such variant on
  /// cpu) / cpu's fastest record on the same query, rays and precision
  double ratio_vs_cpu = 0;
  double mrays_one_thread = 0;          ///< with BenchOptions::scaling: the median on one thread
  double thread_scaling = 0;            ///< mrays_per_s / mrays_one_thread (0: not measured)
  /// A peer library's record (Backend::peer: embree, tinybvh): measured against, not held to
  /// mbvh's contract — its genuine mismatches are reported ("differs"), as `check` counts a witness's.
  bool peer = false;
  /// Whether the timed result passed verification: no genuine mismatch, except in the fast mode,
  /// whose mismatches are its measured error, and a peer's (reported, not a failure).
  bool verified() const { return verify_mismatches == 0 || peer || precision == to_string(Precision::fast); }
};

struct BenchReport {
  std::string machine, cpu, compiler, flags;
  std::string bvh_hash;
  std::vector<BenchRecord> records;
  std::string table() const;
  std::string json() const;
  std::string csv() const;  ///< the JSON records as CSV: a header line, one line per record
  bool verified() const;
};

/// Runs the benchmark. Every result is verified against the reference traversal (cpu-scalar) on
/// `acc`, or, when `acc` has no hierarchy (BuildQuality::none), on a medium build of `scene` made
/// for that and kept until the run ends (the rays come from it too: the same rays).
BenchReport run_bench(const Scene& scene, const Accel& acc, const BenchOptions& opt,
                      const std::function<void(std::size_t done, std::size_t total)>& progress = {});

/// CPU model name, from /proc/cpuinfo.
std::string cpu_model();
/// Where a report was measured (BenchReport's fields of that name): the host, kernel, machine
/// and hardware threads; the CPU model; the compiler; this build type's compiler flags.
void describe_machine(std::string& machine, std::string& cpu, std::string& compiler, std::string& flags);
/// A report's JSON document (`machine`, `cpu`, `compiler`, `flags` and an array `records` of
/// objects) as CSV: a header line with the first record's plain keys (arrays and objects stay
/// in the JSON) and the run's four keys, then one line per record; strings quoted, quotes
/// doubled, a null an empty cell. "" when there is no record. BenchReport::csv's format.
std::string records_csv(const std::string& json);

/// A batch of rays and the answers bench verifies every timed answer to them against: the
/// reference traversal (cpu-scalar, MBVH4 stack) on `acc`, compared ray by ray with compare.h's
/// tie rules, differences they leave open settled by the brute force (check.h
/// oracle_settlement). The tie rules read `acc`, which must outlive this.
struct ReferenceAnswers {
  ReferenceAnswers(const Accel& acc, std::vector<Ray> rays);
  /// Makes the reference answer of query `q` (kept until another query is asked for).
  void reference_for(const Accel& acc, Query q, unsigned threads);
  /// The genuine mismatches of `out`, a trace of `rays` with query `q`, against the reference
  /// answer of `q` (reference_for first; throws Error otherwise).
  std::size_t mismatches(const TraceOutput& out, Query q) const;

  std::vector<Ray> rays;
  TieRule oracle, settle;  ///< settle: differences the tie rules leave open (a peer's)
  bool have_ref = false;
  Query ref_query = Query::closest;
  TraceOutput ref, closest;  ///< closest: the closest hits, for any-hit queries
};

}  // namespace mbvh

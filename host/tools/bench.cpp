// SPDX-License-Identifier: MIT
// bench.cpp — `mbvh bench`: verify, warm up, time, report medians (DESIGN.md, benchmark protocol).
#include "host/tools/bench.h"
#include "host/tools/check.h"

#include <sys/utsname.h>

#include <algorithm>
#include <bit>
#include <chrono>
#include <cstdio>
#include <fstream>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>

#include "mbvh/error.h"
#include "mbvh/backend.h"
#include "mbvh/compare.h"
#include "host/core/parallel.h"
#include "host/tools/stats.h"
#include "host/tools/variants.h"

#ifndef MBVH_COMPILE_FLAGS
#define MBVH_COMPILE_FLAGS ""
#endif

namespace mbvh {

std::string cpu_model() {
  std::ifstream f("/proc/cpuinfo");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind("model name", 0) == 0) {
      const auto p = line.find(':');
      return p == std::string::npos ? line : line.substr(p + 2);
    }
  return "unknown CPU";
}

void describe_machine(std::string& machine, std::string& cpu, std::string& compiler, std::string& flags) {
  utsname u{};
  uname(&u);
  machine = std::string(u.nodename) + " " + u.sysname + " " + u.release + " " + u.machine + ", " +
            std::to_string(resolve_threads(0)) + " hardware threads";
  cpu = cpu_model();
  compiler = std::string("g++ ") + __VERSION__;
  flags = MBVH_COMPILE_FLAGS;
}

bool BenchReport::verified() const {
  for (const auto& r : records)
    if (!r.verified()) return false;
  return true;
}

std::string BenchReport::table() const {
  std::string s;
  char line[512];
  bool scaled = false;
  for (const auto& r : records) scaled = scaled || r.thread_scaling > 0;
  bool errors = false;
  for (const auto& r : records) errors = errors || r.error_rays > 0;
  bool device = false;  // a "dev Mr/s" column only when some backend measured its device time
  for (const auto& r : records) device = device || r.device_mrays_per_s > 0;
  bool util = false;  // a "util" column (packets' SIMD utilisation) only when some record has it
  for (const auto& r : records) util = util || r.simd_utilisation >= 0;
  std::snprintf(line, sizeof line, "%-12s %-6s %-15s %-7s %-8s %-6s %9s %15s%s %8s %7s %8s %7s %7s %7s%s %9s%s%s\n", "backend",
                "layout", "traversal", "query", "rays", "prec", "Mrays/s", "(min-max)", device ? "  dev Mr/s" : "", "vs twin",
                "vs cpu", "state B", "nodes", "leaves", "tris", util ? "    util" : "", "verified",
                errors ? "  genuine  wrong/checked  leaks" : "", scaled ? "  1 thr   x/1thr" : "");
  s += line;
  for (const auto& r : records) {
    char ratio[32] = "";
    if (r.ratio_vs_stack > 0) std::snprintf(ratio, sizeof ratio, "%.3fx", r.ratio_vs_stack);
    char vcpu[32] = "";
    if (r.ratio_vs_cpu > 0) std::snprintf(vcpu, sizeof vcpu, "%.2fx", r.ratio_vs_cpu);
    char spread[48];
    std::snprintf(spread, sizeof spread, "(%.2f-%.2f)", r.mrays_min, r.mrays_max);
    char dev[32] = "";
    if (device && r.device_mrays_per_s > 0) std::snprintf(dev, sizeof dev, " %9.3f", r.device_mrays_per_s);
    else if (device) std::snprintf(dev, sizeof dev, " %9s", "");
    char ut[32] = "";
    if (util && r.simd_utilisation >= 0) std::snprintf(ut, sizeof ut, " %6.1f%%", 100.0 * r.simd_utilisation);
    else if (util) std::snprintf(ut, sizeof ut, " %7s", "");
    std::snprintf(line, sizeof line, "%-12s %-6s %-15s %-7s %-8s %-6s %9.3f %15s%s %8s %7s %8zu %7.1f %7.2f %7.1f%s %9s\n",
                  r.backend.c_str(), r.layout.c_str(), r.traversal.c_str(), r.query.c_str(), r.ray_kind.c_str(),
                  r.precision.c_str(), r.mrays_per_s, spread, dev, ratio, vcpu, r.state_bytes_per_ray, r.nodes_per_ray,
                  r.leaves_per_ray, r.tris_per_ray, ut,
                  !r.verified() ? "MISMATCH" : r.verify_mismatches ? "differs" : "yes");
    s += line;
    if (errors) {
      s.pop_back();
      std::snprintf(line, sizeof line, "  %7zu %6zu/%-6zu %6zu\n", r.error_mismatches, r.wrong_answers, r.error_rays, r.leaks);
      s += line;
    }
    if (scaled) {
      s.pop_back();
      std::snprintf(line, sizeof line, " %8.3f %7.2fx\n", r.mrays_one_thread, r.thread_scaling);
      s += line;
    }
  }
  return s;
}

// The report as a JSON document: what --json writes and --csv flattens.
static nlohmann::json report_json(const BenchReport& rep) {
  const std::string& bvh_hash = rep.bvh_hash;
  nlohmann::json j;
  j["machine"] = rep.machine;
  j["cpu"] = rep.cpu;
  j["compiler"] = rep.compiler;
  j["flags"] = rep.flags;
  j["bvh_hash"] = bvh_hash;
  j["records"] = nlohmann::json::array();
  for (const auto& r : rep.records) {
    j["records"].push_back({{"scene", r.scene},
                            {"backend", r.backend},
                            {"isa", r.isa},
                            {"device", r.device},
                            {"layout", r.layout},
                            {"traversal", r.traversal},
                            {"query", r.query},
                            {"ray_kind", r.ray_kind},
                            {"precision", r.precision},
                            {"rays", r.rays},
                            {"threads", r.threads},
                            {"passes", r.passes},
                            {"mrays_per_s", r.mrays_per_s},
                            {"mrays_per_s_min", r.mrays_min},
                            {"mrays_per_s_max", r.mrays_max},
                            {"device_mrays_per_s", r.device_mrays_per_s > 0 ? nlohmann::json(r.device_mrays_per_s)
                                                                            : nlohmann::json(nullptr)},
                            {"state_bytes_per_ray", r.state_bytes_per_ray},
                            {"leaf_block", r.leaf_block},
                            {"peak_state_bytes_per_ray", r.peak_state_bytes_per_ray},
                            {"nodes_per_ray", r.nodes_per_ray},
                            {"box_tests_per_ray", r.box_tests_per_ray},
                            {"leaves_per_ray", r.leaves_per_ray},
                            {"triangles_per_ray", r.tris_per_ray},
                            {"climbs_per_ray", r.climbs_per_ray},
                            {"simd_utilisation", r.simd_utilisation >= 0 ? nlohmann::json(r.simd_utilisation) : nlohmann::json(nullptr)},
                            {"verify_mismatches", r.verify_mismatches},
                            {"verified", r.verified()},
                            {"peer", r.peer},
                            {"error_rays", r.error_rays},
                            {"error_mismatches", r.error_mismatches},
                            {"error_rate", r.error_rays ? double(r.error_mismatches) / double(r.error_rays) : 0.0},
                            {"wrong_answers", r.wrong_answers},
                            {"leaks", r.leaks},
                            {"bitstack_vs_stack", r.ratio_vs_stack},
                            {"vs_cpu", r.ratio_vs_cpu},
                            {"mrays_per_s_1_thread", r.mrays_one_thread},
                            {"thread_scaling", r.thread_scaling},
                            {"histograms", {{"buckets", "0: none; k >= 1: [2^(k-1), 2^k)"},
                                            {"nodes", r.hist_nodes},
                                            {"leaves", r.hist_leaves},
                                            {"triangles", r.hist_tris},
                                            {"climbs", r.hist_climbs}}},
                            {"bvh_hash", bvh_hash}});
  }
  return j;
}

std::string BenchReport::json() const { return report_json(*this).dump(2); }

std::string BenchReport::csv() const { return records_csv(json()); }

std::string records_csv(const std::string& json_text) {
  // the JSON records flattened: one header line (the record's keys, then the run's machine,
  // cpu, compiler and flags), one line per record; strings quoted, quotes doubled
  const nlohmann::json j = nlohmann::json::parse(json_text);
  auto cell = [](const nlohmann::json& v) {
    if (v.is_null()) return std::string();  // not measured: an empty cell
    if (!v.is_string()) return v.dump();
    std::string s = "\"";
    for (char c : v.get<std::string>()) s += c == '"' ? std::string("\"\"") : std::string(1, c);
    return s + "\"";
  };
  std::string out;
  if (j["records"].empty()) return out;
  std::vector<std::string> keys;
  for (const auto& [k, v] : j["records"][0].items())
    if (!v.is_structured()) keys.push_back(k);  // the histograms and per-frame lists stay in the JSON
  const char* run_keys[] = {"machine", "cpu", "compiler", "flags"};
  for (const auto& k : keys) out += k + ",";
  for (const char* k : run_keys) out += std::string(k) + (k == run_keys[3] ? "\n" : ",");
  for (const auto& r : j["records"]) {
    for (const auto& k : keys) out += cell(r[k]) + ",";
    for (const char* k : run_keys) out += cell(j[k]) + (k == run_keys[3] ? "\n" : ",");
  }
  return out;
}

// The speed of `r` over that of the record of `backend` / `traversal` on r's layout, query and
// rays; 0 when that record was not run.
static double speed_ratio(const std::vector<BenchRecord>& all, const BenchRecord& r, const std::string& backend,
                          const std::string& traversal) {
  for (const auto& s : all)
    if (s.backend == backend && s.traversal == traversal && s.layout == r.layout && s.query == r.query &&
        s.ray_kind == r.ray_kind && s.precision == r.precision && s.mrays_per_s > 0)
      return r.mrays_per_s / s.mrays_per_s;
  return 0;
}

// The speed of `r` over that of `backend`'s fastest record on r's query, rays and precision (any
// layout and traversal): dacrt's ratio to a backend that has no dacrt; 0 when there is none.
static double ratio_vs_fastest(const std::vector<BenchRecord>& all, const BenchRecord& r, const std::string& backend) {
  double best = 0;
  for (const auto& s : all)
    if (s.backend == backend && s.query == r.query && s.ray_kind == r.ray_kind && s.precision == r.precision)
      best = std::max(best, s.mrays_per_s);
  return best > 0 ? r.mrays_per_s / best : 0;
}

ReferenceAnswers::ReferenceAnswers(const Accel& acc, std::vector<Ray> r) : rays(std::move(r)) {
  oracle = oracle_tie_rule(acc, rays);
  settle = oracle_settlement(acc, rays, oracle);
}

void ReferenceAnswers::reference_for(const Accel& acc, Query q, unsigned threads) {
  if (have_ref && ref_query == q) return;
  TraceOptions refo;
  refo.query = q;
  refo.layout = Layout::mbvh4;
  refo.traversal = Traversal::stack;
  ref = {};
  closest = {};
  trace_reference(acc, rays, refo, ref, threads);
  if (q == Query::any) trace_reference(acc, rays, TraceOptions{}, closest, threads);
  have_ref = true;
  ref_query = q;
}

std::size_t ReferenceAnswers::mismatches(const TraceOutput& out, Query q) const {
  if (!have_ref || ref_query != q) throw Error("ReferenceAnswers: no reference answer of that query (reference_for)");
  return (q == Query::any ? compare_occlusion_arrays(out.occluded, ref.occluded, closest.hits, rays)
                          : compare_hit_arrays(out.hits, ref.hits, {}, settle))
      .mismatches;
}

namespace {

// One ray kind's rays and what every variant on them is checked against: ReferenceAnswers, and
// the brute force on a spread subset (BenchOptions::error_rays).
struct KindRays : ReferenceAnswers {
  RayKind kind;
  std::vector<std::size_t> sub;
  std::function<bool(const Ray&, const Hit&)> in_plane;
  std::vector<Hit> brute;

  // `acc`: the build the variants trace; `tree`: a build with a hierarchy of the same scene (acc
  // itself, or run_bench's reference build when acc has none), for the rays and the reference
  // (reference_for(tree, ...)).
  KindRays(const Scene& scene, const Accel& acc, const Accel& tree, const BenchOptions& opt, RayKind k)
      : ReferenceAnswers(acc, generate_rays(scene, tree, ray_options(opt, k))), kind(k) {
    sub = spread_indices(rays.size(), opt.error_rays);
    in_plane = in_plane_rule(acc);
    brute.resize(sub.size());
    parallel_for(sub.size(), 16, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) brute[i] = brute_force(acc, rays[sub[i]]);
    });
  }

  static RayGenOptions ray_options(const BenchOptions& opt, RayKind kind) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = opt.count;
    ro.seed = opt.seed;
    ro.threads = opt.threads;
    ro.has_camera = opt.has_camera;
    ro.camera = opt.camera;
    return ro;
  }
};

// Verifies `out` (the variant's answer) against the reference, and for closest hits measures the
// error against the brute force and the leaks out of a closed mesh.
void verify(const KindRays& k, const TraceOutput& out, const TraceOptions& to, BenchRecord& r) {
  r.verify_mismatches = k.mismatches(out, to.query);
  if (to.query != Query::closest) return;
  r.error_rays = k.sub.size();
  std::vector<Hit> h;
  for (std::size_t i : k.sub) h.push_back(out.hits[i]);
  r.error_mismatches = compare_hit_arrays(h, k.brute, k.sub, k.oracle).mismatches;
  for (std::size_t i = 0; i < k.sub.size(); ++i)
    r.wrong_answers += wrong_answer(h[i], k.brute[i], k.rays[k.sub[i]]) && !k.in_plane(k.rays[k.sub[i]], h[i]) &&
                       !k.in_plane(k.rays[k.sub[i]], k.brute[i]);
  if (k.kind == RayKind::inside)
    for (std::size_t i = 0; i < k.rays.size(); ++i)
      r.leaks += out.hits[i].prim == MBVH_MISS_PRIM && ray_valid(k.rays[i]);
}

// One variant's timing: its backends and options, and its passes' speeds (million rays per
// second) by the host's clock, on one thread (`single`, --scaling) and by the device's clock where
// the backend measures it.
struct Timing {
  Backend* b;
  Backend* single;
  TraceOptions to;
  std::size_t record;  ///< its BenchRecord in the report
  std::vector<double> mr, m1, md;
};

// Warms a variant up for BenchOptions::warmup_seconds, 0.25 s by default (JIT-compiled backends
// such as PoCL reach their speed only after a few dispatches; `single` one pass).
void warm_up(const Accel& acc, const std::vector<Ray>& rays, Timing& v, double warmup_seconds, TraceOutput& out) {
  for (auto w0 = Clock::now(); std::chrono::duration<double>(Clock::now() - w0).count() < warmup_seconds;)
    v.b->trace(acc, rays, v.to, out);
  if (v.single) v.single->trace(acc, rays, v.to, out);
}

// One timed pass of a variant (and of its 1-thread backend right after it).
void time_pass(const Accel& acc, const std::vector<Ray>& rays, Timing& v, TraceOutput& out) {
  const auto timed = [&](Backend& be) {
    const auto t0 = Clock::now();
    be.trace(acc, rays, v.to, out);
    return static_cast<double>(rays.size()) / std::chrono::duration<double>(Clock::now() - t0).count() * 1e-6;
  };
  v.mr.push_back(timed(*v.b));
  if (const double ds = v.b->last_device_seconds(); ds > 0) v.md.push_back(static_cast<double>(rays.size()) / ds * 1e-6);
  if (v.single) v.m1.push_back(timed(*v.single));
}

// The median and spread of a variant's passes into its record.
void finish_timing(const Timing& v, BenchRecord& r) {
  r.mrays_per_s = median(v.mr);
  r.mrays_min = *std::min_element(v.mr.begin(), v.mr.end());
  r.mrays_max = *std::max_element(v.mr.begin(), v.mr.end());
  if (v.md.size() == v.mr.size()) r.device_mrays_per_s = median(v.md);  // every pass measured
  if (v.single) {
    r.mrays_one_thread = median(v.m1);
    r.thread_scaling = r.mrays_per_s / r.mrays_one_thread;
  }
}

// The work per ray, from a separate pass with the backend's own counters: means and histograms.
void count_work(const Accel& acc, const std::vector<Ray>& rays, Backend& b, const TraceOptions& to, BenchRecord& r) {
  TraceOptions so = to;
  so.stats = true;
  TraceOutput st;
  b.trace(acc, rays, so, st);
  double n = 0, bt = 0, lf = 0, tr = 0, cl = 0, peak = 0, lane = 0, group = 0;
  const auto count = [](std::vector<std::uint64_t>& h, std::uint32_t v) {
    const std::size_t k = static_cast<std::size_t>(std::bit_width(v));  // 0 -> 0, [2^(k-1), 2^k) -> k
    if (h.size() <= k) h.resize(k + 1, 0);
    ++h[k];
  };
  for (const RayStats& s : st.stats) {
    n += s.nodes; bt += s.box_tests; lf += s.leaves; tr += s.tris; cl += s.climbs;
    lane += s.lane_ops; group += s.group_ops;
    count(r.hist_nodes, s.nodes);
    count(r.hist_leaves, s.leaves);
    count(r.hist_tris, s.tris);
    count(r.hist_climbs, s.climbs);
    peak += is_dacrt(to.traversal)    ? double(b.state_bytes(to))  // the backend's ray records and side arrays
            : is_packet(to.traversal) ? double(state_bytes_per_ray(to.layout, to.traversal))  // a packet's stack, shared
            : to.traversal == Traversal::stack ? 8.0 + 4.0 * s.max_depth
            : to.traversal == Traversal::stack_ordered || to.traversal == Traversal::stack_octant ? 8.0 + 8.0 * s.max_depth
                                                        : double(state_bytes_per_ray(to.layout, to.traversal));  // bitstacks: fixed
  }
  const double k = rays.empty() ? 1.0 : static_cast<double>(rays.size());
  r.nodes_per_ray = n / k;
  r.box_tests_per_ray = bt / k;
  r.leaves_per_ray = lf / k;
  r.tris_per_ray = tr / k;
  r.climbs_per_ray = cl / k;
  r.peak_state_bytes_per_ray = peak / k;
  r.simd_utilisation = group > 0 ? lane / group : -1;
}

// The machine, compiler and BVH a report was measured on.
void describe_run(const Accel& acc, BenchReport& rep) {
  describe_machine(rep.machine, rep.cpu, rep.compiler, rep.flags);
  char hash[32];
  std::snprintf(hash, sizeof hash, "%016llx", static_cast<unsigned long long>(acc.hash()));
  rep.bvh_hash = hash;
}

}  // namespace

BenchReport run_bench(const Scene& scene, const Accel& acc, const BenchOptions& opt,
                      const std::function<void(std::size_t, std::size_t)>& progress) {
  BenchReport rep;
  describe_run(acc, rep);
  // -- what every result is verified against: the reference traversal (cpu-scalar) on a build with
  // a hierarchy. A build of quality none (the dacrt backends alone) has none, so a medium build of
  // the same scene and options is made for the reference and the rays and kept to the end: the
  // verification stays independent of the dacrt code (dacrt-scalar shares its recursion), and
  // compares the same triangles (the same prim ids), so answers agree up to classified ties
  std::unique_ptr<Accel> reference_build;
  if (!acc.has_hierarchy()) {
    BuildOptions o = acc.options();
    o.quality = BuildQuality::medium;
    o.progress = nullptr;
    reference_build = Accel::build(scene, o);
  }
  const Accel& tree = reference_build ? *reference_build : acc;
  // -- the backends, and with --scaling each once more on one thread
  BackendOptions bo = opt.backend;
  bo.threads = opt.threads;
  const auto backends = make_backends(opt.grid, bo);
  std::map<std::string, std::unique_ptr<Backend>> single;
  const bool scaling = opt.scaling && resolve_threads(opt.threads) > 1;
  if (scaling) {
    BackendOptions one = bo;
    one.threads = 1;
    single = make_backends(opt.grid, one);
  }
  const unsigned passes = std::max(5u, opt.passes);
  const std::size_t total = opt.kinds.size() * opt.grid.size();
  std::size_t done = 0;
  // -- every ray kind: each variant verified (also a warm-up pass), warmed up and its work
  // counted; then timed in rounds, one pass of every variant per round, so a machine whose load
  // drifts (other guests on the host) slows every variant alike and the ratios of one run hold:
  // timed one variant after another, the MBVH8 bitstack/stack ratios of one run spread over
  // 0.85-1.36 on a loaded host
  bool any_variant = false;  // a grid none of whose backends traces anything asked: an Error, not an empty table
  for_each_variant(opt.grid, backends, [&](const std::string&, Backend&, const TraceOptions&) { any_variant = true; });
  if (!any_variant) throw Error(no_variant_message(opt.grid, backends));
  for (RayKind kind : opt.kinds) {
    KindRays k(scene, acc, tree, opt, kind);
    std::vector<Timing> timings;
    TraceOutput scratch;
    for_each_variant(opt.grid, backends, [&](const std::string& bn, Backend& b, const TraceOptions& to) {
      if (opt.first_layout &&
          std::any_of(opt.grid.layouts.begin(), std::find(opt.grid.layouts.begin(), opt.grid.layouts.end(), to.layout),
                      [&](Layout e) { return b.supports(e, to.traversal); }))
        return;  // an earlier layout of the list was run
      k.reference_for(tree, to.query, opt.threads);
      BenchRecord r;
      r.scene = scene.name;
      r.backend = bn;
      r.peer = b.peer();
      r.device = b.describe();
      r.isa = b.isa();
      r.layout = layout_label(to);  // "-" for dacrt
      r.traversal = to_string(to.traversal);
      r.query = to_string(to.query);
      r.ray_kind = to_string(kind);
      r.precision = to_string(to.precision);
      r.rays = k.rays.size();
      r.threads = resolve_threads(opt.threads);
      r.passes = passes;
      r.state_bytes_per_ray = b.state_bytes(to);
      r.leaf_block = b.leaf_block(to);
      TraceOutput out;  // fresh: an entry the backend leaves unwritten cannot pass as another variant's answer
      b.trace(acc, k.rays, to, out);
      verify(k, out, to, r);
      count_work(acc, k.rays, b, to, r);
      timings.push_back(Timing{&b, scaling ? single.at(bn).get() : nullptr, to, rep.records.size(), {}, {}, {}});
      warm_up(acc, k.rays, timings.back(), opt.warmup_seconds, scratch);
      rep.records.push_back(r);
      if (progress) progress(++done, total);
    });
    for (unsigned p = 0; p < passes; ++p)
      for (Timing& v : timings) time_pass(acc, k.rays, v, scratch);
    for (Timing& v : timings) finish_timing(v, rep.records[v.record]);
  }
  // -- ratios side by side from the same run: bitstack / its stack twin, each backend / `cpu`
  for (auto& r : rep.records) {
    if (const std::string twin = to_string(stack_twin(parse_traversal(r.traversal))); twin != r.traversal)
      r.ratio_vs_stack = speed_ratio(rep.records, r, r.backend, twin);
    if (r.backend != "cpu")
      r.ratio_vs_cpu = r.traversal == to_string(Traversal::dacrt) ? ratio_vs_fastest(rep.records, r, "cpu")
                                                                  : speed_ratio(rep.records, r, "cpu", r.traversal);
  }
  return rep;
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// build_bench.cpp — the build benchmark (build_bench.h): ours and the embree peer's build times,
// and the side-by-side trace on two qualities' trees.
#include "host/tools/build_bench.h"

#include <sys/resource.h>

#include <cstring>
#include <nlohmann/json.hpp>

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/tools/stats.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

// Minor page faults of the process so far (every thread's).
double minor_faults() {
  struct rusage u {};
  getrusage(RUSAGE_SELF, &u);
  return static_cast<double>(u.ru_minflt);
}

// Embree's build of `acc`'s triangles, `repeats` times, a fresh device and scene each time
// (device start not timed): the times in ms.
std::vector<double> time_embree(const Accel& acc, const BuildOptions& bo, unsigned repeats, std::vector<double>& faults) {
  BackendOptions eo;
  eo.threads = bo.threads;
  eo.set("embree.quality", to_string(bo.quality));
  TraceOptions to;
  to.layout = Layout::mbvh4;
  to.traversal = Traversal::stack;
  std::vector<double> ms;
  (void)acc.hash();  // the peer's prepare reads it (staleness): made here, outside its timing
  for (unsigned r = 0; r < repeats; ++r) {
    auto be = make_backend("embree", eo);
    const double f0 = minor_faults();
    const auto t0 = Clock::now();
    be->prepare(acc, to);
    ms.push_back(ms_since(t0));
    faults.push_back(minor_faults() - f0);
  }
  return ms;
}

// The same diffuse rays on `acc` and on a tree of quality vs.quality, passes interleaved (this,
// versus, this, ...) so that a machine's changing load hits both alike. The two trees' hits must
// be identical.
VersusResult versus(const Scene& scene, const Accel& acc, const BuildOptions& bo, const VersusOptions& vs) {
  BuildOptions vo = bo;
  vo.quality = parse_quality(vs.quality);
  const auto other = Accel::build(scene, vo);
  RayGenOptions ro;
  ro.kind = RayKind::diffuse;
  ro.count = vs.count;
  ro.threads = bo.threads;
  ro.has_camera = vs.has_camera;
  ro.camera = vs.camera;
  const std::vector<Ray> rays = generate_rays(scene, acc, ro);
  BackendOptions eo;
  eo.threads = bo.threads;
  auto be = make_backend(vs.backend, eo);
  TraceOptions to;
  to.layout = Layout::mbvh4;
  to.traversal = Traversal::stack;
  TraceOutput out[2];
  const Accel* trees[2] = {&acc, other.get()};
  // -- warm-up and check
  for (int t = 0; t < 2; ++t) be->trace(*trees[t], rays, to, out[t]);
  if (std::memcmp(out[0].hits.data(), out[1].hits.data(), rays.size() * sizeof(Hit)) != 0)
    throw Error("build-bench: the " + vs.quality + " tree's hits differ from the " + to_string(bo.quality) + " tree's");
  // -- interleaved passes
  VersusResult v;
  v.quality = vs.quality;
  v.backend = be->name();
  v.rays = rays.size();
  v.passes = vs.passes;
  v.sah_binary = other->binary_stats().sah_cost;
  for (unsigned p = 0; p < vs.passes; ++p) {
    double sec[2];
    for (int t = 0; t < 2; ++t) {
      const auto t0 = Clock::now();
      be->trace(*trees[t], rays, to, out[t]);
      sec[t] = ms_since(t0) * 1e-3;
      (t == 0 ? v.mrays : v.versus_mrays).push_back(double(rays.size()) / sec[t] * 1e-6);
    }
    v.ratios.push_back(sec[1] / sec[0]);  // this tree's speed over the versus tree's
  }
  return v;
}

}  // namespace

BuildBenchReport run_build_bench(const Scene& scene, const BuildBenchOptions& o) {
  const BuildOptions& bo = o.build;
  BuildBenchReport r;
  // -- ours: build and MBVH4, each from scratch
  std::unique_ptr<Accel> acc;
  for (unsigned k = 0; k < o.repeats; ++k) {
    acc.reset();
    const double f0 = minor_faults();
    const auto t0 = Clock::now();
    acc = Accel::build(scene, bo);
    acc->mbvh4();
    r.build_ms.push_back(ms_since(t0));
    r.faults.push_back(minor_faults() - f0);
    for (int p = 0; p < 4; ++p) r.phase_ms[p].push_back(acc->binary_stats().phase_ms[p]);
    r.phase_ms[4].push_back(acc->mbvh4().stats.build_ms);
  }
  r.scene = scene.name;
  r.triangles = scene.triangle_count();
  r.threads = resolve_threads(bo.threads);
  r.quality = bo.quality;
  r.repeats = o.repeats;
  r.hash = acc->hash();
  r.references = acc->tris().size();
  r.sah_binary = acc->binary_stats().sah_cost;
  r.sah_mbvh4 = acc->mbvh4().stats.sah_cost;
  // -- embree's, where it is built in
  bool have_embree = false;
  for (const BackendInfo& b : list_backends()) have_embree |= b.name == "embree" && b.make != nullptr;
  if (have_embree) r.embree_build_ms = time_embree(*acc, bo, o.repeats, r.embree_faults);
  // -- rebuilds in a kept context: two untimed builds fill it, then each timed one reuses it
  if (o.rebuild) {
    BuildOptions ro = bo;
    ro.context = std::make_shared<BuildContext>();
    std::unique_ptr<Accel> kept;
    for (unsigned k = 0; k < 2 + o.repeats; ++k) {
      const double f0 = minor_faults();
      const auto t0 = Clock::now();
      kept = Accel::build(scene, ro);  // the previous build is destroyed after: its arrays go back then
      kept->mbvh4();
      const double ms = ms_since(t0), f = minor_faults() - f0;
      if (kept->hash() != r.hash) throw Error("build-bench: a rebuild in a kept context differs from the build");
      if (k < 2) continue;
      r.rebuild_ms.push_back(ms);
      r.rebuild_faults.push_back(f);
      for (int p = 0; p < 4; ++p) r.rebuild_phase_ms[p].push_back(kept->binary_stats().phase_ms[p]);
      r.rebuild_phase_ms[4].push_back(kept->mbvh4().stats.build_ms);
    }
  }
  // -- side by side with another quality
  if (!o.versus.quality.empty()) r.versus = versus(scene, *acc, bo, o.versus);
  return r;
}

std::string build_bench_json(const BuildBenchReport& r) {
  nlohmann::json j;
  j["scene"] = r.scene;
  j["triangles"] = r.triangles;
  j["threads"] = r.threads;
  j["quality"] = to_string(r.quality);
  j["repeats"] = r.repeats;
  j["hash"] = r.hash;
  j["references"] = r.references;
  j["sah_binary"] = r.sah_binary;
  j["sah_mbvh4"] = r.sah_mbvh4;
  j["build_ms"] = median(r.build_ms);
  j["build_ms_all"] = r.build_ms;
  const double tris = double(std::max<std::size_t>(r.triangles, 1));
  j["faults"] = median(r.faults);
  // each build's, in order: a median of a few builds hides that the first ones fault in fresh
  // pages as the heap grows to fit a build (glibc), and the later ones none
  j["faults_all"] = r.faults;
  j["faults_per_triangle"] = median(r.faults) / tris;
  // the first build of each in this process: a process that builds once pays these
  if (!r.faults.empty()) j["faults_first_per_triangle"] = r.faults[0] / tris;
  if (!r.embree_faults.empty()) j["embree_faults_first_per_triangle"] = r.embree_faults[0] / tris;
  if (!r.embree_faults.empty()) {
    j["embree_faults"] = median(r.embree_faults);
    j["embree_faults_all"] = r.embree_faults;
    j["embree_faults_per_triangle"] = median(r.embree_faults) / tris;
  }
  if (!r.rebuild_ms.empty()) {
    j["rebuild_ms"] = median(r.rebuild_ms);
    j["rebuild_ms_all"] = r.rebuild_ms;
    j["rebuild_faults"] = median(r.rebuild_faults);
    j["rebuild_faults_all"] = r.rebuild_faults;
    j["rebuild_faults_per_triangle"] = median(r.rebuild_faults) / tris;
    j["rebuild_speedup"] = median(r.build_ms) / median(r.rebuild_ms);
    j["rebuild_phases_ms"] = {{"records", median(r.rebuild_phase_ms[0])}, {"tree", median(r.rebuild_phase_ms[1])},
                              {"flatten", median(r.rebuild_phase_ms[2])}, {"stats", median(r.rebuild_phase_ms[3])},
                              {"mbvh4", median(r.rebuild_phase_ms[4])}};
  }
  j["phases_ms"] = {{"records", median(r.phase_ms[0])}, {"tree", median(r.phase_ms[1])},
                    {"flatten", median(r.phase_ms[2])}, {"stats", median(r.phase_ms[3])},
                    {"mbvh4", median(r.phase_ms[4])}};
  if (r.embree_build_ms) {
    j["embree_build_ms"] = median(*r.embree_build_ms);
    j["embree_build_ms_all"] = *r.embree_build_ms;
  } else {
    j["embree_build_ms"] = nullptr;
  }
  if (r.versus) {
    const VersusResult& v = *r.versus;
    nlohmann::json x;
    x["quality"] = v.quality;
    x["backend"] = v.backend;
    x["rays"] = v.rays;
    x["passes"] = v.passes;
    x["mrays_per_s"] = median(v.mrays);
    x["versus_mrays_per_s"] = median(v.versus_mrays);
    x["speed_ratio"] = median(v.ratios);
    x["sah_binary"] = v.sah_binary;
    j["versus"] = x;
  }
  return j.dump(2) + "\n";
}

}  // namespace mbvh

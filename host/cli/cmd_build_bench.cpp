// SPDX-License-Identifier: MIT
// cmd_build_bench.cpp — `mbvh build-bench`: build time of our builder (Accel::build, then the
// MBVH4 collapse) and of the embree peer (rtcCommitScene on the build's triangles, each prim
// once, with the triangle copy), median of --repeats fresh builds each, at --threads; and our
// tree's SAH cost. Embree is left out with a note where it is not built in. With --versus, the
// same diffuse rays traced on this tree and on one of another quality, side by side.
#include <algorithm>
#include <cstring>
#include <nlohmann/json.hpp>

#include "host/cli/commands.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"

namespace mbvh::cli {

namespace {

// --versus and its options.
struct VersusArgs {
  std::string quality;         // "": no side-by-side trace
  std::string backend = "cpu";
  std::size_t count = 200000;  // diffuse rays
  unsigned passes = 15;
  std::vector<float> camera;
};

struct BuildBenchArgs {
  SceneArgs scene;
  unsigned repeats = 5;
  std::string json;
  VersusArgs versus;
};

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

// Embree's build of `acc`'s triangles, `repeats` times, a fresh device and scene each time
// (device start not timed): the times in ms.
std::vector<double> time_embree(const Accel& acc, const BuildOptions& bo, unsigned repeats) {
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
    const auto t0 = Clock::now();
    be->prepare(acc, to);
    ms.push_back(ms_since(t0));
  }
  return ms;
}

// --versus: the same diffuse rays on `acc` and on a tree of quality vs.quality, passes
// interleaved (this, versus, this, ...) so that a machine's changing load hits both alike; the
// ratio is the median of the per-pair ratios. The two trees' hits must be identical.
nlohmann::json versus(const Scene& scene, const Accel& acc, const BuildOptions& bo, const VersusArgs& vs) {
  BuildOptions vo = bo;
  vo.quality = parse_quality(vs.quality);
  const auto other = Accel::build(scene, vo);
  RayGenOptions ro;
  ro.kind = RayKind::diffuse;
  ro.count = vs.count;
  ro.threads = bo.threads;
  set_camera(vs.camera, ro.has_camera, ro.camera);
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
  std::vector<double> mr[2], ratio;
  for (unsigned p = 0; p < vs.passes; ++p) {
    double sec[2];
    for (int t = 0; t < 2; ++t) {
      const auto t0 = Clock::now();
      be->trace(*trees[t], rays, to, out[t]);
      sec[t] = ms_since(t0) * 1e-3;
      mr[t].push_back(double(rays.size()) / sec[t] * 1e-6);
    }
    ratio.push_back(sec[1] / sec[0]);  // this tree's speed over the versus tree's
  }
  nlohmann::json v;
  v["quality"] = vs.quality;
  v["backend"] = be->name();
  v["rays"] = rays.size();
  v["passes"] = vs.passes;
  v["mrays_per_s"] = median(mr[0]);
  v["versus_mrays_per_s"] = median(mr[1]);
  v["speed_ratio"] = median(ratio);
  v["sah_binary"] = other->binary_stats().sah_cost;
  say("  %s, %zu diffuse rays, %u interleaved passes: %s %.3f Mrays/s, %s %.3f Mrays/s, speed %s/%s %.3fx (median of per-pair ratios; min %.3f, max %.3f)\n",
      be->name().c_str(), rays.size(), vs.passes, to_string(bo.quality), median(mr[0]), vs.quality.c_str(),
      median(mr[1]), to_string(bo.quality), vs.quality.c_str(), median(ratio), *std::min_element(ratio.begin(), ratio.end()),
      *std::max_element(ratio.begin(), ratio.end()));
  return v;
}

int run_build_bench(const BuildBenchArgs& a) {
  if (!a.scene.cache.empty())
    throw Error("--cache " + a.scene.cache + ": build-bench times builds from scratch and never reads or writes the BVH cache");
  prepare_outputs({{"--json", a.json, true}}, {{"scene", a.scene.scene}});
  if (!a.versus.quality.empty()) require_ray_memory("--versus-count " + std::to_string(a.versus.count), a.versus.count);
  const Scene scene = load_scene(a.scene.scene);
  const BuildOptions bo = a.scene.build_options();
  // -- ours: build and MBVH4, each from scratch
  std::vector<double> ours;
  std::vector<double> phase[5];  // records, tree, flatten, stats, MBVH4
  std::unique_ptr<Accel> acc;
  for (unsigned r = 0; r < a.repeats; ++r) {
    acc.reset();
    const auto t0 = Clock::now();
    acc = Accel::build(scene, bo);
    acc->mbvh4();
    ours.push_back(ms_since(t0));
    for (int k = 0; k < 4; ++k) phase[k].push_back(acc->binary_stats().phase_ms[k]);
    phase[4].push_back(acc->mbvh4().stats.build_ms);
  }
  nlohmann::json j;
  j["scene"] = scene.name;
  j["triangles"] = scene.triangle_count();
  j["threads"] = resolve_threads(a.scene.threads);
  j["quality"] = to_string(bo.quality);
  j["repeats"] = a.repeats;
  j["hash"] = acc->hash();
  j["references"] = acc->tris().size();
  j["sah_binary"] = acc->binary_stats().sah_cost;
  j["sah_mbvh4"] = acc->mbvh4().stats.sah_cost;
  j["build_ms"] = median(ours);
  j["build_ms_all"] = ours;
  j["phases_ms"] = {{"records", median(phase[0])}, {"tree", median(phase[1])}, {"flatten", median(phase[2])},
                    {"stats", median(phase[3])}, {"mbvh4", median(phase[4])}};
  say("%s, %zu triangles, quality %s, %u threads: ours %.1f ms (build + MBVH4, median of %u), SAH %.2f, %zu references\n",
      scene.name.c_str(), scene.triangle_count(), to_string(bo.quality), resolve_threads(a.scene.threads), median(ours),
      a.repeats, acc->binary_stats().sah_cost, acc->tris().size());
  say("  ours by phase (medians): records %.1f, tree %.1f, flatten %.1f, stats %.1f, MBVH4 %.1f ms\n",
      median(phase[0]), median(phase[1]), median(phase[2]), median(phase[3]), median(phase[4]));
  // -- embree's, where it is built in
  bool have_embree = false;
  for (const BackendInfo& b : list_backends()) have_embree |= b.name == "embree" && b.make != nullptr;
  if (have_embree) {
    const std::vector<double> embree = time_embree(*acc, bo, a.repeats);
    j["embree_build_ms"] = median(embree);
    j["embree_build_ms_all"] = embree;
    say("  embree %.1f ms (rtcCommitScene with the triangle copy, median of %u)\n", median(embree), a.repeats);
  } else {
    j["embree_build_ms"] = nullptr;
    say("  embree: not built in\n");
  }
  // -- side by side with another quality
  if (!a.versus.quality.empty()) j["versus"] = versus(scene, *acc, bo, a.versus);
  if (!a.json.empty()) {
    const std::string text = j.dump(2) + "\n";
    write_bytes_to({"--json", a.json, true}, text.data(), text.size());
  }
  return 0;
}

}  // namespace

Command add_build_bench(CLI::App& app) {
  auto a = std::make_shared<BuildBenchArgs>();
  VersusArgs& vs = a->versus;
  auto* c = app.add_subcommand("build-bench", "build time (median of --repeats) of ours and of the embree peer, and our tree's SAH");
  a->scene.add(c);
  c->add_option("--repeats", a->repeats, "builds timed per builder (median reported)")->check(integer_in(1, 1000));
  c->add_option("--json", a->json, "also write the results as JSON ('-': standard output)");
  c->add_option("--versus", vs.quality,
                "also trace diffuse rays on this tree and on one of quality VERSUS, passes interleaved, and "
                "report the speed ratio (median of per-pair ratios)")
      ->check(CLI::IsMember({"low", "medium", "high"}));
  c->add_option("--versus-backend", vs.backend, "backend of --versus (default cpu)");
  c->add_option("--versus-count", vs.count, "diffuse rays of --versus")->check(ray_count());
  c->add_option("--versus-passes", vs.passes, "interleaved pass pairs of --versus")->check(integer_in(1, 100000));
  add_camera_option(c, vs.camera);
  return {c, [a] { return run_build_bench(*a); }};
}

}  // namespace mbvh::cli

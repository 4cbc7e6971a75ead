// SPDX-License-Identifier: MIT
// cmd_build_bench.cpp — `mbvh build-bench`: the build benchmark (host/tools/build_bench.h) from
// its options, its report printed (and written as JSON with --json). Embree is left out with a
// note where it is not built in.
#include <algorithm>

#include "host/cli/commands.h"
#include "host/tools/build_bench.h"

namespace mbvh::cli {

namespace {

struct BuildBenchArgs {
  SceneArgs scene;
  unsigned repeats = 5;
  bool rebuild = false;
  std::string json;
  VersusOptions versus;
  std::vector<float> camera;  // --camera of --versus
};

void print(const BuildBenchReport& r) {
  const char* q = to_string(r.quality);
  say("%s, %zu triangles, quality %s, %u threads: ours %.1f ms (build + MBVH4, median of %u), SAH %.2f, %zu references\n",
      r.scene.c_str(), r.triangles, q, r.threads, median(r.build_ms), r.repeats, r.sah_binary, r.references);
  const double tris = double(std::max<std::size_t>(r.triangles, 1));
  say("  ours: %.0f minor page faults (%.4f per triangle, median; the first build %.4f)\n", median(r.faults),
      median(r.faults) / tris, r.faults[0] / tris);
  say("  ours by phase (medians): records %.1f, tree %.1f, flatten %.1f, stats %.1f, MBVH4 %.1f ms\n",
      median(r.phase_ms[0]), median(r.phase_ms[1]), median(r.phase_ms[2]), median(r.phase_ms[3]), median(r.phase_ms[4]));
  if (r.embree_build_ms)
    say("  embree %.1f ms (rtcCommitScene with the triangle copy, median of %u)\n", median(*r.embree_build_ms),
        r.repeats);
  else
    say("  embree: not built in\n");
  if (!r.embree_faults.empty())
    say("  embree: %.0f minor page faults (%.4f per triangle, median; the first build %.4f)\n", median(r.embree_faults),
        median(r.embree_faults) / tris, r.embree_faults[0] / tris);
  if (!r.rebuild_ms.empty())
    say("  rebuild in a kept BuildContext: %.1f ms (median of %u), %.0f minor page faults (%.4f per triangle); "
        "cold build / rebuild %.2fx\n",
        median(r.rebuild_ms), r.repeats, median(r.rebuild_faults), median(r.rebuild_faults) / tris,
        median(r.build_ms) / median(r.rebuild_ms));
  if (!r.rebuild_ms.empty())
    say("  rebuild by phase (medians): records %.1f, tree %.1f, flatten %.1f, stats %.1f, MBVH4 %.1f ms\n",
        median(r.rebuild_phase_ms[0]), median(r.rebuild_phase_ms[1]), median(r.rebuild_phase_ms[2]),
        median(r.rebuild_phase_ms[3]), median(r.rebuild_phase_ms[4]));
  if (const auto& v = r.versus)
    say("  %s, %zu diffuse rays, %u interleaved passes: %s %.3f Mrays/s, %s %.3f Mrays/s, speed %s/%s %.3fx (median of "
        "per-pair ratios; min %.3f, max %.3f)\n",
        v->backend.c_str(), v->rays, v->passes, q, median(v->mrays), v->quality.c_str(), median(v->versus_mrays), q,
        v->quality.c_str(), median(v->ratios), *std::min_element(v->ratios.begin(), v->ratios.end()),
        *std::max_element(v->ratios.begin(), v->ratios.end()));
}

int run(BuildBenchArgs a) {
  // -- options
  if (!a.scene.cache.empty())
    throw Error("--cache " + a.scene.cache + ": build-bench times builds from scratch and never reads or writes the BVH cache");
  if (a.scene.build_options().quality == BuildQuality::none)
    throw Error("--quality none: build-bench times hierarchies (the build and its MBVH4), and a build of quality none "
                "has none; use low, medium or high");
  prepare_outputs({{"--json", a.json, true}}, {{"scene", a.scene.scene}});
  if (!a.versus.quality.empty()) require_ray_memory("--versus-count " + std::to_string(a.versus.count), a.versus.count);
  if (!a.versus.quality.empty()) set_camera(a.camera, a.versus.has_camera, a.versus.camera);
  const Scene scene = load_scene(a.scene.scene);
  BuildBenchOptions o;
  o.build = a.scene.build_options();
  o.repeats = a.repeats;
  o.rebuild = a.rebuild;
  o.versus = a.versus;
  // -- run, print, write
  const BuildBenchReport r = run_build_bench(scene, o);
  print(r);
  if (!a.json.empty()) {
    const std::string text = build_bench_json(r);
    write_bytes_to({"--json", a.json, true}, text.data(), text.size());
  }
  return 0;
}

}  // namespace

Command add_build_bench(CLI::App& app) {
  auto a = std::make_shared<BuildBenchArgs>();
  VersusOptions& vs = a->versus;
  auto* c = app.add_subcommand("build-bench", "build time (median of --repeats) of ours and of the embree peer, and our tree's SAH");
  a->scene.add(c);
  c->add_option("--repeats", a->repeats, "builds timed per builder (median reported)")->check(integer_in(1, 1000));
  c->add_flag("--rebuild", a->rebuild,
              "also time --repeats rebuilds in one kept BuildContext (after two untimed ones), each made while the "
              "previous build is alive, and report cold build / rebuild");
  c->add_option("--json", a->json, "also write the results as JSON ('-': standard output)");
  c->add_option("--versus", vs.quality,
                "also trace diffuse rays on this tree and on one of quality VERSUS, passes interleaved, and "
                "report the speed ratio (median of per-pair ratios)")
      ->check(CLI::IsMember({"low", "medium", "high"}));
  c->add_option("--versus-backend", vs.backend, "backend of --versus (default cpu)");
  c->add_option("--versus-count", vs.count, "diffuse rays of --versus")->check(ray_count());
  c->add_option("--versus-passes", vs.passes, "interleaved pass pairs of --versus")->check(integer_in(1, 100000));
  add_camera_option(c, a->camera);
  return {c, [a] { return run(*a); }};
}

}  // namespace mbvh::cli

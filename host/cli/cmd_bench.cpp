// SPDX-License-Identifier: MIT
// cmd_bench.cpp — `mbvh bench`: speed (rays per second), traversal state and work per ray of every variant,
// verified before timing (host/tools/bench.h); exit status 1 when a timed result did not verify.
#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/tools/bench.h"

namespace mbvh::cli {

namespace {

struct BenchArgs {
  SceneArgs scene;
  GridArgs grid;
  std::string kinds = "primary,diffuse", json, csv;
  std::size_t count = 100000, error_rays = 0;
  unsigned passes = 5;
  std::uint64_t seed = 1;
  double warmup = 0.25;
  bool first_layout = false, scaling = false;
  std::vector<float> camera;
};

// The benchmark's options from the arguments; `scene` gets quality none when every backend is a
// dacrt backend and --quality is not given.
BenchOptions bench_options(const BenchArgs& a, SceneArgs& scene) {
  BenchOptions bo;
  bo.grid = a.grid.parse();
  scene.no_hierarchy_for(bo.grid.backends);
  bo.kinds = parse_list<RayKind>(a.kinds, parse_ray_kind);
  bo.count = a.count;
  bo.error_rays = a.error_rays;
  bo.seed = a.seed;
  bo.passes = a.passes;
  bo.warmup_seconds = a.warmup;
  bo.first_layout = a.first_layout;
  bo.scaling = a.scaling;
  bo.threads = a.scene.threads;
  bo.backend = a.grid.dev.options(a.scene.threads, scene.quality);
  set_camera(a.camera, bo.has_camera, bo.camera);
  return bo;
}

// The traversal state per ray of each traversal, after the table.
void print_state_sizes() {
  const double bit = double(state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack));
  say("\ntraversal state per ray: stack %zu B (64 x int32 + sp + node; MBVH4: 1 + 3x21 entries), ordered "
      "stack %zu B (64 x (node, distance)), bitstack %.0f B (node + 64-bit word): %.0fx and %.0fx smaller; "
      "MBVH8 stack %zu B and ordered stack %zu B (128 entries), bitstack %zu B (node + 128-bit word)\n",
      state_bytes_per_ray(Layout::mbvh4, Traversal::stack), state_bytes_per_ray(Layout::mbvh4, Traversal::stack_ordered),
      bit, double(state_bytes_per_ray(Layout::mbvh4, Traversal::stack)) / bit,
      double(state_bytes_per_ray(Layout::mbvh4, Traversal::stack_ordered)) / bit,
      state_bytes_per_ray(Layout::mbvh8, Traversal::stack), state_bytes_per_ray(Layout::mbvh8, Traversal::stack_ordered),
      state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack));
}

int run_bench_command(const BenchArgs& a) {
  const std::vector<OutputTarget> outs{{"--json", a.json, true}, {"--csv", a.csv, true}};
  prepare_outputs(outs, {{"scene", a.scene.scene}});
  // -- run
  SceneArgs scene = a.scene;
  const BenchOptions bo = bench_options(a, scene);
  require_ray_memory("--count " + std::to_string(a.count), std::uint64_t(a.count) + a.error_rays);
  Loaded l = load_and_build(scene);
  Progress p("benchmarking", bo.kinds.size() * bo.grid.size());
  BenchReport rep = run_bench(l.scene, *l.acc, bo, [&p](std::size_t d, std::size_t) { p.update(d); });
  p.finish();
  // -- report
  say("scene %s, %zu triangles, BVH hash %s\ncpu %s, %u threads\n\n%s", l.scene.name.c_str(), l.scene.triangle_count(),
      rep.bvh_hash.c_str(), rep.cpu.c_str(), resolve_threads(a.scene.threads), rep.table().c_str());
  print_state_sizes();
  // -- the records: both outputs or neither
  const std::string json = rep.json() + "\n", csv = rep.csv();
  std::vector<OutputWrite> writes;
  if (!a.json.empty()) writes.push_back({outs[0], json.data(), json.size()});
  if (!a.csv.empty()) writes.push_back({outs[1], csv.data(), csv.size()});
  write_outputs(writes);
  for (const OutputWrite& w : writes) say("wrote %s\n", shown(w.to.path).c_str());
  if (!rep.verified()) {
    std::fprintf(stderr, "error: some timed results did not match the reference (see 'verified')\n");
    return 1;
  }
  return 0;
}

}  // namespace

Command add_bench(CLI::App& app) {
  auto a = std::make_shared<BenchArgs>();
  auto* c = app.add_subcommand("bench", "Mrays/s, traversal state and work per ray, verified before timing");
  a->scene.add(c);
  a->grid.add(c);
  c->add_option("--kinds", a->kinds, "comma-separated ray kinds");
  c->add_option("--count", a->count, "rays per kind")->check(ray_count());
  c->add_option("--error-rays", a->error_rays,
                "rays per kind whose closest hits are also compared with the double-precision brute force "
                "(error_rate in the records; inside rays also count leaks)")
      ->check(integer_in(0, fits_in_memory(kBytesPerRay)));
  c->add_option("--seed", a->seed, "ray seed")->check(integer_in(0, UINT64_MAX));
  c->add_option("--passes", a->passes, "timed passes after the warm-up (at least 5)")->check(integer_in(5, 1000000));
  c->add_flag("--first-layout", a->first_layout,
              "per backend and traversal, only the first layout of --layout it has (mbvh4,mbvh2: MBVH4, else MBVH2)");
  c->add_option("--warmup", a->warmup, "seconds of untimed passes before the timed ones (after the verifying pass)")
      ->check(number_in(0, 3600));
  add_camera_option(c, a->camera);
  c->add_option("--json", a->json, "write the records as JSON ('-': standard output)");
  c->add_option("--csv", a->csv, "write the records as CSV, one line per record ('-': standard output)");
  c->add_flag("--scaling", a->scaling,
              "also time each variant on 1 thread, passes interleaved with the N-thread ones (thread scaling)");
  return {c, [a] { return run_bench_command(*a); }};
}

}  // namespace mbvh::cli

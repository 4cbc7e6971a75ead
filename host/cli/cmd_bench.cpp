// SPDX-License-Identifier: MIT
// cmd_bench.cpp — `mbvh bench`: speed (rays per second), traversal state and work per ray of every variant,
// verified before timing (host/tools/bench.h); exit status 1 when a timed result did not verify.
#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/tools/bench.h"
#include "host/tools/bench_dynamic.h"

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
  unsigned dynamic = 0, width = 1024, height = 768;  ///< --dynamic frames (0: the static benchmark)
  CLI::App* app = nullptr;  ///< which options were given (--dynamic's own defaults)
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

// --dynamic: the frames' options. Options not given take --dynamic's defaults: kinds primary
// and shadow, each its own query (shadow any hit), the default traversal (bitstack) on MBVH4 or
// the first layout a backend has; a backend with none of them its own first pair (dacrt).
DynamicOptions dynamic_options(const BenchArgs& a) {
  const auto given = [&a](const char* o) { return a.app->count(o) > 0; };
  DynamicOptions d;
  d.grid = a.grid.parse();
  if (!given("--layout")) d.grid.layouts = {Layout::mbvh4, Layout::mbvh2, Layout::mbvh8};
  d.first_layout = !given("--layout") || a.first_layout;
  if (!given("--traversal")) d.grid.traversals = {Traversal::bitstack};
  if (!given("--query")) d.grid.queries.clear();
  d.kinds = parse_list<RayKind>(given("--kinds") ? a.kinds : "primary,shadow", parse_ray_kind);
  d.frames = a.dynamic;
  d.width = a.width;
  d.height = a.height;
  if (given("--count")) d.count = a.count;
  d.seed = a.seed;
  d.threads = a.scene.threads;
  d.build = a.scene.build_options();
  d.backend = a.grid.dev.options(a.scene.threads, a.scene.quality);
  set_camera(a.camera, d.has_camera, d.camera);
  return d;
}

// Writes the --json and --csv records (both or neither) and reports them.
void write_records(const std::vector<OutputTarget>& outs, const BenchArgs& a, const std::string& json_text,
                   const std::string& csv) {
  const std::string json = json_text + "\n";
  std::vector<OutputWrite> writes;
  if (!a.json.empty()) writes.push_back({outs[0], json.data(), json.size()});
  if (!a.csv.empty()) writes.push_back({outs[1], csv.data(), csv.size()});
  write_outputs(writes);
  for (const OutputWrite& w : writes) say("wrote %s\n", shown(w.to.path).c_str());
}

// `mbvh bench --dynamic N`: the frames of a moving scene, rebuild / refit / update + trace.
int run_dynamic_command(const BenchArgs& a, const std::vector<OutputTarget>& outs) {
  const DynamicOptions d = dynamic_options(a);
  require_ray_memory("--dynamic rays", d.count > 0 ? 2 * std::uint64_t(d.count) : 2ull * d.width * d.height);
  Loaded l = load_and_build(a.scene);
  Progress p("dynamic frames", d.frames);
  const DynamicReport rep = run_dynamic(l.scene, *l.acc, d, [&p](std::size_t f, std::size_t) { p.update(f); });
  p.finish();
  say("scene %s, %zu triangles (%zu degenerate left out: a displacement would give them area, which a refit refuses), "
      "%u frames moved by the smooth displacement (info --refit's, its phase by frame)\ncpu %s, %u threads\n\n%s",
      l.scene.name.c_str(), l.scene.triangle_count(), rep.left_out, d.frames, rep.cpu.c_str(),
      resolve_threads(a.scene.threads), rep.table().c_str());
  say("\nmodes: rebuild = Accel::build of the moved scene, refit = Accel::refit of the first frame's build, update = "
      "refit of a flat build (no hierarchy), each + the trace of every kind; x update: ms/frame over the update lane's; "
      "held: resident bytes a lane keeps between frames, peak+: its step's resident peak above the size before it\n");
  write_records(outs, a, rep.json(), rep.csv());
  if (!rep.verified()) {
    std::fprintf(stderr, "error: some frames' answers did not match the reference (see 'verified')\n");
    return 1;
  }
  return 0;
}

int run_bench_command(const BenchArgs& a) {
  const std::vector<OutputTarget> outs{{"--json", a.json, true}, {"--csv", a.csv, true}};
  prepare_outputs(outs, {{"scene", a.scene.scene}});
  if (a.dynamic > 0) return run_dynamic_command(a, outs);
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
  write_records(outs, a, rep.json(), rep.csv());
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
  a->app = c;
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
  auto* scaling = c->add_flag("--scaling", a->scaling,
              "also time each variant on 1 thread, passes interleaved with the N-thread ones (thread scaling)");
  // --dynamic: frames of a moving scene (host/tools/bench_dynamic.h)
  auto* dynamic = c->add_option("--dynamic", a->dynamic,
                                "time N frames of the scene moved by a smooth displacement (info --refit's, its phase by "
                                "frame): per frame and backend, rebuild+trace and refit+trace (or update+trace for a "
                                "backend that needs no hierarchy) on the same rays, each frame verified; defaults: "
                                "--kinds primary,shadow (shadow rays any hit), the default traversal, a 1024x768 image")
                      ->check(integer_in(1, 100000));
  dynamic->excludes(scaling);
  for (const char* o : {"--error-rays", "--passes", "--warmup"}) dynamic->excludes(c->get_option(o));
  auto* width = c->add_option("--width", a->width, "--dynamic: primary rays of a W x H image (default 1024)")
                    ->check(integer_in(1, 65536))
                    ->needs(dynamic);
  auto* height = c->add_option("--height", a->height, "--dynamic: primary rays of a W x H image (default 768)")
                     ->check(integer_in(1, 65536))
                     ->needs(dynamic);
  for (auto* o : {width, height}) o->excludes(c->get_option("--count"));
  return {c, [a] { return run_bench_command(*a); }};
}

}  // namespace mbvh::cli

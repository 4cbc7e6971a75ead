// SPDX-License-Identifier: MIT
// cmd_info.cpp — `mbvh info`: the scene and per-layout build statistics, as a table and as JSON;
// with --refit, a refit of the build timed beside a rebuild.
#include <nlohmann/json.hpp>

#include "host/cli/commands.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/tools/displace.h"

namespace mbvh::cli {

namespace {

constexpr unsigned kCpuLeafBlock = 4;  // the SIMD cpu backends' own leaf block (backends/cpu)

// The MBVH4 and MBVH8 statistics of the cpu backends' own leaves, named mbvh4:4 and mbvh8:4.
std::pair<LayoutStats, LayoutStats> cpu_leaf_stats(const Accel& acc) {
  const LeafVariant& lv = acc.leaf_variant(kCpuLeafBlock);
  std::pair<LayoutStats, LayoutStats> s{lv.mbvh4().stats, lv.mbvh8().stats};
  s.first.layout = "mbvh4:4";
  s.second.layout = "mbvh8:4";
  return s;
}

// What a build holds at three points (Accel::memory): right after the build, once the cpu
// backend's default traces are prepared (TraceOptions{}, closest and any hit) and once every
// layout the table shows is made; and the scene's own arrays.
struct MemoryReport {
  Accel::MemoryStats build, traced, all;
  std::size_t scene = 0, triangles = 1;
};

// The build's memory now, then with the default cpu traces prepared (where the cpu backend runs).
MemoryReport memory_report(const Loaded& l) {
  MemoryReport m;
  m.build = l.acc->memory();
  m.scene = l.scene.memory_bytes();
  m.triangles = std::max<std::size_t>(l.acc->scene_triangles(), 1);
  m.traced = m.build;
  if (l.acc->has_hierarchy()) {
    auto cpu = make_backend("cpu");
    TraceOptions to;
    cpu->prepare(*l.acc, to);
    to.query = Query::any;
    cpu->prepare(*l.acc, to);
    m.traced = l.acc->memory();
  }
  return m;
}

void print_memory_row(const char* what, const Accel::MemoryStats& s, std::size_t n) {
  const double t = double(n), total = double(s.total());
  say("  %-30s %8.2f MB %8.1f B/tri (tree %.1f, nodes %.1f, triangles %.1f, packs %.1f)\n", what, total / 1e6,
      total / t, double(s.tree) / t, double(s.nodes) / t, double(s.triangles) / t, double(s.packs) / t);
}

void print_memory(const MemoryReport& m) {
  say("\nmemory held by the build (Accel::memory; MB = 10^6 bytes, per scene triangle):\n");
  print_memory_row("after the build", m.build, m.triangles);
  print_memory_row("+ cpu default traces prepared", m.traced, m.triangles);
  print_memory_row("+ every layout above", m.all, m.triangles);
  say("  %-30s %8.2f MB %8.1f B/tri (the caller's, not the build's)\n", "scene arrays", double(m.scene) / 1e6,
      double(m.scene) / double(m.triangles));
}

nlohmann::json memory_json(const Accel::MemoryStats& s) {
  return {{"tree", s.tree}, {"nodes", s.nodes}, {"triangles", s.triangles}, {"packs", s.packs}, {"total", s.total()}};
}

struct InfoArgs {
  SceneArgs scene;
  std::string json;
  bool refit = false;
};

void print_stats_row(const LayoutStats& s, std::size_t state_stack, std::size_t state_bit) {
  say("%-7s %9zu %9zu %6u %9u %10.2f %12zu %9.1f %10zu %10zu\n", s.layout.c_str(), s.nodes, s.leaves, s.depth,
      s.bitstack_bits, s.sah_cost, s.bytes, s.build_ms, state_stack, state_bit);
}

// The report of a build without a hierarchy (quality none): its triangles, bounds and hash.
void print_flat_info(const SceneArgs& a, const Loaded& l) {
  const Accel& acc = *l.acc;
  const double* ph = acc.binary_stats().phase_ms;
  say("build      quality none (no hierarchy): %zu triangle records in scene order, %zu bytes, %u threads; hash "
      "%016llx\n",
      acc.tris().size(), acc.binary_stats().bytes, static_cast<unsigned>(resolve_threads(a.threads)),
      static_cast<unsigned long long>(acc.hash()));
  say("build ms   records %.1f, triangles %.1f\n", ph[0], ph[2]);
  say("layouts    none: only the dacrt backends trace this build (build with --quality low, medium or high for the "
      "layouts)\n");
}

// The report: the scene, the build and one row per layout.
void print_info(const SceneArgs& a, const Loaded& l, MemoryReport& mem) {
  const Accel& acc = *l.acc;
  const Box b = acc.bounds();
  say("scene      %s\n", l.scene.name.c_str());
  say("triangles  %zu (%zu degenerate, kept out of leaves), %zu vertices, loaded in %.1f ms\n",
      l.scene.triangle_count(), acc.degenerate_triangles(), l.scene.vertices.size(), l.load_ms);
  say("bounds     (%g, %g, %g) .. (%g, %g, %g)\n", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
  if (!acc.has_hierarchy()) {
    print_flat_info(a, l);
    mem.all = acc.memory();
    return print_memory(mem);
  }
  say("build      %s, up to %u bins a node, max leaf %u, leaf block %u, depth cap %u, %u threads; hash %016llx\n",
      acc.options().quality == BuildQuality::low    ? "Morton LBVH (quality low)"
      : acc.options().quality == BuildQuality::high ? "SBVH, spatial splits kept where the SAH after reinsertion is lower (quality high)"
                                                    : "binned SAH (quality medium)",
      acc.options().bins, acc.options().max_leaf, acc.options().leaf_block, acc.options().depth_cap,
      static_cast<unsigned>(resolve_threads(a.threads)), static_cast<unsigned long long>(acc.hash()));
  {
    const double* ph = acc.binary_stats().phase_ms;
    say("build ms   records %.1f, tree %.1f, flatten %.1f, stats %.1f\n", ph[0], ph[1], ph[2], ph[3]);
  }
  say("leaves     largest %zu triangles, %zu forced by the depth cap or equal centroids; %zu references (%.1f %% more than triangles)\n\n",
      acc.bvh2().largest_leaf, acc.bvh2().forced_leaves, acc.tris().size(),
      100.0 * (double(acc.tris().size()) / double(l.scene.triangle_count() - acc.bvh2().degenerate) - 1.0));
  say("%-7s %9s %9s %6s %9s %10s %12s %9s %10s %10s\n", "layout", "nodes", "leaves", "depth", "bits", "SAH cost",
      "bytes", "build ms", "stack B/r", "bitstk B/r");
  print_stats_row(acc.binary_stats(), 0, 0);
  const LayoutStats s2 = acc.mbvh2().stats;  // each layout made here, on first use
  const LayoutStats s4 = acc.mbvh4().stats;
  const LayoutStats s8 = acc.mbvh8().stats;
  print_stats_row(s2, state_bytes_per_ray(Layout::mbvh2, Traversal::stack), state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack));
  print_stats_row(s4, state_bytes_per_ray(Layout::mbvh4, Traversal::stack), state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack));
  print_stats_row(s8, state_bytes_per_ray(Layout::mbvh8, Traversal::stack), state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack));
  // the cpu backend's own leaves (TraceOptions::leaf_block 4), from this build
  const LeafVariant& lv = acc.leaf_variant(kCpuLeafBlock);
  const auto [v4, v8] = cpu_leaf_stats(acc);
  print_stats_row(v4, state_bytes_per_ray(Layout::mbvh4, Traversal::stack), state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack));
  print_stats_row(v8, state_bytes_per_ray(Layout::mbvh8, Traversal::stack), state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack));
  say("(mbvh4:4, mbvh8:4: what the SIMD cpu backends trace by default: this build's leaves regrouped for leaf tests of\n"
      " 4 triangles, %zu leaves of up to %zu; MBVH4 and MBVH8 by the SAH-optimal collapse)\n",
      lv.leaves.size(), lv.largest_leaf);
  say("\ntraversal state per ray: stack %zu B, bitstack %zu B (%.1fx smaller)\n",
      state_bytes_per_ray(Layout::mbvh2, Traversal::stack), state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack),
      double(state_bytes_per_ray(Layout::mbvh2, Traversal::stack)) / double(state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack)));
  mem.all = acc.memory();
  print_memory(mem);
}

// --json: the same statistics as a JSON document.
std::string info_json(const Loaded& l, const MemoryReport& mem) {
  const Accel& acc = *l.acc;
  const LayoutStats& bs = acc.binary_stats();
  nlohmann::json j;
  j["scene"] = l.scene.name;
  j["triangles"] = l.scene.triangle_count();
  char h[32];
  std::snprintf(h, sizeof h, "%016llx", static_cast<unsigned long long>(acc.hash()));
  j["hash"] = h;
  j["quality"] = to_string(acc.options().quality);
  j["build_phases_ms"] = {{"records", bs.phase_ms[0]}, {"tree", bs.phase_ms[1]}, {"flatten", bs.phase_ms[2]},
                          {"stats", bs.phase_ms[3]}};
  j["references"] = acc.tris().size();
  j["degenerate"] = acc.degenerate_triangles();
  j["hierarchy"] = acc.has_hierarchy();
  j["memory"] = {{"build", memory_json(mem.build)}, {"cpu_default_traces", memory_json(mem.traced)},
                 {"all_layouts", memory_json(mem.all)}, {"scene", mem.scene},
                 {"bytes_per_triangle", {{"build", double(mem.build.total()) / double(mem.triangles)},
                                         {"cpu_default_traces", double(mem.traced.total()) / double(mem.triangles)},
                                         {"all_layouts", double(mem.all.total()) / double(mem.triangles)},
                                         {"scene", double(mem.scene) / double(mem.triangles)}}}};
  if (!acc.has_hierarchy()) {  // quality none: the triangles alone
    j["layouts"] = nlohmann::json::array();
    return j.dump(2) + "\n";
  }
  const LayoutStats &s2 = acc.mbvh2().stats, &s4 = acc.mbvh4().stats, &s8 = acc.mbvh8().stats;
  const auto [v4, v8] = cpu_leaf_stats(acc);
  for (const LayoutStats* s : {&bs, &s2, &s4, &s8, &v4, &v8})
    j["layouts"].push_back({{"layout", s->layout}, {"nodes", s->nodes}, {"leaves", s->leaves}, {"depth", s->depth},
                            {"bitstack_bits", s->bitstack_bits}, {"sah_cost", s->sah_cost}, {"bytes", s->bytes},
                            {"build_ms", s->build_ms}});
  return j.dump(2) + "\n";
}

// --refit: refits the build to the scene's vertices moved by a smooth displacement (0.2 % of the
// scene's extent), then rebuilds the moved scene with the same options, and prints both times and
// SAH costs side by side.
void info_refit(const SceneArgs& a, Loaded& l) {
  // -- move the vertices (frame 1 of bench --dynamic's displacement)
  Scene moved = l.scene;
  moved.name += " (moved)";
  displace_vertices(l.scene.vertices, moved.vertices, l.acc->bounds(), 1);
  // -- refit, then rebuild with the same options
  l.acc->refit(moved);
  const double refit_ms = l.acc->last_refit_ms();
  BuildOptions bo = l.acc->options();
  bo.progress = nullptr;
  const auto t0 = Clock::now();
  const auto rebuilt = Accel::build(moved, bo);
  const double build_ms = ms_since(t0);
  if (!rebuilt->has_hierarchy()) {  // quality none: the triangles and bounds alone
    say("\nrefit      %.1f ms (the triangles and bounds: no hierarchy); a rebuild of the moved scene %.1f ms (%u threads)\n",
        refit_ms, build_ms, static_cast<unsigned>(resolve_threads(a.threads)));
    return;
  }
  for (Layout lay : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) rebuilt->make_layout(lay);
  const double layouts_ms = ms_since(t0);
  say("\nrefit      %.1f ms (binary tree, leaves, triangles and the MBVH2/4/8 layouts made above); a rebuild of the "
      "moved scene %.1f ms (%.1fx the refit), with those layouts %.1f ms (%.1fx); SAH cost refitted %.2f, rebuilt %.2f "
      "(%u threads)\n",
      refit_ms, build_ms, build_ms / std::max(refit_ms, 1e-6), layouts_ms, layouts_ms / std::max(refit_ms, 1e-6),
      l.acc->binary_stats().sah_cost, rebuilt->binary_stats().sah_cost, static_cast<unsigned>(resolve_threads(a.threads)));
}

int run_info(const InfoArgs& a) {
  prepare_outputs({{"--json", a.json, true}}, {{"scene", a.scene.scene}});
  Loaded l = load_and_build(a.scene, false);
  MemoryReport mem = memory_report(l);
  print_info(a.scene, l, mem);
  if (!a.json.empty()) {
    const std::string text = info_json(l, mem);
    write_bytes_to({"--json", a.json, true}, text.data(), text.size());
  }
  if (a.refit) info_refit(a.scene, l);
  return 0;
}

}  // namespace

Command add_info(CLI::App& app) {
  auto a = std::make_shared<InfoArgs>();
  auto* c = app.add_subcommand("info", "scene and per-layout build statistics");
  a->scene.add(c);
  c->add_option("--json", a->json, "also write the statistics as JSON ('-': standard output)");
  c->add_flag("--refit", a->refit,
              "also refit the build to the vertices moved by a small smooth displacement and time it beside a "
              "rebuild of the moved scene");
  return {c, [a] { return run_info(*a); }};
}

}  // namespace mbvh::cli

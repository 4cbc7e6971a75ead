// SPDX-License-Identifier: MIT
// cmd_trace.cpp — `mbvh trace`: trace rays on one backend and variant; write hits (closest) or
// occlusion (any).
#include "host/cli/args.h"
#include "host/cli/commands.h"
#include "host/cli/progress.h"

namespace mbvh::cli {

namespace {

// Traces in batches so a long run shows progress; results are concatenated in ray order. `ms`:
// the time spent in Backend::trace.
TraceOutput trace_batches(Backend& backend, const Accel& acc, const std::vector<Ray>& r, const TraceOptions& o,
                          double& ms) {
  TraceOutput out;
  const std::size_t batch = std::size_t(1) << 20;
  Progress p("tracing", r.size());
  ms = 0;
  for (std::size_t b = 0; b < r.size(); b += batch) {
    TraceOutput part;
    const std::size_t n = std::min(batch, r.size() - b);
    const auto t0 = Clock::now();
    backend.trace(acc, std::span<const Ray>(r).subspan(b, n), o, part);
    ms += ms_since(t0);
    out.hits.insert(out.hits.end(), part.hits.begin(), part.hits.end());
    out.occluded.insert(out.occluded.end(), part.occluded.begin(), part.occluded.end());
    out.stats.insert(out.stats.end(), part.stats.begin(), part.stats.end());
    out.invalid += part.invalid;
    p.update(b + n);
  }
  p.finish();
  return out;
}

int run_trace(TraceArgs& a) {
  const OutputTarget hits_to{"-o", a.out};
  prepare_outputs({hits_to}, {{"scene", a.scene.scene}, {"--rays", a.rays.rays_file}});
  // -- the variant and the backend
  a.scene.no_hierarchy_for({a.backend});  // a dacrt backend alone: no BVH built (quality none)
  BackendOptions bo = a.dev.options(a.scene.threads, a.scene.quality);
  auto backend = make_backend(a.backend, bo);
  const TraceOptions o = a.options(*backend);
  // -- scene, rays, trace
  a.rays.check_memory();
  Loaded l = load_and_build(a.scene);
  const std::vector<Ray> r = a.rays.get(l, a.scene.threads);
  if (!quiet()) std::fprintf(stderr, "backend: %s\n", backend->describe().c_str());
  backend->prepare(*l.acc, o);
  double ms = 0;
  const TraceOutput out = trace_batches(*backend, *l.acc, r, o, ms);
  // -- report
  std::size_t hits = 0;
  if (o.query == Query::any) for (auto v : out.occluded) hits += v;
  else for (const auto& h : out.hits) hits += h.prim != MBVH_MISS_PRIM;
  say("traced %zu rays (%s/%s/%s) in %.1f ms: %.3f Mrays/s; %zu %s, %zu invalid\n", r.size(), layout_label(o),
      a.traversal.c_str(), a.query.c_str(), ms, ms > 0 ? static_cast<double>(r.size()) / ms * 1e-3 : 0.0, hits,
      o.query == Query::any ? "occluded" : "hits", out.invalid);
  if (a.stats && !out.stats.empty()) {
    double n = 0, lf = 0, t = 0, c = 0;
    for (const auto& s : out.stats) { n += s.nodes; lf += s.leaves; t += s.tris; c += s.climbs; }
    const double k = static_cast<double>(out.stats.size());
    say("per ray: %.2f nodes, %.2f leaves, %.2f triangles, %.2f climbs; state %zu B\n", n / k, lf / k, t / k, c / k,
        backend->state_bytes(o));
  }
  // -- the hits or the occlusion
  if (!a.out.empty()) {
    if (o.query == Query::any) write_bytes_to(hits_to, out.occluded.data(), out.occluded.size());
    else write_bytes_to(hits_to, out.hits.data(), out.hits.size() * sizeof(Hit));
    say("wrote %s\n", shown(a.out).c_str());
  }
  return 0;
}

}  // namespace

void TraceArgs::add(CLI::App* c) {
  scene.add(c);
  rays.add(c, true);
  c->add_option("--backend", backend, "backend (see `mbvh devices`)");
  c->add_option("--layout", layout, "mbvh2, mbvh4, mbvh8 or auto (the default: the layout the backend traces fastest with the traversal)");
  c->add_option("--traversal", traversal, "stack, bitstack, stack-ordered, bitstack-retest (MBVH4 only) or stack-octant, bitstack-octant (MBVH8 only); packet-ranged, packet-partition or packet (cpu: packets of 64 rays over MBVH2, the layout for the hybrid's single rays); dacrt (no hierarchy, the layout ignored); auto (the default: the backend's fastest exact traversal for the query, docs/library.md \"Defaults\"; the report names it)");
  c->add_option("--query", query, "closest (writes hits, 16 B/ray) or any (writes occlusion, 1 B/ray)");
  c->add_option("-o,--output", out, "output file ('-': standard output)");
  c->add_flag("--stats", stats, "also count work per ray (slower)");
  c->add_option("--precision", precision, "accuracy mode: robust (default), exact or fast");
  dev.add(c);
}

TraceOptions TraceArgs::options(const Backend& b) {
  TraceOptions o;
  o.layout = parse_layout(layout);
  o.traversal = parse_traversal(traversal);
  o.query = parse_query(query);
  o.stats = stats;
  o.precision = parse_precision(precision);
  // auto (the default): the backend's fastest exact traversal for the query, named in the report
  o = resolve_options(b, o);
  layout = to_string(o.layout);
  traversal = to_string(o.traversal);
  if (!b.supports(o.layout, o.traversal))
    throw Error("backend '" + backend + "' does not support " + layout + "/" + traversal);
  if (!b.supports_precision(o.precision))
    throw Error("backend '" + backend + "' does not support precision '" + precision + "'");
  return o;
}

Command add_trace(CLI::App& app) {
  auto a = std::make_shared<TraceArgs>();
  auto* c = app.add_subcommand("trace", "trace rays; write hits (closest) or occlusion (any)");
  a->add(c);
  return {c, [a] { return run_trace(*a); }};
}

}  // namespace mbvh::cli

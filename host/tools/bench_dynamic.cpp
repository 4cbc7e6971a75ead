// SPDX-License-Identifier: MIT
// bench_dynamic.cpp — `mbvh bench --dynamic`: a moving scene, frame by frame; each backend's
// structure rebuilt, refitted or updated flat, then traced, timed in rotated order, verified.
#include "host/tools/bench_dynamic.h"

#include <algorithm>
#include <cstdio>
#include <map>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>

#include "host/core/enum_check.h"
#include "host/core/parallel.h"
#include "host/tools/bench.h"
#include "host/tools/displace.h"
#include "host/tools/resident.h"
#include "host/tools/stats.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"

namespace mbvh {

const char* to_string(FrameMode m) {
  switch (m) {
    case FrameMode::rebuild: return "rebuild+trace";
    case FrameMode::refit: return "refit+trace";
    case FrameMode::update: return "update+trace";
  }
  return "?";
}

bool DynamicRecord::verified() const {
  return verify_mismatches == 0 || precision == to_string(Precision::fast);
}

bool DynamicReport::verified() const {
  return std::all_of(records.begin(), records.end(), [](const DynamicRecord& r) { return r.verified(); });
}

namespace {

// One traced item of a frame: a ray kind and the query it is traced with.
struct Item {
  RayKind kind;
  Query query;
};

std::vector<Item> items_of(const DynamicOptions& opt) {
  std::vector<Item> items;
  for (RayKind k : opt.kinds) {
    if (k != RayKind::primary && k != RayKind::shadow)
      throw Error(std::string("bench --dynamic traces primary and shadow rays, not ") + to_string(k) + " rays");
    if (opt.grid.queries.empty()) items.push_back({k, k == RayKind::shadow ? Query::any : Query::closest});
    else
      for (Query q : opt.grid.queries) items.push_back({k, q});
  }
  return items;
}

// A backend variant and how its structure is brought up to date: one lane of the frames.
struct Lane {
  std::string name;
  Backend* backend = nullptr;
  TraceOptions to;  // layout, traversal, precision; the query per item
  FrameMode mode = FrameMode::rebuild;
  std::unique_ptr<Accel> kept;           // refit and update: the build refitted frame by frame
  std::vector<TraceOutput> out;          // per item
  std::size_t record = 0;
};

// Every (layout, traversal, precision) of the grid backend `b` runs (DynamicOptions::grid); its
// own first supported pair where it runs none of the grid's.
std::vector<TraceOptions> variants_of(const Backend& b, const DynamicOptions& opt) {
  std::vector<TraceOptions> v;
  for (Precision p : opt.grid.precisions) {
    if (!b.supports_precision(p)) continue;
    for (Traversal t : opt.grid.traversals)
      for (Layout l : opt.grid.layouts) {
        if (!b.supports(l, t)) continue;
        TraceOptions to;
        to.layout = l;
        to.traversal = t;
        to.precision = p;
        v.push_back(to);
        if (opt.first_layout) break;
      }
  }
  if (!v.empty()) return v;
  for (int t = 0; t < enum_detail::Names<Traversal>::count; ++t)
    for (int l = 0; l < enum_detail::Names<Layout>::count; ++l)
      if (b.supports(Layout(l), Traversal(t))) {
        TraceOptions to;
        to.layout = Layout(l);
        to.traversal = Traversal(t);
        for (Precision p : opt.grid.precisions)
          if (b.supports_precision(p)) {
            to.precision = p;
            v.push_back(to);
          }
        return v;
      }
  throw Error("bench --dynamic: backend " + b.name() + " supports no layout and traversal");
}

// The rays of one frame and the reference answers on that frame's geometry, per item.
struct FrameRays {
  std::vector<std::unique_ptr<ReferenceAnswers>> refs;  // per item; their tie rules hold spans of their rays
};

FrameRays frame_rays(const Scene& moved, const Accel& ref, const std::vector<Ray>& primary, const Vec3f& light,
                     const std::vector<Item>& items, unsigned threads) {
  // -- shadow rays from this frame's primary hits, toward the light
  std::vector<Ray> shadow;
  if (std::any_of(items.begin(), items.end(), [](const Item& i) { return i.kind == RayKind::shadow; })) {
    TraceOptions po;
    po.layout = Layout::mbvh4;
    po.traversal = Traversal::stack;
    TraceOutput hits;
    trace_reference(ref, primary, po, hits, threads);
    shadow.reserve(primary.size());
    for (const Hit& h : hits.hits)
      if (Ray r; h.prim != MBVH_MISS_PRIM && shadow_ray(moved, h, light, r)) shadow.push_back(r);
  }
  // -- the reference answers
  FrameRays fr;
  for (const Item& it : items) {
    fr.refs.push_back(std::make_unique<ReferenceAnswers>(ref, it.kind == RayKind::shadow ? shadow : primary));
    fr.refs.back()->reference_for(ref, it.query, threads);
  }
  return fr;
}

// One lane's step of a frame: brings its structure up to date with `moved`, traces every item
// (timed), then verifies the answers (untimed) against `fr`.
DynamicFrame step(Lane& lane, const Scene& moved, const BuildOptions& build, const std::vector<Item>& items,
                  const FrameRays& fr, MemoryProbe& mem) {
  DynamicFrame df;
  for (std::size_t i = 0; i < items.size(); ++i) {  // fresh misses: an unwritten entry cannot pass as an answer
    TraceOptions to = lane.to;
    to.query = items[i].query;
    lane.out[i].reset(fr.refs[i]->rays.size(), to);
  }
  mem.start();
  // -- timed: the update, then the traces
  const auto t0 = Clock::now();
  std::unique_ptr<Accel> rebuilt;
  if (lane.mode == FrameMode::rebuild) rebuilt = Accel::build(moved, build);
  else lane.kept->refit(moved);
  const Accel& acc = rebuilt ? *rebuilt : *lane.kept;
  df.update_ms = ms_since(t0);
  for (std::size_t i = 0; i < items.size(); ++i) {
    TraceOptions to = lane.to;
    to.query = items[i].query;
    const auto t1 = Clock::now();
    lane.backend->trace(acc, fr.refs[i]->rays, to, lane.out[i]);
    df.trace_ms.push_back(ms_since(t1));
  }
  df.total_ms = ms_since(t0);
  df.peak_extra_bytes = mem.peak_extra();
  // -- verified against the reference on the frame's own rebuild
  for (std::size_t i = 0; i < items.size(); ++i) {
    df.rays.push_back(fr.refs[i]->rays.size());
    df.verify_mismatches += fr.refs[i]->mismatches(lane.out[i], items[i].query);
  }
  return df;
}

// The medians of a lane's timed frames into its record.
void finish_record(DynamicRecord& r) {
  std::vector<double> total, update, rays;
  std::vector<std::vector<double>> trace(r.kinds.size());
  for (const DynamicFrame& f : r.per_frame) {
    total.push_back(f.total_ms);
    update.push_back(f.update_ms);
    double n = 0;
    for (std::size_t i = 0; i < f.trace_ms.size(); ++i) {
      trace[i].push_back(f.trace_ms[i]);
      n += double(f.rays[i]);
    }
    rays.push_back(n);
    r.peak_extra_bytes = std::max(r.peak_extra_bytes, f.peak_extra_bytes);
  }
  if (total.empty()) return;
  r.median_ms = median(total);
  r.min_ms = *std::min_element(total.begin(), total.end());
  r.max_ms = *std::max_element(total.begin(), total.end());
  r.median_update_ms = median(update);
  for (auto& t : trace) r.median_trace_ms.push_back(median(t));
  r.mrays_per_s = r.median_ms > 0 ? median(rays) / (r.median_ms * 1e3) : 0;
}

// The ratios between lanes of one run: each lane over the first update lane (same kinds and
// queries), and a refit lane over its backend variant's rebuild lane.
void lane_ratios(std::vector<DynamicRecord>& recs) {
  const auto same_items = [](const DynamicRecord& a, const DynamicRecord& b) {
    return a.kinds == b.kinds && a.queries == b.queries;
  };
  for (DynamicRecord& r : recs) {
    for (const DynamicRecord& u : recs)
      if (u.mode == to_string(FrameMode::update) && same_items(u, r) && u.median_ms > 0) {
        r.time_vs_update = r.median_ms / u.median_ms;
        break;
      }
    if (r.mode == to_string(FrameMode::refit))
      for (const DynamicRecord& b : recs)
        if (b.mode == to_string(FrameMode::rebuild) && b.backend == r.backend && b.layout == r.layout &&
            b.traversal == r.traversal && b.precision == r.precision && same_items(b, r) && b.median_ms > 0)
          r.time_vs_rebuild = r.median_ms / b.median_ms;
  }
}

}  // namespace

DynamicReport run_dynamic(const Scene& scene, const Accel& acc, const DynamicOptions& opt,
                          const std::function<void(std::size_t, std::size_t)>& progress) {
  DynamicReport rep;
  describe_machine(rep.machine, rep.cpu, rep.compiler, rep.flags);
  rep.scene = scene.name;
  rep.triangles = scene.triangle_count();
  const std::vector<Item> items = items_of(opt);
  BuildOptions build = opt.build;
  build.progress = nullptr;
  BuildOptions flat = build;
  flat.quality = BuildQuality::none;
  // -- the rays every frame shares: the primary rays, and the light of the shadow rays
  const Box bounds = acc.bounds();
  std::vector<Ray> primary;
  if (opt.count > 0) {
    RayGenOptions ro;
    ro.kind = RayKind::primary;
    ro.count = opt.count;
    ro.seed = opt.seed;
    ro.threads = opt.threads;
    ro.has_camera = opt.has_camera;
    ro.camera = opt.camera;
    primary = generate_rays(scene, acc, ro);
  } else {
    const Camera cam = opt.has_camera ? opt.camera : default_camera(bounds);
    if (const std::string p = camera_problem(cam); !p.empty()) throw Error("camera: " + p);
    primary = image_rays(cam, opt.width, opt.height, opt.seed);
  }
  const Vec3f light = default_light(bounds);
  // -- the lanes: per backend variant, rebuild and refit, or update for a backend without a hierarchy
  BackendOptions bo = opt.backend;
  bo.threads = opt.threads;
  const auto backends = make_backends(opt.grid, bo);
  MemoryProbe mem;
  std::vector<Lane> lanes;
  for (const std::string& name : opt.grid.backends) {
    Backend& b = *backends.at(name);
    const bool hierarchy = backend_needs_hierarchy(name);
    for (const TraceOptions& to : variants_of(b, opt))
      for (FrameMode m : hierarchy ? std::vector<FrameMode>{FrameMode::rebuild, FrameMode::refit}
                                   : std::vector<FrameMode>{FrameMode::update}) {
        Lane lane;
        lane.name = name;
        lane.backend = &b;
        lane.to = to;
        lane.mode = m;
        lane.out.resize(items.size());
        lane.record = rep.records.size();
        lanes.push_back(std::move(lane));
        DynamicRecord r;
        r.scene = scene.name;
        r.backend = name;
        r.isa = b.isa();
        r.device = b.describe();
        r.layout = hierarchy ? to_string(to.layout) : "-";  // no hierarchy: no layout
        r.traversal = to_string(to.traversal);
        r.precision = to_string(to.precision);
        r.mode = to_string(m);
        r.build = to_string(m == FrameMode::update ? flat.quality : build.quality);
        for (const Item& it : items) {
          r.kinds.push_back(to_string(it.kind));
          r.queries.push_back(to_string(it.query));
        }
        r.threads = resolve_threads(opt.threads);
        r.frames = opt.frames;
        rep.records.push_back(std::move(r));
      }
  }
  // -- frame 0, the unmoved scene: every lane's warm-up (untimed), its kept build made and the
  // resident bytes it keeps measured; then frames 1..N, each lane's step timed in an order
  // rotated frame by frame, so a drift in the machine's load slows every lane alike
  const Scene base = without_degenerate(scene, acc);
  rep.left_out = scene.triangle_count() - base.triangle_count();
  Scene moved = base;
  for (unsigned f = 0; f <= opt.frames; ++f) {
    if (f > 0) displace_vertices(base.vertices, moved.vertices, bounds, f);
    const std::unique_ptr<Accel> ref_build = Accel::build(moved, build);
    const Accel& ref = *ref_build;
    const FrameRays fr = frame_rays(moved, ref, primary, light, items, opt.threads);
    for (std::size_t k = 0; k < lanes.size(); ++k) {
      Lane& lane = lanes[(k + f) % lanes.size()];
      DynamicRecord& r = rep.records[lane.record];
      if (f == 0) {
        const std::int64_t before = reset_peak() ? mem.rss_now() : -1;
        if (lane.mode != FrameMode::rebuild) lane.kept = Accel::build(moved, lane.mode == FrameMode::update ? flat : build);
        const DynamicFrame w = step(lane, moved, build, items, fr, mem);
        r.verify_mismatches += w.verify_mismatches;
        if (before >= 0 && reset_peak()) r.held_bytes = std::max<std::int64_t>(0, mem.rss_now() - before);
        continue;
      }
      DynamicFrame df = step(lane, moved, build, items, fr, mem);
      df.frame = f;
      r.verify_mismatches += df.verify_mismatches;
      r.per_frame.push_back(std::move(df));
    }
    if (progress && f > 0) progress(f, opt.frames);
  }
  for (DynamicRecord& r : rep.records) finish_record(r);
  lane_ratios(rep.records);
  return rep;
}

namespace {

std::string mib(std::int64_t bytes) {
  if (bytes < 0) return "-";
  char s[32];
  std::snprintf(s, sizeof s, "%.1f", double(bytes) / (1 << 20));
  return s;
}

}  // namespace

std::string DynamicReport::table() const {
  std::string s;
  char line[512];
  std::snprintf(line, sizeof line, "%-12s %-6s %-15s %-7s %-14s %6s %9s %19s %9s %9s %8s %8s %9s %8s %8s %8s\n", "backend",
                "layout", "traversal", "prec", "mode", "frames", "ms/frame", "(min-max)", "update", "trace", "Mrays/s",
                "x update", "x rebuild", "held MiB", "peak+MiB", "verified");
  s += line;
  for (const DynamicRecord& r : records) {
    double trace = 0;
    for (double t : r.median_trace_ms) trace += t;
    char spread[48], ratio[32] = "", vs_rebuild[32] = "";
    if (r.time_vs_rebuild > 0) std::snprintf(vs_rebuild, sizeof vs_rebuild, "%.2fx", r.time_vs_rebuild);
    std::snprintf(spread, sizeof spread, "(%.1f-%.1f)", r.min_ms, r.max_ms);
    if (r.time_vs_update > 0) std::snprintf(ratio, sizeof ratio, "%.2fx", r.time_vs_update);
    std::snprintf(line, sizeof line, "%-12s %-6s %-15s %-7s %-14s %6u %9.2f %19s %9.2f %9.2f %8.2f %8s %9s %8s %8s %8s\n",
                  r.backend.c_str(), r.layout.c_str(), r.traversal.c_str(), r.precision.c_str(), r.mode.c_str(),
                  r.frames, r.median_ms, spread, r.median_update_ms, trace, r.mrays_per_s, ratio, vs_rebuild,
                  mib(r.held_bytes).c_str(), mib(r.peak_extra_bytes).c_str(),
                  !r.verified() ? "MISMATCH" : r.verify_mismatches ? "differs" : "yes");
    s += line;
  }
  // -- the frames: total ms of each lane, in the records' order
  s += "\nms per frame (update + trace), lanes in the order above:\n";
  std::snprintf(line, sizeof line, "%5s", "frame");
  s += line;
  for (std::size_t i = 0; i < records.size(); ++i) {
    std::snprintf(line, sizeof line, " %10s", ("lane " + std::to_string(i + 1)).c_str());
    s += line;
  }
  s += "\n";
  const std::size_t frames = records.empty() ? 0 : records[0].per_frame.size();
  for (std::size_t f = 0; f < frames; ++f) {
    std::snprintf(line, sizeof line, "%5u", records[0].per_frame[f].frame);
    s += line;
    for (const DynamicRecord& r : records) {
      std::snprintf(line, sizeof line, " %10.2f", f < r.per_frame.size() ? r.per_frame[f].total_ms : 0.0);
      s += line;
    }
    s += "\n";
  }
  return s;
}

std::string DynamicReport::json() const {
  nlohmann::json j;
  j["machine"] = machine;
  j["cpu"] = cpu;
  j["compiler"] = compiler;
  j["flags"] = flags;
  j["scene"] = scene;
  j["triangles"] = triangles;
  j["degenerate_left_out"] = left_out;
  j["records"] = nlohmann::json::array();
  const auto bytes = [](std::int64_t b) { return b < 0 ? nlohmann::json(nullptr) : nlohmann::json(b); };
  const auto or_null = [](double v) { return v > 0 ? nlohmann::json(v) : nlohmann::json(nullptr); };
  const auto join = [](const std::vector<std::string>& v) {
    std::string s;
    for (const auto& x : v) s += (s.empty() ? "" : ",") + x;
    return s;
  };
  for (const DynamicRecord& r : records) {
    nlohmann::json frames = nlohmann::json::array();
    for (const DynamicFrame& f : r.per_frame)
      frames.push_back({{"frame", f.frame},
                        {"total_ms", f.total_ms},
                        {"update_ms", f.update_ms},
                        {"trace_ms", f.trace_ms},
                        {"rays", f.rays},
                        {"verify_mismatches", f.verify_mismatches},
                        {"peak_extra_bytes", bytes(f.peak_extra_bytes)}});
    std::size_t rays = 0;
    if (!r.per_frame.empty())
      for (std::size_t n : r.per_frame.back().rays) rays += n;
    j["records"].push_back({{"scene", r.scene},
                            {"triangles", triangles},
                            {"backend", r.backend},
                            {"isa", r.isa},
                            {"device", r.device},
                            {"layout", r.layout},
                            {"traversal", r.traversal},
                            {"precision", r.precision},
                            {"mode", r.mode},
                            {"build", r.build},
                            {"ray_kind", join(r.kinds)},
                            {"query", join(r.queries)},
                            {"rays", rays},
                            {"threads", r.threads},
                            {"frames", r.frames},
                            {"ms_per_frame", r.median_ms},
                            {"ms_per_frame_min", r.min_ms},
                            {"ms_per_frame_max", r.max_ms},
                            {"update_ms", r.median_update_ms},
                            {"trace_ms", r.median_trace_ms},
                            {"mrays_per_s", r.mrays_per_s},
                            {"time_vs_update", or_null(r.time_vs_update)},
                            {"time_vs_rebuild", or_null(r.time_vs_rebuild)},
                            {"held_bytes", bytes(r.held_bytes)},
                            {"peak_extra_bytes", bytes(r.peak_extra_bytes)},
                            {"verify_mismatches", r.verify_mismatches},
                            {"verified", r.verified()},
                            {"per_frame", frames}});
  }
  return j.dump(2);
}

std::string DynamicReport::csv() const { return records_csv(json()); }

}  // namespace mbvh

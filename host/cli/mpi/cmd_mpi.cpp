// SPDX-License-Identifier: MIT
// cmd_mpi.cpp — `mbvh-mpi trace | render | bench | check` (cmd_mpi.h). Every rank runs the same
// command; rank 0 reads the rays, reports and writes the outputs. Replicated (the default): every
// rank loads the scene and the one BVH rank 0 built (mpi::shared_accel), rays go in batches, tiles
// by rank; the answers and images are bit for bit one process's. --distribute data: each rank
// builds its part (mpi::partition) and rays are forwarded between the parts
// (mpi::trace_data_parallel); render shades each rank's tiles on it, its paths crossing the parts.
#include <algorithm>
#include <cmath>
#include <cstdlib>

#include "host/cli/args.h"
#include "host/cli/mpi/cmd_mpi.h"
#include "host/cli/progress.h"
#include "host/mpi/calls.h"
#include "host/tools/check.h"
#include "host/tools/image.h"
#include "host/tools/render.h"
#include "mbvh/compare.h"
#include "mbvh/rays.h"

namespace mbvh::cli {

namespace {

using mpi::Comm;
using mpi::Traffic;
using mpi::detail::call;
using mpi::detail::count;

// -- the ranks' own options

struct Distribution {
  std::string distribute = "replicated", schedule = "static", forwarding = "ordered";
  std::size_t batch = 65536;
  bool no_shared = false;
  std::vector<CLI::Option*> replicated_only, data_only;  ///< given with the other mode: an error
  bool data() const { return distribute == "data"; }
  /// Refuses an option of one mode given with the other (it would be ignored), and --cache with
  /// --distribute data (the parts are built on their ranks, never cached).
  void check(const SceneArgs& scene) const {
    for (const CLI::Option* o : data() ? replicated_only : data_only)
      if (o->count())
        throw Error(o->get_name() + " applies to --distribute " + (data() ? "replicated" : "data") + " only, not to --distribute " +
                    distribute);
    if (data() && !scene.cache.empty())
      throw Error("--cache: with --distribute data each rank builds its part, which is not cached");
  }
  void add(CLI::App* c, bool with_schedule) {
    c->add_option("--distribute", distribute,
                  "replicated (every rank holds the scene and one shared BVH: answers bit for bit one process's) or "
                  "data (each rank builds the BVH of 1/P of the triangles; rays are forwarded between the ranks)")
        ->check(CLI::IsMember({"replicated", "data"}));
    data_only.push_back(c->add_option("--forwarding", forwarding,
                                      "data: ordered (each ray to the nearest part it reaches, with its best hit so far, "
                                      "round by round) or broadcast (to every part it reaches at once: the baseline)")
                            ->check(CLI::IsMember({"ordered", "broadcast"})));
    if (!with_schedule) return;
    replicated_only.push_back(c->add_option("--schedule", schedule,
                                            "replicated: static (each rank an equal contiguous share of the rays) or "
                                            "dynamic (batches: each rank's share first, then stolen from the rank with "
                                            "the most left)")
                                  ->check(CLI::IsMember({"static", "dynamic"})));
    replicated_only.push_back(
        c->add_option("--batch", batch, "replicated, dynamic schedule: rays per batch")->check(integer_in(1, 1u << 30)));
    replicated_only.push_back(c->add_flag("--no-shared-memory", no_shared,
                                          "replicated: send rays and answers as messages even where every rank runs on "
                                          "one host (by default they pass through a window of shared memory there)"));
  }
  /// How the replicated rays are dealt, for reports: "static shares" or "dynamic batches of N".
  std::string schedule_label() const {
    return schedule == "dynamic" ? "dynamic batches of " + std::to_string(batch) : std::string("static shares");
  }
  mpi::ScheduleOptions schedule_options() const { return {mpi::parse_schedule(schedule), batch, !no_shared}; }
};

// The sum over ranks of every rank's traffic, on rank 0.
Traffic total_traffic(const Comm& comm, const Traffic& t) {
  double s = t.seconds, s_all = 0;
  std::uint64_t v[3] = {t.bytes_sent, t.bytes_received, t.calls}, v_all[3] = {};
  MPI_Reduce(&s, &s_all, 1, MPI_DOUBLE, MPI_SUM, 0, comm.comm);
  MPI_Reduce(v, v_all, 3, MPI_UINT64_T, MPI_SUM, 0, comm.comm);
  return Traffic{s_all, v_all[0], v_all[1], v_all[2]};
}

// The test hook of the error path: MBVH_MPI_TEST_FAIL=R makes rank R fail here, after the scene is
// loaded and before anything is written, as a rank that cannot read its input would.
void test_hook(const Comm& comm, const char* where) {
  if (const char* r = std::getenv("MBVH_MPI_TEST_FAIL"); r && *r && std::to_string(comm.rank()) == r)
    throw Error(std::string("MBVH_MPI_TEST_FAIL: a failure injected into ") + where + " on this rank");
}

// What `now` added since `before` (a Traffic only grows).
Traffic since(const Traffic& now, const Traffic& before) {
  return Traffic{now.seconds - before.seconds, now.bytes_sent - before.bytes_sent, now.bytes_received - before.bytes_received,
                 now.calls - before.calls};
}

// load_and_build's maker for the replicated mode: rank 0 builds, the others read its build.
AccelMaker shared_maker(const Comm& comm, Traffic* t) {
  return [comm, t](const Scene& s, const BuildOptions& o, const Accel::CacheOptions& c, Accel::CacheReport* r) {
    return mpi::shared_accel(comm, s, o, c, r, t);
  };
}

// -- the data-parallel mode: rank 0's rays dealt to the ranks in contiguous shares (each rank owns
//    its share's answers), and the answers gathered back in ray order

// Rank r's share of n rays: [n*r/P, n*(r+1)/P).
std::uint64_t share_begin(std::uint64_t n, int r, int P) { return n * static_cast<std::uint64_t>(r) / static_cast<std::uint64_t>(P); }

void scatter_shares(const Comm& comm, std::span<const Ray> rays, std::uint64_t& n, Traffic* t, std::vector<Ray>& mine) {
  const int P = comm.size();
  n = comm.root() ? rays.size() : 0;
  call(t, "MPI_Bcast (ray count)", 8, 8, [&] { return MPI_Bcast(&n, 1, MPI_UINT64_T, 0, comm.comm); });
  std::vector<int> counts(static_cast<std::size_t>(P)), displs(static_cast<std::size_t>(P));
  for (int r = 0; r < P; ++r) {
    displs[static_cast<std::size_t>(r)] = count(share_begin(n, r, P) * sizeof(Ray), "MPI_Scatterv (rays)");
    counts[static_cast<std::size_t>(r)] = count((share_begin(n, r + 1, P) - share_begin(n, r, P)) * sizeof(Ray), "MPI_Scatterv (rays)");
  }
  const int me = comm.rank();
  mine.resize(share_begin(n, me + 1, P) - share_begin(n, me, P));
  call(t, "MPI_Scatterv (rays)", comm.root() ? (n - mine.size()) * sizeof(Ray) : 0, comm.root() ? 0 : mine.size() * sizeof(Ray), [&] {
    return MPI_Scatterv(rays.data(), counts.data(), displs.data(), MPI_BYTE, mine.data(),
                        counts[static_cast<std::size_t>(me)], MPI_BYTE, 0, comm.comm);
  });
}

void gather_shares(const Comm& comm, const TraceOutput& mine, const TraceOptions& o, std::uint64_t n, Traffic* t,
                   TraceOutput& out) {
  const int P = comm.size();
  const bool any = o.query == Query::any;
  const std::size_t each = any ? 1 : sizeof(Hit);
  std::vector<int> counts(static_cast<std::size_t>(P)), displs(static_cast<std::size_t>(P));
  for (int r = 0; r < P; ++r) {
    displs[static_cast<std::size_t>(r)] = count(share_begin(n, r, P) * each, "MPI_Gatherv (answers)");
    counts[static_cast<std::size_t>(r)] = count((share_begin(n, r + 1, P) - share_begin(n, r, P)) * each, "MPI_Gatherv (answers)");
  }
  if (comm.root()) out.reset(n, o);
  else out = TraceOutput{};
  const void* send = any ? static_cast<const void*>(mine.occluded.data()) : static_cast<const void*>(mine.hits.data());
  void* recv = any ? static_cast<void*>(out.occluded.data()) : static_cast<void*>(out.hits.data());
  const int me = comm.rank();
  call(t, "MPI_Gatherv (answers)", comm.root() ? 0 : counts[static_cast<std::size_t>(me)], comm.root() ? n * each - counts[0] : 0, [&] {
    return MPI_Gatherv(send, counts[static_cast<std::size_t>(me)], MPI_BYTE, recv, counts.data(), displs.data(), MPI_BYTE, 0,
                       comm.comm);
  });
  std::uint64_t inv = mine.invalid, all = 0;
  call(t, "MPI_Reduce (invalid)", 8, 8, [&] { return MPI_Reduce(&inv, &all, 1, MPI_UINT64_T, MPI_SUM, 0, comm.comm); });
  out.invalid = all;
}

// The data-parallel scene: the whole mesh (for shading) on every rank, this rank's part built.
struct DataScene {
  Scene scene;
  mpi::Part part;
  std::unique_ptr<Accel> none;  ///< a rank without triangles (more ranks than triangles): an empty build
  /// This rank's part's build, or the empty one.
  const Accel& accel() const { return part.accel ? *part.accel : *none; }
};

// Backend::prepare for this rank's build: the replicated `whole`, or the data-parallel part (a
// rank without triangles traces nothing).
void prepare_local(Backend& b, const DataScene* ds, const Accel* whole, const TraceOptions& o) {
  if (!ds) b.prepare(*whole, o);
  else if (ds->part.accel) b.prepare(*ds->part.accel, o);
}

std::unique_ptr<DataScene> load_data_scene(const Comm& comm, const SceneArgs& a, Traffic* t) {
  auto d = std::make_unique<DataScene>();
  const auto t0 = Clock::now();
  d->scene = mpi::load_scene_part(a.scene, static_cast<unsigned>(comm.size()));
  const double load_ms = ms_since(t0);
  BuildOptions bo = a.build_options();
  if (bo.quality == BuildQuality::none)
    throw Error("--distribute data: each rank builds a BVH of its part (--quality none builds none)");
  const auto t1 = Clock::now();
  d->part = mpi::partition(comm, d->scene, bo, t);
  if (!d->part.accel) {
    // a stand-in the renderer can hold, never traced: a rank without triangles exists only where
    // the scene has fewer triangles than there are ranks, so the whole scene without a hierarchy
    // costs nothing
    BuildOptions flat = bo;
    flat.quality = BuildQuality::none;
    d->none = Accel::build(d->scene, flat);
  }
  const double ms = ms_since(t1);
  std::uint64_t largest = 0, all = 0;  // of the non-degenerate triangles, which the parts share
  for (std::uint64_t c : d->part.rank_triangles) {
    largest = std::max(largest, c);
    all += c;
  }
  const double fair = static_cast<double>(all) / comm.size();
  if (!quiet())
    std::fprintf(stderr, "scene %s: %zu triangles, loaded in %.1f ms; %d parts built in %.1f ms (the largest %llu triangles, "
                         "%.3f of an equal share)\n",
                 a.scene.c_str(), d->scene.triangle_count(), load_ms, comm.size(), ms,
                 static_cast<unsigned long long>(largest), fair > 0 ? static_cast<double>(largest) / fair : 0.0);
  return d;
}

// One distributed trace of rank 0's `rays` (the others pass none): replicated over `acc`, or data-parallel
// over `ds`; rank 0 gets every answer in ray order.
void distributed_trace(const Comm& comm, Backend& backend, const Accel* acc, const DataScene* ds, std::span<const Ray> rays,
                       const TraceOptions& o, const Distribution& d, TraceOutput& out, Traffic* t) {
  if (!ds) {
    mpi::trace(comm, backend, *acc, rays, o, out, d.schedule_options(), t);
    return;
  }
  std::uint64_t n = 0;
  static std::vector<Ray> mine;  // kept between calls: fresh pages cost as much as tracing
  static TraceOutput part;
  scatter_shares(comm, rays, n, t, mine);
  try {
    mpi::trace_data_parallel(comm, backend, ds->part, mine, o, part, t, mpi::parse_forwarding(d.forwarding));
  } catch (const Error& e) {  // a ray's index there is its index in this rank's share
    const std::uint64_t lo = share_begin(n, comm.rank(), comm.size());
    throw Error("rays " + std::to_string(lo) + " to " + std::to_string(lo + mine.size()) + " of the call (ray i there is ray " +
                std::to_string(lo) + " + i): " + e.what());
  }
  gather_shares(comm, part, o, n, t, out);
}

std::string ranks_label(const Comm& comm, unsigned threads) {
  return std::to_string(comm.size()) + " ranks x " + (threads ? std::to_string(threads) : std::string("all")) + " threads";
}

// -- trace

struct MpiTraceArgs {
  TraceArgs t;
  Distribution d;
};

// '-' (standard output) is refused: under mpirun a rank's standard output is mpirun's pseudo-terminal
void no_standard_output(const std::vector<std::pair<std::string, std::string>>& outputs) {
  for (const auto& [option, path] : outputs)
    if (path == "-")
      throw Error(option + " -: mbvh-mpi writes no standard output (under mpirun a rank's standard output is "
                  "mpirun's terminal, which may not carry binary bytes); name a file");
}

int run_trace(const Comm& comm, MpiTraceArgs& a) {
  no_standard_output({{"-o", a.t.out}});
  a.d.check(a.t.scene);
  const OutputTarget hits_to{"-o", a.t.out};
  prepare_outputs({hits_to}, {{"scene", a.t.scene.scene}, {"--rays", a.t.rays.rays_file}});
  if (a.t.stats) throw Error("--stats: mbvh-mpi does not gather per-ray statistics over ranks (use mbvh trace --stats)");
  if (a.d.data() && a.t.rays.rays_file.empty())
    throw Error("--distribute data traces a ray file (--rays; `mbvh rays` writes one): generating shadow, diffuse and "
                "path rays needs the whole scene's BVH, which no rank holds");
  if (!a.d.data()) a.t.scene.no_hierarchy_for({a.t.backend});  // data: every part is built (its box routes the rays)
  auto backend = make_backend(a.t.backend, a.t.dev.options(a.t.scene.threads, a.t.scene.quality));
  const TraceOptions o = a.t.options(*backend);
  a.t.rays.check_memory();
  Traffic tr;
  Loaded l;
  std::unique_ptr<DataScene> ds;
  if (a.d.data()) ds = load_data_scene(comm, a.t.scene, &tr);
  else l = load_and_build(a.t.scene, true, shared_maker(comm, &tr));
  const Accel& acc = ds ? ds->accel() : *l.acc;
  std::vector<Ray> rays;
  if (comm.root()) rays = a.t.rays.rays_file.empty() ? a.t.rays.get(l, a.t.scene.threads) : read_rays(a.t.rays.rays_file);
  if (!quiet()) std::fprintf(stderr, "backend: %s, on %s\n", backend->describe().c_str(), ranks_label(comm, a.t.scene.threads).c_str());
  prepare_local(*backend, ds.get(), &acc, o);
  test_hook(comm, "trace");
  const Traffic before = tr;
  call(nullptr, "MPI_Barrier", 0, 0, [&] { return MPI_Barrier(comm.comm); });
  const auto t0 = Clock::now();
  TraceOutput out;
  distributed_trace(comm, *backend, &acc, ds.get(), rays, o, a.d, out, &tr);
  const double ms = ms_since(t0);
  const Traffic all = total_traffic(comm, since(tr, before));
  if (!comm.root()) return 0;
  std::size_t hits = 0;
  if (o.query == Query::any) for (auto v : out.occluded) hits += v;
  else for (const auto& h : out.hits) hits += h.prim != MBVH_MISS_PRIM;
  say("traced %zu rays (%s/%s/%s, %s%s) on %s in %.1f ms: %.3f Mrays/s; %zu %s, %zu invalid; MPI calls %.1f %% of "
      "the ranks' time, %.1f bytes moved a ray\n",
      rays.size(), layout_label(o), a.t.traversal.c_str(), a.t.query.c_str(), a.d.distribute.c_str(),
      a.d.data() ? "" : (", " + a.d.schedule_label()).c_str(),
      ranks_label(comm, a.t.scene.threads).c_str(), ms, ms > 0 ? static_cast<double>(rays.size()) / ms * 1e-3 : 0.0, hits,
      o.query == Query::any ? "occluded" : "hits", out.invalid, ms > 0 ? 100.0 * all.seconds / (comm.size() * ms * 1e-3) : 0.0,
      rays.empty() ? 0.0 : static_cast<double>(all.bytes_received) / static_cast<double>(rays.size()));
  if (!a.t.out.empty()) {
    if (o.query == Query::any) write_bytes_to(hits_to, out.occluded.data(), out.occluded.size());
    else write_bytes_to(hits_to, out.hits.data(), out.hits.size() * sizeof(Hit));
    say("wrote %s\n", shown(a.t.out).c_str());
  }
  return 0;
}

// -- render

struct MpiRenderArgs {
  RenderArgs r;
  Distribution d;
  std::string tiles = "static";
};

int run_render(const Comm& comm, MpiRenderArgs& a) {
  no_standard_output({{"-o", a.r.out}, {"--pfm", a.r.pfm}});
  a.d.check(a.r.scene);
  const std::vector<OutputTarget> outs{{"-o", a.r.out}, {"--pfm", a.r.pfm}};
  prepare_outputs(outs, {{"scene", a.r.scene.scene}});
  if (!a.r.reference.empty() || !a.r.curve.empty())
    throw Error("--reference and --curve: mbvh-mpi renders no error curve (its image is bit for bit mbvh render's: "
                "run the curve there)");
  if (a.d.data() && a.tiles == "dynamic")
    throw Error("--tiles dynamic: with --distribute data every rank traces every batch together (a collective "
                "trace), so the tiles are dealt statically");
  SceneArgs scene = a.r.scene;
  if (!a.d.data()) scene.no_hierarchy_for({a.r.backend});
  auto backend = make_backend(a.r.backend, a.r.dev.options(scene.threads, scene.quality));
  std::vector<float> reference;
  RenderOptions o = a.r.options(*backend, reference);
  Traffic tr;
  Loaded l;
  std::unique_ptr<DataScene> ds;
  if (a.d.data()) ds = load_data_scene(comm, scene, &tr);
  else l = load_and_build(scene, true, shared_maker(comm, &tr));
  const Scene& whole = ds ? ds->scene : l.scene;
  const Accel& acc = ds ? ds->accel() : *l.acc;
  if (!quiet()) std::fprintf(stderr, "backend: %s, on %s\n", backend->describe().c_str(), ranks_label(comm, scene.threads).c_str());
  const TraceOptions closest{o.layout, o.traversal, Query::closest, false, o.precision};
  prepare_local(*backend, ds.get(), &acc, closest);
  test_hook(comm, "render");
  if (ds) {
    o.bounds = &ds->part.scene_bounds;
    o.tracer = [&](std::span<const Ray> rays, const TraceOptions& to, TraceOutput& out) {
      mpi::trace_data_parallel(comm, *backend, ds->part, rays, to, out, &tr, mpi::parse_forwarding(a.d.forwarding));
    };
  }
  const Traffic before = tr;  // the render's share: the build's waits left out
  const auto t0 = Clock::now();
  // the camera: the given one, or the framing every rank computes alike (no tiles rendered)
  std::string camera_rule;
  if (!o.has_camera) {
    const std::vector<std::uint32_t> none;
    RenderOptions c = o;
    c.tiles = &none;
    const RenderResult r0 = render(whole, acc, *backend, c);
    o.has_camera = true;
    o.camera = r0.camera;
    camera_rule = r0.camera_rule;
  }
  // -- this rank's tiles: every pixel's value is the one a whole render gives it, so the image is
  //    the sum of the ranks' images (each pixel nonzero on one rank at most: x + 0 is x exactly)
  const std::uint32_t tiles = tile_count(o.width, o.height);
  const int P = comm.size(), me = comm.rank();
  std::vector<float> rgb(static_cast<std::size_t>(o.width) * o.height * 3, 0.0f);
  std::uint64_t rays = 0;
  double trace_s = 0;
  auto render_tiles = [&](const std::vector<std::uint32_t>& mine) {
    RenderOptions ro = o;
    ro.tiles = &mine;
    const RenderResult r = render(whole, acc, *backend, ro);
    for (std::size_t i = 0; i < rgb.size(); ++i) rgb[i] += r.rgb[i];
    rays += r.rays;
    trace_s += r.trace_seconds;
  };
  if (a.tiles == "static") {
    std::vector<std::uint32_t> mine;
    for (std::uint32_t t = static_cast<std::uint32_t>(me); t < tiles; t += static_cast<std::uint32_t>(P)) mine.push_back(t);
    render_tiles(mine);
  } else {
    // chunks of consecutive tiles, about 8 a rank, from the work queue (stealing once a rank's own are done)
    const std::uint32_t chunk = std::max<std::uint32_t>(1, tiles / (8u * static_cast<std::uint32_t>(P)));
    const std::uint64_t chunks = (tiles + chunk - 1) / chunk;
    mpi::WorkQueue queue(comm, chunks, &tr);
    for (std::int64_t c; (c = queue.next()) >= 0;) {
      std::vector<std::uint32_t> mine;
      for (std::uint32_t t = static_cast<std::uint32_t>(c) * chunk; t < std::min<std::uint32_t>(tiles, (static_cast<std::uint32_t>(c) + 1) * chunk); ++t)
        mine.push_back(t);
      render_tiles(mine);
    }
  }
  std::vector<float> image(comm.root() ? rgb.size() : 0);
  call(&tr, "MPI_Reduce (image)", rgb.size() * 4, comm.root() ? rgb.size() * 4 * static_cast<std::size_t>(P - 1) : 0, [&] {
    return MPI_Reduce(rgb.data(), image.data(), count(rgb.size(), "MPI_Reduce (image)"), MPI_FLOAT, MPI_SUM, 0, comm.comm);
  });
  std::uint64_t all_rays = 0;
  double all_trace = 0;
  MPI_Reduce(&rays, &all_rays, 1, MPI_UINT64_T, MPI_SUM, 0, comm.comm);
  MPI_Reduce(&trace_s, &all_trace, 1, MPI_DOUBLE, MPI_SUM, 0, comm.comm);
  const double seconds = ms_since(t0) * 1e-3;
  const Traffic all = total_traffic(comm, since(tr, before));
  if (!comm.root()) return 0;
  if (!camera_rule.empty()) say("camera: %s\n  --camera %s\n", camera_rule.c_str(), camera_argument(o.camera).c_str());
  const std::vector<std::uint8_t> png = png_bytes(a.r.out, o.width, o.height, to_srgb8(image));
  std::vector<OutputWrite> writes{{outs[0], png.data(), png.size()}};
  std::vector<char> pfm;
  if (!a.r.pfm.empty()) {
    pfm = pfm_bytes(a.r.pfm, o.width, o.height, image);
    writes.push_back({outs[1], pfm.data(), pfm.size()});
  }
  write_outputs(writes);
  say("rendered %ux%u, %u spp, %s (%s/%s) on %s, %s, %s tiles: %llu rays over all bounces in %.2f s (%.3f Mrays/s); "
      "MPI calls %.1f %% of the ranks' time\nwrote %s\n",
      o.width, o.height, o.spp, to_string(o.mode), is_dacrt(o.traversal) ? "-" : to_string(o.layout),
      to_string(o.traversal), ranks_label(comm, scene.threads).c_str(), a.d.distribute.c_str(), a.tiles.c_str(),
      static_cast<unsigned long long>(all_rays), seconds, seconds > 0 ? static_cast<double>(all_rays) / seconds * 1e-6 : 0.0,
      seconds > 0 ? 100.0 * all.seconds / (P * seconds) : 0.0, shown(a.r.out).c_str());
  (void)all_trace;
  return 0;
}

// -- bench and check: generated rays of several kinds, traced over the ranks and compared on rank 0
//    with one process's answers

struct MpiRunArgs {
  SceneArgs scene;
  RayArgs rays;
  DeviceArgs dev;
  Distribution d;
  std::string backend = "cpu", layout = "auto", traversal = "auto", precision = "robust", kinds;
  void add(CLI::App* c) {
    scene.add(c);
    rays.add(c, false);
    c->add_option("--kinds", kinds, "comma-separated ray kinds (default: --kind)");
    c->add_option("--backend", backend, "backend (see `mbvh devices`)");
    c->add_option("--layout", layout, "mbvh2, mbvh4, mbvh8 or auto (the backend's fastest for each query)");
    c->add_option("--traversal", traversal, "a traversal (see `mbvh trace --help`) or auto (the backend's fastest for each query)");
    c->add_option("--precision", precision, "accuracy mode: robust (default), exact or fast");
    dev.add(c);
  }
  std::vector<RayKind> kind_list() const {
    std::vector<RayKind> k;
    for (const std::string& s : split_list(kinds.empty() ? rays.kind : kinds, "--kinds")) k.push_back(parse_ray_kind(s));
    return k;
  }
  TraceOptions options(const Backend& b, Query q) const {
    TraceOptions o;
    o.layout = parse_layout(layout);
    o.traversal = parse_traversal(traversal);
    o.query = q;
    o.precision = parse_precision(precision);
    o = resolve_options(b, o);
    if (!b.supports(o.layout, o.traversal))
      throw Error("backend '" + backend + "' does not support " + to_string(o.layout) + "/" + to_string(o.traversal));
    if (!b.supports_precision(o.precision)) throw Error("backend '" + backend + "' does not support precision '" + precision + "'");
    return o;
  }
};

// What bench and check share: the backend, the scene on every rank, and on rank 0 the whole BVH
// (the rays are generated from it and the answers compared with one process's).
struct Setup {
  std::unique_ptr<Backend> backend;
  Loaded l;                        ///< replicated: every rank's; data: rank 0's whole build (for rays and answers)
  std::unique_ptr<DataScene> ds;   ///< data-parallel
  Traffic tr;
};

Setup setup(const Comm& comm, MpiRunArgs& a) {
  a.d.check(a.scene);
  Setup s;
  a.rays.check_memory();
  s.backend = make_backend(a.backend, a.dev.options(a.scene.threads, a.scene.quality));
  if (a.d.data()) {
    s.ds = load_data_scene(comm, a.scene, &s.tr);
    if (comm.root()) {  // the rays and the one-process answers need the whole scene's BVH, on rank 0 alone
      s.l.scene = load_scene(a.scene.scene);
      s.l.acc = Accel::build(s.l.scene, a.scene.build_options());
    }
  } else {
    s.l = load_and_build(a.scene, true, shared_maker(comm, &s.tr));
  }
  if (!quiet())
    std::fprintf(stderr, "backend: %s, on %s, %s\n", s.backend->describe().c_str(), ranks_label(comm, a.scene.threads).c_str(),
                 a.d.distribute.c_str());
  return s;
}

const Accel& local_accel(const Setup& s) { return s.ds ? s.ds->accel() : *s.l.acc; }



std::vector<Ray> root_rays(const Comm& comm, const MpiRunArgs& a, const Setup& s, RayKind k) {
  if (!comm.root()) return {};
  return generate_rays(s.l.scene, *s.l.acc, a.rays.generator(to_string(k), a.scene.threads));
}

struct BenchArgs {
  MpiRunArgs run;
  unsigned reps = 3;
};

int run_bench(const Comm& comm, BenchArgs& b) {
  MpiRunArgs& a = b.run;
  const std::vector<RayKind> kinds = a.kind_list();
  Setup s = setup(comm, a);
  bool verified = true;
  if (comm.root())
    say("%-8s %10s %10s %12s %10s %10s %10s  %s\n", "kind", "rays", "Mrays/s", "MPI share", "B/ray", "rounds", "fwd/ray", "verified");
  for (RayKind k : kinds) {
    const Query q = k == RayKind::shadow ? Query::any : Query::closest;
    const TraceOptions o = a.options(*s.backend, q);
    prepare_local(*s.backend, s.ds.get(), s.l.acc.get(), o);
    const std::vector<Ray> rays = root_rays(comm, a, s, k);
    std::vector<double> walls, shares;
    TraceOutput out;
    Traffic last;
    for (unsigned rep = 0; rep <= b.reps; ++rep) {  // rep 0 warms up
      Traffic t;
      call(nullptr, "MPI_Barrier", 0, 0, [&] { return MPI_Barrier(comm.comm); });
      const double t0 = MPI_Wtime();
      distributed_trace(comm, *s.backend, &local_accel(s), s.ds.get(), rays, o, a.d, out, &t);
      double wall = MPI_Wtime() - t0, slowest = 0;
      MPI_Allreduce(&wall, &slowest, 1, MPI_DOUBLE, MPI_MAX, comm.comm);
      const Traffic all = total_traffic(comm, t);
      if (rep == 0) continue;
      walls.push_back(slowest);
      shares.push_back(slowest > 0 ? all.seconds / (comm.size() * slowest) : 0);
      last = all;
    }
    std::uint64_t fwd[2] = {mpi::last_forward_stats().forwards, mpi::last_forward_stats().rounds}, fwd_all[2] = {};
    MPI_Reduce(fwd, fwd_all, 2, MPI_UINT64_T, MPI_SUM, 0, comm.comm);
    if (!comm.root()) continue;
    // -- verified against one process on rank 0: bit for bit (replicated), or ties classified (data)
    TraceOutput ref;
    s.backend->prepare(*s.l.acc, o);
    s.backend->trace(*s.l.acc, rays, o, ref);
    std::string verdict;
    if (!s.ds) {
      const bool same = q == Query::any ? out.occluded == ref.occluded
                                        : std::equal(out.hits.begin(), out.hits.end(), ref.hits.begin(), ref.hits.end(),
                                                     [](const Hit& x, const Hit& y) { return std::memcmp(&x, &y, sizeof x) == 0; });
      verdict = same ? "bit-identical" : "DIFFERENT";
      verified = verified && same;
    } else {
      TraceOutput closest;
      if (q == Query::any) trace_reference(*s.l.acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, Query::closest}, closest, a.scene.threads);
      const Comparison c = q == Query::any
                               ? compare_occlusion_arrays(out.occluded, ref.occluded, closest.hits, rays)
                               : compare_hit_arrays(out.hits, ref.hits, {}, oracle_settlement(*s.l.acc, rays, oracle_tie_rule(*s.l.acc, rays)));
      verdict = std::to_string(c.mismatches) + " mismatches, " + std::to_string(c.ties) + " ties";
      verified = verified && c.mismatches == 0;
    }
    std::sort(walls.begin(), walls.end());
    std::sort(shares.begin(), shares.end());
    const double wall = walls[walls.size() / 2], n = static_cast<double>(std::max<std::size_t>(rays.size(), 1));
    say("%-8s %10zu %10.3f %11.1f%% %10.1f %10s %10s  %s\n", to_string(k), rays.size(), wall > 0 ? static_cast<double>(rays.size()) / wall * 1e-6 : 0.0,
        100.0 * shares[shares.size() / 2], static_cast<double>(last.bytes_received) / n,
        s.ds ? std::to_string(fwd_all[1] / static_cast<std::uint64_t>(comm.size())).c_str() : "-",
        s.ds ? (std::to_string(static_cast<double>(fwd_all[0]) / n).substr(0, 5)).c_str() : "-", verdict.c_str());
  }
  if (comm.root())
    say("%s, %s; Mrays/s: the median of %u runs (wall time of the slowest rank, MPI calls included); MPI share: the "
        "ranks' time in MPI calls\n",
        ranks_label(comm, a.scene.threads).c_str(), a.d.data() ? "data-parallel" : ("replicated, " + a.d.schedule_label()).c_str(),
        b.reps);
  return verified ? 0 : 1;
}

int run_check(const Comm& comm, MpiRunArgs& a) {
  const std::vector<RayKind> kinds = a.kind_list();
  Setup s = setup(comm, a);
  std::size_t genuine = 0;
  bool enough = true;
  if (comm.root()) say("%-8s %-8s %8s %14s %8s %10s\n", "kind", "query", "rays", "bit-identical", "ties", "mismatches");
  for (RayKind k : kinds) {
    const std::vector<Ray> rays = root_rays(comm, a, s, k);
    TraceOutput closest_ref;
    for (Query q : {Query::closest, Query::any}) {
      const TraceOptions o = a.options(*s.backend, q);
      prepare_local(*s.backend, s.ds.get(), s.l.acc.get(), o);
      TraceOutput out;
      distributed_trace(comm, *s.backend, &local_accel(s), s.ds.get(), rays, o, a.d, out, &s.tr);
      if (!comm.root()) continue;
      // one process: the reference traversal (cpu-scalar's) on the whole BVH
      TraceOutput ref;
      trace_reference(*s.l.acc, rays, TraceOptions{Layout::mbvh4, Traversal::stack, q}, ref, a.scene.threads);
      if (q == Query::closest) closest_ref = ref;
      const Comparison c =
          q == Query::any ? compare_occlusion_arrays(out.occluded, ref.occluded, closest_ref.hits, rays)
                          : compare_hit_arrays(out.hits, ref.hits, {}, oracle_settlement(*s.l.acc, rays, oracle_tie_rule(*s.l.acc, rays)));
      std::size_t same = 0;
      for (std::size_t i = 0; i < rays.size(); ++i)
        same += q == Query::any ? out.occluded[i] == ref.occluded[i] : std::memcmp(&out.hits[i], &ref.hits[i], sizeof(Hit)) == 0;
      const double share = rays.empty() ? 1.0 : static_cast<double>(same) / static_cast<double>(rays.size());
      genuine += c.mismatches;
      enough = enough && share >= 0.9999;
      say("%-8s %-8s %8zu %13.4f%% %8zu %10zu%s\n", to_string(k), to_string(q), rays.size(), 100.0 * share, c.ties, c.mismatches,
          share >= 0.9999 ? "" : "  (below 99.99 %)");
      for (std::size_t i : c.first_mismatches) say("  mismatch: ray %zu\n", i);
    }
  }
  if (!comm.root()) return 0;
  say("%s on %s against one process (the reference traversal on the whole scene's BVH): %zu genuine mismatches%s\n",
      a.d.distribute.c_str(), ranks_label(comm, a.scene.threads).c_str(), genuine,
      enough ? "; at least 99.99 % of the answers bit-identical on every kind"
             : "; fewer than 99.99 % of the answers bit-identical on some kind");
  return genuine == 0 ? 0 : 1;  // exit 1 for genuine mismatches only (a non-exact backend's ties are not)
}

}  // namespace

Command add_mpi_trace(CLI::App& app, const Comm& comm) {
  auto a = std::make_shared<MpiTraceArgs>();
  auto* c = app.add_subcommand("trace", "trace rays over the ranks; rank 0 writes hits (closest) or occlusion (any) in ray order");
  a->t.add(c);
  a->d.add(c, true);
  return {c, [a, comm] { return run_trace(comm, *a); }};
}

Command add_mpi_render(CLI::App& app, const Comm& comm) {
  auto a = std::make_shared<MpiRenderArgs>();
  auto* c = app.add_subcommand("render", "render an image over the ranks (8x8 tiles); rank 0 writes it, bit for bit mbvh render's");
  a->r.add(c);
  a->d.add(c, false);
  c->add_option("--tiles", a->tiles,
                "static (tile i on rank i mod P) or dynamic (chunks of tiles, each rank's own first, then stolen from the "
                "rank with the most left; replicated only)")
      ->check(CLI::IsMember({"static", "dynamic"}));
  return {c, [a, comm] { return run_render(comm, *a); }};
}

Command add_mpi_bench(CLI::App& app, const Comm& comm) {
  auto a = std::make_shared<BenchArgs>();
  auto* c = app.add_subcommand("bench", "time distributed traces of generated rays (shadow: any hit; the others: closest), "
                                        "with the share of time in MPI calls and the bytes sent a ray; verified on rank 0");
  a->run.add(c);
  a->run.d.add(c, true);
  c->add_option("--reps", a->reps, "timed runs per kind (after one warm-up); the median is reported")->check(integer_in(1, 1000));
  return {c, [a, comm] { return run_bench(comm, *a); }};
}

Command add_mpi_check(CLI::App& app, const Comm& comm) {
  auto a = std::make_shared<MpiRunArgs>();
  auto* c = app.add_subcommand("check", "trace generated rays over the ranks (closest and any hit) and compare them on rank 0 "
                                        "with one process's reference answers: bit-identical share, classified ties, "
                                        "genuine mismatches");
  a->add(c);
  a->d.add(c, true);
  return {c, [a, comm] { return run_check(comm, *a); }};
}

}  // namespace mbvh::cli

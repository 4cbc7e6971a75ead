// SPDX-License-Identifier: MIT
// main.cpp — the `mbvh` program: info, rays, trace, check, bench, render, devices.
#include <CLI/CLI.hpp>

#include <unistd.h>

#include <cfloat>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <iostream>
#include <nlohmann/json.hpp>

#include "mbvh/backend.h"
#include "mbvh/backends.h"
#include "host/tools/bench.h"
#include "host/tools/check.h"
#include "mbvh/error.h"
#include "host/core/io/output.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/cli/progress.h"
#include "mbvh/version.h"
#include "host/tools/raygen.h"
#include "host/tools/render.h"

using namespace mbvh;

namespace {

using Clock = std::chrono::steady_clock;

// The report (tables, "wrote ..."): standard output, or standard error while an output goes to
// standard output ('-'), so the two never mix.
FILE* g_report = stdout;
bool g_quiet = false;  // --quiet: no report, errors only

__attribute__((format(printf, 1, 2))) void say(const char* format, ...) {
  if (g_quiet) return;
  va_list args;
  va_start(args, format);
  std::vfprintf(g_report, format, args);
  va_end(args);
}

// Checks a command's outputs against each other and its inputs before any work (check_outputs),
// and sends the report to standard error if one of them is '-'. Empty paths are options not given;
// a generated scene (gen:...) is no input file.
void prepare_outputs(std::vector<OutputTarget> outputs, std::vector<InputFile> inputs) {
  std::erase_if(outputs, [](const OutputTarget& o) { return o.path.empty(); });
  std::erase_if(inputs, [](const InputFile& i) { return i.path.empty() || i.path.rfind("gen:", 0) == 0; });
  check_outputs(outputs, inputs);
  for (const OutputTarget& o : outputs)
    if (o.path == "-") g_report = stderr;
}

// Writes one output (write_outputs).
void write_bytes_to(const OutputTarget& to, const void* data, std::size_t size) {
  const OutputWrite w{to, data, size};
  write_outputs(std::span(&w, 1));
}

// How the report names an output.
std::string shown(const std::string& path) { return path == "-" ? "standard output" : path; }

double ms_since(Clock::time_point t0) { return std::chrono::duration<double, std::milli>(Clock::now() - t0).count(); }

std::vector<std::string> split_list(const std::string& s) {
  std::vector<std::string> out;
  std::size_t a = 0;
  while (a <= s.size()) {
    std::size_t b = s.find(',', a);
    if (b == std::string::npos) b = s.size();
    if (b > a) out.push_back(s.substr(a, b - a));
    a = b + 1;
  }
  return out;
}

template <class T, class F>
std::vector<T> parse_list(const std::string& s, F parse) {
  std::vector<T> out;
  for (const auto& x : split_list(s)) out.push_back(parse(x));
  if (out.empty()) throw Error("empty list '" + s + "'");
  return out;
}

// -- numeric options: every one range-checked before conversion; CLI11 puts the option's name in
// front of a validator's message ("--count: ...") and exits with its validation code

/// An unsigned integer option in [lo, hi], `why` appended to the error. Refuses a sign, which
/// CLI11 would wrap into 2^64-1 for a 64-bit option, and any trailing text.
CLI::Validator integer_in(std::uint64_t lo, std::uint64_t hi, const std::string& why = "") {
  const std::string range = "an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]";
  return CLI::Validator(
      [lo, hi, range, why](std::string& s) -> std::string {
        std::uint64_t v = 0;
        const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
        if (r.ec != std::errc() || r.ptr != s.data() + s.size() || v < lo || v > hi)
          return "'" + s + "' is not " + range + why;
        return "";
      },
      "INT in [" + std::to_string(lo) + ", " + std::to_string(hi) + "]");
}

/// A finite number in [lo, hi] (as a float, when `as_float`: 1e39 is not a finite float).
CLI::Validator number_in(double lo, double hi, bool as_float = false) {
  return CLI::Validator(
      [lo, hi, as_float](std::string& s) -> std::string {
        char* end = nullptr;
        const double v = std::strtod(s.c_str(), &end);
        const bool finite = std::isfinite(v) && (!as_float || std::isfinite(static_cast<float>(v)));
        if (s.empty() || end != s.c_str() + s.size() || !finite || v < lo || v > hi) {
          char range[96];
          std::snprintf(range, sizeof range, "a finite number in [%g, %g]", lo, hi);
          return "'" + s + "' is not " + range;
        }
        return "";
      },
      "NUMBER");
}

/// Items of `bytes_each` bytes that fit in this machine's physical memory (the bound of the
/// count options: a larger count is an error naming the option, not a failed allocation).
std::uint64_t fits_in_memory(std::uint64_t bytes_each) {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  const std::uint64_t bytes = pages > 0 && page > 0 ? std::uint64_t(pages) * std::uint64_t(page) : std::uint64_t(1) << 34;
  return std::max<std::uint64_t>(1, bytes / bytes_each);
}

/// The bound of ray counts: a traced ray holds its 32-byte record, its 16-byte hit and copies.
constexpr std::uint64_t kBytesPerRay = 64;
/// The bound of image sizes: a pixel holds its radiance, a path's ray, hit and state.
constexpr std::uint64_t kBytesPerPixel = 256;
CLI::Validator ray_count() {
  return integer_in(1, fits_in_memory(kBytesPerRay),
                    " (" + std::to_string(kBytesPerRay) + " bytes per ray must fit in this machine's memory)");
}

struct SceneArgs {
  std::string scene;
  unsigned threads = 0;
  unsigned max_leaf = BuildOptions{}.max_leaf;
  unsigned leaf_block = BuildOptions{}.leaf_block;
  std::string cache;
  std::string quality = to_string(BuildOptions{}.quality);
};

void add_scene_args(CLI::App* c, SceneArgs& a) {
  c->add_option("scene", a.scene, "scene file (.obj/.ply, optionally .zst) or gen:NAME:PARAMS")->required();
  c->add_option("--threads", a.threads, "worker threads (0 = all hardware threads)")->check(integer_in(0, kMaxThreads));
  c->add_option("--max-leaf", a.max_leaf, "largest leaf the SAH may choose")->check(integer_in(1, 1024));
  c->add_option("--leaf-block", a.leaf_block, "triangles the SAH prices as one leaf test (4: SIMD leaves)")
      ->check(integer_in(1, 64));
  c->add_option("--cache", a.cache,
                "BVH cache directory: the build is read from it when it holds this scene's with these options, "
                "else built and written there (a damaged or mismatched file is rebuilt)");
  c->add_option("--quality", a.quality,
                "builder: low (Morton-code LBVH, fastest build), medium (binned SAH, the default) or high (SBVH)")
      ->check(CLI::IsMember({"low", "medium", "high"}));
}

struct Loaded {
  Scene scene;
  std::unique_ptr<Accel> acc;
  double load_ms = 0;
};

Loaded load_and_build(const SceneArgs& a, bool verbose = true) {
  Loaded l;
  auto t0 = Clock::now();
  l.scene = load_scene(a.scene);
  l.load_ms = ms_since(t0);
  BuildOptions bo;
  bo.threads = a.threads;
  bo.max_leaf = a.max_leaf;
  bo.leaf_block = a.leaf_block;
  bo.quality = parse_quality(a.quality);
  Progress p("building BVH", 1000);
  bo.progress = [&p](double f) { p.update(static_cast<std::size_t>(f * 1000)); };
  const auto t1 = Clock::now();
  Accel::CacheReport cr;
  l.acc = a.cache.empty() ? Accel::build(l.scene, bo) : Accel::build_cached(l.scene, bo, a.cache, &cr);
  const double ms = ms_since(t1);
  p.finish();
  if (!cr.problem.empty()) std::fprintf(stderr, "mbvh: warning: %s; rebuilt and replaced\n", cr.problem.c_str());
  if (!g_quiet && (verbose || !a.cache.empty()))
    std::fprintf(stderr, "scene %s: %zu triangles, loaded in %.1f ms; BVH %s in %.1f ms%s%s, hash %016llx\n",
                 a.scene.c_str(), l.scene.triangle_count(), l.load_ms, cr.loaded ? "read from the cache" : "built",
                 cr.loaded ? ms : l.acc->binary_stats().build_ms, a.cache.empty() ? "" : cr.loaded ? ": " : ", cached in ",
                 cr.path.c_str(), static_cast<unsigned long long>(l.acc->hash()));
  return l;
}

// The layout used when --layout is not given: MBVH4, or MBVH2 where the backend has no MBVH4
// traversal of that kind (vulkan).
Layout default_layout(const Backend& b, Traversal t) {
  return !b.supports(Layout::mbvh4, t) && b.supports(Layout::mbvh2, t) ? Layout::mbvh2 : Layout::mbvh4;
}

// --cl-device, --vk-device: which device the OpenCL and Vulkan backends use; --cl-mapping;
// --vk-validation.
struct DeviceArgs {
  std::string cl_device, vk_device, cl_mapping = "auto";
  bool vk_validation = false;
  void add(CLI::App* c) {
    c->add_option("--cl-device", cl_device,
                  "OpenCL device: P:D (platform:device), N (index), gpu, cpu or accelerator (the first of that type) or "
                  "part of its name (see `mbvh devices`; default: a GPU if there is one)");
    c->add_option("--cl-mapping", cl_mapping,
                  "OpenCL work mapping: auto (by device type), cpu (16-wide node test) or gpu (ray per lane, "
                  "work-groups from the kernel's preferred multiple); forcing gpu on a CPU device tests that mapping")
        ->check(CLI::IsMember({"auto", "cpu", "gpu"}));
    c->add_option("--vk-device", vk_device,
                  "Vulkan device: index, gpu or cpu (the first of that type) or part of its name (see `mbvh devices`; "
                  "default: a discrete GPU if there is one)");
    c->add_flag("--vk-validation", vk_validation,
                "Vulkan: enable the Khronos validation layer; any message it reports is an error "
                "(also MBVH_VK_VALIDATION=1)");
  }
  BackendOptions options(unsigned threads) const {
    BackendOptions o;
    o.threads = threads;
    o.cl_device = cl_device;
    o.cl_mapping = cl_mapping;
    o.vk_device = vk_device;
    o.vk_validation = vk_validation;
    return o;
  }
};

// `--backend all`: every backend built into this binary whose hardware this machine has, each
// once (a backend another name stands for, cpu-avx512 under `cpu`, only under that name). A
// backend that is built but fails to start is an error, not left out.
std::vector<std::string> all_backends() {
  std::vector<std::string> names, aliased;
  const auto infos = list_backends();
  for (const auto& b : infos)
    if (!b.alias_of.empty()) aliased.push_back(b.alias_of);
  for (const auto& b : infos) {
    if (!b.make || (b.missing_hardware && !b.missing_hardware().empty())) continue;
    if (std::find(aliased.begin(), aliased.end(), b.name) != aliased.end()) continue;
    names.push_back(b.name);
  }
  return names;
}

// --backend, --layout, --traversal, --query as comma-separated lists (check and bench).
struct GridArgs {
  DeviceArgs dev;
  std::string backends = "cpu", layouts = "mbvh2,mbvh4,mbvh8", traversals = "stack,bitstack,stack-ordered,bitstack-retest",
              queries = "closest,any", precisions = "robust";
  void add(CLI::App* c) {
    c->add_option("--backend", backends,
                  "comma-separated backends (see `mbvh devices`), or 'all': every backend this machine runs, once each");
    c->add_option("--layout", layouts, "comma-separated layouts: mbvh2, mbvh4, mbvh8 (stack, bitstack, stack-ordered)");
    c->add_option("--traversal", traversals,
                  "comma-separated traversals: stack, bitstack, stack-ordered, bitstack-retest (the last two MBVH4/8)");
    c->add_option("--query", queries, "comma-separated queries: closest, any");
    c->add_option("--precision", precisions,
                  "comma-separated accuracy modes: robust (default), exact (the same kernels, refused by embree), fast "
                  "(non-conservative boxes, Moller-Trumbore)");
    dev.add(c);
  }
  VariantGrid parse() const {
    VariantGrid g;
    g.backends = backends == "all" ? all_backends() : split_list(backends);
    g.layouts = parse_list<Layout>(layouts, parse_layout);
    g.traversals = parse_list<Traversal>(traversals, parse_traversal);
    g.queries = parse_list<Query>(queries, parse_query);
    g.precisions = parse_list<Precision>(precisions, parse_precision);
    for (const auto& b : g.backends) make_backend(b, dev.options(0));  // fail early, naming the backend
    return g;
  }
};

void add_camera_option(CLI::App* c, std::vector<float>& camera) {
  c->add_option("--camera", camera, "eye x y z, target x y z [, fov degrees] (default: frames the scene)")
      ->delimiter(',')
      ->expected(6, 7)
      ->check(number_in(-FLT_MAX, FLT_MAX, true));
}

struct RayArgs {
  std::string rays_file;
  std::string kind = "primary";
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  std::vector<float> camera;
};

void add_ray_args(CLI::App* c, RayArgs& r, bool allow_file) {
  if (allow_file) c->add_option("--rays", r.rays_file, "ray file (32 bytes per ray) instead of generated rays");
  c->add_option("--kind", r.kind, "generated ray kind: primary, shadow, diffuse, random, inside (closed generated meshes), special, path (the path tracer's bounces)");
  c->add_option("--count", r.count, "number of generated rays")->check(ray_count());
  c->add_option("--seed", r.seed, "seed of the generated rays")->check(integer_in(0, UINT64_MAX));
  add_camera_option(c, r.camera);
}

// --camera's values go in `cam`; a camera that cannot make rays is an error naming --camera.
void set_camera(const std::vector<float>& c, bool& has, Camera& cam) {
  if (c.empty()) return;
  has = true;
  cam.eye = {c[0], c[1], c[2]};
  cam.target = {c[3], c[4], c[5]};
  if (c.size() == 7) cam.fov_deg = c[6];
  if (const std::string p = camera_problem(cam); !p.empty()) {
    std::string text;
    for (float v : c) {
      char x[32];
      std::snprintf(x, sizeof x, "%s%g", text.empty() ? "" : ",", static_cast<double>(v));
      text += x;
    }
    throw Error("--camera " + text + ": " + p);
  }
}

RayGenOptions ray_gen(const RayArgs& r, const std::string& kind, unsigned threads) {
  RayGenOptions o;
  o.kind = parse_ray_kind(kind);
  o.count = r.count;
  o.seed = r.seed;
  o.threads = threads;
  set_camera(r.camera, o.has_camera, o.camera);
  return o;
}

std::vector<Ray> get_rays(const RayArgs& r, const Loaded& l, unsigned threads) {
  if (!r.rays_file.empty()) return read_rays(r.rays_file);
  return generate_rays(l.scene, *l.acc, ray_gen(r, r.kind, threads));
}

void print_stats_row(const LayoutStats& s, std::size_t state_stack, std::size_t state_bit) {
  say("%-7s %9zu %9zu %6u %9u %10.2f %12zu %9.1f %10zu %10zu\n", s.layout.c_str(), s.nodes, s.leaves, s.depth,
      s.bitstack_bits, s.sah_cost, s.bytes, s.build_ms, state_stack, state_bit);
}

// `mbvh info --refit`: refits the build to the scene's vertices moved by a smooth displacement
// (0.2 % of the scene's extent), then rebuilds the moved scene with the same options, and prints
// both times and SAH costs side by side.
void info_refit(const SceneArgs& a, Loaded& l) {
  Scene moved = l.scene;
  moved.name += " (moved)";
  const Box b = l.acc->bounds();
  const Vec3f e = b.extent();
  const float ext = std::max({e.x, e.y, e.z});
  for (Vec3f& v : moved.vertices) {
    const Vec3f p = v;
    v.x = p.x + 0.002f * ext * std::sin(6.0f * p.y / ext);
    v.y = p.y + 0.002f * ext * std::sin(6.0f * p.z / ext);
    v.z = p.z + 0.002f * ext * std::sin(6.0f * p.x / ext);
  }
  l.acc->refit(moved);
  const double refit_ms = l.acc->last_refit_ms();
  BuildOptions bo = l.acc->options();
  bo.progress = nullptr;
  const auto t0 = Clock::now();
  const auto rebuilt = Accel::build(moved, bo);
  const double build_ms = ms_since(t0);
  for (Layout lay : {Layout::mbvh2, Layout::mbvh4, Layout::mbvh8}) rebuilt->make_layout(lay);
  const double layouts_ms = ms_since(t0);
  say("\nrefit      %.1f ms (binary tree, leaves, triangles and the MBVH2/4/8 layouts made above); a rebuild of the "
      "moved scene %.1f ms (%.1fx the refit), with those layouts %.1f ms (%.1fx); SAH cost refitted %.2f, rebuilt %.2f "
      "(%u threads)\n",
      refit_ms, build_ms, build_ms / std::max(refit_ms, 1e-6), layouts_ms, layouts_ms / std::max(refit_ms, 1e-6),
      l.acc->binary_stats().sah_cost, rebuilt->binary_stats().sah_cost, static_cast<unsigned>(resolve_threads(a.threads)));
}

int cmd_info(const SceneArgs& a, const std::string& json_path, bool refit) {
  prepare_outputs({{"--json", json_path, true}}, {{"scene", a.scene}});
  Loaded l = load_and_build(a, false);
  const Accel& acc = *l.acc;
  const Box b = acc.bounds();
  say("scene      %s\n", l.scene.name.c_str());
  say("triangles  %zu (%zu degenerate, kept out of leaves), %zu vertices, loaded in %.1f ms\n",
      l.scene.triangle_count(), acc.bvh2().degenerate, l.scene.vertices.size(), l.load_ms);
  say("bounds     (%g, %g, %g) .. (%g, %g, %g)\n", b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z);
  say("build      %s, %u bins, max leaf %u, leaf block %u, depth cap %u, %u threads; hash %016llx\n",
      acc.options().quality == BuildQuality::low    ? "Morton LBVH (quality low)"
      : acc.options().quality == BuildQuality::high ? "SBVH, spatial splits (quality high)"
                                                    : "binned SAH (quality medium)",
      acc.options().bins, acc.options().max_leaf, acc.options().leaf_block, acc.options().depth_cap,
      static_cast<unsigned>(resolve_threads(a.threads)), static_cast<unsigned long long>(acc.hash()));
  {
    const double* ph = acc.binary_stats().phase_ms;
    say("build ms   records %.1f, tree %.1f, flatten %.1f, stats and hash %.1f\n", ph[0], ph[1], ph[2], ph[3]);
  }
  say("leaves     largest %zu triangles, %zu forced by the depth cap or equal centroids; %zu references (%.1f %% more than triangles)\n\n",
      acc.bvh2().largest_leaf, acc.bvh2().forced_leaves, acc.tris().size(),
      100.0 * (double(acc.tris().size()) / double(l.scene.triangle_count() - acc.bvh2().degenerate) - 1.0));
  say("%-7s %9s %9s %6s %9s %10s %12s %9s %10s %10s\n", "layout", "nodes", "leaves", "depth", "bits", "SAH cost",
      "bytes", "build ms", "stack B/r", "bitstk B/r");
  const LayoutStats& bs = acc.binary_stats();
  print_stats_row(bs, 0, 0);
  const LayoutStats s2 = acc.mbvh2().stats;
  const LayoutStats s4 = acc.mbvh4().stats;
  const LayoutStats s8 = acc.mbvh8().stats;
  print_stats_row(s2, state_bytes_per_ray(Layout::mbvh2, Traversal::stack), state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack));
  print_stats_row(s4, state_bytes_per_ray(Layout::mbvh4, Traversal::stack), state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack));
  print_stats_row(s8, state_bytes_per_ray(Layout::mbvh8, Traversal::stack), state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack));
  say("\ntraversal state per ray: stack %zu B, bitstack %zu B (%.1fx smaller)\n",
      state_bytes_per_ray(Layout::mbvh2, Traversal::stack), state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack),
      double(state_bytes_per_ray(Layout::mbvh2, Traversal::stack)) / double(state_bytes_per_ray(Layout::mbvh2, Traversal::bitstack)));
  if (!json_path.empty()) {
    nlohmann::json j;
    j["scene"] = l.scene.name;
    j["triangles"] = l.scene.triangle_count();
    char h[32];
    std::snprintf(h, sizeof h, "%016llx", static_cast<unsigned long long>(acc.hash()));
    j["hash"] = h;
    j["quality"] = to_string(acc.options().quality);
    j["build_phases_ms"] = {{"records", bs.phase_ms[0]}, {"tree", bs.phase_ms[1]}, {"flatten", bs.phase_ms[2]},
                            {"stats_hash", bs.phase_ms[3]}};
    j["references"] = acc.tris().size();
    for (const LayoutStats* s : {&bs, &s2, &s4, &s8})
      j["layouts"].push_back({{"layout", s->layout}, {"nodes", s->nodes}, {"leaves", s->leaves}, {"depth", s->depth},
                              {"bitstack_bits", s->bitstack_bits}, {"sah_cost", s->sah_cost}, {"bytes", s->bytes},
                              {"build_ms", s->build_ms}});
    const std::string text = j.dump(2) + "\n";
    write_bytes_to({"--json", json_path, true}, text.data(), text.size());
  }
  if (refit) info_refit(a, l);
  return 0;
}

// One ray kind of `mbvh check --json`: the rays, and every comparison with its counts (labels
// "backend/layout/traversal/query", as the table).
nlohmann::json check_json(const CheckReport& rep, const std::string& kind) {
  nlohmann::json k{{"kind", kind},
                   {"rays", rep.rays},
                   {"invalid", rep.invalid},
                   {"brute_rays", rep.brute_rays},
                   {"mismatches", rep.mismatches()},
                   {"comparisons", nlohmann::json::array()}};
  for (const Comparison& c : rep.comparisons)
    k["comparisons"].push_back({{"a", c.a},
                                {"b", c.b},
                                {"rays", c.rays},
                                {"equal", c.equal},
                                {"ties", c.ties},
                                {"mismatches", c.mismatches},
                                {"bit_identical", c.bit_identical},
                                {"max_t_ulps", c.max_t_ulps}});
  return k;
}

}  // namespace

// `mbvh build-bench`: build time of our builder (Accel::build, then the MBVH4 collapse) and of
// the embree peer (rtcCommitScene on the build's triangles, each prim once, with the triangle
// copy), median of --repeats fresh builds each, at --threads; and our tree's SAH cost. Embree is
// left out with a note where it is not built in.
struct VersusArgs {
  std::string quality;         // "": no side-by-side trace
  std::string backend = "cpu";
  std::size_t count = 200000;  // diffuse rays
  unsigned passes = 15;
  std::vector<float> camera;
};

int cmd_build_bench(const SceneArgs& a, unsigned repeats, const std::string& json_path, const VersusArgs& vs) {
  prepare_outputs({{"--json", json_path, true}}, {{"scene", a.scene}});
  const Scene scene = load_scene(a.scene);
  BuildOptions bo;
  bo.threads = a.threads;
  bo.max_leaf = a.max_leaf;
  bo.leaf_block = a.leaf_block;
  bo.quality = parse_quality(a.quality);
  auto median = [](std::vector<double> v) {
    std::sort(v.begin(), v.end());
    return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
  };
  std::vector<double> ours, embree;
  std::unique_ptr<Accel> acc;
  for (unsigned r = 0; r < repeats; ++r) {
    acc.reset();
    const auto t0 = Clock::now();
    acc = Accel::build(scene, bo);
    acc->mbvh4();
    ours.push_back(ms_since(t0));
  }
  nlohmann::json j;
  j["scene"] = scene.name;
  j["triangles"] = scene.triangle_count();
  j["threads"] = resolve_threads(a.threads);
  j["quality"] = to_string(bo.quality);
  j["repeats"] = repeats;
  j["hash"] = acc->hash();
  j["references"] = acc->tris().size();
  j["sah_binary"] = acc->binary_stats().sah_cost;
  j["sah_mbvh4"] = acc->mbvh4().stats.sah_cost;
  j["build_ms"] = median(ours);
  j["build_ms_all"] = ours;
  say("%s, %zu triangles, quality %s, %u threads: ours %.1f ms (build + MBVH4, median of %u), SAH %.2f, %zu references\n",
      scene.name.c_str(), scene.triangle_count(), to_string(bo.quality), resolve_threads(a.threads), median(ours), repeats,
      acc->binary_stats().sah_cost, acc->tris().size());
  bool have_embree = false;
  for (const BackendInfo& b : list_backends()) have_embree |= b.name == "embree" && b.make != nullptr;
  if (have_embree) {
    BackendOptions eo;
    eo.threads = a.threads;
    eo.quality = bo.quality;
    TraceOptions to;
    to.layout = Layout::mbvh4;
    to.traversal = Traversal::stack;
    for (unsigned r = 0; r < repeats; ++r) {
      auto be = make_backend("embree", eo);  // a fresh device and scene each time (device start not timed)
      const auto t0 = Clock::now();
      be->prepare(*acc, to);
      embree.push_back(ms_since(t0));
    }
    j["embree_build_ms"] = median(embree);
    j["embree_build_ms_all"] = embree;
    say("  embree %.1f ms (rtcCommitScene with the triangle copy, median of %u)\n", median(embree), repeats);
  } else {
    j["embree_build_ms"] = nullptr;
    say("  embree: not built in\n");
  }
  if (!vs.quality.empty()) {
    // -- side by side: the same diffuse rays on this tree and on a --versus tree, passes
    //    interleaved (this, versus, this, ...) so that a machine's changing load hits both alike;
    //    the ratio is the median of the per-pair ratios. The two trees' hits must be identical.
    BuildOptions vo = bo;
    vo.quality = parse_quality(vs.quality);
    const auto other = Accel::build(scene, vo);
    RayGenOptions ro;
    ro.kind = RayKind::diffuse;
    ro.count = vs.count;
    ro.threads = a.threads;
    set_camera(vs.camera, ro.has_camera, ro.camera);
    const std::vector<Ray> rays = generate_rays(scene, *acc, ro);
    BackendOptions eo;
    eo.threads = a.threads;
    auto be = make_backend(vs.backend, eo);
    TraceOptions to;
    to.layout = Layout::mbvh4;
    to.traversal = Traversal::stack;
    TraceOutput out[2];
    const Accel* trees[2] = {acc.get(), other.get()};
    for (int t = 0; t < 2; ++t) be->trace(*trees[t], rays, to, out[t]);  // warm-up and check
    if (std::memcmp(out[0].hits.data(), out[1].hits.data(), rays.size() * sizeof(Hit)) != 0)
      throw Error("build-bench: the " + vs.quality + " tree's hits differ from the " + to_string(bo.quality) + " tree's");
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
    j["versus"] = v;
    say("  %s, %zu diffuse rays, %u interleaved passes: %s %.3f Mrays/s, %s %.3f Mrays/s, speed %s/%s %.3fx (median of per-pair ratios; min %.3f, max %.3f)\n",
        be->name().c_str(), rays.size(), vs.passes, to_string(bo.quality), median(mr[0]), vs.quality.c_str(),
        median(mr[1]), to_string(bo.quality), vs.quality.c_str(), median(ratio), *std::min_element(ratio.begin(), ratio.end()),
        *std::max_element(ratio.begin(), ratio.end()));
  }
  if (!json_path.empty()) {
    const std::string text = j.dump(2) + "\n";
    const OutputTarget out{"--json", json_path, true};
    const std::vector<OutputWrite> writes{{out, text.data(), text.size()}};
    write_outputs(writes);
  }
  return 0;
}

static int run(int argc, char** argv) {
  CLI::App app{"mbvh " MBVH_VERSION_STRING " — one MBVH2/MBVH4/MBVH8 build, stackless bitstack traversal on several "
               "backends\n\nexit status: 0 success; 1 `check` found a genuine mismatch or `bench` a timed result "
               "that did not verify; 2 an error (a bad option or value, a bad input, a failed run)"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "help for every command");
  app.set_version_flag("--version", "mbvh " MBVH_VERSION_STRING);
  app.option_defaults()->always_capture_default();  // --help shows every option's default
  app.fallthrough();  // --quiet may follow the subcommand
  app.add_flag("-q,--quiet", g_quiet, "print nothing but errors (outputs are still written)");

  // -- info
  SceneArgs info_a;
  std::string info_json;
  auto* info = app.add_subcommand("info", "scene and per-layout build statistics");
  add_scene_args(info, info_a);
  info->add_option("--json", info_json, "also write the statistics as JSON ('-': standard output)");
  bool info_refit_flag = false;
  info->add_flag("--refit", info_refit_flag,
                 "also refit the build to the vertices moved by a small smooth displacement and time it beside a "
                 "rebuild of the moved scene");

  // -- rays
  SceneArgs rays_a;
  RayArgs rays_r;
  std::string rays_out;
  auto* rays = app.add_subcommand("rays", "generate a ray file (32 bytes per ray)");
  add_scene_args(rays, rays_a);
  add_ray_args(rays, rays_r, false);
  rays->add_option("-o,--output", rays_out, "output ray file ('-': standard output)")->required();

  // -- trace
  SceneArgs tr_a;
  RayArgs tr_r;
  std::string tr_backend = "cpu", tr_layout = "mbvh4", tr_trav = "bitstack", tr_query = "closest", tr_out;
  bool tr_stats = false;
  auto* trace = app.add_subcommand("trace", "trace rays; write hits (closest) or occlusion (any)");
  add_scene_args(trace, tr_a);
  add_ray_args(trace, tr_r, true);
  trace->add_option("--backend", tr_backend, "backend (see `mbvh devices`)");
  trace->add_option("--layout", tr_layout, "mbvh2, mbvh4 or mbvh8 (default: mbvh4, or mbvh2 where the backend has only that)");
  trace->add_option("--traversal", tr_trav, "stack, bitstack, stack-ordered or bitstack-retest (bitstack-retest: MBVH4 only)");
  trace->add_option("--query", tr_query, "closest (writes hits, 16 B/ray) or any (writes occlusion, 1 B/ray)");
  trace->add_option("-o,--output", tr_out, "output file ('-': standard output)");
  trace->add_flag("--stats", tr_stats, "also count work per ray (slower)");
  std::string tr_precision = "robust";
  trace->add_option("--precision", tr_precision, "accuracy mode: robust (default), exact or fast");
  DeviceArgs tr_dev;
  tr_dev.add(trace);

  // -- check
  SceneArgs ck_a;
  RayArgs ck_r;
  GridArgs ck_g;
  std::string ck_kinds = "", ck_brute = "2000", ck_json;
  auto* check = app.add_subcommand("check", "cross-check backends x layouts x traversals ray by ray and against brute force");
  add_scene_args(check, ck_a);
  add_ray_args(check, ck_r, true);
  ck_g.add(check);
  check->add_option("--kinds", ck_kinds, "comma-separated generated ray kinds (default: --kind)");
  check->add_option("--brute", ck_brute, "rays checked by double-precision brute force, spread over the batch, or 'all'")
      ->check(CLI::IsMember({"all"}) | integer_in(0, UINT64_MAX));
  check->add_option("--json", ck_json, "also write every comparison as JSON (per ray kind: rays, invalid, pairs)");

  // -- bench
  SceneArgs bn_a;
  GridArgs bn_g;
  std::string bn_kinds = "primary,diffuse", bn_json;
  std::size_t bn_count = 100000;
  unsigned bn_passes = 5;
  std::uint64_t bn_seed = 1;
  auto* bench = app.add_subcommand("bench", "Mrays/s, traversal state and work per ray, verified before timing");
  add_scene_args(bench, bn_a);
  bn_g.add(bench);
  bench->add_option("--kinds", bn_kinds, "comma-separated ray kinds");
  bench->add_option("--count", bn_count, "rays per kind")->check(ray_count());
  std::size_t bn_error = 0;
  bench->add_option("--error-rays", bn_error,
                    "rays per kind whose closest hits are also compared with the double-precision brute force "
                    "(error_rate in the records; inside rays also count leaks)")
      ->check(integer_in(0, fits_in_memory(kBytesPerRay)));
  bench->add_option("--seed", bn_seed, "ray seed")->check(integer_in(0, UINT64_MAX));
  bench->add_option("--passes", bn_passes, "timed passes after the warm-up (at least 5)")->check(integer_in(5, 1000000));
  double bn_warmup = 0.25;
  bool bn_first_layout = false;
  bench->add_flag("--first-layout", bn_first_layout,
                  "per backend and traversal, only the first layout of --layout it has (mbvh4,mbvh2: MBVH4, else MBVH2)");
  bench->add_option("--warmup", bn_warmup, "seconds of untimed passes before the timed ones (after the verifying pass)")
      ->check(number_in(0, 3600));
  std::vector<float> bn_camera;
  add_camera_option(bench, bn_camera);
  bench->add_option("--json", bn_json, "write the records as JSON ('-': standard output)");
  std::string bn_csv;
  bench->add_option("--csv", bn_csv, "write the records as CSV, one line per record ('-': standard output)");
  bool bn_scaling = false;
  bench->add_flag("--scaling", bn_scaling,
                  "also time each variant on 1 thread, passes interleaved with the N-thread ones (thread scaling)");

  // -- render
  SceneArgs rn_a;
  DeviceArgs rn_dev;
  std::string rn_backend = "cpu", rn_layout = "mbvh4", rn_trav = "bitstack", rn_mode = "path", rn_out;
  RenderOptions rn_o;
  std::vector<float> rn_camera;
  auto* render_cmd = app.add_subcommand("render", "render an image on a backend: 8-bounce diffuse path tracing, AO or normals");
  add_scene_args(render_cmd, rn_a);
  render_cmd->add_option("--backend", rn_backend, "backend (see `mbvh devices`)");
  render_cmd->add_option("--layout", rn_layout, "mbvh2, mbvh4 or mbvh8 (default: mbvh4, or mbvh2 where the backend has only that)");
  render_cmd->add_option("--traversal", rn_trav, "stack, bitstack, stack-ordered or bitstack-retest");
  render_cmd->add_option("--mode", rn_mode, "path (8-bounce diffuse, point light and sky), ao or normals");
  render_cmd->add_option("--spp", rn_o.spp, "samples per pixel")->check(integer_in(1, 1u << 20));
  render_cmd->add_option("--bounces", rn_o.bounces, "path mode: diffuse bounces after the primary hit")
      ->check(integer_in(0, 1024));
  render_cmd->add_option("--width", rn_o.width, "image width")->check(integer_in(1, 65536));
  render_cmd->add_option("--height", rn_o.height, "image height")->check(integer_in(1, 65536));
  render_cmd->add_option("--seed", rn_o.seed, "seed of every random number of the image")->check(integer_in(0, UINT64_MAX));
  add_camera_option(render_cmd, rn_camera);
  render_cmd->add_option("-o,--output", rn_out, "PNG file ('-': standard output, not a terminal)")->required();
  std::string rn_precision = "robust", rn_pfm, rn_reference, rn_curve;
  render_cmd->add_option("--precision", rn_precision, "accuracy mode: robust (default), exact or fast");
  render_cmd->add_option("--pfm", rn_pfm, "also write the linear image as PFM (a reference for --reference)");
  render_cmd->add_option("--reference", rn_reference,
                         "PFM of the same size: report the RMSE against it after every sample pass");
  render_cmd->add_option("--curve", rn_curve, "with --reference: write the RMSE-against-time curve as JSON");
  rn_dev.add(render_cmd);

  // -- build-bench
  SceneArgs bb_a;
  unsigned bb_repeats = 5;
  std::string bb_json;
  auto* build_bench = app.add_subcommand("build-bench", "build time (median of --repeats) of ours and of the embree peer, and our tree's SAH");
  add_scene_args(build_bench, bb_a);
  build_bench->add_option("--repeats", bb_repeats, "builds timed per builder (median reported)")->check(integer_in(1, 1000));
  build_bench->add_option("--json", bb_json, "also write the results as JSON ('-': standard output)");
  VersusArgs bb_vs;
  build_bench->add_option("--versus", bb_vs.quality,
                          "also trace diffuse rays on this tree and on one of quality VERSUS, passes interleaved, and "
                          "report the speed ratio (median of per-pair ratios)")
      ->check(CLI::IsMember({"low", "medium", "high"}));
  build_bench->add_option("--versus-backend", bb_vs.backend, "backend of --versus (default cpu)");
  build_bench->add_option("--versus-count", bb_vs.count, "diffuse rays of --versus")->check(ray_count());
  build_bench->add_option("--versus-passes", bb_vs.passes, "interleaved pass pairs of --versus")->check(integer_in(1, 100000));
  add_camera_option(build_bench, bb_vs.camera);

  // -- devices
  auto* devices = app.add_subcommand("devices", "list the backends of this build, their devices and whether they can start");
  DeviceArgs dv_dev;
  dv_dev.add(devices);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {  // --help and --version exit 0; every usage error exits 2
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (g_quiet) Progress::set_enabled(false);
  try {
    if (*info) return cmd_info(info_a, info_json, info_refit_flag);
    if (*build_bench) return cmd_build_bench(bb_a, bb_repeats, bb_json, bb_vs);

    if (*rays) {
      const OutputTarget out{"-o", rays_out};
      prepare_outputs({out}, {{"scene", rays_a.scene}});
      Loaded l = load_and_build(rays_a);
      const std::vector<Ray> r = generate_rays(l.scene, *l.acc, ray_gen(rays_r, rays_r.kind, rays_a.threads));
      write_bytes_to(out, r.data(), r.size() * sizeof(Ray));
      say("wrote %zu %s rays (seed %llu) to %s\n", r.size(), rays_r.kind.c_str(),
          static_cast<unsigned long long>(rays_r.seed), shown(rays_out).c_str());
      return 0;
    }

    if (*render_cmd) {
      const std::vector<OutputTarget> outs{{"-o", rn_out}, {"--pfm", rn_pfm}, {"--curve", rn_curve, true}};
      prepare_outputs(outs, {{"scene", rn_a.scene}, {"--reference", rn_reference}});
      if (const std::uint64_t pixels = std::uint64_t(rn_o.width) * rn_o.height; pixels > fits_in_memory(kBytesPerPixel))
        throw Error("--width " + std::to_string(rn_o.width) + " --height " + std::to_string(rn_o.height) + ": " +
                    std::to_string(pixels) + " pixels of " + std::to_string(kBytesPerPixel) +
                    " bytes each do not fit in this machine's memory");
      rn_o.mode = parse_render_mode(rn_mode);
      rn_o.traversal = parse_traversal(rn_trav);
      rn_o.threads = rn_a.threads;
      rn_o.precision = parse_precision(rn_precision);
      set_camera(rn_camera, rn_o.has_camera, rn_o.camera);
      std::vector<float> reference;
      if (!rn_reference.empty()) {
        unsigned w = 0, h = 0;
        reference = read_pfm(rn_reference, w, h);
        if (w != rn_o.width || h != rn_o.height)
          throw Error(rn_reference + ": the reference is " + std::to_string(w) + "x" + std::to_string(h) + ", the image " +
                      std::to_string(rn_o.width) + "x" + std::to_string(rn_o.height));
        rn_o.reference = &reference;
      } else if (!rn_curve.empty()) {
        throw Error("--curve needs --reference (the converged image the curve measures against)");
      }
      auto backend = make_backend(rn_backend, rn_dev.options(rn_a.threads));
      // a backend without a bitstack (embree) renders with its stack unless --traversal says otherwise
      if (!render_cmd->count("--traversal") && !backend->supports(default_layout(*backend, rn_o.traversal), rn_o.traversal))
        rn_o.traversal = Traversal::stack;
      rn_o.layout = render_cmd->count("--layout") ? parse_layout(rn_layout) : default_layout(*backend, rn_o.traversal);
      Loaded l = load_and_build(rn_a);
      if (!g_quiet) std::fprintf(stderr, "backend: %s\n", backend->describe().c_str());
      backend->prepare(*l.acc, TraceOptions{rn_o.layout, rn_o.traversal, Query::closest, false, rn_o.precision});
      Progress p("rendering", rn_o.spp);
      const RenderResult res = render(l.scene, *l.acc, *backend, rn_o, [&p](unsigned d, unsigned) { p.update(d); });
      p.finish();
      // all outputs or none: the PNG is not left behind when the PFM or the curve cannot be written
      const std::vector<std::uint8_t> png = png_bytes(rn_out, res.width, res.height, to_srgb8(res.rgb));
      std::vector<OutputWrite> writes{{outs[0], png.data(), png.size()}};
      std::vector<char> pfm;
      if (!rn_pfm.empty()) {
        pfm = pfm_bytes(rn_pfm, res.width, res.height, res.rgb);
        writes.push_back({outs[1], pfm.data(), pfm.size()});
      }
      std::string curve;
      if (!rn_curve.empty()) {
        nlohmann::json j{{"backend", rn_backend},       {"device", backend->describe()}, {"precision", rn_precision},
                         {"scene", l.scene.name},        {"width", res.width},            {"height", res.height},
                         {"rays", res.rays},             {"mrays_per_s", res.mrays_per_s()}, {"points", nlohmann::json::array()}};
        for (const CurvePoint& c : res.curve)
          j["points"].push_back(
              {{"spp", c.spp}, {"trace_seconds", c.trace_seconds}, {"total_seconds", c.total_seconds}, {"rmse", c.rmse}});
        curve = j.dump(1) + "\n";
        writes.push_back({outs[2], curve.data(), curve.size()});
      }
      write_outputs(writes);
      say("rendered %ux%u, %u spp, %s (%s/%s) on %s: %zu rays over all bounces, %.3f Mrays/s in traversal "
          "(%.2f s), %.2f s in all\nwrote %s\n",
          res.width, res.height, rn_o.spp, to_string(rn_o.mode), to_string(rn_o.layout), to_string(rn_o.traversal),
          rn_backend.c_str(), res.rays, res.mrays_per_s(), res.trace_seconds, res.total_seconds, shown(rn_out).c_str());
      if (!res.curve.empty())
        say("RMSE against %s: %.5f after 1 spp, %.5f after %u spp\n", rn_reference.c_str(), res.curve.front().rmse,
            res.curve.back().rmse, res.curve.back().spp);
      return 0;
    }

    if (*trace) {
      const OutputTarget hits_to{"-o", tr_out};
      prepare_outputs({hits_to}, {{"scene", tr_a.scene}, {"--rays", tr_r.rays_file}});
      TraceOptions o;
      o.layout = parse_layout(tr_layout);
      o.traversal = parse_traversal(tr_trav);
      o.query = parse_query(tr_query);
      o.stats = tr_stats;
      o.precision = parse_precision(tr_precision);
      BackendOptions bo = tr_dev.options(tr_a.threads);
      bo.quality = parse_quality(tr_a.quality);
      auto backend = make_backend(tr_backend, bo);
      if (trace->count("--layout") == 0) {
        o.layout = default_layout(*backend, o.traversal);
        tr_layout = to_string(o.layout);
      }
      if (!backend->supports(o.layout, o.traversal))
        throw Error("backend '" + tr_backend + "' does not support " + tr_layout + "/" + tr_trav);
      if (!backend->supports_precision(o.precision))
        throw Error("backend '" + tr_backend + "' does not support precision '" + tr_precision + "'");
      Loaded l = load_and_build(tr_a);
      const std::vector<Ray> r = get_rays(tr_r, l, tr_a.threads);
      if (!g_quiet) std::fprintf(stderr, "backend: %s\n", backend->describe().c_str());
      backend->prepare(*l.acc, o);
      // trace in batches so a long run shows progress; results are concatenated in ray order
      TraceOutput out;
      const std::size_t batch = std::size_t(1) << 20;
      Progress p("tracing", r.size());
      double ms = 0;
      for (std::size_t b = 0; b < r.size(); b += batch) {
        TraceOutput part;
        const std::size_t n = std::min(batch, r.size() - b);
        const auto t0 = Clock::now();
        backend->trace(*l.acc, std::span<const Ray>(r).subspan(b, n), o, part);
        ms += ms_since(t0);
        out.hits.insert(out.hits.end(), part.hits.begin(), part.hits.end());
        out.occluded.insert(out.occluded.end(), part.occluded.begin(), part.occluded.end());
        out.stats.insert(out.stats.end(), part.stats.begin(), part.stats.end());
        out.invalid += part.invalid;
        p.update(b + n);
      }
      p.finish();
      std::size_t hits = 0;
      if (o.query == Query::any) for (auto v : out.occluded) hits += v;
      else for (const auto& h : out.hits) hits += h.prim != MBVH_MISS_PRIM;
      say("traced %zu rays (%s/%s/%s) in %.1f ms: %.3f Mrays/s; %zu %s, %zu invalid\n", r.size(), tr_layout.c_str(),
          tr_trav.c_str(), tr_query.c_str(), ms, ms > 0 ? static_cast<double>(r.size()) / ms * 1e-3 : 0.0, hits,
          o.query == Query::any ? "occluded" : "hits", out.invalid);
      if (tr_stats && !out.stats.empty()) {
        double n = 0, lf = 0, t = 0, c = 0;
        for (const auto& s : out.stats) { n += s.nodes; lf += s.leaves; t += s.tris; c += s.climbs; }
        const double k = static_cast<double>(out.stats.size());
        say("per ray: %.2f nodes, %.2f leaves, %.2f triangles, %.2f climbs; state %zu B\n", n / k, lf / k, t / k,
            c / k, backend->state_bytes(o));
      }
      if (!tr_out.empty()) {
        if (o.query == Query::any) write_bytes_to(hits_to, out.occluded.data(), out.occluded.size());
        else write_bytes_to(hits_to, out.hits.data(), out.hits.size() * sizeof(Hit));
        say("wrote %s\n", shown(tr_out).c_str());
      }
      return 0;
    }

    if (*check) {
      if (!ck_json.empty()) prepare_outputs({{"--json", ck_json, true}}, {{"scene", ck_a.scene}, {"--rays", ck_r.rays_file}});
      CheckOptions co;
      co.grid = ck_g.parse();
      co.threads = ck_a.threads;
      co.backend = ck_g.dev.options(ck_a.threads);
      co.backend.quality = parse_quality(ck_a.quality);
      co.brute_rays = ck_brute == "all" ? SIZE_MAX : std::strtoull(ck_brute.c_str(), nullptr, 10);  // checked: an integer
      Loaded l = load_and_build(ck_a);
      std::vector<std::string> kinds = ck_kinds.empty() ? std::vector<std::string>{ck_r.kind} : split_list(ck_kinds);
      if (!ck_r.rays_file.empty()) kinds = {"file"};
      std::size_t genuine = 0;
      nlohmann::json j{{"scene", l.scene.name}, {"kinds", nlohmann::json::array()}};
      for (const auto& k : kinds) {
        const std::vector<Ray> r = k == "file" ? read_rays(ck_r.rays_file)
                                               : generate_rays(l.scene, *l.acc, ray_gen(ck_r, k, ck_a.threads));
        const bool tty = Progress::enabled();  // false under --quiet
        CheckReport rep = run_check(*l.acc, r, co, [tty](const std::string& s) {
          if (tty) std::fprintf(stderr, "\r%-72.72s\r", s.c_str());
        });
        if (tty) std::fprintf(stderr, "\r%72s\r", "");
        say("== %s: %s rays\n%s\n", l.scene.name.c_str(), k == "file" ? ck_r.rays_file.c_str() : k.c_str(),
            rep.table(r).c_str());
        genuine += rep.mismatches();
        j["kinds"].push_back(check_json(rep, k));
      }
      if (!ck_json.empty()) {
        j["mismatches"] = genuine;
        const std::string text = j.dump(1) + "\n";
        write_bytes_to({"--json", ck_json, true}, text.data(), text.size());
      }
      return genuine ? 1 : 0;
    }

    if (*bench) {
      const std::vector<OutputTarget> outs{{"--json", bn_json, true}, {"--csv", bn_csv, true}};
      prepare_outputs(outs, {{"scene", bn_a.scene}});
      BenchOptions bo;
      bo.grid = bn_g.parse();
      bo.kinds = parse_list<RayKind>(bn_kinds, parse_ray_kind);
      bo.count = bn_count;
      bo.error_rays = bn_error;
      bo.seed = bn_seed;
      bo.passes = bn_passes;
      bo.warmup_seconds = bn_warmup;
      bo.first_layout = bn_first_layout;
      bo.scaling = bn_scaling;
      bo.threads = bn_a.threads;
      bo.backend = bn_g.dev.options(bn_a.threads);
      bo.backend.quality = parse_quality(bn_a.quality);
      set_camera(bn_camera, bo.has_camera, bo.camera);
      Loaded l = load_and_build(bn_a);
      Progress p("benchmarking", bo.kinds.size() * bo.grid.size());
      BenchReport rep = run_bench(l.scene, *l.acc, bo, [&p](std::size_t d, std::size_t) { p.update(d); });
      p.finish();
      say("scene %s, %zu triangles, BVH hash %s\ncpu %s, %u threads\n\n%s", l.scene.name.c_str(),
          l.scene.triangle_count(), rep.bvh_hash.c_str(), rep.cpu.c_str(), resolve_threads(bn_a.threads),
          rep.table().c_str());
      const double bit = double(state_bytes_per_ray(Layout::mbvh4, Traversal::bitstack));
      say("\ntraversal state per ray: stack %zu B (64 x int32 + sp + node; MBVH4: 1 + 3x21 entries), ordered "
          "stack %zu B (64 x (node, distance)), bitstack %.0f B (node + 64-bit word): %.0fx and %.0fx smaller; "
          "MBVH8 stack %zu B and ordered stack %zu B (128 entries), bitstack %zu B (node + 128-bit word)\n",
          state_bytes_per_ray(Layout::mbvh4, Traversal::stack), state_bytes_per_ray(Layout::mbvh4, Traversal::stack_ordered),
          bit, double(state_bytes_per_ray(Layout::mbvh4, Traversal::stack)) / bit,
          double(state_bytes_per_ray(Layout::mbvh4, Traversal::stack_ordered)) / bit,
          state_bytes_per_ray(Layout::mbvh8, Traversal::stack), state_bytes_per_ray(Layout::mbvh8, Traversal::stack_ordered),
          state_bytes_per_ray(Layout::mbvh8, Traversal::bitstack));
      const std::string json = rep.json() + "\n", csv = rep.csv();
      std::vector<OutputWrite> writes;
      if (!bn_json.empty()) writes.push_back({outs[0], json.data(), json.size()});
      if (!bn_csv.empty()) writes.push_back({outs[1], csv.data(), csv.size()});
      write_outputs(writes);  // both or neither
      for (const OutputWrite& w : writes) say("wrote %s\n", shown(w.to.path).c_str());
      if (!rep.verified()) {
        std::fprintf(stderr, "error: some timed results did not match the reference (see 'verified')\n");
        return 1;
      }
      return 0;
    }

    if (*devices) {
      for (const BackendInfo& b : list_backends()) {
        if (!b.make) {
          say("%-12s not built: %s\n", b.name.c_str(), b.unavailable.c_str());
          continue;
        }
        try {
          auto be = b.make(dv_dev.options(0));
          say("%-12s ready: %s%s\n", b.name.c_str(), be->describe().c_str(),
              b.alias_of.empty() ? "" : (" (= " + b.alias_of + ")").c_str());
          if (b.devices && b.alias_of.empty())
            for (const std::string& d : b.devices()) say("%-12s   device %s\n", "", d.c_str());
        } catch (const std::exception& e) {
          say("%-12s cannot start: %s\n", b.name.c_str(), e.what());
        }
      }
      return 0;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbvh: error: %s\n", e.what());
    return 2;
  }
  return 0;
}

int main(int argc, char** argv) {
  mbvh::register_builtin_backends();  // the program links every backend of this build
  int rc = run(argc, argv);
  // the report is an output too: a failed write to standard output fails the run
  if (std::fflush(stdout) != 0 || std::ferror(stdout)) {
    std::fprintf(stderr, "mbvh: error: standard output: write failed: %s\n", std::strerror(errno));
    if (rc == 0) rc = 2;
  }
  // problems a backend's diagnostics raised where they could not throw (Vulkan validation
  // messages while tearing down): the run fails
  for (const BackendInfo& b : list_backends())
    if (b.pending_problems)
      if (const std::vector<std::string> p = b.pending_problems(); !p.empty()) {
        for (const std::string& m : p) std::fprintf(stderr, "mbvh: error: %s: %s\n", b.name.c_str(), m.c_str());
        if (rc == 0) rc = 2;
      }
  return rc;
}

// SPDX-License-Identifier: MIT
// common.cpp — the pieces every `mbvh` subcommand shares (common.h).
#include "host/cli/common.h"

#include <unistd.h>

#include <algorithm>
#include <cfloat>
#include <charconv>
#include <cmath>
#include <cstdarg>
#include <cstdlib>

#include "host/cli/progress.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"

namespace mbvh::cli {

namespace {

// The report (tables, "wrote ..."): standard output, or standard error while an output goes to
// standard output ('-'), so the two never mix.
FILE* g_report = stdout;
bool g_quiet = false;
// The command's input and output files (prepare_outputs): the BVH cache entry is none of them.
std::vector<std::string> g_command_files;

}  // namespace

bool& quiet() { return g_quiet; }

void say(const char* format, ...) {
  if (g_quiet) return;
  va_list args;
  va_start(args, format);
  std::vfprintf(g_report, format, args);
  va_end(args);
}

// -- outputs

void prepare_outputs(std::vector<OutputTarget> outputs, std::vector<InputFile> inputs) {
  std::erase_if(outputs, [](const OutputTarget& o) { return o.path.empty(); });
  std::erase_if(inputs, [](const InputFile& i) { return i.path.empty() || i.path.rfind("gen:", 0) == 0; });
  check_outputs(outputs, inputs);
  for (const OutputTarget& o : outputs) g_command_files.push_back(o.path);
  for (const InputFile& i : inputs) g_command_files.push_back(i.path);
  for (const OutputTarget& o : outputs)
    if (o.path == "-") g_report = stderr;
}

void write_bytes_to(const OutputTarget& to, const void* data, std::size_t size) {
  const OutputWrite w{to, data, size};
  write_outputs(std::span(&w, 1));
}

std::string shown(const std::string& path) { return path == "-" ? "standard output" : path; }

// -- lists

std::vector<std::string> split_list(const std::string& s, const std::string& option) {
  std::vector<std::string> out;
  std::size_t a = 0;
  while (a <= s.size()) {
    std::size_t b = s.find(',', a);
    if (b == std::string::npos) b = s.size();
    if (b == a)  // ",", "a,,b", "a,": a list that names nothing, or less than it seems to
      throw Error((option.empty() ? std::string("the list") : option) + " '" + s +
                  "': an empty name in the comma-separated list (write the names separated by single commas)");
    out.push_back(s.substr(a, b - a));
    a = b + 1;
  }
  return out;
}

// -- numeric options

CLI::Validator integer_in(std::uint64_t lo, std::uint64_t hi, const std::string& why) {
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

CLI::Validator number_in(double lo, double hi, bool as_float) {
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

std::uint64_t fits_in_memory(std::uint64_t bytes_each) {
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGE_SIZE);
  const std::uint64_t bytes = pages > 0 && page > 0 ? std::uint64_t(pages) * std::uint64_t(page) : std::uint64_t(1) << 34;
  return std::max<std::uint64_t>(1, bytes / bytes_each);
}

CLI::Validator ray_count() {
  return integer_in(1, fits_in_memory(kBytesPerRay),
                    " (" + std::to_string(kBytesPerRay) + " bytes per ray must fit in this machine's memory)");
}

void require_ray_memory(const std::string& what, std::uint64_t items, std::uint64_t bytes_each, const char* unit) {
  const std::uint64_t bytes = items > UINT64_MAX / bytes_each ? UINT64_MAX : items * bytes_each;
  require_memory(what, bytes, std::to_string(items) + " " + unit + ", " + std::to_string(bytes_each) + " bytes each");
}

// -- the scene and its BVH

void SceneArgs::add(CLI::App* c) {
  c->add_option("scene", scene, "scene file (.obj/.ply, optionally .zst) or gen:NAME:PARAMS")->required();
  c->add_option("--threads", threads, "worker threads (0 = all hardware threads)")->check(integer_in(0, kMaxThreads));
  c->add_option("--max-leaf", max_leaf, "largest leaf the SAH may choose")->check(integer_in(1, 1024));
  c->add_option("--leaf-block", leaf_block, "triangles the SAH prices as one leaf test (4: SIMD leaves)")
      ->check(integer_in(1, 64));
  CLI::Option* cache_opt =
      c->add_option("--cache", cache,
                    "BVH cache directory: the build is read from it when it holds this scene's with these options, "
                    "else built and written there (a damaged or mismatched file is rebuilt)");
  c->add_option("--cache-max-size", cache_max_size,
                "bound the --cache directory's entries to SIZE (bytes, or K, M, G, T): the least recently used "
                "others are removed after this run's entry is read or written")
      ->needs(cache_opt)
      ->check(CLI::Validator(
          [](std::string& v) {
            std::uint64_t b = 0;
            return parse_size(v, b) ? std::string() : "'" + v + "' is not a size (bytes, or with a K, M, G or T suffix, e.g. 2G)";
          },
          "SIZE"));
  quality_opt_ = c->add_option("--quality", quality,
                               "builder: low (Morton-code LBVH, fastest build), medium (binned SAH, the default), high "
                               "(SBVH with and without spatial splits, each then reinserted, the lower SAH kept) or none (no hierarchy, the triangles alone: only dacrt traces it; the default "
                               "when every backend is dacrt)")
                     ->check(CLI::IsMember({"low", "medium", "high", "none"}));
}

bool SceneArgs::quality_given() const { return quality_opt_ && quality_opt_->count() > 0; }

void SceneArgs::no_hierarchy_for(const std::vector<std::string>& backends) {
  if (quality_given() || backends.empty()) return;
  for (const std::string& b : backends)
    if (backend_needs_hierarchy(b)) return;
  quality = to_string(BuildQuality::none);
}

BuildOptions SceneArgs::build_options() const {
  BuildOptions bo;
  bo.threads = threads;
  bo.max_leaf = max_leaf;
  bo.leaf_block = leaf_block;
  bo.quality = parse_quality(quality);
  return bo;
}

Loaded load_and_build(const SceneArgs& a, bool verbose, const AccelMaker& make) {
  Loaded l;
  // -- load
  auto t0 = Clock::now();
  l.scene = load_scene(a.scene);
  l.load_ms = ms_since(t0);
  // -- build, or read from the cache
  BuildOptions bo = a.build_options();
  Progress p("building BVH", 1000);
  bo.progress = [&p](double f) { p.update(static_cast<std::size_t>(f * 1000)); };
  const auto t1 = Clock::now();
  Accel::CacheReport cr;
  std::uint64_t max_bytes = 0;
  if (!a.cache_max_size.empty()) parse_size(a.cache_max_size, max_bytes);  // checked by the option's validator
  const Accel::CacheOptions co{a.cache, g_command_files, max_bytes};
  l.acc = make ? make(l.scene, bo, co, &cr) : a.cache.empty() ? Accel::build(l.scene, bo) : Accel::build_cached(l.scene, bo, co, &cr);
  const double ms = ms_since(t1);
  p.finish();
  // -- report
  if (!cr.problem.empty()) std::fprintf(stderr, "mbvh: warning: %s; rebuilt and replaced\n", cr.problem.c_str());
  if (!l.acc->has_hierarchy()) {  // quality none: never cached (Accel::build_cached)
    if (!g_quiet && (verbose || !a.cache.empty()))
      std::fprintf(stderr,
                   "scene %s: %zu triangles, loaded in %.1f ms; quality none (no hierarchy): %zu triangles kept (%zu "
                   "degenerate) in %.1f ms%s, hash %016llx\n",
                   a.scene.c_str(), l.scene.triangle_count(), l.load_ms, l.acc->tris().size(), l.acc->degenerate_triangles(),
                   l.acc->binary_stats().build_ms, a.cache.empty() ? "" : ", not cached",
                   static_cast<unsigned long long>(l.acc->hash()));
  } else if (!g_quiet && (verbose || !a.cache.empty()))
    std::fprintf(stderr, "scene %s: %zu triangles, loaded in %.1f ms; BVH %s in %.1f ms%s%s, hash %016llx\n",
                 a.scene.c_str(), l.scene.triangle_count(), l.load_ms, cr.loaded ? "read from the cache" : "built",
                 cr.loaded ? ms : l.acc->binary_stats().build_ms, a.cache.empty() ? "" : cr.loaded ? ": " : ", cached in ",
                 cr.path.c_str(), static_cast<unsigned long long>(l.acc->hash()));
  if (!g_quiet && cr.evicted)
    std::fprintf(stderr, "BVH cache %s: removed %zu least recently used entries (%.1f MiB) to stay within --cache-max-size %s\n",
                 a.cache.c_str(), cr.evicted, double(cr.evicted_bytes) / (1 << 20), a.cache_max_size.c_str());
  return l;
}

// -- backends and devices

void DeviceArgs::add(CLI::App* c) {
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
  c->add_option("--set", settings,
                "a backend's own setting, FAMILY.NAME=VALUE (repeatable; each backend's settings: `mbvh devices`), "
                "e.g. --set vulkan.staging=1");
}

BackendOptions DeviceArgs::options(unsigned threads, const std::string& quality) const {
  BackendOptions o;
  o.threads = threads;
  // the device flags are the opencl.* and vulkan.* settings under their old names
  if (!cl_device.empty()) o.set("opencl.device", cl_device);
  if (cl_mapping != "auto") o.set("opencl.mapping", cl_mapping);
  if (!vk_device.empty()) o.set("vulkan.device", vk_device);
  if (vk_validation) o.set("vulkan.validation", "1");
  for (const std::string& s : settings) {
    const std::size_t eq = s.find('=');
    if (eq == std::string::npos || eq == 0) throw Error("--set '" + s + "': expected FAMILY.NAME=VALUE");
    o.set(s.substr(0, eq), s.substr(eq + 1));
  }
  // the peer builds its own BVH: at the quality of ours, unless set apart
  // (quality none builds no BVH: the peer keeps its own default then)
  if (!quality.empty() && parse_quality(quality) != BuildQuality::none && !o.settings.count("embree.quality"))
    o.set("embree.quality", to_string(parse_quality(quality)));
  return o;
}

namespace {

// `--backend all`: every backend that can start here, once each (runnable_backends), a backend
// another name stands for under that name (cpu-avx512 as `cpu`, opencl-wide as `opencl`), the
// name records compare against. A backend that is built but fails to start is an error, not
// left out.
std::vector<std::string> all_backends() {
  std::vector<std::string> names = runnable_backends();
  for (const BackendInfo& b : list_backends())
    if (!b.alias_of.empty()) std::replace(names.begin(), names.end(), b.alias_of, b.name);
  return names;
}

}  // namespace

void GridArgs::add(CLI::App* c) {
  c->add_option("--backend", backends,
                "comma-separated backends (see `mbvh devices`), or 'all': every backend this machine runs, once each");
  c->add_option("--layout", layouts, "comma-separated layouts: mbvh2, mbvh4, mbvh8");
  c->add_option("--traversal", traversals,
                "comma-separated traversals: stack, bitstack, stack-ordered, bitstack-retest (the last two MBVH4/8), stack-octant (MBVH8: the children pushed in the ray octant's order), bitstack-octant (MBVH8: the bitstack in that order), packet-ranged, packet-partition, packet (cpu packets: 64 rays on AVX2, 128 on AVX-512), dacrt (no hierarchy; a dacrt backend runs it whatever this list says)");
  c->add_option("--query", queries, "comma-separated queries: closest, any");
  c->add_option("--precision", precisions,
                "comma-separated accuracy modes: robust (default), exact (the same kernels, refused by embree), fast "
                "(non-conservative boxes, Moller-Trumbore)");
  dev.add(c);
}

VariantGrid GridArgs::parse() const {
  VariantGrid g;
  g.backends = backends == "all" ? all_backends() : split_list(backends, "--backend");
  g.layouts = parse_list<Layout>(layouts, parse_layout);
  g.traversals = parse_list<Traversal>(traversals, parse_traversal);
  g.queries = parse_list<Query>(queries, parse_query);
  g.precisions = parse_list<Precision>(precisions, parse_precision);
  for (const auto& b : g.backends) make_backend(b, dev.options(0));  // fail early, naming the backend
  return g;
}

// -- rays and the camera

void add_camera_option(CLI::App* c, std::vector<float>& camera) {
  c->add_option("--camera", camera, "eye x y z, target x y z [, fov degrees] (default: frames the scene)")
      ->delimiter(',')
      ->expected(6, 7)
      ->check(number_in(-FLT_MAX, FLT_MAX, true));
}

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

void RayArgs::add(CLI::App* c, bool allow_file) {
  if (allow_file) c->add_option("--rays", rays_file, "ray file (32 bytes per ray) instead of generated rays");
  c->add_option("--kind", kind, "generated ray kind: primary, shadow, diffuse, random, inside (closed generated meshes), special, path (the path tracer's bounces)");
  c->add_option("--count", count, "number of generated rays")->check(ray_count());
  c->add_option("--seed", seed, "seed of the generated rays")->check(integer_in(0, UINT64_MAX));
  add_camera_option(c, camera);
}

RayGenOptions RayArgs::generator(const std::string& ray_kind, unsigned threads) const {
  RayGenOptions o;
  o.kind = parse_ray_kind(ray_kind);
  o.count = count;
  o.seed = seed;
  o.threads = threads;
  set_camera(camera, o.has_camera, o.camera);
  return o;
}

void RayArgs::check_memory() const {
  if (rays_file.empty()) return require_ray_memory("--count " + std::to_string(count), count);
  const std::uint64_t size = regular_file_size(rays_file, "ray");
  require_ray_memory("--rays " + rays_file, size / sizeof(Ray));
}

std::vector<Ray> RayArgs::get(const Loaded& l, unsigned threads) const {
  if (!rays_file.empty()) return read_rays(rays_file);
  return generate_rays(l.scene, *l.acc, generator(kind, threads));
}

}  // namespace mbvh::cli

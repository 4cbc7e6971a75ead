// SPDX-License-Identifier: MIT
// cmd_render.cpp — `mbvh render`: render an image on a backend (host/tools/render.h): 8-bounce
// diffuse path tracing, AO or normals; a PNG, optionally the linear PFM and an error curve. Without
// --camera it reports the camera frame_scene chose, as a --camera argument.
#include <algorithm>
#include <chrono>
#include <cfloat>
#include <cmath>
#include <cstdio>
#include <filesystem>

#include <nlohmann/json.hpp>

#include "host/cli/args.h"
#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/tools/image.h"
#include "host/core/resources.h"
#include "host/tools/camera_path.h"
#include "host/tools/render.h"
#include "host/tools/resident.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

// --light x,y,z: the point light instead of the default one.
static void set_light(const std::vector<float>& l, RenderOptions& r) {
  if (l.empty()) return;
  r.has_light = true;
  r.light = Vec3f{l[0], l[1], l[2]};
}

RenderOptions RenderArgs::options(const Backend& b, std::vector<float>& ref) const {
  const RenderArgs& a = *this;
  if (const std::uint64_t pixels = std::uint64_t(a.o.width) * a.o.height; pixels > fits_in_memory(kBytesPerPixel))
    throw Error("--width " + std::to_string(a.o.width) + " --height " + std::to_string(a.o.height) + ": " +
                std::to_string(pixels) + " pixels of " + std::to_string(kBytesPerPixel) +
                " bytes each do not fit in this machine's memory");
  require_ray_memory("--width " + std::to_string(a.o.width) + " --height " + std::to_string(a.o.height),
                     std::uint64_t(a.o.width) * a.o.height, kBytesPerPixel, "pixels");
  RenderOptions r = a.o;
  r.mode = parse_render_mode(a.mode);
  r.traversal = parse_traversal(a.traversal);
  r.threads = a.scene.threads;
  r.precision = parse_precision(a.precision);
  set_camera(a.camera, r.has_camera, r.camera);
  set_light(a.light, r);
  if (!a.reference.empty()) {
    unsigned w = 0, h = 0;
    ref = read_pfm(a.reference, w, h);
    if (w != r.width || h != r.height)
      throw Error(a.reference + ": the reference is " + std::to_string(w) + "x" + std::to_string(h) + ", the image " +
                  std::to_string(r.width) + "x" + std::to_string(r.height));
    r.reference = &ref;
  } else if (!a.curve.empty()) {
    throw Error("--curve needs --reference (the converged image the curve measures against)");
  }
  // auto (the default): the backend's fastest exact closest-hit traversal, named in the report
  TraceOptions t;
  t.layout = parse_layout(a.layout);
  t.traversal = r.traversal;
  t = resolve_options(b, t);
  r.layout = t.layout;
  r.traversal = t.traversal;
  return r;
}

namespace {

// --curve: the RMSE against time, as JSON.
std::string curve_json(const RenderArgs& a, const Backend& backend, const Scene& scene, const RenderResult& res) {
  nlohmann::json j{{"backend", a.backend},       {"device", backend.describe()}, {"precision", a.precision},
                   {"scene", scene.name},        {"width", res.width},           {"height", res.height},
                   {"rays", res.rays},           {"mrays_per_s", res.mrays_per_s()}, {"points", nlohmann::json::array()}};
  for (const CurvePoint& c : res.curve)
    j["points"].push_back({{"spp", c.spp}, {"trace_seconds", c.trace_seconds}, {"total_seconds", c.total_seconds}, {"rmse", c.rmse}});
  return j.dump(1) + "\n";
}

// The options of `mbvh render` on a .mlod model (not mbvh-mpi's: its ranks trace in-core parts).
struct LodArgs {
  std::string lod;  ///< "", "on" (also --lod alone) or "off"
  float quality = 1;
  std::string memory, io_bandwidth, camera_path, stats_json, out_pattern;
  bool sync = false;
  unsigned io_threads = 1, frames = 1;
  std::vector<CLI::Option*> given;  ///< every option above: any of them given needs a model
  CLI::Option* frames_opt = nullptr;
  void add(CLI::App* c);
  bool any_given() const {
    return std::any_of(given.begin(), given.end(), [](const CLI::Option* o) { return o->count() > 0; });
  }
};

CLI::Validator size_option() {
  return CLI::Validator(
      [](std::string& v) {
        std::uint64_t b = 0;
        return parse_size(v, b) ? std::string() : "'" + v + "' is not a size (bytes, or with a K, M, G or T suffix, e.g. 8G)";
      },
      "SIZE");
}

void LodArgs::add(CLI::App* c) {
  given.push_back(c->add_option("--lod", lod,
                                "a .mlod model: --lod or --lod on traces LOD voxels where a ray's footprint allows "
                                "(--lod-quality); --lod off or no --lod: full detail (every block the rays need is loaded)")
                      ->expected(0, 1)
                      ->default_str("on")
                      ->check(CLI::IsMember({"on", "off"})));
  given.push_back(c->add_option("--lod-quality", quality,
                                "a voxel is accepted when its box's largest extent <= Q x the ray's footprint (0: never, "
                                "full detail as far as blocks are resident)")
                      ->check(number_in(0, 1e6, true)));
  given.push_back(c->add_option("--memory", memory,
                                "the model's budget of decompressed blocks (bytes, or K, M, G, T), a hard cap (default: "
                                "the whole model)")
                      ->check(size_option()));
  given.push_back(c->add_flag("--lod-sync", sync, "load missing blocks before the rays that need them finish (deterministic images)"));
  given.push_back(c->add_option("--lod-io-bandwidth", io_bandwidth, "cap the model's reads at SIZE bytes per second (an emulated disk)")
                      ->check(size_option()));
  given.push_back(c->add_option("--io-threads", io_threads, "the model's I/O threads")->check(integer_in(1, 64)));
  frames_opt = c->add_option("--frames", frames,
                             "frames to render (each ends the model's frame: LRU stamp, requests, evictions); without "
                             "--camera-path or --camera: an orbit around the model");
  frames_opt->check(integer_in(1, 1000000));
  given.push_back(frames_opt);
  given.push_back(c->add_option("--camera-path", camera_path,
                                "file of cameras, one a line as --camera takes it (ex,ey,ez,tx,ty,tz[,fov]); --frames "
                                "(default: the path's length) cycles through it"));
  given.push_back(c->add_option("--stats-json", stats_json, "write per-frame time, rays and cache statistics as JSON"));
  given.push_back(c->add_option("--out-pattern", out_pattern,
                                "also write every frame's PNG to this printf pattern of the frame number (e.g. frame%03d.png)"));
}

// VmHWM of this process (bytes; -1 where /proc/self cannot be read).
std::int64_t vmhwm() { return status_bytes("VmHWM:"); }

// The PNG (outs[0]) and, with --pfm, the PFM (outs[1]) of a render, encoded into `keep` (which
// the writes point into).
struct ImageBytes {
  std::vector<std::uint8_t> png;
  std::vector<char> pfm;
};
std::vector<OutputWrite> image_writes(const RenderArgs& a, const std::vector<OutputTarget>& outs, const RenderResult& res,
                                      ImageBytes& keep) {
  keep.png = png_bytes(a.out, res.width, res.height, to_srgb8(res.rgb));
  std::vector<OutputWrite> writes{{outs[0], keep.png.data(), keep.png.size()}};
  if (!a.pfm.empty()) {
    keep.pfm = pfm_bytes(a.pfm, res.width, res.height, res.rgb);
    writes.push_back({outs[1], keep.pfm.data(), keep.pfm.size()});
  }
  return writes;
}

double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  const std::size_t n = v.size();
  return n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
}

// The file name of frame k under --out-pattern: the pattern must hold exactly one %d conversion
// (optionally %0Nd), and no other '%' but "%%".
std::string frame_file(const std::string& pattern, unsigned k) {
  std::string out;
  unsigned conversions = 0;
  for (std::size_t i = 0; i < pattern.size(); ++i) {
    if (pattern[i] != '%') {
      out += pattern[i];
      continue;
    }
    if (i + 1 < pattern.size() && pattern[i + 1] == '%') {
      out += '%';
      ++i;
      continue;
    }
    std::size_t j = i + 1;
    unsigned width = 0;
    bool zero = j < pattern.size() && pattern[j] == '0';
    while (j < pattern.size() && pattern[j] >= '0' && pattern[j] <= '9' && width < 100) width = width * 10 + (pattern[j++] - '0');
    if (j >= pattern.size() || pattern[j] != 'd' || width > 20)
      throw Error("--out-pattern " + pattern + ": only one %d (or %0Nd, N <= 20) conversion is allowed");
    std::string num = std::to_string(k);
    if (num.size() < width) num.insert(0, width - num.size(), zero ? '0' : ' ');
    out += num;
    ++conversions;
    i = j;
  }
  if (conversions != 1) throw Error("--out-pattern " + pattern + ": needs exactly one %d conversion (the frame number)");
  return out;
}

// `mbvh render MODEL.mlod`: one or more frames of an out-of-core model.
int run_model_render(const RenderArgs& a, const LodArgs& l, CLI::App* app) {
  // options of the in-core path have no meaning here: refused rather than ignored
  for (const char* name : {"--backend", "--layout", "--traversal", "--precision", "--curve", "--max-leaf", "--leaf-block",
                           "--cache", "--cache-max-size", "--quality", "--cl-device", "--cl-mapping", "--vk-device"})
    if (const CLI::Option* o = app->get_option_no_throw(name); o && o->count() > 0)
      throw Error(std::string(name) + " does not apply to a .mlod model (" + a.scene.scene + ")");
  if (!l.camera_path.empty() && !a.camera.empty()) throw Error("--camera and --camera-path: give one of them");
  const std::vector<OutputTarget> outs{{"-o", a.out}, {"--pfm", a.pfm}, {"--stats-json", l.stats_json, true}};
  // the first frame's --out-pattern file is checked with the others before any work (an input, the
  // same as another output, a missing directory)
  std::vector<OutputTarget> checked = outs;
  if (!l.out_pattern.empty()) checked.push_back({"--out-pattern", frame_file(l.out_pattern, 0)});
  prepare_outputs(checked, {{"scene", a.scene.scene}, {"--reference", a.reference}, {"--camera-path", l.camera_path}});
  if (const std::uint64_t pixels = std::uint64_t(a.o.width) * a.o.height; pixels > fits_in_memory(kBytesPerPixel))
    throw Error("--width " + std::to_string(a.o.width) + " --height " + std::to_string(a.o.height) +
                ": the pixels do not fit in this machine's memory");
  require_ray_memory("--width " + std::to_string(a.o.width) + " --height " + std::to_string(a.o.height),
                     std::uint64_t(a.o.width) * a.o.height, kBytesPerPixel, "pixels");
  // -- render options
  RenderOptions o = a.o;
  o.mode = parse_render_mode(a.mode);
  o.threads = a.scene.threads;
  set_camera(a.camera, o.has_camera, o.camera);
  set_light(a.light, o);
  std::vector<float> reference;
  if (!a.reference.empty()) {
    unsigned w = 0, h = 0;
    reference = read_pfm(a.reference, w, h);
    if (w != o.width || h != o.height)
      throw Error(a.reference + ": the reference is " + std::to_string(w) + "x" + std::to_string(h) + ", the image " +
                  std::to_string(o.width) + "x" + std::to_string(o.height));
    o.reference = &reference;
  }
  ModelRenderOptions mo;
  mo.lod = l.lod == "on";
  mo.quality = l.quality;
  // -- the model
  lod::CacheOptions co;
  if (!l.memory.empty()) parse_size(l.memory, co.memory_budget);  // checked by the option's validator
  if (!l.io_bandwidth.empty()) parse_size(l.io_bandwidth, co.io_bandwidth);
  co.io_threads = l.io_threads;
  co.synchronous = l.sync;
  co.threads = a.scene.threads;
  const auto t_open = std::chrono::steady_clock::now();
  std::unique_ptr<lod::Model> model = lod::Model::open(a.scene.scene, co);
  const double open_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t_open).count();
  const lod::ModelInfo info = model->info();
  say("model %s: %llu triangles, %llu blocks (%s raw, %s pinned), budget %s, opened in %.3f s\n", a.scene.scene.c_str(),
      static_cast<unsigned long long>(info.triangles), static_cast<unsigned long long>(info.blocks),
      format_bytes(info.raw_bytes).c_str(), format_bytes(info.pinned_bytes).c_str(),
      format_bytes(model->stats().budget).c_str(), open_s);
  // -- the cameras: a path, an orbit, or one view (given or framed)
  std::vector<Camera> cams;
  const bool frames_given = l.frames_opt->count() > 0;
  if (!l.camera_path.empty()) cams = read_camera_path(l.camera_path);
  else if (frames_given && !o.has_camera) cams = orbit_path(model->bounds(), l.frames);
  const unsigned frames = frames_given ? l.frames : cams.empty() ? 1u : static_cast<unsigned>(cams.size());
  // -- the frames
  nlohmann::json per_frame = nlohmann::json::array();
  std::vector<double> seconds;
  RenderResult res;
  std::uint64_t peak_bytes = 0;
  std::int64_t peak_hwm = -1;
  Progress p("rendering frames", frames);
  for (unsigned k = 0; k < frames; ++k) {
    RenderOptions fo = o;
    if (!cams.empty()) {
      fo.has_camera = true;
      fo.camera = cams[k % cams.size()];
    }
    const auto t0 = std::chrono::steady_clock::now();
    res = render(*model, fo, mo);
    model->end_frame();
    const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    seconds.push_back(s);
    const lod::CacheStats cs = model->stats();
    const std::int64_t hwm = vmhwm();
    peak_bytes = std::max(peak_bytes, cs.peak_bytes);
    peak_hwm = std::max(peak_hwm, hwm);
    per_frame.push_back({{"frame", k},
                         {"seconds", s},
                         {"trace_seconds", res.trace_seconds},
                         {"rays", res.rays},
                         {"mrays_per_s", s > 0 ? double(res.rays) / s * 1e-6 : 0.0},
                         {"resident_bytes", cs.resident_bytes},
                         {"peak_bytes", cs.peak_bytes},
                         {"pinned_bytes", cs.pinned_bytes},
                         {"resident_blocks", cs.resident_blocks},
                         {"loads", cs.loads},
                         {"evictions", cs.evictions},
                         {"misses", cs.misses},
                         {"pending", cs.pending},
                         {"bytes_read", cs.bytes_read},
                         {"voxel_hits", res.voxel_hits},
                         {"forced_voxels", res.forced_voxels},
                         {"vmhwm", hwm}});
    if (!l.out_pattern.empty()) {
      const std::string f = frame_file(l.out_pattern, k);
      const std::vector<std::uint8_t> png = png_bytes(f, res.width, res.height, to_srgb8(res.rgb));
      const OutputWrite w{{"--out-pattern", f}, png.data(), png.size()};
      write_outputs(std::span<const OutputWrite>(&w, 1));
    }
    p.update(k + 1);
  }
  p.finish();
  if (!res.camera_rule.empty())
    say("camera: %s\n  --camera %s\n", res.camera_rule.c_str(), camera_argument(res.camera).c_str());
  // -- the summary
  const double med = median(seconds), mx = *std::max_element(seconds.begin(), seconds.end());
  const lod::CacheStats last = model->stats();
  nlohmann::json summary{{"frames", frames},
                         {"first_seconds", seconds.front()},
                         {"median_seconds", med},
                         {"max_seconds", mx},
                         {"max_over_median", med > 0 ? mx / med : 0.0},
                         {"median_fps", med > 0 ? 1.0 / med : 0.0},
                         {"peak_bytes", peak_bytes},
                         {"budget", last.budget},
                         {"loads", last.loads},
                         {"evictions", last.evictions},
                         {"bytes_read", last.bytes_read},
                         {"vmhwm", peak_hwm},
                         {"open_seconds", open_s}};
  const std::vector<std::uint32_t> damaged = model->damaged_blocks();
  // -- all outputs or none
  ImageBytes image;
  std::vector<OutputWrite> writes = image_writes(a, outs, res, image);
  std::string stats;
  if (!l.stats_json.empty()) {
    nlohmann::json j{{"model", a.scene.scene},
                     {"triangles", info.triangles},
                     {"blocks", info.blocks},
                     {"raw_bytes", info.raw_bytes},
                     {"file_bytes", info.file_bytes},
                     {"pinned_bytes", info.pinned_bytes},
                     {"width", o.width},
                     {"height", o.height},
                     {"spp", o.spp},
                     {"mode", to_string(o.mode)},
                     {"bounces", o.bounces},
                     {"lod", mo.lod},
                     {"quality", mo.quality},
                     {"sync", l.sync},
                     {"budget", last.budget},
                     {"io_bandwidth", co.io_bandwidth},
                     {"io_threads", co.io_threads},
                     {"damaged_blocks", damaged},
                     {"frames", per_frame},
                     {"summary", summary}};
    stats = j.dump(1) + "\n";
    writes.push_back({outs[2], stats.data(), stats.size()});
  }
  write_outputs(writes);
  char detail[64] = "full detail";
  if (mo.lod) std::snprintf(detail, sizeof detail, "LOD quality %g", static_cast<double>(mo.quality));
  say("rendered %u frame(s) %ux%u, %u spp, %s, %s: first %.3f s, median %.3f s (%.2f fps), max %.3f s (%.2f x the "
      "median); %zu rays in the last frame; peak %s of a %s budget, %llu loads, %llu evictions, VmHWM %s\nwrote %s\n",
      frames, res.width, res.height, o.spp, to_string(o.mode),
      detail, seconds.front(), med,
      med > 0 ? 1 / med : 0.0, mx, med > 0 ? mx / med : 0.0, res.rays, format_bytes(peak_bytes).c_str(),
      format_bytes(last.budget).c_str(), static_cast<unsigned long long>(last.loads),
      static_cast<unsigned long long>(last.evictions), peak_hwm >= 0 ? format_bytes(std::uint64_t(peak_hwm)).c_str() : "?",
      shown(a.out).c_str());
  if (!damaged.empty()) {
    std::string list;
    for (std::uint32_t b : damaged) list += (list.empty() ? "" : ", ") + std::to_string(b);
    std::fprintf(stderr, "mbvh: error: %s: damaged block(s) %s were traced as missing (LOD voxels in their place)\n",
                 a.scene.scene.c_str(), list.c_str());
    return 2;
  }
  return 0;
}

// Whether `scene` names a .mlod model: only a regular file is opened to read its magic (a FIFO
// would block; load_scene refuses what is not a regular file with its own message).
bool is_model(const std::string& scene) {
  std::error_code ec;
  return scene.rfind("gen:", 0) != 0 && std::filesystem::is_regular_file(scene, ec) && lod::is_model_file(scene);
}

int run_render(const RenderArgs& a, const LodArgs& lod, CLI::App* app) {
  if (is_model(a.scene.scene)) return run_model_render(a, lod, app);
  if (lod.any_given())
    throw Error("--lod, --memory, --frames and the other model options need a .mlod model; " + a.scene.scene +
                " is a scene (build a model with `mbvh lod build`)");
  const std::vector<OutputTarget> outs{{"-o", a.out}, {"--pfm", a.pfm}, {"--curve", a.curve, true}};
  prepare_outputs(outs, {{"scene", a.scene.scene}, {"--reference", a.reference}});
  // -- options, backend, variant
  std::vector<float> reference;
  SceneArgs scene = a.scene;
  scene.no_hierarchy_for({a.backend});  // a dacrt backend alone: no BVH built (quality none)
  auto backend = make_backend(a.backend, a.dev.options(scene.threads, scene.quality));
  const RenderOptions o = a.options(*backend, reference);
  // -- scene and render
  Loaded l = load_and_build(scene);
  if (!quiet()) std::fprintf(stderr, "backend: %s\n", backend->describe().c_str());
  backend->prepare(*l.acc, TraceOptions{o.layout, o.traversal, Query::closest, false, o.precision});
  Progress p("rendering", o.spp);
  const RenderResult res = render(l.scene, *l.acc, *backend, o, [&p](unsigned d, unsigned) { p.update(d); });
  p.finish();
  if (!res.camera_rule.empty())  // the default camera: what it is, so a user can reuse or vary it
    say("camera: %s\n  --camera %s\n", res.camera_rule.c_str(), camera_argument(res.camera).c_str());
  // -- all outputs or none: the PNG is not left behind when the PFM or the curve cannot be written
  ImageBytes image;
  std::vector<OutputWrite> writes = image_writes(a, outs, res, image);
  std::string curve;
  if (!a.curve.empty()) {
    curve = curve_json(a, *backend, l.scene, res);
    writes.push_back({outs[2], curve.data(), curve.size()});
  }
  write_outputs(writes);
  // -- report
  say("rendered %ux%u, %u spp, %s (%s/%s) on %s: %zu rays over all bounces, %.3f Mrays/s in traversal "
      "(%.2f s), %.2f s in all\nwrote %s\n",
      res.width, res.height, o.spp, to_string(o.mode), is_dacrt(o.traversal) ? "-" : to_string(o.layout),
      to_string(o.traversal), a.backend.c_str(),
      res.rays, res.mrays_per_s(), res.trace_seconds, res.total_seconds, shown(a.out).c_str());
  if (!res.curve.empty())
    say("RMSE against %s: %.5f after 1 spp, %.5f after %u spp\n", a.reference.c_str(), res.curve.front().rmse,
        res.curve.back().rmse, res.curve.back().spp);
  return 0;
}

}  // namespace

void RenderArgs::add(CLI::App* c) {
  scene.add(c);
  c->add_option("--backend", backend, "backend (see `mbvh devices`)");
  c->add_option("--layout", layout, "mbvh2, mbvh4, mbvh8 or auto (the default: the layout the backend traces fastest with the traversal)");
  c->add_option("--traversal", traversal, "stack, bitstack, stack-ordered, bitstack-retest, stack-octant, bitstack-octant (MBVH8), or packet-ranged, packet-partition, packet (cpu: 8x8-tile packets), or dacrt (no hierarchy), or auto (the default: the backend's fastest exact closest-hit traversal, docs/library.md \"Defaults\"; the report names it)");
  c->add_option("--mode", mode, "path (8-bounce diffuse, point light and sky), ao or normals");
  c->add_option("--spp", o.spp, "samples per pixel")->check(integer_in(1, 1u << 20));
  c->add_option("--bounces", o.bounces, "path mode: diffuse bounces after the primary hit")->check(integer_in(0, 1024));
  c->add_option("--width", o.width, "image width")->check(integer_in(1, 65536));
  c->add_option("--height", o.height, "image height")->check(integer_in(1, 65536));
  c->add_option("--seed", o.seed, "seed of every random number of the image")->check(integer_in(0, UINT64_MAX));
  add_camera_option(c, camera);
  c->add_option("--light", light, "path mode: the point light x,y,z (default: near the top of the scene's box, centred)")
      ->delimiter(',')
      ->expected(3)
      ->check(number_in(-FLT_MAX, FLT_MAX, true));
  c->add_option("-o,--output", out, "PNG file ('-': standard output, not a terminal)")->required();
  c->add_option("--precision", precision, "accuracy mode: robust (default), exact or fast");
  c->add_option("--pfm", pfm, "also write the linear image as PFM (a reference for --reference)");
  c->add_option("--reference", reference, "PFM of the same size: report the RMSE against it after every sample pass");
  c->add_option("--curve", curve, "with --reference: write the RMSE-against-time curve as JSON");
  dev.add(c);
}

Command add_render(CLI::App& app) {
  auto a = std::make_shared<RenderArgs>();
  auto l = std::make_shared<LodArgs>();
  auto* c = app.add_subcommand("render",
                               "render an image on a backend: 8-bounce diffuse path tracing, AO or normals; or frames "
                               "of an out-of-core .mlod model (--lod, --memory, --frames)");
  a->add(c);
  l->add(c);
  return {c, [a, l, c] { return run_render(*a, *l, c); }};
}

}  // namespace mbvh::cli

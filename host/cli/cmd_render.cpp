// SPDX-License-Identifier: MIT
// cmd_render.cpp — `mbvh render`: render an image on a backend (host/tools/render.h): 8-bounce
// diffuse path tracing, AO or normals; a PNG, optionally the linear PFM and an error curve. Without
// --camera it reports the camera frame_scene chose, as a --camera argument.
#include <nlohmann/json.hpp>

#include "host/cli/args.h"
#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/tools/image.h"
#include "host/tools/render.h"

namespace mbvh::cli {

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

int run_render(const RenderArgs& a) {
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
  const std::vector<std::uint8_t> png = png_bytes(a.out, res.width, res.height, to_srgb8(res.rgb));
  std::vector<OutputWrite> writes{{outs[0], png.data(), png.size()}};
  std::vector<char> pfm;
  if (!a.pfm.empty()) {
    pfm = pfm_bytes(a.pfm, res.width, res.height, res.rgb);
    writes.push_back({outs[1], pfm.data(), pfm.size()});
  }
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
  c->add_option("--traversal", traversal, "stack, bitstack, stack-ordered, bitstack-retest, or packet-ranged, packet-partition, packet (cpu: 8x8-tile packets), or dacrt (no hierarchy), or auto (the default: the backend's fastest exact closest-hit traversal, docs/library.md \"Defaults\"; the report names it)");
  c->add_option("--mode", mode, "path (8-bounce diffuse, point light and sky), ao or normals");
  c->add_option("--spp", o.spp, "samples per pixel")->check(integer_in(1, 1u << 20));
  c->add_option("--bounces", o.bounces, "path mode: diffuse bounces after the primary hit")->check(integer_in(0, 1024));
  c->add_option("--width", o.width, "image width")->check(integer_in(1, 65536));
  c->add_option("--height", o.height, "image height")->check(integer_in(1, 65536));
  c->add_option("--seed", o.seed, "seed of every random number of the image")->check(integer_in(0, UINT64_MAX));
  add_camera_option(c, camera);
  c->add_option("-o,--output", out, "PNG file ('-': standard output, not a terminal)")->required();
  c->add_option("--precision", precision, "accuracy mode: robust (default), exact or fast");
  c->add_option("--pfm", pfm, "also write the linear image as PFM (a reference for --reference)");
  c->add_option("--reference", reference, "PFM of the same size: report the RMSE against it after every sample pass");
  c->add_option("--curve", curve, "with --reference: write the RMSE-against-time curve as JSON");
  dev.add(c);
}

Command add_render(CLI::App& app) {
  auto a = std::make_shared<RenderArgs>();
  auto* c = app.add_subcommand("render", "render an image on a backend: 8-bounce diffuse path tracing, AO or normals");
  a->add(c);
  return {c, [a] { return run_render(*a); }};
}

}  // namespace mbvh::cli

// SPDX-License-Identifier: MIT
// cmd_rays.cpp — `mbvh rays`: generate a ray file (32 bytes per ray).
#include "host/cli/commands.h"

namespace mbvh::cli {

namespace {

struct RaysArgs {
  SceneArgs scene;
  RayArgs rays;
  std::string out;
};

int run_rays(const RaysArgs& a) {
  const OutputTarget out{"-o", a.out};
  prepare_outputs({out}, {{"scene", a.scene.scene}});
  a.rays.check_memory();
  Loaded l = load_and_build(a.scene);
  const std::vector<Ray> r = generate_rays(l.scene, *l.acc, a.rays.generator(a.rays.kind, a.scene.threads));
  write_bytes_to(out, r.data(), r.size() * sizeof(Ray));
  say("wrote %zu %s rays (seed %llu) to %s\n", r.size(), a.rays.kind.c_str(), static_cast<unsigned long long>(a.rays.seed),
      shown(a.out).c_str());
  return 0;
}

}  // namespace

Command add_rays(CLI::App& app) {
  auto a = std::make_shared<RaysArgs>();
  auto* c = app.add_subcommand("rays", "generate a ray file (32 bytes per ray)");
  a->scene.add(c);
  a->rays.add(c, false);
  c->add_option("-o,--output", a->out, "output ray file ('-': standard output)")->required();
  return {c, [a] { return run_rays(*a); }};
}

}  // namespace mbvh::cli

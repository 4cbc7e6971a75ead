// SPDX-License-Identifier: MIT
// cmd_check.cpp — `mbvh check`: cross-check backends x layouts x traversals x queries ray by ray
// and against the brute force (host/tools/check.h); exit status 1 on a genuine mismatch.
#include <nlohmann/json.hpp>

#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/tools/check.h"

namespace mbvh::cli {

namespace {

struct CheckArgs {
  SceneArgs scene;
  RayArgs rays;
  GridArgs grid;
  std::string kinds = "", brute = "2000", json;
};

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

int run_check_command(const CheckArgs& a) {
  const OutputTarget json_to{"--json", a.json, true};
  prepare_outputs({json_to}, {{"scene", a.scene.scene}, {"--rays", a.rays.rays_file}});
  // -- the options, the scene and the ray kinds
  CheckOptions co;
  co.grid = a.grid.parse();
  SceneArgs scene = a.scene;
  scene.no_hierarchy_for(co.grid.backends);  // dacrt backends alone: no BVH built (quality none)
  co.threads = scene.threads;
  co.backend = a.grid.dev.options(scene.threads, scene.quality);
  co.brute_rays = a.brute == "all" ? SIZE_MAX : std::strtoull(a.brute.c_str(), nullptr, 10);  // checked: an integer
  a.rays.check_memory();  // one kind's rays at a time
  Loaded l = load_and_build(scene);
  std::vector<std::string> kinds = a.kinds.empty() ? std::vector<std::string>{a.rays.kind} : split_list(a.kinds, "--kinds");
  if (!a.rays.rays_file.empty()) kinds = {"file"};
  // -- one check per kind
  std::size_t genuine = 0;
  nlohmann::json j{{"scene", l.scene.name}, {"kinds", nlohmann::json::array()}};
  for (const auto& k : kinds) {
    const std::vector<Ray> r = k == "file" ? read_rays(a.rays.rays_file)
                                           : generate_rays(l.scene, *l.acc, a.rays.generator(k, a.scene.threads));
    const bool tty = Progress::enabled();  // false under --quiet
    CheckReport rep = run_check(*l.acc, r, co, [tty](const std::string& s) {
      if (tty) std::fprintf(stderr, "\r%-72.72s\r", s.c_str());
    });
    if (tty) std::fprintf(stderr, "\r%72s\r", "");
    say("== %s: %s rays\n%s\n", l.scene.name.c_str(), k == "file" ? a.rays.rays_file.c_str() : k.c_str(),
        rep.table(r).c_str());
    genuine += rep.mismatches();
    j["kinds"].push_back(check_json(rep, k));
  }
  // -- the verdict: in the JSON and as the exit status
  if (!a.json.empty()) {
    j["mismatches"] = genuine;
    j["genuine_mismatches"] = genuine;
    j["verdict"] = genuine ? "mismatch" : "ok";  // "mismatch": exit status 1
    const std::string text = j.dump(1) + "\n";
    write_bytes_to(json_to, text.data(), text.size());
  }
  return genuine ? 1 : 0;
}

}  // namespace

Command add_check(CLI::App& app) {
  auto a = std::make_shared<CheckArgs>();
  auto* c = app.add_subcommand("check", "cross-check backends x layouts x traversals ray by ray and against brute force");
  a->scene.add(c);
  a->rays.add(c, true);
  a->grid.add(c);
  c->add_option("--kinds", a->kinds, "comma-separated generated ray kinds (default: --kind)");
  c->add_option("--brute", a->brute, "rays checked by double-precision brute force, spread over the batch, or 'all'")
      ->check(CLI::IsMember({"all"}) | integer_in(0, UINT64_MAX));
  c->add_option("--json", a->json, "also write every comparison as JSON (per ray kind: rays, invalid, pairs)");
  return {c, [a] { return run_check_command(*a); }};
}

}  // namespace mbvh::cli

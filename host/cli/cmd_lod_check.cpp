// SPDX-License-Identifier: MIT
// cmd_lod_check.cpp — `mbvh lod check MODEL --against SOURCE`: the model's full-detail answers
// against cpu-scalar's and the brute force's on the source's in-core build (host/tools/lod_check.h);
// exit status 1 on a genuine mismatch or a leak, 2 on an error (a damaged block: named).
#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "host/tools/lod_check.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

namespace {

struct LodCheckArgs {
  std::string model, against, kinds = "primary", memory, brute = "2000";
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  unsigned threads = 0;
};

int run_lod_check_command(const LodCheckArgs& a) {
  LodCheckOptions o;
  o.kinds.clear();
  for (const std::string& k : split_list(a.kinds, "--kinds")) o.kinds.push_back(parse_ray_kind(k));
  o.count = a.count;
  o.seed = a.seed;
  o.brute_rays = a.brute == "all" ? SIZE_MAX : std::strtoull(a.brute.c_str(), nullptr, 10);  // checked: an integer
  if (!a.memory.empty()) parse_size(a.memory, o.cache.memory_budget);                       // checked by the validator
  o.cache.threads = a.threads;
  require_ray_memory("--count " + std::to_string(a.count), a.count);
  if (!lod::is_model_file(a.model)) throw Error(a.model + ": not a .mlod model (no MBVHLOD magic)");
  // -- the model, and its source: the same triangles, or no comparison makes sense
  std::unique_ptr<lod::Model> model = lod::Model::open(a.model, o.cache);
  check_model_source(*model, *lod::open_triangles(a.against, a.threads));
  SceneArgs sa;
  sa.scene = a.against;
  sa.threads = a.threads;
  Loaded l = load_and_build(sa);
  const bool tty = Progress::enabled();
  std::vector<std::vector<Ray>> rays;
  const LodCheckReport rep = run_lod_check(*model, l.scene, *l.acc, o, &rays, [tty](const std::string& s) {
    if (tty) std::fprintf(stderr, "\r%-72.72s\r", s.c_str());
  });
  if (tty) std::fprintf(stderr, "\r%72s\r", "");
  say("%s", rep.text(rays).c_str());
  return rep.failures() ? 1 : 0;
}

}  // namespace

Command add_lod_check(CLI::App& lod) {
  auto a = std::make_shared<LodCheckArgs>();
  auto* c = lod.add_subcommand("check", "check a .mlod model's full-detail answers against the in-core build of --against");
  c->add_option("model", a->model, "the .mlod model")->required();
  c->add_option("--against", a->against, "the model's source: a .mtri, a scene file or a gen: spec (built in core)")->required();
  c->add_option("--kinds", a->kinds,
                "comma-separated generated ray kinds: primary, shadow, diffuse, random, inside (closed generated meshes: "
                "counts leaks), special, path");
  c->add_option("--count", a->count, "rays of each kind")->check(ray_count());
  c->add_option("--seed", a->seed, "seed of the generated rays")->check(integer_in(0, UINT64_MAX));
  c->add_option("--memory", a->memory, "the model's cache budget of decompressed blocks (bytes, or K, M, G, T; default: the whole model)")
      ->check(CLI::Validator(
          [](std::string& v) {
            std::uint64_t b = 0;
            return parse_size(v, b) ? std::string() : "'" + v + "' is not a size (bytes, or with a K, M, G or T suffix, e.g. 2G)";
          },
          "SIZE"));
  c->add_option("--threads", a->threads, "worker threads (0: every hardware thread)")->check(integer_in(0, kMaxThreads));
  c->add_option("--brute", a->brute, "rays checked by double-precision brute force, spread over each batch, or 'all'")
      ->check(CLI::IsMember({"all"}) | integer_in(0, UINT64_MAX));
  return {c, [a] { return run_lod_check_command(*a); }};
}

}  // namespace mbvh::cli

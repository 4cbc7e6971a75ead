// SPDX-License-Identifier: MIT
// cmd_lod.cpp — `mbvh lod`: the out-of-core LOD model (mbvh/lod.h; docs/massive.md): `lod build`
// writes a .mlod from any triangle source, `lod info` prints its header, `lod check`
// (cmd_lod_check.cpp) checks its full-detail answers against the in-core reference.
#include "host/cli/commands.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

namespace {

// TODO(lod build, lod info): the builder's helper fills these in.
Command add_lod_build(CLI::App& lod) {
  auto* c = lod.add_subcommand("build", "build a .mlod model from SOURCE (.mtri, a scene file or a gen: spec) within --memory");
  return {c, [] { throw Error("lod build: not built yet"); return 2; }};
}

Command add_lod_info(CLI::App& lod) {
  auto* c = lod.add_subcommand("info", "print a .mlod model's counts, sizes and pinned bytes");
  return {c, [] { throw Error("lod info: not built yet"); return 2; }};
}

}  // namespace

Command add_lod(CLI::App& app) {
  auto* lod = app.add_subcommand("lod", "out-of-core LOD models (.mlod): build, info, check");
  lod->require_subcommand(1);
  auto subs = std::make_shared<std::vector<Command>>(
      std::vector<Command>{add_lod_build(*lod), add_lod_info(*lod), add_lod_check(*lod)});
  return {lod, [subs] {
            for (const Command& c : *subs)
              if (*c.app) return c.run();
            return 2;
          }};
}

}  // namespace mbvh::cli

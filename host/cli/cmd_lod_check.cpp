// SPDX-License-Identifier: MIT
// cmd_lod_check.cpp — `mbvh lod check MODEL --against SOURCE`: the model's full-detail answers
// against cpu-scalar's and the brute force's on the source's in-core build.
#include "host/cli/commands.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

// TODO(lod check): the model's helper fills this in.
Command add_lod_check(CLI::App& lod) {
  auto* c = lod.add_subcommand("check", "check a .mlod model's full-detail answers against the in-core build of --against");
  return {c, [] { throw Error("lod check: not built yet"); return 2; }};
}

}  // namespace mbvh::cli

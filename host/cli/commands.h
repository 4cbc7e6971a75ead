// SPDX-License-Identifier: MIT
// commands.h — the `mbvh` subcommands, one file each (cmd_*.cpp): each adds its subcommand and
// options to the program and returns what runs it.
#pragma once
#include <CLI/CLI.hpp>

#include "host/cli/common.h"

namespace mbvh::cli {

Command add_info(CLI::App& app);         ///< cmd_info.cpp: scene and per-layout build statistics
Command add_rays(CLI::App& app);         ///< cmd_rays.cpp: write a ray file
Command add_trace(CLI::App& app);        ///< cmd_trace.cpp: trace rays, write hits or occlusion
Command add_check(CLI::App& app);        ///< cmd_check.cpp: cross-check variants and the brute force
Command add_bench(CLI::App& app);        ///< cmd_bench.cpp: verified speed of every variant
Command add_render(CLI::App& app);       ///< cmd_render.cpp: render an image on a backend
Command add_build_bench(CLI::App& app);  ///< cmd_build_bench.cpp: build times, ours and embree's
Command add_devices(CLI::App& app);      ///< cmd_devices.cpp: the backends and their devices
Command add_gen(CLI::App& app);          ///< cmd_gen.cpp: write a (streamed) .mtri triangle file
Command add_lod(CLI::App& app);          ///< cmd_lod.cpp: out-of-core LOD models: build, info, check
Command add_lod_check(CLI::App& lod);    ///< cmd_lod_check.cpp: `lod check` (a subcommand of `lod`)

}  // namespace mbvh::cli

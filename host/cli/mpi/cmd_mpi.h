// SPDX-License-Identifier: MIT
// cmd_mpi.h — `mbvh-mpi`'s subcommands (cmd_mpi.cpp): `mbvh`'s trace, render, bench and check with
// the plain program's options (host/cli/args.h) and the ranks' own: --distribute, --schedule,
// --batch, --tiles.
#pragma once
#include <CLI/CLI.hpp>

#include "host/cli/common.h"
#include "mbvh/mpi.h"

namespace mbvh::cli {

Command add_mpi_trace(CLI::App& app, const mpi::Comm& comm);   ///< trace rays over the ranks
Command add_mpi_render(CLI::App& app, const mpi::Comm& comm);  ///< render an image over the ranks
Command add_mpi_bench(CLI::App& app, const mpi::Comm& comm);   ///< time and verify distributed traces
Command add_mpi_check(CLI::App& app, const mpi::Comm& comm);   ///< distributed answers against one process

}  // namespace mbvh::cli

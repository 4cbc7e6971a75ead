// SPDX-License-Identifier: MIT
// main.cpp — the `mbvh-mpi` program: `mbvh`'s trace, render, bench and check over the ranks of
// MPI_COMM_WORLD (mpirun -np P mbvh-mpi COMMAND ...), with the plain program's options. Rank 0
// reports and writes the outputs; an error on any rank prints "mbvh-mpi: error (rank r/P): ..." and
// ends every rank with exit status 2 (MPI_Abort), before any output is written.
#include <mpi.h>

#include <CLI/CLI.hpp>

#include <cstdio>
#include <exception>
#include <new>
#include <optional>
#include <string>

#include "host/cli/mpi/cmd_mpi.h"
#include "host/cli/progress.h"
#include "mbvh/backends.h"
#include "mbvh/log.h"
#include "mbvh/version.h"

namespace {

int g_rank = 0, g_ranks = 1;

// An error on this rank: every rank ends, with exit status 2 (the other ranks wait in a collective call).
[[noreturn]] void fail(const std::string& what) {
  std::fprintf(stderr, "mbvh-mpi: error (rank %d/%d): %s\n", g_rank, g_ranks, what.c_str());
  std::fflush(stderr);
  MPI_Abort(MPI_COMM_WORLD, 2);
  std::_Exit(2);  // MPI_Abort does not return
}

int run(int argc, char** argv) {
  using namespace mbvh::cli;
  CLI::App app{"mbvh-mpi " MBVH_VERSION_STRING " — mbvh's trace, render, bench and check over MPI ranks "
               "(mpirun -np P mbvh-mpi COMMAND ...): replicated (every rank holds the scene and one shared BVH; "
               "the answers and images are bit for bit those of one process) or --distribute data (each rank "
               "builds the BVH of one part of the scene; rays are forwarded between the ranks)\n\nexit status: "
               "0 success; 1 `check` found a genuine mismatch or `bench` an answer that did not verify; 2 an error "
               "on any rank (named in the message), and then no output is written"};
  app.require_subcommand(1);
  app.set_version_flag("--version", "mbvh-mpi " MBVH_VERSION_STRING);
  app.option_defaults()->always_capture_default();
  app.fallthrough();
  app.add_flag("-q,--quiet", quiet(), "print nothing but errors (outputs are still written)");
  const mbvh::mpi::Comm comm;
  const Command commands[] = {add_mpi_trace(app, comm), add_mpi_render(app, comm), add_mpi_bench(app, comm),
                              add_mpi_check(app, comm)};
  // every rank parses its command line; they must agree before any rank goes on into a collective
  // call (ranks given different lines would wait there for ever): 0 run, 1 done (--help, --version),
  // 2 a usage error. Rank 0 says why; a rank alone in error says so itself.
  int parsed = 0;
  std::optional<CLI::ParseError> error;
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    parsed = e.get_exit_code() == 0 ? 1 : 2;
    error.emplace(e);
  }
  int worst = parsed, root = parsed;
  MPI_Allreduce(&parsed, &worst, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  MPI_Bcast(&root, 1, MPI_INT, 0, MPI_COMM_WORLD);
  if (error && (g_rank == 0 || (parsed == 2 && root != 2))) app.exit(*error);
  if (worst == 2) {
    if (g_rank == 0 && parsed != 2)
      std::fprintf(stderr, "mbvh-mpi: error (rank 0/%d): the command line is not valid on every rank (above)\n", g_ranks);
    return 2;
  }
  if (worst == 1) return 0;
  if (g_rank != 0) quiet() = true;  // the report is rank 0's
  if (quiet()) mbvh::Progress::set_enabled(false);
  try {
    for (const Command& c : commands)
      if (*c.app) return c.run();
  } catch (const std::bad_alloc&) {
    fail("out of memory: an allocation failed (MBVH_MEMORY_LIMIT bounds what mbvh plans to use)");
  } catch (const std::exception& e) {
    fail(e.what());
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  // the backends' worker threads never call MPI: only the main thread does
  int provided = 0;
  if (MPI_Init_thread(&argc, &argv, MPI_THREAD_FUNNELED, &provided) != MPI_SUCCESS) {
    std::fprintf(stderr, "mbvh-mpi: error: MPI_Init_thread failed\n");
    return 2;
  }
  MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
  MPI_Comm_size(MPI_COMM_WORLD, &g_ranks);
  // an MPI failure returns its code: mbvh::mpi turns it into an Error naming the call, which ends
  // every rank through fail() with exit status 2 (MPI_ERRORS_ARE_FATAL would exit with MPI's own)
  MPI_Comm_set_errhandler(MPI_COMM_WORLD, MPI_ERRORS_RETURN);
  mbvh::register_builtin_backends();
  mbvh::set_log_callback([](mbvh::LogLevel level, const std::string& m) {
    if (g_rank == 0) std::fprintf(stderr, "%s\n", m.c_str());
    else if (level == mbvh::LogLevel::warning) std::fprintf(stderr, "(rank %d) %s\n", g_rank, m.c_str());
  });
  int rc = run(argc, argv);
  if (std::fflush(stdout) != 0 || std::ferror(stdout)) fail("standard output: write failed");
  // every rank ends with the same status: the worst
  int worst = rc;
  MPI_Allreduce(&rc, &worst, 1, MPI_INT, MPI_MAX, MPI_COMM_WORLD);
  MPI_Finalize();
  return worst;
}

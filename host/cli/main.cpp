// SPDX-License-Identifier: MIT
// main.cpp — the `mbvh` program: sets up the command line (one file per subcommand,
// host/cli/cmd_*.cpp), runs the chosen subcommand and turns its outcome into the exit status.
#include <CLI/CLI.hpp>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <exception>
#include <new>

#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "mbvh/backends.h"
#include "mbvh/log.h"
#include "mbvh/version.h"

namespace {

// Parses the command line and runs the subcommand; the exit status.
int run(int argc, char** argv) {
  using namespace mbvh::cli;
  CLI::App app{"mbvh " MBVH_VERSION_STRING " — one MBVH2/MBVH4/MBVH8 build, stackless bitstack traversal on several "
               "backends\n\nexit status: 0 success; 1 `check` found a genuine mismatch or `bench` a timed result "
               "that did not verify; 2 an error (a bad option or value, a bad input, a failed run)"};
  app.require_subcommand(1);
  app.set_help_all_flag("--help-all", "help for every command");
  app.set_version_flag("--version", "mbvh " MBVH_VERSION_STRING);
  app.option_defaults()->always_capture_default();  // --help shows every option's default
  app.fallthrough();  // --quiet may follow the subcommand
  app.add_flag("-q,--quiet", quiet(), "print nothing but errors (outputs are still written)");
  const Command commands[] = {add_info(app),   add_rays(app),   add_trace(app),       add_check(app),
                              add_bench(app),  add_render(app), add_build_bench(app), add_devices(app),
                              add_gen(app),    add_lod(app)};
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {  // --help and --version exit 0; every usage error exits 2
    return app.exit(e) == 0 ? 0 : 2;
  }
  if (quiet()) mbvh::Progress::set_enabled(false);
  try {
    for (const Command& c : commands)
      if (*c.app) return c.run();
  } catch (const std::bad_alloc&) {  // one no wrapper named (resources.h allocating)
    std::fprintf(stderr, "mbvh: error: out of memory: an allocation failed (the system refused it: an address-space or "
                         "cgroup limit, or memory taken by others; MBVH_MEMORY_LIMIT bounds what mbvh plans to use)\n");
    return 2;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mbvh: error: %s\n", e.what());
    return 2;
  }
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  mbvh::register_builtin_backends();  // the program links every backend of this build
  // the library's messages (the device a backend chose) go to standard error, one line each
  mbvh::set_log_callback([](mbvh::LogLevel, const std::string& m) { std::fprintf(stderr, "%s\n", m.c_str()); });
  int rc = run(argc, argv);
  // the report is an output too: a failed write to standard output fails the run
  if (std::fflush(stdout) != 0 || std::ferror(stdout)) {
    std::fprintf(stderr, "mbvh: error: standard output: write failed: %s\n", std::strerror(errno));
    if (rc == 0) rc = 2;
  }
  // problems a backend's diagnostics raised where they could not throw (Vulkan validation
  // messages while tearing down): the run fails
  for (const mbvh::BackendInfo& b : mbvh::list_backends())
    if (b.pending_problems)
      if (const std::vector<std::string> p = b.pending_problems(); !p.empty()) {
        for (const std::string& m : p) std::fprintf(stderr, "mbvh: error: %s: %s\n", b.name.c_str(), m.c_str());
        if (rc == 0) rc = 2;
      }
  return rc;
}

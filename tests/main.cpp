// SPDX-License-Identifier: MIT
// main.cpp — the Catch2 main of mbvh-tests. After the tests, any problem a backend's diagnostics
// raised where it could not throw (Vulkan validation messages at teardown) fails the run.
#define CATCH_CONFIG_RUNNER
#include <catch2/catch.hpp>

#include <cstdio>

#include "mbvh/backend.h"
#include "mbvh/backends.h"

int main(int argc, char** argv) {
  mbvh::register_builtin_backends();
  int rc = Catch::Session().run(argc, argv);
  for (const mbvh::BackendInfo& b : mbvh::list_backends())
    if (b.pending_problems)
      for (const std::string& m : b.pending_problems()) {
        std::fprintf(stderr, "error: %s: %s\n", b.name.c_str(), m.c_str());
        rc = rc ? rc : 1;
      }
  return rc;
}

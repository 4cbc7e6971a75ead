// SPDX-License-Identifier: MIT
// build_config.cpp — the facts of the build the tests run in (tests/helpers.h), compiled in each
// build with its own definitions (CMakeLists.txt): every other test file compiles to the same
// object in every build of the same sources, so a build may link another's (MBVH_TEST_OBJECTS_FROM).
#include "tests/helpers.h"

namespace mbvh_test {

const char* built_cli_path() { return MBVH_CLI_PATH; }

const char* scenes_dir() { return MBVH_SCENES_DIR; }

bool sanitized() {
#ifdef MBVH_TEST_SANITIZED
  return true;
#else
  return false;
#endif
}

}  // namespace mbvh_test

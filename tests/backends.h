// backends.h — the backends a test runs on: every backend built into this binary; one whose
// hardware this machine lacks (e.g. AVX-512) is skipped with the reason printed, and one that
// is built but cannot start for any other reason fails the test; an alias (`cpu`) is tested
// under the name it stands for.
#pragma once
#include <catch2/catch.hpp>

#include <cstdio>

#include "host/backend.h"

namespace mbvh_test {

inline mbvh::VariantGrid all_backends() {
  mbvh::VariantGrid g;
  g.backends.clear();
  for (const mbvh::BackendInfo& b : mbvh::list_backends()) {
    if (!b.make) continue;
    if (!b.alias_of.empty()) {
      std::printf("backend %s is %s here: tested under that name\n", b.name.c_str(), b.alias_of.c_str());
      continue;
    }
    if (b.missing_hardware) {
      if (const std::string why = b.missing_hardware(); !why.empty()) {
        std::printf("skipping backend %s: %s\n", b.name.c_str(), why.c_str());
        continue;
      }
    }
    INFO("backend " << b.name);
    REQUIRE_NOTHROW(mbvh::make_backend(b.name));
    g.backends.push_back(b.name);
  }
  REQUIRE(!g.backends.empty());
  return g;
}

}  // namespace mbvh_test

// SPDX-License-Identifier: MIT
// fuzz_scene.cpp — libFuzzer target for the OBJ and PLY loaders (and zstd decompression):
// any input must either load or throw mbvh::Error; a crash, hang, leak or sanitizer report is a
// bug. Built with -DMBVH_FUZZ=ON and clang; MBVH_FUZZ_FORMAT selects the parser.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "mbvh/error.h"
#include "mbvh/scene.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  try {
    std::vector<char> bytes(reinterpret_cast<const char*>(data), reinterpret_cast<const char*>(data) + size);
    bytes = mbvh::maybe_decompress("fuzz", std::move(bytes));
    const mbvh::Scene s = MBVH_FUZZ_FORMAT("fuzz", bytes.data(), bytes.size());
    for (const auto& t : s.triangles)  // every index the loader accepted is in range
      for (std::uint32_t v : t)
        if (v >= s.vertices.size()) __builtin_trap();
  } catch (const mbvh::Error&) {
  }
  return 0;
}

// SPDX-License-Identifier: MIT
// fuzz_mtri.cpp — libFuzzer target for the .mtri reader (host/core/io/mtri.h): any bytes either
// open and stream (every triangle delivered once, in order, finite, within the header's bounds)
// or throw mbvh::Error; a crash, hang, leak or sanitizer report is a bug. The reader works on a
// file (it is made for files larger than memory), so each input is written to a temporary first.
#include <unistd.h>

#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

#include "host/core/io/mtri.h"
#include "mbvh/error.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const struct Temp {
    std::string path = "/tmp/fuzz-mtri-" + std::to_string(::getpid()) + ".mtri";
    ~Temp() { ::unlink(path.c_str()); }
  } temp;
  const std::string& path = temp.path;
  if (FILE* f = std::fopen(path.c_str(), "wb")) {
    if (size > 0 && std::fwrite(data, 1, size, f) != size) __builtin_trap();
    std::fclose(f);
  } else {
    __builtin_trap();
  }
  try {
    const mbvh::MtriReader r(path);
    std::uint64_t next = 0;
    r.for_each_chunk([&](std::uint64_t first, std::span<const mbvh::SourceTri> tris) {
      if (first != next) __builtin_trap();
      for (const mbvh::SourceTri& t : tris)
        for (float c : t.v)
          if (!std::isfinite(c)) __builtin_trap();
      next += tris.size();
    });
    if (next != r.count()) __builtin_trap();
  } catch (const mbvh::Error&) {
  }
  return 0;
}

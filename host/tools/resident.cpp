// SPDX-License-Identifier: MIT
// resident.cpp — resident memory by /proc/self (resident.h).
#include "host/tools/resident.h"

#include <algorithm>
#include <fstream>
#include <string>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

namespace mbvh {

std::int64_t status_bytes(const char* key) {
  std::ifstream f("/proc/self/status");
  std::string line;
  while (std::getline(f, line))
    if (line.rfind(key, 0) == 0) return std::stoll(line.substr(std::string(key).size())) * 1024;
  return -1;
}

bool reset_peak() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
  std::ofstream f("/proc/self/clear_refs");
  f << "5";
  f.flush();
  return static_cast<bool>(f);
}

std::int64_t MemoryProbe::peak_extra() const {
  return base < 0 ? -1 : std::max<std::int64_t>(0, status_bytes("VmHWM:") - base);
}

}  // namespace mbvh

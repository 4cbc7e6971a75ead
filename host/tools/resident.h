// SPDX-License-Identifier: MIT
// resident.h — this process's resident memory, by /proc/self (Linux): VmRSS now and VmHWM, its
// peak since the last reset, for the benchmarks that report what a build or a trace keeps and
// what it needs at its peak (bench --dynamic, bench/memory.cpp).
#pragma once
#include <cstdint>

namespace mbvh {

/// A field of /proc/self/status in bytes ("VmRSS:", "VmHWM:"), or -1 where it cannot be read.
std::int64_t status_bytes(const char* key);

/// Returns freed heap to the system (malloc_trim, glibc), then resets VmHWM to the current VmRSS
/// (writing 5 to /proc/self/clear_refs, Linux 4.0 on), so a step's peak counts what it allocates,
/// not what an earlier step left in the allocator's free lists. False where the reset failed.
bool reset_peak();

/// A step's resident memory: start() before it, peak_extra() (VmHWM above the start's VmRSS) and
/// rss_now() after it; -1 where /proc/self cannot be used.
struct MemoryProbe {
  bool on = reset_peak();
  std::int64_t base = -1;
  void start() { base = on && reset_peak() ? status_bytes("VmRSS:") : -1; }
  std::int64_t peak_extra() const;
  std::int64_t rss_now() const { return on ? status_bytes("VmRSS:") : -1; }
};

}  // namespace mbvh

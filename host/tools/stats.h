// SPDX-License-Identifier: MIT
// stats.h — what the tools time with and report over repeated timings: the clock, milliseconds
// since a start, the median.
#pragma once
#include <algorithm>
#include <chrono>
#include <vector>

namespace mbvh {

using Clock = std::chrono::steady_clock;

/// Milliseconds from `t0` to now.
inline double ms_since(Clock::time_point t0) {
  return std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

/// The median of `v` (the mean of the two middle values for an even count); 0 for none.
inline double median(std::vector<double> v) {
  if (v.empty()) return 0;
  std::sort(v.begin(), v.end());
  return v.size() % 2 ? v[v.size() / 2] : 0.5 * (v[v.size() / 2 - 1] + v[v.size() / 2]);
}

}  // namespace mbvh

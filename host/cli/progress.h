// SPDX-License-Identifier: MIT
// progress.h — a progress bar on stderr for long builds and runs, shown only on a terminal.
#pragma once
#include <chrono>
#include <cstddef>
#include <mutex>
#include <string>

namespace mbvh {

class Progress {
public:
  /// Starts a bar for `total` units; silent unless stderr is a terminal.
  Progress(std::string label, std::size_t total);
  ~Progress();
  /// Sets the units done so far (thread-safe, throttled to ~10 redraws per second).
  void update(std::size_t done);
  /// Clears the bar.
  void finish();
  static bool enabled();
  /// Turns every bar off (false: `--quiet`) or back on where stderr is a terminal.
  static void set_enabled(bool on);

private:
  std::string label_;
  std::size_t total_;
  bool on_, finished_ = false;
  std::mutex mutex_;
  std::chrono::steady_clock::time_point last_{};
};

}  // namespace mbvh

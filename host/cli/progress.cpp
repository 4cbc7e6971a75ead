// SPDX-License-Identifier: MIT
// progress.cpp — the terminal progress bar.
#include "host/cli/progress.h"

#include <unistd.h>

#include <cstdio>

namespace mbvh {

namespace {
bool g_progress_allowed = true;
}
bool Progress::enabled() { return g_progress_allowed && isatty(fileno(stderr)) != 0; }
void Progress::set_enabled(bool on) { g_progress_allowed = on; }

Progress::Progress(std::string label, std::size_t total) : label_(std::move(label)), total_(total), on_(enabled()) {}

Progress::~Progress() { finish(); }

void Progress::update(std::size_t done) {
  if (!on_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  const auto now = std::chrono::steady_clock::now();
  if (finished_ || (now - last_ < std::chrono::milliseconds(100) && done < total_)) return;
  last_ = now;
  const int width = 30;
  const double f = total_ ? static_cast<double>(done) / static_cast<double>(total_) : 1.0;
  const int fill = static_cast<int>(f * width + 0.5);
  std::fprintf(stderr, "\r%-28.28s [%.*s%*s] %5.1f%%", label_.c_str(), fill, "##############################",
               width - fill, "", 100.0 * f);
  std::fflush(stderr);
}

void Progress::finish() {
  if (!on_ || finished_) return;
  std::lock_guard<std::mutex> lock(mutex_);
  finished_ = true;
  std::fprintf(stderr, "\r%*s\r", 72, "");
  std::fflush(stderr);
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// log.cpp — the log callback (mbvh/log.h). The callback is copied under the lock and called
// outside it: a callback that waits for something (the Python module's takes the GIL) never holds
// the lock, so no thread setting a callback can deadlock with one logging.
#include "mbvh/log.h"

#include <mutex>

namespace mbvh {

namespace {
std::mutex& log_mutex() {
  static std::mutex m;
  return m;
}
LogCallback& log_callback() {
  static LogCallback cb;
  return cb;
}
}  // namespace

const char* to_string(LogLevel level) {
  switch (level) {
    case LogLevel::debug: return "debug";
    case LogLevel::info: return "info";
    case LogLevel::warning: return "warning";
  }
  return "?";
}

LogCallback set_log_callback(LogCallback callback) {
  const std::lock_guard<std::mutex> lock(log_mutex());
  std::swap(log_callback(), callback);
  return callback;
}

void log_message(LogLevel level, const std::string& message) {
  LogCallback cb;
  {
    const std::lock_guard<std::mutex> lock(log_mutex());
    cb = log_callback();
  }
  if (cb) cb(level, message);
}

}  // namespace mbvh

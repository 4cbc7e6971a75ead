// SPDX-License-Identifier: MIT
// log.h — where the library's messages go. The library never writes to standard output or
// standard error itself: what it has to say (the device a backend chose, the work-group size of a
// GPU mapping) goes to the log callback a program sets, and is dropped when none is set. The
// `mbvh` program sets one that prints to standard error; the C API and the Python module forward
// to the caller's (mbvh_set_log_callback, mbvh.set_log).
#pragma once
#include <functional>
#include <string>

namespace mbvh {

enum class LogLevel { debug, info, warning };
const char* to_string(LogLevel level);

/// Receives every library message: its level and one line of text (no trailing newline).
using LogCallback = std::function<void(LogLevel, const std::string&)>;

/// Sets the callback (an empty one: messages are dropped, the default) and returns the one it
/// replaces. Thread-safe. The callback may be called from any thread the library runs on, from
/// several at once (it is called outside the library's locks), and may be called once more after
/// it was replaced, by a thread that took it before.
LogCallback set_log_callback(LogCallback callback);

/// Sends a message to the callback, if one is set (the backends' messages). Thread-safe.
void log_message(LogLevel level, const std::string& message);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// error.h — the one exception type of the mbvh library: input errors with context, device and
// backend failures. The library never exits; the CLI catches Error and prints what().
#pragma once
#include <stdexcept>
#include <string>

namespace mbvh {

/// Thrown for every recoverable failure: malformed input (the message names file, line and what
/// was wrong), unknown names, a backend that cannot start.
class Error : public std::runtime_error {
public:
  explicit Error(const std::string& what) : std::runtime_error(what) {}
};

/// Error at a position in an input file: "FILE:LINE: MESSAGE" (line 0 omits the line).
[[noreturn]] void fail_at(const std::string& file, std::size_t line, const std::string& message);

}  // namespace mbvh

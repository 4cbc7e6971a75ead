// SPDX-License-Identifier: MIT
// input.h — input files streamed in 1 MiB pieces, zstd-compressed ones decompressed as they are
// read, so a reader that parses as it goes holds one piece of the file at a time, never all of it.
#pragma once
#include <cstddef>
#include <functional>
#include <string>

namespace mbvh {

/// The size of the pieces stream_file reads (and, decompressed, about the size of those it hands on).
inline constexpr std::size_t kInputChunk = std::size_t(1) << 20;

/// True when `data` starts with a zstd frame or a skippable frame (magic numbers 0xFD2FB528 and
/// 0x184D2A50-5F, little-endian): the content is zstd-compressed.
bool starts_zstd(const char* data, std::size_t size);

/// Calls `consume(data, size)` with the content of the regular file at `path`, piece by piece
/// (decompressed as it is read when the file starts with a zstd frame, skippable frames
/// included), until the file ends or `consume` returns false. Throws Error naming `path` when it
/// is not a regular file (unopened), cannot be read, changes size while read, or holds a corrupt
/// or truncated zstd stream. Allocates two pieces' worth; what `consume` keeps is its own to bound.
void stream_file(const std::string& path, const std::function<bool(const char*, std::size_t)>& consume);

}  // namespace mbvh

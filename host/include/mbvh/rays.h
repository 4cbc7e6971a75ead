// SPDX-License-Identifier: MIT
// rays.h — the ray / hit / occlusion files of DESIGN.md (the ray generators are the tools'
// host/tools/raygen.h).
#pragma once
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include "mbvh/trace.h"

namespace mbvh {

/// Files (little-endian, no header): rays 32 B, hits 16 B, occlusion 1 B per ray. Writers go
/// through write_outputs (io/output.h): a unique temporary renamed on success, regular files only.
/// The readers throw Error naming the file when its size is not a multiple of the record, when it
/// starts like another format (PNG, PFM, zstd, gzip, PLY, the BVH cache, text), when a ray holds a
/// NaN or infinite value (tmax = +inf excepted: no far limit) and when an occlusion byte is not 0 or 1.
std::vector<Ray> read_rays(const std::string& path);
/// Writes `bytes` bytes to `path` ("-": standard output) as write_outputs does: a unique temporary
/// beside it renamed on success; refuses anything but a regular file; Error on any failure.
void write_bytes(const std::string& path, const void* data, std::size_t bytes);
/// The ray records in `size` bytes; throws Error (naming `name`) as read_rays does.
std::vector<Ray> rays_from_bytes(const std::string& name, const char* data, std::size_t size);
/// Throws Error naming `name` and the ray's index and field when a ray holds a NaN or infinite
/// value (tmax = +inf excepted: no far limit); `hint`, if given, ends the message. What read_rays
/// checks, for rays from memory (the C and Python bindings). O(rays), on up to `threads` workers
/// (0: every hardware thread) for a large batch.
void check_ray_values(const std::string& name, std::span<const Ray> rays, const char* hint = nullptr,
                      unsigned threads = 1);
void write_rays(const std::string& path, std::span<const Ray> rays);
std::vector<Hit> read_hits(const std::string& path);
void write_hits(const std::string& path, std::span<const Hit> hits);
std::vector<std::uint8_t> read_occlusion(const std::string& path);
void write_occlusion(const std::string& path, std::span<const std::uint8_t> occ);

}  // namespace mbvh

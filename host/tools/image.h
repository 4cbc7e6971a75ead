// SPDX-License-Identifier: MIT
// image.h — image files: PNG (8-bit sRGB, zlib-compressed) and PFM (linear floats, the
// renderer's references), written atomically (a temporary renamed on success) like every output.
#pragma once
#include <cstdint>
#include <string>
#include <vector>

namespace mbvh {

/// 8-bit sRGB of linear radiance (clamped to [0, 1]), 3 bytes per pixel.
std::vector<std::uint8_t> to_srgb8(const std::vector<float>& rgb);

/// The bytes of an 8-bit RGB PNG: IHDR, the scanlines (filter 0) compressed by zlib (compress2,
/// the default level) in one IDAT (several past 1 GiB), IEND. Throws Error naming `name` unless rgb8 is
/// width x height x 3, both non-zero, or if zlib fails.
std::vector<std::uint8_t> png_bytes(const std::string& name, unsigned width, unsigned height,
                                    const std::vector<std::uint8_t>& rgb8);
/// Writes png_bytes to `path` as write_bytes does (a unique temporary beside it renamed on
/// success, '-': standard output); throws Error naming the path on failure.
void write_png(const std::string& path, unsigned width, unsigned height, const std::vector<std::uint8_t>& rgb8);

/// Portable float map (PFM, "PF", little-endian, rows bottom to top as the format says): the
/// linear image without loss, for references. pfm_bytes: the file's bytes (Error naming `name`
/// if rgb is not width x height x 3).
std::vector<char> pfm_bytes(const std::string& name, unsigned width, unsigned height, const std::vector<float>& rgb);
/// Writes pfm_bytes to `path` as write_bytes does; throws Error naming the path on failure.
void write_pfm(const std::string& path, unsigned width, unsigned height, const std::vector<float>& rgb);
/// Reads a PFM written by write_pfm (3 floats per pixel, rows from the top); throws Error naming
/// the path for anything else, a header that disagrees with the file's size included.
std::vector<float> read_pfm(const std::string& path, unsigned& width, unsigned& height);

}  // namespace mbvh

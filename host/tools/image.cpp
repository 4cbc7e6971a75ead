// SPDX-License-Identifier: MIT
// image.cpp — the PNG and PFM writers and the PFM reader (image.h).
#include "host/tools/image.h"

#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <fstream>

#include "host/core/resources.h"
#include "mbvh/error.h"
#include "mbvh/rays.h"

namespace mbvh {

std::vector<std::uint8_t> to_srgb8(const std::vector<float>& rgb) {
  std::vector<std::uint8_t> out(rgb.size());
  for (std::size_t i = 0; i < rgb.size(); ++i) {
    const float v = std::clamp(rgb[i], 0.0f, 1.0f);
    const float s = v <= 0.0031308f ? 12.92f * v : 1.055f * std::pow(v, 1.0f / 2.4f) - 0.055f;
    out[i] = static_cast<std::uint8_t>(std::lround(s * 255.0f));
  }
  return out;
}

// -- PNG: signature, IHDR, the zlib stream of the scanlines in IDAT chunks, IEND

namespace {

// The largest IDAT written (a chunk holds at most 2^31-1 bytes); smaller images have one.
constexpr std::size_t kIdatBytes = std::size_t(1) << 30;

void put32(std::vector<std::uint8_t>& o, std::uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) o.push_back(static_cast<std::uint8_t>(v >> s));
}

// A chunk: length, type, data, and the CRC-32 of type and data.
void chunk(std::vector<std::uint8_t>& o, const char* type, const std::uint8_t* data, std::size_t size) {
  put32(o, static_cast<std::uint32_t>(size));
  const std::size_t start = o.size();
  o.insert(o.end(), type, type + 4);
  o.insert(o.end(), data, data + size);
  const uLong crc = crc32(crc32(0L, Z_NULL, 0), o.data() + start, static_cast<uInt>(o.size() - start));
  put32(o, static_cast<std::uint32_t>(crc));
}

}  // namespace

std::vector<std::uint8_t> png_bytes(const std::string& name, unsigned width, unsigned height,
                                    const std::vector<std::uint8_t>& rgb8) {
  if (width == 0 || height == 0 || rgb8.size() != std::size_t(width) * height * 3)
    throw Error(name + ": cannot write a PNG of " + std::to_string(width) + "x" + std::to_string(height) + " from " +
                std::to_string(rgb8.size()) + " bytes");
  // -- the scanlines, each with filter byte 0
  std::vector<std::uint8_t> raw;
  raw.reserve((std::size_t(width) * 3 + 1) * height);
  for (unsigned y = 0; y < height; ++y) {
    raw.push_back(0);
    const auto row = rgb8.begin() + static_cast<std::ptrdiff_t>(std::size_t(y) * width * 3);
    raw.insert(raw.end(), row, row + static_cast<std::ptrdiff_t>(width) * 3);
  }
  // -- compressed: a zlib stream (header, deflate blocks, Adler-32), as PNG's IDAT holds it
  uLongf zlen = compressBound(static_cast<uLong>(raw.size()));
  std::vector<std::uint8_t> z(zlen);
  if (const int rc = compress2(z.data(), &zlen, raw.data(), static_cast<uLong>(raw.size()), Z_DEFAULT_COMPRESSION);
      rc != Z_OK)
    throw Error(name + ": zlib could not compress the PNG's " + std::to_string(raw.size()) + " bytes of pixels (" +
                zError(rc) + ")");
  z.resize(zlen);
  // -- the file
  std::vector<std::uint8_t> png{0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  std::vector<std::uint8_t> ihdr;
  put32(ihdr, width);
  put32(ihdr, height);
  ihdr.insert(ihdr.end(), {8, 2, 0, 0, 0});  // 8 bits, RGB, deflate, adaptive filtering, no interlace
  chunk(png, "IHDR", ihdr.data(), ihdr.size());
  for (std::size_t at = 0; at < z.size(); at += kIdatBytes)  // consecutive IDATs: one stream, split
    chunk(png, "IDAT", z.data() + at, std::min(kIdatBytes, z.size() - at));
  chunk(png, "IEND", nullptr, 0);
  return png;
}

void write_png(const std::string& path, unsigned width, unsigned height, const std::vector<std::uint8_t>& rgb8) {
  const std::vector<std::uint8_t> png = png_bytes(path, width, height, rgb8);
  write_bytes(path, png.data(), png.size());
}

// -- PFM

std::vector<char> pfm_bytes(const std::string& name, unsigned width, unsigned height, const std::vector<float>& rgb) {
  if (rgb.size() != std::size_t(width) * height * 3) throw Error(name + ": PFM size does not match the image");
  const std::string header = "PF\n" + std::to_string(width) + " " + std::to_string(height) + "\n-1.0\n";
  std::vector<char> bytes(header.begin(), header.end());
  for (unsigned y = height; y-- > 0;) {  // bottom row first
    const char* row = reinterpret_cast<const char*>(rgb.data() + std::size_t(y) * width * 3);
    bytes.insert(bytes.end(), row, row + std::size_t(width) * 12);
  }
  return bytes;
}

void write_pfm(const std::string& path, unsigned width, unsigned height, const std::vector<float>& rgb) {
  const std::vector<char> bytes = pfm_bytes(path, width, height, rgb);
  write_bytes(path, bytes.data(), bytes.size());
}

std::vector<float> read_pfm(const std::string& path, unsigned& width, unsigned& height) {
  const std::uint64_t file_size = regular_file_size(path, "PFM");  // before opening: a FIFO would block
  std::ifstream f(path, std::ios::binary);
  if (!f) throw Error(path + ": cannot open the PFM file");
  std::string magic;
  double scale = 0;
  long long w = 0, h = 0;
  f >> magic >> w >> h >> scale;
  if (!f || magic != "PF" || w <= 0 || h <= 0 || w > 65536 || h > 65536 || !(scale < 0))
    throw Error(path + ": not a little-endian RGB PFM (expected 'PF', width, height, a negative scale)");
  f.get();  // the single whitespace after the scale
  // -- the header's size against the file's, before allocating: 21 bytes may claim 48 GiB
  const std::uint64_t pixels = static_cast<std::uint64_t>(w) * static_cast<std::uint64_t>(h) * 12;
  const std::streamoff at = f.tellg();  // -1 when the header ends the file
  const std::uint64_t have = at < 0 ? 0 : file_size - static_cast<std::uint64_t>(at);
  if (pixels != have)
    throw Error(path + ": the PFM header says " + std::to_string(w) + "x" + std::to_string(h) + " pixels (" +
                std::to_string(pixels) + " bytes of RGB floats) but the file holds " + std::to_string(have) +
                " bytes after the header");
  require_memory(path, pixels, "to read the PFM image");
  width = static_cast<unsigned>(w);
  height = static_cast<unsigned>(h);
  std::vector<float> rgb(std::size_t(width) * height * 3);
  for (unsigned y = height; y-- > 0;)
    if (!f.read(reinterpret_cast<char*>(rgb.data() + std::size_t(y) * width * 3), std::streamsize(width) * 12))
      throw Error(path + ": PFM data ends early (row " + std::to_string(height - 1 - y) + " of " + std::to_string(height) + ")");
  return rgb;
}

}  // namespace mbvh

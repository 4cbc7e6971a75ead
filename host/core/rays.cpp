// SPDX-License-Identifier: MIT
// rays.cpp — the ray, hit and occlusion files of DESIGN.md (little-endian records, no header).
#include "mbvh/rays.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <type_traits>

#include "mbvh/error.h"
#include "host/core/io/output.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"

namespace mbvh {

static_assert(std::endian::native == std::endian::little, "file formats are little-endian; add byte swapping");

// -- files
namespace {

void check_record_size(const std::string& name, const char* what, std::size_t size, std::size_t record) {
  if (size % record != 0)
    throw Error(name + ": size " + std::to_string(size) + " bytes is not a multiple of the " + std::to_string(record) +
                "-byte " + what + " record");
}

// The files have no header, so any bytes of the right size would pass as records: the first
// bytes are compared with the formats an mbvh user has at hand (images, compressed scenes, the
// BVH cache, PLY, text), which no ray, hit or occlusion file starts with in practice.
const char* foreign_format(const unsigned char* b, std::size_t n) {
  auto starts = [&](const char* m, std::size_t k) { return n >= k && std::memcmp(b, m, k) == 0; };
  if (starts("\x89PNG", 4)) return "a PNG image";
  if (starts("\x28\xB5\x2F\xFD", 4)) return "a zstd-compressed file";
  if (n >= 4 && (b[0] & 0xF0) == 0x50 && std::memcmp(b + 1, "\x2A\x4D\x18", 3) == 0) return "a zstd-compressed file (skippable frame)";
  if (starts("\x1F\x8B", 2)) return "a gzip-compressed file";
  if (starts("MBVHBVH", 7)) return "an mbvh BVH cache file";
  if (starts("ply\n", 4) || starts("ply\r", 4)) return "a PLY scene";
  if (starts("PF\n", 3) || starts("Pf\n", 3)) return "a PFM image";
  // text: the first 64 bytes (or all) printable ASCII or whitespace; a float record almost always
  // holds a byte below 0x20 or above 0x7E (1.0f is 00 00 80 3F)
  const std::size_t k = std::min<std::size_t>(n, 64);
  if (k == 0) return nullptr;
  for (std::size_t i = 0; i < k; ++i)
    if (!((b[i] >= 0x20 && b[i] < 0x7F) || b[i] == '\n' || b[i] == '\r' || b[i] == '\t')) return nullptr;
  return "a text file";
}

void check_not_foreign(const std::string& name, const char* what, const void* data, std::size_t size) {
  if (const char* f = foreign_format(static_cast<const unsigned char*>(data), size))
    throw Error(name + ": this is " + f + ", not a " + what + " file (" + what + " files are raw little-endian records, "
                "DESIGN.md)");
}

void check_occlusion_values(const std::string& name, std::span<const std::uint8_t> occ) {
  for (std::size_t i = 0; i < occ.size(); ++i)
    if (occ[i] > 1)
      throw Error(name + ": byte " + std::to_string(i) + " is " + std::to_string(occ[i]) +
                  ", not an occlusion flag (0 or 1); is this an occlusion file?");
}

template <class T>
void check_records(const std::string& name, const char* what, std::span<const T> r) {
  check_not_foreign(name, what, r.data(), r.size_bytes());
  if constexpr (std::is_same_v<T, Ray>) check_ray_values(name, r, "; is this a ray file?");
  if constexpr (std::is_same_v<T, std::uint8_t>) check_occlusion_values(name, r);
}

template <class T>
std::vector<T> records_from_bytes(const std::string& name, const char* what, const char* data, std::size_t size) {
  check_record_size(name, what, size, sizeof(T));
  std::vector<T> out(size / sizeof(T));
  if (size) std::memcpy(out.data(), data, size);
  check_records<T>(name, what, out);
  return out;
}

template <class T>
std::vector<T> read_records(const std::string& path, const char* what) {
  // stat()ed before it is opened: a FIFO would block in open, a device has no size
  const std::uint64_t size = regular_file_size(path, what);
  check_record_size(path, what, static_cast<std::size_t>(size), sizeof(T));
  require_memory(path, size, std::string("to read the ") + what + " file");
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) throw Error(path + ": cannot open " + what + " file: " + std::strerror(errno));
  std::vector<T> out = allocating(path + ": the " + std::to_string(size / sizeof(T)) + " records of the " + what + " file", size,
                                  [&] { return std::vector<T>(static_cast<std::size_t>(size) / sizeof(T)); });
  if (!out.empty() && std::fread(out.data(), sizeof(T), out.size(), f.get()) != out.size())
    throw Error(path + ": read error in " + what + " file");
  check_records<T>(path, what, out);
  return out;
}

}  // namespace

void write_bytes(const std::string& path, const void* data, std::size_t bytes) {
  const OutputWrite out{{"", path, false}, data, bytes};
  write_outputs(std::span(&out, 1));
}

std::vector<Ray> read_rays(const std::string& path) { return read_records<Ray>(path, "ray"); }
std::vector<Ray> rays_from_bytes(const std::string& name, const char* data, std::size_t size) {
  return records_from_bytes<Ray>(name, "ray", data, size);
}
std::vector<Hit> read_hits(const std::string& path) { return read_records<Hit>(path, "hit"); }
std::vector<std::uint8_t> read_occlusion(const std::string& path) { return read_records<std::uint8_t>(path, "occlusion"); }
void write_rays(const std::string& path, std::span<const Ray> r) { write_bytes(path, r.data(), r.size_bytes()); }
void write_hits(const std::string& path, std::span<const Hit> h) { write_bytes(path, h.data(), h.size_bytes()); }
void write_occlusion(const std::string& path, std::span<const std::uint8_t> o) { write_bytes(path, o.data(), o.size_bytes()); }

// Rays: every value finite, except tmax, which may be +inf (the default: no far limit). A NaN,
// an infinite origin, direction or tmin, or tmax = -inf is no ray a program meant to write.
namespace {
// Whether rays[b, e) hold a NaN or an infinity (tmax = +inf excepted): a branch-free scan of the
// exponent bits (NaN and infinity have them all set; tmax may be exactly +inf), which the
// compiler vectorises.
bool any_bad_value(std::span<const Ray> rays, std::size_t b, std::size_t e) {
  unsigned bad = 0;
  for (std::size_t i = b; i < e; ++i) {
    std::uint32_t w[8];
    std::memcpy(w, &rays[i], sizeof w);
    for (int k = 0; k < 7; ++k) bad |= (w[k] & 0x7F800000u) == 0x7F800000u;
    bad |= ((w[7] & 0x7F800000u) == 0x7F800000u) & (w[7] != 0x7F800000u);
  }
  return bad != 0;
}
}  // namespace

void check_ray_values(const std::string& name, std::span<const Ray> rays, const char* hint, unsigned threads) {
  // The scan first (the bindings check every batch they trace: on `threads` workers where the
  // batch is large); only a batch with a bad ray goes through the loop below, which names it.
  constexpr std::size_t kChunk = 1 << 16;
  bool bad = false;
  if (threads == 1 || rays.size() <= kChunk) {
    bad = any_bad_value(rays, 0, rays.size());
  } else {
    std::atomic<bool> found{false};
    parallel_for(rays.size(), kChunk, threads, [&](std::size_t b, std::size_t e, unsigned) {
      if (any_bad_value(rays, b, e)) found.store(true, std::memory_order_relaxed);
    });
    bad = found.load();
  }
  if (!bad) return;
  static const char* const field[8] = {"origin x", "origin y", "origin z", "tmin", "direction x", "direction y", "direction z", "tmax"};
  for (std::size_t i = 0; i < rays.size(); ++i) {
    const float v[8] = {rays[i].ox, rays[i].oy, rays[i].oz, rays[i].tmin, rays[i].dx, rays[i].dy, rays[i].dz, rays[i].tmax};
    for (int k = 0; k < 8; ++k)
      if (!std::isfinite(v[k]) && !(k == 7 && v[k] > 0))
        throw Error(name + ": ray " + std::to_string(i) + " has " + field[k] + " = " + std::to_string(v[k]) +
                    " (rays hold finite values; only tmax may be +inf)" + (hint ? hint : ""));
  }
}

}  // namespace mbvh

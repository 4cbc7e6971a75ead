// SPDX-License-Identifier: MIT
// rays.cpp — the ray, hit and occlusion files of DESIGN.md (little-endian records, no header).
#include "mbvh/rays.h"

#include <bit>
#include <cstring>

#include "mbvh/error.h"
#include "host/core/io/output.h"
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

template <class T>
std::vector<T> records_from_bytes(const std::string& name, const char* what, const char* data, std::size_t size) {
  check_record_size(name, what, size, sizeof(T));
  std::vector<T> out(size / sizeof(T));
  if (size) std::memcpy(out.data(), data, size);
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

}  // namespace mbvh

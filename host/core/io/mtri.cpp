// SPDX-License-Identifier: MIT
// mtri.cpp — writing and reading .mtri files (mtri.h has the format).
#include "host/core/io/mtri.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cctype>
#include <cerrno>
#include <cstddef>
#include <cmath>
#include <cstring>
#include <optional>

#include "host/core/gen/mandelbulb.h"
#include "host/core/layouts.h"  // hash_bytes
#include "host/core/resources.h"
#include "mbvh/error.h"

namespace mbvh {

namespace {

struct MtriHeader {
  char magic[8];
  std::uint32_t version;
  std::uint32_t flags;
  std::uint64_t count;
  Box bounds;
  std::uint64_t content_hash;
  std::uint64_t check;  // hash_bytes of the bytes before it
};
static_assert(sizeof(MtriHeader) == kMtriHeaderBytes);
static_assert(sizeof(Box) == 24);

std::uint64_t header_check(const MtriHeader& h) { return hash_bytes(&h, offsetof(MtriHeader, check)); }
std::uint64_t block_count(std::uint64_t count) { return (count * sizeof(SourceTri) + kMtriBlockBytes - 1) / kMtriBlockBytes; }
std::uint64_t content_hash(const std::vector<std::uint64_t>& table, std::uint64_t count) {
  return hash_bytes(table.data(), table.size() * sizeof(std::uint64_t), count);
}

}  // namespace

std::uint64_t mtri_file_bytes(std::uint64_t count) {
  return kMtriHeaderBytes + count * sizeof(SourceTri) + block_count(count) * 8 + 8;
}

bool is_mtri(const void* head, std::size_t size) { return size >= 8 && std::memcmp(head, kMtriMagic, 8) == 0; }

// -- writing

MtriWriter::MtriWriter(const OutputTarget& to) : out_(to) {
  const MtriHeader placeholder{};  // patched by finish()
  out_.write(&placeholder, sizeof placeholder);
  block_.reserve(kMtriBlockBytes);
}

MtriWriter::~MtriWriter() = default;

void MtriWriter::flush_block() {
  if (block_.empty()) return;
  table_.push_back(hash_bytes(block_.data(), block_.size(), table_.size()));
  out_.write(block_.data(), block_.size());
  block_.clear();
}

void MtriWriter::add(std::span<const SourceTri> tris) {
  for (const SourceTri& t : tris)
    for (int k = 0; k < 3; ++k) bounds_.grow(Vec3f{t.v[3 * k], t.v[3 * k + 1], t.v[3 * k + 2]});
  const char* p = reinterpret_cast<const char*>(tris.data());
  std::size_t n = tris.size_bytes();
  while (n > 0) {  // records may straddle two blocks
    const std::size_t take = std::min<std::size_t>(n, kMtriBlockBytes - block_.size());
    block_.insert(block_.end(), p, p + take);
    p += take;
    n -= take;
    if (block_.size() == kMtriBlockBytes) flush_block();
  }
  count_ += tris.size();
}

void MtriWriter::finish() {
  flush_block();
  MtriHeader h{};
  std::memcpy(h.magic, kMtriMagic, 8);
  h.version = kMtriVersion;
  h.flags = 0;
  h.count = count_;
  h.bounds = bounds_;
  h.content_hash = hash_ = content_hash(table_, count_);
  h.check = header_check(h);
  const std::uint64_t sum = hash_bytes(table_.data(), table_.size() * sizeof(std::uint64_t), h.check);
  out_.write(table_.data(), table_.size() * sizeof(std::uint64_t));
  out_.write(&sum, sizeof sum);
  out_.patch(0, &h, sizeof h);
  bytes_ = out_.bytes();
  out_.commit();
}

// -- reading

namespace {

void read_exactly(int fd, const std::string& path, void* dst, std::uint64_t bytes, std::uint64_t off) {
  char* d = static_cast<char*>(dst);
  while (bytes > 0) {
    const ssize_t got = ::pread(fd, d, bytes, static_cast<off_t>(off));
    if (got < 0 && errno == EINTR) continue;
    if (got < 0) throw Error(path + ": read failed at byte " + std::to_string(off) + ": " + std::strerror(errno));
    if (got == 0) throw Error(path + ": the file ended at byte " + std::to_string(off) + " while it was read (truncated meanwhile?)");
    d += got;
    off += static_cast<std::uint64_t>(got);
    bytes -= static_cast<std::uint64_t>(got);
  }
}

}  // namespace

MtriReader::MtriReader(const std::string& path) : path_(path) {
  const std::string bad = path + ": not a usable .mtri file: ";
  regular_file_size(path, "triangle");  // a FIFO or device is refused unopened
  fd_ = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd_ < 0) throw Error(path + ": cannot be opened: " + std::strerror(errno));
  try {
    struct stat st {};
    if (::fstat(fd_, &st) != 0) throw Error(path + ": cannot be inspected: " + std::strerror(errno));
    if (!S_ISREG(st.st_mode)) throw Error(path + ": not a regular file");
    size_ = static_cast<std::uint64_t>(st.st_size);
    // -- the header
    if (size_ < kMtriHeaderBytes + 8)
      throw Error(bad + "truncated: " + std::to_string(size_) + " bytes, less than the " + std::to_string(kMtriHeaderBytes + 8) +
                  " of an empty file");
    MtriHeader h;
    read_exactly(fd_, path, &h, sizeof h, 0);
    if (std::memcmp(h.magic, kMtriMagic, 8) != 0) throw Error(bad + "magic: no \"MBVHTRI\" header");
    if (h.version != kMtriVersion)
      throw Error(bad + "version: format version " + std::to_string(h.version) + ", this library reads " + std::to_string(kMtriVersion));
    if (h.check != header_check(h)) throw Error(bad + "header: its check does not match (the header is damaged)");
    if (h.flags != 0)
      throw Error(bad + "flags: " + std::to_string(h.flags) + ", this library reads 0 (36-byte records without colour)");
    // -- the size against the count: every count bounded by the file
    if (h.count > size_ / sizeof(SourceTri) || mtri_file_bytes(h.count) != size_)
      throw Error(bad + "size: " + std::to_string(size_) + " bytes, but its " + std::to_string(h.count) + " triangles make a file of " +
                  std::to_string(mtri_file_bytes(h.count)) + " bytes (" +
                  (h.count > size_ / sizeof(SourceTri) || mtri_file_bytes(h.count) > size_ ? "truncated)" : "bytes after the end)"));
    // -- the block table against the trailer
    table_.resize(block_count(h.count));
    const std::uint64_t table_at = kMtriHeaderBytes + h.count * sizeof(SourceTri);
    read_exactly(fd_, path, table_.data(), table_.size() * 8, table_at);
    std::uint64_t sum;
    read_exactly(fd_, path, &sum, 8, size_ - 8);
    if (hash_bytes(table_.data(), table_.size() * 8, h.check) != sum)
      throw Error(bad + "block table: its checksum does not match (the table or the trailer is damaged)");
    if (content_hash(table_, h.count) != h.content_hash) throw Error(bad + "content hash: it does not match the block table");
    count_ = h.count;
    bounds_ = h.bounds;
    hash_ = h.content_hash;
  } catch (...) {
    ::close(fd_);
    throw;
  }
}

MtriReader::~MtriReader() {
  if (fd_ >= 0) ::close(fd_);
}

void MtriReader::for_each_chunk(const ChunkFn& fn) const {
  std::vector<char> block(kMtriBlockBytes + sizeof(SourceTri));
  std::vector<SourceTri> tris(kMtriBlockBytes / sizeof(SourceTri) + 2);
  const std::uint64_t record_bytes = count_ * sizeof(SourceTri);
  std::size_t carry = 0;  // bytes of a record begun in the previous block
  std::uint64_t next = 0;
  Box seen;
  for (std::uint64_t b = 0; b < table_.size(); ++b) {
    const std::uint64_t at = b * kMtriBlockBytes, n = std::min(kMtriBlockBytes, record_bytes - at);
    read_exactly(fd_, path_, block.data() + carry, n, kMtriHeaderBytes + at);
    if (hash_bytes(block.data() + carry, n, b) != table_[b])
      throw Error(path_ + ": block " + std::to_string(b) + " of " + std::to_string(table_.size()) + " (file bytes " +
                  std::to_string(kMtriHeaderBytes + at) + ".." + std::to_string(kMtriHeaderBytes + at + n) + ", triangles " +
                  std::to_string(at / sizeof(SourceTri)) + ".." + std::to_string((at + n - 1) / sizeof(SourceTri)) +
                  ") is damaged: its checksum does not match");
    const std::size_t have = carry + n, whole = have / sizeof(SourceTri);
    std::memcpy(tris.data(), block.data(), whole * sizeof(SourceTri));
    carry = have - whole * sizeof(SourceTri);
    std::memmove(block.data(), block.data() + whole * sizeof(SourceTri), carry);
    for (std::size_t i = 0; i < whole; ++i)
      for (int k = 0; k < 3; ++k) {
        const Vec3f p{tris[i].v[3 * k], tris[i].v[3 * k + 1], tris[i].v[3 * k + 2]};
        if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
          throw Error(path_ + ": triangle " + std::to_string(next + i) + " has a non-finite coordinate; vertices must be finite");
        seen.grow(p);
      }
    if (whole > 0) fn(next, std::span<const SourceTri>(tris.data(), whole));
    next += whole;
  }
  if (std::memcmp(&seen, &bounds_, sizeof seen) != 0)
    throw Error(path_ + ": the header's bounds do not match the bounds of its triangles");
}

Scene load_mtri(const std::string& path) {
  MtriReader r(path);
  if (r.count() > kMaxTriangles)
    throw Error(path + ": " + std::to_string(r.count()) + " triangles, more than the " + std::to_string(kMaxTriangles) +
                " one in-core scene holds (32-bit prim ids)");
  const std::uint64_t n = r.count();
  require_memory(path, scene_memory_estimate(n, 3 * n) - build_memory_estimate(n, 3 * n) + loading_build_estimate(n, 3 * n),
                 std::to_string(n) + " triangles with 3 vertices each, and their build");
  Scene s;
  s.vertices.reserve(3 * n);
  s.triangles.reserve(n);
  r.for_each_chunk([&s](std::uint64_t, std::span<const SourceTri> t) { append_triangles(s, t); });
  return s;
}

MtriWritten write_mtri(const std::string& source, const OutputTarget& to, unsigned threads) {
  MtriWritten w;
  MandelbulbOptions mo;
  const bool is_gen = source.rfind("gen:", 0) == 0;
  const bool mandelbulb = is_gen && streamed_mandelbulb(source.substr(4), mo);  // parameters checked before the output is made
  std::string lower = source;
  for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  const bool copy = !is_gen && lower.size() > 5 && lower.compare(lower.size() - 5, 5, ".mtri") == 0;
  std::optional<MtriReader> reader;
  if (copy) reader.emplace(source);  // refused at open before the output is made
  Scene scene;
  if (!mandelbulb && !copy) scene = load_scene(source);
  MtriWriter out(to);
  const ChunkFn add = [&out](std::uint64_t, std::span<const SourceTri> t) { out.add(t); };
  if (mandelbulb) {
    mo.threads = threads;
    w.buffer_bytes = generate_mandelbulb(mo, add).peak_buffer;
  } else if (copy) {
    reader->for_each_chunk(add);
  } else {
    scene.validate();
    std::vector<SourceTri> chunk;
    for (std::size_t i = 0; i < scene.triangle_count(); ++i) {
      Vec3f a, b, c;
      scene.triangle(i, a, b, c);
      chunk.push_back({{a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z}});
      if (chunk.size() == 4096 || i + 1 == scene.triangle_count()) {
        out.add(chunk);
        chunk.clear();
      }
    }
  }
  out.finish();
  w.count = out.count();
  w.bytes = out.bytes();
  w.hash = out.hash();
  w.bounds = out.bounds();
  w.streamed = mandelbulb || copy;
  return w;
}

}  // namespace mbvh

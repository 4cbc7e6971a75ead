// SPDX-License-Identifier: MIT
// file.cpp — input files streamed piece by piece (decompressed as they are read when zstd), and
// whole-file reads with transparent zstd decompression, bounded by the memory budget before
// anything is allocated.
#include <zstd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <functional>
#include <memory>

#include "host/core/io/input.h"
#include "mbvh/error.h"
#include "host/core/resources.h"
#include "mbvh/scene.h"

namespace mbvh {

void fail_at(const std::string& file, std::size_t line, const std::string& message) {
  if (line == 0) throw Error(file + ": " + message);
  throw Error(file + ":" + std::to_string(line) + ": " + message);
}

namespace {

// The file is stat()ed before it is opened: a FIFO would block in open and a device never ends.
std::vector<char> read_raw(const std::string& path) {
  const std::uint64_t size = regular_file_size(path, "input");
  require_memory(path, size, "to read the file");
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) fail_at(path, 0, std::string("cannot open file: ") + std::strerror(errno));
  std::vector<char> data(static_cast<std::size_t>(size));
  const std::size_t n = size ? std::fread(data.data(), 1, data.size(), f.get()) : 0;
  if (std::ferror(f.get())) fail_at(path, 0, std::string("read error: ") + std::strerror(errno));
  if (n != data.size() || std::fgetc(f.get()) != EOF)
    fail_at(path, 0, "the file changed size while it was read");
  return data;
}

bool is_zstd(const std::vector<char>& d) { return starts_zstd(d.data(), d.size()); }

using ZstdStream = std::unique_ptr<ZSTD_DStream, std::size_t (*)(ZSTD_DStream*)>;

std::vector<char> decompress(const std::string& path, const std::vector<char>& in) {
  ZstdStream ds(ZSTD_createDStream(), &ZSTD_freeDStream);
  if (!ds) fail_at(path, 0, "zstd: out of memory");
  ZSTD_initDStream(ds.get());
  std::vector<char> out;
  // The first frame's content size, when its header states it, is checked against the budget
  // before decompressing; the stream is capped at the budget either way. A corrupt header may
  // claim terabytes (found by fuzzing), so reserve no more than a plausible ratio of the input.
  const MemoryBudget budget = memory_budget();
  const unsigned long long stated = ZSTD_getFrameContentSize(in.data(), in.size());
  if (stated != ZSTD_CONTENTSIZE_UNKNOWN && stated != ZSTD_CONTENTSIZE_ERROR) {
    require_memory(path, stated, "to decompress: the size the zstd frame header states", budget);
    out.reserve(static_cast<std::size_t>(std::min<unsigned long long>(stated, 64ull * in.size() + (1u << 20))));
  }
  ZSTD_inBuffer ib{in.data(), in.size(), 0};
  std::vector<char> chunk(ZSTD_DStreamOutSize());
  std::size_t ret = 0;
  bool full = false;
  // a full output buffer may hold more: call again, unless the frame just ended (ret == 0), where
  // another call would start a new frame and report it missing
  while (ib.pos < ib.size || (full && ret != 0)) {
    ZSTD_outBuffer ob{chunk.data(), chunk.size(), 0};
    ret = ZSTD_decompressStream(ds.get(), &ob, &ib);
    if (ZSTD_isError(ret)) fail_at(path, 0, std::string("zstd: ") + ZSTD_getErrorName(ret));
    require_memory(path, out.size() + ob.pos, "to decompress, at least: the zstd stream goes on", budget);
    out.insert(out.end(), chunk.data(), chunk.data() + ob.pos);
    full = ob.pos == ob.size;
  }
  if (ret != 0) fail_at(path, 0, "truncated zstd stream (the compressed file ends mid-frame)");
  return out;
}

}  // namespace

bool starts_zstd(const char* data, std::size_t size) {
  if (size < 4) return false;
  const unsigned char* b = reinterpret_cast<const unsigned char*>(data);
  const std::uint32_t magic = b[0] | b[1] << 8 | b[2] << 16 | std::uint32_t(b[3]) << 24;
  return magic == 0xFD2FB528u || (magic & 0xFFFFFFF0u) == 0x184D2A50u;  // a frame, a skippable frame
}

// The file is stat()ed before it is opened (a FIFO would block in open); read 1 MiB at a time; a
// zstd stream goes through ZSTD_decompressStream, whose output buffer holds a whole block, so the
// output of an input piece is drained once that piece is consumed (zstd's streaming contract).
void stream_file(const std::string& path, const std::function<bool(const char*, std::size_t)>& consume) {
  const std::uint64_t size = regular_file_size(path, "input");
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) fail_at(path, 0, std::string("cannot open file: ") + std::strerror(errno));
  std::vector<char> in(kInputChunk), out;
  ZstdStream ds(nullptr, &ZSTD_freeDStream);
  std::uint64_t total = 0;
  std::size_t ret = 0;  // the decompressor's last hint: 0 at the end of a frame
  for (;;) {
    const std::size_t n = std::fread(in.data(), 1, in.size(), f.get());
    if (std::ferror(f.get())) fail_at(path, 0, std::string("read error: ") + std::strerror(errno));
    total += n;
    if (total > size) fail_at(path, 0, "the file changed size while it was read");
    if (n == 0) break;
    if (total == n && starts_zstd(in.data(), n)) {
      ds.reset(ZSTD_createDStream());
      if (!ds) fail_at(path, 0, "zstd: out of memory");
      ZSTD_initDStream(ds.get());
      out.resize(ZSTD_DStreamOutSize());
    }
    if (!ds) {
      if (!consume(in.data(), n)) return;
      continue;
    }
    ZSTD_inBuffer ib{in.data(), n, 0};
    while (ib.pos < ib.size) {
      ZSTD_outBuffer ob{out.data(), out.size(), 0};
      ret = ZSTD_decompressStream(ds.get(), &ob, &ib);
      if (ZSTD_isError(ret)) fail_at(path, 0, std::string("zstd: ") + ZSTD_getErrorName(ret));
      if (ob.pos && !consume(out.data(), ob.pos)) return;
    }
  }
  if (total != size) fail_at(path, 0, "the file changed size while it was read");
  if (ds && ret != 0) fail_at(path, 0, "truncated zstd stream (the compressed file ends mid-frame)");
}

std::vector<char> maybe_decompress(const std::string& name, std::vector<char> data) {
  if (is_zstd(data)) return decompress(name, data);
  return data;
}

std::vector<char> read_file(const std::string& path) { return maybe_decompress(path, read_raw(path)); }

}  // namespace mbvh

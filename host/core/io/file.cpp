// SPDX-License-Identifier: MIT
// file.cpp — whole-file reads with transparent zstd decompression (libzstd streaming API), both
// bounded by the memory budget before anything is allocated.
#include <zstd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <memory>

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

bool is_zstd(const std::vector<char>& d) {
  static const unsigned char magic[4] = {0x28, 0xB5, 0x2F, 0xFD};
  return d.size() >= 4 && std::memcmp(d.data(), magic, 4) == 0;
}

std::vector<char> decompress(const std::string& path, const std::vector<char>& in) {
  std::unique_ptr<ZSTD_DStream, std::size_t (*)(ZSTD_DStream*)> ds(ZSTD_createDStream(), &ZSTD_freeDStream);
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

std::vector<char> maybe_decompress(const std::string& name, std::vector<char> data) {
  if (is_zstd(data)) return decompress(name, data);
  return data;
}

std::vector<char> read_file(const std::string& path) { return maybe_decompress(path, read_raw(path)); }

}  // namespace mbvh

// file.cpp — whole-file reads with transparent zstd decompression (libzstd streaming API).
#include <zstd.h>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <memory>

#include "host/error.h"
#include "host/scene.h"

namespace mbvh {

void fail_at(const std::string& file, std::size_t line, const std::string& message) {
  if (line == 0) throw Error(file + ": " + message);
  throw Error(file + ":" + std::to_string(line) + ": " + message);
}

namespace {

std::vector<char> read_raw(const std::string& path) {
  std::unique_ptr<FILE, int (*)(FILE*)> f(std::fopen(path.c_str(), "rb"), &std::fclose);
  if (!f) fail_at(path, 0, std::string("cannot open file: ") + std::strerror(errno));
  std::vector<char> data;
  char buf[1 << 16];
  std::size_t n;
  while ((n = std::fread(buf, 1, sizeof buf, f.get())) > 0) data.insert(data.end(), buf, buf + n);
  if (std::ferror(f.get())) fail_at(path, 0, "read error");
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
  // The frame header's content size is only a hint: a corrupt header may claim terabytes (found
  // by fuzzing), so reserve no more than a plausible ratio of the input; the vector grows past it.
  const unsigned long long hint = ZSTD_getFrameContentSize(in.data(), in.size());
  if (hint != ZSTD_CONTENTSIZE_UNKNOWN && hint != ZSTD_CONTENTSIZE_ERROR)
    out.reserve(static_cast<std::size_t>(std::min<unsigned long long>(hint, 64ull * in.size() + (1u << 20))));
  ZSTD_inBuffer ib{in.data(), in.size(), 0};
  std::vector<char> chunk(ZSTD_DStreamOutSize());
  std::size_t ret = 0;
  bool full = false;
  while (ib.pos < ib.size || full) {  // a full output buffer may hold more: call again
    ZSTD_outBuffer ob{chunk.data(), chunk.size(), 0};
    ret = ZSTD_decompressStream(ds.get(), &ob, &ib);
    if (ZSTD_isError(ret)) fail_at(path, 0, std::string("zstd: ") + ZSTD_getErrorName(ret));
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

// SPDX-License-Identifier: MIT
// fuzz_mlod.cpp — libFuzzer target for the .mlod reader and block cache (host/core/lod/cache.h):
// any bytes either open (and then every block loads or is recorded damaged, with the cache's
// rules kept: peak within the budget, a resident block's parent resident) or throw mbvh::Error;
// a crash, hang, leak, huge allocation or sanitizer report is a bug. Each input is tried twice:
// as it is, and with its checksums and file_bytes made right (the header's, the albedo table's,
// each block's whose zstd frame decompresses, the directory's), so that mutations reach the
// structural checks behind the checksums (check_block) instead of stopping at the first hash. The
// input is also checked as one raw block (check_block against a fixed header and directory: block
// 0 the root, blocks 1..3 its children), so that mutations of a block's records are not lost in
// its compression (the seeds include raw blocks).
#include <unistd.h>
#include <zstd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "host/core/layouts.h"  // hash_bytes
#include "host/core/lod/cache.h"
#include "mbvh/error.h"

namespace {

using namespace mbvh::lod;
using namespace mbvh::lod::format;

void write_file(const std::string& path, const std::string& bytes) {
  FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) __builtin_trap();
  if (!bytes.empty() && std::fwrite(bytes.data(), 1, bytes.size(), f) != bytes.size()) __builtin_trap();
  std::fclose(f);
}

void check_rules(const BlockCache& c) {
  const auto& dir = c.directory();
  for (std::uint32_t b = 0; b < dir.size(); ++b) {
    if ((dir[b].flags & kDirPinned) && !c.resident(b)) __builtin_trap();
    if (c.resident(b) && b != c.header().root_block && !c.resident(dir[b].parent_block)) __builtin_trap();
  }
  const mbvh::lod::CacheStats s = c.stats();
  if (s.peak_bytes > s.budget || s.resident_bytes > s.budget) __builtin_trap();
}

void exercise(const std::string& path, const std::string& bytes, bool async) {
  write_file(path, bytes);
  try {
    mbvh::lod::CacheOptions o;
    o.memory_budget = 0;  // the file's raw bytes
    o.io_threads = 1;
    o.direct_io = false;
    BlockCache c(path, o);
    const std::uint32_t n = static_cast<std::uint32_t>(c.directory().size());
    // Coarse first: a block can load once its parent is resident, so a round per directory level.
    for (unsigned round = 0; round < 64; ++round) {
      const std::uint64_t before = c.stats().loads + c.damaged().size();
      for (std::uint32_t b = 0; b < n; ++b) c.get(b);
      if (async) {
        c.end_frame();
        c.wait_idle();
      } else {
        c.fetch_requested(false);
      }
      check_rules(c);
      if (c.stats().loads + c.damaged().size() == before) break;
    }
  } catch (const mbvh::Error&) {
  }
}

/// The input with its checksums and file_bytes made right where the regions they cover are in it.
std::string with_checksums(std::string s) {
  FileHeader h;
  if (s.size() < sizeof h) return s;
  std::memcpy(&h, s.data(), sizeof h);
  h.file_bytes = s.size();
  const std::uint64_t size = s.size();
  const bool dir_ok = h.blocks <= size / sizeof(DirEntry) && h.directory_offset <= size &&
                      h.blocks * sizeof(DirEntry) + 8 <= size - h.directory_offset;
  if (dir_ok && h.blocks > 0) {  // each block's checksum from its decompressed bytes, when its frame is small and sound
    std::vector<DirEntry> dir(h.blocks);
    std::memcpy(dir.data(), s.data() + h.directory_offset, dir.size() * sizeof(DirEntry));
    std::vector<char> raw;
    for (std::uint64_t b = 0; b < dir.size(); ++b) {
      DirEntry& e = dir[b];
      if (e.offset > size || e.stored_bytes > size - e.offset) continue;
      const unsigned long long content = ZSTD_getFrameContentSize(s.data() + e.offset, e.stored_bytes);
      if (content == ZSTD_CONTENTSIZE_ERROR || content == ZSTD_CONTENTSIZE_UNKNOWN || content != e.raw_bytes ||
          content > (4u << 20))
        continue;
      raw.resize(content ? content : 1);
      const std::size_t got = ZSTD_decompress(raw.data(), content, s.data() + e.offset, e.stored_bytes);
      if (!ZSTD_isError(got) && got == content) e.checksum = mbvh::hash_bytes(raw.data(), got, b);
    }
    std::memcpy(s.data() + h.directory_offset, dir.data(), dir.size() * sizeof(DirEntry));
  }
  h.checksum = mbvh::hash_bytes(&h, offsetof(FileHeader, checksum));
  std::memcpy(s.data(), &h, sizeof h);
  if (h.albedo_offset <= size && h.albedos <= (size - h.albedo_offset) / 12 &&
      std::uint64_t(h.albedos) * 12 + 8 <= size - h.albedo_offset) {
    const std::uint64_t sum = mbvh::hash_bytes(s.data() + h.albedo_offset, std::size_t(h.albedos) * 12, h.checksum);
    std::memcpy(s.data() + h.albedo_offset + std::uint64_t(h.albedos) * 12, &sum, 8);
  }
  if (dir_ok && h.blocks > 0) {
    const std::uint64_t sum = mbvh::hash_bytes(s.data() + h.directory_offset, h.blocks * sizeof(DirEntry), h.checksum);
    std::memcpy(s.data() + h.directory_offset + h.blocks * sizeof(DirEntry), &sum, 8);
  }
  return s;
}

/// The input as raw block 0 of a model of 4 blocks, 2^20 triangles and 2 albedos.
void check_raw_block(const std::string& path, const std::string& bytes) {
  FileHeader h{};
  h.triangles = 1u << 20;
  h.albedos = 2;
  h.blocks = 4;
  std::vector<DirEntry> dir(4);
  for (std::uint32_t b = 0; b < 4; ++b) dir[b].parent_block = 0, dir[b].depth = b ? 1 : 0;
  dir[0].raw_bytes = static_cast<std::uint32_t>(bytes.size());
  std::vector<std::byte> raw(bytes.size() + 1);  // not aligned: check_block copies what it reads
  std::memcpy(raw.data() + 1, bytes.data(), bytes.size());
  try {
    check_block(path, h, dir, 0, raw.data() + 1, bytes.size());
  } catch (const mbvh::Error&) {
  }
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const struct Temp {
    std::string path = "/tmp/fuzz-mlod-" + std::to_string(::getpid()) + ".mlod";
    ~Temp() { ::unlink(path.c_str()); }
  } temp;
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  check_raw_block(temp.path, bytes);
  exercise(temp.path, bytes, false);
  exercise(temp.path, with_checksums(bytes), size % 2 == 1);
  return 0;
}

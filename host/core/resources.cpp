// SPDX-License-Identifier: MIT
// resources.cpp — the memory budget (MBVH_MEMORY_LIMIT, /proc/meminfo, sysconf), memory estimates,
// the regular-file check for inputs, the allocator's release and the huge-page advice (huge_pages.h).
#include "host/core/resources.h"

#include <sys/mman.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>
#if defined(__GLIBC__)
#include <malloc.h>
#endif

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <string>

#include "host/core/huge_pages.h"
#include "mbvh/error.h"

namespace mbvh {

bool parse_size(std::string_view text, std::uint64_t& bytes) {
  const char* const begin = text.data();
  const char* const end = begin + text.size();
  std::uint64_t v = 0;
  const auto r = std::from_chars(begin, end, v);
  if (r.ec != std::errc() || r.ptr == begin) return false;
  int shift = 0;
  if (r.ptr + 1 == end) {
    switch (*r.ptr) {
      case 'K': case 'k': shift = 10; break;
      case 'M': case 'm': shift = 20; break;
      case 'G': case 'g': shift = 30; break;
      case 'T': case 't': shift = 40; break;
      default: return false;
    }
  } else if (r.ptr != end) {
    return false;
  }
  if (v == 0 || (shift > 0 && v > (UINT64_MAX >> shift))) return false;
  bytes = v << shift;
  return true;
}

namespace {

// MBVH_MEMORY_LIMIT: a size (parse_size); 0 if unset.
std::uint64_t limit_from_env() {
  const char* env = std::getenv("MBVH_MEMORY_LIMIT");
  if (!env || !*env) return 0;
  std::uint64_t v = 0;
  if (!parse_size(env, v))
    throw Error(std::string("MBVH_MEMORY_LIMIT=") + env + " is not a size (use bytes or a K, M, G or T suffix, e.g. 8G)");
  return v;
}

// MemAvailable in bytes, 0 when /proc/meminfo lacks it.
std::uint64_t mem_available() {
  std::ifstream f("/proc/meminfo");
  std::string key, unit;
  std::uint64_t kib = 0;
  while (f >> key >> kib) {
    std::getline(f, unit);
    if (key == "MemAvailable:") return kib * 1024;
  }
  return 0;
}

// The address space an address-space limit (RLIMIT_AS, ulimit -v) leaves: the limit less the
// process's VmSize; UINT64_MAX without a limit.
std::uint64_t address_space_left() {
  rlimit rl {};
  if (getrlimit(RLIMIT_AS, &rl) != 0 || rl.rlim_cur == RLIM_INFINITY) return UINT64_MAX;
  std::ifstream f("/proc/self/status");
  std::string key, unit;
  std::uint64_t kib = 0;
  while (f >> key) {
    if (key == "VmSize:" && f >> kib) break;
    std::getline(f, unit);
  }
  const std::uint64_t used = kib * 1024;
  return used < rl.rlim_cur ? rl.rlim_cur - used : 0;
}

MemoryBudget system_budget() {
  if (const std::uint64_t avail = mem_available()) return {avail, "MemAvailable in /proc/meminfo; set MBVH_MEMORY_LIMIT to change"};
  // no /proc (a POSIX system other than Linux): the physical memory, where sysconf can say it
  // (_SC_PHYS_PAGES is an extension: Linux, the BSDs, macOS); else no limit but the caller's
#ifdef _SC_PHYS_PAGES
  const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
  if (pages > 0 && page > 0)
    return {static_cast<std::uint64_t>(pages) * static_cast<std::uint64_t>(page),
            "physical memory; set MBVH_MEMORY_LIMIT to change"};
#endif
  return {UINT64_MAX, "unknown; set MBVH_MEMORY_LIMIT to bound it"};
}

}  // namespace

MemoryBudget memory_budget() {
  if (const std::uint64_t env = limit_from_env()) return {env, "MBVH_MEMORY_LIMIT"};
  const MemoryBudget b = system_budget();
  if (const std::uint64_t as = address_space_left(); as < b.bytes)
    return {as, "the address-space limit (ulimit -v) less what the process has mapped"};
  return b;
}

void throw_out_of_memory(const std::string& what, std::uint64_t bytes) {
  std::string budget;
  try {
    const MemoryBudget b = memory_budget();
    budget = ", though within the " + format_bytes(b.bytes) + " the estimates allowed (" + b.source + ")";
  } catch (const Error&) {
  }
  throw Error(what + ": out of memory: " + (bytes ? "allocating about " + format_bytes(bytes) : std::string("an allocation")) +
              " failed (the system refused it: an address-space or cgroup limit, or memory taken by others" + budget + ")");
}

void require_memory(const std::string& what, std::uint64_t bytes, const std::string& how, const MemoryBudget& b) {
  if (bytes <= b.bytes) return;
  throw Error(what + ": needs about " + format_bytes(bytes) + " of memory (" + how + "), more than the " +
              format_bytes(b.bytes) + " available (" + b.source + ")");
}

std::uint64_t build_memory_estimate(std::uint64_t triangles, std::uint64_t vertices) {
  triangles = std::min(triangles, UINT64_MAX / 1024);  // no overflow for any count
  vertices = std::min(vertices, UINT64_MAX / 1024);
  return 128 * triangles + 56 * vertices;
}

std::uint64_t scene_memory_estimate(std::uint64_t triangles, std::uint64_t vertices) {
  triangles = std::min(triangles, UINT64_MAX / 1024);
  vertices = std::min(vertices, UINT64_MAX / 1024);
  return 12 * vertices + 12 * triangles + build_memory_estimate(triangles, vertices);
}

namespace {
std::atomic<unsigned> g_build_share{1};
}  // namespace

ScopedBuildShare::ScopedBuildShare(unsigned parts) : previous_(g_build_share.exchange(std::max(parts, 1u))) {}
ScopedBuildShare::~ScopedBuildShare() { g_build_share.store(previous_); }

unsigned build_share() { return g_build_share.load(); }

std::uint64_t loading_build_estimate(std::uint64_t triangles, std::uint64_t vertices) {
  const std::uint64_t whole = build_memory_estimate(triangles, vertices), parts = build_share();
  return whole / parts + (whole % parts != 0);
}

std::uint64_t regular_file_size(const std::string& path, const std::string& what) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) fail_at(path, 0, "cannot open " + what + " file: " + std::strerror(errno));
  const char* kind = S_ISDIR(st.st_mode)    ? "a directory"
                     : S_ISFIFO(st.st_mode) ? "a FIFO (named pipe)"
                     : S_ISSOCK(st.st_mode) ? "a socket"
                     : S_ISCHR(st.st_mode)  ? "a character device"
                     : S_ISBLK(st.st_mode)  ? "a block device"
                     : S_ISREG(st.st_mode)  ? nullptr
                                            : "an unusual kind of file";
  if (kind) fail_at(path, 0, "is " + std::string(kind) + ", not a regular " + what + " file");
  return static_cast<std::uint64_t>(st.st_size);
}

std::string format_bytes(std::uint64_t bytes) {
  static const char* const units[] = {"KiB", "MiB", "GiB", "TiB", "PiB", "EiB"};
  if (bytes < 1024) return std::to_string(bytes) + " bytes";
  double v = static_cast<double>(bytes) / 1024;
  int u = 0;
  while (v >= 1024 && u < 5) { v /= 1024; ++u; }
  char buf[32];
  std::snprintf(buf, sizeof buf, v < 10 ? "%.1f %s" : "%.0f %s", v, units[u]);
  return buf;
}

void release_free_heap() {
#if defined(__GLIBC__)
  malloc_trim(0);
#endif
}

#if defined(__linux__) && defined(MADV_HUGEPAGE)
namespace {
// The transparent huge page's size where advice can take effect, else 0: THP not "never", the
// kernel's PMD page size (2 MiB on x86-64; 512 MiB on aarch64 with 64 KiB pages, where arrays
// rarely hold a whole one), and MBVH_HUGE_PAGES not 0 (the user's opt-out). Read once.
std::uintptr_t huge_page_size() {
  static const std::uintptr_t size = [] {
    if (const char* env = std::getenv("MBVH_HUGE_PAGES"); env && std::strcmp(env, "0") == 0) return std::uintptr_t(0);
    std::ifstream mode("/sys/kernel/mm/transparent_hugepage/enabled");
    std::string line;
    if (!std::getline(mode, line) || line.find("[never]") != std::string::npos) return std::uintptr_t(0);
    std::ifstream pmd("/sys/kernel/mm/transparent_hugepage/hpage_pmd_size");
    unsigned long long v = 0;
    if (!(pmd >> v) || v < 4096 || (v & (v - 1)) != 0) return std::uintptr_t(0);
    return static_cast<std::uintptr_t>(v);
  }();
  return size;
}
}  // namespace
#endif

void advise_huge_pages(const void* p, std::size_t bytes) {
#if defined(__linux__) && defined(MADV_HUGEPAGE)
  const std::uintptr_t huge = huge_page_size();
  if (!p || huge == 0 || bytes < huge) return;
  const auto a = reinterpret_cast<std::uintptr_t>(p);
  const std::uintptr_t lo = (a + huge - 1) & ~(huge - 1), hi = (a + bytes) & ~(huge - 1);
  if (hi > lo) (void)madvise(reinterpret_cast<void*>(lo), hi - lo, MADV_HUGEPAGE);
#else
  (void)p;
  (void)bytes;
#endif
}

void release_free_heap_above(std::uint64_t bytes) {
#if defined(__GLIBC__) && (__GLIBC__ > 2 || (__GLIBC__ == 2 && __GLIBC_MINOR__ >= 33))
  // the lowest free heap seen since the last release (the first call's is its own): a heuristic
  // shared by every thread, so a race between two builds costs at most one release
  static std::atomic<std::uint64_t> low{UINT64_MAX};
  const std::uint64_t now = mallinfo2().fordblks;
  std::uint64_t was = low.load(std::memory_order_relaxed);
  if (was == UINT64_MAX || now <= was) {
    low.store(now, std::memory_order_relaxed);
    return;
  }
  if (now - was <= bytes) return;
  malloc_trim(0);
  low.store(mallinfo2().fordblks, std::memory_order_relaxed);
#else
  (void)bytes;
  release_free_heap();
#endif
}

}  // namespace mbvh

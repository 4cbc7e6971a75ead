// SPDX-License-Identifier: MIT
// resources.h — bounded resources: the memory a command may use, estimated before allocating, and
// the checks that refuse an input which is not a regular file (a FIFO would block, /dev/zero never ends).
#pragma once
#include <cstdint>
#include <new>
#include <string>
#include <string_view>

namespace mbvh {

/// A positive size: bytes, or with a K, M, G or T suffix (powers of 1024), e.g. "512M", "8G".
/// False (and `bytes` untouched) for anything else, 0 and a value that overflows 64 bits.
bool parse_size(std::string_view text, std::uint64_t& bytes);

/// The memory a command may plan to use and where that number came from.
struct MemoryBudget {
  std::uint64_t bytes = 0;
  const char* source = "";  ///< for messages: "MBVH_MEMORY_LIMIT", "MemAvailable in /proc/meminfo; ..."
};

/// MBVH_MEMORY_LIMIT when set (bytes, or with a K, M, G or T suffix, powers of 1024), else
/// MemAvailable from /proc/meminfo, else the physical memory (sysconf); without MBVH_MEMORY_LIMIT,
/// no more than the address space an address-space limit (ulimit -v) leaves unmapped. Read at every call (a few
/// microseconds): take it once before allocating, as MemAvailable falls with every allocation.
/// Throws Error on a malformed MBVH_MEMORY_LIMIT.
MemoryBudget memory_budget();

/// Throws Error "WHAT: needs about X of memory (HOW), more than the Y available (SOURCE)" when
/// `bytes` exceeds `budget`; allocates nothing.
void require_memory(const std::string& what, std::uint64_t bytes, const std::string& how,
                    const MemoryBudget& budget = memory_budget());

/// Throws Error "WHAT: out of memory: allocating about X failed (...)": what a std::bad_alloc
/// becomes, naming what was being allocated and how much (0: not known), and the budget the
/// estimates allowed.
[[noreturn]] void throw_out_of_memory(const std::string& what, std::uint64_t bytes);

/// Runs `fn`, turning a std::bad_alloc out of it into throw_out_of_memory(what, bytes): wraps the
/// big allocations (scene, build, ray and hit arrays), whose estimates passed the budget but which
/// the system still refused (ulimit -v, a cgroup, memory taken since).
template <class F>
decltype(auto) allocating(const std::string& what, std::uint64_t bytes, F&& fn) {
  try {
    return fn();
  } catch (const std::bad_alloc&) {
    throw_out_of_memory(what, bytes);
  }
}

/// Returns the allocator's free memory to the system (glibc: malloc_trim; elsewhere nothing), so
/// what a build's temporaries occupied stops counting as resident: glibc's dynamic mmap threshold
/// otherwise serves them from the heap, which keeps their pages after they are freed. Called once a
/// build, a load or a structure made on first use has freed its temporaries. O(free heap).
void release_free_heap();

/// release_free_heap() once the allocator's freed memory has grown by more than `bytes` since its
/// lowest point after the last release (glibc 2.33 and later: mallinfo2's free bytes, process-wide;
/// elsewhere it always releases). Called after a build with about one build's worth
/// (build_memory_estimate): the next build of that size reuses the pages the last one freed
/// instead of faulting fresh ones in, and what the process keeps beyond its live arrays grows by
/// at most about one build between releases (glibc's heap does grow over repeated builds: blocks
/// freed in one order are not always taken back in the next, so new pages are touched).
void release_free_heap_above(std::uint64_t bytes);

/// Bytes one build of a scene costs beyond the scene (the builder's references, the BVH2 and the
/// MBVH2, MBVH4 and MBVH8 layouts): 128 a triangle and 56 a vertex, fitted to the peak RSS of
/// `mbvh info` on gen:hairball (0.53 vertices a triangle, 155 B a triangle in all) and gen:soup
/// (3 vertices a triangle, 293 B a triangle) at 1M and 2M triangles.
std::uint64_t build_memory_estimate(std::uint64_t triangles, std::uint64_t vertices);
/// Bytes a scene of `triangles` triangles and `vertices` vertices costs, itself (12 bytes a
/// vertex, 12 a triangle) and through one build.
std::uint64_t scene_memory_estimate(std::uint64_t triangles, std::uint64_t vertices);

/// The build share: how many processes will each build one part of the scene being loaded. A
/// data-parallel program (mbvh::mpi, load_scene_part) loads the whole scene in every process but
/// builds only 1/parts of it there, so its memory checks must count the scene and 1/parts of one
/// build; everything else loads with the default, 1 (the whole build). Process-wide while an
/// object lives (scoped; nested objects restore the share before them): it applies to every load
/// in the process meanwhile, on any thread, so set it around one load, not while other threads
/// load scenes of their own.
class ScopedBuildShare {
public:
  explicit ScopedBuildShare(unsigned parts);  ///< parts 0 counts as 1
  ~ScopedBuildShare();
  ScopedBuildShare(const ScopedBuildShare&) = delete;
  ScopedBuildShare& operator=(const ScopedBuildShare&) = delete;

private:
  unsigned previous_;
};
/// The build share now in force (1 unless a ScopedBuildShare lives).
unsigned build_share();
/// What loading a scene counts for the build that follows it: build_memory_estimate divided by
/// build_share(), rounded up. load_scene, the OBJ parser and the generators check this, so the
/// plain program (share 1) counts the whole build as before.
std::uint64_t loading_build_estimate(std::uint64_t triangles, std::uint64_t vertices);

/// The size of the regular file at `path`, without opening it; throws Error naming the path and
/// `what` (e.g. "scene", "ray") when it cannot be examined or is a directory, FIFO, socket or
/// device: opening a FIFO blocks until a writer comes and a device may never end.
std::uint64_t regular_file_size(const std::string& path, const std::string& what);

/// "1.5 GiB", "12 MiB", "300 bytes": for messages.
std::string format_bytes(std::uint64_t bytes);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// parallel.h — the one threading primitive of mbvh: a blocking parallel loop over index chunks,
// run on a persistent worker pool (no thread is created per call). Chunks are claimed
// dynamically, so results that must be deterministic may depend only on the chunk index, never
// on which worker ran it. A call from inside a running parallel_for runs inline on its thread.
#pragma once
#include <cstddef>
#include <functional>

namespace mbvh {

/// The most worker threads mbvh starts (`--threads` takes 0..kMaxThreads); a larger request is
/// clamped to it, so any value is safe (per-thread arithmetic never overflows).
inline constexpr unsigned kMaxThreads = 1024;
/// Rays per work item of the trace batch drivers (a packet driver's chunks hold whole packets).
inline constexpr std::size_t kTraceChunk = 2048;

/// Number of worker threads to use for a request of `threads` (0 = every hardware thread), in
/// [1, kMaxThreads].
unsigned resolve_threads(unsigned threads);

/// Calls fn(begin, end, worker) for consecutive chunks of [0, n) of size `grain` (the last may be
/// shorter) on up to `threads` workers (0 = all hardware threads); returns when all are done.
/// The first exception thrown by fn is rethrown on the calling thread.
void parallel_for(std::size_t n, std::size_t grain, unsigned threads,
                  const std::function<void(std::size_t, std::size_t, unsigned)>& fn);

}  // namespace mbvh

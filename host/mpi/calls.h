// SPDX-License-Identifier: MIT
// calls.h — how host/mpi calls MPI: every call timed and its bytes counted into a Traffic (the
// share `mbvh-mpi bench` reports), a failure turned into Error naming the call, and byte counts
// checked against MPI's int counts.
#pragma once
#include <mpi.h>

#include <climits>
#include <cstdint>
#include <string>

#include "mbvh/error.h"
#include "mbvh/mpi.h"

namespace mbvh::mpi::detail {

/// Runs `fn` (an MPI call returning its error code), adding its wall time, `sent` and `received`
/// bytes and one call to `t` (may be null); throws Error "MPI: WHAT failed: ..." on an error code.
template <class F>
void call(Traffic* t, const char* what, std::uint64_t sent, std::uint64_t received, F&& fn) {
  const double t0 = MPI_Wtime();
  const int rc = fn();
  if (t) {
    t->seconds += MPI_Wtime() - t0;
    t->bytes_sent += sent;
    t->bytes_received += received;
    ++t->calls;
  }
  if (rc != MPI_SUCCESS) {
    char msg[MPI_MAX_ERROR_STRING] = {};
    int len = 0;
    MPI_Error_string(rc, msg, &len);
    std::string hint;
    if (std::string(what).find("MPI_Win_allocate") != std::string::npos)
      hint = " (a window's memory: with MPI_Win_allocate_shared, shared memory (/dev/shm) must hold the rays and "
             "answers, 48 bytes a ray; mbvh-mpi's --no-shared-memory --schedule static sends messages instead)";
    throw Error(std::string("MPI: ") + what + " failed: " + std::string(msg, static_cast<std::size_t>(len)) + hint);
  }
}

/// `n` as an MPI count; throws Error naming `what` beyond INT_MAX (MPI counts are int: larger
/// messages go in pieces, or as larger datatypes).
inline int count(std::uint64_t n, const char* what) {
  if (n > static_cast<std::uint64_t>(INT_MAX))
    throw Error(std::string("MPI: ") + what + ": " + std::to_string(n) + " elements exceed MPI's int count");
  return static_cast<int>(n);
}

}  // namespace mbvh::mpi::detail

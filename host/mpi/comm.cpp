// SPDX-License-Identifier: MIT
// comm.cpp — mbvh::mpi's communicator and schedule names (mbvh/mpi.h).
#include "host/mpi/calls.h"
#include "mbvh/mpi.h"

namespace mbvh::mpi {

int Comm::rank() const {
  int r = 0;
  MPI_Comm_rank(comm, &r);
  return r;
}

int Comm::size() const {
  int n = 1;
  MPI_Comm_size(comm, &n);
  return n;
}

const char* to_string(Schedule s) { return s == Schedule::dynamic ? "dynamic" : "static"; }

Schedule parse_schedule(const std::string& s) {
  if (s == "static") return Schedule::static_batches;
  if (s == "dynamic") return Schedule::dynamic;
  throw Error("unknown schedule '" + s + "' (known: static, dynamic)");
}

}  // namespace mbvh::mpi

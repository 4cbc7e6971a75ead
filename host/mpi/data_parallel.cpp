// SPDX-License-Identifier: MIT
// data_parallel.cpp — placeholder until the data-parallel mode lands (branch dp).
#include "mbvh/error.h"
#include "mbvh/mpi.h"

namespace mbvh::mpi {
Scene load_scene_part(const std::string& p, unsigned) { return load_scene(p); }
Part partition(const Comm&, const Scene&, const BuildOptions&, Traffic*) { throw Error("data-parallel: not yet"); }
void trace_data_parallel(const Comm&, Backend&, const Part&, std::span<const Ray>, const TraceOptions&, TraceOutput&, Traffic*) {
  throw Error("data-parallel: not yet");
}
ForwardStats last_forward_stats() { return {}; }
}  // namespace mbvh::mpi

// SPDX-License-Identifier: MIT
// mpi_trace.cpp — mbvh::mpi from a program of one's own (mpirun -np P mpi_trace): every rank makes
// the same scene, rank 0 builds its BVH once and the others read that build (mbvh::mpi::shared_accel),
// rank 0's rays are traced over all ranks (mbvh::mpi::trace), and rank 0 checks that the answers are
// bit for bit those of one process. Links mbvh::mpi and mbvh::cpu (find_package(mbvh COMPONENTS cpu mpi)).
#include <mpi.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <vector>

#include <mbvh/backends.h>
#include <mbvh/mbvh.h>
#include <mbvh/mpi.h>

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  int status = 0;
  try {
    mbvh::register_cpu_backends();
    const mbvh::mpi::Comm comm;  // MPI_COMM_WORLD
    const mbvh::Scene scene = mbvh::load_scene("gen:sphere:64");
    auto accel = mbvh::mpi::shared_accel(comm, scene, {}, {});  // no cache directory: a private one
    auto cpu = mbvh::make_backend("cpu");
    std::vector<mbvh::Ray> rays;  // on rank 0: a fan of rays from outside the sphere
    if (comm.root())
      for (int i = 0; i < 100000; ++i) {
        const float a = 0.0001f * static_cast<float>(i);
        rays.push_back({3 * std::cos(a), 3 * std::sin(a), 0.5f, 0, -std::cos(a), -std::sin(a), 0.1f, INFINITY});
      }
    mbvh::TraceOutput out;
    mbvh::mpi::trace(comm, *cpu, *accel, rays, {}, out, {mbvh::mpi::Schedule::dynamic, 8192});
    if (comm.root()) {
      mbvh::TraceOutput one;  // one process, for comparison
      cpu->trace(*accel, rays, {}, one);
      const bool same = std::memcmp(out.hits.data(), one.hits.data(), rays.size() * sizeof(mbvh::Hit)) == 0;
      std::printf("%zu rays on %d ranks: %s one process's answers\n", rays.size(), comm.size(), same ? "bit for bit" : "NOT");
      status = same ? 0 : 1;
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "mpi_trace: error: %s\n", e.what());
    MPI_Abort(MPI_COMM_WORLD, 2);
  }
  MPI_Bcast(&status, 1, MPI_INT, 0, MPI_COMM_WORLD);
  MPI_Finalize();
  return status;
}

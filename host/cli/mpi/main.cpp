// SPDX-License-Identifier: MIT
// placeholder: the mbvh-mpi program is being written
#include <mpi.h>
int main(int argc, char** argv) { MPI_Init(&argc, &argv); MPI_Finalize(); return 0; }

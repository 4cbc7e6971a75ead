// SPDX-License-Identifier: MIT
// data_parallel.cpp — placeholder; being written (partition, trace_data_parallel, load_scene_part).
#include "mbvh/mpi.h"

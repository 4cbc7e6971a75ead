// SPDX-License-Identifier: MIT
// replicated.cpp — placeholder; being written (shared_accel, trace).
#include "mbvh/mpi.h"

// SPDX-License-Identifier: MIT
// register.cpp — mbvh::cpu's registration entry point (mbvh/backends.h).
#include "backends/cpu/cpu_backends.h"
#include "mbvh/backends.h"

namespace mbvh {

void register_cpu_backends() {
  register_cpu_scalar_backend();
  register_cpu_simd_backends();
}

}  // namespace mbvh

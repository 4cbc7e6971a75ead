// SPDX-License-Identifier: MIT
// cpu_backends.h — the CPU backends' registration entry points and the per-ISA kernel table.
#pragma once
#include <span>

#include "mbvh/trace.h"

namespace mbvh {

/// One ISA's compiled kernels (backends/cpu/simd_kernels.cpp, built once per ISA). Only call
/// `trace` after CPUID says the ISA is there.
struct CpuKernels {
  const char* isa;
  void (*trace)(const Accel&, std::span<const Ray>, const TraceOptions&, TraceOutput&, unsigned threads);
};

void register_cpu_scalar_backend();
void register_cpu_simd_backends();

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// cpu_backends.h — the CPU backends' registration entry points and the per-ISA kernel table.
#pragma once
#include <span>

#include "mbvh/backend.h"
#include "mbvh/trace.h"

namespace mbvh {

/// One ISA's compiled kernels (backends/cpu/isa_kernels.cpp, built once per ISA). Only call
/// `trace` after CPUID says the ISA is there.
struct CpuKernels {
  const char* isa;
  /// hybrid: the packet traversals trace an incoherent packet ray by ray (the `cpu.packet-hybrid`
  /// setting; off: every packet as a packet, for tests and measurements).
  void (*trace)(const Accel&, std::span<const Ray>, const TraceOptions&, TraceOutput&, unsigned threads, bool hybrid);
};

/// The cpu family's `cpu.leaf-block` setting: the leaf block (TraceOptions::leaf_block) a cpu
/// backend traces when a call leaves it 0 — `fallback` (4 on the SIMD backends, 1 on cpu-scalar)
/// when not set. Throws Error naming the setting and value outside 1 to 64.
unsigned cpu_leaf_block(const BackendOptions& o, unsigned fallback);
/// Its declaration (BackendInfo::settings), with the backend's default in the help text.
BackendSetting cpu_leaf_block_setting(const char* fallback);

/// The cpu family's `cpu.packet-hybrid` setting (the packet traversals' hybrid switch; read by the
/// SIMD backends, accepted by cpu-scalar, which traces every ray alone), `note` appended to its help.
BackendSetting cpu_packet_hybrid_setting(const char* note = "");

void register_cpu_scalar_backend();
void register_cpu_simd_backends();

}  // namespace mbvh

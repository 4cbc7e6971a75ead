// SPDX-License-Identifier: MIT
// cpu_backends.h — the CPU backends' registration entry points and the per-ISA kernel table.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>
#include <span>
#include <string>

#include "mbvh/backend.h"
#include "mbvh/trace.h"

namespace mbvh {

/// The dacrt backends' settings (BackendOptions `dacrt.*`, backends/cpu/dacrt_backend.cpp): how
/// the recursion of divide-and-conquer ray tracing (Áfra, EG 2012; backends/cpu/dacrt/) splits
/// the triangles and when it stops. Every value gives exact answers; they trade speed only.
struct DacrtSettings {
  enum class Partition { adaptive, sah, middle };
  Partition partition = Partition::adaptive;  ///< adaptive: SAH where active rays / triangles > ratio, else middle
  float ratio = 8.0f;          ///< the adaptive switch
  unsigned bins = 16;          ///< SAH bins per axis on the centroid bounds
  unsigned leaf_rays = 16;     ///< the naive leaf below this many active rays
  unsigned leaf_tris = 8;      ///< the naive leaf at this many triangles or fewer
  bool ordered = true;         ///< near child first by the first active ray's direction sign
  std::size_t chunk = 262144;  ///< rays per independent task (fixed: answers do not depend on the threads)
};

/// A dacrt kernel's buffers, kept by its backend between trace calls (a call that needs no more
/// than the last one allocates nothing, and touches no fresh page): one per worker and one shared.
struct DacrtScratch {
  virtual ~DacrtScratch() = default;
};
using DacrtBuffers = std::vector<std::unique_ptr<DacrtScratch>>;
/// The SIMD policy's side record of a ray (dacrt/simd.h), for Backend::state_bytes.
constexpr std::size_t kDacrtSimdSideBytes = 40;

/// One ISA's compiled kernels (backends/cpu/isa_kernels.cpp, built once per ISA on x86-64:
/// MBVH_HAVE_CPU_SIMD). Only call `trace` after CPUID says the ISA is there.
struct CpuKernels {
  const char* isa;
  int packet_rays;  ///< rays per packet of the packet traversals (packet/packet.h: kPacketRays)
  int packet_lanes;  ///< lanes per SIMD ray of a packet (8 or 16)
  /// hybrid: the packet traversals trace an incoherent packet ray by ray (the `cpu.packet-hybrid`
  /// setting; off: every packet as a packet, for tests and measurements). mic: the MBVH4 single-ray
  /// traversals test a node in 16 lanes on its Node4W view (`cpu.mic`; the AVX-512 kernels only,
  /// ignored by AVX2's: the backend refuses it there).
  void (*trace)(const Accel&, std::span<const Ray>, const TraceOptions&, TraceOutput&, unsigned threads, bool hybrid,
                bool mic);
  /// Divide-and-conquer ray tracing over acc.tris() (backends/cpu/dacrt/): no hierarchy read.
  void (*dacrt)(const Accel&, std::span<const Ray>, const TraceOptions&, TraceOutput&, unsigned threads,
                const DacrtSettings&, DacrtBuffers&);
  /// The single-ray query (Backend::ray_query) of `closest` and `any` (checked, a single-ray
  /// traversal each, leaf blocks resolved, the build prepared): the views of both resolved now,
  /// the kernels a function each (the traversal fixed for the defaults, default_ray_query_options).
  RayQueryKernels (*ray_query)(const Accel&, const TraceOptions& closest, const TraceOptions& any, bool mic);
  /// The MBVH8 ordered stack's sorted push (simd/kernels.h, SimdKernelsT::push_sorted8: the row of
  /// eight (node, d) entries stored at `entries`, the hits of `mask` first, farthest first), for
  /// its unit test against the insertion sort; null where the ISA has none (AVX2).
  void (*push_sorted8)(void* entries, unsigned mask, const std::int32_t* child, const float* d);
};

/// What `cpu` and `dacrt` run on this machine (backends/cpu/simd_backend.cpp), from the build
/// (MBVH_HAVE_CPU_SIMD), CPUID and MBVH_CPU_ISA (unset, scalar, avx2 or avx512).
struct CpuChoice {
  /// The kernels of the best ISA this CPU has (AVX-512, else AVX2, within MBVH_CPU_ISA's cap);
  /// null: the portable (scalar) kernels, or none (`error`).
  const CpuKernels* kernels = nullptr;
  /// With no kernels: why `cpu` and `dacrt` run the portable kernels of cpu-scalar and
  /// dacrt-scalar ("this CPU has no AVX2 and FMA", "MBVH_CPU_ISA=scalar turns the SIMD kernels
  /// off", a build without them), the text of their notice.
  std::string portable_because;
  /// Set when nothing may run: MBVH_CPU_ISA holds no ISA (a message naming the value).
  std::string error;
};
CpuChoice choose_cpu_kernels();

/// Registers `info` (cpu-scalar's or dacrt-scalar's, named `name`: cpu, dacrt) as a second name
/// of the portable backend `portable`: its summary says so and why (`because`), and every backend
/// it makes logs that once (LogLevel::info, mbvh/log.h): "backend 'cpu' runs cpu-scalar, the
/// portable kernels: this CPU has no AVX2 and FMA".
void register_portable_alias(BackendInfo info, const std::string& portable, const std::string& because);

/// cpu-scalar's registration under `name` (cpu-scalar; cpu where that runs the portable kernels).
BackendInfo cpu_scalar_info(const std::string& name);

/// The portable (scalar) dacrt: the same recursion, box tests and triangle tests one ray at a time
/// (backends/cpu/dacrt_scalar.cpp); the same bytes as the SIMD kernels'.
void dacrt_scalar(const Accel&, std::span<const Ray>, const TraceOptions&, TraceOutput&, unsigned threads,
                  const DacrtSettings&, DacrtBuffers&);

/// The cpu family's `cpu.leaf-block` setting: the leaf block (TraceOptions::leaf_block) a cpu
/// backend traces when a call leaves it 0 — `fallback` (4 on the SIMD backends, 1 on cpu-scalar)
/// when not set. Throws Error naming the setting and value outside 1 to 64.
unsigned cpu_leaf_block(const BackendOptions& o, unsigned fallback);
/// Its declaration (BackendInfo::settings), with the backend's default in the help text.
BackendSetting cpu_leaf_block_setting(const char* fallback);

/// The cpu family's `cpu.mic` setting (the MIC path: MBVH4 nodes tested in 16 lanes, AVX-512 only;
/// read by the SIMD backends, accepted by cpu-scalar, which traces the reference's test), `note`
/// appended to its help.
BackendSetting cpu_mic_setting(const char* note = "");

/// The cpu family's `cpu.packet-hybrid` setting (the packet traversals' hybrid switch; read by the
/// SIMD backends, accepted by cpu-scalar, which traces every ray alone), `note` appended to its help.
BackendSetting cpu_packet_hybrid_setting(const char* note = "");

void register_cpu_scalar_backend();
void register_cpu_simd_backends();
void register_dacrt_backends();

}  // namespace mbvh

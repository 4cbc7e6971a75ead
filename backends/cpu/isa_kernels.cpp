// SPDX-License-Identifier: MIT
// isa_kernels.cpp — the cpu backend's kernels, compiled once per ISA from this one translation
// unit (CMake: mbvh_cpu_avx2, mbvh_cpu_avx512), each in its own inline namespace (MBVH_ISA_NS).
// The std and host headers come first, at the baseline ISA: TU-wide -mavx512f would also compile
// the std and host inline functions this unit instantiates, and the linker may keep those AVX-512
// copies for the portable code too (a crash on a CPU without it). Then, between MBVH_ISA_BEGIN and
// MBVH_ISA_END, the ISA-namespaced code: the reference's traversal engine (host/core/trace), the
// SIMD kernel policy (simd/), the packet traversals (packet/), divide-and-conquer ray tracing
// (dacrt/) and the entry points. The policy
// tests an MBVH4 node's four boxes or an MBVH8 node's eight at once and a leaf's triangles eight
// at a time; the traversals are the reference's — the same operations in the same order, so the
// answers are bit-identical to cpu-scalar's. Áfra & Szirmay-Kalos 2014 for the traversals (Áfra's
// thesis, ch. 3, for 8-wide MBVH8), Ize 2013 for the conservative slab test, Woop, Benthin & Wald
// 2013 for the watertight triangle test.
#include <immintrin.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>

#include "backends/cpu/cpu_backends.h"
#include "backends/cpu/isa.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/view.h"  // plain records, at the baseline ISA
#include "mbvh/trace.h"

// -- from here on, functions are compiled for the ISA
MBVH_ISA_BEGIN
#define MBVH_IN_ISA_REGION 1  // the kernel headers refuse to be included anywhere else

// The engine's templates are defined here, not at the baseline ISA: a template is compiled with
// the target of its definition, and the box test and leaves could then not be inlined into it.
#include "host/core/trace/intersect.h"
#include "host/core/trace/traverse.h"
#include "host/core/trace/batch.h"  // the batch driver, in namespace mbvh::MBVH_ISA_NS

// The kernel headers: namespace mbvh::MBVH_ISA_NS::(anonymous), this unit's alone.
#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/ray.h"
#include "backends/cpu/simd/box.h"
#include "backends/cpu/simd/triangle.h"
#include "backends/cpu/simd/kernels.h"
#include "backends/cpu/packet/packet.h"
#include "backends/cpu/packet/frustum.h"
#include "backends/cpu/packet/triangle.h"
#include "backends/cpu/packet/traverse.h"
#include "backends/cpu/packet/batch.h"
#include "backends/cpu/dacrt/simd.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
           bool hybrid) {
  if (is_packet(opt.traversal)) {
    if (opt.precision == Precision::fast) trace_packets<SimdKernelsT<true>>(acc, rays, opt, out, threads, hybrid);
    else trace_packets<SimdKernelsT<false>>(acc, rays, opt, out, threads, hybrid);
    return;
  }
  if (opt.precision == Precision::fast) trace_parallel<SimdKernelsT<true>>(acc, rays, opt, out, threads);
  else trace_parallel<SimdKernelsT<false>>(acc, rays, opt, out, threads);
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

#undef MBVH_IN_ISA_REGION
MBVH_ISA_END

namespace mbvh {
extern const CpuKernels MBVH_CPU_KERNELS_NAME;
const CpuKernels MBVH_CPU_KERNELS_NAME{MBVH_STR(MBVH_CPU_ISA), &MBVH_ISA_NS::trace, &MBVH_ISA_NS::dacrt::trace_dacrt};

}  // namespace mbvh

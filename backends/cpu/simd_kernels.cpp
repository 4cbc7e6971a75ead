// simd_kernels.cpp — the cpu backend's kernels, compiled once per ISA from this one source
// (CMake: mbvh_cpu_avx2, mbvh_cpu_avx512), each in its own inline namespace (MBVH_ISA_NS).
// The ISA is switched on with a target pragma around our own kernels only, after every shared
// header has been included at the baseline ISA: TU-wide -mavx512f would also compile the std and
// host inline functions this file instantiates, and the linker may keep those AVX-512 copies for
// the portable code too (a crash on a CPU without it). The MBVH4 node test checks the
// four children's x, y and z slabs at once (SSE-width vectors, VEX/EVEX-encoded); everything
// else is the reference traversal code (traverse.h) — the same operations in the same order, so
// the answers are bit-identical to cpu-scalar's. Áfra & Szirmay-Kalos 2014 for the traversals,
// Ize 2013 for the conservative slab test.
#include <immintrin.h>

#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <functional>
#include <span>
#include <stdexcept>
#include <vector>

#include "backends/cpu/cpu_backends.h"
#include "host/parallel.h"
#include "host/trace/trace.h"  // shared types and declarations, at the baseline ISA

#ifndef MBVH_CPU_ISA
#error "compile with -DMBVH_CPU_ISA=avx2|avx512, -DMBVH_CPU_ISA_ID=1|2 and -DMBVH_ISA_NS=<the ISA>"
#endif

// -- from here on, functions are compiled for the ISA
#if defined(__clang__)
#if MBVH_CPU_ISA_ID == 2
#pragma clang attribute push(__attribute__((target("avx2,avx512f,avx512vl,avx512dq,avx512bw"))), apply_to = function)
#else
#pragma clang attribute push(__attribute__((target("avx2"))), apply_to = function)
#endif
#else
#pragma GCC push_options
#if MBVH_CPU_ISA_ID == 2
#pragma GCC target("avx2,avx512f,avx512vl,avx512dq,avx512bw")
#else
#pragma GCC target("avx2")
#endif
#endif

#include "host/trace/batch.h"  // the kernels, in namespace mbvh::MBVH_ISA_NS
#define MBVH_STR2(x) #x
#define MBVH_STR(x) MBVH_STR2(x)

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// Four slab tests in one pass: (plane - o) * inv per axis, the NaN-discarding max/min chain of
/// box_test (maxps/minps return their second operand on NaN, exactly like max_nan/min_nan), and
/// an ordered <= compare.
struct SimdBox4 {
  static unsigned test(const Node4& n, const RayPre& r, float tcull, float d[4]) {
    const __m128 lox = _mm_loadu_ps(n.lo_x), hix = _mm_loadu_ps(n.hi_x);
    const __m128 loy = _mm_loadu_ps(n.lo_y), hiy = _mm_loadu_ps(n.hi_y);
    const __m128 loz = _mm_loadu_ps(n.lo_z), hiz = _mm_loadu_ps(n.hi_z);
    const __m128 nx = r.neg[0] ? hix : lox, fx = r.neg[0] ? lox : hix;
    const __m128 ny = r.neg[1] ? hiy : loy, fy = r.neg[1] ? loy : hiy;
    const __m128 nz = r.neg[2] ? hiz : loz, fz = r.neg[2] ? loz : hiz;
    const __m128 ox = _mm_set1_ps(r.o[0]), oy = _mm_set1_ps(r.o[1]), oz = _mm_set1_ps(r.o[2]);
    const __m128 tnx = _mm_mul_ps(_mm_sub_ps(nx, ox), _mm_set1_ps(r.inv[0]));
    const __m128 tny = _mm_mul_ps(_mm_sub_ps(ny, oy), _mm_set1_ps(r.inv[1]));
    const __m128 tnz = _mm_mul_ps(_mm_sub_ps(nz, oz), _mm_set1_ps(r.inv[2]));
    const __m128 tfx = _mm_mul_ps(_mm_sub_ps(fx, ox), _mm_set1_ps(r.inv_far[0]));
    const __m128 tfy = _mm_mul_ps(_mm_sub_ps(fy, oy), _mm_set1_ps(r.inv_far[1]));
    const __m128 tfz = _mm_mul_ps(_mm_sub_ps(fz, oz), _mm_set1_ps(r.inv_far[2]));
    const __m128 te = _mm_max_ps(tnz, _mm_max_ps(tny, _mm_max_ps(tnx, _mm_set1_ps(r.tmin))));
    const __m128 tx = _mm_min_ps(tfz, _mm_min_ps(tfy, _mm_min_ps(tfx, _mm_set1_ps(tcull))));
    _mm_storeu_ps(d, te);
#if MBVH_CPU_ISA_ID == 2
    return static_cast<unsigned>(_mm_cmp_ps_mask(te, tx, _CMP_LE_OQ));
#else
    return static_cast<unsigned>(_mm_movemask_ps(_mm_cmp_ps(te, tx, _CMP_LE_OQ)));
#endif
  }
};

void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads) {
  trace_parallel<SimdBox4>(acc, rays, opt, out, threads);
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

#if defined(__clang__)
#pragma clang attribute pop
#else
#pragma GCC pop_options
#endif

namespace mbvh {
extern const CpuKernels MBVH_CPU_KERNELS_NAME;
const CpuKernels MBVH_CPU_KERNELS_NAME{MBVH_STR(MBVH_CPU_ISA), &MBVH_ISA_NS::trace};

}  // namespace mbvh

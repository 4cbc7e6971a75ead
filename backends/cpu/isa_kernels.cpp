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
#include "backends/cpu/simd/occlusion.h"
#include "backends/cpu/simd/mic.h"
#include "backends/cpu/packet/packet.h"
#include "backends/cpu/packet/frustum.h"
#include "backends/cpu/packet/triangle.h"
#include "backends/cpu/packet/traverse.h"
#include "backends/cpu/packet/batch.h"
#include "backends/cpu/dacrt/simd.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// Whether the MIC path (mic.h) traces `opt`: asked for (cpu.mic), an AVX-512 build, an MBVH4
/// single-ray traversal.
bool runs_mic(const TraceOptions& opt, bool mic) {
  return MBVH_CPU_ISA_ID == 2 && mic && opt.layout == Layout::mbvh4 && !is_packet(opt.traversal) && !is_dacrt(opt.traversal);
}

void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
           bool hybrid, [[maybe_unused]] bool mic) {
  if (is_packet(opt.traversal)) {
    if (opt.precision == Precision::fast) trace_packets<SimdKernelsT<true>>(acc, rays, opt, out, threads, hybrid);
    else trace_packets<SimdKernelsT<false>>(acc, rays, opt, out, threads, hybrid);
    return;
  }
#if MBVH_CPU_ISA_ID == 2
  if (runs_mic(opt, mic)) {
    if (opt.precision == Precision::fast) trace_parallel<MicKernelsT<true>>(acc, rays, opt, out, threads);
    else trace_parallel<MicKernelsT<false>>(acc, rays, opt, out, threads);
    return;
  }
#endif
  if (opt.precision == Precision::fast) trace_parallel<SimdKernelsT<true>>(acc, rays, opt, out, threads);
  else trace_parallel<SimdKernelsT<false>>(acc, rays, opt, out, threads);
}

// -- the single-ray query (Backend::ray_query): the views resolved once, at make; per call the
// batch's steps for one ray (run_batch: prepare, relax, finish, the traversal), nothing else

/// What a query's kernels read: the view of each query (0: closest, 1: any) and its pair.
struct OneRayState {
  TraceView view[2];
  Layout layout[2];
  Traversal traversal[2];
};

/// One ray of query Any through `Trace` (a traversal of view `v`), as run_batch traces it.
template <bool Any, class K, class Trace>
[[gnu::always_inline]] inline Hit one_ray(const TraceView& v, const Ray& ray, Trace trace) {
  typename K::Ray r;
  if (!ready_ray<K>(v, ray, r)) return miss_hit();
  NoStats st;
  return trace(r, st);
}

/// Any pair, chosen per call (dispatch's switch).
template <bool Any, class K>
Hit one_ray_any_pair(const void* state, const Ray& ray) {
  const auto& s = *static_cast<const OneRayState*>(state);
  const TraceView& v = s.view[Any];
  return one_ray<Any, K>(v, ray, [&](const typename K::Ray& r, NoStats& st) {
    return dispatch<Any, K>(v, r, s.layout[Any], s.traversal[Any], st);
  });
}
/// The defaults (default_ray_query_options), traversal fixed: closest hit MBVH8 ordered stack, any
/// hit MBVH8 bitstack.
template <class K>
Hit one_ray_closest_mbvh8_ordered(const void* state, const Ray& ray) {
  const TraceView& v = static_cast<const OneRayState*>(state)->view[0];
  return one_ray<false, K>(v, ray, [&](const typename K::Ray& r, NoStats& st) {
    return trace_wide_stack_ordered<false, NoStats, K, Node8>(v, r, st);
  });
}
template <class K>
Hit one_ray_any_mbvh8_bitstack(const void* state, const Ray& ray) {
  const TraceView& v = static_cast<const OneRayState*>(state)->view[1];
  return one_ray<true, K>(v, ray, [&](const typename K::Ray& r, NoStats& st) {
    return trace_mbvh8_bitstack<true, NoStats, K>(v, r, st);
  });
}

template <Hit (*F)(const void*, const Ray&)>
bool occluded_by(const void* state, const Ray& ray) {
  return F(state, ray).prim != MBVH_MISS_PRIM;
}

template <class K>
RayQueryKernels query_kernels(const TraceOptions& c, const TraceOptions& a) {
  RayQueryKernels k;
  k.closest = c.layout == Layout::mbvh8 && c.traversal == Traversal::stack_ordered ? &one_ray_closest_mbvh8_ordered<K>
                                                                                    : &one_ray_any_pair<false, K>;
  k.any = a.layout == Layout::mbvh8 && a.traversal == Traversal::bitstack ? &occluded_by<&one_ray_any_mbvh8_bitstack<K>>
                                                                           : &occluded_by<&one_ray_any_pair<true, K>>;
  return k;
}

RayQueryKernels ray_query(const Accel& acc, const TraceOptions& c, const TraceOptions& a, bool mic) {
  auto s = std::make_shared<OneRayState>();
  const TraceOptions* o[2] = {&c, &a};
  // one precision for both: the query's options share it (Backend::ray_query)
  const bool fast = c.precision == Precision::fast;
  for (int q = 0; q < 2; ++q) {  // the batch's view: packs (fast: TriPacks::mt), packed references (trace_parallel)
    s->view[q] = trace_view(acc, o[q]->layout, true, o[q]->leaf_block, true, runs_mic(*o[q], mic), fast);
    s->layout[q] = o[q]->layout;
    s->traversal[q] = o[q]->traversal;
  }
  RayQueryKernels k = fast ? query_kernels<SimdKernelsT<true>>(c, a) : query_kernels<SimdKernelsT<false>>(c, a);
#if MBVH_CPU_ISA_ID == 2
  // the MIC path's query where it traces (an MBVH4 query; the other keeps the 8-lane kernels)
  if (runs_mic(c, mic)) k.closest = fast ? &one_ray_any_pair<false, MicKernelsT<true>> : &one_ray_any_pair<false, MicKernelsT<false>>;
  if (runs_mic(a, mic))
    k.any = fast ? &occluded_by<&one_ray_any_pair<true, MicKernelsT<true>>> : &occluded_by<&one_ray_any_pair<true, MicKernelsT<false>>>;
#endif
  k.state = std::move(s);
  return k;
}

#if MBVH_CPU_ISA_ID == 2
// Out of line for the tests, GCC 12 warns -Wuninitialized inside its own avx512fintrin.h here: the
// `_mm512_undefined_*` idiom of its headers (GCC bug 105593, fixed in GCC 13).
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
void push_sorted8(void* entries, unsigned mask, const std::int32_t* child, const float* d) {
  SimdKernelsT<false>::push_sorted8(entries, mask, child, d);
}
#pragma GCC diagnostic pop
constexpr auto kPushSorted8 = &push_sorted8;
#else
constexpr void (*kPushSorted8)(void*, unsigned, const std::int32_t*, const float*) = nullptr;
#endif

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

#undef MBVH_IN_ISA_REGION
MBVH_ISA_END

namespace mbvh {
extern const CpuKernels MBVH_CPU_KERNELS_NAME;
const CpuKernels MBVH_CPU_KERNELS_NAME{MBVH_STR(MBVH_CPU_ISA), MBVH_ISA_NS::packet::kPacketRays, MBVH_ISA_NS::packet::kLanes,
                                         &MBVH_ISA_NS::trace, &MBVH_ISA_NS::dacrt::trace_dacrt,
                                         &MBVH_ISA_NS::ray_query, MBVH_ISA_NS::kPushSorted8};

}  // namespace mbvh

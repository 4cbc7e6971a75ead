// SPDX-License-Identifier: MIT
// traverse.h — the scalar reference traversals every backend is checked against: stack-based and
// bitstack (Áfra & Szirmay-Kalos, "Stackless Multi-BVH Traversal for CPU, MIC and GPU Ray
// Tracing", CGF 2014) for MBVH2, MBVH4 and MBVH8 (Áfra's thesis, ch. 3), templated on the query
// (closest / any hit), the kernel policy (scalar_kernels.h; the SIMD cpu backends pass theirs) and
// a statistics policy (stats.h), and the dispatch to the one chosen at run time. Pseudocode:
// TRAVERSAL.md §4.
#pragma once
#include "host/core/trace/bitstack.h"
#include "host/core/trace/intersect.h"
#include "host/core/trace/scalar_kernels.h"
#include "host/core/trace/stack.h"
#include "host/core/trace/stats.h"
#include "host/core/trace/view.h"
#include "host/core/trace/visit.h"
#include "mbvh/trace.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

/// Traces `r` with traversal `t` on layout `l`, both chosen at run time (a packet traversal and
/// dacrt as packet_single_ray's, ray by ray); the pair is one reference_supports, or dacrt.
template <bool Any, class K, class St>
inline Hit dispatch(const TraceView& v, const typename K::Ray& r, Layout l, Traversal t, St& st) {
  if (is_packet(t) || is_dacrt(t)) t = packet_single_ray(l, Any);  // their answers, ray by ray
  if (l == Layout::mbvh2)
    return t == Traversal::stack ? trace_mbvh2_stack<Any, St, K>(v, r, st) : trace_mbvh2_bitstack<Any, St, K>(v, r, st);
  if (l == Layout::mbvh8) {
    switch (t) {
      case Traversal::stack: return trace_mbvh8_stack<Any, St, K>(v, r, st);
      case Traversal::bitstack: return trace_mbvh8_bitstack<Any, St, K>(v, r, st);
      case Traversal::stack_ordered: return trace_wide_stack_ordered<Any, St, K, Node8>(v, r, st);
      case Traversal::stack_octant: return trace_mbvh8_octant<Any, St, K>(v, r, st);
      case Traversal::bitstack_octant: return trace_mbvh8_bitstack_octant<Any, St, K>(v, r, st);
      case Traversal::bitstack_retest: return miss_hit();
      case Traversal::packet_ranged: case Traversal::packet_partition: case Traversal::packet: case Traversal::dacrt:
        break;  // mapped above
      case Traversal::automatic: break;  // resolved at the entry points (resolve_options)
    }
    return miss_hit();
  }
  switch (t) {
    case Traversal::stack: return trace_mbvh4_stack<Any, St, K>(v, r, st);
    case Traversal::bitstack: return trace_mbvh4_bitstack<Any, St, K>(v, r, st);
    case Traversal::stack_ordered: return trace_wide_stack_ordered<Any, St, K>(v, r, st);
    case Traversal::bitstack_retest: return trace_mbvh4_bitstack_retest<Any, St, K>(v, r, st);
    case Traversal::stack_octant: case Traversal::bitstack_octant: return miss_hit();  // MBVH8 only (reference_supports)
    case Traversal::packet_ranged: case Traversal::packet_partition: case Traversal::packet: case Traversal::dacrt:
      break;  // mapped above
    case Traversal::automatic: break;  // resolved at the entry points (resolve_options)
  }
  return miss_hit();
}

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

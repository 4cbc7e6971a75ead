// SPDX-License-Identifier: MIT
// batch.h — the multi-threaded batch driver shared by the reference (cpu-scalar) and the SIMD
// cpu backends: validate each ray, dispatch to the traversal chosen at run time, fill the
// outputs in ray order. Templated on the kernel policy (box test and leaf visit,
// scalar_kernels.h); lives in the ISA namespace like the kernels it calls.
#pragma once
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <functional>
#include <span>

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/traverse.h"
#include "mbvh/trace.h"

namespace mbvh {

inline namespace MBVH_ISA_NS {

/// Points `v` at `src`'s nodes of `layout` (src: the Accel, or one of its leaf variants; each
/// makes the layout on first use).
template <class Src>
inline void view_nodes(TraceView& v, const Src& src, Layout layout) {
  if (layout == Layout::mbvh2) {
    v.n2 = src.mbvh2().nodes.data();
    v.nodes = src.mbvh2().nodes.size();
  } else if (layout == Layout::mbvh4) {
    v.n4 = src.mbvh4().nodes.data();
    v.nodes = src.mbvh4().nodes.size();
  } else {
    v.n8 = src.mbvh8().nodes.data();
    v.nodes = src.mbvh8().nodes.size();
  }
}

/// The view of `layout` a traversal reads (makes the layout on first use); with the SIMD leaf
/// packs when `packs` (a kernel policy's `uses_packs`); on the build's leaves regrouped for
/// `leaf_block` (Accel::leaf_variant) when it is above 1: their own nodes, leaves and packs over
/// the same triangles.
/// `packed_refs`: nodes whose leaf references locate the packs (TraceView::packed_refs) where the
/// variant's leaves allow them.
/// `node4w`: for MBVH4 also the nodes' 16-wide view (TraceView::n4w; a kernel policy's uses_node4w).
/// `mt`: the packs laid out for the fast precision's Möller–Trumbore (TriPacks::mt) in place of
/// the watertight test's, the same slots (a fast SIMD kernel policy's).
inline TraceView trace_view(const Accel& acc, Layout layout, bool packs = false, unsigned leaf_block = 1,
                            bool packed_refs = false, bool node4w = false, bool mt = false) {
  TraceView v;
  v.tris = acc.tris().data();
  const TriPacks* p = nullptr;
  if (leaf_block > 1) {
    const LeafVariant& lv = acc.leaf_variant(leaf_block);
    view_nodes(v, lv, layout);
    v.leaf_count = lv.leaves.size();
    v.leaves = lv.leaves.data();
    if (packs) p = &lv.tri_packs(acc.tris());
    if (node4w && layout == Layout::mbvh4) v.n4w = lv.mbvh4_wide().nodes.data();
    if (packs && packed_refs) {
      if (const void* k = lv.packed_nodes(layout, acc.tris())) {
        if (layout == Layout::mbvh2) v.n2 = static_cast<const Node2*>(k);
        else if (layout == Layout::mbvh4) v.n4 = static_cast<const Node4*>(k);
        else v.n8 = static_cast<const Node8*>(k);
        v.packed_refs = true;
      }
    }
  } else {
    view_nodes(v, acc, layout);
    v.leaf_count = acc.leaves().size();
    v.leaves = acc.leaves().data();
    if (packs) p = &acc.tri_packs();
    if (node4w && layout == Layout::mbvh4) v.n4w = acc.mbvh4_wide().nodes.data();
  }
  if (p) {
    v.tri4 = mt ? p->mt().data() : p->packs.data();
    v.leaf4 = p->leaves.data();
  }
  return v;
}

/// Whether kernel policy K reads the MBVH4 nodes' 16-wide view (its `uses_node4w`; none of the
/// reference's).
template <class K>
constexpr bool uses_node4w() {
  if constexpr (requires { K::uses_node4w; }) return K::uses_node4w;
  else return false;
}

/// Whether kernel policy K walks two rays in turn on the ordered and octant stacks
/// (walked_in_turn says where; its `interleave`; none of the reference's).
template <class K>
constexpr bool interleaves() {
  if constexpr (requires { K::interleave; }) return K::interleave;
  else return false;
}

/// Whether kernel policy K may trace MBVH8 (its `mbvh4_only` off; the MIC policy, which the cpu
/// backend runs on MBVH4 alone, has it on: walked_in_turn then makes none of the MBVH8 walks for
/// it, code that would never run).
template <class K>
constexpr bool walks_mbvh8() {
  if constexpr (requires { K::mbvh4_only; }) return !K::mbvh4_only;
  else return true;
}

/// Whether kernel policy K walks the MBVH8 octant-ordered stack's any hit with its own batch walk
/// (its `octant_any` on: K::trace_octant_any in place of OctantWalk; the SIMD policies' fast
/// precision, which compiles it per ray direction octant).
template <class K>
constexpr bool own_octant_any() {
  if constexpr (requires { K::octant_any; }) return K::octant_any;
  else return false;
}

/// Readies `ray` for a walk in r (K's prepare; the fast mode's relaxed box test; finish): false for
/// an invalid ray, whose answer is a miss.
template <class K>
[[gnu::always_inline]] inline bool ready_ray(const TraceView& v, const Ray& ray, typename K::Ray& r) {
  if (!K::prepare(ray, r)) return false;
  if constexpr (K::fast) relax_ray(r);
  K::finish(r, v);
  return true;
}

/// Stores ray i's answer: any hit whether it is occluded, closest hit the hit.
template <bool Any>
[[gnu::always_inline]] inline void store_answer(TraceOutput& out, std::size_t i, const Hit& h) {
  if constexpr (Any) out.occluded[i] = h.prim != MBVH_MISS_PRIM ? 1 : 0;
  else out.hits[i] = h;
}

/// A walk (stack.h's OrderedWalk or OctantWalk, bitstack.h's Mbvh8BitstackWalk or
/// Mbvh8OctantBitstackWalk) with two rays
/// walked in turn, a node or leaf of one, then of the other: a ray's walk is one chain of
/// dependent loads and tests (the node, its box test, the child picked, the child's node), and
/// the other ray's step fills the core while it waits. Each ray's answer is the single-ray walk's
/// (the same steps in the same order); a finished ray's slot takes the next ray of [b, e). `at`
/// maps a position of [b, e) to its ray's index in `rays` and `out` (by default the position
/// itself; simd/occlusion.h walks one direction octant's rays of a chunk by their indices).
struct SameIndex {
  constexpr std::size_t operator()(std::size_t k) const { return k; }
};
template <bool Any, class K, class Walk, class At = SameIndex>
inline void run_interleaved(const TraceView& v, std::span<const Ray> rays, std::size_t b, std::size_t e, TraceOutput& out,
                            std::size_t& invalid, At at = {}) {
  typename K::Ray r0{}, r1{};  // defined before a walk is made on them (its start() reads tmax); load() sets them
  Walk w0(v, r0), w1(v, r1);
  std::size_t id0 = 0, id1 = 0, next = b;
  NoStats st;
  const auto store = [&](const Walk& w, std::size_t id) { store_answer<Any>(out, id, w.best); };
  const auto load = [&](typename K::Ray& r, Walk& w, std::size_t& id) {  // the next valid ray; false when none is left
    while (next < e) {
      const std::size_t i = at(next++);
      if (!ready_ray<K>(v, rays[i], r)) {
        ++invalid;
        store_answer<Any>(out, i, miss_hit());
        continue;
      }
      w.start();
      id = i;
      return true;
    }
    return false;
  };
  bool live0 = load(r0, w0, id0), live1 = live0 && load(r1, w1, id1);
  while (live0 && live1) {
    if (!w0.step(st)) {
      store(w0, id0);
      live0 = load(r0, w0, id0);
    }
    if (!w1.step(st)) {
      store(w1, id1);
      live1 = load(r1, w1, id1);
    }
  }
  if (live0) {  // the ray left, alone
    while (w0.step(st)) {
    }
    store(w0, id0);
  }
  if (live1) {
    while (w1.step(st)) {
    }
    store(w1, id1);
  }
}

/// Whether the rays [b, e) point much the same way: the mean of their unit directions (every
/// kCoherenceStride-th ray, the valid ones) at least kCoherentMean (0.8) long. A chunk of a camera's
/// primary rays (neighbouring pixels) is; a chunk of diffuse rays (a cosine lobe about each
/// ray's surface normal: a mean at most 2/3 long) is not.
inline constexpr std::size_t kCoherenceStride = 8;
inline constexpr float kCoherentMean = 0.8f;
inline bool coherent_directions(std::span<const Ray> rays, std::size_t b, std::size_t e) {
  float sx = 0.0f, sy = 0.0f, sz = 0.0f, n = 0.0f;
  for (std::size_t i = b; i < e; i += kCoherenceStride) {
    const Ray& r = rays[i];
    // scaled by its largest component first, so that no valid direction's square overflows or
    // underflows
    const float m = std::max({std::fabs(r.dx), std::fabs(r.dy), std::fabs(r.dz)});
    if (!(m > 0.0f && m < INFINITY)) continue;  // a zero, infinite or NaN direction (an invalid ray)
    const float x = r.dx / m, y = r.dy / m, z = r.dz / m;
    const float s = 1.0f / std::sqrt(x * x + y * y + z * z);
    sx += x * s;
    sy += y * s;
    sz += z * s;
    n += 1.0f;
  }
  return n > 0.0f && sx * sx + sy * sy + sz * sz >= kCoherentMean * kCoherentMean * n * n;
}

/// Walks rays [b, e) two in turn (run_interleaved) where K and `opt` take it, without statistics:
/// the MBVH4 ordered stack and the MBVH8 bitstack, octant stack and octant bitstack, both queries;
/// the MBVH8 ordered stack any hit, and closest hit where the rays are coherent
/// (coherent_directions): on two incoherent rays the ordered stack's sort branches mispredict,
/// where the octant stack's push has no branch on the order (measurements: docs/backends.md).
/// False where the rays are left to run_batch (and for MBVH8 where K is MBVH4's only: walks_mbvh8).
template <class K>
inline bool walked_in_turn(const TraceView& v, std::span<const Ray> rays, std::size_t b, std::size_t e,
                           const TraceOptions& opt, TraceOutput& out, std::size_t& invalid) {
  if constexpr (interleaves<K>()) {
    if (opt.stats) return false;
    const bool any = opt.query == Query::any;
    if (opt.layout == Layout::mbvh4) {
      if (opt.traversal != Traversal::stack_ordered) return false;
      if (any) run_interleaved<true, K, OrderedWalk<true, NoStats, K, Node4>>(v, rays, b, e, out, invalid);
      else run_interleaved<false, K, OrderedWalk<false, NoStats, K, Node4>>(v, rays, b, e, out, invalid);
      return true;
    }
    if (opt.layout != Layout::mbvh8) return false;
    if constexpr (walks_mbvh8<K>()) {
      if (opt.traversal == Traversal::bitstack) {
        if (any) run_interleaved<true, K, Mbvh8BitstackWalk<true, NoStats, K>>(v, rays, b, e, out, invalid);
        else run_interleaved<false, K, Mbvh8BitstackWalk<false, NoStats, K>>(v, rays, b, e, out, invalid);
        return true;
      }
      if (opt.traversal == Traversal::bitstack_octant) {
        if (any) run_interleaved<true, K, Mbvh8OctantBitstackWalk<true, NoStats, K>>(v, rays, b, e, out, invalid);
        else run_interleaved<false, K, Mbvh8OctantBitstackWalk<false, NoStats, K>>(v, rays, b, e, out, invalid);
        return true;
      }
      if (opt.traversal == Traversal::stack_octant) {
        if (any) {
          if constexpr (own_octant_any<K>()) K::trace_octant_any(v, rays, b, e, out, invalid);
          else run_interleaved<true, K, OctantWalk<true, NoStats, K>>(v, rays, b, e, out, invalid);
        } else run_interleaved<false, K, OctantWalk<false, NoStats, K>>(v, rays, b, e, out, invalid);
        return true;
      }
      if (opt.traversal != Traversal::stack_ordered) return false;
      if (any) run_interleaved<true, K, OrderedWalk<true, NoStats, K, Node8>>(v, rays, b, e, out, invalid);
      else if (coherent_directions(rays, b, e))  // the insertion sort (OrderedWalk's Sorted off): coherent rays predict it
        run_interleaved<false, K, OrderedWalk<false, NoStats, K, Node8, false>>(v, rays, b, e, out, invalid);
      else return false;
      return true;
    }
  }
  return false;
}

template <bool Any, bool Stats, class K>
inline void run_batch(const TraceView& v, std::span<const Ray> rays, std::size_t b, std::size_t e,
                      const TraceOptions& opt, TraceOutput& out, std::size_t& invalid) {
  for (std::size_t i = b; i < e; ++i) {
    typename K::Ray r;
    Hit h = miss_hit();
    if (!ready_ray<K>(v, rays[i], r)) {
      ++invalid;
      if constexpr (Stats) out.stats[i] = RayStats{};
    } else if constexpr (Stats) {
      CountStats st;
      h = dispatch<Any, K>(v, r, opt.layout, opt.traversal, st);
      out.stats[i] = st.s;
    } else {
      NoStats st;
      h = dispatch<Any, K>(v, r, opt.layout, opt.traversal, st);
    }
    store_answer<Any>(out, i, h);
  }
}

/// Traces `rays` on `threads` workers (0 = all) in chunks of kTraceChunk rays; no per-ray allocation.
/// K: the kernel policy of TraceOptions::precision (the caller picks it).
template <class K>
inline void trace_parallel(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out,
                           unsigned threads, const std::function<void(std::size_t)>& progress = {}) {
  // counted traversals visit leaves through the reference's visit_leaf (the leaf table)
  const TraceView v = trace_view(acc, opt.layout, K::uses_packs, opt.leaf_block, K::uses_packs && !opt.stats,
                                    uses_node4w<K>(), K::uses_packs && K::fast && !opt.stats);
  const bool any = opt.query == Query::any;
  out.resize_for(rays.size(), opt);  // every ray's entries are written below
  std::atomic<std::size_t> invalid{0}, done{0};
  parallel_for(rays.size(), kTraceChunk, threads, [&](std::size_t b, std::size_t e, unsigned worker) {
    std::size_t inv = 0;
    if (!walked_in_turn<K>(v, rays, b, e, opt, out, inv)) {
      if (any && opt.stats) run_batch<true, true, K>(v, rays, b, e, opt, out, inv);
      else if (any) run_batch<true, false, K>(v, rays, b, e, opt, out, inv);
      else if (opt.stats) run_batch<false, true, K>(v, rays, b, e, opt, out, inv);
      else run_batch<false, false, K>(v, rays, b, e, opt, out, inv);
    }
    invalid += inv;
    const std::size_t d = done += e - b;
    if (progress && worker == 0) progress(d);
  });
  out.invalid = invalid;
}

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

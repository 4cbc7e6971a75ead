// SPDX-License-Identifier: MIT
// batch.h — the packet traversals' batch driver: rays MBVH_PACKET_RAYS at a time, a coherent
// packet through its MBVH2 walk, an incoherent one ray by ray (the hybrid switch).
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/packet/packet.h"
#include "backends/cpu/packet/traverse.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// One packet's trace with the statistics policy and the traversal chosen at run time.
template <bool Any, bool Stats, bool Fast, bool Partition, bool UniformK>
inline void trace_packet_signs(const TraceView& v, packet::Packet& P, RayStats* st) {
  if (P.same_sign) packet::trace_packet<Any, Partition, UniformK, true, Stats, Fast>(v, P, st);
  else packet::trace_packet<Any, Partition, UniformK, false, Stats, Fast>(v, P, st);
}
/// Fast: Möller–Trumbore, which has no shear axes (UniformK does not matter).
template <bool Any, bool Stats, bool Fast>
inline void trace_one_packet(const TraceView& v, packet::Packet& P, bool partition, RayStats* st) {
  const bool uniform = Fast || P.uniform_k;
  if (partition) {
    if (uniform) trace_packet_signs<Any, Stats, Fast, true, true>(v, P, st);
    else if constexpr (!Fast) trace_packet_signs<Any, Stats, Fast, true, false>(v, P, st);
  } else {
    if (uniform) trace_packet_signs<Any, Stats, Fast, false, true>(v, P, st);
    else if constexpr (!Fast) trace_packet_signs<Any, Stats, Fast, false, false>(v, P, st);
  }
}

/// The packet traversals' batch driver: rays in arrival order, MBVH_PACKET_RAYS at a time; a
/// coherent packet walks the MBVH2 nodes of the leaves traced, an incoherent one goes ray by ray
/// through opt.layout (the hybrid switch, packet/packet.h).
template <class K>
void trace_packets(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
                   bool hybrid) {
  const TraceView pv = trace_view(acc, Layout::mbvh2, false, opt.leaf_block, false);
  const TraceView sv = trace_view(acc, opt.layout, true, opt.leaf_block, !opt.stats, false, K::fast && !opt.stats);
  const bool any = opt.query == Query::any;
  // the hybrid's single rays: run_batch's dispatch traces a packet traversal ray by ray as
  // packet_single_ray's traversal, whose bytes every packet ray gives (but for classified ties)
  const bool partition = opt.traversal != Traversal::packet_ranged;  // packet: partition, the faster (docs/benchmarks.md)
  out.resize_for(rays.size(), opt);
  std::atomic<std::size_t> invalid{0};
  constexpr std::size_t kN = packet::kPacketRays;
  parallel_for(rays.size(), kTraceChunk, threads, [&](std::size_t b, std::size_t e, unsigned) {
    static_assert(kTraceChunk % kN == 0, "chunks hold whole packets");
    auto P = std::make_unique<packet::Packet>();
    std::array<RayStats, kN> st{};
    std::size_t inv = 0;
    for (std::size_t s = b; s < e; s += kN) {
      const int n = static_cast<int>(std::min(kN, e - s));
      std::size_t bad = 0;
      if (!packet::load_packet<K::fast>(*P, rays.data() + s, n, bad, hybrid)) {
        std::size_t again = 0;
        if (any) {
          if (opt.stats) run_batch<true, true, K>(sv, rays, s, s + n, opt, out, again);
          else run_batch<true, false, K>(sv, rays, s, s + n, opt, out, again);
        } else {
          if (opt.stats) run_batch<false, true, K>(sv, rays, s, s + n, opt, out, again);
          else run_batch<false, false, K>(sv, rays, s, s + n, opt, out, again);
        }
        inv += again;
        continue;
      }
      inv += bad;
      if (opt.stats) {
        st.fill(RayStats{});
        if (any) trace_one_packet<true, true, K::fast>(pv, *P, partition, st.data());
        else trace_one_packet<false, true, K::fast>(pv, *P, partition, st.data());
        for (int i = 0; i < int(kN); ++i)
          if (const int at = packet::ray_of(i); at < n)
            out.stats[s + at] = P->valid[i / packet::kLanes] >> (i % packet::kLanes) & 1u ? st[i] : RayStats{};
      } else {
        if (any) trace_one_packet<true, false, K::fast>(pv, *P, partition, nullptr);
        else trace_one_packet<false, false, K::fast>(pv, *P, partition, nullptr);
      }
      for (int i = 0; i < int(kN); ++i) {  // slot i holds ray ray_of(i) of the packet
        const int at = packet::ray_of(i);
        if (at >= n) continue;
        if (any) out.occluded[s + at] = P->prim[i] != MBVH_MISS_PRIM ? 1 : 0;
        else out.hits[s + at] = P->prim[i] != MBVH_MISS_PRIM ? Hit{P->t[i], P->u[i], P->v[i], P->prim[i]} : miss_hit();
      }
    }
    invalid += inv;
  });
  out.invalid = invalid;
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

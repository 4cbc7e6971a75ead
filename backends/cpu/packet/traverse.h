// SPDX-License-Identifier: MIT
// traverse.h — a packet's walk of the binary tree (MBVH2): ranged (Wald, Boulos & Shirley 2007) or
// partition (Overbeck, Ramamoorthi & Mark 2008) traversal with the frustum test, per-lane box tests
// and the lanes' triangle tests.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/packet/frustum.h"
#include "backends/cpu/packet/packet.h"
#include "backends/cpu/packet/triangle.h"
#include "backends/cpu/simd/lanes.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace packet {

/// box_test (intersect.h) on the lanes of SIMD ray g against two boxes at once: each lane's
/// near and far planes by the sign of its direction, the same operations in the same order.
/// Returns the hit lanes of each box and their entry distances. SameSign: every lane has the
/// packet's signs, so the planes are the box's broadcast ones. Fast: box_test_wide's FMA form,
/// p * inv - o * inv per plane (the relaxed ray: invf = inv), the single rays' fast bits.
template <bool SameSign, bool Fast = false>
[[gnu::always_inline]] inline void box2_group(const Packet& P, int g, const Box8& b0, const Box8& b1, unsigned& h0,
                                              unsigned& h1, PV& te0, PV& te1) {
  using F = PL;
  const int i = g * kLanes;
  PV tcull = F::mul(F::load(P.t + i), F::set1(kCullSlack));
  if constexpr (Fast) tcull = F::add(tcull, F::load(P.tol + i));  // finish_fast_ray's raised bound
  const PV tmin = F::load(P.tmin + i);
  PV e0 = tmin, e1 = tmin, x0 = tcull, x1 = tcull;
  for (int a = 0; a < 3; ++a) {
    const PV inv = F::load(P.inv[a] + i);
    PV n0, f0, n1, f1;
    if constexpr (SameSign) {
      n0 = b0.nearv[a], f0 = b0.farv[a], n1 = b1.nearv[a], f1 = b1.farv[a];
    } else {
      const PV s = F::load(P.d[a] + i);  // the sign bit selects the planes
      n0 = F::sel_sign(b0.lo[a], b0.hi[a], s), f0 = F::sel_sign(b0.hi[a], b0.lo[a], s);
      n1 = F::sel_sign(b1.lo[a], b1.hi[a], s), f1 = F::sel_sign(b1.hi[a], b1.lo[a], s);
    }
    // box_test's order: te = max(tnz, max(tny, max(tnx, tmin))), tx likewise from tcull
    if constexpr (Fast) {
      const PV oi = F::load(P.oi[a] + i);
      e0 = F::max(F::fmsub(n0, inv, oi), e0);
      x0 = F::min(F::fmsub(f0, inv, oi), x0);
      e1 = F::max(F::fmsub(n1, inv, oi), e1);
      x1 = F::min(F::fmsub(f1, inv, oi), x1);
    } else {
      const PV o = F::load(P.o[a] + i), invf = F::load(P.invf[a] + i);
      e0 = F::max(F::mul(F::sub(n0, o), inv), e0);
      x0 = F::min(F::mul(F::sub(f0, o), invf), x0);
      e1 = F::max(F::mul(F::sub(n1, o), inv), e1);
      x1 = F::min(F::mul(F::sub(f1, o), invf), x1);
    }
  }
  h0 = F::le(e0, x0);
  h1 = F::le(e1, x1);
  te0 = e0;
  te1 = e1;
}

/// The active SIMD rays of a traversal step: ranged, the span [first, last] of SIMD rays (those
/// between with no lane left are skipped); partition, the list of those with a lane left.
template <bool Partition>
struct Active {
  std::uint8_t n = 0;            ///< partition: SIMD rays listed; ranged: last + 1
  std::uint8_t first = 0;        ///< ranged
  std::uint8_t ids[kGroups]{};   ///< partition
  LaneBits mask[kGroups]{};  ///< lanes per SIMD ray
  // the SIMD rays to visit: g = at(k) for k in [begin(), end()), skipping mask[g] == 0
  int begin() const { return Partition ? 0 : first; }
  int end() const { return n; }
  int at(int k) const { return Partition ? ids[k] : k; }
  void clear() {
    n = 0;
    first = kGroups;
  }
  /// Records SIMD ray g's lanes `m` (g rising between clears).
  [[gnu::always_inline]] void add(int g, unsigned m) {
    mask[g] = static_cast<LaneBits>(m);
    if constexpr (Partition) {  // without a branch: the list grows by one only when m != 0
      ids[n] = static_cast<std::uint8_t>(g);  // n <= g < kGroups: one add per g between clears
      n = static_cast<std::uint8_t>(n + (m != 0 ? 1 : 0));
    } else {
      if (m == 0) return;
      if (first == kGroups) first = static_cast<std::uint8_t>(g);
      n = static_cast<std::uint8_t>(g + 1);
    }
  }
  bool empty() const { return Partition ? n == 0 : first >= n; }
};

/// Counts one SIMD operation on SIMD ray g, lanes `m` active (RayStats::lane_ops, group_ops).
inline void count_op(RayStats* st, int g, unsigned m) {
  for (int l = 0; l < kLanes; ++l) {
    RayStats& s = st[g * kLanes + l];
    ++s.group_ops;
    s.lane_ops += (m >> l) & 1u;
  }
}

/// Adds to the counters of SIMD ray g's lanes `m`.
inline void count_lanes(RayStats* st, int g, unsigned m, unsigned nodes, unsigned boxes, unsigned leaves = 0, unsigned tris = 0) {
  for (; m != 0; m &= m - 1) {
    RayStats& s = st[g * kLanes + std::countr_zero(m)];
    s.nodes += nodes;
    s.box_tests += boxes;
    s.leaves += leaves;
    s.tris += tris;
  }
}

/// Traces the packet through the MBVH2 nodes of v: ranged or partition traversal with the
/// frustum test, the nearer child (the smaller entry over the packet's hit lanes) first; any hit
/// with a frustum: the child of the longer chord first.
/// Stats: st[i] counts lane i's work — the nodes and leaves it was active in, the triangles
/// tested for it (as its own traversal would count them), and the peak stack depth.
template <bool Any, bool Partition, bool UniformK, bool SameSign, bool Stats, bool Fast>
inline void trace_packet(const TraceView& v, Packet& P, RayStats* st) {
  using A = Active<Partition>;
  struct Entry {
    std::int32_t node;
    A act;
  };
  Entry stack[MBVH_STACK2_ENTRIES + 1];
  unsigned sp = 0;
  std::int32_t cur = 0;
  A act;
  act.clear();
  for (int g = 0; g < kGroups; ++g) {
    act.mask[g] = 0;
    act.add(g, P.live[g]);
  }
  if (act.empty()) return;
  for (;;) {
    if (cur >= 0) {
      const Node2& n = v.n2[cur];
      Box8 b0, b1;
      load_box(b0, n.c0[0], n.c0[1], n.c0[2], n.c0[3], n.zz[0], n.zz[1], P);
      load_box(b1, n.c1[0], n.c1[1], n.c1[2], n.c1[3], n.zz[2], n.zz[3], P);
      if constexpr (Stats) {
        for (int k = act.begin(); k < act.end(); ++k) {
          const int g = act.at(k);
          count_lanes(st, g, Any ? act.mask[g] & P.live[g] : act.mask[g], 1, 2);
        }
      }
      Cover c0 = Cover::some, c1 = Cover::some;
      float ent0 = 0, ent1 = 0, ex0 = 0, ex1 = 0;
      if (P.frustum) {
        c0 = frustum_cover<Fast>(P, b0, ent0, ex0);
        c1 = frustum_cover<Fast>(P, b1, ent1, ex1);
      }
      if (c0 != Cover::none || c1 != Cover::none) {
        A a0, a1;
        a0.clear();
        a1.clear();
        if (c0 == Cover::all) a0 = act;
        if (c1 == Cover::all) a1 = act;
        if (c0 == Cover::some || c1 == Cover::some) {
          // the lanes' own tests, for the boxes the frustum leaves open
          PV near0 = PL::set1(INFINITY), near1 = near0;
          for (int k = act.begin(); k < act.end(); ++k) {
            const int g = act.at(k);
            unsigned lanes = act.mask[g];
            if constexpr (Any) lanes &= P.live[g];
            if (lanes == 0) continue;
            if constexpr (Stats) count_op(st, g, lanes);
            unsigned h0, h1;
            PV te0, te1;
            box2_group<SameSign, Fast>(P, g, b0, b1, h0, h1, te0, te1);
            if (c0 == Cover::some) a0.add(g, h0 & lanes);
            if (c1 == Cover::some) a1.add(g, h1 & lanes);
            if (!P.frustum) {  // the order of children from the lanes' entries
              near0 = PL::min(near0, PL::sel(h0 & lanes, PL::set1(INFINITY), te0));
              near1 = PL::min(near1, PL::sel(h1 & lanes, PL::set1(INFINITY), te1));
            }
          }
          if (!P.frustum) {
            ent0 = PL::hmin(near0);
            ent1 = PL::hmin(near1);
          }
        }
        const bool e0 = a0.empty(), e1 = a1.empty();
        if (!e0 || !e1) {
          int k = e0 ? 1 : 0;
          if (!e0 && !e1) {
            // closest hit: the nearer child first. Any hit: the longer chord first (the
            // frustum's widest span through the box), as the single-ray any-hit traversals
            // (longest_slot) — a shadow ray leaves its surface through the near boxes it
            // grazes; its occluder lies in the box it crosses longest (docs/benchmarks.md)
            if (Any && P.frustum) k = ex1 - ent1 > ex0 - ent0 ? 1 : 0;
            else k = ent1 < ent0 ? 1 : 0;
            if (sp >= MBVH_STACK2_ENTRIES) throw std::runtime_error("packet traversal stack overflow: the tree is deeper than its cap");
            stack[sp].node = n.link[2 + (1 - k)];
            stack[sp].act = k ? a0 : a1;
            ++sp;
            if constexpr (Stats)
              for (int i = 0; i < Packet::N; ++i) st[i].max_depth = std::max(st[i].max_depth, static_cast<std::uint32_t>(sp));
          }
          cur = n.link[2 + k];
          act = k ? a1 : a0;
          continue;
        }
      }
    } else if (cur != MBVH_EMPTY) {
      const Leaf l = v.leaves[~cur];
      for (std::uint32_t j = l.first; j < l.first + l.count; ++j) {
        const Tri& tri = v.tris[j];
        PV vb[3][3];
        const float* rows[3] = {tri.v0, tri.v1, tri.v2};
        for (int q = 0; q < 3; ++q)
          for (int a = 0; a < 3; ++a) vb[q][a] = PL::set1(rows[q][a]);
        bool any_left = false;
        for (int k = act.begin(); k < act.end(); ++k) {
          const int g = act.at(k);
          unsigned lanes = act.mask[g];
          if constexpr (Any) lanes &= P.live[g];
          if (lanes == 0) continue;
          if constexpr (Stats) {
            count_lanes(st, g, lanes, 0, 0, j == l.first ? 1 : 0, 1);
            count_op(st, g, lanes);
          }
          unsigned hit;
          if constexpr (Fast) hit = tri_group_mt<Any>(P, g, tri, vb, lanes);
          else hit = tri_group<Any, UniformK>(P, g, tri, vb, lanes);
          if constexpr (Any) {
            for (unsigned h = hit; h != 0; h &= h - 1) P.prim[g * kLanes + std::countr_zero(h)] = tri_prim(tri);
            P.live[g] = static_cast<LaneBits>(P.live[g] & ~hit);
            any_left = any_left || (lanes & ~hit) != 0;
          }
        }
        if constexpr (Any) {
          if (!any_left) break;
        }
      }
    }
    // pop the next entry with a lane left
    for (;;) {
      if (sp == 0) return;
      --sp;
      cur = stack[sp].node;
      act = stack[sp].act;
      if constexpr (Any) {
        bool left = false;
        for (int k = act.begin(); k < act.end() && !left; ++k) left = (act.mask[act.at(k)] & P.live[act.at(k)]) != 0;
        if (!left) continue;
      }
      break;
    }
  }
}

}  // namespace packet
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

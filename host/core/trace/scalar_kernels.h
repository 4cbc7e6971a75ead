// SPDX-License-Identifier: MIT
// scalar_kernels.h — the reference's kernel policy: boxes and triangles one by one (intersect.h),
// the leaf visit, the child choice and the MBVH8 push every traversal calls through its policy.
#pragma once
#include <bit>
#include <cstdint>

#include "host/core/trace/intersect.h"
#include "host/core/trace/view.h"
#include "host/core/trace/visit.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

namespace detail {

// LEAF (§4): closest hit keeps the smallest (t, prim) and shrinks tmax; any hit stops.
// Fast: Möller–Trumbore instead of the watertight test (the `fast` accuracy mode).
template <bool Any, class St, bool Fast = false>
[[gnu::always_inline]] inline bool visit_leaf(const TraceView& v, std::int32_t ref, const RayPre& r, float& tmax, Hit& best, St& st) {
  const Leaf l = v.leaves[~ref];
  st.leaf(ref);
  for (std::uint32_t i = l.first; i < l.first + l.count; ++i) {
    st.tri();
    float t, u, w;
    bool hit;
    if constexpr (Fast) hit = tri_test_mt(r, v.tris[i], tmax, t, u, w);
    else hit = tri_test(r, v.tris[i], tmax, t, u, w);
    if (hit) {
      const std::uint32_t prim = tri_prim(v.tris[i]);
      if constexpr (Any) {
        best = Hit{t, u, w, prim};
        return true;
      }
      if (t < best.t || prim < best.prim) {  // t <= best.t holds: equal t -> smaller prim id
        best = Hit{t, u, w, prim};
        tmax = t;
      }
    }
  }
  return false;
}

// Chord (occlusion queries): d receives each box's chord instead of its entry (box_test).
template <bool Chord, class St>
[[gnu::always_inline]] inline unsigned test2(const Node2& n, const RayPre& r, float tcull, float d[2], St& st) {
  st.node(2);
  const bool h0 = box_test<Chord>(r, n.c0[0], n.c0[1], n.c0[2], n.c0[3], n.zz[0], n.zz[1], tcull, d[0]);
  const bool h1 = box_test<Chord>(r, n.c1[0], n.c1[1], n.c1[2], n.c1[3], n.zz[2], n.zz[3], tcull, d[1]);
  return (h0 ? 1u : 0u) | (h1 ? 2u : 0u);
}

// A wide node's boxes one by one (the reference's MBVH4 and MBVH8 node test).
template <bool Chord = false, class N>
[[gnu::always_inline]] inline unsigned test_boxes(const N& n, const RayPre& r, float tcull, float* d) {
  unsigned mask = 0;
  for (int s = 0; s < node_width<N>(); ++s)
    if (box_test<Chord>(r, n.lo_x[s], n.hi_x[s], n.lo_y[s], n.hi_y[s], n.lo_z[s], n.hi_z[s], tcull, d[s])) mask |= 1u << s;
  return mask;
}

}  // namespace detail

/// The kernels a traversal calls, as a policy: a wide node's box test, the leaf visit, the child
/// choice and the MBVH8 push. The reference tests boxes and triangles one by one; the SIMD cpu
/// backends pass a policy that tests a node's four or eight slabs at once and four or eight
/// triangles at once with the same operations in the same order and the same choice among hits
/// (so every answer is bit-identical), and reuse these traversals unchanged. Fast: the `fast` accuracy mode (relax_ray's box test, Möller–Trumbore triangles).
template <bool Fast>
struct ScalarKernelsT {
  static constexpr bool uses_packs = false;
  static constexpr bool fast = Fast;
  /// The ray a traversal carries: a policy may extend RayPre with its own per-ray constants
  /// (the SIMD policies: broadcast vectors and near-plane offsets), filled once by finish().
  using Ray = RayPre;
  /// Validates `ray` and makes its constants (prepare_ray; a SIMD policy may do it in vector
  /// registers, with the same checks and bits); false for an invalid ray (a defined miss).
  [[gnu::always_inline]] static bool prepare(const mbvh::Ray& ray, Ray& r) { return prepare_ray(ray, r); }
  static void finish(Ray&, const TraceView&) {}
  template <class N>
  static void prefetch(const N&, const Ray&, unsigned) {}
  template <bool Chord = false, class N>
  [[gnu::always_inline]] static unsigned test(const N& n, const RayPre& r, float tcull, float* d) {
    return detail::test_boxes<Chord>(n, r, tcull, d);
  }
  template <bool Any, class St>
  [[gnu::always_inline]] static bool leaf(const TraceView& v, std::int32_t ref, const RayPre& r, float& tmax, Hit& best, St& st) {
    return detail::visit_leaf<Any, St, Fast>(v, ref, r, tmax, best, st);
  }
  /// The slot of `mask` with the smallest entry distance, ties to the lower slot.
  template <int W>
  static int nearest(unsigned mask, const float* d) { return detail::nearest_slot<W>(mask, d); }
  /// The slot of `mask` with the largest d (chords: occlusion order), ties to the lower slot.
  template <int W>
  static int longest(unsigned mask, const float* d) { return detail::longest_slot<W>(mask, d); }
  /// Pushes the MBVH8 children of `mask` highest slot first (they pop in ascending slot order);
  /// returns the new stack pointer. The stack has room for 8 entries past sp (a SIMD policy may
  /// store a whole row).
  static unsigned push8(std::int32_t* stack, unsigned sp, unsigned mask, const std::int32_t* child) {
    while (mask != 0) {
      const int s = 31 - std::countl_zero(mask);
      mask &= ~(1u << s);
      stack[sp++] = child[s];
    }
    return sp;
  }
  /// Pushes the MBVH8 children of `mask` (two or more) in `order` (a node's octant order: lane k's
  /// slot in bits 3k..3k+2, farthest first), so the last pushed, `top`'s slot, is the nearest;
  /// Dist: each entry's d beside it in `dist`. Returns the new stack pointer; the stack (and dist)
  /// have room for 8 entries past sp.
  template <bool Dist>
  static unsigned push_octant(std::int32_t* stack, float* dist, unsigned sp, unsigned mask, std::uint32_t order,
                              const std::int32_t* child, const float* d, int& top) {
    for (int k = 0; k < 8; ++k) {
      const int s = static_cast<int>((order >> (3 * k)) & 7u);
      if ((mask >> s) & 1u) {
        stack[sp] = child[s];
        if constexpr (Dist) dist[sp] = d[s];
        ++sp;
        top = s;
      }
    }
    return sp;
  }
  /// The hit children of `mask` by rank in `order` (push_octant's): bit j set where the slot of
  /// lane 7 - j (the j-th nearest) is hit — what the octant bitstack keeps per level.
  static unsigned octant_ranks(unsigned mask, std::uint32_t order) {
    unsigned ranks = 0;
    for (int j = 0; j < 8; ++j) ranks |= ((mask >> ((order >> (21 - 3 * j)) & 7u)) & 1u) << j;
    return ranks;
  }
};
using ScalarKernels = ScalarKernelsT<false>;

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

// SPDX-License-Identifier: MIT
// traverse.h — the scalar reference traversals every backend is checked against: stack-based and
// bitstack (Áfra & Szirmay-Kalos, "Stackless Multi-BVH Traversal for CPU, MIC and GPU Ray
// Tracing", CGF 2014) for MBVH2, MBVH4 and MBVH8 (Áfra's thesis, ch. 3), templated on the query (closest / any hit) and on a
// statistics policy (NoStats compiles every counter away). Pseudocode: TRAVERSAL.md §4.
#pragma once
#include <bit>
#include <stdexcept>
#include <cstdint>
#include <utility>
#include <vector>

#include "host/core/trace/intersect.h"
#include "host/core/trace/view.h"

namespace mbvh {

inline namespace MBVH_ISA_NS {

struct NoStats {
  static constexpr bool on = false;
  void node(unsigned) {}
  void leaf(std::int32_t) {}
  void tri() {}
  void climb() {}
  void retest() {}
  void depth(unsigned) {}
};

struct CountStats {
  static constexpr bool on = true;
  RayStats s;
  std::vector<std::int32_t>* leaf_log = nullptr;  ///< if set, every visited leaf in order
  void node(unsigned boxes) { ++s.nodes; s.box_tests += boxes; }
  void leaf(std::int32_t ref) { ++s.leaves; if (leaf_log) leaf_log->push_back(ref); }
  void tri() { ++s.tris; }
  void climb() { ++s.climbs; }
  void retest() { ++s.retests; }
  void depth(unsigned d) { if (d > s.max_depth) s.max_depth = d; }
};

/// Termination guard of checked builds (Debug and sanitizer builds define
/// MBVH_CHECK_TERMINATION): a tree traversal enters each node and leaf at most once, climbs at
/// most once per node and makes at most one sibling move per entry, so more loop steps than
/// 3 * nodes + 2 * leaves + 2 mean a corrupt tree; it throws instead of looping. Release builds
/// compile it away (validate_layout guards them).
struct StepGuard {
#ifdef MBVH_CHECK_TERMINATION
  std::size_t left;
  explicit StepGuard(const TraceView& v) : left(3 * v.nodes + 2 * v.leaf_count + 2) {}
  void step() {
    if (left-- == 0) throw std::runtime_error("traversal exceeded its step bound: the tree is corrupt");
  }
  void room(unsigned sp, unsigned need, unsigned capacity) {
    if (sp + need > capacity) throw std::runtime_error("traversal stack overflow: the tree is deeper than its cap");
  }
#else
  explicit StepGuard(const TraceView&) {}
  void step() {}
  void room(unsigned, unsigned, unsigned) {}
#endif
};

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

// Chord: d receives the boxes' chords (occlusion order), else their entry distances.
template <class K, bool Any, bool Chord = Any, class N, class St>
[[gnu::always_inline]] inline unsigned test_node(const N& n, const typename K::Ray& r, float tcull, float* d, St& st) {
  st.node(node_width<N>());
  return K::template test<Chord>(n, r, tcull, d);
}

// Closest hit lets the policy prefetch the hit children left for later (the SIMD policies do: a
// latency-bound walk over incoherent rays), all but the one entered now, which is read at once
// (prefetching it too cost 13 % of the instructions of a diffuse ray on Sibenik, callgrind); an
// occlusion query, which stops early, gains nothing.
template <class K, bool Any, class N>
[[gnu::always_inline]] inline void prefetch_pending(const N& n, const typename K::Ray& r, unsigned mask, int entered) {
  if constexpr (!Any) K::prefetch(n, r, mask & ~(1u << entered));
}

// MBVH2 child entered first: closest hit the nearer of two hit children, any hit the one with the
// longer chord (d holds chords then); ties to child 0.
template <bool Any>
inline int first_slot2(unsigned mask, const float d[2]) {
  if (mask == 3u) return Any ? (d[1] > d[0] ? 1 : 0) : (d[1] < d[0] ? 1 : 0);
  return (mask & 1u) ? 0 : 1;
}

// The hit slot of `mask` with the smallest d (Largest: the largest), ties to the lower slot.
template <int W, bool Largest>
inline int extreme_slot(unsigned mask, const float* d) {
  int q = std::countr_zero(mask);
  for (int s = q + 1; s < W; ++s)
    if (((mask >> s) & 1u) && (Largest ? d[s] > d[q] : d[s] < d[q])) q = s;
  return q;
}

// Nearest slot of `mask` by entry distance, ties to the lower slot (variant B and its twin order
// every child by distance, for both queries).
template <int W = 4>
inline int nearest_slot(unsigned mask, const float* d) { return extreme_slot<W, false>(mask, d); }

// The hit slot of largest d, ties to the lower slot: for an occlusion query, whose d are chords,
// the child the ray crosses longest, the likeliest to hold an occluder (the work per shadow ray
// falls on every shared scene: Sibenik's MBVH8 nodes -27 %, leaves -24 %, the bunny's leaves -20 %,
// against the lowest slot first). max_nan makes chords never NaN, so any order of comparison
// finds the same slot (the SIMD policies reduce in registers).
template <int W>
inline int longest_slot(unsigned mask, const float* d) { return extreme_slot<W, true>(mask, d); }

// Slot entered first: closest hit the smallest entry distance, any hit the longest chord; ties to
// the lower slot (identical in stack and bitstack code).
template <bool Any>
inline int first_slot4(unsigned mask, const float d[4]) { return extreme_slot<4, Any>(mask, d); }

inline std::uint64_t skip_code(unsigned mask, int i) {  // rot(mask, i), TRAVERSAL.md §3.3
  return ((mask >> (i + 1)) | (mask << (3 - i))) & 7u;
}

}  // namespace detail

/// The kernels a traversal calls, as a policy: the MBVH4 four-box test and the leaf visit. The
/// reference tests boxes and triangles one by one; the SIMD cpu backends pass a policy that tests
/// all four slabs at once and four triangles at once with the same operations in the same order
/// and the same choice among hits (so every answer is bit-identical), and reuse these traversals
/// unchanged. Fast: the `fast` accuracy mode (relax_ray's box test, Möller–Trumbore triangles).
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
};
using ScalarKernels = ScalarKernelsT<false>;

/// MBVH2, stack-based (Aila–Laine order without postponed leaves): nearest child first, the far
/// child pushed when both are hit.
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh2_stack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t stack[MBVH_STACK2_ENTRIES];
  unsigned sp = 0;
  std::int32_t cur = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node2& n = v.n2[cur];
      float d[2];
      const unsigned m = detail::test2<Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int k = detail::first_slot2<Any>(m, d);
        if (m == 3u) {
          guard.room(sp, 1, MBVH_STACK2_ENTRIES);
          stack[sp++] = n.link[2 + (1 - k)];
          st.depth(sp);
        }
        cur = n.link[2 + k];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    if (sp == 0) return best;
    cur = stack[--sp];
  }
}

/// MBVH2 bitstack (TRAVERSAL.md §4.2): one bit per level, 1 = the sibling is still pending;
/// backtracking climbs parent links to the deepest pending level and moves to the sibling.
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh2_bitstack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t cur = 0, par = MBVH_NONE, sib = MBVH_NONE;
  std::uint64_t bits = 0;
  unsigned level = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node2& n = v.n2[cur];
      float d[2];
      const unsigned m = detail::test2<Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int k = detail::first_slot2<Any>(m, d);
        bits = (bits << 1) | (m == 3u ? 1u : 0u);  // push
        if constexpr (St::on) st.depth(++level);
        par = cur;
        sib = n.link[2 + (1 - k)];
        cur = n.link[2 + k];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    // -- backtrack: climb to the deepest level with a pending sibling
    while ((bits & 1u) == 0) {
      if (bits == 0) return best;
      guard.step();
      cur = par;
      par = v.n2[cur].link[0];
      sib = v.n2[cur].link[1];
      bits >>= 1;
      st.climb();
      if constexpr (St::on) --level;
    }
    bits ^= 1u;  // the sibling is now taken
    const std::int32_t t = cur;
    cur = sib;
    sib = t;
  }
}

/// MBVH4, stack-based twin of the skip-code traversal (TRAVERSAL.md §4.5): enter the nearest
/// hit child, push the other hit children in reverse cyclic order so they pop in cyclic order.
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh4_stack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t stack[MBVH_STACK4_ENTRIES];
  unsigned sp = 0;
  std::int32_t cur = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node4& n = v.n4[cur];
      float d[4];
      const unsigned m = detail::test_node<K, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = detail::first_slot4<Any>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, i);
        guard.room(sp, 3, MBVH_STACK4_ENTRIES);
        for (int k = 2; k >= 0; --k) {
          const int s = (i + 1 + k) & 3;
          if ((m >> s) & 1u) stack[sp++] = n.child[s];
        }
        st.depth(sp);
        cur = n.child[i];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    if (sp == 0) return best;
    cur = stack[--sp];
  }
}

/// MBVH4 bitstack with skip codes (TRAVERSAL.md §4.3): 3 bits per level, the code of a level
/// marks which cyclic siblings of the current node are pending. Kept as (parent, slot) rather
/// than §3.3's three cached sibling registers: a sibling move reads the parent's child link at
/// the cyclic slot (the parent's line is hot: it was tested last on that level) instead of
/// permuting four registers through memory; a climb reads only the parent link, and after the
/// last climb of a backtrack the slot is found among the parent's four links. Same visit
/// sequence as the register form and the stack twin; 7% fewer instructions than the register
/// form on Sponza's shadow rays (callgrind, issue 14).
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh4_bitstack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t cur = 0, par = MBVH_NONE;
  int slot = 0;
  std::uint64_t bits = 0;
  unsigned level = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node4& n = v.n4[cur];
      float d[4];
      const unsigned m = detail::test_node<K, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = detail::first_slot4<Any>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, i);
        bits = (bits << 3) | detail::skip_code(m, i);  // push
        if constexpr (St::on) st.depth(++level);
        par = cur;
        slot = i;
        cur = n.child[i];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    // -- backtrack: climb while the current level has no pending sibling (parent links only)
    std::uint64_t code = bits & 7u;
    if (code == 0) {
      do {
        if (bits == 0) return best;
        guard.step();
        cur = par;
        par = v.n4[cur].parent;
        bits >>= 3;
        st.climb();
        if constexpr (St::on) --level;
        code = bits & 7u;
      } while (code == 0);
      const Node4& p = v.n4[par];
      slot = 0;
      for (int s = 1; s < 4; ++s)
        if (p.child[s] == cur) slot = s;
    }
    // -- move to the next pending sibling: skip k, keep the rest relative to the new node
    const int k = std::countr_zero(code);
    const std::uint64_t rest = code >> (k + 1);
    bits ^= code ^ rest;
    slot = (slot + 1 + k) & 3;
    cur = v.n4[par].child[slot];
  }
}

namespace detail {


template <class N> const N* nodes_of(const TraceView& v);
template <> inline const Node4* nodes_of<Node4>(const TraceView& v) { return v.n4; }
template <> inline const Node8* nodes_of<Node8>(const TraceView& v) { return v.n8; }

}  // namespace detail

/// MBVH4 and MBVH8, Embree-like ordered stack (TRAVERSAL.md §4.5, variant B's twin; for MBVH8
/// the 8-wide single-ray traversal of Áfra's thesis, ch. 3): hit children pushed with their entry
/// distances, the nearest entered, the rest popped nearest first — sorting specialised by the
/// number of hits: 1: no push; 2: push the farther; 3: two pushes, one compare; 4-8: push all
/// and insertion-sort by (d, slot). A popped entry beyond the current tmax * S is culled.
/// Any hit: d is the chord (as the stack's longest_slot), the longest entered and popped first,
/// nothing culled (the query ends at its first hit, so tmax never shrinks): nearest-first made
/// a shadow ray test the boxes it only grazes leaving its surface (Sibenik 1.6x slower).
template <bool Any, class St, class K = ScalarKernels, class N = Node4>
inline Hit trace_wide_stack_ordered(const TraceView& v, const typename K::Ray& r, St& st) {
  struct Entry {  // 8 bytes, as Embree's (node, distance) entries
    std::int32_t node;
    float d;
  };
  constexpr int W = node_width<N>();
  constexpr unsigned kEntries = W == 4 ? MBVH_STACK4_ENTRIES : MBVH_STACK8_ENTRIES;
  const N* nodes = detail::nodes_of<N>(v);
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  Entry stack[kEntries];
  unsigned sp = 0;
  std::int32_t cur = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const N& n = nodes[cur];
      float d[W];
      const unsigned m = detail::test_node<K, Any, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int q = Any ? K::template longest<W>(m, d) : K::template nearest<W>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, q);
        unsigned others = m & ~(1u << q);
        guard.room(sp, W - 1, kEntries);
        if (others != 0) {
          const int a = 31 - std::countl_zero(others);  // highest slot first (deepest on ties)
          others &= ~(1u << a);
          if (others == 0) {
            stack[sp++] = Entry{n.child[a], d[a]};
          } else if ((others & (others - 1)) == 0) {
            const int b = std::countr_zero(others);  // b < a: pop b first unless d[a] < d[b]
            if (Any ? d[a] > d[b] : d[a] < d[b]) {
              stack[sp++] = Entry{n.child[b], d[b]};
              stack[sp++] = Entry{n.child[a], d[a]};
            } else {
              stack[sp++] = Entry{n.child[a], d[a]};
              stack[sp++] = Entry{n.child[b], d[b]};
            }
          } else {
            const unsigned base = sp;
            stack[sp++] = Entry{n.child[a], d[a]};
            for (int s = a - 1; s >= 0; --s)  // reverse slot order, then a stable sort by d
              if ((others >> s) & 1u) stack[sp++] = Entry{n.child[s], d[s]};
            for (unsigned i = base + 1; i < sp; ++i)
              for (unsigned j = i; j > base && (Any ? stack[j - 1].d > stack[j].d : stack[j - 1].d < stack[j].d); --j)
                std::swap(stack[j - 1], stack[j]);
          }
        }
        st.depth(sp);
        cur = n.child[q];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    // -- pop, culling entries beyond the best hit
    for (;;) {
      if (sp == 0) return best;
      const Entry e = stack[--sp];
      if (!Any && e.d > tmax * kCullSlack) continue;
      cur = e.node;
      break;
    }
  }
}

/// MBVH8, stack-based twin of the MBVH8 bitstack below: enter the first child (closest hit: the
/// nearest, ties to the lower slot; any hit: the longest chord, longest_slot), push the other hit
/// children highest slot first (K::push8: one permute, one
/// compress and one store on AVX-512), so they pop in ascending slot order.
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh8_stack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t stack[MBVH_STACK8_ENTRIES];
  unsigned sp = 0;
  std::int32_t cur = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      float d[8];
      const unsigned m = detail::test_node<K, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = Any ? K::template longest<8>(m, d) : K::template nearest<8>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, i);
        guard.room(sp, 8, MBVH_STACK8_ENTRIES);
        sp = K::push8(stack, sp, m & ~(1u << i), n.child);
        st.depth(sp);
        cur = n.child[i];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    if (sp == 0) return best;
    cur = stack[--sp];
  }
}

/// MBVH8 bitstack (Áfra & Szirmay-Kalos 2014, §3 of the paper, on the 8-wide nodes of Áfra's
/// thesis, ch. 3; the encoding is ours, not yet in TRAVERSAL.md): 7 skip bits per level do not fit a 64-bit word at
/// the MBVH8 depth cap (14 levels, 98 bits), so the word is 128 bits (two uint64, §3.5's push and
/// pop) and a level's code is the parent's pending-slot mask itself — 8 bits, absolute slots, the
/// entered child's bit cleared (16 levels fit, the cap stays 14). The next sibling is the lowest
/// pending slot (the stack twin's pop order), read from the parent, which stays in a register: a sibling move re-fetches
/// nothing but the parent's child link; only a climb reads a record (the parent link). State:
/// node + 128-bit word = 20 bytes against 520 (plain stack twin) and 1032 (ordered stack).
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh8_bitstack(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t cur = 0;
  const Node8* par = nullptr;
  std::uint64_t lo = 0, hi = 0;
  unsigned level = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      float d[8];
      const unsigned m = detail::test_node<K, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = Any ? K::template longest<8>(m, d) : K::template nearest<8>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, i);
        hi = (hi << 8) | (lo >> 56);  // push the pending slots
        lo = (lo << 8) | (m & ~(1u << i));
        if constexpr (St::on) st.depth(++level);
        par = &n;
        cur = n.child[i];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    // -- backtrack: climb while the current level has no pending sibling (parent links only)
    std::uint64_t code;
    for (;;) {
      if ((lo | hi) == 0) return best;
      code = lo & 0xFFu;
      if (code != 0) break;
      guard.step();
      par = &v.n8[par->parent];  // a level with pending bits lies above: never the root's parent
      lo = (lo >> 8) | (hi << 56);  // pop
      hi >>= 8;
      st.climb();
      if constexpr (St::on) --level;
    }
    // -- the lowest pending slot of this level
    const int k = std::countr_zero(code);
    lo ^= std::uint64_t{1} << k;
    cur = par->child[k];
  }
}

/// MBVH4 bitstack, variant B (TRAVERSAL.md §3.4, §4.4; mbvh's extension of Áfra &
/// Szirmay-Kalos 2014): the same skip codes, but each move to a sibling re-tests the parent's
/// four boxes against the current tmax, takes the nearest pending child and drops those now
/// beyond tmax — the visit sequence of the ordered, culling stack above (any hit: the longest
/// chord first, as there).
template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh4_bitstack_retest(const TraceView& v, const typename K::Ray& r, St& st) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  StepGuard guard(v);
  std::int32_t cur = 0, par = MBVH_NONE;
  int slot = -1;
  std::uint64_t bits = 0;
  unsigned level = 0;
  for (;;) {
    guard.step();
    if (cur >= 0) {
      const Node4& n = v.n4[cur];
      float d[4];
      const unsigned m = detail::test_node<K, Any, Any>(n, r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = detail::first_slot4<Any>(m, d);
        detail::prefetch_pending<K, Any>(n, r, m, i);
        bits = (bits << 3) | detail::skip_code(m, i);  // push
        if constexpr (St::on) st.depth(++level);
        par = cur;
        slot = i;
        cur = n.child[i];
        continue;
      }
    } else if (K::template leaf<Any>(v, cur, r, tmax, best, st)) {
      return best;
    }
    // -- backtrack: re-test the parent for the nearest live pending sibling, else climb
    for (;;) {
      guard.step();
      if (bits == 0) return best;
      const std::uint64_t code = bits & 7u;
      if (code != 0) {
        const Node4& p = v.n4[par];
        float d[4];
        st.retest();
        const unsigned m = K::template test<Any>(p, r, tmax * kCullSlack, d);
        unsigned pending = 0;
        for (int k = 0; k < 3; ++k)
          if ((code >> k) & 1u) pending |= 1u << ((slot + 1 + k) & 3);
        const unsigned live = pending & m;
        if (live != 0) {
          const int q = detail::first_slot4<Any>(live, d);
          bits ^= code ^ detail::skip_code(live & ~(1u << q), q);
          cur = p.child[q];
          slot = q;
          break;
        }
      }
      cur = par;  // climb (also when every pending sibling was culled)
      par = v.n4[cur].parent;
      slot = -1;
      if (par != MBVH_NONE)
        for (int s = 0; s < 4; ++s)
          if (v.n4[par].child[s] == cur) slot = s;
      bits >>= 3;
      st.climb();
      if constexpr (St::on) --level;
    }
  }
}

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

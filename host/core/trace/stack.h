// SPDX-License-Identifier: MIT
// stack.h — the stack-based traversals: MBVH2, MBVH4 and MBVH8 with a plain stack of nodes, and
// the ordered stack of (node, distance) entries for MBVH4 and MBVH8. Pseudocode: TRAVERSAL.md §4.5.
#pragma once
#include <bit>
#include <cstdint>
#include <cstring>
#include <utility>

#include "host/core/trace/intersect.h"
#include "host/core/trace/scalar_kernels.h"
#include "host/core/trace/stats.h"
#include "host/core/trace/view.h"
#include "host/core/trace/visit.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

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

/// MBVH4 and MBVH8, Embree-like ordered stack (TRAVERSAL.md §4.5, bitstack-retest's twin; for MBVH8
/// the 8-wide single-ray traversal of Áfra's thesis, ch. 3): hit children pushed with their entry
/// distances, the nearest entered, the rest popped nearest first — sorting specialised by the
/// number of hits: 1: no push; 2: push the farther; 3: two pushes, one compare; 4-8: push all
/// and insertion-sort by (d, slot). A popped entry beyond the current tmax * S is culled.
/// Any hit: d is the chord (as the stack's longest_slot), the longest entered and popped first,
/// nothing culled (the query ends at its first hit, so tmax never shrinks): nearest-first makes
/// a shadow ray test the boxes it only grazes leaving its surface.
/// The walk's state and one step of it, so that a driver may advance two rays in turn
/// (batch.h's run_interleaved, closest and any hit) with the single-ray traversal's code.
/// Where K has a sorted push of an MBVH8 node's hits (K::push_sorted8; closest hit) and Sorted is
/// on, it replaces the insertion sort of four or more hits (the same order, without a branch on
/// the distances): for incoherent rays, whose sort branches mispredict; on coherent ones (batch.h
/// walks them two in turn) the branches predict well and the insertion sort is cheaper.
template <class K, bool Any, int W>
constexpr bool sorted_push8() {
  if constexpr (Any || W != 8) return false;
  else if constexpr (requires { K::sorted_push8; }) return K::sorted_push8;
  else return false;
}

template <bool Any, class St, class K, class N, bool Sorted = true>
struct OrderedWalk {
  struct Entry {  // 8 bytes, as Embree's (node, distance) entries
    std::int32_t node;
    float d;
  };
  static constexpr int W = node_width<N>();
  static constexpr unsigned kEntries = W == 4 ? MBVH_STACK4_ENTRIES : MBVH_STACK8_ENTRIES;
  const TraceView& v;
  const N* nodes;
  const typename K::Ray* r;
  Hit best;
  float tmax;
  float tcull;  ///< tmax * S, made once per ray for an occlusion query (its tmax never shrinks)
  StepGuard guard;
  unsigned sp;
  std::int32_t cur;
  // + 1 where K::push_sorted8 runs: it stores a whole row of eight at sp <= kEntries - 7
  Entry stack[kEntries + (Sorted && sorted_push8<K, Any, W>() ? 1 : 0)];

  OrderedWalk(const TraceView& view, const typename K::Ray& ray) : v(view), nodes(detail::nodes_of<N>(view)), r(&ray), guard(view) {
    start();
  }
  /// Starts the walk of the ray given at construction (its values as they are now).
  [[gnu::always_inline]] void start() {
    best = miss_hit();
    tmax = r->tmax;
    tcull = tmax * kCullSlack;
    guard = StepGuard(v);
    sp = 0;
    cur = 0;
  }
  /// One node or leaf visit and the pop after it; false once the ray is done (its answer in best).
  [[gnu::always_inline]] bool step(St& st) {
    guard.step();
    if (cur >= 0) {
      const N& n = nodes[cur];
      float d[W];
      const unsigned m = detail::test_node<K, Any, Any>(n, *r, Any ? tcull : tmax * kCullSlack, d, st);
      if (m) {
        const int q = Any ? K::template longest<W>(m, d) : K::template nearest<W>(m, d);
        detail::prefetch_pending<K, Any>(n, *r, m, q);
        unsigned others = m & ~(1u << q);
        guard.room(sp, W - 1, kEntries);
        if (others != 0) {
          const int a = 31 - std::countl_zero(others);  // highest slot first (deepest on ties)
          others &= ~(1u << a);
          if (others == 0) {
            stack[sp++] = Entry{n.child[a], d[a]};
          } else if ((others & (others - 1)) == 0) {
            const int b = std::countr_zero(others);  // b < a: pop b first unless d[a] < d[b]
            // the order without a branch (it is not on the way to the child entered now, and
            // mispredicts often on incoherent rays): `under` is pushed first, popped last
            const int swap = -static_cast<int>(Any ? d[a] > d[b] : d[a] < d[b]);
            const int under = a ^ ((a ^ b) & swap), over = a ^ b ^ under;
            stack[sp] = Entry{n.child[under], d[under]};
            stack[sp + 1] = Entry{n.child[over], d[over]};
            sp += 2;
          } else if constexpr (Sorted && sorted_push8<K, Any, W>()) {
            K::push_sorted8(stack + sp, m, n.child, d);  // all hits, the nearest (q) last
            sp += static_cast<unsigned>(std::popcount(m)) - 1;
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
        return true;
      }
    } else if (K::template leaf<Any>(v, cur, *r, tmax, best, st)) {
      return false;
    }
    // -- pop, culling entries beyond the best hit
    for (;;) {
      if (sp == 0) return false;
      const Entry e = stack[--sp];
      if (!Any && e.d > tmax * kCullSlack) continue;
      cur = e.node;
      return true;
    }
  }
};

template <bool Any, class St, class K = ScalarKernels, class N = Node4>
inline Hit trace_wide_stack_ordered(const TraceView& v, const typename K::Ray& r, St& st) {
  return walk_to_end<OrderedWalk<Any, St, K, N>>(v, r, st);
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

/// MBVH8, the octant-ordered stack (Fuetterling, Lojewski, Pfreundt & Ebert, "Accelerated Single
/// Ray Tracing for Wide Vector Units", HPG 2017): each node holds, per ray direction octant, its
/// children's order along that octant's diagonal (mbvh_layout.h, Node8::pad; set_octant_order),
/// so a node's hit children are pushed in that order with no sort and no branch on their number
/// (K::push_octant: a permute and a compress), and the last pushed entered at once (read from
/// the node, not the stack). One hit child is entered without a push.
/// Closest hit walks the ray's own octant's order, nearest first, keeps each entry's distance
/// beside it and culls a popped entry beyond tmax * S, as the ordered stack does. Any hit walks
/// the opposite octant's order: the child reaching farthest along the ray first (its far corner
/// on the ray's diagonal), so a shadow ray leaves the boxes around its own origin — its surface,
/// which cannot occlude it — for last; nothing is culled (the query ends at its first hit).
/// The walk's state and one step of it (as OrderedWalk), so that a driver may advance two rays in
/// turn (batch.h's run_interleaved) with the single-ray traversal's code.
template <bool Any, class St, class K>
struct OctantWalk {
  const TraceView& v;
  const typename K::Ray* r;
  Hit best;
  float tmax;
  float tcull;  ///< tmax * S, made once per ray for an occlusion query (its tmax never shrinks)
  StepGuard guard;
  unsigned sp;
  unsigned oct;  ///< the order's byte in Node8::pad: the ray's octant (closest hit) or the opposite one (any hit)
  std::int32_t cur;
  std::int32_t stack[MBVH_STACK8_ENTRIES];
  float dist[Any ? 1 : MBVH_STACK8_ENTRIES];

  OctantWalk(const TraceView& view, const typename K::Ray& ray) : v(view), r(&ray), guard(view) { start(); }
  /// Starts the walk of the ray given at construction (its values as they are now).
  [[gnu::always_inline]] void start() {
    best = miss_hit();
    tmax = r->tmax;
    tcull = tmax * kCullSlack;
    guard = StepGuard(v);
    sp = 0;
    cur = 0;
    oct = 3u * (static_cast<unsigned>(r->neg[0] | r->neg[1] << 1 | r->neg[2] << 2) ^ (Any ? 7u : 0u));
  }
  /// One node or leaf visit and the pop after it; false once the ray is done (its answer in best).
  [[gnu::always_inline]] bool step(St& st) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      float d[8];
      const unsigned m = detail::test_node<K, Any, false>(n, *r, Any ? tcull : tmax * kCullSlack, d, st);
      if (m) {
        if ((m & (m - 1)) == 0) {  // one hit child: entered, nothing pushed
          cur = n.child[std::countr_zero(m)];
          return true;
        }
        std::uint32_t order;
        std::memcpy(&order, reinterpret_cast<const unsigned char*>(n.pad) + oct, sizeof(order));
        guard.room(sp, 8, MBVH_STACK8_ENTRIES);
        int top = 0;  // push_octant sets it (GCC 12 cannot see that: -Wmaybe-uninitialized)
        sp = K::template push_octant<!Any>(stack, dist, sp, m, order, n.child, d, top) - 1;
        detail::prefetch_pending<K, Any>(n, *r, m, top);
        cur = n.child[top];
        st.depth(sp);
        return true;
      }
    } else if (K::template leaf<Any>(v, cur, *r, tmax, best, st)) {
      return false;
    }
    for (;;) {  // pop, culling (closest hit) entries beyond the best hit
      if (sp == 0) return false;
      --sp;
      if (!Any && dist[Any ? 0 : sp] > tmax * kCullSlack) continue;
      cur = stack[sp];
      return true;
    }
  }
};

template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh8_octant(const TraceView& v, const typename K::Ray& r, St& st) {
  return walk_to_end<OctantWalk<Any, St, K>>(v, r, st);
}

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

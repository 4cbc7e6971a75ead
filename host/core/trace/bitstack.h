// SPDX-License-Identifier: MIT
// bitstack.h — the bitstack traversals (Áfra & Szirmay-Kalos, "Stackless Multi-BVH Traversal for
// CPU, MIC and GPU Ray Tracing", CGF 2014): MBVH2, MBVH4 with skip codes, MBVH8 with a 128-bit
// word, and MBVH4 bitstack-retest. Pseudocode: TRAVERSAL.md §4.2-4.4.
#pragma once
#include <bit>
#include <cstdint>
#include <cstring>

#include "host/core/trace/intersect.h"
#include "host/core/trace/scalar_kernels.h"
#include "host/core/trace/stats.h"
#include "host/core/trace/view.h"
#include "host/core/trace/visit.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

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

/// MBVH4 bitstack with skip codes (TRAVERSAL.md §4.3): 3 bits per level, the code of a level
/// marks which cyclic siblings of the current node are pending. Kept as (parent, slot) rather
/// than §3.3's three cached sibling registers: a sibling move reads the parent's child link at
/// the cyclic slot (the parent's line is hot: it was tested last on that level) instead of
/// permuting four registers through memory; a climb reads only the parent link, and after the
/// last climb of a backtrack the slot is found among the parent's four links. Same visit
/// sequence as the register form and the stack twin, in fewer instructions.
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
/// Where the MBVH8 bitstack's backtrack goes: `up` levels above the current parent, to its lowest
/// pending slot.
struct Backtrack8 {
  int up, slot;
};
/// The climb of the MBVH8 bitstacks' backtrack on their 128-bit word (lo, hi; byte j: the pending
/// slots or ranks of the j-th level above the current parent; not both 0): the deepest level with
/// a pending sibling is the word's lowest non-zero byte. The word becomes that level's (the levels
/// climbed past popped in one shift rather than a test and shift a level); returns how many
/// levels to climb and that level's lowest pending bit, left set (the octant bitstack may re-test
/// the level before it takes one).
[[gnu::always_inline]] constexpr Backtrack8 climb8(std::uint64_t& lo, std::uint64_t& hi) {
  int up = 0;
  if (lo == 0) {  // none in the lower 8 levels: all 8 climbed (rare; the depth cap is 14)
    lo = hi;
    hi = 0;
    up = 8;
  }
  const int low = std::countr_zero(lo);
  if (const int u = low >> 3; u != 0) {
    const int sh = u << 3;  // 8 to 56 bits
    lo = (lo >> sh) | (hi << (64 - sh));
    hi >>= sh;
    up += u;
  }
  return {up, low & 7};
}
/// The MBVH8 bitstack's backtrack: climb8, then the slot taken (its bit cleared).
[[gnu::always_inline]] constexpr Backtrack8 backtrack8(std::uint64_t& lo, std::uint64_t& hi) {
  const Backtrack8 b = climb8(lo, hi);
  lo &= lo - 1;
  return b;
}
}  // namespace detail

/// MBVH8 bitstack (Áfra & Szirmay-Kalos 2014, §3 of the paper, on the 8-wide nodes of Áfra's
/// thesis, ch. 3; the encoding is mbvh's, TRAVERSAL.md does not describe it): 7 skip bits per
/// level do not fit a 64-bit word at the MBVH8 depth cap (14 levels, 98 bits), so the word is 128
/// bits (two uint64, §3.5's push and pop) and a level's code is the parent's pending-slot mask
/// itself — 8 bits, absolute slots, the entered child's bit cleared (16 levels fit, the cap stays
/// 14). The next sibling is the lowest pending slot (the stack twin's pop order), read from the
/// parent, which stays in a register: a sibling move re-fetches nothing but the parent's child
/// link; only a climb reads a record (the parent link). State:
/// node + 128-bit word = 20 bytes against 520 (plain stack twin) and 1032 (ordered stack).
/// The walk's state and one step of it, so that a driver may advance two rays in turn (batch.h's
/// run_interleaved, closest hit) with the single-ray traversal's code: the state is small, and
/// the walk's chain of dependent loads (a node, its child; a climb's parent links) leaves the
/// core idle on incoherent rays.
template <bool Any, class St, class K>
struct Mbvh8BitstackWalk {
  const TraceView& v;
  const typename K::Ray* r;
  Hit best;
  float tmax;
  StepGuard guard;
  std::int32_t cur;
  const Node8* par;
  std::uint64_t lo, hi;
  unsigned level;

  Mbvh8BitstackWalk(const TraceView& view, const typename K::Ray& ray) : v(view), r(&ray), guard(view) { start(); }
  /// Starts the walk of the ray given at construction (its values as they are now).
  [[gnu::always_inline]] void start() {
    best = miss_hit();
    tmax = r->tmax;
    guard = StepGuard(v);
    cur = 0;
    par = nullptr;
    lo = hi = 0;
    level = 0;
  }
  /// Up one level: par becomes its own parent (a level with pending bits lies above: never past the root).
  [[gnu::always_inline]] void climb(St& st) {
    guard.step();
    par = &v.n8[par->parent];
    st.climb();
    if constexpr (St::on) --level;
  }
  /// One node or leaf visit and the move after it; false once the ray is done (its answer in best).
  [[gnu::always_inline]] bool step(St& st) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      float d[8];
      const unsigned m = detail::test_node<K, Any>(n, *r, tmax * kCullSlack, d, st);
      if (m) {
        const int i = Any ? K::template longest<8>(m, d) : K::template nearest<8>(m, d);
        detail::prefetch_pending<K, Any>(n, *r, m, i);
        hi = (hi << 8) | (lo >> 56);  // push the pending slots
        lo = (lo << 8) | (m & ~(1u << i));
        if constexpr (St::on) st.depth(++level);
        par = &n;
        cur = n.child[i];
        return true;
      }
    } else if (K::template leaf<Any>(v, cur, *r, tmax, best, st)) {
      return false;
    }
    // -- backtrack (detail::backtrack8): climb to the deepest level with a pending sibling
    // (parent links only) and take its lowest pending slot
    if ((lo | hi) == 0) return false;
    const detail::Backtrack8 b = detail::backtrack8(lo, hi);
    for (int j = 0; j < b.up; ++j) climb(st);
    cur = par->child[b.slot];
    return true;
  }
};

template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh8_bitstack(const TraceView& v, const typename K::Ray& r, St& st) {
  return walk_to_end<Mbvh8BitstackWalk<Any, St, K>>(v, r, st);
}

/// MBVH8 octant bitstack: the MBVH8 bitstack's 128-bit word walked in the octant stack's order
/// (stack.h, OctantWalk: Fuetterling, Lojewski, Pfreundt & Ebert, HPG 2017, on Áfra &
/// Szirmay-Kalos's bitstack, CGF 2014). With the visiting order of a node's children fixed by the
/// ray's direction octant (Node8::pad's orders), a level's byte keeps the pending children by
/// rank in that order (bit j: the j-th child of the order, nearest first), so the child entered
/// is the lowest set rank, the next after a backtrack the lowest pending rank, and no distance is
/// needed to resume: the rank's slot is read back from the parent's order (the parent stays in a
/// register, its line hot). Closest hit: the octant stack culls a popped entry beyond tmax * S; a
/// backtrack here re-tests the parent's eight boxes against tmax * S instead (once a hit has
/// shrunk tmax: before it nothing can be culled) and drops the pending ranks that now miss — a
/// box entered at d is hit again exactly while d <= tmax * S, so the visit sequence, the leaves
/// and the answer are the octant stack's (its stackless twin) in robust precision; in fast
/// precision the two bounds (the stack's te - tol against tcull, the re-test's te against
/// tcull + tol) may differ by a rounding, which can change the nodes visited, never the answer's
/// distance (both stay above tmax * S). The re-test is skipped on the
/// levels pushed since tmax last shrank (tested against it already), and where the lowest pending
/// rank survives it the walk goes on to that child on a branch rather than a data dependency on
/// the re-test, whose latency then overlaps the child's fetch. Any hit walks the opposite
/// octant's order and culls nothing, as the octant stack. State: node + word + octant = 24 bytes.
/// The walk's state and one step of it, as Mbvh8BitstackWalk (batch.h's run_interleaved).
template <bool Any, class St, class K>
struct Mbvh8OctantBitstackWalk {
  const TraceView& v;
  const typename K::Ray* r;
  Hit best;
  float tmax;
  StepGuard guard;
  std::int32_t cur;
  const Node8* par;
  std::uint64_t lo, hi;
  unsigned oct;  ///< the order's byte in Node8::pad: the ray's octant (closest hit) or the opposite one (any hit)
  /// Closest hit: how many of the deepest levels were pushed since tmax last shrank (their ranks
  /// were tested against it: no re-test); before the first hit more than the depth cap.
  int fresh;
  unsigned level;

  Mbvh8OctantBitstackWalk(const TraceView& view, const typename K::Ray& ray) : v(view), r(&ray), guard(view) { start(); }
  /// Starts the walk of the ray given at construction (its values as they are now).
  [[gnu::always_inline]] void start() {
    best = miss_hit();
    tmax = r->tmax;
    guard = StepGuard(v);
    cur = 0;
    par = nullptr;
    lo = hi = 0;
    oct = 3u * (static_cast<unsigned>(r->neg[0] | r->neg[1] << 1 | r->neg[2] << 2) ^ (Any ? 7u : 0u));
    fresh = 64;
    level = 0;
  }
  /// Node n's order for this ray (lane k's slot in bits 3k..3k+2, farthest first).
  [[gnu::always_inline]] std::uint32_t order(const Node8& n) const {
    std::uint32_t o;
    std::memcpy(&o, reinterpret_cast<const unsigned char*>(n.pad) + oct, sizeof(o));
    return o;
  }
  /// The slot of rank j (0: the nearest) in `order`.
  [[gnu::always_inline]] static int slot(std::uint32_t order, int j) { return static_cast<int>((order >> (21 - 3 * j)) & 7u); }
  /// One node or leaf visit and the move after it; false once the ray is done (its answer in best).
  [[gnu::always_inline]] bool step(St& st) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      float d[8];
      const unsigned m = detail::test_node<K, Any, false>(n, *r, tmax * kCullSlack, d, st);
      if (m) {
        const std::uint32_t o = order(n);
        const unsigned ranks = K::octant_ranks(m, o);
        const int i = slot(o, std::countr_zero(ranks));
        detail::prefetch_pending<K, Any>(n, *r, m, i);
        hi = (hi << 8) | (lo >> 56);  // push the pending ranks
        lo = (lo << 8) | (ranks & (ranks - 1));
        if constexpr (!Any) ++fresh;
        if constexpr (St::on) st.depth(++level);
        par = &n;
        cur = n.child[i];
        return true;
      }
    } else {
      const float t0 = tmax;
      if (K::template leaf<Any>(v, cur, *r, tmax, best, st)) return false;
      if constexpr (!Any)
        if (tmax < t0) fresh = 0;
    }
    // -- backtrack: climb to the deepest level with a pending rank (detail::climb8, parent links
    // only), closest hit drop its ranks now beyond tmax * S where tmax shrank since the level's
    // push (else on up), take the lowest
    for (;;) {
      if ((lo | hi) == 0) return false;
      const int up = detail::climb8(lo, hi).up;
      for (int j = up; j > 0; --j) {
        guard.step();
        par = &v.n8[par->parent];
        st.climb();
        if constexpr (St::on) --level;
      }
      if constexpr (!Any) {
        fresh -= up;
        if (fresh <= 0) {
          float d[8];
          st.retest();
          const unsigned m = K::template test<false>(*par, *r, tmax * kCullSlack, d);
          const std::uint32_t o = order(*par);
          const int s = slot(o, std::countr_zero(lo));
          lo &= ~std::uint64_t{0xff} | K::octant_ranks(m, o);
          fresh = 1;
          // the lowest pending rank still hit (the usual case) is taken on a branch on the re-test,
          // not a wait for it: the next node's address comes from the word as it was
          if ((m >> s) & 1u) {
            lo &= lo - 1;
            cur = par->child[s];
            return true;
          }
          if ((lo & 0xffu) == 0) continue;
        }
      }
      const int j = std::countr_zero(lo);
      lo &= lo - 1;
      cur = par->child[slot(order(*par), j)];
      return true;
    }
  }
};

template <bool Any, class St, class K = ScalarKernels>
inline Hit trace_mbvh8_bitstack_octant(const TraceView& v, const typename K::Ray& r, St& st) {
  return walk_to_end<Mbvh8OctantBitstackWalk<Any, St, K>>(v, r, st);
}

/// MBVH4 bitstack-retest (TRAVERSAL.md §3.4, §4.4, "variant B"; mbvh's extension of Áfra &
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

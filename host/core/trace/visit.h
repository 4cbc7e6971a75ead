// SPDX-License-Identifier: MIT
// visit.h — what every traversal does at an inner node: test it through the kernel policy, ask for
// the children left for later, pick the child entered first, encode the pending siblings; and a
// step-struct walk run to its end.
#pragma once
#include <bit>
#include <cstdint>

#include "host/core/trace/intersect.h"  // MBVH_ISA_NS
#include "host/core/trace/view.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {

namespace detail {

// Chord: d receives the boxes' chords (occlusion order), else their entry distances.
template <class K, bool Any, bool Chord = Any, class N, class St>
[[gnu::always_inline]] inline unsigned test_node(const N& n, const typename K::Ray& r, float tcull, float* d, St& st) {
  st.node(node_width<N>());
  return K::template test<Chord>(n, r, tcull, d);
}

// Closest hit lets the policy prefetch the hit children left for later (the SIMD policies do: a
// latency-bound walk over incoherent rays), all but the one entered now, which is read at once
// (a prefetch of it only adds instructions); an occlusion query, which stops early, gains nothing.
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

// Nearest slot of `mask` by entry distance, ties to the lower slot (bitstack-retest and its twin
// order every child by distance, for both queries).
template <int W = 4>
inline int nearest_slot(unsigned mask, const float* d) { return extreme_slot<W, false>(mask, d); }

// The hit slot of largest d, ties to the lower slot: for an occlusion query, whose d are chords,
// the child the ray crosses longest, the likeliest to hold an occluder (a shadow ray then visits
// fewer nodes and leaves than with the lowest slot first). max_nan makes chords never NaN, so any
// order of comparison finds the same slot (the SIMD policies reduce in registers).
template <int W>
inline int longest_slot(unsigned mask, const float* d) { return extreme_slot<W, true>(mask, d); }

// Slot entered first: closest hit the smallest entry distance, any hit the longest chord; ties to
// the lower slot (identical in stack and bitstack code).
template <bool Any>
inline int first_slot4(unsigned mask, const float d[4]) { return extreme_slot<4, Any>(mask, d); }

inline std::uint64_t skip_code(unsigned mask, int i) {  // rot(mask, i), TRAVERSAL.md §3.3
  return ((mask >> (i + 1)) | (mask << (3 - i))) & 7u;
}

template <class N> const N* nodes_of(const TraceView& v);
template <> inline const Node4* nodes_of<Node4>(const TraceView& v) { return v.n4; }
template <> inline const Node8* nodes_of<Node8>(const TraceView& v) { return v.n8; }

}  // namespace detail

/// One ray walked to its end by a step struct (`Walk w(v, r); while (w.step(st)) {}`): the
/// single-ray form of the walks that batch.h also runs two rays in turn.
template <class Walk, class St, class R>
[[gnu::always_inline]] inline Hit walk_to_end(const TraceView& v, const R& r, St& st) {
  Walk w(v, r);
  while (w.step(st)) {
  }
  return w.best;
}

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

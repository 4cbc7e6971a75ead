// SPDX-License-Identifier: MIT
// wide_node.h — how the layouts' nodes are written (internal to host/core/bvh/): the one writer of
// a wide node's slots (Node4, Node8) for the greedy and SAH collapses and for refit, of an MBVH2
// node's two child boxes for make_mbvh2 and refit, and of the 16-wide view's boxes for
// make_mbvh4_wide and refit.
#pragma once
#include <cmath>
#include <cstdint>
#include <cstring>
#include <utility>

#include "host/core/layouts.h"
#include "host/core/trace/view.h"  // node_width

namespace mbvh::build {

/// The box in slot `s` of wide node `n`.
template <class N>
inline Box slot_box(const N& n, int s) {
  Box b;
  b.lo = {n.lo_x[s], n.lo_y[s], n.lo_z[s]};
  b.hi = {n.hi_x[s], n.hi_y[s], n.hi_z[s]};
  return b;
}

/// Writes box `b` into slot `s` of wide node `n`; the slot's child reference stays.
template <class N>
inline void set_slot(N& n, int s, const Box& b) {
  n.lo_x[s] = b.lo.x; n.hi_x[s] = b.hi.x;
  n.lo_y[s] = b.lo.y; n.hi_y[s] = b.hi.y;
  n.lo_z[s] = b.lo.z; n.hi_z[s] = b.hi.z;
}

/// Writes MBVH8 node `n`'s per-octant child order into its pad (mbvh_layout.h, Node8): for each
/// of the eight direction octants, the slots ordered by their box's near corner projected on the
/// octant's diagonal (the corner a ray of that octant meets first: lo on a positive axis, hi on a
/// negative one), the farthest first, ties to the higher slot first (so the lower pops first),
/// empty boxes before all (Fuetterling, Lojewski, Pfreundt & Ebert, "Accelerated Single Ray
/// Tracing for Wide Vector Units", HPG 2017: the order is made once per node, so the walk pushes
/// its hit children without sorting them). Only the octant traversals (stack-octant,
/// bitstack-octant) read it, and only for speed: any order gives the same answers.
inline void set_octant_order(Node8& n) {
  std::uint8_t bytes[sizeof(n.pad)] = {};
  for (unsigned o = 0; o < 8; ++o) {
    double key[8];
    int slot[8];
    for (int s = 0; s < 8; ++s) {
      slot[s] = s;
      const bool empty = !(n.lo_x[s] <= n.hi_x[s] && n.lo_y[s] <= n.hi_y[s] && n.lo_z[s] <= n.hi_z[s]);
      const double x = (o & 1u) ? -static_cast<double>(n.hi_x[s]) : n.lo_x[s];
      const double y = (o & 2u) ? -static_cast<double>(n.hi_y[s]) : n.lo_y[s];
      const double z = (o & 4u) ? -static_cast<double>(n.hi_z[s]) : n.lo_z[s];
      key[s] = empty ? INFINITY : x + y + z;
    }
    // insertion sort, farthest first (a higher slot first on equal keys)
    for (int i = 1; i < 8; ++i)
      for (int j = i; j > 0 && (key[slot[j - 1]] < key[slot[j]] || (key[slot[j - 1]] == key[slot[j]] && slot[j - 1] < slot[j])); --j)
        std::swap(slot[j - 1], slot[j]);
    std::uint32_t bits = 0;
    for (int k = 0; k < 8; ++k) bits |= static_cast<std::uint32_t>(slot[k]) << (3 * k);
    for (int b = 0; b < 3; ++b) bytes[3 * o + static_cast<unsigned>(b)] = static_cast<std::uint8_t>(bits >> (8 * b));
  }
  std::memcpy(n.pad, bytes, sizeof(bytes));
}

/// Writes every word of wide node `n`: slot s holds box_of(s) and child[s] (an empty slot: an
/// empty Box, never hit, and MBVH_EMPTY), then the parent link, and for MBVH4 the sibling links
/// as MBVH_NONE until the parent's children are linked (finish_mbvh4), for MBVH8 the per-octant
/// child order (set_octant_order; nodes of an AlignedVector start uninitialised). Returns the union of the slots' boxes.
template <class N, class BoxOf>
inline Box write_wide_node(N& n, const std::int32_t* child, std::int32_t parent, BoxOf&& box_of) {
  constexpr int W = node_width<N>();
  Box all;
  for (int s = 0; s < W; ++s) {
    const Box bx = box_of(s);
    all.grow(bx);
    set_slot(n, s, bx);
    n.child[s] = child[s];
  }
  n.parent = parent;
  if constexpr (W == 4) n.sib[0] = n.sib[1] = n.sib[2] = MBVH_NONE;
  else set_octant_order(n);
  return all;
}

/// Writes the two child boxes of MBVH2 node `d` (mbvh_layout.h, Node2); its links stay.
inline void set_boxes(Node2& d, const Box& b0, const Box& b1) {
  d.c0[0] = b0.lo.x; d.c0[1] = b0.hi.x; d.c0[2] = b0.lo.y; d.c0[3] = b0.hi.y;
  d.c1[0] = b1.lo.x; d.c1[1] = b1.hi.x; d.c1[2] = b1.lo.y; d.c1[3] = b1.hi.y;
  d.zz[0] = b0.lo.z; d.zz[1] = b0.hi.z; d.zz[2] = b1.lo.z; d.zz[3] = b1.hi.z;
}

/// Writes the boxes of MBVH4 node `n` into its 16-wide view `o` (mbvh_layout.h, Node4W): lanes
/// 0-2 of each slot's rows; lane 3 (the child and link words) stays.
inline void set_view_boxes(Node4W& o, const Node4& n) {
  for (int s = 0; s < 4; ++s) {
    o.lo[s][0] = n.lo_x[s];
    o.lo[s][1] = n.lo_y[s];
    o.lo[s][2] = n.lo_z[s];
    o.hi[s][0] = n.hi_x[s];
    o.hi[s][1] = n.hi_y[s];
    o.hi[s][2] = n.hi_z[s];
  }
}

}  // namespace mbvh::build

// SPDX-License-Identifier: MIT
// quant8.h — the cpu backend's quantized view of an MBVH8 layout (`cpu.quant8`): per node one
// 64-byte record with its eight child boxes in 8 bits per plane, relative to the node's own box,
// as the compressed wide nodes of Ylitie, Karras & Laine 2017 ("Efficient Incoherent Ray Traversal
// on GPUs Through Compressed Wide BVHs") and Embree's quantized BVH8 nodes. The walk still reads
// the MBVH8 nodes' child references (one line of the 256-byte node), the box test reads this
// record of the same index (one line instead of three).
#pragma once
#include <bit>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "mbvh/mbvh_layout.h"

namespace mbvh {

/// One MBVH8 node's child boxes, quantized: plane (row, slot) of the node's Node8 (rows lo_x,
/// hi_x, lo_y, hi_y, lo_z, hi_z) is decoded as origin[a] + float(q[row][slot]) * 2^exp[a], a =
/// row / 2, in float with one rounding (float(q) * 2^exp is exact). Conservative: the decoded lo
/// planes are at most the float node's, the hi planes at least, so a box test on the decoded
/// planes culls only what the float node's culls (a superset of the hit children: only the visit
/// order and the work change, never the exact leaf tests' answer). Slots outside `valid` hold
/// no child.
struct alignas(64) Node8Q {
  std::uint8_t q[6][8];
  float origin[3];
  std::int8_t exp[3];
  std::uint8_t valid;
};
static_assert(sizeof(Node8Q) == 64, "a quantized MBVH8 node is one cache line");

/// The decoded plane of a Node8Q: origin + q * 2^e (the kernel's float operations, in this order:
/// the product is exact, the sum rounds once).
inline float decode_plane(float origin, unsigned q, int e) {
  const float scale = std::bit_cast<float>(static_cast<std::uint32_t>(e + 127) << 23);  // 2^e, normal
  const float step = static_cast<float>(q) * scale;
  return origin + step;
}

/// The quantized records of `nodes` (the same index, topology untouched); empty when some child
/// box has a bound that is not finite (the float nodes are traced then).
std::vector<Node8Q> quantize_mbvh8(const Node8* nodes, std::size_t count);

}  // namespace mbvh

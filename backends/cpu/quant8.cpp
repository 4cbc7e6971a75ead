// SPDX-License-Identifier: MIT
// quant8.cpp — the quantized MBVH8 view (quant8.h): each plane rounded outward to the 8-bit grid
// of its node's box, checked by the kernel's own decoding (the float sum's rounding may move a
// plane inward by part of a step: the code then steps one further out).
#include "backends/cpu/quant8.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <cstring>

namespace mbvh {

namespace {

constexpr int kMinExp = -126, kMaxExp = 119;  // 2^e normal, 255 * 2^e finite

/// The smallest e for which the top of the grid, decoded, reaches hi (origin <= hi); false when
/// none does (a range past the float range).
bool grid_exp(float origin, float hi, int& e) {
  const double range = static_cast<double>(hi) - static_cast<double>(origin);
  e = range > 0 ? std::max(kMinExp, static_cast<int>(std::floor(std::log2(range / 255.0))) - 1) : kMinExp;
  for (; e <= kMaxExp; ++e)
    if (decode_plane(origin, 255, e) >= hi) return true;
  return false;
}

}  // namespace

std::vector<Node8Q> quantize_mbvh8(const Node8* nodes, std::size_t count) {
  std::vector<Node8Q> out(count);
  for (std::size_t i = 0; i < count; ++i) {
    const Node8& n = nodes[i];
    Node8Q& o = out[i];
    std::memset(&o, 0, sizeof o);
    const float* rows[6] = {n.lo_x, n.hi_x, n.lo_y, n.hi_y, n.lo_z, n.hi_z};
    for (int s = 0; s < 8; ++s)
      if (n.child[s] != MBVH_EMPTY) o.valid |= static_cast<std::uint8_t>(1u << s);
    for (int a = 0; a < 3; ++a) {
      const float* lo = rows[2 * a];
      const float* hi = rows[2 * a + 1];
      float origin = INFINITY, top = -INFINITY;
      for (int s = 0; s < 8; ++s) {
        if (!((o.valid >> s) & 1u)) continue;
        if (!std::isfinite(lo[s]) || !std::isfinite(hi[s])) return {};
        origin = std::min(origin, lo[s]);
        top = std::max(top, hi[s]);
      }
      if (o.valid == 0) origin = top = 0.0f;
      int e = 0;
      if (!grid_exp(origin, top, e)) return {};
      o.origin[a] = origin;
      o.exp[a] = static_cast<std::int8_t>(e);
      const double step = std::ldexp(1.0, e);
      for (int s = 0; s < 8; ++s) {
        if (!((o.valid >> s) & 1u)) {
          o.q[2 * a][s] = 255;  // an empty slot: an inverted box (the valid mask drops it anyway)
          o.q[2 * a + 1][s] = 0;
          continue;
        }
        // lower plane: the largest grid point at or below lo, by the kernel's decoding
        int ql = static_cast<int>(std::clamp(std::floor((static_cast<double>(lo[s]) - origin) / step), 0.0, 255.0));
        while (ql > 0 && decode_plane(origin, static_cast<unsigned>(ql), e) > lo[s]) --ql;
        // upper plane: the smallest grid point at or above hi
        int qh = static_cast<int>(std::clamp(std::ceil((static_cast<double>(hi[s]) - origin) / step), 0.0, 255.0));
        while (qh < 255 && decode_plane(origin, static_cast<unsigned>(qh), e) < hi[s]) ++qh;
        if (decode_plane(origin, static_cast<unsigned>(ql), e) > lo[s] || decode_plane(origin, static_cast<unsigned>(qh), e) < hi[s])
          return {};  // cannot happen (q = 0 decodes to origin, q = 255 reaches top): refuse rather than cull
        o.q[2 * a][s] = static_cast<std::uint8_t>(ql);
        o.q[2 * a + 1][s] = static_cast<std::uint8_t>(qh);
      }
    }
  }
  return out;
}

}  // namespace mbvh

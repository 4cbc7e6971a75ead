// SPDX-License-Identifier: MIT
// dacrt_scalar.cpp — the portable kernel policy of divide-and-conquer ray tracing (dacrt/recursion.h):
// one ray at a time, the reference's own box_test operations and tri_test (intersect.h). The
// `dacrt-scalar` backend; the reference the SIMD policy (dacrt/simd.h) reproduces bit for bit.
#include <bit>

#include "backends/cpu/dacrt/recursion.h"

namespace mbvh {
namespace {

struct ScalarPolicy {
  /// The whole prepared ray and the best hit so far, by id.
  struct Side {
    RayPre pre;
    Hit best;
  };
  struct Local {};

  static bool set_up(const Ray& r, dacrt::RayRec& rec, Side& side, bool fast) {
    if (!prepare_ray(r, side.pre)) return false;
    if (fast) relax_ray(side.pre);
    dacrt::fill_record(side.pre, rec);
    side.best = miss_hit();
    return true;
  }
  static Hit best(const dacrt::Work<ScalarPolicy>& w, std::size_t p) { return w.side[w.id[p]].best; }

  /// One bit a ray: box_hit, the reference's slab test.
  template <bool Fast>
  static std::size_t test(dacrt::Work<ScalarPolicy>& w, std::size_t n, const dacrt::Bounds& box) {
    std::size_t na = 0;
    for (std::size_t b = 0; b < n; b += 64) {
      std::uint64_t word = 0;
      const std::size_t e = std::min(n, b + 64);
      for (std::size_t p = b; p < e; ++p) word |= std::uint64_t(dacrt::box_hit<Fast>(w.rec[p], box) ? 1 : 0) << (p - b);
      w.bits[b / 64] = word;
      na += static_cast<std::size_t>(std::popcount(word));
    }
    return na;
  }

  template <bool Any, bool Fast, bool Stats>
  static void leaf(dacrt::Work<ScalarPolicy>& w, std::size_t na, std::uint32_t tb, std::uint32_t te) {
    for (std::size_t p = 0; p < na; ++p) {
      dacrt::RayRec& rec = w.rec[p];
      const std::uint32_t id = w.id[p];
      const RayPre& pre = w.side[id].pre;
      float tmax = rec.tmax;
      Hit best = w.side[id].best;
      for (std::uint32_t j = tb; j < te; ++j) {
        const Tri& tri = w.tris[w.tri[j].id];
        if constexpr (Stats) ++w.stats[id].tris;
        float t, u, v;
        const bool hit = Fast ? tri_test_mt(pre, tri, tmax, t, u, v) : tri_test(pre, tri, tmax, t, u, v);
        if (!hit) continue;
        const std::uint32_t prim = tri_prim(tri);
        if constexpr (Any) {
          w.occluded[id] = 1;
          tmax = -1.0f;  // below every tmin: every later filter drops the ray
          break;
        }
        if (t < best.t || prim < best.prim) {  // visit_leaf's rule: equal t -> smaller prim id
          best = Hit{t, u, v, prim};
          tmax = t;
        }
      }
      rec.tmax = tmax;
      if constexpr (!Any) w.side[id].best = best;
    }
  }
};

}  // namespace

void dacrt_scalar(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
                  const DacrtSettings& s, DacrtBuffers& buffers) {
  dacrt::trace<ScalarPolicy>(acc, rays, opt, out, threads, s, buffers);
}

}  // namespace mbvh

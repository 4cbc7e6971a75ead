// SPDX-License-Identifier: MIT
// occlusion.h — the `fast` precision's MBVH8 octant-ordered any-hit walk compiled once per ray
// direction octant (stack.h's OctantWalk<true> with the octant a template argument), and the batch
// driver that sorts a chunk's rays by octant to run it.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/kernels.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// A ray's direction octant: the sign bits of dx, dy, dz (RayPre::neg's, as prepare_ray_simd takes
/// them: -0 is negative).
[[gnu::always_inline]] inline unsigned ray_octant(const Ray& ray) {
  return static_cast<unsigned>(std::signbit(ray.dx)) | static_cast<unsigned>(std::signbit(ray.dy)) << 1 |
         static_cast<unsigned>(std::signbit(ray.dz)) << 2;
}

/// The MBVH8 octant-ordered stack's any-hit walk, `fast` precision, of a ray of direction octant Oct (stack.h,
/// OctantWalk<true>: the same nodes and leaves in the same order) with what depends on the octant
/// made constant — the near and far plane rows of each axis (finish_ray's near8 and far8) and the
/// order's offset in Node8::pad (the opposite octant's) — and the ray's broadcasts made once, at
/// start(), where OctantWalk's step reloads them at every node (Fuetterling et al. 2017 and
/// tinybvh's BVH8_CPU compile their walks per octant likewise). The node test is box_test_wide's
/// (F8; no distances stored: the any-hit push reads none), so its answers are the same bit for
/// bit; the child entered is read back from the row the push stored, not looked up by its slot
/// (off the order's bit field, a shorter chain from a node's test to its child's load).
/// start() and step() as OctantWalk's, so that two rays of one octant are walked in turn.
/// Fast only: robust precision's leaf (the watertight test's exact steps) leaves too few registers
/// for two rays' broadcasts, and its eight copies ran slower than OctantWalk (docs/backends.md).
template <unsigned Oct>
struct OctantOcclusionWalk {
  using K = SimdKernelsT<true>;
  using F = F8;
  using V = F8::V;
  // the rows lo_x, hi_x, lo_y, hi_y, lo_z, hi_z are 8 floats apart: near = (2a + neg) * 8, far = near ^ 8
  static constexpr int nx = (0 + static_cast<int>(Oct & 1u)) * 8, ny = (2 + static_cast<int>((Oct >> 1) & 1u)) * 8;
  static constexpr int nz = (4 + static_cast<int>((Oct >> 2) & 1u)) * 8;
  static constexpr int fx = nx ^ 8, fy = ny ^ 8, fz = nz ^ 8;
  static constexpr unsigned order_at = 3u * (Oct ^ 7u);  // any hit walks the opposite octant's order

  const TraceView& v;
  const SimdRay* r;
  V ix, iy, iz, ox, oy, oz, tmin, tfar;  // ix: inv (the fast ray's inv_far is inv), ox: o * inv
  StepGuard guard;
  unsigned sp;
  std::int32_t cur;
  Hit best;  ///< the answer, once step() returned false: a miss, or the occluder's prim
  std::int32_t stack[MBVH_STACK8_ENTRIES];

  OctantOcclusionWalk(const TraceView& view, const SimdRay& ray) : v(view), r(&ray), guard(view) {}
  /// Starts the walk of the ray given at construction (its values as they are now).
  [[gnu::always_inline]] void start() {
    ix = F::bcast(&r->inv[0]), iy = F::bcast(&r->inv[1]), iz = F::bcast(&r->inv[2]);
    ox = F::bcast(&r->oinv[0]), oy = F::bcast(&r->oinv[1]), oz = F::bcast(&r->oinv[2]);
    const float tcull = r->tmax * kCullSlack;  // OctantWalk's, made once per ray
    tmin = F::bcast(&r->tmin);
    tfar = F::set1(tcull + r->tol);
    guard = StepGuard(v);
    sp = 0;
    cur = 0;
    best = miss_hit();
  }
  /// One node or leaf visit and the pop after it; false once the ray is done (its answer in best).
  [[gnu::always_inline]] bool step(NoStats& st) {
    guard.step();
    if (cur >= 0) {
      const Node8& n = v.n8[cur];
      const float* p = n.lo_x;
      const V tnx = F::fmsub(F::load(p + nx), ix, ox), tny = F::fmsub(F::load(p + ny), iy, oy);
      const V tnz = F::fmsub(F::load(p + nz), iz, oz), tfx = F::fmsub(F::load(p + fx), ix, ox);
      const V tfy = F::fmsub(F::load(p + fy), iy, oy), tfz = F::fmsub(F::load(p + fz), iz, oz);
      const V te = F::max(tnz, F::max(tny, F::max(tnx, tmin)));
      const V tx = F::min(tfz, F::min(tfy, F::min(tfx, tfar)));
      const unsigned m = F::le(te, tx);
      if (m) {
        if ((m & (m - 1)) == 0) {  // one hit child: entered, nothing pushed
          cur = n.child[std::countr_zero(m)];
          return true;
        }
        std::uint32_t order;
        std::memcpy(&order, reinterpret_cast<const unsigned char*>(n.pad) + order_at, sizeof(order));
        guard.room(sp, 8, MBVH_STACK8_ENTRIES);
        int top = 0;  // push_octant sets it (unread: the child entered is read back from the row just stored)
        sp = K::template push_octant<false>(stack, nullptr, sp, m, order, n.child, nullptr, top) - 1;
        cur = stack[sp];
        return true;
      }
    } else {
      float tmax = r->tmax;
      if (K::template leaf<true>(v, cur, *r, tmax, best, st)) return false;
    }
    if (sp == 0) return false;
    cur = stack[--sp];
    return true;
  }
};

/// Traces the any-hit rays [b, e) of one chunk, `fast` precision, on the MBVH8 octant-ordered stack with
/// OctantOcclusionWalk: the rays bucketed by octant (a counting sort; ray order kept within an
/// octant), then each octant's rays through its own walk, so the octant is decided once per
/// bucket, not per ray.
void occluded_octant_run(const TraceView& v, std::span<const Ray> rays, std::size_t b, std::size_t e, TraceOutput& out,
                         std::size_t& invalid) {
  constexpr std::size_t kPart = kTraceChunk;  // rays bucketed at a time
  static_assert(kPart <= 65536, "idx holds 16-bit indices");
  std::uint16_t idx[kPart];
  std::uint8_t oct[kPart];
  for (std::size_t base = b; base < e; base += kPart) {
    const unsigned n = static_cast<unsigned>(std::min(kPart, e - base));
    unsigned start[9] = {};
    for (unsigned k = 0; k < n; ++k) {
      oct[k] = static_cast<std::uint8_t>(ray_octant(rays[base + k]));
      ++start[oct[k] + 1];
    }
    for (int o = 0; o < 8; ++o) start[o + 1] += start[o];
    unsigned at[8];
    std::memcpy(at, start, sizeof(at));
    for (unsigned k = 0; k < n; ++k) idx[at[oct[k]]++] = static_cast<std::uint16_t>(k);
    [&]<unsigned... O>(std::integer_sequence<unsigned, O...>) {
      // each octant's rays two in turn (batch.h's run_interleaved), by their indices in the chunk
      const auto ray_at = [&](std::size_t k) { return base + idx[k]; };
      ((start[O + 1] > start[O]
            ? run_interleaved<true, SimdKernelsT<true>, OctantOcclusionWalk<O>>(v, rays, start[O], start[O + 1], out, invalid, ray_at)
            : void()),
       ...);
    }(std::make_integer_sequence<unsigned, 8>{});
  }
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

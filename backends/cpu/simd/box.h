// SPDX-License-Identifier: MIT
// box.h — a wide node's slab tests in one pass (Ize 2013's conservative test, box_test's
// operations lane by lane).
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/simd/lanes.h"
#include "backends/cpu/simd/ray.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

/// A wide node's W slab tests in one pass (W = 4: MBVH4, 8: MBVH8): (plane - o) * inv per axis,
/// the NaN-discarding max/min chain of box_test (maxps/minps return their second operand on NaN,
/// exactly like max_nan/min_nan), and an ordered <= compare. Fast (the `fast` precision, whose
/// ray is relaxed: inv_far = inv): each plane distance as one FMA, p * inv - o * inv
/// (finish_fast_ray's o * inv), the same chain after it, against tcull + tol (finish_fast_ray);
/// the entries it writes are te - tol, so the ordered stack's later cull (entry > tcull) keeps
/// the same margin.
template <class F, bool Chord, class N, bool Fast = false>
[[gnu::always_inline]] inline unsigned box_test_wide(const N& n, const SimdRay& r, float tcull, float* d) {
  constexpr int W = node_width<N>();
  using V = typename F::V;
  const float* p = n.lo_x;
  const int* near = W == 4 ? r.near4 : r.near8;
  const int* far = W == 4 ? r.far4 : r.far8;
  const V nx = F::load(p + near[0]), fx = F::load(p + far[0]);
  const V ny = F::load(p + near[1]), fy = F::load(p + far[1]);
  const V nz = F::load(p + near[2]), fz = F::load(p + far[2]);
  V tnx, tny, tnz, tfx, tfy, tfz;
  if constexpr (Fast) {
    const V ix = F::bcast(&r.inv[0]), iy = F::bcast(&r.inv[1]), iz = F::bcast(&r.inv[2]);
    const V ox = F::bcast(&r.oinv[0]), oy = F::bcast(&r.oinv[1]), oz = F::bcast(&r.oinv[2]);
    tnx = F::fmsub(nx, ix, ox), tny = F::fmsub(ny, iy, oy), tnz = F::fmsub(nz, iz, oz);
    tfx = F::fmsub(fx, ix, ox), tfy = F::fmsub(fy, iy, oy), tfz = F::fmsub(fz, iz, oz);
  } else {
    const V ox = F::bcast(&r.o[0]), oy = F::bcast(&r.o[1]), oz = F::bcast(&r.o[2]);
    tnx = F::mul(F::sub(nx, ox), F::bcast(&r.inv[0]));
    tny = F::mul(F::sub(ny, oy), F::bcast(&r.inv[1]));
    tnz = F::mul(F::sub(nz, oz), F::bcast(&r.inv[2]));
    tfx = F::mul(F::sub(fx, ox), F::bcast(&r.inv_far[0]));
    tfy = F::mul(F::sub(fy, oy), F::bcast(&r.inv_far[1]));
    tfz = F::mul(F::sub(fz, oz), F::bcast(&r.inv_far[2]));
  }
  const V te = F::max(tnz, F::max(tny, F::max(tnx, F::bcast(&r.tmin))));
  const V tx = F::min(tfz, F::min(tfy, F::min(tfx, F::set1(Fast ? tcull + r.tol : tcull))));
  if constexpr (Chord) F::store(d, F::max(F::sub(tx, te), F::set1(0.0f)));  // max_nan(tx - te, 0), box_test's
  else if constexpr (Fast) F::store(d, F::sub(te, F::set1(r.tol)));  // the ordered stack's pop-time cull too
  else F::store(d, te);
  return F::le(te, tx);
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

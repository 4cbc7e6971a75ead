// SPDX-License-Identifier: MIT
// triangle.h — a leaf pack's triangles lane by lane: the watertight test (Woop, Benthin & Wald
// 2013) with pbrt-v3's error bound on t, and the fast mode's Möller–Trumbore; the lane cores are
// shared with the packets (packet/triangle.h).
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

/// Lane `lane` of a pack as a Tri (the same float bits as the leaf-ordered triangle it was made
/// from), for the scalar test of an undecided lane: a pack alone then settles its leaf.
inline Tri tri_of(const Tri4& p, int lane) {
  Tri t;
  float* rows[3] = {t.v0, t.v1, t.v2};
  for (int i = 0; i < 3; ++i) {
    for (int a = 0; a < 3; ++a) rows[i][a] = p.v[3 * i + a][lane];
    rows[i][3] = 0.0f;
  }
  std::memcpy(&t.v0[3], &p.prim[lane], 4);
  return t;
}

/// tri_test's error bound δt on t (pbrt-v3's Triangle::Intersect), lane by lane, from the sheared
/// vertices X, Y, Z, the edge functions U, V, W and det: a lane whose t exceeds it has a certain
/// positive t. std::fmax and maxps agree here (no NaN in a candidate lane's inputs: a NaN there
/// makes t NaN). watertight_lanes' last step.
template <class F>
[[gnu::always_inline]] inline typename F::V t_error_bound(const typename F::V (&X)[3], const typename F::V (&Y)[3],
                                                          const typename F::V (&Z)[3], typename F::V U, typename F::V V,
                                                          typename F::V W, typename F::V det) {
  using V4 = typename F::V;
  constexpr float u = MBVH_UNIT_ROUNDOFF;
  constexpr float g2 = 2 * u / (1 - 2 * u), g3 = 3 * u / (1 - 3 * u), g5 = 5 * u / (1 - 5 * u);
  const V4 maxZt = absmax3<F>(Z[0], Z[1], Z[2]), maxXt = absmax3<F>(X[0], X[1], X[2]), maxYt = absmax3<F>(Y[0], Y[1], Y[2]);
  const V4 maxE = absmax3<F>(U, V, W);
  const V4 dz = F::mul(F::set1(g3), maxZt);
  const V4 dx = F::mul(F::set1(g5), F::add(maxXt, maxZt));
  const V4 dy = F::mul(F::set1(g5), F::add(maxYt, maxZt));
  const V4 de = F::mul(F::set1(2.0f),
                       F::add(F::add(F::mul(F::mul(F::set1(g2), maxXt), maxYt), F::mul(dy, maxXt)), F::mul(dx, maxYt)));
  const V4 sum = F::add(F::add(F::mul(F::mul(F::set1(g3), maxE), maxZt), F::mul(de, maxZt)), F::mul(dz, maxE));
  return F::mul(F::mul(F::set1(3.0f), sum), F::andnot(F::set1(-0.0f), F::div(F::set1(1.0f), det)));
}

/// One vertex of a triangle, its coordinates on the ray's kx, ky, kz axes (px, py, pz), translated
/// to the ray's permuted origin o and sheared by s: tri_test's X, Y, Z, lane by lane.
template <class F>
[[gnu::always_inline]] inline void shear_lanes(typename F::V px, typename F::V py, typename F::V pz,
                                               const typename F::V (&o)[3], const typename F::V (&s)[3], typename F::V& X,
                                               typename F::V& Y, typename F::V& Z) {
  const typename F::V ax = F::sub(px, o[0]), ay = F::sub(py, o[1]), az = F::sub(pz, o[2]);
  X = F::sub(ax, F::mul(s[0], az));
  Y = F::sub(ay, F::mul(s[1], az));
  Z = F::mul(s[2], az);
}

/// What watertight_lanes decides for each lane, and the values a caller's epilogue reads.
template <class F>
struct Watertight {
  unsigned exact0 = 0;  ///< lanes of `valid` with an edge function exactly 0 (tri_test settles them in double)
  unsigned cand = 0;    ///< lanes inside, det != 0, t within [tmin, tmax]
  unsigned sure = 0;    ///< lanes of cand whose t exceeds its error bound: certain hits
  typename F::V V, W, det, t;  ///< set when cand != 0: u = V / det, v = W / det
};

/// The [tmin, tmax] of watertight_lanes' lanes, read only once some lane is inside its triangle:
/// the SIMD leaves broadcast their ray's (this), the packets load their SIMD ray's lanes.
template <class F>
struct RayRange {
  const float* tmin;
  float tmax;
  [[gnu::always_inline]] typename F::V lo() const { return F::bcast(tmin); }
  [[gnu::always_inline]] typename F::V hi() const { return F::set1(tmax); }
};

/// The watertight test (Woop, Benthin & Wald 2013) lane by lane from the sheared vertices X, Y, Z
/// (shear_lanes): tri_test's operations in its order — the edge functions U, V, W, the inside
/// test, det, t, the [tmin, tmax] test and pbrt-v3's error bound on t. The one sequence of
/// operations of the SIMD leaves (a pack's triangles against one ray, tri_test_simd) and of the
/// packets (one triangle against a SIMD ray, packet/triangle.h); each caller settles its lanes of
/// exact0 and cand & ~sure itself. The work is deferred until a lane can still win: nothing past
/// the edge tests when no lane is inside, the error bound only when some lane's t is in range.
template <class F, class Range>
[[gnu::always_inline]] inline void watertight_lanes(const typename F::V (&X)[3], const typename F::V (&Y)[3],
                                                    const typename F::V (&Z)[3], const Range& range, unsigned valid,
                                                    Watertight<F>& w) {
  using V4 = typename F::V;
  const V4 U = F::sub(F::mul(X[2], Y[1]), F::mul(Y[2], X[1]));
  const V4 V = F::sub(F::mul(X[0], Y[2]), F::mul(Y[0], X[2]));
  const V4 W = F::sub(F::mul(X[1], Y[0]), F::mul(Y[1], X[0]));
  const V4 zero = F::zero();
  const unsigned exact0 = F::bits(F::or_(F::template cmp<_CMP_EQ_OQ>(U, zero),
                                         F::or_(F::template cmp<_CMP_EQ_OQ>(V, zero), F::template cmp<_CMP_EQ_OQ>(W, zero))));
  const auto neg = F::or_(F::template cmp<_CMP_LT_OQ>(U, zero),
                        F::or_(F::template cmp<_CMP_LT_OQ>(V, zero), F::template cmp<_CMP_LT_OQ>(W, zero)));
  const auto pos = F::or_(F::template cmp<_CMP_GT_OQ>(U, zero),
                        F::or_(F::template cmp<_CMP_GT_OQ>(V, zero), F::template cmp<_CMP_GT_OQ>(W, zero)));
  w.exact0 = valid & exact0;
  const unsigned inside = valid & ~exact0 & ~F::bits(F::and_(neg, pos));
  if (inside == 0) return;
  const V4 det = F::add(F::add(U, V), W);
  const V4 T = F::add(F::add(F::mul(U, Z[0]), F::mul(V, Z[1])), F::mul(W, Z[2]));
  const V4 t = F::div(T, det);
  const auto in = F::and_(F::template cmp<_CMP_GE_OQ>(t, range.lo()), F::template cmp<_CMP_LE_OQ>(t, range.hi()));
  w.cand = inside & F::bits(F::and_(in, F::template cmp<_CMP_NEQ_UQ>(det, zero)));
  if (w.cand == 0) return;
  w.sure = w.cand & F::bits(F::template cmp<_CMP_GT_OQ>(t, t_error_bound<F>(X, Y, Z, U, V, W, det)));
  w.V = V;
  w.W = W;
  w.det = det;
  w.t = t;
}

/// The triangles of one pack (F = F4: four lanes) or of two consecutive packs (F8: eight lanes,
/// a leaf of five to eight triangles in one pass) at once against one ray: watertight_lanes, so
/// either width gives every lane the reference's answer. Returns the lanes of `valid` that hit
/// within [tmin, tmax]. Closest hit stores t and the barycentrics' numerators and denominator
/// (u = V / det, v = W / det: divided for the chosen lane only) for every lane once some lane is
/// a candidate; any hit (occlusion) stores nothing. The lanes this cannot settle in float are the
/// caller's: `near0` (inside, t in [tmin, tmax], t within its error bound of 0 — a secondary ray's
/// own surface) has every value tri_test would compute, so only its last step is left, the plane
/// distance in double (plane_t_double); `fallback` (an edge function exactly 0) needs the whole
/// scalar test, a rare case.
template <class F, bool Any = false>
[[gnu::always_inline]] inline unsigned tri_test_simd(const Tri4* p, const SimdRay& r, unsigned valid, float tmax, float* t_out,
                                                     float* V_out, float* W_out, float* det_out, unsigned& fallback,
                                                     unsigned& near0) {
  using V4 = typename F::V;
  const V4 o[3] = {F::bcast(&r.tri_o[0]), F::bcast(&r.tri_o[1]), F::bcast(&r.tri_o[2])};
  const V4 s[3] = {F::bcast(&r.sx), F::bcast(&r.sy), F::bcast(&r.sz)};
  V4 X[3], Y[3], Z[3];
  for (int i = 0; i < 3; ++i)
    shear_lanes<F>(F::row(p, 3 * i + r.kx), F::row(p, 3 * i + r.ky), F::row(p, 3 * i + r.kz), o, s, X[i], Y[i], Z[i]);
  Watertight<F> w;
  watertight_lanes<F>(X, Y, Z, RayRange<F>{&r.tmin, tmax}, valid, w);
  fallback = w.exact0;
  near0 = w.cand & ~w.sure;
  if (Any || w.cand == 0) return w.sure;
  F::store(t_out, w.t);
  F::store(V_out, w.V);
  F::store(W_out, w.W);
  F::store(det_out, w.det);
  return w.sure;
}

/// Möller–Trumbore lane by lane from the edges e1, e2, the direction d and
/// s = o - v0, with FMA and the reciprocal estimate refined by one Newton step: returns the lanes
/// that hit within [tmin, tmax] (F's comparison result: all ones, or F16's mask register) with t and the weights u, v. The one sequence of
/// operations of the fast mode's SIMD leaves (a pack's triangles against one ray) and of its
/// packets (one triangle against a SIMD ray, packet/triangle.h), so both give a ray the same bits.
template <class F>
[[gnu::always_inline]] inline auto mt_lanes(const typename F::V (&e1)[3],
                                                     const typename F::V (&e2)[3], const typename F::V (&d)[3],
                                                     const typename F::V (&s)[3], typename F::V tmin, typename F::V tmax,
                                                     typename F::V& t, typename F::V& u, typename F::V& v) {
  using V4 = typename F::V;
  V4 pv[3], q[3];
  cross_fma<F>(d, e2, pv);
  const V4 det = dot_fma<F>(e1, pv);
  V4 inv = F::rcp(det);
  inv = F::mul(inv, F::fnmadd(det, inv, F::set1(2.0f)));  // one Newton step
  u = F::mul(dot_fma<F>(s, pv), inv);
  cross_fma<F>(s, e1, q);
  v = F::mul(dot_fma<F>(d, q), inv);
  t = F::mul(dot_fma<F>(e2, q), inv);
  const V4 zero = F::zero(), one = F::set1(1.0f);
  auto ok = F::template cmp<_CMP_NEQ_OQ>(det, zero);
  ok = F::and_(ok, F::and_(F::template cmp<_CMP_GE_OQ>(u, zero), F::template cmp<_CMP_GE_OQ>(v, zero)));
  ok = F::and_(ok, F::template cmp<_CMP_LE_OQ>(F::add(u, v), one));
  return F::and_(ok, F::and_(F::template cmp<_CMP_GE_OQ>(t, tmin), F::template cmp<_CMP_LE_OQ>(t, tmax)));
}

/// Row `row` of a fast pass's triangles (make_mt_packs' layout: F4, a Tri4 slot; F8, the
/// eight-lane block of two slots, one aligned load a row).
template <class F>
[[gnu::always_inline]] inline typename F::V mt_row(const Tri4* p, int row) {
  if constexpr (sizeof(typename F::V) == 16) return F::row(p, row);
  else return F::load(reinterpret_cast<const float*>(p) + 8 * row);
}

/// Lane `lane`'s prim id in a fast pass's triangles (make_mt_packs' layout: F4, the slot's; F8,
/// the block's ids after its 9 rows).
template <class F>
[[gnu::always_inline]] inline std::uint32_t mt_prim(const Tri4* p, int lane) {
  if constexpr (sizeof(typename F::V) == 16) return p->prim[lane];
  std::uint32_t id;
  std::memcpy(&id, reinterpret_cast<const char*>(p) + 4 * (72 + lane), 4);
  return id;
}

/// The `fast` mode's triangles of one pack (F4) or two (F8) at once: Möller–Trumbore (1997) with
/// FMA and the reciprocal estimate refined by one Newton step (about 23 bits, not correctly
/// rounded), as fast SIMD tracers do, on make_mt_packs' layout (v0 and the edges e1, e2 as they
/// were subtracted here from the vertices: the same bits as the packets' mt_lanes). Returns the
/// hit lanes of `valid` with t and the weights u, v.
template <class F, bool Any = false>
[[gnu::always_inline]] inline unsigned tri_test_simd_mt(const Tri4* p, const SimdRay& r, unsigned valid, float tmax,
                                                        float* t_out, float* u_out, float* v_out) {
  using V4 = typename F::V;
  V4 e1[3], e2[3], d[3], s[3];
  for (int a = 0; a < 3; ++a) {
    e1[a] = mt_row<F>(p, 3 + a);
    e2[a] = mt_row<F>(p, 6 + a);
    d[a] = F::bcast(&r.d[a]);
    s[a] = F::sub(F::bcast(&r.o[a]), mt_row<F>(p, a));
  }
  V4 t, u, v;
  const auto ok = mt_lanes<F>(e1, e2, d, s, F::bcast(&r.tmin), F::set1(tmax), t, u, v);
  const unsigned hit = valid & F::bits(ok);
  if (Any || hit == 0) return hit;
  F::store(t_out, t);
  F::store(u_out, u);
  F::store(v_out, v);
  return hit;
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

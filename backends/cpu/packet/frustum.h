// SPDX-License-Identifier: MIT
// frustum.h — a packet's frustum test of a box (Boulos, Wald & Shirley 2006: interval arithmetic
// over the packet's origins and reciprocal directions), exact for every lane.
#pragma once
// A kernel header: included only by backends/cpu/isa_kernels.cpp, inside its ISA region, after
// <immintrin.h> and the core engine it builds on.
#ifndef MBVH_IN_ISA_REGION
#error "include from backends/cpu/isa_kernels.cpp only, between MBVH_ISA_BEGIN and MBVH_ISA_END"
#endif

#include "backends/cpu/packet/packet.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace packet {

/// A child box of a Node2, as broadcast rows of the SIMD ray's width (lo, hi per axis) and its scalar planes.
struct Box8 {
  PV lo[3], hi[3];
  PV nearv[3], farv[3];  ///< the near and far planes broadcast, where the packet's signs agree
  alignas(16) float near[4], far[4];  ///< the frustum's planes (the packet's common signs)
};

inline void load_box(Box8& b, const float lox, const float hix, const float loy, const float hiy, const float loz,
                     const float hiz, const Packet& P) {
  const float lo[3] = {lox, loy, loz}, hi[3] = {hix, hiy, hiz};
  for (int a = 0; a < 3; ++a) {
    b.lo[a] = PL::set1(lo[a]);
    b.hi[a] = PL::set1(hi[a]);
    b.near[a] = P.neg[a] ? hi[a] : lo[a];
    b.far[a] = P.neg[a] ? lo[a] : hi[a];
    b.nearv[a] = P.neg[a] ? b.hi[a] : b.lo[a];
    b.farv[a] = P.neg[a] ? b.lo[a] : b.hi[a];
  }
  b.near[3] = b.far[3] = 0.0f;
}

/// What the frustum says of a box for the whole packet.
enum class Cover { some, none, all };

/// The frustum test (Boulos, Wald & Shirley 2006; interval arithmetic) of box `b`, exact for
/// every lane: a lane computes tn = (near - o) * inv rounded; rounding is monotone, so the
/// rounded corner products of [near - o_hi, near - o_lo] x [inv_lo, inv_hi] bound every lane's
/// tn from both sides (likewise tf with inv_far), and a lane's entry max(tn, tmin) and exit
/// min(tf, tcull) lie within the bounds taken over the axes. none: the lowest entry exceeds the
/// highest exit, every lane misses (its own test would say so). all: the highest entry is at most
/// the lowest exit on a frustum of all three axes, every lane hits. `entry` receives the lowest
/// entry and `exit` the highest exit (the packet's order of children).
/// Fast: the lanes compute p * inv - o * inv in one FMA (box2_group's fast form), which differs
/// from (p - o) * inv by at most the rounding of o * inv and of both results, below
/// 4u (|o| + |p - o|) |inv| (u = 2^-24); the bounds are widened by 2^-20 (2 max|o| + max|p|) max|inv|
/// per axis, four times that and the widening's own rounding, so they still bound every lane.
template <bool Fast = false>
inline Cover frustum_cover(const Packet& P, const Box8& b, float& entry, float& exit) {
  const __m128 n = _mm_load_ps(b.near), f = _mm_load_ps(b.far);
  const __m128 olo = _mm_load_ps(P.o_lo), ohi = _mm_load_ps(P.o_hi);
  const __m128 alo = _mm_sub_ps(n, ohi), ahi = _mm_sub_ps(n, olo);
  const __m128 ilo = _mm_load_ps(P.inv_lo), ihi = _mm_load_ps(P.inv_hi);
  const __m128 p0 = _mm_mul_ps(alo, ilo), p1 = _mm_mul_ps(alo, ihi), p2 = _mm_mul_ps(ahi, ilo), p3 = _mm_mul_ps(ahi, ihi);
  const __m128 blo = _mm_sub_ps(f, ohi), bhi = _mm_sub_ps(f, olo);
  const __m128 jlo = _mm_load_ps(P.invf_lo), jhi = _mm_load_ps(P.invf_hi);
  const __m128 q0 = _mm_mul_ps(blo, jlo), q1 = _mm_mul_ps(blo, jhi), q2 = _mm_mul_ps(bhi, jlo), q3 = _mm_mul_ps(bhi, jhi);
  __m128 off = _mm_castsi128_ps(_mm_load_si128(reinterpret_cast<const __m128i*>(P.axis_off)));
  const __m128 pinf = _mm_set1_ps(INFINITY), ninf = _mm_set1_ps(-INFINITY);
  __m128 tn_lo = _mm_min_ps(_mm_min_ps(p0, p1), _mm_min_ps(p2, p3)), tn_hi = _mm_max_ps(_mm_max_ps(p0, p1), _mm_max_ps(p2, p3));
  __m128 tf_lo = _mm_min_ps(_mm_min_ps(q0, q1), _mm_min_ps(q2, q3)), tf_hi = _mm_max_ps(_mm_max_ps(q0, q1), _mm_max_ps(q2, q3));
  if constexpr (Fast) {
    const __m128 sign = _mm_set1_ps(-0.0f);
    const __m128 ao = _mm_max_ps(_mm_andnot_ps(sign, olo), _mm_andnot_ps(sign, ohi));
    const __m128 ai = _mm_max_ps(_mm_andnot_ps(sign, ilo), _mm_andnot_ps(sign, ihi));
    const __m128 ap = _mm_max_ps(_mm_andnot_ps(sign, n), _mm_andnot_ps(sign, f));
    __m128 eps = _mm_mul_ps(_mm_mul_ps(_mm_add_ps(_mm_add_ps(ao, ao), ap), ai), _mm_set1_ps(0x1p-20f));
    // no bound on an axis where o * inv may overflow (a lane's distances are then -inf or NaN) or
    // eps is not finite (NaN from 0 * inf included): it is left off like axis_off's
    off = _mm_or_ps(off, _mm_or_ps(_mm_cmp_ps(_mm_mul_ps(ao, ai), _mm_set1_ps(0x1p100f), _CMP_NLT_UQ),
                                   _mm_cmp_ps(eps, pinf, _CMP_NLT_UQ)));
    tn_lo = _mm_sub_ps(tn_lo, eps), tn_hi = _mm_add_ps(tn_hi, eps);
    tf_lo = _mm_sub_ps(tf_lo, eps), tf_hi = _mm_add_ps(tf_hi, eps);
  }
  tn_lo = _mm_blendv_ps(tn_lo, ninf, off), tn_hi = _mm_blendv_ps(tn_hi, pinf, off);
  tf_lo = _mm_blendv_ps(tf_lo, ninf, off), tf_hi = _mm_blendv_ps(tf_hi, pinf, off);
  alignas(16) float nl[4], nh[4], fl[4], fh[4];
  _mm_store_ps(nl, tn_lo);
  _mm_store_ps(nh, tn_hi);
  _mm_store_ps(fl, tf_lo);
  _mm_store_ps(fh, tf_hi);
  entry = std::max(std::max(nl[0], nl[1]), std::max(nl[2], P.tmin_lo));
  const float exit_hi = std::min(std::min(fh[0], fh[1]), std::min(fh[2], P.tcull_hi));
  exit = exit_hi;
  if (entry > exit_hi) return Cover::none;
  const float entry_hi = std::max(std::max(nh[0], nh[1]), std::max(nh[2], P.tmin_hi));
  const float exit_lo = std::min(std::min(fl[0], fl[1]), std::min(fl[2], P.tcull_lo));
  return entry_hi <= exit_lo ? Cover::all : Cover::some;
}

}  // namespace packet
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

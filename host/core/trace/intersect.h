// SPDX-License-Identifier: MIT
// intersect.h — the shared numerical kernels of every traversal: ray set-up and validation
// (TRAVERSAL.md §4.1), the conservative NaN-safe slab test (Ize, "Robust BVH Ray Traversal",
// JCGT 2013; §6) and the watertight ray/triangle test (Woop, Benthin & Wald, JCGT 2013; §7).
// Compiled with -ffp-contract=off: the operation order here is the one every backend repeats.
//
// The functions live in an inline namespace named by MBVH_ISA_NS (default `ref`, or `ref_checked`
// under MBVH_CHECK_TERMINATION, below): a backend
// that compiles these kernels again with other -m flags (backends/cpu, per ISA) defines its own
// name, so inline code built for AVX-512 can never be merged into the portable reference.
#pragma once
#include <cmath>
#include <cstdint>
#include <cstring>

#include "mbvh/mbvh_layout.h"

namespace mbvh {

/// Far factor K = 1 + 2^-21 on the exit distances and culling slack S = 1 + 3*2^-23 on tmax: the
/// values the devices use, from their one declaration in mbvh_layout.h.
constexpr float kFarFactor = MBVH_FAR_FACTOR;
constexpr float kCullSlack = MBVH_CULL_SLACK;

/// A validated ray with its per-ray constants.
struct RayPre {
  float o[3], d[3];
  float inv[3], inv_far[3];
  int neg[3];
  float tmin, tmax;
  int kx, ky, kz;
  float sx, sy, sz;
};

// The reference's own namespace. Builds that bound each traversal's steps (MBVH_CHECK_TERMINATION:
// StepGuard, stats.h) name it apart, so no object compiled without the bound (a test file shared
// between a Release and a sanitizer build: CMakeLists.txt, MBVH_TEST_OBJECTS_FROM) can instantiate
// a traversal template that the linker would pick for the library's checked one.
#ifndef MBVH_ISA_NS
#ifdef MBVH_CHECK_TERMINATION
#define MBVH_ISA_NS ref_checked
#else
#define MBVH_ISA_NS ref
#endif
#endif
inline namespace MBVH_ISA_NS {

/// False for an invalid ray (NaN anywhere, infinite origin/direction/tmin, zero or subnormal
/// direction, tmin < 0, tmin > tmax): such a ray is a defined miss. tmax may be +inf.
[[gnu::always_inline]] inline bool prepare_ray(const Ray& r, RayPre& p) {
  const float v[8] = {r.ox, r.oy, r.oz, r.tmin, r.dx, r.dy, r.dz, r.tmax};
  for (int i = 0; i < 7; ++i)
    if (!std::isfinite(v[i])) return false;
  if (std::isnan(r.tmax)) return false;
  if (!(r.tmin >= 0.0f) || !(r.tmin <= r.tmax)) return false;
  const float ad[3] = {std::fabs(r.dx), std::fabs(r.dy), std::fabs(r.dz)};
  int kz = 0;
  if (ad[1] > ad[kz]) kz = 1;
  if (ad[2] > ad[kz]) kz = 2;
  if (!std::isnormal(ad[kz])) return false;  // zero or subnormal direction
  p.o[0] = r.ox; p.o[1] = r.oy; p.o[2] = r.oz;
  p.d[0] = r.dx; p.d[1] = r.dy; p.d[2] = r.dz;
  p.tmin = r.tmin + 0.0f;  // -0 becomes +0
  p.tmax = r.tmax;
  for (int a = 0; a < 3; ++a) {
    p.inv[a] = 1.0f / p.d[a];
    p.neg[a] = std::signbit(p.d[a]) ? 1 : 0;
    p.inv_far[a] = p.inv[a] * kFarFactor;
  }
  p.kz = kz;
  p.kx = (kz + 1) % 3;
  p.ky = (p.kx + 1) % 3;
  if (p.d[kz] < 0.0f) { const int t = p.kx; p.kx = p.ky; p.ky = t; }
  p.sx = p.d[p.kx] / p.d[p.kz];
  p.sy = p.d[p.ky] / p.d[p.kz];
  p.sz = 1.0f / p.d[p.kz];
  return true;
}

inline float max_nan(float a, float b) { return a > b ? a : b; }  // NaN in a yields b
inline float min_nan(float a, float b) { return a < b ? a : b; }

/// Conservative slab test of one box against [tmin, tcull], tcull = tmax * kCullSlack.
/// Returns hit and the entry distance (>= tmin).
/// With Chord, `entry` receives the length of the ray's path through the box instead,
/// max_nan(exit - entry, 0) (never NaN: +inf - +inf gives 0): what an occlusion query orders
/// children by (the longest chord first, visit.h's longest_slot).
template <bool Chord = false>
[[gnu::always_inline]] inline bool box_test(const RayPre& r, float lox, float hix, float loy, float hiy, float loz, float hiz, float tcull,
                     float& entry) {
  const float nx = r.neg[0] ? hix : lox, fx = r.neg[0] ? lox : hix;
  const float ny = r.neg[1] ? hiy : loy, fy = r.neg[1] ? loy : hiy;
  const float nz = r.neg[2] ? hiz : loz, fz = r.neg[2] ? loz : hiz;
  const float tnx = (nx - r.o[0]) * r.inv[0], tfx = (fx - r.o[0]) * r.inv_far[0];
  const float tny = (ny - r.o[1]) * r.inv[1], tfy = (fy - r.o[1]) * r.inv_far[1];
  const float tnz = (nz - r.o[2]) * r.inv[2], tfz = (fz - r.o[2]) * r.inv_far[2];
  const float te = max_nan(tnz, max_nan(tny, max_nan(tnx, r.tmin)));
  const float tx = min_nan(tfz, min_nan(tfy, min_nan(tfx, tcull)));
  entry = Chord ? max_nan(tx - te, 0.0f) : te;
  return te <= tx;
}

/// Distance along the ray to the triangle's plane, in double from the float inputs; used only to
/// decide the sign of t when the float t lies within its error bound of 0.
inline double plane_t_double(const RayPre& r, const Tri& tri) {
  const double e1[3] = {double(tri.v1[0]) - tri.v0[0], double(tri.v1[1]) - tri.v0[1], double(tri.v1[2]) - tri.v0[2]};
  const double e2[3] = {double(tri.v2[0]) - tri.v0[0], double(tri.v2[1]) - tri.v0[1], double(tri.v2[2]) - tri.v0[2]};
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  const double w[3] = {double(tri.v0[0]) - r.o[0], double(tri.v0[1]) - r.o[1], double(tri.v0[2]) - r.o[2]};
  const double nd = n[0] * r.d[0] + n[1] * r.d[1] + n[2] * r.d[2];
  return (n[0] * w[0] + n[1] * w[1] + n[2] * w[2]) / nd;
}

/// Watertight two-sided ray/triangle test; accepts t in [tmin, tmax] whose sign is certain: t
/// above the pbrt-v3 error bound δt, or a positive plane distance in double. On a hit writes t
/// and the barycentrics of vertices 1 and 2 (u, v).
[[gnu::always_inline]] inline bool tri_test(const RayPre& r, const Tri& tri, float tmax, float& t_out, float& u_out, float& v_out) {
  const float* P[3] = {tri.v0, tri.v1, tri.v2};
  float X[3], Y[3], Z[3];
  for (int i = 0; i < 3; ++i) {
    const float ax = P[i][r.kx] - r.o[r.kx];
    const float ay = P[i][r.ky] - r.o[r.ky];
    const float az = P[i][r.kz] - r.o[r.kz];
    X[i] = ax - r.sx * az;
    Y[i] = ay - r.sy * az;
    Z[i] = r.sz * az;
  }
  // edge functions; exact zeros are settled in double (Woop et al. §3)
  float U = X[2] * Y[1] - Y[2] * X[1];
  float V = X[0] * Y[2] - Y[0] * X[2];
  float W = X[1] * Y[0] - Y[1] * X[0];
  if (U == 0.0f || V == 0.0f || W == 0.0f) {
    U = static_cast<float>(double(X[2]) * double(Y[1]) - double(Y[2]) * double(X[1]));
    V = static_cast<float>(double(X[0]) * double(Y[2]) - double(Y[0]) * double(X[2]));
    W = static_cast<float>(double(X[1]) * double(Y[0]) - double(Y[1]) * double(X[0]));
  }
  if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return false;
  const float det = U + V + W;
  if (det == 0.0f) return false;
  const float T = U * Z[0] + V * Z[1] + W * Z[2];
  const float t = T / det;
  if (!(t >= r.tmin && t <= tmax)) return false;
  // conservative t > 0 (pbrt-v3 Triangle::Intersect)
  constexpr float u = MBVH_UNIT_ROUNDOFF;  // 2^-24
  constexpr float g2 = 2 * u / (1 - 2 * u), g3 = 3 * u / (1 - 3 * u), g5 = 5 * u / (1 - 5 * u);
  const float maxZt = std::fmax(std::fabs(Z[0]), std::fmax(std::fabs(Z[1]), std::fabs(Z[2])));
  const float maxXt = std::fmax(std::fabs(X[0]), std::fmax(std::fabs(X[1]), std::fabs(X[2])));
  const float maxYt = std::fmax(std::fabs(Y[0]), std::fmax(std::fabs(Y[1]), std::fabs(Y[2])));
  const float maxE = std::fmax(std::fabs(U), std::fmax(std::fabs(V), std::fabs(W)));
  const float dz = g3 * maxZt;
  const float dx = g5 * (maxXt + maxZt);
  const float dy = g5 * (maxYt + maxZt);
  const float de = 2 * (g2 * maxXt * maxYt + dy * maxXt + dx * maxYt);
  const float dt = 3 * (g3 * maxE * maxZt + de * maxZt + dz * maxE) * std::fabs(1.0f / det);
  // pbrt-v3 rejects t <= δt outright; on long triangles δt exceeds true hits (1.16 against a hit
  // at 0.87 on the conference room's 525-unit walls), a leak. Within the bound, settle the sign
  // of t with the plane distance in double instead.
  if (t <= dt && !(plane_t_double(r, tri) > 0.0)) return false;
  t_out = t;
  u_out = V / det;
  v_out = W / det;
  return true;
}

/// The `fast` accuracy mode's triangle test: Möller & Trumbore, "Fast, Minimum Storage Ray/Triangle
/// Intersection", JGT 1997 — edges and determinant from the untransformed vertices, one reciprocal
/// of the determinant, no watertightness (a ray through a shared edge may miss both triangles)
/// and no error bound on t (a secondary ray may re-hit its own surface). Two-sided; u, v weight
/// vertices 1 and 2 as tri_test's.
[[gnu::always_inline]] inline bool tri_test_mt(const RayPre& r, const Tri& tri, float tmax, float& t_out, float& u_out, float& v_out) {
  const float e1[3] = {tri.v1[0] - tri.v0[0], tri.v1[1] - tri.v0[1], tri.v1[2] - tri.v0[2]};
  const float e2[3] = {tri.v2[0] - tri.v0[0], tri.v2[1] - tri.v0[1], tri.v2[2] - tri.v0[2]};
  const float p[3] = {r.d[1] * e2[2] - r.d[2] * e2[1], r.d[2] * e2[0] - r.d[0] * e2[2], r.d[0] * e2[1] - r.d[1] * e2[0]};
  const float det = e1[0] * p[0] + e1[1] * p[1] + e1[2] * p[2];
  const float s[3] = {r.o[0] - tri.v0[0], r.o[1] - tri.v0[1], r.o[2] - tri.v0[2]};
  const float q[3] = {s[1] * e1[2] - s[2] * e1[1], s[2] * e1[0] - s[0] * e1[2], s[0] * e1[1] - s[1] * e1[0]};
  // the inside test on the numerators, the division deferred to candidates
  const float un = s[0] * p[0] + s[1] * p[1] + s[2] * p[2];
  const float vn = r.d[0] * q[0] + r.d[1] * q[1] + r.d[2] * q[2];
  if (det > 0.0f ? !(un >= 0.0f && vn >= 0.0f && un + vn <= det) : !(det < 0.0f && un <= 0.0f && vn <= 0.0f && un + vn >= det))
    return false;
  const float inv = 1.0f / det;
  const float t = (e2[0] * q[0] + e2[1] * q[1] + e2[2] * q[2]) * inv;
  if (!(t >= r.tmin && t <= tmax)) return false;
  t_out = t;
  u_out = un * inv;
  v_out = vn * inv;
  return true;
}

/// The `fast` mode's box test: the slab test without the far-plane widening (Ize 2013 shows it
/// can cull a box the ray enters by one rounding), what most renderers ship.
inline void relax_ray(RayPre& r) {
  for (int a = 0; a < 3; ++a) r.inv_far[a] = r.inv[a];
}

inline std::uint32_t tri_prim(const Tri& t) {
  std::uint32_t id;
  std::memcpy(&id, &t.v0[3], 4);
  return id;
}

inline Hit miss_hit() { return Hit{INFINITY, 0.0f, 0.0f, MBVH_MISS_PRIM}; }

}  // namespace MBVH_ISA_NS
}  // namespace mbvh

// SPDX-License-Identifier: MIT
// simd_kernels.cpp — the cpu backend's kernels, compiled once per ISA from this one source
// (CMake: mbvh_cpu_avx2, mbvh_cpu_avx512), each in its own inline namespace (MBVH_ISA_NS).
// The ISA is switched on with a target pragma around the ISA-namespaced code only (intersect.h,
// traverse.h, batch.h and this file's kernels); the std and host headers are included before it
// at the baseline ISA: TU-wide -mavx512f would also compile the std and host inline functions
// this file instantiates, and the linker may keep those AVX-512 copies for the portable code too
// (a crash on a CPU without it). The kernel policy (SimdKernels) tests an MBVH4 node's four boxes
// or an MBVH8 node's eight at once and a leaf's triangles eight at a time (two SoA packs per pass)
// (Accel::tri_packs); the traversals are the reference's (traverse.h) — the same operations in
// the same order, so the answers are bit-identical to cpu-scalar's. Áfra & Szirmay-Kalos 2014
// for the traversals (Áfra's thesis, ch. 3, for 8-wide MBVH8), Ize 2013 for the conservative slab
// test, Woop, Benthin & Wald 2013 for the watertight triangle test.
#include <immintrin.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstddef>
#include <cstring>
#include <functional>
#include <limits>
#include <memory>
#include <span>
#include <stdexcept>
#include <utility>
#include <vector>

#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/view.h"  // plain records, at the baseline ISA

#ifndef MBVH_CPU_ISA
#error "compile with -DMBVH_CPU_ISA=avx2|avx512, -DMBVH_CPU_ISA_ID=1|2 and -DMBVH_ISA_NS=<the ISA>"
#endif

// MBVH_ISA_BEGIN ... MBVH_ISA_END: functions defined between them are compiled for the ISA.
#if MBVH_CPU_ISA_ID == 2
#define MBVH_ISA_TARGET "avx2,fma,avx512f,avx512vl,avx512dq,avx512bw"
#else
#define MBVH_ISA_TARGET "avx2,fma"  // FMA only in the fast mode's explicit intrinsics (-ffp-contract=off)
#endif
#define MBVH_PRAGMA(x) _Pragma(#x)
#if defined(__clang__)
#define MBVH_ISA_PUSH(t) MBVH_PRAGMA(clang attribute push(__attribute__((target(t))), apply_to = function))
#define MBVH_ISA_END _Pragma("clang attribute pop")
#else
#define MBVH_ISA_PUSH(t) _Pragma("GCC push_options") MBVH_PRAGMA(GCC target(t))
#define MBVH_ISA_END _Pragma("GCC pop_options")
#endif
#define MBVH_ISA_BEGIN MBVH_ISA_PUSH(MBVH_ISA_TARGET)

// -- from here on, functions are compiled for the ISA
MBVH_ISA_BEGIN

// The kernels (namespace mbvh::MBVH_ISA_NS) are included first, under the ISA: the traversal
// templates must be defined here, not at the baseline ISA (a template is compiled with the
// target of its definition; the box test and leaves could then not be inlined into it).
#include "host/core/trace/intersect.h"
#include "host/core/trace/traverse.h"
MBVH_ISA_END
// -- trace.h's shared declarations (and TraceOutput::reset) at the baseline ISA
#include "backends/cpu/cpu_backends.h"
#include "mbvh/trace.h"
MBVH_ISA_BEGIN
#include "host/core/trace/batch.h"  // the batch driver, in namespace mbvh::MBVH_ISA_NS
#define MBVH_STR2(x) #x
#define MBVH_STR(x) MBVH_STR2(x)

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {

inline unsigned mask4(__m128 m) { return static_cast<unsigned>(_mm_movemask_ps(m)); }

#if MBVH_CPU_ISA_ID == 2
/// 8-bit masks bit-reversed (slot s <-> 7 - s).
constexpr std::array<std::uint8_t, 256> kReverse8 = [] {
  std::array<std::uint8_t, 256> t{};
  for (unsigned m = 0; m < 256; ++m) {
    unsigned r = 0;
    for (int b = 0; b < 8; ++b)
      if ((m >> b) & 1u) r |= 1u << (7 - b);
    t[m] = static_cast<std::uint8_t>(r);
  }
  return t;
}();
#endif


/// The SIMD policies' ray: RayPre plus the per-ray constants the kernels need beyond it, made
/// once per ray (finish) instead of at every node and leaf: the offsets of each axis' near and far
/// plane rows in a Node4 and a Node8 (Embree's nearX/farX) and the triangle test's permuted origin
/// (Woop et al. 2013). The kernels broadcast RayPre's scalars where they use them (a broadcast
/// from memory is one load, as a load of a stored broadcast is): a ray once kept 14 broadcast
/// vectors, 448 bytes written per ray, a fifth of the set-up's instructions.
struct SimdRay : RayPre {
  float tri_o[3];  ///< the triangle test's permuted origin (o[kx], o[ky], o[kz])
  int near4[4], far4[4], near8[4], far8[4];  ///< three axes (the fourth entry unused)
  const TraceView* view;  ///< what the ray traverses (for prefetches)
};

#if MBVH_CPU_ISA_ID != 2
/// For each 8-bit mask, its set slots highest first, one byte each (the AVX2 MBVH8 push).
constexpr std::array<std::uint64_t, 256> kDescending8 = [] {
  std::array<std::uint64_t, 256> t{};
  for (unsigned m = 0; m < 256; ++m) {
    std::uint64_t packed = 0;
    int n = 0;
    for (int s = 7; s >= 0; --s)
      if ((m >> s) & 1u) packed |= std::uint64_t(s) << (8 * n++);
    t[m] = packed;
  }
  return t;
}();
#endif


/// 4 and 8 lanes of float: the operations the box test needs.
struct F4 {
  using V = __m128;
  static V load(const float* p) { return _mm_load_ps(p); }
  static V set1(float x) { return _mm_set1_ps(x); }
  static V bcast(const float* p) { return _mm_broadcast_ss(p); }
  static V sub(V a, V b) { return _mm_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm_mul_ps(a, b); }
  static V max(V a, V b) { return _mm_max_ps(a, b); }
  static V min(V a, V b) { return _mm_min_ps(a, b); }
  static void store(float* d, V v) { _mm_storeu_ps(d, v); }
  static V add(V a, V b) { return _mm_add_ps(a, b); }
  static V div(V a, V b) { return _mm_div_ps(a, b); }
  static V and_(V a, V b) { return _mm_and_ps(a, b); }
  static V or_(V a, V b) { return _mm_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm_andnot_ps(a, b); }
  static V zero() { return _mm_setzero_ps(); }
  template <int Cmp>
  static V cmp(V a, V b) { return _mm_cmp_ps(a, b, Cmp); }
  static unsigned bits(V m) { return mask4(m); }
  static V fmsub(V a, V b, V c) { return _mm_fmsub_ps(a, b, c); }
  static V fmadd(V a, V b, V c) { return _mm_fmadd_ps(a, b, c); }
  static V fnmadd(V a, V b, V c) { return _mm_fnmadd_ps(a, b, c); }
  static V rcp(V a) { return _mm_rcp_ps(a); }
  /// Row `row` of the pack at p: its four lanes.
  static V row(const Tri4* p, int row) { return _mm_load_ps(p->v[row]); }
#if MBVH_CPU_ISA_ID == 2
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
#else
  static unsigned le(V a, V b) { return mask4(_mm_cmp_ps(a, b, _CMP_LE_OQ)); }
#endif
};
struct F8 {
  using V = __m256;
  static V load(const float* p) { return _mm256_load_ps(p); }
  static V set1(float x) { return _mm256_set1_ps(x); }
  static V bcast(const float* p) { return _mm256_broadcast_ss(p); }
  static V sub(V a, V b) { return _mm256_sub_ps(a, b); }
  static V mul(V a, V b) { return _mm256_mul_ps(a, b); }
  static V max(V a, V b) { return _mm256_max_ps(a, b); }
  static V min(V a, V b) { return _mm256_min_ps(a, b); }
  static void store(float* d, V v) { _mm256_storeu_ps(d, v); }
  static V add(V a, V b) { return _mm256_add_ps(a, b); }
  static V div(V a, V b) { return _mm256_div_ps(a, b); }
  static V and_(V a, V b) { return _mm256_and_ps(a, b); }
  static V or_(V a, V b) { return _mm256_or_ps(a, b); }
  static V andnot(V a, V b) { return _mm256_andnot_ps(a, b); }
  static V zero() { return _mm256_setzero_ps(); }
  template <int Cmp>
  static V cmp(V a, V b) { return _mm256_cmp_ps(a, b, Cmp); }
  static unsigned bits(V m) { return static_cast<unsigned>(_mm256_movemask_ps(m)); }
  static V fmsub(V a, V b, V c) { return _mm256_fmsub_ps(a, b, c); }
  static V fmadd(V a, V b, V c) { return _mm256_fmadd_ps(a, b, c); }
  static V fnmadd(V a, V b, V c) { return _mm256_fnmadd_ps(a, b, c); }
  static V rcp(V a) { return _mm256_rcp_ps(a); }
  /// Row `row` of the two consecutive packs at p: eight lanes, p[0]'s four low, p[1]'s high.
  static V row(const Tri4* p, int row) {
    return _mm256_insertf128_ps(_mm256_castps128_ps256(_mm_load_ps(p[0].v[row])), _mm_load_ps(p[1].v[row]), 1);
  }
#if MBVH_CPU_ISA_ID == 2
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm256_cmp_ps_mask(a, b, _CMP_LE_OQ)); }
#else
  static unsigned le(V a, V b) { return static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(a, b, _CMP_LE_OQ))); }
#endif
};

/// prepare_ray (intersect.h) in vector registers: the same checks — every component finite
/// (|x| < inf, false for NaN) but tmax, which may be +inf, tmin in [0, tmax], the largest
/// direction component normal — and the same per-ray constants with the same IEEE operations
/// (1 / d, inv * K, the shear's three quotients in one division), so every bit is the scalar's;
/// about half its instructions (callgrind: the per-ray set-up was 261 of the bunny's 1,478
/// instructions per shadow ray).
[[gnu::always_inline]] inline bool prepare_ray_simd(const Ray& ray, RayPre& p) {
  static_assert(offsetof(RayPre, d) == offsetof(RayPre, o) + 12 && offsetof(RayPre, inv) == offsetof(RayPre, d) + 12 &&
                    offsetof(RayPre, inv_far) == offsetof(RayPre, inv) + 12 &&
                    offsetof(RayPre, neg) == offsetof(RayPre, inv_far) + 12 && offsetof(RayPre, tmin) == offsetof(RayPre, neg) + 12,
                "RayPre's rows are written 16 bytes at a time, each store's fourth lane overwritten by the next");
  const __m128 o = _mm_loadu_ps(&ray.ox), d = _mm_loadu_ps(&ray.dx);  // (o, tmin), (d, tmax)
  const __m128 sign = _mm_set1_ps(-0.0f), inf = _mm_set1_ps(INFINITY);
  const __m128 ad = _mm_andnot_ps(sign, d);
  const unsigned finite_o = mask4(_mm_cmp_ps(_mm_andnot_ps(sign, o), inf, _CMP_LT_OQ));
  const unsigned finite_d = mask4(_mm_cmp_ps(ad, inf, _CMP_LT_OQ));
  if ((finite_o & (finite_d | 8u)) != 0xFu || std::isnan(ray.tmax)) return false;
  if (!(ray.tmin >= 0.0f) || !(ray.tmin <= ray.tmax)) return false;
  alignas(16) float a[4];
  _mm_store_ps(a, ad);
  int kz = 0;
  if (a[1] > a[0]) kz = 1;
  if (a[2] > a[kz]) kz = 2;
  if (!(a[kz] >= std::numeric_limits<float>::min())) return false;  // zero or subnormal (a[kz] is finite)
  char* base = reinterpret_cast<char*>(&p);
  const __m128 inv = _mm_div_ps(_mm_set1_ps(1.0f), d);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, o)), o);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, d)), d);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, inv)), inv);
  _mm_storeu_ps(reinterpret_cast<float*>(base + offsetof(RayPre, inv_far)), _mm_mul_ps(inv, _mm_set1_ps(kFarFactor)));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(base + offsetof(RayPre, neg)), _mm_srli_epi32(_mm_castps_si128(d), 31));
  p.tmin = ray.tmin + 0.0f;  // -0 becomes +0
  p.tmax = ray.tmax;
  constexpr int next[3] = {1, 2, 0};
  int kx = next[kz], ky = next[kx];
  if (p.d[kz] < 0.0f) std::swap(kx, ky);
  p.kx = kx;
  p.ky = ky;
  p.kz = kz;
  alignas(16) float sh[4];
  _mm_store_ps(sh, _mm_div_ps(_mm_setr_ps(p.d[kx], p.d[ky], 1.0f, 1.0f), _mm_setr_ps(p.d[kz], p.d[kz], p.d[kz], 1.0f)));
  p.sx = sh[0];
  p.sy = sh[1];
  p.sz = sh[2];
  return true;
}

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

/// Fills SimdRay's constants from its (validated, possibly relaxed) RayPre part.
inline void finish_ray(SimdRay& r, const TraceView& v) {
  r.view = &v;
  // rows lo_x, hi_x, lo_y, ... are W floats apart: near = (2a + neg) * W, far = near ^ W, the
  // three axes at once (neg's fourth lane is tmin's bits: its entries are never read)
  const __m128i near8 = _mm_slli_epi32(_mm_add_epi32(_mm_loadu_si128(reinterpret_cast<const __m128i*>(r.neg)),
                                                     _mm_setr_epi32(0, 2, 4, 0)), 3);
  const __m128i near4 = _mm_srli_epi32(near8, 1);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.near8), near8);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.far8), _mm_xor_si128(near8, _mm_set1_epi32(8)));
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.near4), near4);
  _mm_storeu_si128(reinterpret_cast<__m128i*>(r.far4), _mm_xor_si128(near4, _mm_set1_epi32(4)));
  r.tri_o[0] = r.o[r.kx];
  r.tri_o[1] = r.o[r.ky];
  r.tri_o[2] = r.o[r.kz];
}

/// A wide node's W slab tests in one pass (W = 4: MBVH4, 8: MBVH8): (plane - o) * inv per axis,
/// the NaN-discarding max/min chain of box_test (maxps/minps return their second operand on NaN,
/// exactly like max_nan/min_nan), and an ordered <= compare.
template <class F, bool Chord, class N>
[[gnu::always_inline]] inline unsigned box_test_wide(const N& n, const SimdRay& r, float tcull, float* d) {
  constexpr int W = node_width<N>();
  using V = typename F::V;
  const float* p = n.lo_x;
  const int* near = W == 4 ? r.near4 : r.near8;
  const int* far = W == 4 ? r.far4 : r.far8;
  const V nx = F::load(p + near[0]), fx = F::load(p + far[0]);
  const V ny = F::load(p + near[1]), fy = F::load(p + far[1]);
  const V nz = F::load(p + near[2]), fz = F::load(p + far[2]);
  const V ox = F::bcast(&r.o[0]), oy = F::bcast(&r.o[1]), oz = F::bcast(&r.o[2]);
  const V tnx = F::mul(F::sub(nx, ox), F::bcast(&r.inv[0]));
  const V tny = F::mul(F::sub(ny, oy), F::bcast(&r.inv[1]));
  const V tnz = F::mul(F::sub(nz, oz), F::bcast(&r.inv[2]));
  const V tfx = F::mul(F::sub(fx, ox), F::bcast(&r.inv_far[0]));
  const V tfy = F::mul(F::sub(fy, oy), F::bcast(&r.inv_far[1]));
  const V tfz = F::mul(F::sub(fz, oz), F::bcast(&r.inv_far[2]));
  const V te = F::max(tnz, F::max(tny, F::max(tnx, F::bcast(&r.tmin))));
  const V tx = F::min(tfz, F::min(tfy, F::min(tfx, F::set1(tcull))));
  if constexpr (Chord) F::store(d, F::max(F::sub(tx, te), F::set1(0.0f)));  // max_nan(tx - te, 0), box_test's
  else F::store(d, te);
  return F::le(te, tx);
}

/// max(|a|, |b|, |c|) lane by lane (the error bounds' maxima; andnot of -0 clears the sign).
template <class F>
[[gnu::always_inline]] inline typename F::V absmax3(typename F::V a, typename F::V b, typename F::V c) {
  const typename F::V sign = F::set1(-0.0f);
  return F::max(F::andnot(sign, a), F::max(F::andnot(sign, b), F::andnot(sign, c)));
}
/// The fast mode's cross and dot products, with FMA (plain functions, not lambdas: a lambda is
/// not compiled for the ISA of the pragma around it).
template <class F>
[[gnu::always_inline]] inline void cross_fma(const typename F::V a[3], const typename F::V b[3], typename F::V c[3]) {
  c[0] = F::fmsub(a[1], b[2], F::mul(a[2], b[1]));
  c[1] = F::fmsub(a[2], b[0], F::mul(a[0], b[2]));
  c[2] = F::fmsub(a[0], b[1], F::mul(a[1], b[0]));
}
template <class F>
[[gnu::always_inline]] inline typename F::V dot_fma(const typename F::V a[3], const typename F::V b[3]) {
  return F::fmadd(a[0], b[0], F::fmadd(a[1], b[1], F::mul(a[2], b[2])));
}

/// tri_test's error bound δt on t (pbrt-v3's Triangle::Intersect), lane by lane, from the sheared
/// vertices X, Y, Z, the edge functions U, V, W and det: a lane whose t exceeds it has a certain
/// positive t. std::fmax and maxps agree here (no NaN in a candidate lane's inputs: a NaN there
/// makes t NaN). Shared by the SIMD leaves and the packets' per-lane test (packet.h).
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

/// The triangles of one pack (F = F4: four lanes) or of two consecutive packs (F8: eight lanes,
/// a leaf of five to eight triangles in one pass) at once: tri_test (intersect.h) lane by lane,
/// the same operations in the same order (Woop, Benthin & Wald 2013, watertight; pbrt-v3's error
/// bound on t), so either width gives every lane the reference's answer. Returns the lanes of
/// `valid` that hit within [tmin, tmax], with t and the barycentrics' numerators and denominator
/// (u = V / det, v = W / det: divided for the chosen lane only); the lanes this cannot settle in
/// float — an edge function exactly 0 (settled in double) or t within its error bound of 0
/// (settled by the plane distance in double) — go to `fallback` for the scalar test, a rare case.
/// The exact-contract work is deferred until a lane can still win: nothing past the edge tests
/// when no lane is inside its triangle, the error bound on t only when some lane's t lies within
/// [tmin, tmax]. Any (occlusion): the same decision, but nothing beyond it — no t,
/// barycentrics or determinant leave the function. The t-error bound stays: it is the decision's
/// last step (a lane with t within it is no certain hit). Such a lane (`near0`: inside, t in
/// [tmin, tmax], t <= δt — a secondary ray's own surface, about one ray in three) has every value
/// tri_test would compute, so only its last step is left to the caller: the plane distance in
/// double (plane_t_double); only `fallback` lanes (an edge function exactly 0) need the whole
/// scalar test. Closest hit stores t, V, W and det for every lane.
template <class F, bool Any = false>
[[gnu::always_inline]] inline unsigned tri_test_simd(const Tri4* p, const SimdRay& r, unsigned valid, float tmax, float* t_out,
                                                     float* V_out, float* W_out, float* det_out, unsigned& fallback,
                                                     unsigned& near0) {
  using V4 = typename F::V;
  const V4 ox = F::bcast(&r.tri_o[0]), oy = F::bcast(&r.tri_o[1]), oz = F::bcast(&r.tri_o[2]);
  const V4 sx = F::bcast(&r.sx), sy = F::bcast(&r.sy), sz = F::bcast(&r.sz);
  V4 X[3], Y[3], Z[3];
  for (int i = 0; i < 3; ++i) {
    const V4 ax = F::sub(F::row(p, 3 * i + r.kx), ox);
    const V4 ay = F::sub(F::row(p, 3 * i + r.ky), oy);
    const V4 az = F::sub(F::row(p, 3 * i + r.kz), oz);
    X[i] = F::sub(ax, F::mul(sx, az));
    Y[i] = F::sub(ay, F::mul(sy, az));
    Z[i] = F::mul(sz, az);
  }
  const V4 U = F::sub(F::mul(X[2], Y[1]), F::mul(Y[2], X[1]));
  const V4 V = F::sub(F::mul(X[0], Y[2]), F::mul(Y[0], X[2]));
  const V4 W = F::sub(F::mul(X[1], Y[0]), F::mul(Y[1], X[0]));
  const V4 zero = F::zero();
  const unsigned exact0 = F::bits(F::or_(F::template cmp<_CMP_EQ_OQ>(U, zero),
                                         F::or_(F::template cmp<_CMP_EQ_OQ>(V, zero), F::template cmp<_CMP_EQ_OQ>(W, zero))));
  const V4 neg = F::or_(F::template cmp<_CMP_LT_OQ>(U, zero),
                        F::or_(F::template cmp<_CMP_LT_OQ>(V, zero), F::template cmp<_CMP_LT_OQ>(W, zero)));
  const V4 pos = F::or_(F::template cmp<_CMP_GT_OQ>(U, zero),
                        F::or_(F::template cmp<_CMP_GT_OQ>(V, zero), F::template cmp<_CMP_GT_OQ>(W, zero)));
  fallback = valid & exact0;
  near0 = 0;
  const unsigned inside = valid & ~exact0 & ~F::bits(F::and_(neg, pos));
  if (inside == 0) return 0;
  const V4 det = F::add(F::add(U, V), W);
  const V4 T = F::add(F::add(F::mul(U, Z[0]), F::mul(V, Z[1])), F::mul(W, Z[2]));
  const V4 t = F::div(T, det);
  const V4 in = F::and_(F::template cmp<_CMP_GE_OQ>(t, F::bcast(&r.tmin)), F::template cmp<_CMP_LE_OQ>(t, F::set1(tmax)));
  const unsigned cand = inside & F::bits(F::and_(in, F::template cmp<_CMP_NEQ_UQ>(det, zero)));
  if (cand == 0) return 0;
  const unsigned sure = cand & F::bits(F::template cmp<_CMP_GT_OQ>(t, t_error_bound<F>(X, Y, Z, U, V, W, det)));
  near0 = cand & ~sure;
  if constexpr (Any) return sure;
  F::store(t_out, t);
  F::store(V_out, V);
  F::store(W_out, W);
  F::store(det_out, det);
  return sure;
}

/// Möller–Trumbore lane by lane from the edges e1, e2, the direction d and
/// s = o - v0, with FMA and the reciprocal estimate refined by one Newton step: returns the lanes
/// that hit within [tmin, tmax] (all ones) with t and the weights u, v. The one sequence of
/// operations of the fast mode's SIMD leaves (a pack's triangles against one ray) and of its
/// packets (one triangle against a SIMD ray, packet.h), so both give a ray the same bits.
template <class F>
[[gnu::always_inline]] inline typename F::V mt_lanes(const typename F::V (&e1)[3],
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
  V4 ok = F::template cmp<_CMP_NEQ_OQ>(det, zero);
  ok = F::and_(ok, F::and_(F::template cmp<_CMP_GE_OQ>(u, zero), F::template cmp<_CMP_GE_OQ>(v, zero)));
  ok = F::and_(ok, F::template cmp<_CMP_LE_OQ>(F::add(u, v), one));
  return F::and_(ok, F::and_(F::template cmp<_CMP_GE_OQ>(t, tmin), F::template cmp<_CMP_LE_OQ>(t, tmax)));
}

/// The `fast` mode's triangles of one pack (F4) or two (F8) at once: Möller–Trumbore (1997) with
/// FMA and the reciprocal estimate refined by one Newton step (about 23 bits, not correctly
/// rounded), as fast SIMD tracers do. Returns the hit lanes of `valid` with t, u, v (det_out = 1:
/// u, v are the weights already).
template <class F, bool Any = false>
[[gnu::always_inline]] inline unsigned tri_test_simd_mt(const Tri4* p, const SimdRay& r, unsigned valid, float tmax,
                                                        float* t_out, float* u_out, float* v_out, float* det_out) {
  using V4 = typename F::V;
  V4 v0[3], e1[3], e2[3], d[3], s[3];
  for (int a = 0; a < 3; ++a) {
    v0[a] = F::row(p, a);
    e1[a] = F::sub(F::row(p, 3 + a), v0[a]);
    e2[a] = F::sub(F::row(p, 6 + a), v0[a]);
    d[a] = F::bcast(&r.d[a]);
    s[a] = F::sub(F::bcast(&r.o[a]), v0[a]);
  }
  V4 t, u, v;
  const V4 ok = mt_lanes<F>(e1, e2, d, s, F::bcast(&r.tmin), F::set1(tmax), t, u, v);
  const V4 one = F::set1(1.0f);
  const unsigned hit = valid & F::bits(ok);
  if (Any || hit == 0) return hit;
  F::store(t_out, t);
  F::store(u_out, u);
  F::store(v_out, v);
  F::store(det_out, one);
  return hit;
}

/// The cpu backend's kernels: four or eight boxes per test, four or eight triangles per pass (the
/// leaves as Tri4 packs).
/// A leaf's answer is the reference's: any hit takes the first hit triangle in leaf order,
/// closest hit the smallest (t, prim) — what the sequential loop of visit_leaf keeps, as tmax
/// only shrinks to the best hit's t. With statistics on, the scalar leaf counts the work. Fast: the
/// `fast` accuracy mode (relax_ray's box test, tri_test_simd_mt).
template <bool Fast>
struct SimdKernelsT {
  static constexpr bool uses_packs = true;
  static constexpr bool fast = Fast;
  using Ray = SimdRay;
  [[gnu::always_inline]] static bool prepare(const mbvh::Ray& ray, Ray& r) { return prepare_ray_simd(ray, r); }
  static void finish(Ray& r, const TraceView& v) { finish_ray(r, v); }
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node4& n, const Ray& r, float tcull, float d[4]) {
    return box_test_wide<F4, Chord>(n, r, tcull, d);
  }
  template <bool Chord = false>
  [[gnu::always_inline]] static unsigned test(const Node8& n, const Ray& r, float tcull, float d[8]) {
    return box_test_wide<F8, Chord>(n, r, tcull, d);
  }
  /// Closest hit: the record of every child in `mask` (traverse.h passes the hit children left
  /// for later: an inner node's lines, a leaf's first pack, or its leaf4 entry where the references
  /// are not packed) is asked for at once, so the misses
  /// of the children visited later overlap the work before them.
  /// With packed references (the default) the address is picked without a branch (a node or
  /// the leaf's first pack; the node's size in lines either way: a leaf of five or more triangles
  /// reads into its second pack): the branch on the child's kind mispredicted on about one
  /// prefetch in four (callgrind's branch model, Sponza diffuse rays), a sixth of the traversal's.
  template <class N>
  [[gnu::always_inline]] static void prefetch(const N& n, const Ray& r, unsigned mask) {
    const char* nodes = reinterpret_cast<const char*>(detail::nodes_of<N>(*r.view));
    if (r.view->packed_refs) {
      const char* packs = reinterpret_cast<const char*>(r.view->tri4);
      for (unsigned k = mask; k != 0; k &= k - 1) {
        const std::int32_t c = n.child[std::countr_zero(k)];
        const std::size_t node_at = static_cast<std::size_t>(static_cast<std::uint32_t>(c)) * sizeof(N);
        const std::size_t pack_at = static_cast<std::size_t>(static_cast<std::uint32_t>(~c) >> 3) * sizeof(Tri4);
        const char* p = c >= 0 ? nodes + node_at : packs + pack_at;
        for (std::size_t line = 0; line < sizeof(N); line += 64) _mm_prefetch(p + line, _MM_HINT_T0);
      }
      return;
    }
    for (unsigned k = mask; k != 0; k &= k - 1) {
      const std::int32_t c = n.child[std::countr_zero(k)];
      if (c >= 0) {
        const char* p = nodes + static_cast<std::size_t>(c) * sizeof(N);
        for (std::size_t line = 0; line < sizeof(N); line += 64) _mm_prefetch(p + line, _MM_HINT_T0);
      } else {
        _mm_prefetch(reinterpret_cast<const char*>(r.view->leaf4 + ~c), _MM_HINT_T0);
      }
    }
  }
  /// The hit slot of `mask` with the smallest d (Largest: the largest; an occlusion query's
  /// chords), ties to the lower slot, without a branch per slot: two hits by one compare, more by
  /// a horizontal min (max) over the row with the misses set to +inf (-inf) and the lowest slot
  /// equal to it (d is never NaN: entries start at tmin, chords are clamped at 0).
  template <bool Largest>
  [[gnu::always_inline]] static __m256 pick(__m256 a, __m256 b) {
    if constexpr (Largest) return _mm256_max_ps(a, b);
    else return _mm256_min_ps(a, b);
  }
  template <int W, bool Largest>
  [[gnu::always_inline]] static int extreme(unsigned mask, const float* d) {
    const unsigned rest = mask & (mask - 1);
    if (rest == 0) return std::countr_zero(mask);
    if ((rest & (rest - 1)) == 0) {  // two hits, the commonest case: one compare
      const int a = std::countr_zero(mask), b = std::countr_zero(rest);
      return (Largest ? d[b] > d[a] : d[b] < d[a]) ? b : a;
    }
    if constexpr (W == 8) {
      const __m256 none = _mm256_set1_ps(Largest ? -INFINITY : INFINITY);
      const __m256 bits = _mm256_castsi256_ps(_mm256_and_si256(_mm256_set1_epi32(static_cast<int>(mask)),
                                                               _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128)));
      const __m256 v = _mm256_blendv_ps(_mm256_loadu_ps(d), none, _mm256_cmp_ps(bits, _mm256_setzero_ps(), _CMP_EQ_OQ));
      __m256 m = pick<Largest>(v, _mm256_permute_ps(v, 0xB1));
      m = pick<Largest>(m, _mm256_permute_ps(m, 0x4E));
      m = pick<Largest>(m, _mm256_permute2f128_ps(m, m, 0x01));
      const unsigned eq = static_cast<unsigned>(_mm256_movemask_ps(_mm256_cmp_ps(v, m, _CMP_EQ_OQ))) & mask;
      return std::countr_zero(eq);
    } else {
      return detail::extreme_slot<W, Largest>(mask, d);
    }
  }
  template <int W>
  [[gnu::always_inline]] static int nearest(unsigned mask, const float* d) { return extreme<W, false>(mask, d); }
  template <int W>
  [[gnu::always_inline]] static int longest(unsigned mask, const float* d) { return extreme<W, true>(mask, d); }

  /// MBVH8 pushes (traverse.h: highest slot first): AVX-512 reverses the row of child links,
  /// compresses the hit ones (the mask bit-reversed) in a register and stores the whole row (a
  /// compress straight to memory is microcoded on Zen 4).
  [[gnu::always_inline]] static unsigned push8(std::int32_t* stack, unsigned sp, unsigned mask, const std::int32_t* child) {
#if MBVH_CPU_ISA_ID == 2
    const __m256i links = _mm256_permutexvar_epi32(_mm256_setr_epi32(7, 6, 5, 4, 3, 2, 1, 0),
                                                   _mm256_loadu_si256(reinterpret_cast<const __m256i*>(child)));
    const unsigned rev = static_cast<unsigned>(kReverse8[mask & 0xFFu]);
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(stack + sp), _mm256_maskz_compress_epi32(static_cast<__mmask8>(rev), links));
    return sp + static_cast<unsigned>(std::popcount(mask));
#else
    // AVX2 has no compress: a table gives each mask's slots highest first, one permute gathers them
    const __m256i idx = _mm256_cvtepu8_epi32(_mm_cvtsi64_si128(static_cast<long long>(kDescending8[mask & 0xFFu])));
    const __m256i links = _mm256_loadu_si256(reinterpret_cast<const __m256i*>(child));
    _mm256_storeu_si256(reinterpret_cast<__m256i*>(stack + sp), _mm256_permutevar8x32_epi32(links, idx));
    return sp + static_cast<unsigned>(std::popcount(mask));
#endif
  }

  /// One pass of a leaf's test over the pack at p (F4: lanes k..k+3 of the leaf) or the two packs
  /// at p (F8: lanes k..k+7), `valid` its lanes that hold a triangle. Closest hit: keeps the
  /// smallest (t, prim) in best and shrinks tmax; any hit: true at the first certain hit. The
  /// undecided lanes (occlusion: only while no lane is certain) are settled as tri_test settles
  /// them: a lane with t within its error bound of 0 by the plane distance in double, a lane with
  /// an edge function exactly 0 by the scalar test itself (rare). The reference accepts exactly
  /// the same lanes, and the smallest (t, prim) of a leaf does not depend on how its triangles
  /// are grouped into passes.
  template <class F, bool Any>
  [[gnu::always_inline]] static bool leaf_pass(const Tri4* p, unsigned valid, const Ray& r, float& tmax, Hit& best) {
    constexpr int L = sizeof(typename F::V) / sizeof(float);
    const auto prim = [p](int lane) { return p[lane >> 2].prim[lane & 3]; };
    float t[L], u[L], w[L], det[L];
    unsigned fallback = 0, near0 = 0, hit;
    if constexpr (Fast) hit = tri_test_simd_mt<F, Any>(p, r, valid, tmax, t, u, w, det);
    else hit = tri_test_simd<F, Any>(p, r, valid, tmax, t, u, w, det, fallback, near0);
    if constexpr (Any) {
      if (hit != 0) {
        best.prim = prim(std::countr_zero(hit));
        return true;
      }
    }
    for (unsigned f = near0; f != 0; f &= f - 1) {  // tri_test's last step: t's sign in double
      const int lane = std::countr_zero(f);
      if (plane_t_double(r, tri_of(p[lane >> 2], lane & 3)) > 0.0) {
        if constexpr (Any) {
          best.prim = prim(lane);
          return true;
        }
        hit |= 1u << lane;  // t, V, W and det as tri_test's: u = V / det, v = W / det below
      }
    }
    for (unsigned f = fallback; f != 0; f &= f - 1) {
      const int lane = std::countr_zero(f);
      if (tri_test(r, tri_of(p[lane >> 2], lane & 3), tmax, t[lane], u[lane], w[lane])) {
        if constexpr (Any) {
          best.prim = prim(lane);
          return true;
        }
        hit |= 1u << lane;
        det[lane] = 1.0f;  // u, w are the quotients already (x / 1 is exact)
      }
    }
    if constexpr (!Any) {
      if (hit == 0) return false;
      int q = std::countr_zero(hit);
      for (unsigned o = hit & (hit - 1); o != 0; o &= o - 1) {
        const int s = std::countr_zero(o);
        if (t[s] < t[q] || (t[s] == t[q] && prim(s) < prim(q))) q = s;
      }
      if (t[q] < best.t || prim(q) < best.prim) {  // t[q] <= best.t, as in visit_leaf
        best = Hit{t[q], u[q] / det[q], w[q] / det[q], prim(q)};
        tmax = t[q];
      }
    }
    return false;
  }

  /// A leaf's triangles eight at a time (two packs per pass: the same instructions on 256-bit
  /// registers, issue 14 item 2), its last one to four in a four-lane pass.
  template <bool Any, class St>
  [[gnu::always_inline]] static bool leaf(const TraceView& v, std::int32_t ref, const Ray& r, float& tmax, Hit& best,
                                          St& st) {
    if constexpr (St::on) {
      return detail::visit_leaf<Any, St, Fast>(v, ref, r, tmax, best, st);
    } else {
      Leaf l;
      if (v.packed_refs) l = packed_leaf(ref);  // TraceView::packed_refs: the reference locates the packs
      else l = v.leaf4[~ref];
      const Tri4* p = v.tri4 + l.first;
      std::uint32_t k = 0;
      for (; k + 4 < l.count; k += 8, p += 2) {
        const unsigned valid = l.count - k >= 8 ? 0xFFu : (1u << (l.count - k)) - 1u;
        if (leaf_pass<F8, Any>(p, valid, r, tmax, best)) return true;
      }
      if (k < l.count) return leaf_pass<F4, Any>(p, (1u << (l.count - k)) - 1u, r, tmax, best);
      return false;
    }
  }
};

#include "backends/cpu/packet.h"  // the packet traversals, in this namespace

/// One packet's trace with the statistics policy and the traversal chosen at run time.
template <bool Any, bool Stats, bool Fast, bool Partition, bool UniformK>
inline void trace_packet_signs(const TraceView& v, packet::Packet& P, RayStats* st) {
  if (P.same_sign) packet::trace_packet<Any, Partition, UniformK, true, Stats, Fast>(v, P, st);
  else packet::trace_packet<Any, Partition, UniformK, false, Stats, Fast>(v, P, st);
}
/// Fast: Möller–Trumbore, which has no shear axes (UniformK does not matter).
template <bool Any, bool Stats, bool Fast>
inline void trace_one_packet(const TraceView& v, packet::Packet& P, bool partition, RayStats* st) {
  const bool uniform = Fast || P.uniform_k;
  if (partition) {
    if (uniform) trace_packet_signs<Any, Stats, Fast, true, true>(v, P, st);
    else if constexpr (!Fast) trace_packet_signs<Any, Stats, Fast, true, false>(v, P, st);
  } else {
    if (uniform) trace_packet_signs<Any, Stats, Fast, false, true>(v, P, st);
    else if constexpr (!Fast) trace_packet_signs<Any, Stats, Fast, false, false>(v, P, st);
  }
}

/// The packet traversals' batch driver: rays in arrival order, MBVH_PACKET_RAYS at a time; a
/// coherent packet walks the MBVH2 nodes of the leaves traced, an incoherent one goes ray by ray
/// through opt.layout (the hybrid switch, packet.h).
template <class K>
void trace_packets(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
                   bool hybrid) {
  const TraceView pv = trace_view(acc, Layout::mbvh2, false, opt.leaf_block, false);
  const TraceView sv = trace_view(acc, opt.layout, true, opt.leaf_block, !opt.stats);
  const bool any = opt.query == Query::any;
  // the hybrid's single rays: run_batch's dispatch traces a packet traversal ray by ray as
  // packet_single_ray's traversal, whose bytes every packet ray gives (but for classified ties)
  const bool partition = opt.traversal != Traversal::packet_ranged;  // packet: partition, the faster here (docs/benchmarks.md)
  out.resize_for(rays.size(), opt);
  std::atomic<std::size_t> invalid{0};
  constexpr std::size_t kN = MBVH_PACKET_RAYS;
  parallel_for(rays.size(), 2048, threads, [&](std::size_t b, std::size_t e, unsigned) {
    static_assert(2048 % kN == 0, "chunks hold whole packets");
    auto P = std::make_unique<packet::Packet>();
    std::array<RayStats, kN> st{};
    std::size_t inv = 0;
    for (std::size_t s = b; s < e; s += kN) {
      const int n = static_cast<int>(std::min(kN, e - s));
      std::size_t bad = 0;
      if (!packet::load_packet<K::fast>(*P, rays.data() + s, n, bad, hybrid)) {
        std::size_t again = 0;
        if (any) {
          if (opt.stats) run_batch<true, true, K>(sv, rays, s, s + n, opt, out, again);
          else run_batch<true, false, K>(sv, rays, s, s + n, opt, out, again);
        } else {
          if (opt.stats) run_batch<false, true, K>(sv, rays, s, s + n, opt, out, again);
          else run_batch<false, false, K>(sv, rays, s, s + n, opt, out, again);
        }
        inv += again;
        continue;
      }
      inv += bad;
      if (opt.stats) {
        st.fill(RayStats{});
        if (any) trace_one_packet<true, true, K::fast>(pv, *P, partition, st.data());
        else trace_one_packet<false, true, K::fast>(pv, *P, partition, st.data());
        for (int i = 0; i < int(kN); ++i)
          if (const int at = packet::ray_of(i); at < n)
            out.stats[s + at] = P->valid[i / packet::kLanes] >> (i % packet::kLanes) & 1u ? st[i] : RayStats{};
      } else {
        if (any) trace_one_packet<true, false, K::fast>(pv, *P, partition, nullptr);
        else trace_one_packet<false, false, K::fast>(pv, *P, partition, nullptr);
      }
      for (int i = 0; i < int(kN); ++i) {  // slot i holds ray ray_of(i) of the packet
        const int at = packet::ray_of(i);
        if (at >= n) continue;
        if (any) out.occluded[s + at] = P->prim[i] != MBVH_MISS_PRIM ? 1 : 0;
        else out.hits[s + at] = P->prim[i] != MBVH_MISS_PRIM ? Hit{P->t[i], P->u[i], P->v[i], P->prim[i]} : miss_hit();
      }
    }
    invalid += inv;
  });
  out.invalid = invalid;
}

void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
           bool hybrid) {
  if (is_packet(opt.traversal)) {
    if (opt.precision == Precision::fast) trace_packets<SimdKernelsT<true>>(acc, rays, opt, out, threads, hybrid);
    else trace_packets<SimdKernelsT<false>>(acc, rays, opt, out, threads, hybrid);
    return;
  }
  if (opt.precision == Precision::fast) trace_parallel<SimdKernelsT<true>>(acc, rays, opt, out, threads);
  else trace_parallel<SimdKernelsT<false>>(acc, rays, opt, out, threads);
}

}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

MBVH_ISA_END

namespace mbvh {
extern const CpuKernels MBVH_CPU_KERNELS_NAME;
const CpuKernels MBVH_CPU_KERNELS_NAME{MBVH_STR(MBVH_CPU_ISA), &MBVH_ISA_NS::trace};

}  // namespace mbvh

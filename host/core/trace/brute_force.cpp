// SPDX-License-Identifier: MIT
// brute_force.cpp — the double-precision brute-force oracle (mbvh::brute_force): every triangle of
// the build, the watertight test of Woop et al. (JCGT 2013) evaluated in double from the float
// inputs, t from the plane equation in double.
//
// Where the CPU has AVX2 the edge functions of four triangles are evaluated in one 256-bit step:
// the same double operations in the same order as the scalar test (the float inputs widened
// exactly, no FMA: the build sets -ffp-contract=off), so a lane's signs are the scalar test's.
// A triangle whose signs reject it is rejected by the scalar test too; every other one goes through
// the scalar test, in triangle order: the same answer bit for bit (docs/ci.md has its speed).
#include "host/core/trace/brute_force.h"

#include <atomic>
#include <cmath>
#include <cstdint>

#include "host/core/trace/intersect.h"
#include "mbvh/trace.h"

#if defined(__x86_64__) && (defined(__GNUC__) || defined(__clang__))  // (32-bit x86 may run the scalar test on x87)
#define MBVH_BRUTE_VEC256 1
#include <immintrin.h>
#endif

namespace mbvh {

namespace {

std::atomic<BruteKernels> g_kernels{BruteKernels::best};

// The ray in the oracle's frame: the float origin widened, the shear in double.
struct Sheared {
  const RayPre& r;
  double o[3];
  double sx, sy;
};

struct Best {
  double t = INFINITY, u = 0, v = 0;
  std::uint32_t prim = MBVH_MISS_PRIM;
};

// The whole test of one triangle; a hit closer than `b` (ties to the smaller prim) replaces it.
inline void test_one(const Sheared& s, const Tri& tri, Best& b) {
  const RayPre& r = s.r;
  const float* P[3] = {tri.v0, tri.v1, tri.v2};
  double X[3], Y[3];
  for (int i = 0; i < 3; ++i) {
    const double ax = double(P[i][r.kx]) - s.o[r.kx], ay = double(P[i][r.ky]) - s.o[r.ky], az = double(P[i][r.kz]) - s.o[r.kz];
    X[i] = ax - s.sx * az;
    Y[i] = ay - s.sy * az;
  }
  const double U = X[2] * Y[1] - Y[2] * X[1];
  const double V = X[0] * Y[2] - Y[0] * X[2];
  const double W = X[1] * Y[0] - Y[1] * X[0];
  if ((U < 0 || V < 0 || W < 0) && (U > 0 || V > 0 || W > 0)) return;
  const double det = U + V + W;
  if (det == 0) return;
  // t from the plane equation: the differences and products of float inputs are (nearly) exact
  // in double, so its sign is right even at t ~ 1e-45, where the sheared T / det is not
  // (a ray leaving a floor from 1e-45 above it gave T / det = +1e-16).
  const double t = plane_t_double(r, tri);
  if (!(t > 0 && t >= r.tmin && t <= double(r.tmax))) return;
  const std::uint32_t prim = tri_prim(tri);
  if (t < b.t || (t == b.t && prim < b.prim)) {
    b.t = t;
    b.u = V / det;
    b.v = W / det;
    b.prim = prim;
  }
}

void test_all_scalar(const Sheared& s, const Tri* tris, std::size_t n, Best& b) {
  for (std::size_t i = 0; i < n; ++i) test_one(s, tris[i], b);
}

#if defined(MBVH_BRUTE_VEC256)
// Named for the registers: the core's symbols name none of the cpu backend's ISAs
// (tests/consumer/core_symbols.sh).
namespace vec256 {

[[gnu::target("avx2")]] void test_all(const Sheared& s, const Tri* tris, std::size_t n, Best& b) {
  const RayPre& r = s.r;
  const __m256d ox = _mm256_set1_pd(s.o[r.kx]), oy = _mm256_set1_pd(s.o[r.ky]), oz = _mm256_set1_pd(s.o[r.kz]);
  const __m256d sx = _mm256_set1_pd(s.sx), sy = _mm256_set1_pd(s.sy), zero = _mm256_setzero_pd();
  std::size_t i = 0;
  for (; i + 4 <= n; i += 4) {
    __m256d X[3], Y[3];
    for (int j = 0; j < 3; ++j) {
      // vertex j of the four triangles, one row (x, y, z, prim id) each, transposed to coordinates
      __m128 c[4];
      for (int k = 0; k < 4; ++k) {
        const Tri& t = tris[i + k];
        c[k] = _mm_loadu_ps(j == 0 ? t.v0 : j == 1 ? t.v1 : t.v2);
      }
      _MM_TRANSPOSE4_PS(c[0], c[1], c[2], c[3]);
      const __m256d ax = _mm256_sub_pd(_mm256_cvtps_pd(c[r.kx]), ox);
      const __m256d ay = _mm256_sub_pd(_mm256_cvtps_pd(c[r.ky]), oy);
      const __m256d az = _mm256_sub_pd(_mm256_cvtps_pd(c[r.kz]), oz);
      X[j] = _mm256_sub_pd(ax, _mm256_mul_pd(sx, az));
      Y[j] = _mm256_sub_pd(ay, _mm256_mul_pd(sy, az));
    }
    const __m256d U = _mm256_sub_pd(_mm256_mul_pd(X[2], Y[1]), _mm256_mul_pd(Y[2], X[1]));
    const __m256d V = _mm256_sub_pd(_mm256_mul_pd(X[0], Y[2]), _mm256_mul_pd(Y[0], X[2]));
    const __m256d W = _mm256_sub_pd(_mm256_mul_pd(X[1], Y[0]), _mm256_mul_pd(Y[1], X[0]));
    // the scalar test's rejection: a negative and a positive edge function (NaN: neither)
    const __m256d neg = _mm256_or_pd(_mm256_or_pd(_mm256_cmp_pd(U, zero, _CMP_LT_OQ), _mm256_cmp_pd(V, zero, _CMP_LT_OQ)),
                                     _mm256_cmp_pd(W, zero, _CMP_LT_OQ));
    const __m256d pos = _mm256_or_pd(_mm256_or_pd(_mm256_cmp_pd(U, zero, _CMP_GT_OQ), _mm256_cmp_pd(V, zero, _CMP_GT_OQ)),
                                     _mm256_cmp_pd(W, zero, _CMP_GT_OQ));
    unsigned left = ~static_cast<unsigned>(_mm256_movemask_pd(_mm256_and_pd(neg, pos))) & 0xFu;
    for (; left; left &= left - 1) test_one(s, tris[i + static_cast<unsigned>(__builtin_ctz(left))], b);
  }
  test_all_scalar(s, tris + i, n - i, b);
}

}  // namespace vec256

bool use_vec256() {
  static const bool has = __builtin_cpu_supports("avx2");
  return has && g_kernels.load(std::memory_order_relaxed) == BruteKernels::best;
}
#endif

}  // namespace

void set_brute_kernels(BruteKernels k) { g_kernels.store(k, std::memory_order_relaxed); }

Hit brute_force(const Accel& acc, const Ray& ray) {
  RayPre r;
  if (!prepare_ray(ray, r)) return miss_hit();
  const double dk = r.d[r.kz];
  const Sheared s{r, {r.o[0], r.o[1], r.o[2]}, double(r.d[r.kx]) / dk, double(r.d[r.ky]) / dk};
  const auto& tris = acc.tris();
  Best b;
#if defined(MBVH_BRUTE_VEC256)
  if (use_vec256())
    vec256::test_all(s, tris.data(), tris.size(), b);
  else
#endif
    test_all_scalar(s, tris.data(), tris.size(), b);
  if (b.prim == MBVH_MISS_PRIM) return miss_hit();
  return Hit{static_cast<float>(b.t), static_cast<float>(b.u), static_cast<float>(b.v), b.prim};
}

}  // namespace mbvh

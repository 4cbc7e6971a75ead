// SPDX-License-Identifier: MIT
// tinybvh_kernels.cpp — the one translation unit that compiles tinybvh (jbikker/tinybvh 1.6.7,
// MIT; ../shared/peers/tinybvh, MBVH_TINYBVH_DIR) with TINYBVH_IMPLEMENTATION, for the `tinybvh`
// peer backend: its BVH4_CPU and BVH8_CPU layouts, built by its own default builder from the
// triangles mbvh traces, and its Intersect / IsOccluded single-ray queries. A peer to measure
// against, never code of mbvh's.
//
// tinybvh picks its CPU layouts by the compiler's ISA macros (BVH8_CPU needs __AVX2__ and
// __FMA__, BVH4_CPU __SSE4_2__ and __AVX__). As in backends/cpu/isa_kernels.cpp, the ISA is set
// by a target pragma, not TU-wide -m flags: the std headers (every one tinybvh includes) and
// <immintrin.h> come first, at the baseline ISA, so the std inline functions and templates this
// unit instantiates stay baseline code the linker may share with portable code; then the ISA
// macros tinybvh tests are defined by hand (GCC's C++ front end does not define them for a target
// pragma) and tinybvh's code is compiled for AVX2 + FMA between the push and the pop. Its
// warnings are third-party's: CMake compiles this file with -w. Callers run it only on a CPU with
// AVX2 and FMA (tinybvh_backend.cpp).
#include <immintrin.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <deque>
#include <fstream>
#include <functional>
#include <memory>
#include <mutex>
#include <span>
#include <thread>
#include <utility>
#include <vector>

#include "backends/tinybvh/tinybvh_kernels.h"
#include "host/core/trace/intersect.h"  // prepare_ray: the numerical contract's valid rays, at the baseline ISA

#if defined(__clang__)
// clang: CMake compiles this file with -mavx2 -mfma (clang has no target pragma that defines the
// ISA macros either); tinybvh then finds them set
#else
#ifndef __AVX2__
#define __AVX2__ 1
#define MBVH_TINYBVH_SET_AVX2
#endif
#ifndef __AVX__
#define __AVX__ 1
#endif
#ifndef __FMA__
#define __FMA__ 1
#endif
#ifndef __SSE4_2__
#define __SSE4_2__ 1
#endif
#pragma GCC push_options
#pragma GCC target("avx2,fma")
#endif

// tinybvh initialises a few namespace-scope SIMD constants (BVH::max8, mask6, signFlip8, the
// BVH8_CPU traversal's idxLUT256) with AVX intrinsics. Those initialisers run in the unit's static
// constructor, at load time, compiled at the baseline ISA: the intrinsics would not compile there
// and, compiled for AVX2, would stop the library from starting on a CPU without it. Spelled as
// GCC's generic vector literals (what the intrinsics are), they are constants at any ISA; inside
// tinybvh's AVX2 functions they compile to the same broadcasts and shuffles.
#define _mm256_set1_ps(x) (__extension__(__m256){(x), (x), (x), (x), (x), (x), (x), (x)})
#define _mm256_setr_ps(a, b, c, d, e, f, g, h) (__extension__(__m256){(a), (b), (c), (d), (e), (f), (g), (h)})
#define _mm256_set_m128(hi, lo) ((__m256)__builtin_shufflevector((__v4sf)(lo), (__v4sf)(hi), 0, 1, 2, 3, 4, 5, 6, 7))
#define _mm_cvtsi64_si128(x) (static_cast<unsigned long long>(x))
#define MBVH_TINYBVH_BYTE(x, k) static_cast<int>(((x) >> (8 * (k))) & 255u)
#define _mm256_cvtepu8_epi32(x)                                                                                       \
  ((__m256i)(__extension__(__v8si){MBVH_TINYBVH_BYTE(x, 0), MBVH_TINYBVH_BYTE(x, 1), MBVH_TINYBVH_BYTE(x, 2),          \
                                   MBVH_TINYBVH_BYTE(x, 3), MBVH_TINYBVH_BYTE(x, 4), MBVH_TINYBVH_BYTE(x, 5),          \
                                   MBVH_TINYBVH_BYTE(x, 6), MBVH_TINYBVH_BYTE(x, 7)}))

#define TINYBVH_IMPLEMENTATION
#include "tiny_bvh.h"

#undef _mm256_set1_ps
#undef _mm256_setr_ps
#undef _mm256_set_m128
#undef _mm_cvtsi64_si128
#undef _mm256_cvtepu8_epi32
#undef MBVH_TINYBVH_BYTE

namespace mbvh::tinybvh_peer {
namespace {

/// tinybvh's ray for an mbvh ray that prepare_ray accepted. tinybvh has no tmin (it accepts
/// t > 0) and does not want a normalised direction: the ray starts at o + tmin d (an mbvh ray's
/// t is along its own, unnormalised direction, as tinybvh's is along D) and runs tmax - tmin;
/// its answer's t gets tmin back (t0). rD is tinybvh's own reciprocal (tinybvh_rcp: +-1e30 for a
/// component within 1e-12 of 0), as its Ray constructor makes it. False for a ray whose moved
/// origin overflows (no finite point to hit there: a miss); tinybvh would stop the process on the
/// NaN such an origin can make (VALIDATE_RAY).
inline bool to_tiny(const Ray& r, tinybvh::Ray& t, float& t0) {
  t0 = r.tmin > 0.0f ? r.tmin : 0.0f;
  t.O = t0 > 0.0f ? tinybvh::bvhvec3(r.ox + t0 * r.dx, r.oy + t0 * r.dy, r.oz + t0 * r.dz) : tinybvh::bvhvec3(r.ox, r.oy, r.oz);
  t.D = tinybvh::bvhvec3(r.dx, r.dy, r.dz);
  t.rD = tinybvh::tinybvh_rcp(t.D);
  t.mask = RAY_MASK_INTERSECT_ALL;
  t.instIdx = 0;
  t.hit.t = r.tmax - t0;
  t.hit.u = t.hit.v = 0.0f;
  t.hit.prim = 0;
  return t0 == 0.0f || (std::isfinite(t.O.x) && std::isfinite(t.O.y) && std::isfinite(t.O.z));
}

template <class B>
class TreeOf final : public Tree {
public:
  TreeOf(bool hq, const std::vector<float>& xyz, std::vector<std::uint32_t> prims) : prims_(std::move(prims)) {
    const std::size_t n = prims_.size();
    verts_.resize(3 * n);
    for (std::size_t i = 0; i < 3 * n; ++i)
      verts_[i] = tinybvh::bvhvec4(xyz[3 * i], xyz[3 * i + 1], xyz[3 * i + 2], 0.0f);
    if (hq) bvh_.BuildHQ(verts_.data(), static_cast<std::uint32_t>(n));
    else bvh_.Build(verts_.data(), static_cast<std::uint32_t>(n));
  }

  void closest(std::span<const Ray> rays, std::size_t b, std::size_t e, Hit* hits, std::size_t& invalid) const override {
    for (std::size_t i = b; i < e; ++i) {
      const Ray& r = rays[i];
      RayPre p;
      if (!prepare_ray(r, p)) {  // the numerical contract's invalid rays: defined misses
        ++invalid;
        continue;
      }
      tinybvh::Ray t;
      float t0;
      if (!to_tiny(r, t, t0)) continue;
      const float far = t.hit.t;
      bvh_.Intersect(t);
      if (t.hit.t < far)  // tinybvh accepts only t below the ray's current t
        hits[i] = Hit{t.hit.t + t0, t.hit.u, t.hit.v, prims_[t.hit.prim]};
    }
  }

  void any(std::span<const Ray> rays, std::size_t b, std::size_t e, std::uint8_t* occluded, std::size_t& invalid) const override {
    for (std::size_t i = b; i < e; ++i) {
      const Ray& r = rays[i];
      RayPre p;
      if (!prepare_ray(r, p)) {
        ++invalid;
        continue;
      }
      tinybvh::Ray t;
      float t0;
      if (!to_tiny(r, t, t0)) continue;
      occluded[i] = bvh_.IsOccluded(t) ? 1 : 0;
    }
  }

private:
  std::vector<std::uint32_t> prims_;      // tinybvh's triangle index -> the file's prim id
  std::vector<tinybvh::bvhvec4> verts_;   // 3 per triangle (tinybvh's layouts copy them into their leaves)
  B bvh_;
};

}  // namespace

std::unique_ptr<Tree> build_tree(Width width, bool hq, const std::vector<float>& xyz, std::vector<std::uint32_t> prims) {
  if (width == Width::bvh4) return std::make_unique<TreeOf<tinybvh::BVH4_CPU>>(hq, xyz, std::move(prims));
  return std::make_unique<TreeOf<tinybvh::BVH8_CPU>>(hq, xyz, std::move(prims));
}

}  // namespace mbvh::tinybvh_peer

#if !defined(__clang__)
#pragma GCC pop_options
#endif

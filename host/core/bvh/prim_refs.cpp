// SPDX-License-Identifier: MIT
// prim_refs.cpp — what Accel::build reads from the scene: the record pass (one PrimRef per
// non-degenerate triangle, with the checks that the scene is traceable exactly) and, once the
// tree is built, the leaf-ordered triangle records.
#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>
#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "host/core/bvh/builder.h"
#include "host/core/bvh/triangles.h"
#include "host/core/huge_pages.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "mbvh/error.h"

namespace mbvh::build {
namespace {

[[noreturn]] void throw_below_scene_scale(const Scene& scene, float largest) {
  char buf[256];
  std::snprintf(buf, sizeof buf,
                ": the largest coordinate magnitude is %.9g, below 2^-36 (%.3g), the smallest scene scale mbvh traces "
                "exactly (float products of three coordinates would underflow); rescale the scene",
                double(largest), double(kMinSceneScale));
  throw Error(scene.display_name() + buf);
}

// The scene's non-degenerate triangles must lie in the exactly traced range (accel.h): a
// coordinate beyond ±kMaxCoordinate is named with its triangle; a scene whose largest magnitude
// is below kMinSceneScale is refused as a whole. `largest`: the largest magnitude of the records.
void check_traceable_range(const Scene& scene, const RawVector<PrimRef>& prims, float largest) {
  if (largest > kMaxCoordinate) {
    for (const PrimRef& r : prims) {  // the first offending triangle, in scene order
      Vec3f p[3];
      scene.triangle(r.prim, p[0], p[1], p[2]);
      const GeomPrim g = scene.geometry_of(r.prim);
      const std::array<std::uint32_t, 3> index =
          scene.meshes().empty() ? scene.triangles[r.prim] : scene.meshes()[g.geom_id].triangle(g.prim_id);
      for (int k = 0; k < 3; ++k)
        for (float c : {p[k].x, p[k].y, p[k].z})
          if (std::fabs(c) > kMaxCoordinate) {
            char buf[320];
            const std::string where =
                scene.meshes().empty() ? "" : ", geometry " + std::to_string(g.geom_id) + " triangle " + std::to_string(g.prim_id);
            std::snprintf(buf, sizeof buf,
                          ": coordinate %.9g of vertex %u (triangle %u%s) is beyond +-2^40 (%.3g), the range mbvh traces "
                          "exactly (float products of three coordinates would overflow); rescale the scene",
                          double(c), index[k], r.prim, where.c_str(), double(kMaxCoordinate));
            throw Error(scene.display_name() + buf);
          }
    }
  }
  if (largest < kMinSceneScale) throw_below_scene_scale(scene, largest);
}

#if defined(__SSE2__)
// A chunk's running bounds of its records' boxes and centroids, as SSE rows (x, y, z, unused):
// record() writes a triangle's PrimRef and grows them with the operations, and the operand
// order, of prim_ref, FastBox::grow and FastBox::grow_centroid (std::min(x, y) is y < x ? y : x,
// _mm_min_ps(y, x); std::max(x, y) is x < y ? y : x, _mm_max_ps(y, x)), so the records and
// bounds have the same bits as theirs, -0.0 and +0.0 included. Its three vertices' finiteness
// is finite()'s (x - x is +0 or NaN, summed; any order gives the same test).
struct RecordRows {
  __m128 lo = _mm_set1_ps(INFINITY), hi = _mm_set1_ps(-INFINITY);
  __m128 clo = _mm_set1_ps(INFINITY), chi = _mm_set1_ps(-INFINITY);

  static __m128 row(const Vec3f& v) { return _mm_setr_ps(v.x, v.y, v.z, 0.0f); }
  static bool finite(__m128 a, __m128 b, __m128 c) {
    const __m128 s = _mm_add_ps(_mm_add_ps(_mm_sub_ps(a, a), _mm_sub_ps(b, b)), _mm_sub_ps(c, c));
    return (_mm_movemask_ps(_mm_cmpeq_ps(s, _mm_setzero_ps())) & 7) == 7;
  }
  // The record of the triangle (a, b, c) (finite rows; lane 3 zero) into r, its bounds grown.
  void record(__m128 a, __m128 b, __m128 c, std::uint32_t prim, PrimRef& r) {
    const __m128 l = _mm_min_ps(c, _mm_min_ps(b, a));
    const __m128 h = _mm_max_ps(c, _mm_max_ps(b, a));  // lane 3: 0, the record's pad
    lo = _mm_min_ps(l, lo);
    hi = _mm_max_ps(h, hi);
    const __m128 m = _mm_mul_ps(_mm_set1_ps(0.5f), _mm_add_ps(l, h));
    clo = _mm_min_ps(m, clo);
    chi = _mm_max_ps(m, chi);
    _mm_storeu_ps(r.lo, l);  // lane 3 lands on prim, written next
    r.prim = prim;
    _mm_storeu_ps(r.hi, h);
  }
};
#endif

// The leaf-ordered triangle records: tris[i] is the triangle `prim(order[i])` of the scene.
// `order` holds prim ids (SBVH) or the leaf-ordered records (binned SAH, LBVH).
std::uint32_t prim_of(std::uint32_t p) { return p; }
std::uint32_t prim_of(const PrimRef& r) { return r.prim; }

template <class Order>
void fill_tris_of(const Scene& scene, const Order& order, AlignedVector<Tri>& tris, unsigned threads) {
  // four chunks a worker at least, of 4096 to 65536 triangles: chunks of 65536 left a 70K-triangle
  // scene (the bunny, Sponza) a chunk of 65536 and one of a few thousand, the whole pass on one
  // worker; each triangle is written on its own, so the bytes do not depend on the chunks
  const std::size_t grain = std::clamp<std::size_t>(order.size() / (4 * std::size_t(resolve_threads(threads))), 4096, 65536);
  with_triangles(scene, [&](const auto& src) {
    parallel_for(order.size(), grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      constexpr std::size_t ahead = 16;  // triangles: vertices fetched this far ahead, indices twice as far
      for (std::size_t i = b; i < e; ++i) {
        if (i + 2 * ahead < e) src.prefetch_index(prim_of(order[i + 2 * ahead]));
        if (i + ahead < e) src.prefetch_vertices(prim_of(order[i + ahead]));
        const std::uint32_t prim = prim_of(order[i]);
        Vec3f v0, v1, v2;
        src.get(prim, v0, v1, v2);
        fill_tri(tris[i], v0, v1, v2, prim);
      }
    });
  });
}

}  // namespace

void throw_too_small(const Scene& scene, std::uint32_t prim, const char* who) {
  Vec3f p[3];
  scene.triangle(prim, p[0], p[1], p[2]);
  double edge[3];
  for (int k = 0; k < 3; ++k) {
    const Vec3f& a = p[k];
    const Vec3f& b = p[(k + 1) % 3];
    const double d[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
    edge[k] = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
  }
  std::string where;
  if (!scene.meshes().empty()) {
    const GeomPrim g = scene.geometry_of(prim);
    where = " (geometry " + std::to_string(g.geom_id) + " triangle " + std::to_string(g.prim_id) + ")";
  }
  char buf[512];
  std::snprintf(buf, sizeof buf,
                ": %striangle %u%s has area %.3g (edges %.3g, %.3g, %.3g), below 2^-110 (%.3g, accel.h "
                "kMinTriangleArea), the smallest triangle mbvh traces exactly (float products of its edges would "
                "underflow and rays pass through it); rescale the scene or remove the triangle",
                who, prim, where.c_str(), 0.5 * std::sqrt(twice_area_sq(p[0], p[1], p[2])), edge[0], edge[1], edge[2],
                double(kMinTriangleArea));
  throw Error(scene.display_name() + buf);
}

PrimRefs make_prim_refs(const Scene& scene, unsigned threads, RawVector<PrimRef>&& storage) {
  // chunks count their kept triangles, then write them at their prefix offsets with the chunk's
  // bounds; compiled once for the owned arrays and once for mesh views (triangles.h)
  const std::size_t n = scene.triangle_count();
  if (n > kMaxTriangles) throw Error(scene.display_name() + ": too many triangles for 32-bit references");
  // chunks of 65536, or of 16384 up to 256K triangles: a scene of 70K (the bunny, Sponza) then
  // makes five, so the second worker shares the pass even when it wakes late (with 65536 it got a
  // few thousand triangles); the records and bounds do not depend on the chunks (scene order
  // kept, bounds exact unions)
  const std::size_t grain = n <= (std::size_t(1) << 18) ? 16384 : 65536;
  const std::size_t chunks = (n + grain - 1) / grain;
  std::vector<std::size_t> kept_in(chunks, 0);
  PrimRefs out;
  RawVector<PrimRef>& prims = out.prims;
  prims = std::move(storage);
  prims.clear();
  prims.resize(n);
  advise_huge_pages(prims.data(), n * sizeof(PrimRef));  // written in full by the pass below
  std::vector<FastBox> cb(chunks), ccb(chunks);
  std::vector<float> mag(chunks, 0.0f);
  std::vector<float> tiny_mag(chunks, 0.0f);  // per chunk: the largest magnitude of its too-small triangles
  std::vector<std::size_t> tiny(chunks, SIZE_MAX);  // per chunk: its first triangle too small to trace
  std::atomic<bool> invalid{false};
  // a chunk that starts once every chunk before it has written its records in place (always, on
  // one worker: chunks run in order) writes its own at their final place, after the previous
  // chunk's; others write at their chunk's start and are moved down when they end or below.
  // end_of[c]: 1 + the end of chunk c's records once they are in place, else 0
  std::vector<std::atomic<std::size_t>> end_of(chunks);
  std::vector<std::uint8_t> in_place(chunks, 0);
  with_triangles(scene, [&](const auto& src) {
    parallel_for(n, grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      const std::size_t c = b / grain;
      const std::size_t after = c == 0 ? 1 : end_of[c - 1].load(std::memory_order_acquire);
      const std::size_t start = after ? after - 1 : b;  // at or below b: only this chunk's triangles are read below
      std::size_t o = start;
      FastBox box, cbox;
#if defined(__SSE2__)
      RecordRows rows;
#endif
      for (std::size_t i = b; i < e; ++i) {
        Vec3f v0, v1, v2;
        if (!src.get_checked(i, v0, v1, v2)) {
          invalid = true;
          continue;
        }
#if defined(__SSE2__)
        const __m128 r0 = RecordRows::row(v0), r1 = RecordRows::row(v1), r2 = RecordRows::row(v2);
        if (!RecordRows::finite(r0, r1, r2)) {
#else
        if (!finite(v0, v1, v2)) {
#endif
          invalid = true;
          continue;
        }
        const double a2 = twice_area_sq(v0, v1, v2);
        if (a2 == 0) continue;  // degenerate: in no leaf
        if (too_small(a2)) {  // refused below, the first in scene order named
          tiny[c] = std::min(tiny[c], i);
          for (const Vec3f& v : {v0, v1, v2})
            tiny_mag[c] = std::max({tiny_mag[c], std::fabs(v.x), std::fabs(v.y), std::fabs(v.z)});
          continue;
        }
#if defined(__SSE2__)
        rows.record(r0, r1, r2, static_cast<std::uint32_t>(i), prims[o++]);
#else
        const PrimRef r = prim_ref(v0, v1, v2, static_cast<std::uint32_t>(i));
        box.grow(r);
        cbox.grow_centroid(r);
        prims[o++] = r;
#endif
      }
#if defined(__SSE2__)
      set_rows(box, rows.lo, rows.hi);
      set_rows(cbox, rows.clo, rows.chi);
#endif
      float m = 0;  // the largest magnitude of the records: on each axis, their least lo or greatest hi
      if (o > start)
        for (int a = 0; a < 3; ++a) m = std::max({m, std::fabs(box.lo[a]), std::fabs(box.hi[a])});
      kept_in[c] = o - start;
      // a chunk that started early moves its records down itself if the chunks before it are in
      // place by now (the move then runs beside the other chunks' work, not in the serial step)
      const std::size_t now = after ? after : end_of[c - 1].load(std::memory_order_acquire);
      if (now) {
        if (!after && kept_in[c]) std::memmove(&prims[now - 1], &prims[b], kept_in[c] * sizeof(PrimRef));
        in_place[c] = 1;
        end_of[c].store(now + kept_in[c], std::memory_order_release);
      }
      cb[c] = box;
      ccb[c] = cbox;
      mag[c] = m;
    });
  });
  if (invalid) {
    scene.validate();  // throws, naming the first bad triangle
    throw Error(scene.display_name() + ": internal: a triangle failed the build's index or finiteness check but not Scene::validate");
  }
  if (const std::size_t first = chunks ? *std::min_element(tiny.begin(), tiny.end()) : SIZE_MAX; first != SIZE_MAX) {
    // a scene too small as a whole is named as such before any of its triangles
    float all = 0;
    for (std::size_t c = 0; c < chunks; ++c) all = std::max({all, mag[c], tiny_mag[c]});
    if (all < kMinSceneScale) throw_below_scene_scale(scene, all);
    throw_too_small(scene, static_cast<std::uint32_t>(first), "");
  }
  std::size_t kept = 0;  // close the other chunks' gaps (in place: a record only moves down)
  for (std::size_t c = 0; c < chunks; ++c) {
    if (!in_place[c] && kept != c * grain) std::memmove(&prims[kept], &prims[c * grain], kept_in[c] * sizeof(PrimRef));
    kept += kept_in[c];
  }
  prims.resize(kept);
  out.degenerate = n - kept;
  if (kept == 0)
    throw Error(scene.display_name() + ": the scene has no non-degenerate triangle (" + std::to_string(n) + " triangles, " +
                std::to_string(out.degenerate) + " degenerate)");
  float largest = 0;
  for (std::size_t c = 0; c < chunks; ++c) {
    out.root.grow(cb[c]);
    out.croot.grow(ccb[c]);
    largest = std::max(largest, mag[c]);
  }
  check_traceable_range(scene, prims, largest);
  return out;
}

void fill_tris(const Scene& scene, const RawVector<PrimRef>& order, AlignedVector<Tri>& tris, unsigned threads) {
  fill_tris_of(scene, order, tris, threads);
}

void fill_tris(const Scene& scene, const std::vector<std::uint32_t>& order, AlignedVector<Tri>& tris, unsigned threads) {
  fill_tris_of(scene, order, tris, threads);
}

}  // namespace mbvh::build

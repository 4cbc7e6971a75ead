// SPDX-License-Identifier: MIT
// recursion.h — divide-and-conquer ray tracing without an acceleration structure: Áfra,
// "Incoherent Ray Tracing without Acceleration Structures", Eurographics 2012 short paper (the
// thesis' chapter 6), after Keller & Wächter's HPG 2011 poster. A set of rays meets a set of
// triangles: the rays that miss the triangles' bounding box leave (the filter), a few rays or
// triangles are intersected naively (the leaf, many rays against one triangle at a time), else the
// triangles are split in two and each half recursed on, the nearer half first. The recursion walks
// an implicit BVH over the rays and the triangles together and stores none.
//
// What is ours (the papers leave it open or measure otherwise; docs/backends.md, "dacrt"):
// - Rays are 32-byte filter records (origin, tmin, reciprocal direction, current tmax) permuted in
//   place with their ids, so the active rays of a step are always a prefix of the array (the paper
//   moves its records the same way); what only the leaf reads (the shear of the watertight test)
//   stays in a side array by id.
// - Triangles are ids permuted in place over precomputed boxes; the split is the middle of the
//   centroid bounds' longest axis, or a binned SAH over all three axes where the active rays per
//   triangle exceed `ratio` (the paper's adaptive partitioning; its threshold "1-2").
// - Exact under the numerical contract: the filter is the conservative slab test (box_test's
//   operations, against tmax * kCullSlack) and the leaf the watertight test; a closest hit keeps
//   the smallest (t, prim) and shrinks tmax to t as visit_leaf does, so the answer is the
//   reference's but for the order-dependent corner ties every traversal order has (DESIGN.md).
// - Deterministic at any thread count: the batch is cut into fixed chunks of `chunk` rays in ray
//   order, each traced by the sequential recursion on its own triangle ids (parallel_for).
//
// The recursion and partitioning here are scalar C++ shared by every ISA; a kernel policy K brings
// the ray set-up, the filter and the leaf (scalar: dacrt_scalar.cpp; SIMD: dacrt/simd.h). Both
// policies make the same decisions bit for bit, so dacrt and dacrt-scalar give the same bytes.
#pragma once
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <vector>

#include "backends/cpu/cpu_backends.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"
#include "mbvh/accel.h"
#include "mbvh/trace.h"

namespace mbvh {
inline namespace MBVH_ISA_NS {
namespace {
namespace dacrt {

/// A ray's filter record, permuted in place with its id.
struct alignas(32) RayRec {
  float o[3];
  float tmin;
  float inv[3];  ///< 1 / d (the sign picks the near planes, as RayPre::neg)
  float tmax;    ///< the current end: the best hit's t (closest hit), -1 once occluded (any hit)
};
static_assert(sizeof(RayRec) == 32, "the filter moves 32-byte records");

/// A box; also the bounds of centroid sums (a triangle box's lo + hi per axis, twice its centre).
struct Bounds {
  float lo[3] = {INFINITY, INFINITY, INFINITY};
  float hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  void grow(const float* l, const float* h) {
    for (int a = 0; a < 3; ++a) {
      lo[a] = std::min(lo[a], l[a]);
      hi[a] = std::max(hi[a], h[a]);
    }
  }
  void grow(const Bounds& b) { grow(b.lo, b.hi); }
  float extent(int a) const { return hi[a] - lo[a]; }
  float half_area() const {
    const float x = hi[0] - lo[0], y = hi[1] - lo[1], z = hi[2] - lo[2];
    return x * y + y * z + z * x;
  }
};

inline Bounds tri_bounds(const Tri& t) {
  Bounds b;
  b.grow(t.v0, t.v0);
  b.grow(t.v1, t.v1);
  b.grow(t.v2, t.v2);
  return b;
}
inline void centroid2(const Bounds& b, float c[3]) {
  for (int a = 0; a < 3; ++a) c[a] = b.lo[a] + b.hi[a];
}

/// One chunk's working set: its rays' records and ids (permuted together), the policy's side
/// array by id, the outputs by id (the chunk's slice), and the triangle ids (permuted).
template <class K>
struct Work {
  RayRec* rec = nullptr;
  std::uint32_t* id = nullptr;
  typename K::Side* side = nullptr;
  const Ray* rays = nullptr;
  Hit* hits = nullptr;
  std::uint8_t* occluded = nullptr;
  RayStats* stats = nullptr;
  const Tri* tris = nullptr;
  const Bounds* boxes = nullptr;
  std::uint32_t* tid = nullptr;
  const DacrtSettings* s = nullptr;
  typename K::Local* local = nullptr;
};

/// How a step splits its triangles: on `axis`, by the middle of the centroid bounds (`mid2`, in
/// centroid sums) or by SAH bin (`bin` and below go left).
struct Split {
  int axis = -1;
  bool sah = false;
  float mid2 = 0;
  float lo = 0, scale = 0;
  unsigned bins = 0, bin = 0;
  bool left(const float c[3]) const {
    if (!sah) return c[axis] < mid2;
    return bin_of(c[axis]) <= bin;
  }
  unsigned bin_of(float c) const {
    const float f = (c - lo) * scale;
    return f >= float(bins - 1) ? bins - 1 : static_cast<unsigned>(f);
  }
};

/// The middle of the centroid bounds' longest axis; no split (axis -1) when every centroid is equal.
inline Split middle_split(const Bounds& cb) {
  Split sp;
  int a = 0;
  if (cb.extent(1) > cb.extent(a)) a = 1;
  if (cb.extent(2) > cb.extent(a)) a = 2;
  if (!(cb.extent(a) > 0.0f)) return sp;
  sp.axis = a;
  sp.mid2 = cb.lo[a] + cb.extent(a) * 0.5f;
  return sp;
}

/// A binned SAH split (Wald 2007) over the three axes of the centroid bounds: the bin boundary
/// with the least count-weighted area of the two sides' triangle boxes.
inline Split sah_split(const std::uint32_t* tid, std::uint32_t tb, std::uint32_t te, const Bounds* boxes, const Bounds& cb,
                       unsigned bins) {
  constexpr unsigned kMaxBins = 64;
  bins = std::clamp(bins, 2u, kMaxBins);
  Split per_axis[3];
  Bounds box[3][kMaxBins];
  std::uint32_t count[3][kMaxBins] = {};
  for (int a = 0; a < 3; ++a) {
    if (!(cb.extent(a) > 0.0f)) continue;
    Split& sp = per_axis[a];
    sp.axis = a;
    sp.sah = true;
    sp.bins = bins;
    sp.lo = cb.lo[a];
    sp.scale = float(bins) / cb.extent(a);
  }
  for (std::uint32_t j = tb; j < te; ++j) {
    const Bounds& b = boxes[tid[j]];
    float c[3];
    centroid2(b, c);
    for (int a = 0; a < 3; ++a) {
      if (per_axis[a].axis < 0) continue;
      const unsigned k = per_axis[a].bin_of(c[a]);
      ++count[a][k];
      box[a][k].grow(b);
    }
  }
  Split best;
  float best_cost = INFINITY;
  for (int a = 0; a < 3; ++a) {
    if (per_axis[a].axis < 0) continue;
    float right_area[kMaxBins];
    std::uint32_t right_count[kMaxBins];
    Bounds r;
    std::uint32_t n = 0;
    for (unsigned k = bins - 1; k > 0; --k) {  // right side of boundary k - 1 | k
      r.grow(box[a][k]);
      n += count[a][k];
      right_area[k] = n ? r.half_area() : 0.0f;
      right_count[k] = n;
    }
    Bounds l;
    n = 0;
    for (unsigned k = 0; k + 1 < bins; ++k) {
      l.grow(box[a][k]);
      n += count[a][k];
      if (n == 0 || right_count[k + 1] == 0) continue;
      const float cost = float(n) * l.half_area() + float(right_count[k + 1]) * right_area[k + 1];
      if (cost < best_cost) {
        best_cost = cost;
        best = per_axis[a];
        best.bin = k;
      }
    }
  }
  return best;
}

/// The recursion over one chunk. Any: occlusion; Fast: the `fast` precision's tests.
template <class K, bool Any, bool Fast, bool Stats>
struct Recursion {
  Work<K>& w;
  /// Deeper than any split of float centroids needs in practice; a step there is a leaf (exact,
  /// only slower).
  static constexpr unsigned kMaxDepth = 64;

  void node(std::size_t n, std::uint32_t tb, std::uint32_t te, const Bounds& box, const Bounds& cb, unsigned depth) {
    const std::size_t na = K::template filter<Fast>(w, n, box);
    if constexpr (Stats) {
      for (std::size_t p = 0; p < n; ++p) ++w.stats[w.id[p]].box_tests;
      for (std::size_t p = 0; p < na; ++p) {
        RayStats& st = w.stats[w.id[p]];
        ++st.nodes;
        st.max_depth = std::max(st.max_depth, depth + 1);
      }
    }
    if (na == 0) return;
    const DacrtSettings& s = *w.s;
    const std::uint32_t m = te - tb;
    if (na < s.leaf_rays || m <= s.leaf_tris || depth >= kMaxDepth) return leaf(na, tb, te);
    const bool sah = s.partition == DacrtSettings::Partition::sah ||
                     (s.partition == DacrtSettings::Partition::adaptive && double(na) > double(s.ratio) * double(m));
    Split sp = sah ? sah_split(w.tid, tb, te, w.boxes, cb, s.bins) : middle_split(cb);
    if (sp.axis < 0) return leaf(na, tb, te);
    // partition the ids in place, growing each side's box and centroid bounds
    Bounds lb, rb, lc, rc;
    std::uint32_t i = tb, j = te;
    while (i < j) {
      const std::uint32_t t = w.tid[i];
      const Bounds& b = w.boxes[t];
      float c[3];
      centroid2(b, c);
      if (sp.left(c)) {
        lb.grow(b);
        lc.grow(c, c);
        ++i;
      } else {
        rb.grow(b);
        rc.grow(c, c);
        --j;
        w.tid[i] = w.tid[j];
        w.tid[j] = t;
      }
    }
    if (i == tb || i == te) return leaf(na, tb, te);
    // the near side first: the first active ray's direction sign on the split axis (Wald, Boulos &
    // Shirley 2007's cheap order, as the paper does); its hits shrink tmax before the far side's filter
    const bool right_first = s.ordered && std::signbit(w.rec[0].inv[sp.axis]);
    if (right_first) {
      node(na, i, te, rb, rc, depth + 1);
      node(na, tb, i, lb, lc, depth + 1);
    } else {
      node(na, tb, i, lb, lc, depth + 1);
      node(na, i, te, rb, rc, depth + 1);
    }
  }

  void leaf(std::size_t na, std::uint32_t tb, std::uint32_t te) {
    if constexpr (Stats)
      for (std::size_t p = 0; p < na; ++p) ++w.stats[w.id[p]].leaves;
    K::template leaf<Any, Fast, Stats>(w, na, tb, te);
  }
};

/// A worker's buffers, kept across its chunks.
template <class K>
struct Scratch {
  std::vector<RayRec> rec;
  std::vector<std::uint32_t> id;
  std::vector<typename K::Side> side;
  std::vector<std::uint32_t> tid;
  typename K::Local local;
};

template <class K, bool Any, bool Fast, bool Stats>
void trace_chunk(Work<K>& w, std::size_t n_rays, std::uint32_t m, const Bounds& root, const Bounds& croot,
                 std::size_t& invalid) {
  std::size_t nv = 0;
  for (std::size_t i = 0; i < n_rays; ++i) {
    if constexpr (Any) w.occluded[i] = 0;
    else w.hits[i] = miss_hit();
    if constexpr (Stats) w.stats[i] = RayStats{};
    if (!K::set_up(w.rays[i], w.rec[nv], w.side[i], Fast)) {
      ++invalid;
      continue;
    }
    w.id[nv++] = static_cast<std::uint32_t>(i);
  }
  for (std::uint32_t t = 0; t < m; ++t) w.tid[t] = t;
  if (nv == 0 || m == 0) return;
  Recursion<K, Any, Fast, Stats>{w}.node(nv, 0, m, root, croot, 0);
}

/// Traces `rays` against acc.tris() with policy K: the triangle boxes first (parallel), then the
/// chunks of s.chunk rays, each a task of parallel_for.
template <class K>
void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
           const DacrtSettings& s) {
  const AlignedVector<Tri>& tris = acc.tris();
  const auto m = static_cast<std::uint32_t>(tris.size());
  std::vector<Bounds> boxes(m);
  constexpr std::size_t kBoxGrain = 16384;
  const std::size_t parts = (m + kBoxGrain - 1) / kBoxGrain;
  std::vector<Bounds> part_box(parts), part_c(parts);
  parallel_for(m, kBoxGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
    Bounds pb, pc;
    for (std::size_t i = b; i < e; ++i) {
      boxes[i] = tri_bounds(tris[i]);
      float c[3];
      centroid2(boxes[i], c);
      pb.grow(boxes[i]);
      pc.grow(c, c);
    }
    part_box[b / kBoxGrain] = pb;
    part_c[b / kBoxGrain] = pc;
  });
  Bounds root, croot;
  for (std::size_t k = 0; k < parts; ++k) {
    root.grow(part_box[k]);
    croot.grow(part_c[k]);
  }
  out.resize_for(rays.size(), opt);  // every ray's entries are written by its chunk
  const unsigned workers = resolve_threads(threads);
  const std::size_t chunk = std::max<std::size_t>(s.chunk, 1);
  std::vector<std::unique_ptr<Scratch<K>>> scratch(workers);
  std::vector<std::size_t> invalid((rays.size() + chunk - 1) / chunk, 0);
  const bool any = opt.query == Query::any, fast = opt.precision == Precision::fast;
  parallel_for(rays.size(), chunk, workers, [&](std::size_t b, std::size_t e, unsigned worker) {
    auto& sc = scratch[worker];
    if (!sc) sc = std::make_unique<Scratch<K>>();
    const std::size_t n = e - b;
    if (sc->rec.size() < n) {
      sc->rec.resize(n);
      sc->id.resize(n);
      sc->side.resize(n);
    }
    sc->tid.resize(m);
    Work<K> w;
    w.rec = sc->rec.data();
    w.id = sc->id.data();
    w.side = sc->side.data();
    w.rays = rays.data() + b;
    w.hits = any ? nullptr : out.hits.data() + b;
    w.occluded = any ? out.occluded.data() + b : nullptr;
    w.stats = opt.stats ? out.stats.data() + b : nullptr;
    w.tris = tris.data();
    w.boxes = boxes.data();
    w.tid = sc->tid.data();
    w.s = &s;
    w.local = &sc->local;
    std::size_t& inv = invalid[b / chunk];
#define MBVH_DACRT_CASE(A, F, S) trace_chunk<K, A, F, S>(w, n, m, root, croot, inv)
    if (any) {
      if (fast) { if (opt.stats) MBVH_DACRT_CASE(true, true, true); else MBVH_DACRT_CASE(true, true, false); }
      else { if (opt.stats) MBVH_DACRT_CASE(true, false, true); else MBVH_DACRT_CASE(true, false, false); }
    } else {
      if (fast) { if (opt.stats) MBVH_DACRT_CASE(false, true, true); else MBVH_DACRT_CASE(false, true, false); }
      else { if (opt.stats) MBVH_DACRT_CASE(false, false, true); else MBVH_DACRT_CASE(false, false, false); }
    }
#undef MBVH_DACRT_CASE
  });
  out.invalid = 0;
  for (std::size_t v : invalid) out.invalid += v;
}

/// The conservative slab test of a filter record against a box: box_test's operations (the near
/// planes by the sign of inv, inv_far = inv * kFarFactor, relaxed to inv in the fast precision,
/// the NaN-discarding max/min chain against [tmin, tmax * kCullSlack]).
template <bool Fast>
[[gnu::always_inline]] inline bool box_hit(const RayRec& r, const Bounds& b) {
  float tn[3], tf[3];
  for (int a = 0; a < 3; ++a) {
    const bool neg = std::signbit(r.inv[a]);
    const float near = neg ? b.hi[a] : b.lo[a], far = neg ? b.lo[a] : b.hi[a];
    tn[a] = (near - r.o[a]) * r.inv[a];
    tf[a] = (far - r.o[a]) * (Fast ? r.inv[a] : r.inv[a] * kFarFactor);
  }
  const float te = max_nan(tn[2], max_nan(tn[1], max_nan(tn[0], r.tmin)));
  const float tx = min_nan(tf[2], min_nan(tf[1], min_nan(tf[0], r.tmax * kCullSlack)));
  return te <= tx;
}

/// The filter record of a prepared ray.
inline void fill_record(const RayPre& p, RayRec& rec) {
  for (int a = 0; a < 3; ++a) {
    rec.o[a] = p.o[a];
    rec.inv[a] = p.inv[a];
  }
  rec.tmin = p.tmin;
  rec.tmax = p.tmax;
}

/// Moves the record and id at `from` to `to` and back (the in-place filter's swap).
template <class K>
[[gnu::always_inline]] inline void swap_rays(Work<K>& w, std::size_t to, std::size_t from) {
  std::swap(w.rec[to], w.rec[from]);
  std::swap(w.id[to], w.id[from]);
}

}  // namespace dacrt
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

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
//   moves its records the same way); what only the leaf reads (the shear of the watertight test,
//   the best hit so far) stays in a side array by id, fetched ahead by the leaf (moving it with the
//   records at every filter step moves far more bytes than a leaf reads).
// - Triangles are 32-byte records (box and id) permuted in place, so a step reads its triangles'
//   boxes in sequence (the paper permutes ids over boxes it keeps in place; by id, the boxes of
//   a step lie anywhere in memory); the split is the middle of the
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
#include <bit>
#include <cmath>
#include <cstdint>
#include <memory>
#include <span>
#include <stdexcept>
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

/// A triangle's box and its index in Accel::tris(), permuted in place by the partitioning.
struct alignas(32) TriRec {
  float lo[3];
  std::uint32_t id;
  float hi[3];
  float pad;
};
static_assert(sizeof(TriRec) == 32, "the partition moves 32-byte records");

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
inline void centroid2(const TriRec& b, float c[3]) {
  for (int a = 0; a < 3; ++a) c[a] = b.lo[a] + b.hi[a];
}

/// One chunk's working set: its rays' records and ids (permuted together), side records by id, the
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
  TriRec* tri = nullptr;  ///< the chunk's triangle records, permuted
  std::uint64_t* bits = nullptr;   ///< the filter's verdicts, one bit a ray (a step's, used at once)
  std::uint64_t* tbits = nullptr;  ///< the partition's sides, one bit a triangle (likewise)
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
  bool left(const TriRec& t) const {
    const float c = t.lo[axis] + t.hi[axis];
    return sah ? bin_of(c) <= bin : c < mid2;
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
inline Split sah_split(const TriRec* tri, std::uint32_t tb, std::uint32_t te, const Bounds& cb, unsigned bins) {
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
    const TriRec& b = tri[j];
    float c[3];
    centroid2(b, c);
    for (int a = 0; a < 3; ++a) {
      if (per_axis[a].axis < 0) continue;
      const unsigned k = per_axis[a].bin_of(c[a]);
      ++count[a][k];
      box[a][k].grow(b.lo, b.hi);
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

/// Swaps the rays at `to` and `from`: record and id (the in-place filter's move).
template <class K>
[[gnu::always_inline]] inline void swap_rays(Work<K>& w, std::size_t to, std::size_t from) {
  std::swap(w.rec[to], w.rec[from]);
  std::swap(w.id[to], w.id[from]);
}

/// Moves the items whose bit is set (k of the n, bits[i / 64] bit i % 64) to the front [0, k):
/// each unset one of the front swapped with a set one of the back, both taken in order (Hoare's
/// pairing: only the misplaced items move). Bits past n must be clear.
template <class Swap>
inline void pair_to_front(const std::uint64_t* bits, std::size_t n, std::size_t k, Swap&& swap) {
  if (k == 0 || k == n) return;
  std::size_t wi = 0, wj = k / 64;  // the words scanned in the front and in the back region
  std::uint64_t front = ~bits[0], back = bits[wj] & (~std::uint64_t(0) << (k % 64));
  const std::size_t last = (k - 1) / 64;
  for (;;) {
    while (front == 0 && wi < last) front = ~bits[++wi];
    if (front == 0) break;
    const std::size_t i = wi * 64 + static_cast<std::size_t>(std::countr_zero(front));
    if (i >= k) break;
    front &= front - 1;
    while (back == 0) back = bits[++wj];  // as many set items behind k as unset ones before it
    const std::size_t j = wj * 64 + static_cast<std::size_t>(std::countr_zero(back));
    back &= back - 1;
    swap(i, j);
  }
}

/// The recursion over one chunk. Any: occlusion; Fast: the `fast` precision's tests.
template <class K, bool Any, bool Fast, bool Stats>
struct Recursion {
  Work<K>& w;
  /// Deeper than any split of float centroids needs in practice; a step there is a leaf (exact,
  /// only slower).
  static constexpr unsigned kMaxDepth = 64;

  void node(std::size_t n, std::uint32_t tb, std::uint32_t te, const Bounds& box, const Bounds& cb, unsigned depth) {
    const std::size_t na = filter(n, box);
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
    Split sp = sah ? sah_split(w.tri, tb, te, cb, s.bins) : middle_split(cb);
    if (sp.axis < 0) return leaf(na, tb, te);
    // partition the records in place: one bit a triangle (its side), the left ones paired to the
    // front (pair_to_front), then each side's box and centroid bounds in a pass over its records
    // in sequence (which side a triangle takes is as good as random: no branch decides it)
    const TriRec* tr = w.tri + tb;
    std::size_t nl = 0;
    for (std::uint32_t b = 0; b < m; b += 64) {
      std::uint64_t word = 0;
      const std::uint32_t e = std::min(m, b + 64);
      for (std::uint32_t p = b; p < e; ++p) word |= std::uint64_t(sp.left(tr[p]) ? 1 : 0) << (p - b);
      w.tbits[b / 64] = word;
      nl += static_cast<std::size_t>(std::popcount(word));
    }
    if (nl == 0 || nl == m) return leaf(na, tb, te);
    pair_to_front(w.tbits, m, nl, [&](std::size_t a, std::size_t b) { std::swap(w.tri[tb + a], w.tri[tb + b]); });
    const auto i = static_cast<std::uint32_t>(tb + nl);
    Bounds lb, rb, lc, rc;
    side_bounds(w.tri + tb, w.tri + i, lb, lc);
    side_bounds(w.tri + i, w.tri + te, rb, rc);
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

  /// The filter: the policy's slab tests write one bit a ray (K::test), then the active rays move
  /// to the front, each inactive one of the front swapped with an active one of the back, both
  /// taken in order (Hoare's pairing: only the misplaced records move). Returns the active count.
  std::size_t filter(std::size_t n, const Bounds& box) {
    const std::size_t na = K::template test<Fast>(w, n, box);
    pair_to_front(w.bits, n, na, [&](std::size_t i, std::size_t j) { swap_rays(w, i, j); });
    return na;
  }

  /// The box and centroid bounds of the records [b, e).
  static void side_bounds(const TriRec* b, const TriRec* e, Bounds& box, Bounds& cen) {
    for (const TriRec* r = b; r != e; ++r) {
      float c[3];
      centroid2(*r, c);
      box.grow(r->lo, r->hi);
      cen.grow(c, c);
    }
  }

  void leaf(std::size_t na, std::uint32_t tb, std::uint32_t te) {
    if constexpr (Stats)
      for (std::size_t p = 0; p < na; ++p) ++w.stats[w.id[p]].leaves;
    K::template leaf<Any, Fast, Stats>(w, na, tb, te);
  }
};

/// A worker's buffers, kept across its chunks and (by the backend) across calls.
template <class K>
struct Scratch : DacrtScratch {
  std::vector<RayRec> rec;
  std::vector<std::uint32_t> id;
  std::vector<typename K::Side> side;
  std::vector<TriRec> tri;
  std::vector<std::uint64_t> bits, tbits;
  typename K::Local local;
};

template <class K, bool Any, bool Fast, bool Stats>
void trace_chunk(Work<K>& w, std::size_t n_rays, std::uint32_t m, const TriRec* boxes, const Bounds& root, const Bounds& croot,
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
  std::copy(boxes, boxes + m, w.tri);
  if (nv == 0 || m == 0) return;
  Recursion<K, Any, Fast, Stats>{w}.node(nv, 0, m, root, croot, 0);
  if constexpr (!Any)
    for (std::size_t p = 0; p < nv; ++p) w.hits[w.id[p]] = K::best(w, p);  // the answers, by id
}

/// Traces `rays` against acc.tris() with policy K: the triangle records first (parallel), then the
/// chunks of s.chunk rays, each a task of parallel_for on its own copy of them.
/// The triangle records every chunk starts from, kept across calls.
struct SharedScratch : DacrtScratch {
  std::vector<TriRec> boxes;
};

template <class K>
void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out, unsigned threads,
           const DacrtSettings& s, DacrtBuffers& buffers) {
  const AlignedVector<Tri>& tris = acc.tris();
  const auto m = static_cast<std::uint32_t>(tris.size());
  const unsigned workers = resolve_threads(threads);
  if (buffers.size() != workers + 1 || !dynamic_cast<SharedScratch*>(buffers[0].get())) {
    buffers.clear();
    buffers.push_back(std::make_unique<SharedScratch>());
    for (unsigned k = 0; k < workers; ++k) buffers.push_back(std::make_unique<Scratch<K>>());
  }
  std::vector<TriRec>& boxes = static_cast<SharedScratch&>(*buffers[0]).boxes;
  boxes.resize(m);
  constexpr std::size_t kBoxGrain = 16384;
  const std::size_t parts = (m + kBoxGrain - 1) / kBoxGrain;
  std::vector<Bounds> part_box(parts), part_c(parts);
  parallel_for(m, kBoxGrain, threads, [&](std::size_t first, std::size_t end, unsigned) {
    Bounds pb, pc;
    for (std::size_t i = first; i < end; ++i) {
      const Bounds b = tri_bounds(tris[i]);
      TriRec& r = boxes[i];
      for (int a = 0; a < 3; ++a) {
        r.lo[a] = b.lo[a];
        r.hi[a] = b.hi[a];
      }
      r.id = static_cast<std::uint32_t>(i);
      r.pad = 0.0f;
      float c[3];
      centroid2(b, c);
      pb.grow(b);
      pc.grow(c, c);
    }
    part_box[first / kBoxGrain] = pb;
    part_c[first / kBoxGrain] = pc;
  });
  Bounds root, croot;
  for (std::size_t k = 0; k < parts; ++k) {
    root.grow(part_box[k]);
    croot.grow(part_c[k]);
  }
  out.resize_for(rays.size(), opt);  // every ray's entries are written by its chunk
  const std::size_t chunk = std::max<std::size_t>(s.chunk, 1);
  std::vector<std::size_t> invalid((rays.size() + chunk - 1) / chunk, 0);
  const bool any = opt.query == Query::any, fast = opt.precision == Precision::fast;
  parallel_for(rays.size(), chunk, workers, [&](std::size_t b, std::size_t e, unsigned worker) {
    auto* sc = dynamic_cast<Scratch<K>*>(buffers[1 + worker].get());
    if (!sc) throw std::logic_error("dacrt: a worker's buffers are of another kernel");
    const std::size_t n = e - b;
    // each on its own: a resize that threw leaves the others right for the next call
    if (sc->rec.size() < n) sc->rec.resize(n);
    if (sc->id.size() < n) sc->id.resize(n);
    if (sc->side.size() < n) sc->side.resize(n);
    if (sc->bits.size() < n / 64 + 1) sc->bits.resize(n / 64 + 1);
    sc->tri.resize(m);
    sc->tbits.resize(m / 64 + 1);
    Work<K> w;
    w.rec = sc->rec.data();
    w.id = sc->id.data();
    w.side = sc->side.data();
    w.rays = rays.data() + b;
    w.hits = any ? nullptr : out.hits.data() + b;
    w.occluded = any ? out.occluded.data() + b : nullptr;
    w.stats = opt.stats ? out.stats.data() + b : nullptr;
    w.tris = tris.data();
    w.tri = sc->tri.data();
    w.bits = sc->bits.data();
    w.tbits = sc->tbits.data();
    w.s = &s;
    w.local = &sc->local;
    std::size_t& inv = invalid[b / chunk];
#define MBVH_DACRT_CASE(A, F, S) trace_chunk<K, A, F, S>(w, n, m, boxes.data(), root, croot, inv)
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

}  // namespace dacrt
}  // namespace
}  // namespace MBVH_ISA_NS
}  // namespace mbvh

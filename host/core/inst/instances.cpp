// SPDX-License-Identifier: MIT
// instances.cpp — the two-level scene (mbvh/instance.h): instance transforms and their inverses,
// the top-level BVH over the instances' world boxes (the binned-SAH builder of Accel::build over
// one record per instance), its refit, the top-level traversal calling each mesh's single-ray
// query with the object-space ray, flattening, and the comparison with a flattened scene.
#include "mbvh/instance.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <sstream>
#include <string>

#include "host/core/bvh/builder.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"
#include "mbvh/error.h"

namespace mbvh {

// -- Affine helpers: computed in double, each entry rounded to float once

Affine Affine::translation(float x, float y, float z) {
  Affine a;
  a.m[3] = x, a.m[7] = y, a.m[11] = z;
  return a;
}

Affine Affine::scale(float x, float y, float z) {
  Affine a;
  a.m[0] = x, a.m[5] = y, a.m[10] = z;
  return a;
}

Affine Affine::rotation(float x, float y, float z, float radians) {
  const double n = std::sqrt(double(x) * x + double(y) * y + double(z) * z);
  if (!(n > 0) || !std::isfinite(n) || !std::isfinite(radians))
    throw Error("Affine::rotation: the axis (" + std::to_string(x) + ", " + std::to_string(y) + ", " +
                std::to_string(z) + ") and the angle " + std::to_string(radians) +
                " must be finite, the axis not zero");
  const double ax = x / n, ay = y / n, az = z / n;
  const double c = std::cos(double(radians)), s = std::sin(double(radians)), k = 1 - c;  // Rodrigues
  const double r[9] = {c + ax * ax * k,      ax * ay * k - az * s, ax * az * k + ay * s,
                       ay * ax * k + az * s, c + ay * ay * k,      ay * az * k - ax * s,
                       az * ax * k - ay * s, az * ay * k + ax * s, c + az * az * k};
  Affine a;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) a.m[4 * i + j] = static_cast<float>(r[3 * i + j]);
  return a;
}

Affine operator*(const Affine& a, const Affine& b) {
  Affine c;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 4; ++j) {
      double s = j == 3 ? double(a.m[4 * i + 3]) : 0.0;
      for (int k = 0; k < 3; ++k) s += double(a.m[4 * i + k]) * double(b.m[4 * k + j]);
      c.m[4 * i + j] = static_cast<float>(s);
    }
  return c;
}

Vec3f Affine::apply(const Vec3f& p) const {
  Vec3f w;
  for (int i = 0; i < 3; ++i)
    w[i] = static_cast<float>(double(m[4 * i]) * p.x + double(m[4 * i + 1]) * p.y + double(m[4 * i + 2]) * p.z +
                              double(m[4 * i + 3]));
  return w;
}

// a named namespace, not an anonymous one: InstanceScene::Impl, a class of the public header,
// holds these types (an anonymous one would give the class internal-linkage members)
namespace instances_detail {

using Clock = std::chrono::steady_clock;

/// What the traversal reads of one instance: L^-1 in double, the translation, the mesh's query.
struct InstRec {
  double inv[9];
  double t[3];
  const RayQuery* query;
  std::uint32_t mask;
};

/// A top-level node with both children's boxes (Aila & Laine 2009's MBVH2 record, TRAVERSAL.md
/// §2.2), their references (>= 0 a node, MBVH_EMPTY none, else ~leaf) and their masks' union.
struct TopNode {
  float lo[2][3], hi[2][3];
  std::int32_t child[2];
  std::uint32_t mask[2];
};

std::string fmt(double v) {
  std::ostringstream s;
  s.precision(9);
  s << v;
  return s.str();
}

/// L^-1 and the condition number of L (infinity norms), or Error naming the instance.
void invert(const Affine& a, std::size_t i, double inv[9], double& cond) {
  for (int k = 0; k < 12; ++k)
    if (!std::isfinite(a.m[k]))
      throw Error("instance " + std::to_string(i) + ": transform entry m[" + std::to_string(k) + "] (row " +
                  std::to_string(k / 4) + ", column " + std::to_string(k % 4) + ") is " + fmt(a.m[k]) +
                  ": every entry must be finite");
  const auto L = [&](int r, int c) { return double(a.m[4 * r + c]); };
  const double c00 = L(1, 1) * L(2, 2) - L(1, 2) * L(2, 1), c01 = L(1, 2) * L(2, 0) - L(1, 0) * L(2, 2),
               c02 = L(1, 0) * L(2, 1) - L(1, 1) * L(2, 0);
  const double det = L(0, 0) * c00 + L(0, 1) * c01 + L(0, 2) * c02;
  if (det == 0 || !std::isfinite(det))
    throw Error("instance " + std::to_string(i) + ": transform is singular (determinant " + fmt(det) +
                "): an instance needs an invertible linear part");
  const double id = 1.0 / det;
  inv[0] = c00 * id, inv[1] = (L(0, 2) * L(2, 1) - L(0, 1) * L(2, 2)) * id, inv[2] = (L(0, 1) * L(1, 2) - L(0, 2) * L(1, 1)) * id;
  inv[3] = c01 * id, inv[4] = (L(0, 0) * L(2, 2) - L(0, 2) * L(2, 0)) * id, inv[5] = (L(0, 2) * L(1, 0) - L(0, 0) * L(1, 2)) * id;
  inv[6] = c02 * id, inv[7] = (L(0, 1) * L(2, 0) - L(0, 0) * L(2, 1)) * id, inv[8] = (L(0, 0) * L(1, 1) - L(0, 1) * L(1, 0)) * id;
  double nl = 0, ni = 0;
  for (int r = 0; r < 3; ++r) {
    nl = std::max(nl, std::fabs(L(r, 0)) + std::fabs(L(r, 1)) + std::fabs(L(r, 2)));
    ni = std::max(ni, std::fabs(inv[3 * r]) + std::fabs(inv[3 * r + 1]) + std::fabs(inv[3 * r + 2]));
  }
  cond = nl * ni;
  if (!(cond <= kMaxInstanceCondition))
    throw Error("instance " + std::to_string(i) + ": transform is ill-conditioned (condition number " + fmt(cond) +
                " > 2^20, kMaxInstanceCondition): its object-space rays would lose too much precision");
}

/// The corners of `b` under `a`, in double, rounded outwards to float.
Box world_box(const Affine& a, const Box& b) {
  double lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
  for (int c = 0; c < 8; ++c) {
    const double p[3] = {(c & 1) ? b.hi.x : b.lo.x, (c & 2) ? b.hi.y : b.lo.y, (c & 4) ? b.hi.z : b.lo.z};
    for (int r = 0; r < 3; ++r) {
      const double w = double(a.m[4 * r]) * p[0] + double(a.m[4 * r + 1]) * p[1] + double(a.m[4 * r + 2]) * p[2] +
                       double(a.m[4 * r + 3]);
      lo[r] = std::min(lo[r], w), hi[r] = std::max(hi[r], w);
    }
  }
  Box out;
  for (int r = 0; r < 3; ++r) {
    float l = static_cast<float>(lo[r]), h = static_cast<float>(hi[r]);
    if (double(l) > lo[r]) l = std::nextafter(l, -INFINITY);
    if (double(h) < hi[r]) h = std::nextafter(h, INFINITY);
    out.lo[r] = l, out.hi[r] = h;
  }
  return out;
}

/// The object-space ray of the contract (InstanceScene::object_ray).
[[gnu::always_inline]] inline Ray to_object(const InstRec& R, const Ray& w) {
  const double ox = double(w.ox) - R.t[0], oy = double(w.oy) - R.t[1], oz = double(w.oz) - R.t[2];
  const double dx = w.dx, dy = w.dy, dz = w.dz;
  Ray o;
  o.ox = static_cast<float>(R.inv[0] * ox + R.inv[1] * oy + R.inv[2] * oz);
  o.oy = static_cast<float>(R.inv[3] * ox + R.inv[4] * oy + R.inv[5] * oz);
  o.oz = static_cast<float>(R.inv[6] * ox + R.inv[7] * oy + R.inv[8] * oz);
  o.dx = static_cast<float>(R.inv[0] * dx + R.inv[1] * dy + R.inv[2] * dz);
  o.dy = static_cast<float>(R.inv[3] * dx + R.inv[4] * dy + R.inv[5] * dz);
  o.dz = static_cast<float>(R.inv[6] * dx + R.inv[7] * dy + R.inv[8] * dz);
  o.tmin = w.tmin;
  o.tmax = w.tmax;
  return o;
}

}  // namespace instances_detail
using namespace instances_detail;

struct InstanceScene::Impl {
  std::vector<std::shared_ptr<const Accel>> meshes;
  std::vector<RayQuery> queries;                    ///< one per mesh
  std::vector<std::vector<std::uint64_t>> geom_off;  ///< per mesh: its geometries' first prim ids
  std::vector<Instance> inst;
  std::vector<InstRec> rec;
  std::vector<double> cond;
  std::vector<Box> boxes;                 ///< world boxes
  std::vector<std::uint64_t> flat_off;    ///< instance_count + 1 entries
  // the top level
  std::vector<TopNode> nodes;
  std::vector<std::int32_t> parent;       ///< node k: parent node * 2 + slot, -1 for the root
  std::vector<Leaf> leaves;               ///< ranges of `order`
  std::vector<std::int32_t> leaf_parent;  ///< leaf k: parent node * 2 + slot
  std::vector<std::uint32_t> order;       ///< instance indices in leaf order
  Box bounds;
  float pad_scale = 0, scale = 0;  ///< the per-ray widening: pad_scale * (max |o| + scale)
  bool stale = false;
  unsigned threads = 0;
  InstanceStats st;

  void check_index(std::size_t i, const char* what) const {
    if (i >= inst.size())
      throw Error(std::string(what) + ": instance " + std::to_string(i) + " out of range (" +
                  std::to_string(inst.size()) + " instances)");
  }
  /// Checks instance i's transform and fills its record and world box.
  void place(std::size_t i) {
    InstRec& R = rec[i];
    invert(inst[i].transform, i, R.inv, cond[i]);
    for (int r = 0; r < 3; ++r) R.t[r] = inst[i].transform.m[4 * r + 3];
    R.query = &queries[inst[i].mesh];
    R.mask = inst[i].mask;
    boxes[i] = world_box(inst[i].transform, meshes[inst[i].mesh]->bounds());
    for (int a = 0; a < 3; ++a)
      if (!(std::fabs(boxes[i].lo[a]) <= kMaxCoordinate && std::fabs(boxes[i].hi[a]) <= kMaxCoordinate))
        throw Error("instance " + std::to_string(i) + ": its world box reaches " +
                    fmt(std::max(std::fabs(boxes[i].lo[a]), std::fabs(boxes[i].hi[a]))) +
                    ", beyond kMaxCoordinate (" + fmt(kMaxCoordinate) + "), the exactly traced range");
  }
  /// The widening of the top level's boxes: the object-space ray's rounding (one rounding of each
  /// coordinate of origin and direction, relative 2^-24) moves the traced path, mapped back to
  /// world space, by at most about cond * 2^-24 * (|o| + |P| + |t|) at a point P of an
  /// instance's box; 2^-20 covers that with a margin for the few double roundings.
  void set_padding() {
    double kmax = 1, s = 0;
    for (std::size_t i = 0; i < inst.size(); ++i) {
      kmax = std::max(kmax, cond[i]);
      for (int a = 0; a < 3; ++a)
        s = std::max({s, double(std::fabs(boxes[i].lo[a])), double(std::fabs(boxes[i].hi[a])),
                      std::fabs(rec[i].t[a])});
    }
    pad_scale = static_cast<float>(0x1p-20 * kmax);
    scale = static_cast<float>(s);
  }
  void build_top();
  void refit_top();
  template <bool Any>
  bool traverse(const Ray& ray, std::uint32_t mask, Hit& best, std::uint32_t& best_inst) const;
};

// -- the top level: the binned-SAH builder over one record per instance (Wald 2007)

void InstanceScene::Impl::build_top() {
  const auto t0 = Clock::now();
  nodes.clear(), parent.clear(), leaves.clear(), leaf_parent.clear(), order.clear();
  bounds = Box();
  if (inst.empty()) {
    st = {0, meshes.size(), 0, 0, 0, st.refit_ms};
    return;
  }
  build::RawVector<build::PrimRef> prims(inst.size());
  build::FastBox root, croot;
  for (std::size_t i = 0; i < inst.size(); ++i) {
    build::PrimRef& p = prims[i];
    for (int a = 0; a < 3; ++a) p.lo[a] = boxes[i].lo[a], p.hi[a] = boxes[i].hi[a];
    p.prim = static_cast<std::uint32_t>(i);
    p.pad = 0;
    root.grow(p);
    croot.grow_centroid(p);
  }
  BuildOptions opt;
  opt.threads = threads;
  opt.max_leaf = 1;  // one instance a leaf where the centroids allow: an instance costs a traversal
  build::Arenas arenas;
  build::build_binned_sah(prims, root, croot, opt, arenas);
  Bvh2 bvh;
  build::flatten(arenas, bvh, leaves, threads);
  order.resize(prims.size());
  for (std::size_t k = 0; k < prims.size(); ++k) order[k] = prims[k].prim;
  // -- the compact two-box nodes, with parent slots for refit
  nodes.resize(bvh.nodes.size());
  parent.assign(bvh.nodes.size(), -1);
  leaf_parent.assign(leaves.size(), -1);
  for (std::size_t k = 0; k < bvh.nodes.size(); ++k)
    for (int s = 0; s < 2; ++s) {
      const std::int32_t c = bvh.nodes[k].child[s];
      nodes[k].child[s] = c;
      if (c >= 0) parent[static_cast<std::size_t>(c)] = static_cast<std::int32_t>(2 * k + s);
      else if (c != MBVH_EMPTY) leaf_parent[static_cast<std::size_t>(~c)] = static_cast<std::int32_t>(2 * k + s);
    }
  refit_top();
  st.instances = inst.size();
  st.meshes = meshes.size();
  st.nodes = nodes.size();
  st.leaves = leaves.size();
  st.build_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

void InstanceScene::Impl::refit_top() {
  const auto put = [&](std::int32_t slot, const Box& b, std::uint32_t m) {
    TopNode& n = nodes[static_cast<std::size_t>(slot >> 1)];
    const int s = slot & 1;
    for (int a = 0; a < 3; ++a) n.lo[s][a] = b.lo[a], n.hi[s][a] = b.hi[a];
    n.mask[s] = m;
  };
  for (TopNode& n : nodes)
    for (int s = 0; s < 2; ++s) {
      for (int a = 0; a < 3; ++a) n.lo[s][a] = INFINITY, n.hi[s][a] = -INFINITY;
      n.mask[s] = 0;
    }
  for (std::size_t l = 0; l < leaves.size(); ++l) {
    Box b;
    std::uint32_t m = 0;
    for (std::uint32_t k = leaves[l].first; k < leaves[l].first + leaves[l].count; ++k) {
      b.grow(boxes[order[k]]);
      m |= rec[order[k]].mask;
    }
    put(leaf_parent[l], b, m);
  }
  bounds = Box();
  for (std::size_t k = nodes.size(); k-- > 0;) {  // depth-first order: children after parents
    Box b;
    std::uint32_t m = 0;
    for (int s = 0; s < 2; ++s) {
      if (nodes[k].child[s] == MBVH_EMPTY) continue;
      b.grow(Box{{nodes[k].lo[s][0], nodes[k].lo[s][1], nodes[k].lo[s][2]},
                 {nodes[k].hi[s][0], nodes[k].hi[s][1], nodes[k].hi[s][2]}});
      m |= nodes[k].mask[s];
    }
    if (parent[k] >= 0) put(parent[k], b, m);
    else bounds = b;
  }
  set_padding();
}

// -- traversal: the top level's stack, nearest child first; each instance's mesh through its
//    single-ray query with the object-space ray and the best t so far as tmax

template <bool Any>
bool InstanceScene::Impl::traverse(const Ray& ray, std::uint32_t mask, Hit& best, std::uint32_t& best_inst) const {
  RayPre r;
  if (nodes.empty() || !prepare_ray(ray, r)) return false;
  const float mo = std::max({std::fabs(r.o[0]), std::fabs(r.o[1]), std::fabs(r.o[2])});
  const float e = pad_scale * (mo + scale);
  float tmax = r.tmax;
  struct Entry {
    std::int32_t ref;
    float entry;
  };
  Entry stack[2 * MBVH_BINARY_DEPTH_CAP + 8];
  int sp = 0;
  stack[sp++] = {0, r.tmin};
  while (sp > 0) {
    const Entry top = stack[--sp];
    if (top.entry > tmax * kCullSlack) continue;
    if (top.ref >= 0) {
      const TopNode& n = nodes[static_cast<std::size_t>(top.ref)];
      float te[2];
      bool hit[2];
      for (int s = 0; s < 2; ++s) {
        hit[s] = n.child[s] != MBVH_EMPTY && (n.mask[s] & mask) != 0 &&
                 box_test(r, n.lo[s][0] - e, n.hi[s][0] + e, n.lo[s][1] - e, n.hi[s][1] + e, n.lo[s][2] - e,
                          n.hi[s][2] + e, tmax * kCullSlack, te[s]);
      }
      if (hit[0] && hit[1]) {
        const int nearer = te[1] < te[0] ? 1 : 0;
        stack[sp++] = {n.child[1 - nearer], te[1 - nearer]};
        stack[sp++] = {n.child[nearer], te[nearer]};
      } else if (hit[0]) stack[sp++] = {n.child[0], te[0]};
      else if (hit[1]) stack[sp++] = {n.child[1], te[1]};
      continue;
    }
    const Leaf& lf = leaves[static_cast<std::size_t>(~top.ref)];
    for (std::uint32_t k = lf.first; k < lf.first + lf.count; ++k) {
      const std::uint32_t i = order[k];
      const InstRec& R = rec[i];
      if (!(R.mask & mask)) continue;
      Ray o = to_object(R, ray);
      if constexpr (Any) {
        if (R.query->occluded(o)) return true;
      } else {
        o.tmax = tmax;
        const Hit h = R.query->intersect(o);
        if (h.prim != MBVH_MISS_PRIM && (h.t < best.t || (h.t == best.t && i < best_inst))) {
          best = h;
          best_inst = i;
          tmax = h.t;
        }
      }
    }
  }
  return best_inst != kInvalidInstance;
}

// -- the public calls

InstanceScene::InstanceScene(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
InstanceScene::InstanceScene(InstanceScene&&) noexcept = default;
InstanceScene& InstanceScene::operator=(InstanceScene&&) noexcept = default;
InstanceScene::~InstanceScene() = default;

InstanceScene InstanceScene::build(Backend& backend, std::vector<std::shared_ptr<const Accel>> meshes,
                                   std::vector<Instance> instances, unsigned threads) {
  auto s = std::make_unique<Impl>();
  if (instances.size() > 0x7FFFFFFFu)
    throw Error("InstanceScene::build: " + std::to_string(instances.size()) + " instances, more than 2^31 - 1");
  for (std::size_t m = 0; m < meshes.size(); ++m) {
    if (!meshes[m]) throw Error("InstanceScene::build: mesh " + std::to_string(m) + " is null");
    if (!meshes[m]->has_hierarchy())
      throw Error("InstanceScene::build: mesh " + std::to_string(m) +
                  " is a build without a hierarchy (BuildQuality::none): instancing traces its BVH");
  }
  s->meshes = std::move(meshes);
  s->inst = std::move(instances);
  s->threads = threads;
  s->flat_off.assign(s->inst.size() + 1, 0);
  for (std::size_t i = 0; i < s->inst.size(); ++i) {
    if (s->inst[i].mesh >= s->meshes.size())
      throw Error("InstanceScene::build: instance " + std::to_string(i) + " names mesh " +
                  std::to_string(s->inst[i].mesh) + ", out of range (" + std::to_string(s->meshes.size()) +
                  " meshes)");
    s->flat_off[i + 1] = s->flat_off[i] + s->meshes[s->inst[i].mesh]->scene_triangles();
  }
  // -- each mesh's query (made once: it resolves layout, leaves and kernels) and geometry offsets
  s->queries.reserve(s->meshes.size());
  s->geom_off.resize(s->meshes.size());
  for (std::size_t m = 0; m < s->meshes.size(); ++m) {
    const Accel& acc = *s->meshes[m];
    s->queries.push_back(backend.ray_query(acc));
    if (acc.geometry_count() > 1) {
      std::vector<std::uint64_t>& off = s->geom_off[m];
      off.assign(acc.geometry_count(), 0);
      for (std::size_t p = 0; p < acc.scene_triangles(); ++p) {
        const GeomPrim g = acc.geometry_of(static_cast<std::uint32_t>(p));
        if (g.prim_id == 0) off[g.geom_id] = p;
      }
    }
  }
  s->rec.resize(s->inst.size());
  s->cond.resize(s->inst.size());
  s->boxes.resize(s->inst.size());
  for (std::size_t i = 0; i < s->inst.size(); ++i) s->place(i);
  s->build_top();
  return InstanceScene(std::move(s));
}

InstanceHit InstanceScene::intersect(const Ray& ray, std::uint32_t mask) const {
  const Impl& s = *impl_;
  if (s.stale) throw Error("InstanceScene::intersect: an instance moved or changed its mask: call refit() or rebuild() first");
  Hit best{INFINITY, 0, 0, MBVH_MISS_PRIM};
  std::uint32_t bi = kInvalidInstance;
  InstanceHit out;
  if (!s.traverse<false>(ray, mask, best, bi)) return out;
  const Accel& acc = *s.meshes[s.inst[bi].mesh];
  const GeomPrim g = acc.geometry_count() > 1 ? acc.geometry_of(best.prim) : GeomPrim{0, best.prim};
  out.t = best.t, out.u = best.u, out.v = best.v;
  out.inst_id = bi, out.geom_id = g.geom_id, out.prim_id = g.prim_id;
  return out;
}

bool InstanceScene::occluded(const Ray& ray, std::uint32_t mask) const {
  const Impl& s = *impl_;
  if (s.stale) throw Error("InstanceScene::occluded: an instance moved or changed its mask: call refit() or rebuild() first");
  Hit best{INFINITY, 0, 0, MBVH_MISS_PRIM};
  std::uint32_t bi = kInvalidInstance;
  return s.traverse<true>(ray, mask, best, bi);
}

void InstanceScene::trace(std::span<const Ray> rays, Query query, InstanceOutput& out,
                          std::span<const std::uint32_t> masks) const {
  if (!masks.empty() && masks.size() != rays.size())
    throw Error("InstanceScene::trace: " + std::to_string(masks.size()) + " masks for " + std::to_string(rays.size()) +
                " rays: give one mask per ray, or none");
  if (impl_->stale) throw Error("InstanceScene::trace: an instance moved or changed its mask: call refit() or rebuild() first");
  const bool any = query == Query::any;
  out.hits.resize(any ? 0 : rays.size());
  out.occluded.resize(any ? rays.size() : 0);
  std::atomic<std::size_t> invalid{0};
  parallel_for(rays.size(), kTraceChunk, impl_->threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::size_t bad = 0;
    for (std::size_t k = b; k < e; ++k) {
      const std::uint32_t m = masks.empty() ? 0xFFFFFFFFu : masks[k];
      bad += ray_valid(rays[k]) ? 0 : 1;
      if (any) out.occluded[k] = occluded(rays[k], m) ? 1 : 0;
      else out.hits[k] = intersect(rays[k], m);
    }
    invalid += bad;
  });
  out.invalid = invalid;
}

void InstanceScene::set_transform(std::size_t i, const Affine& transform) {
  Impl& s = *impl_;
  s.check_index(i, "InstanceScene::set_transform");
  const Instance old = s.inst[i];
  const InstRec old_rec = s.rec[i];
  const Box old_box = s.boxes[i];
  const double old_cond = s.cond[i];
  s.inst[i].transform = transform;
  try {
    s.place(i);
  } catch (...) {
    s.inst[i] = old, s.rec[i] = old_rec, s.boxes[i] = old_box, s.cond[i] = old_cond;
    throw;
  }
  s.stale = true;
}

void InstanceScene::set_mask(std::size_t i, std::uint32_t mask) {
  Impl& s = *impl_;
  s.check_index(i, "InstanceScene::set_mask");
  s.inst[i].mask = mask;
  s.rec[i].mask = mask;
  s.stale = true;
}

void InstanceScene::refit() {
  const auto t0 = Clock::now();
  impl_->refit_top();
  impl_->stale = false;
  impl_->st.refit_ms = std::chrono::duration<double, std::milli>(Clock::now() - t0).count();
}

void InstanceScene::rebuild() {
  impl_->build_top();
  impl_->stale = false;
}

std::size_t InstanceScene::instance_count() const { return impl_->inst.size(); }
const Instance& InstanceScene::instance(std::size_t i) const {
  impl_->check_index(i, "InstanceScene::instance");
  return impl_->inst[i];
}
std::size_t InstanceScene::mesh_count() const { return impl_->meshes.size(); }
const Accel& InstanceScene::mesh(std::size_t m) const {
  if (m >= impl_->meshes.size())
    throw Error("InstanceScene::mesh: mesh " + std::to_string(m) + " out of range (" +
                std::to_string(impl_->meshes.size()) + " meshes)");
  return *impl_->meshes[m];
}
Box InstanceScene::bounds() const { return impl_->bounds; }
InstanceStats InstanceScene::stats() const { return impl_->st; }

Ray InstanceScene::object_ray(std::size_t i, const Ray& ray) const {
  impl_->check_index(i, "InstanceScene::object_ray");
  return to_object(impl_->rec[i], ray);
}

std::uint64_t InstanceScene::flat_offset(std::size_t i) const {
  if (i > impl_->inst.size())
    throw Error("InstanceScene::flat_offset: instance " + std::to_string(i) + " out of range (" +
                std::to_string(impl_->inst.size()) + " instances)");
  return impl_->flat_off[i];
}

std::uint64_t InstanceScene::flat_prim(const InstanceHit& h) const {
  if (!h.hit()) return MBVH_MISS_PRIM;
  impl_->check_index(h.inst_id, "InstanceScene::flat_prim");
  const std::uint32_t m = impl_->inst[h.inst_id].mesh;
  const std::vector<std::uint64_t>& off = impl_->geom_off[m];
  return impl_->flat_off[h.inst_id] + (off.empty() ? 0 : off[h.geom_id]) + h.prim_id;
}

Scene InstanceScene::flatten() const {
  const Impl& s = *impl_;
  Scene out;
  out.name = "flattened instances";
  const std::uint64_t total = s.flat_off.back();
  if (total > kMaxTriangles)
    throw Error("InstanceScene::flatten: " + std::to_string(total) + " triangles, beyond kMaxTriangles (" +
                std::to_string(kMaxTriangles) + ")");
  // each mesh's triangle records by prim id (a spatial-split build may hold one several times)
  std::vector<std::vector<std::uint32_t>> rec_of(s.meshes.size());
  for (std::size_t m = 0; m < s.meshes.size(); ++m) {
    const AlignedVector<Tri>& tris = s.meshes[m]->tris();
    rec_of[m].assign(s.meshes[m]->scene_triangles(), 0xFFFFFFFFu);
    for (std::size_t k = 0; k < tris.size(); ++k) rec_of[m][tri_prim(tris[k])] = static_cast<std::uint32_t>(k);
  }
  out.triangles.assign(total, {0, 0, 0});
  out.vertices.reserve(3 * total + 1);
  out.vertices.push_back({0, 0, 0});  // every degenerate triangle's one vertex
  for (std::size_t i = 0; i < s.inst.size(); ++i) {
    const std::uint32_t m = s.inst[i].mesh;
    const AlignedVector<Tri>& tris = s.meshes[m]->tris();
    for (std::size_t p = 0; p < rec_of[m].size(); ++p) {
      if (rec_of[m][p] == 0xFFFFFFFFu) continue;
      const Tri& t = tris[rec_of[m][p]];
      const auto first = static_cast<std::uint32_t>(out.vertices.size());
      out.vertices.push_back(s.inst[i].transform.apply({t.v0[0], t.v0[1], t.v0[2]}));
      out.vertices.push_back(s.inst[i].transform.apply({t.v1[0], t.v1[1], t.v1[2]}));
      out.vertices.push_back(s.inst[i].transform.apply({t.v2[0], t.v2[1], t.v2[2]}));
      out.triangles[s.flat_off[i] + p] = {first, first + 1, first + 2};
    }
  }
  return out;
}

// -- comparison with the flattened scene

namespace {

struct D3 {
  double x, y, z;
};
D3 sub(D3 a, D3 b) { return {a.x - b.x, a.y - b.y, a.z - b.z}; }
double dot(D3 a, D3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
double norm(D3 a) { return std::sqrt(dot(a, a)); }
D3 d3(const Vec3f& v) { return {v.x, v.y, v.z}; }

/// Distance from p to the segment ab.
double seg_dist(D3 p, D3 a, D3 b) {
  const D3 ab = sub(b, a), ap = sub(p, a);
  const double l2 = dot(ab, ab);
  const double s = l2 > 0 ? std::clamp(dot(ap, ab) / l2, 0.0, 1.0) : 0.0;
  return norm(sub(ap, {ab.x * s, ab.y * s, ab.z * s}));
}

}  // namespace

Comparison compare_flattened(const InstanceScene& scene, const Scene& flat_scene, std::span<const Ray> rays,
                             std::span<const InstanceHit> inst, std::span<const Hit> flat) {
  if (inst.size() != rays.size() || flat.size() != rays.size())
    throw Error("compare_flattened: " + std::to_string(rays.size()) + " rays, " + std::to_string(inst.size()) +
                " instanced answers and " + std::to_string(flat.size()) + " flattened answers: they must line up");
  std::vector<Hit> a(rays.size());
  for (std::size_t k = 0; k < rays.size(); ++k)
    a[k] = Hit{inst[k].t, inst[k].u, inst[k].v, static_cast<std::uint32_t>(scene.flat_prim(inst[k]))};
  std::vector<std::uint64_t> offs(scene.instance_count() + 1);
  for (std::size_t i = 0; i <= scene.instance_count(); ++i) offs[i] = scene.flat_offset(i);
  // whether hit h (a flattened prim) of ray r lies within the transform's rounding of its edges
  const auto explained = [&](const Ray& r, const Hit& h) {
    if (h.prim == MBVH_MISS_PRIM || h.prim >= flat_scene.triangle_count()) return false;
    const double t = h.t;
    if (std::fabs(t - r.tmin) <= 0x1p-18 * std::fabs(t) ||
        (std::isfinite(r.tmax) && std::fabs(t - r.tmax) <= 0x1p-18 * std::fabs(t)))
      return true;
    const std::size_t i =
        static_cast<std::size_t>(std::upper_bound(offs.begin(), offs.end(), std::uint64_t(h.prim)) - offs.begin()) - 1;
    const D3 d{r.dx, r.dy, r.dz};
    const D3 P{r.ox + t * d.x, r.oy + t * d.y, r.oz + t * d.z};
    // the object-space ray at t, mapped back to world space in double
    const Ray ob = scene.object_ray(i, r);
    const float* M = scene.instance(i).transform.m;
    const double q[3] = {ob.ox + t * double(ob.dx), ob.oy + t * double(ob.dy), ob.oz + t * double(ob.dz)};
    D3 Q;
    double* Qp[3] = {&Q.x, &Q.y, &Q.z};
    for (int row = 0; row < 3; ++row)
      *Qp[row] = double(M[4 * row]) * q[0] + double(M[4 * row + 1]) * q[1] + double(M[4 * row + 2]) * q[2] +
                 double(M[4 * row + 3]);
    const double disp = norm(sub(Q, P));
    // the object-space ray's displacement (twice, for margin), the flattened vertices' rounding
    // (2^-24 |P| a coordinate) and the float triangle test's (relative to the distance travelled)
    const double tol = 2 * disp + 0x1p-21 * (t * norm(d) + norm(P));
    Vec3f va, vb, vc;
    flat_scene.triangle(h.prim, va, vb, vc);
    const double edge = std::min({seg_dist(P, d3(va), d3(vb)), seg_dist(P, d3(vb), d3(vc)), seg_dist(P, d3(vc), d3(va))});
    return edge <= tol;
  };
  const TieRule rule = [&](std::size_t k, const Hit& x, const Hit& y) {
    const Ray& r = rays[k];
    const bool hx = x.prim != MBVH_MISS_PRIM, hy = y.prim != MBVH_MISS_PRIM;
    if (hx && hy) {
      if (x.t < y.t) return explained(r, x);
      if (y.t < x.t) return explained(r, y);
      return explained(r, x) || explained(r, y);
    }
    return hx ? explained(r, x) : explained(r, y);
  };
  Comparison c = compare_hit_arrays(a, flat, {}, rule);
  c.a = "instanced";
  c.b = "flattened";
  return c;
}

}  // namespace mbvh

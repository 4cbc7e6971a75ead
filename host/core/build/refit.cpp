// SPDX-License-Identifier: MIT
// refit.cpp — Accel::refit: new vertex positions, the same topology. Every box is recomputed
// bottom-up from the float vertices as the build computes it (a triangle's box is the min/max of
// its three vertices, a node's the union of its children's), so traversal of a refitted build is
// exact; only its work per ray may grow (Lauterbach et al. 2006, "RT-DEFORM", refitting).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstring>

#include "host/core/layouts.h"
#include "host/core/build/builder.h"
#include "host/core/build/triangles.h"
#include "mbvh/error.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"

namespace mbvh {
namespace build {
std::uint64_t hash_build(const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris, unsigned threads);
double sah_of_binary(const Bvh2& b, const std::vector<Leaf>& leaves, float ct);
}  // namespace build

namespace {

inline Box tri_box(const Tri& t) {
  Box b;
  b.lo = {std::min(std::min(t.v0[0], t.v1[0]), t.v2[0]), std::min(std::min(t.v0[1], t.v1[1]), t.v2[1]),
          std::min(std::min(t.v0[2], t.v1[2]), t.v2[2])};
  b.hi = {std::max(std::max(t.v0[0], t.v1[0]), t.v2[0]), std::max(std::max(t.v0[1], t.v1[1]), t.v2[1]),
          std::max(std::max(t.v0[2], t.v1[2]), t.v2[2])};
  return b;
}

inline void unite(Box& d, const Box& s) {
  d.lo = {std::min(d.lo.x, s.lo.x), std::min(d.lo.y, s.lo.y), std::min(d.lo.z, s.lo.z)};
  d.hi = {std::max(d.hi.x, s.hi.x), std::max(d.hi.y, s.hi.y), std::max(d.hi.z, s.hi.z)};
}

template <class N>
Box slot_box(const N& n, int s) {
  Box b;
  b.lo = {n.lo_x[s], n.lo_y[s], n.lo_z[s]};
  b.hi = {n.hi_x[s], n.hi_y[s], n.hi_z[s]};
  return b;
}

template <class N>
void set_slot(N& n, int s, const Box& b) {
  n.lo_x[s] = b.lo.x; n.hi_x[s] = b.hi.x;
  n.lo_y[s] = b.lo.y; n.hi_y[s] = b.hi.y;
  n.lo_z[s] = b.lo.z; n.hi_z[s] = b.hi.z;
}

double leaf_sah(const Bvh2& b, const std::vector<Leaf>& leaves, double root) {
  double c = 0;
  for (std::size_t i = 0; i < leaves.size(); ++i) c += double(leaves[i].count) * b.leaf_boxes[i].half_area() / root;
  return c;
}

// A wide layout's slots bottom-up (a child node always follows its parent); its SAH cost as
// collapse.cpp counts it.
template <class M>
void refit_wide(M& m, const Bvh2& b, const std::vector<Leaf>& leaves) {
  using N = typename decltype(m.nodes)::value_type;
  constexpr int W = static_cast<int>(sizeof(N::child) / sizeof(N::child[0]));
  const double root = std::max(1e-30, static_cast<double>(b.nodes[0].box.half_area()));
  double cost = 0;
  for (std::size_t i = m.nodes.size(); i-- > 0;) {
    N& n = m.nodes[i];
    Box all;
    for (int s = 0; s < W; ++s) {
      const std::int32_t c = n.child[s];
      if (c == MBVH_EMPTY) continue;
      Box bx;
      if (c < 0) {
        bx = b.leaf_boxes[static_cast<std::size_t>(~c)];
      } else {
        const N& ch = m.nodes[static_cast<std::size_t>(c)];
        for (int g = 0; g < W; ++g)
          if (ch.child[g] != MBVH_EMPTY) unite(bx, slot_box(ch, g));
      }
      set_slot(n, s, bx);
      unite(all, bx);
    }
    cost += all.half_area() / root;
  }
  m.stats.sah_cost = cost + leaf_sah(b, leaves, root);
}

}  // namespace

void Accel::refit(const Scene& moved) {
  const auto t0 = std::chrono::steady_clock::now();
  if (moved.triangle_count() != impl_->scene_triangles_)
    throw Error(moved.name + ": refit needs the scene the build was made from (" + std::to_string(impl_->scene_triangles_) +
                " triangles), not " + std::to_string(moved.triangle_count()) + " triangles; rebuild instead");
  const std::vector<std::uint64_t>& geoms = impl_->geometry_offsets_;  // {0, n} for an owned scene
  bool same = moved.geometry_count() + 1 == geoms.size();
  for (std::size_t g = 0; same && g < geoms.size(); ++g) same = moved.geometry_offset(g) == geoms[g];
  if (!same)
    throw Error(moved.name + ": refit needs the geometries the build was made from (" + std::to_string(geoms.size() - 1) +
                " with the same triangle counts each), not these " + std::to_string(moved.geometry_count()) + "; rebuild instead");
  const unsigned threads = impl_->opt_.threads;
  constexpr std::size_t grain = 65536;
  // Scene::validate's conditions on triangle i of `src` (triangles.h): its vertices, in range and
  // finite, or false
  auto usable = [](const auto& src, std::size_t i, Vec3f& v0, Vec3f& v1, Vec3f& v2) {
    return src.get_checked(i, v0, v1, v2) && build::finite(v0, v1, v2);
  };

  // -- the leaf-ordered triangles, new, and the checks a build makes of them (Scene::validate's
  //    on the triangles used, the traced range; it names the first problem if there is one)
  AlignedVector<Tri> tris(impl_->tris_.size());  // not zeroed (CacheAligned): every word written below
  const std::size_t chunks = (tris.size() + grain - 1) / grain;
  std::vector<float> mag(chunks, 0.0f);
  std::vector<std::uint8_t> bad(chunks, 0);
  build::with_triangles(moved, [&](const auto& src) {
    parallel_for(tris.size(), grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      float m = 0;
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t prim = tri_prim(impl_->tris_[i]);
        Vec3f v0, v1, v2;
        if (!usable(src, prim, v0, v1, v2)) {
          bad[b / grain] = 1;
          return;
        }
        build::fill_tri(tris[i], v0, v1, v2, prim);
        m = std::max(m, build::magnitude(build::prim_ref(v0, v1, v2, prim)));
      }
      mag[b / grain] = m;
    });
  });
  if (std::find(bad.begin(), bad.end(), 1) != bad.end()) {
    moved.validate();  // throws, naming the triangle
    throw Error(moved.name + ": refit: a triangle names a missing or non-finite vertex");
  }
  const float largest = *std::max_element(mag.begin(), mag.end());
  if (largest > kMaxCoordinate || largest < kMinSceneScale)
    throw Error(moved.name + ": refit moves a coordinate out of the range mbvh traces exactly (magnitude " +
                std::to_string(largest) + ", accel.h kMaxCoordinate, kMinSceneScale); rescale the scene");
  if (impl_->bvh2_.degenerate > 0) {  // the triangles kept out as degenerate must stay so
    std::vector<std::uint8_t> in_leaf(impl_->scene_triangles_, 0);
    for (const Tri& t : impl_->tris_) in_leaf[tri_prim(t)] = 1;
    const std::size_t all_chunks = (impl_->scene_triangles_ + grain - 1) / grain;
    std::vector<std::uint8_t> grew(all_chunks, 0);
    build::with_triangles(moved, [&](const auto& src) {
      parallel_for(impl_->scene_triangles_, grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
        for (std::size_t i = b; i < e; ++i) {
          if (in_leaf[i]) continue;
          Vec3f v0, v1, v2;
          if (!usable(src, i, v0, v1, v2) || build::has_area(v0, v1, v2)) {
            grew[b / grain] = 1;
            return;
          }
        }
      });
    });
    if (std::find(grew.begin(), grew.end(), 1) != grew.end()) {
      moved.validate();
      throw Error(moved.name + ": refit: a triangle the build kept out as degenerate has area now, and is in no "
                  "leaf; rebuild instead");
    }
  }
  impl_->tris_.swap(tris);
  tris = AlignedVector<Tri>();

  // -- leaf boxes, then the binary nodes bottom-up (depth-first order: children follow parents)
  parallel_for(impl_->leaves_.size(), 16384, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) {
      const Leaf& l = impl_->leaves_[i];
      Box bx;
      for (std::uint32_t k = l.first; k < l.first + l.count; ++k) unite(bx, tri_box(impl_->tris_[k]));
      impl_->bvh2_.leaf_boxes[i] = bx;
    }
  });
  for (std::size_t i = impl_->bvh2_.nodes.size(); i-- > 0;) {
    Bvh2::Node& n = impl_->bvh2_.nodes[i];
    Box bx;
    for (int s = 0; s < 2; ++s)
      if (n.child[s] != MBVH_EMPTY) unite(bx, impl_->bvh2_.box(n.child[s]));
    n.box = bx;
  }
  impl_->bounds_ = impl_->bvh2_.nodes[0].box;
  impl_->binary_stats_.sah_cost = build::sah_of_binary(impl_->bvh2_, impl_->leaves_, impl_->opt_.traversal_cost);

  // -- the layouts and packs already made, in place
  if (!impl_->mbvh2_.nodes.empty()) {
    parallel_for(impl_->bvh2_.nodes.size(), 16384, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
      for (std::size_t i = lo; i < hi; ++i) {
        const Bvh2::Node& s = impl_->bvh2_.nodes[i];
        Node2& d = impl_->mbvh2_.nodes[i];
        const Box b0 = s.child[0] == MBVH_EMPTY ? Box() : impl_->bvh2_.box(s.child[0]);
        const Box b1 = s.child[1] == MBVH_EMPTY ? Box() : impl_->bvh2_.box(s.child[1]);
        d.c0[0] = b0.lo.x; d.c0[1] = b0.hi.x; d.c0[2] = b0.lo.y; d.c0[3] = b0.hi.y;
        d.c1[0] = b1.lo.x; d.c1[1] = b1.hi.x; d.c1[2] = b1.lo.y; d.c1[3] = b1.hi.y;
        d.zz[0] = b0.lo.z; d.zz[1] = b0.hi.z; d.zz[2] = b1.lo.z; d.zz[3] = b1.hi.z;
      }
    });
    const double root = impl_->bvh2_.nodes[0].box.half_area();
    double cost = 0;
    if (root > 0) {
      for (const auto& n : impl_->bvh2_.nodes) cost += n.box.half_area() / root;
      cost += leaf_sah(impl_->bvh2_, impl_->leaves_, root);
    }
    impl_->mbvh2_.stats.sah_cost = cost;
  }
  if (!impl_->mbvh4_.nodes.empty()) refit_wide(impl_->mbvh4_, impl_->bvh2_, impl_->leaves_);
  if (!impl_->mbvh8_.nodes.empty()) refit_wide(impl_->mbvh8_, impl_->bvh2_, impl_->leaves_);
  if (!impl_->mbvh4w_.nodes.empty()) {
    for (std::size_t i = 0; i < impl_->mbvh4_.nodes.size(); ++i) {
      const Node4& n = impl_->mbvh4_.nodes[i];
      Node4W& o = impl_->mbvh4w_.nodes[i];
      for (int s = 0; s < 4; ++s) {  // the boxes only: the child and link words (lane 3) stay
        o.lo[s][0] = n.lo_x[s];
        o.lo[s][1] = n.lo_y[s];
        o.lo[s][2] = n.lo_z[s];
        o.hi[s][0] = n.hi_x[s];
        o.hi[s][1] = n.hi_y[s];
        o.hi[s][2] = n.hi_z[s];
      }
    }
  }
  if (!impl_->packs_.leaves.empty()) {
    parallel_for(impl_->leaves_.size(), 16384, threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) {
        const Leaf& l = impl_->leaves_[i];
        for (std::uint32_t k = 0; k < l.count; ++k) {
          const Tri& t = impl_->tris_[l.first + k];
          Tri4& o = impl_->packs_.packs[impl_->packs_.leaves[i].first + k / 4];
          const float* vert[3] = {t.v0, t.v1, t.v2};
          for (int v = 0; v < 3; ++v)
            for (int a = 0; a < 3; ++a) o.v[3 * v + a][k % 4] = vert[v][a];
        }
      }
    });
  }
  drop_leaf_variants();  // remade on next use from the refit tree
  impl_->hash_ = build::hash_build(impl_->bvh2_, impl_->leaves_, impl_->tris_, threads);
  ++impl_->generation_;
  impl_->refit_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// refit.cpp — Accel::refit: new vertex positions, the same topology. Every box is recomputed
// bottom-up from the float vertices as the build computes it (a triangle's box is the min/max of
// its three vertices, a node's the union of its children's), so traversal of a refitted build is
// exact; only its work per ray may grow (Lauterbach et al. 2006, "RT-DEFORM", refitting).
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>

#include "host/core/layouts.h"
#include "host/core/bvh/builder.h"
#include "host/core/bvh/triangles.h"
#include "host/core/bvh/wide_node.h"
#include "mbvh/error.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"

namespace mbvh {

namespace {

// A tree stored in preorder (a node's subtree is the range of nodes from it to `end`, its
// children in slot order), cut for a parallel bottom-up pass: subtrees of at most kCut nodes,
// each refitted on its own from its last node back to its root, and the nodes above them, the
// `upper` ones, refitted after them in decreasing index order. The cut depends on the tree alone,
// not on the thread count. All builders and collapses emit their nodes in preorder; `preorder`
// is false (and the pass must run serially) for a tree that is not.
struct Cut {
  std::vector<std::pair<std::size_t, std::size_t>> ranges;  // [root, end) of each subtree
  std::vector<std::size_t> upper;                           // increasing
  bool preorder = true;
};
constexpr std::size_t kCut = 4096;

// `kid(i, s)`: child reference s of node i (a node when >= 0); W slots.
template <int W, class Kid>
Cut cut_preorder(std::size_t count, Kid kid) {
  Cut c;
  auto end_of = [&](std::size_t i) {  // past the last node of i's subtree: its last inner child's, down
    for (;;) {
      std::int32_t last = -1;
      for (int s = 0; s < W; ++s)
        if (kid(i, s) >= 0) last = kid(i, s);
      if (last < 0) return i + 1;
      if (static_cast<std::size_t>(last) <= i || static_cast<std::size_t>(last) >= count) return count + 1;
      i = static_cast<std::size_t>(last);
    }
  };
  std::vector<std::size_t> stack{0};
  std::size_t covered = 0;
  while (!stack.empty() && c.preorder) {
    const std::size_t i = stack.back();
    stack.pop_back();
    const std::size_t e = end_of(i);
    if (e > count) c.preorder = false;
    else if (e - i <= kCut) {
      c.ranges.push_back({i, e});
      covered += e - i;
    } else {
      c.upper.push_back(i);
      ++covered;
      for (int s = W; s-- > 0;)
        if (kid(i, s) >= 0) stack.push_back(static_cast<std::size_t>(kid(i, s)));
    }
  }
  c.preorder = c.preorder && covered == count;
  std::sort(c.upper.begin(), c.upper.end());
  return c;
}

// Runs refit(i) on every node of a cut tree, children before parents: the subtrees side by side,
// then the upper nodes; a tree not in preorder, and a subtree whose node names a child outside
// its range, serially from the last node back. `refit(i)` returns false on such a child (its
// results are then recomputed) and adds the node's SAH area to `area`. Returns the area sum,
// added in a fixed order: the same at any thread count.
template <class Refit>
double refit_tree(const Cut& c, std::size_t count, unsigned threads, Refit&& refit) {
  std::vector<double> area(c.ranges.size(), 0.0);
  std::atomic<bool> inside{c.preorder};
  if (c.preorder)
    parallel_for(c.ranges.size(), 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t r = b; r < e; ++r) {
        double a = 0;  // local: neighbouring entries of `area` share a cache line
        for (std::size_t i = c.ranges[r].second; i-- > c.ranges[r].first;)
          if (!refit(i, c.ranges[r].second, a)) inside = false;
        area[r] = a;
      }
    });
  double sum = 0;
  if (inside) {
    for (double a : area) sum += a;
    for (std::size_t u = c.upper.size(); u-- > 0 && inside;) inside = refit(c.upper[u], count, sum);
  }
  if (!inside) {
    sum = 0;
    for (std::size_t i = count; i-- > 0;) refit(i, count, sum);
  }
  return sum;
}

// A wide layout's node boxes, bottom-up: slot s of node i is leaf ~child's box or the union of
// node child's slots; its SAH cost as collapse.cpp counts it (`leaves`: leaf_area of the build).
template <class M>
void refit_wide(M& m, const Bvh2& b, double leaves, double root, unsigned threads) {
  using N = typename decltype(m.nodes)::value_type;
  constexpr int W = static_cast<int>(sizeof(N::child) / sizeof(N::child[0]));
  const Cut cut = cut_preorder<W>(m.nodes.size(), [&](std::size_t i, int s) { return m.nodes[i].child[s]; });
  const double area = refit_tree(cut, m.nodes.size(), threads, [&](std::size_t i, std::size_t end, double& sum) {
    N& n = m.nodes[i];
    bool inside = true;
    Box all;
    for (int s = 0; s < W; ++s) {
      const std::int32_t c = n.child[s];
      if (c == MBVH_EMPTY) continue;
      Box bx;
      if (c < 0) {
        bx = b.leaf_boxes[static_cast<std::size_t>(~c)];
      } else {
        inside = inside && static_cast<std::size_t>(c) > i && static_cast<std::size_t>(c) < end;
        const N& ch = m.nodes[static_cast<std::size_t>(c)];
        for (int g = 0; g < W; ++g)
          if (ch.child[g] != MBVH_EMPTY) bx.grow(build::slot_box(ch, g));
      }
      build::set_slot(n, s, bx);
      all.grow(bx);
    }
    if constexpr (W == 8) build::set_octant_order(n);  // the order follows the new boxes
    sum += all.half_area();
    return inside;
  });
  m.stats.sah_cost = (area + leaves) / root;
}

// A sufficient condition for refit's checks on an owned scene whose every triangle is in a leaf,
// cheaper than its pass over the triangles (sequential, no gather): every index in range, every
// vertex, used or not, finite and within kMaxCoordinate, every coordinate 0 or of magnitude at
// least 2^-31 (so a multiple of 2^-54: a triangle's edges' cross product is then 0 or at least
// 2^-108, no triangle has an area below kMinTriangleArea but 0), and a triangle, usually the
// first, reaching kMinSceneScale. False: the exact pass decides (an unused vertex may hold anything).
bool quick_check(const Scene& s, unsigned threads) {
  const std::size_t nv = s.vertices.size(), nt = s.triangles.size();
  constexpr std::size_t grain = 65536;
  std::vector<std::uint8_t> fine((nv + grain - 1) / grain + (nt + grain - 1) / grain, 0);
  const std::size_t vchunks = (nv + grain - 1) / grain;
  parallel_for(nv, grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
    float finite = 0, m = 0;  // x - x: +0 when finite, NaN otherwise; NaN survives the sum
    bool tiny = false;        // a coordinate that is neither 0 nor of magnitude >= 2^-31
    for (std::size_t i = b; i < e; ++i) {
      const Vec3f& v = s.vertices[i];
      finite += (v.x - v.x) + (v.y - v.y) + (v.z - v.z);
      m = std::max(m, std::max(std::fabs(v.x), std::max(std::fabs(v.y), std::fabs(v.z))));
      for (float c : {v.x, v.y, v.z}) tiny |= c != 0.0f && std::fabs(c) < 0x1p-31f;
    }
    fine[b / grain] = finite == 0.0f && m <= kMaxCoordinate && !tiny;
  });
  parallel_for(nt, grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::uint32_t top = 0;
    for (std::size_t i = b; i < e; ++i) top = std::max(top, std::max(s.triangles[i][0], std::max(s.triangles[i][1], s.triangles[i][2])));
    fine[vchunks + b / grain] = top < nv;
  });
  if (std::find(fine.begin(), fine.end(), 0) != fine.end()) return false;
  for (const auto& t : s.triangles)
    for (int k = 0; k < 3; ++k) {
      const Vec3f& v = s.vertices[t[k]];
      if (std::max(std::fabs(v.x), std::max(std::fabs(v.y), std::fabs(v.z))) >= kMinSceneScale) return true;
    }
  return false;
}

// The checks a build makes, made before refit writes anything (the Accel stays unchanged if one
// fails): `moved` has the build's triangle count and geometries (`geoms`: Accel::Impl's
// geometry_offsets_, {0, n} for an owned scene); Scene::validate's conditions on every triangle,
// in scene order; the traced range on those in leaves (`tris`); no area on those the build kept
// out as degenerate (`degenerate` of them, in no leaf). An owned scene with every triangle in a
// leaf passing quick_check needs no pass over its triangles.
void refit_check(const Scene& moved, std::size_t scene_triangles, const std::vector<std::uint64_t>& geoms,
                 std::size_t degenerate, const AlignedVector<Tri>& tris, unsigned threads) {
  if (moved.triangle_count() != scene_triangles)
    throw Error(moved.display_name() + ": refit needs the scene the build was made from (" + std::to_string(scene_triangles) +
                " triangles), not " + std::to_string(moved.triangle_count()) + " triangles; rebuild instead");
  bool same = moved.geometry_count() + 1 == geoms.size();
  for (std::size_t g = 0; same && g < geoms.size(); ++g) same = moved.geometry_offset(g) == geoms[g];
  if (!same)
    throw Error(moved.display_name() + ": refit needs the geometries the build was made from (" + std::to_string(geoms.size() - 1) +
                " with the same triangle counts each), not these " + std::to_string(moved.geometry_count()) + "; rebuild instead");
  constexpr std::size_t grain = 65536;
  // Scene::validate's conditions on triangle i of `src` (triangles.h): its vertices, in range and
  // finite, or false
  auto usable = [](const auto& src, std::size_t i, Vec3f& v0, Vec3f& v1, Vec3f& v2) {
    return src.get_checked(i, v0, v1, v2) && build::finite(v0, v1, v2);
  };

  const std::size_t n = scene_triangles;
  std::vector<std::uint8_t> in_leaf;
  if (degenerate > 0) {
    in_leaf.assign(n, 0);
    for (const Tri& t : tris) in_leaf[tri_prim(t)] = 1;
  }
  const bool quick = in_leaf.empty() && moved.meshes().empty() && quick_check(moved, threads);
  const std::size_t chunks = quick ? 0 : (n + grain - 1) / grain;
  std::vector<float> mag(chunks, 0.0f);
  std::vector<std::uint8_t> bad(chunks, 0), grew(chunks, 0);
  std::vector<std::size_t> tiny(chunks, SIZE_MAX);  // per chunk: its first leaf triangle too small to trace
  if (!quick) build::with_triangles(moved, [&](const auto& src) {
    parallel_for(n, grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      float m = 0;
      for (std::size_t i = b; i < e; ++i) {
        Vec3f v[3];
        if (!usable(src, i, v[0], v[1], v[2])) {
          bad[b / grain] = 1;
          return;
        }
        if (!in_leaf.empty() && !in_leaf[i]) {
          if (build::has_area(v[0], v[1], v[2])) grew[b / grain] = 1;
          continue;
        }
        for (const Vec3f& p : v) m = std::max({m, std::fabs(p.x), std::fabs(p.y), std::fabs(p.z)});
        if (build::too_small(build::twice_area_sq(v[0], v[1], v[2]))) tiny[b / grain] = std::min(tiny[b / grain], i);
      }
      mag[b / grain] = m;
    });
  });
  if (std::find(bad.begin(), bad.end(), 1) != bad.end()) {
    moved.validate();  // throws, naming the triangle
    throw Error(moved.display_name() + ": refit: a triangle names a missing or non-finite vertex");
  }
  const float largest = quick ? kMaxCoordinate : *std::max_element(mag.begin(), mag.end());
  if (largest > kMaxCoordinate || largest < kMinSceneScale)
    throw Error(moved.display_name() + ": refit moves a coordinate out of the range mbvh traces exactly (magnitude " +
                std::to_string(largest) + ", accel.h kMaxCoordinate, kMinSceneScale); rescale the scene");
  if (const std::size_t first = chunks ? *std::min_element(tiny.begin(), tiny.end()) : SIZE_MAX; first != SIZE_MAX)
    build::throw_too_small(moved, static_cast<std::uint32_t>(first), "refit: ");
  if (std::find(grew.begin(), grew.end(), 1) != grew.end())
    throw Error(moved.display_name() + ": refit: a triangle the build kept out as degenerate has area now, and is in no "
                "leaf; rebuild instead");
}

// The leaf-ordered triangles of `moved`, the leaf boxes and the SIMD packs if made, in place (their
// pages already mapped), in chunks of whole hash blocks of triangles, each chunk's blocks hashed
// into `tri_hashes` while they are in cache (hash_build's tri_hashes); a leaf cut by a chunk's
// edge gets a partial box from each chunk it spans, united in order afterwards (min and max of
// finite floats: the same box). Returns the leaves' SAH area sum (count times half area).
double refit_leaves(const Scene& moved, AlignedVector<Tri>& tris, const std::vector<Leaf>& leaves, Bvh2& bvh,
                    TriPacks& packs, unsigned threads, std::vector<std::uint64_t>& tri_hashes) {
  const bool with_packs = !packs.leaves.empty();
  constexpr std::size_t kAhead = 16;  // triangles: their vertices fetched this far ahead, their indices twice as far
  constexpr std::size_t kChunkBlocks = 3;  // 3 MiB: 65536 triangles of 48 bytes
  constexpr std::size_t tri_grain = kChunkBlocks * build::kHashBlock / sizeof(Tri);
  static_assert(tri_grain * sizeof(Tri) == kChunkBlocks * build::kHashBlock);
  const std::size_t tri_chunks = (tris.size() + tri_grain - 1) / tri_grain;
  tri_hashes.assign((tris.size() * sizeof(Tri) + build::kHashBlock - 1) / build::kHashBlock, 0);
  struct Edge {  // a chunk's partial boxes of the leaf it starts inside and of the one it ends inside
    std::size_t head_leaf = SIZE_MAX, tail_leaf = SIZE_MAX;
    Box head, tail;
    double area = 0;  // the leaves wholly inside
  };
  std::vector<Edge> edges(tri_chunks);
  build::with_triangles(moved, [&](const auto& src) {
    parallel_for(tris.size(), tri_grain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      Edge& edge = edges[b / tri_grain];
      // the leaf holding triangle b: the last one starting at or before it
      std::size_t i = static_cast<std::size_t>(
          std::upper_bound(leaves.begin(), leaves.end(), b, [](std::size_t t, const Leaf& l) { return t < l.first; }) -
          leaves.begin() - 1);
      for (; i < leaves.size() && leaves[i].first < e; ++i) {
        const Leaf& l = leaves[i];
        const std::size_t k0 = std::max<std::size_t>(l.first, b), k1 = std::min<std::size_t>(l.first + l.count, e);
        Box bx;
        for (std::size_t k = k0; k < k1; ++k) {
          if (k + 2 * kAhead < e) src.prefetch_index(tri_prim(tris[k + 2 * kAhead]));
          if (k + kAhead < e) src.prefetch_vertices(tri_prim(tris[k + kAhead]));
          Tri& t = tris[k];
          Vec3f v0, v1, v2;
          src.get(tri_prim(t), v0, v1, v2);
          t.v0[0] = v0.x, t.v0[1] = v0.y, t.v0[2] = v0.z;  // lane 3 (prim id, zeros) stays
          t.v1[0] = v1.x, t.v1[1] = v1.y, t.v1[2] = v1.z;
          t.v2[0] = v2.x, t.v2[1] = v2.y, t.v2[2] = v2.z;
          bx.grow(build::tri_box(t));
          if (with_packs) {
            const std::size_t j = k - l.first;
            Tri4& o = packs.packs[packs.leaves[i].first + j / 4];
            const Vec3f* vert[3] = {&v0, &v1, &v2};
            for (int v = 0; v < 3; ++v) {
              o.v[3 * v + 0][j % 4] = vert[v]->x;
              o.v[3 * v + 1][j % 4] = vert[v]->y;
              o.v[3 * v + 2][j % 4] = vert[v]->z;
            }
          }
        }
        if (l.first < b) {
          edge.head_leaf = i;
          edge.head = bx;
        } else if (l.first + l.count > e) {
          edge.tail_leaf = i;
          edge.tail = bx;
        } else {
          bvh.leaf_boxes[i] = bx;
          edge.area += double(l.count) * bx.half_area();
        }
      }
      const unsigned char* bytes = reinterpret_cast<const unsigned char*>(tris.data());
      for (std::size_t o = b * sizeof(Tri); o < e * sizeof(Tri); o += build::kHashBlock)
        tri_hashes[o / build::kHashBlock] = hash_bytes(bytes + o, std::min(build::kHashBlock, e * sizeof(Tri) - o));
    });
  });
  double leaf_sum = 0;
  for (std::size_t c = 0; c < tri_chunks; ++c) {
    leaf_sum += edges[c].area;
    if (edges[c].tail_leaf == SIZE_MAX) continue;
    const std::size_t i = edges[c].tail_leaf;
    Box bx = edges[c].tail;
    for (std::size_t d = c + 1; d < tri_chunks && edges[d].head_leaf == i; ++d) bx.grow(edges[d].head);
    bvh.leaf_boxes[i] = bx;
    leaf_sum += double(leaves[i].count) * bx.half_area();
  }
  return leaf_sum;
}

// The binary nodes bottom-up, each MBVH2 node (its children's boxes) beside its binary node
// when the MBVH2 layout is made. Returns the nodes' half-area sum.
double refit_binary(Bvh2& bvh, Mbvh2& mbvh2, unsigned threads) {
  const bool with_mbvh2 = !mbvh2.nodes.empty();
  const Cut cut = cut_preorder<2>(bvh.nodes.size(), [&](std::size_t i, int s) { return bvh.nodes[i].child[s]; });
  return refit_tree(cut, bvh.nodes.size(), threads, [&](std::size_t i, std::size_t end, double& sum) {
    Bvh2::Node& nd = bvh.nodes[i];
    bool inside = true;
    Box cb[2];
    for (int s = 0; s < 2; ++s) {
      const std::int32_t c = nd.child[s];
      if (c == MBVH_EMPTY) continue;
      inside = inside && (c < 0 || (static_cast<std::size_t>(c) > i && static_cast<std::size_t>(c) < end));
      cb[s] = bvh.box(c);
    }
    Box bx;
    bx.grow(cb[0]);
    bx.grow(cb[1]);
    nd.box = bx;
    sum += bx.half_area();
    if (with_mbvh2) {
      Node2& d = mbvh2.nodes[i];
      build::set_boxes(d, cb[0], cb[1]);
    }
    return inside;
  });
}

// The 16-wide view's boxes, copied from the refitted MBVH4 `m` (its child and link words stay).
void refit_view(const Mbvh4& m, Mbvh4Wide& w, unsigned threads) {
  parallel_for(m.nodes.size(), 16384, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) build::set_view_boxes(w.nodes[i], m.nodes[i]);
  });
}

}  // namespace

void Accel::refit(const Scene& moved) {
  const auto t0 = std::chrono::steady_clock::now();
  const unsigned threads = impl_->opt_.threads;
  refit_check(moved, impl_->scene_triangles_, impl_->geometry_offsets_, impl_->bvh2_.degenerate, impl_->tris_, threads);
  if (!has_hierarchy()) {
    refit_triangles(moved);
    impl_->refit_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    return;
  }

  // -- the triangles and leaf boxes, then the nodes bottom-up and the SAH costs
  Bvh2& bvh = impl_->bvh2_;
  std::vector<std::uint64_t> tri_hashes;
  const double leaf_sum = refit_leaves(moved, impl_->tris_, impl_->leaves_, bvh, impl_->packs_, threads, tri_hashes);
  impl_->packs_.refresh_mt();
  const double node_sum = refit_binary(bvh, impl_->mbvh2_, threads);
  impl_->bounds_ = bvh.nodes[0].box;
  const double root = bvh.nodes[0].box.half_area();
  impl_->binary_stats_.sah_cost = root > 0 ? (impl_->opt_.traversal_cost * node_sum + leaf_sum) / root : 0;
  if (!impl_->mbvh2_.nodes.empty()) impl_->mbvh2_.stats.sah_cost = root > 0 ? (node_sum + leaf_sum) / root : 0;

  // -- the wide layouts already made, in place
  const double wide_root = std::max(1e-30, root);
  if (!impl_->mbvh4_.nodes.empty()) refit_wide(impl_->mbvh4_, bvh, leaf_sum, wide_root, threads);
  if (!impl_->mbvh8_.nodes.empty()) refit_wide(impl_->mbvh8_, bvh, leaf_sum, wide_root, threads);
  if (!impl_->mbvh4w_.nodes.empty()) refit_view(impl_->mbvh4_, impl_->mbvh4w_, threads);

  // -- what depends on the boxes: the leaf variants are remade on next use, the hash is known now
  drop_leaf_variants();
  impl_->hash_ = build::hash_build(impl_->bvh2_, impl_->leaves_, impl_->tris_, threads, tri_hashes.data());
  impl_->hash_known_.store(true, std::memory_order_release);
  ++impl_->generation_;
  impl_->refit_ms_ = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

// A build without a hierarchy (quality none), checked by refit: its triangles (scene order) in
// place, by the leaves' pass over one leaf holding them all, whose box is the new bounds(); then
// the hash, as Accel::hash computes it (no nodes, no leaves), and the generation.
void Accel::refit_triangles(const Scene& moved) {
  const unsigned threads = impl_->opt_.threads;
  Bvh2 flat;
  flat.leaf_boxes.resize(1);
  const std::vector<Leaf> all{Leaf{0, static_cast<std::uint32_t>(impl_->tris_.size())}};
  TriPacks no_packs;
  std::vector<std::uint64_t> tri_hashes;
  refit_leaves(moved, impl_->tris_, all, flat, no_packs, threads, tri_hashes);
  impl_->bounds_ = flat.leaf_boxes[0];
  impl_->hash_ = build::hash_build(impl_->bvh2_, impl_->leaves_, impl_->tris_, threads, tri_hashes.data());
  impl_->hash_known_.store(true, std::memory_order_release);
  ++impl_->generation_;
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// sbvh.cpp — the high-quality build (BuildQuality::high): a binary BVH with spatial splits
// (Stich, Friedrich & Dietrich, "Spatial Splits in Bounding Volume Hierarchies", HPG 2009).
//
// Each node weighs three choices by the SAH: a leaf, the binned object split of binned_sah.cpp
// (Wald 2007) over its references' centroids, and — when the object split's children overlap by
// more than α = 1e-5 of the root's area (SBVH §4.4) — a binned spatial split that clips the
// references straddling a bin plane against the triangle (SBVH §4.2, "chopped binning"), with
// reference unsplitting (§4.5). A reference is a triangle and a box bounding its part inside the
// node; a leaf stores the whole original triangle with its original prim id, so a triangle split
// by a plane sits in one leaf on each side. No node ever holds two references of one triangle
// (the root holds one each and a split sends each reference, or each of its two halves, to one
// child), so no leaf holds a triangle twice.
//
// Exactness: a clipped box must contain the triangle's part on its side of the plane. The part is
// the convex hull of the triangle's vertices on that side and its edges' crossings of the plane;
// the crossings are computed in double and rounded outward to float (one float ulp each way), the
// plane coordinate itself is exact, and the result is intersected with the reference's previous
// box. A ray's hit point on the triangle lies in some reference's part, hence in its leaf's box.
//
// References grow by at most kGrowth: each node carries a budget of references its subtree may
// hold (the root: (1 + kGrowth) n), a spatial split must fit the node's budget, and the children
// share what it leaves in proportion to their references. Every decision is a function of the
// node's references alone, so the bytes do not depend on the thread count (the top of the tree is
// split in order, then subtrees are built one per task, as in binned_sah.cpp).
#include "host/core/bvh/sbvh.h"

#include <algorithm>
#include <atomic>
#include <cmath>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/reinsert.h"
#include "host/core/parallel.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

constexpr unsigned kMaxBins = 64;
constexpr float kAlpha = 1e-5f;   // SBVH §4.4: spatial splits only where children overlap this much
constexpr double kGrowth = 0.1;   // at most 10 % more references than triangles
// Binning clips a reference against the triangle at each bin plane it crosses when it crosses at
// most this many; a longer one (a large triangle in a small node, where the clipping would cost
// most) is binned as its box cut at the planes: an upper bound of the chopped boxes' SAH. The
// chosen split itself always clips the triangle.
constexpr unsigned kExactSpan = 4;

struct Ref {
  Box box;
  std::uint32_t prim;
};

struct Node {
  Box box;
  std::vector<Ref> refs;
  std::size_t cap = 0;  // references this subtree may hold
  std::uint32_t depth = 0;
  std::int32_t child[2] = {-1, -1};
  bool leaf = false;
  bool forced = false;
};

bool valid(const Box& b) { return b.lo.x <= b.hi.x && b.lo.y <= b.hi.y && b.lo.z <= b.hi.z; }

// Box::grow, inlined: the builder's innermost operation
inline void grow_box(Box& b, const Box& o) {
  b.lo = {std::min(b.lo.x, o.lo.x), std::min(b.lo.y, o.lo.y), std::min(b.lo.z, o.lo.z)};
  b.hi = {std::max(b.hi.x, o.hi.x), std::max(b.hi.y, o.hi.y), std::max(b.hi.z, o.hi.z)};
}
inline void grow_box(Box& b, const Vec3f& p) {
  b.lo = {std::min(b.lo.x, p.x), std::min(b.lo.y, p.y), std::min(b.lo.z, p.z)};
  b.hi = {std::max(b.hi.x, p.x), std::max(b.hi.y, p.y), std::max(b.hi.z, p.z)};
}

Box intersect(const Box& a, const Box& b) {
  Box r;
  r.lo = {std::max(a.lo.x, b.lo.x), std::max(a.lo.y, b.lo.y), std::max(a.lo.z, b.lo.z)};
  r.hi = {std::min(a.hi.x, b.hi.x), std::min(a.hi.y, b.hi.y), std::min(a.hi.z, b.hi.z)};
  return r;
}

float area(const Box& b) { return valid(b) ? b.half_area() : 0.0f; }

// A spatial split: its SAH cost (the children's areas times their blocks), axis and plane.
struct SpatialSplit {
  float cost = INFINITY;
  int axis = -1;
  float plane = 0;
};

struct SBin {
  Box box;
  std::uint32_t enter = 0, exit = 0;
};

class Sbvh {
public:
  Sbvh(const Scene& scene, const BuildOptions& opt, float root_area)
      : scene_(scene), opt_(opt), bins_(std::clamp(opt.bins, 2u, kMaxBins)), root_area_(root_area) {}

  float blocks(std::size_t n) const {
    const std::size_t b = std::max(opt_.leaf_block, 1u);
    return static_cast<float>((n + b - 1) / b);
  }

  // The parts of reference r's triangle on each side of the plane x[a] = p, as conservative boxes
  // (invalid where that side holds nothing of it).
  void clip(const Ref& r, int a, float p, Box& left, Box& right) const {
    Vec3f tri[3];
    scene_.triangle(r.prim, tri[0], tri[1], tri[2]);
    const Vec3f* v[3] = {&tri[0], &tri[1], &tri[2]};
    left = Box();
    right = Box();
    for (int k = 0; k < 3; ++k) {
      const Vec3f& v0 = *v[k];
      const Vec3f& v1 = *v[(k + 1) % 3];
      const float a0 = v0[a], a1 = v1[a];
      if (a0 <= p) grow_box(left, v0);
      if (a0 >= p) grow_box(right, v0);
      if ((a0 < p && a1 > p) || (a0 > p && a1 < p)) {
        const double s = (double(p) - a0) / (double(a1) - double(a0));
        Box pt;
        for (int c = 0; c < 3; ++c) {
          if (c == a) {
            pt.lo[c] = pt.hi[c] = p;
            continue;
          }
          const double x = double(v0[c]) + s * (double(v1[c]) - double(v0[c]));
          const float f = static_cast<float>(x);
          pt.lo[c] = std::nextafter(f, -INFINITY);
          pt.hi[c] = std::nextafter(f, INFINITY);
        }
        grow_box(left, pt);
        grow_box(right, pt);
      }
    }
    left.hi[a] = std::min(left.hi[a], p);
    right.lo[a] = std::max(right.lo[a], p);
    left = intersect(left, r.box);
    right = intersect(right, r.box);
  }

  void make_leaf(Node& node, bool forced) {
    node.leaf = true;
    node.forced = forced;
  }

  // The cheapest spatial split of node's references by the SAH: chopped binning over the node's
  // box, each reference clipped against its triangle at the bin planes it crosses (SBVH §4.2);
  // axis -1 when no axis has extent.
  SpatialSplit best_spatial_split(const Node& node) const {
    const Box& nbox = node.box;
    SpatialSplit best;
    for (int a = 0; a < 3; ++a) {
      const float lo = nbox.lo[a], ext = nbox.hi[a] - nbox.lo[a];
      if (!(ext > 0)) continue;
      const float scale = static_cast<float>(bins_) / ext;
      auto pos = [&](unsigned k) { return lo + ext * static_cast<float>(k) / static_cast<float>(bins_); };
      auto bin = [&](float x) {
        const float f = (x - lo) * scale;
        return std::min(bins_ - 1, static_cast<unsigned>(f > 0 ? f : 0));
      };
      SBin sb[kMaxBins];
      for (const Ref& r : node.refs) {
        const unsigned b0 = bin(r.box.lo[a]), b1 = bin(r.box.hi[a]);
        if (b1 - b0 > kExactSpan) {  // a long reference: its box cut at the bin planes (an upper bound)
          for (unsigned k = b0; k <= b1; ++k) {
            Box piece = r.box;
            if (k > b0) piece.lo[a] = std::max(piece.lo[a], pos(k));
            if (k < b1) piece.hi[a] = std::min(piece.hi[a], pos(k + 1));
            grow_box(sb[k].box, piece);
          }
          ++sb[b0].enter;
          ++sb[b1].exit;
          continue;
        }
        Ref cur = r;
        unsigned last = b0;
        for (unsigned k = b0; k < b1; ++k) {
          Box l, rt;
          clip(cur, a, pos(k + 1), l, rt);
          if (valid(l)) grow_box(sb[k].box, l);
          if (!valid(rt)) break;
          cur.box = rt;
          last = k + 1;
        }
        if (last == b1 || b0 == b1) grow_box(sb[last].box, cur.box);
        ++sb[b0].enter;
        ++sb[last].exit;
      }
      Box rbox[kMaxBins];
      std::uint32_t rcnt[kMaxBins];
      Box acc;
      std::uint32_t cnt = 0;
      for (unsigned k = bins_ - 1; k > 0; --k) {
        grow_box(acc, sb[k].box);
        cnt += sb[k].exit;
        rbox[k] = acc;
        rcnt[k] = cnt;
      }
      acc = Box();
      cnt = 0;
      for (unsigned k = 1; k < bins_; ++k) {
        grow_box(acc, sb[k - 1].box);
        cnt += sb[k - 1].enter;
        if (cnt == 0 || rcnt[k] == 0) continue;
        const float cost = area(acc) * blocks(cnt) + area(rbox[k]) * blocks(rcnt[k]);
        if (cost < best.cost) {
          best.cost = cost;
          best.axis = a;
          best.plane = pos(k);
        }
      }
    }
    return best;
  }

  // Splits node n of `arena` into two children appended to it, or makes it a leaf.
  void split(std::vector<Node>& arena, std::size_t n) {
    Node& node = arena[n];
    const std::size_t count = node.refs.size();
    if (count <= 1 || node.depth >= opt_.depth_cap) return make_leaf(node, count > opt_.max_leaf);
    const Box nbox = node.box;
    const float narea = nbox.half_area();

    // -- object split: binned SAH over the references' centroids (as binned_sah.cpp)
    Box cbox;
    for (const Ref& r : node.refs) grow_box(cbox, r.box.center());
    const Vec3f cext = cbox.extent();
    float oscale[3];
    for (int a = 0; a < 3; ++a) oscale[a] = cext[a] > 0 ? static_cast<float>(bins_) / cext[a] : 0.0f;
    auto obin = [&](const Ref& r, int a) {
      const float f = (r.box.center()[a] - cbox.lo[a]) * oscale[a];
      return std::min(bins_ - 1, static_cast<unsigned>(f > 0 ? f : 0));
    };
    float obest = INFINITY;
    int oaxis = -1;
    unsigned osplit = 0;
    Box oleft, oright;
    for (int a = 0; a < 3; ++a) {
      if (oscale[a] == 0.0f) continue;
      Box bb[kMaxBins];
      std::uint32_t bc[kMaxBins] = {};
      for (const Ref& r : node.refs) {
        const unsigned b = obin(r, a);
        grow_box(bb[b], r.box);
        ++bc[b];
      }
      Box rbox[kMaxBins];
      std::uint32_t rcnt[kMaxBins];
      Box acc;
      std::uint32_t cnt = 0;
      for (unsigned k = bins_ - 1; k > 0; --k) {
        grow_box(acc, bb[k]);
        cnt += bc[k];
        rbox[k] = acc;
        rcnt[k] = cnt;
      }
      acc = Box();
      cnt = 0;
      for (unsigned k = 1; k < bins_; ++k) {
        grow_box(acc, bb[k - 1]);
        cnt += bc[k - 1];
        if (cnt == 0 || rcnt[k] == 0) continue;
        const float cost = area(acc) * blocks(cnt) + area(rbox[k]) * blocks(rcnt[k]);
        if (cost < obest) {
          obest = cost;
          oaxis = a;
          osplit = k;
          oleft = acc;
          oright = rbox[k];
        }
      }
    }

    // -- spatial split, where the object split's children overlap
    SpatialSplit spatial;
    const bool may_grow = node.cap > count;
    const bool overlap = oaxis < 0 || area(intersect(oleft, oright)) > kAlpha * root_area_;
    if (may_grow && overlap) spatial = best_spatial_split(node);

    // -- choose
    const float ct = opt_.traversal_cost;
    const float leaf_cost = blocks(count);
    const float ocost = oaxis >= 0 ? ct + (narea > 0 ? obest / narea : 0.0f) : INFINITY;
    const float scost = spatial.axis >= 0 ? ct + (narea > 0 ? spatial.cost / narea : 0.0f) : INFINITY;
    if (count <= opt_.max_leaf && leaf_cost <= std::min(ocost, scost)) return make_leaf(node, false);

    std::vector<Ref> left, right;
    bool done = false;
    if (scost < ocost) done = spatial_partition(node, spatial.axis, spatial.plane, left, right);
    if (!done) {
      left.clear();
      right.clear();
      if (oaxis >= 0) {
        for (const Ref& r : node.refs) (obin(r, oaxis) < osplit ? left : right).push_back(r);
      } else {
        // all centroids equal and no spatial split: halve by index if the leaf would be too big
        if (count <= opt_.max_leaf) return make_leaf(node, false);
        left.assign(node.refs.begin(), node.refs.begin() + static_cast<std::ptrdiff_t>(count / 2));
        right.assign(node.refs.begin() + static_cast<std::ptrdiff_t>(count / 2), node.refs.end());
      }
    }

    // -- children share the reference budget left in proportion to their references
    const std::size_t nl = left.size(), nr = right.size();
    const std::size_t extra = node.cap - (nl + nr);
    const std::size_t lcap = nl + extra * nl / (nl + nr);
    const std::size_t rcap = nr + extra - (lcap - nl);
    const std::uint32_t depth = node.depth;
    node.refs.clear();
    node.refs.shrink_to_fit();
    std::vector<Ref>* sides[2] = {&left, &right};
    const std::size_t caps[2] = {lcap, rcap};
    for (int s = 0; s < 2; ++s) {
      Node c;
      for (const Ref& r : *sides[s]) grow_box(c.box, r.box);
      c.refs = std::move(*sides[s]);
      c.cap = caps[s];
      c.depth = depth + 1;
      arena[n].child[s] = static_cast<std::int32_t>(arena.size());
      arena.push_back(std::move(c));
    }
  }

  // Partitions node's references at x[a] = p, splitting or (SBVH §4.5) unsplitting straddlers.
  // False (and nothing decided) if the split would exceed the node's budget or leave a side empty.
  bool spatial_partition(const Node& node, int a, float p, std::vector<Ref>& left, std::vector<Ref>& right) {
    std::vector<std::size_t> straddle;
    Box lb, rb;
    for (std::size_t i = 0; i < node.refs.size(); ++i) {
      const Ref& r = node.refs[i];
      if (r.box.hi[a] <= p) {
        left.push_back(r);
        grow_box(lb, r.box);
      } else if (r.box.lo[a] >= p) {
        right.push_back(r);
        grow_box(rb, r.box);
      } else {
        straddle.push_back(i);
      }
    }
    if (node.refs.size() + straddle.size() > node.cap) return false;
    for (std::size_t i : straddle) {
      const Ref& r = node.refs[i];
      Box l, rt;
      clip(r, a, p, l, rt);
      const bool hl = valid(l), hr = valid(rt);
      const float nl = blocks(left.size()), nr = blocks(right.size());
      int choice = 0;  // 0 split, 1 whole left, 2 whole right
      if (!hl) choice = 2;
      else if (!hr) choice = 1;
      else {
        Box ls = lb, rs = rb, lw = lb, rw = rb;
        grow_box(ls, l);
        grow_box(rs, rt);
        grow_box(lw, r.box);
        grow_box(rw, r.box);
        const float csplit = area(ls) * blocks(left.size() + 1) + area(rs) * blocks(right.size() + 1);
        const float c1 = area(lw) * blocks(left.size() + 1) + area(rb) * nr;
        const float c2 = area(lb) * nl + area(rw) * blocks(right.size() + 1);
        if (c1 < csplit && c1 <= c2) choice = 1;
        else if (c2 < csplit) choice = 2;
      }
      if (choice == 0) {
        left.push_back({l, r.prim});
        right.push_back({rt, r.prim});
        grow_box(lb, l);
        grow_box(rb, rt);
      } else if (choice == 1) {
        Ref w = r;
        if (!hr) w.box = l;
        left.push_back(w);
        grow_box(lb, w.box);
      } else {
        Ref w = r;
        if (!hl) w.box = rt;
        right.push_back(w);
        grow_box(rb, w.box);
      }
    }
    return !left.empty() && !right.empty();
  }

  void build_subtree(std::vector<Node>& arena) {
    for (std::size_t n = 0; n < arena.size(); ++n) split(arena, n);
  }

private:
  const Scene& scene_;
  const BuildOptions& opt_;
  unsigned bins_;
  float root_area_;
};

struct Flattener {
  const std::vector<Node>& upper;
  const std::vector<std::vector<Node>>& subtrees;
  const std::vector<std::int32_t>& subtree_of;
  SbvhResult& out;

  std::int32_t emit(const std::vector<Node>& arena, std::size_t n, std::int32_t parent, std::uint32_t& height) {
    const Node& t = arena[n];
    if (&arena == &upper && subtree_of[n] >= 0)
      return emit(subtrees[static_cast<std::size_t>(subtree_of[n])], 0, parent, height);
    Bvh2& b = out.bvh;
    if (t.leaf) {
      const std::uint32_t first = static_cast<std::uint32_t>(out.prims.size());
      for (const Ref& r : t.refs) out.prims.push_back(r.prim);
      std::vector<std::uint32_t> check(out.prims.begin() + first, out.prims.end());
      std::sort(check.begin(), check.end());
      if (std::adjacent_find(check.begin(), check.end()) != check.end())
        throw Error("internal: the high-quality build put a triangle twice in one leaf");
      out.leaves.push_back({first, static_cast<std::uint32_t>(t.refs.size())});
      b.leaf_boxes.push_back(t.box);
      b.largest_leaf = std::max(b.largest_leaf, t.refs.size());
      b.forced_leaves += t.forced ? 1 : 0;
      height = 0;
      return ~static_cast<std::int32_t>(out.leaves.size() - 1);
    }
    const std::int32_t self = static_cast<std::int32_t>(b.nodes.size());
    b.nodes.push_back({t.box, {MBVH_EMPTY, MBVH_EMPTY}, parent, 0});
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side) {
      const std::int32_t ref = emit(arena, static_cast<std::size_t>(t.child[side]), self, h[side]);
      b.nodes[static_cast<std::size_t>(self)].child[side] = ref;
    }
    height = 1 + std::max(h[0], h[1]);
    b.nodes[static_cast<std::size_t>(self)].height = height;
    return self;
  }
};

}  // namespace

SbvhResult build_sbvh(const Scene& scene, const BuildOptions& opt, const std::vector<Box>& boxes,
                      const std::vector<std::uint32_t>& idx, bool spatial) {
  std::vector<Node> upper(1);
  Node& root = upper[0];
  root.refs.reserve(idx.size());
  for (std::uint32_t p : idx) {
    root.refs.push_back({boxes[p], p});
    grow_box(root.box, boxes[p]);
  }
  // no budget beyond one reference per triangle: no spatial split is tried (Sbvh::split)
  root.cap = spatial ? static_cast<std::size_t>(static_cast<double>(idx.size()) * (1.0 + kGrowth)) : idx.size();
  Sbvh builder(scene, opt, root.box.half_area());

  // -- top of the tree in order, then subtrees one per task (the split points do not depend on
  //    where the top ends, so neither do the bytes)
  const std::size_t threads = resolve_threads(opt.threads);
  const std::size_t small = std::max<std::size_t>(4096, idx.size() / (8 * threads));
  std::vector<std::size_t> jobs;
  for (std::size_t k = 0; k < upper.size(); ++k) {
    if (k > 0 && upper[k].refs.size() <= small) {
      jobs.push_back(k);
      continue;
    }
    builder.split(upper, k);
    if (opt.progress && k == 0) opt.progress(0.1);
  }
  if (upper[0].leaf) {  // the root is always an inner node: a one-leaf scene gets one leaf child
    Node leaf = upper[0];
    leaf.depth = 1;
    upper[0].leaf = false;
    upper[0].forced = false;
    upper[0].refs.clear();
    upper[0].child[0] = 1;
    upper.push_back(std::move(leaf));
  }
  std::vector<std::int32_t> subtree_of(upper.size(), -1);
  std::vector<std::vector<Node>> subtrees(jobs.size());
  for (std::size_t j = 0; j < jobs.size(); ++j) subtree_of[jobs[j]] = static_cast<std::int32_t>(j);
  std::atomic<std::size_t> built{0};
  parallel_for(jobs.size(), 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t j = b; j < e; ++j) {
      subtrees[j].push_back(std::move(upper[jobs[j]]));
      builder.build_subtree(subtrees[j]);
      if (opt.progress) opt.progress(0.25 + 0.7 * static_cast<double>(++built) / static_cast<double>(jobs.size()));
    }
  });

  // -- flatten depth-first
  SbvhResult res;
  Flattener fl{upper, subtrees, subtree_of, res};
  const Node& r = upper[0];
  res.bvh.nodes.push_back({r.box, {MBVH_EMPTY, MBVH_EMPTY}, MBVH_NONE, 0});
  std::uint32_t h[2] = {0, 0};
  for (int side = 0; side < 2; ++side)
    if (r.child[side] >= 0) res.bvh.nodes[0].child[side] = fl.emit(upper, static_cast<std::size_t>(r.child[side]), 0, h[side]);
  res.bvh.nodes[0].height = 1 + std::max(h[0], h[1]);
  res.references = res.prims.size();
  return res;
}

SbvhResult build_high(const Scene& scene, const BuildOptions& opt, const std::vector<Box>& boxes,
                      const std::vector<std::uint32_t>& idx) {
  // Spatial splits are chosen top-down, each against the object split of its node alone; the
  // references they duplicate are fixed before reinsertion, which then moves only whole subtrees.
  // On some scenes (large triangles beside small ones: the conference room) the tree without them
  // reaches the lower SAH once both are reinserted, so both are built and the SAH decides.
  SbvhResult cand[2];
  for (int k = 0; k < 2; ++k) {
    BuildOptions o = opt;  // each candidate's progress in its share of [0.05, 0.5]
    if (opt.progress) o.progress = [&opt, k](double f) { opt.progress(0.05 + 0.225 * (k + f)); };
    cand[k] = build_sbvh(scene, o, boxes, idx, k == 0);
  }
  // each reinsertion is sequential and a function of its tree alone: the two side by side
  parallel_for(2, 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t k = b; k < e; ++k) {
      build::reinsert(cand[k].bvh, cand[k].leaves, cand[k].prims, opt);
      cand[k].sah = build::sah_of_binary(cand[k].bvh, cand[k].leaves, opt.traversal_cost);
    }
  });
  if (opt.progress) opt.progress(0.95);
  return std::move(cand[cand[1].sah < cand[0].sah ? 1 : 0]);
}

}  // namespace mbvh

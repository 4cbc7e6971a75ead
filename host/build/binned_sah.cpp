// binned_sah.cpp — the one BVH build: a binned-SAH binary BVH over the non-degenerate triangles
// (Wald, "On fast Construction of SAH-based Bounding Volume Hierarchies", 2007), with the binary
// depth capped so that every path fits the 64-bit bitstack (TRAVERSAL.md §3.5).
//
// Parallel and deterministic: the top of the tree is split breadth-first with binning spread
// over threads (box unions and counts are exact, so the reduction order does not matter), then
// the remaining subtrees are built one per task. Every split decision is the same function of
// the same inputs, so the bytes do not depend on the thread count.
#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>

#include "host/accel.h"
#include "host/build/sbvh.h"
#include "host/error.h"
#include "host/parallel.h"

namespace mbvh {

const char* to_string(Layout l) { return l == Layout::mbvh2 ? "mbvh2" : l == Layout::mbvh4 ? "mbvh4" : "mbvh8"; }

Layout parse_layout(const std::string& s) {
  if (s == "mbvh2") return Layout::mbvh2;
  if (s == "mbvh4") return Layout::mbvh4;
  if (s == "mbvh8") return Layout::mbvh8;
  throw Error("unknown layout '" + s + "' (known: mbvh2, mbvh4, mbvh8)");
}

const char* to_string(BuildQuality q) {
  return q == BuildQuality::low ? "low" : q == BuildQuality::medium ? "medium" : "high";
}

BuildQuality parse_quality(const std::string& s) {
  if (s == "low") return BuildQuality::low;
  if (s == "medium") return BuildQuality::medium;
  if (s == "high") return BuildQuality::high;
  throw Error("unknown build quality '" + s + "' (known: low, medium, high)");
}

std::uint64_t hash_bytes(const void* p, std::size_t n, std::uint64_t h) {
  const unsigned char* b = static_cast<const unsigned char*>(p);
  for (std::size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 0x100000001b3ull;
  return h;
}

namespace {

constexpr unsigned kMaxBins = 64;

struct TmpNode {
  Box box, cbox;              // bounds of the triangles and of their centroids
  std::uint32_t begin, end;   // range of the index array
  std::uint32_t depth;
  std::int32_t child[2] = {-1, -1};  // indices into the same arena; -1: none
  bool leaf = false;
  bool forced = false;        // leaf made by the depth cap or unsplittable centroids
};

struct Bin {
  Box box;
  std::uint32_t count = 0;
};

class Builder {
public:
  Builder(const BuildOptions& opt, std::vector<Box>& boxes, std::vector<Vec3f>& cents, std::vector<std::uint32_t>& idx)
      : opt_(opt), boxes_(boxes), cents_(cents), idx_(idx), bins_(std::clamp(opt.bins, 2u, kMaxBins)) {}

  // SAH price of testing `n` triangles: blocks of leaf_block.
  float blocks(std::uint32_t n) const {
    const std::uint32_t b = std::max(opt_.leaf_block, 1u);
    return static_cast<float>((n + b - 1) / b);
  }

  // Splits node n (in `arena`) into two children appended to `arena`, or marks it a leaf.
  void split(std::vector<TmpNode>& arena, std::size_t n, bool parallel_binning) {
    TmpNode node = arena[n];
    const std::uint32_t count = node.end - node.begin;
    const bool at_cap = node.depth >= opt_.depth_cap;
    if (count <= 1 || at_cap) {
      arena[n].leaf = true;
      arena[n].forced = count > opt_.max_leaf;
      return;
    }
    // -- bin centroids along the three axes
    Bin bins[3][kMaxBins];
    float scale[3];
    const Vec3f ext = node.cbox.extent();
    for (int a = 0; a < 3; ++a) scale[a] = ext[a] > 0 ? static_cast<float>(bins_) / ext[a] : 0.0f;
    auto bin_of = [&](std::uint32_t prim, int a) {
      const float f = (cents_[prim][a] - node.cbox.lo[a]) * scale[a];
      return std::min(bins_ - 1, static_cast<unsigned>(f > 0 ? f : 0));
    };
    auto bin_range = [&](std::size_t b, std::size_t e, Bin (&out)[3][kMaxBins]) {
      for (std::size_t i = b; i < e; ++i) {
        const std::uint32_t p = idx_[i];
        for (int a = 0; a < 3; ++a) {
          Bin& bn = out[a][bin_of(p, a)];
          bn.box.grow(boxes_[p]);
          ++bn.count;
        }
      }
    };
    if (parallel_binning && count >= 65536) {
      const std::size_t grain = 16384;
      const std::size_t chunks = (count + grain - 1) / grain;
      std::vector<Bin> partial(chunks * 3 * kMaxBins);
      parallel_for(count, grain, opt_.threads, [&](std::size_t b, std::size_t e, unsigned) {
        Bin local[3][kMaxBins];
        bin_range(node.begin + b, node.begin + e, local);
        Bin* dst = &partial[(b / grain) * 3 * kMaxBins];
        for (int a = 0; a < 3; ++a)
          for (unsigned k = 0; k < bins_; ++k) dst[static_cast<unsigned>(a) * kMaxBins + k] = local[a][k];
      });
      for (std::size_t c = 0; c < chunks; ++c)
        for (int a = 0; a < 3; ++a)
          for (unsigned k = 0; k < bins_; ++k) {
            const Bin& src = partial[c * 3 * kMaxBins + static_cast<unsigned>(a) * kMaxBins + k];
            bins[a][k].box.grow(src.box);
            bins[a][k].count += src.count;
          }
    } else {
      bin_range(node.begin, node.end, bins);
    }
    // -- sweep for the cheapest SAH split
    float best_cost = INFINITY;
    int best_axis = -1;
    unsigned best_split = 0;
    for (int a = 0; a < 3; ++a) {
      if (scale[a] == 0.0f) continue;
      float right_area[kMaxBins];
      std::uint32_t right_count[kMaxBins];
      Box acc;
      std::uint32_t cnt = 0;
      for (unsigned k = bins_ - 1; k > 0; --k) {
        acc.grow(bins[a][k].box);
        cnt += bins[a][k].count;
        right_area[k] = acc.half_area();
        right_count[k] = cnt;
      }
      acc = Box();
      cnt = 0;
      for (unsigned k = 1; k < bins_; ++k) {
        acc.grow(bins[a][k - 1].box);
        cnt += bins[a][k - 1].count;
        if (cnt == 0 || right_count[k] == 0) continue;
        const float cost = acc.half_area() * blocks(cnt) + right_area[k] * blocks(right_count[k]);
        if (cost < best_cost) {
          best_cost = cost;
          best_axis = a;
          best_split = k;
        }
      }
    }
    const float area = node.box.half_area();
    const float leaf_cost = blocks(count);
    const float split_cost = opt_.traversal_cost + (area > 0 ? best_cost / area : 0.0f);
    std::uint32_t mid;
    if (best_axis < 0) {
      // all centroids equal: no spatial split exists; halve by index if the leaf would be too big
      if (count <= opt_.max_leaf) {
        arena[n].leaf = true;
        return;
      }
      mid = node.begin + count / 2;
    } else {
      if (count <= opt_.max_leaf && leaf_cost <= split_cost) {
        arena[n].leaf = true;
        return;
      }
      auto it = std::partition(idx_.begin() + node.begin, idx_.begin() + node.end,
                               [&](std::uint32_t p) { return bin_of(p, best_axis) < best_split; });
      mid = static_cast<std::uint32_t>(it - idx_.begin());
    }
    // -- children
    for (int side = 0; side < 2; ++side) {
      TmpNode c;
      c.begin = side == 0 ? node.begin : mid;
      c.end = side == 0 ? mid : node.end;
      c.depth = node.depth + 1;
      for (std::uint32_t i = c.begin; i < c.end; ++i) {
        c.box.grow(boxes_[idx_[i]]);
        c.cbox.grow(cents_[idx_[i]]);
      }
      arena[n].child[side] = static_cast<std::int32_t>(arena.size());
      arena.push_back(c);
    }
  }

  void build_subtree(std::vector<TmpNode>& arena) {
    for (std::size_t n = 0; n < arena.size(); ++n) split(arena, n, false);
  }

private:
  const BuildOptions& opt_;
  const std::vector<Box>& boxes_;
  const std::vector<Vec3f>& cents_;
  std::vector<std::uint32_t>& idx_;
  unsigned bins_;
};

// Flattens the arenas depth-first into `out`; returns the child reference of node n.
struct Flattener {
  const std::vector<TmpNode>& upper;
  const std::vector<std::vector<TmpNode>>& subtrees;
  const std::vector<std::int32_t>& subtree_of;  // upper node -> subtree index or -1
  Bvh2& out;
  std::vector<Leaf>& leaves;

  std::int32_t emit(const std::vector<TmpNode>& arena, std::size_t n, std::int32_t parent, std::uint32_t& height) {
    const TmpNode& t = arena[n];
    if (&arena == &upper && subtree_of[n] >= 0) return emit(subtrees[static_cast<std::size_t>(subtree_of[n])], 0, parent, height);
    if (t.leaf) {
      leaves.push_back({t.begin, t.end - t.begin});
      out.leaf_boxes.push_back(t.box);
      out.largest_leaf = std::max<std::size_t>(out.largest_leaf, t.end - t.begin);
      out.forced_leaves += t.forced ? 1 : 0;
      height = 0;
      return ~static_cast<std::int32_t>(leaves.size() - 1);
    }
    const std::int32_t self = static_cast<std::int32_t>(out.nodes.size());
    out.nodes.push_back({t.box, {MBVH_EMPTY, MBVH_EMPTY}, parent, 0});
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side) {
      const std::int32_t ref = emit(arena, static_cast<std::size_t>(t.child[side]), self, h[side]);
      out.nodes[static_cast<std::size_t>(self)].child[side] = ref;
    }
    height = 1 + std::max(h[0], h[1]);
    out.nodes[static_cast<std::size_t>(self)].height = height;
    return self;
  }
};

double sah_of_binary(const Bvh2& b, const std::vector<Leaf>& leaves, float ct) {
  const double root = b.nodes[0].box.half_area();
  if (!(root > 0)) return 0;
  double cost = 0;
  for (const auto& n : b.nodes) cost += ct * n.box.half_area() / root;
  for (std::size_t i = 0; i < leaves.size(); ++i) cost += double(leaves[i].count) * b.leaf_boxes[i].half_area() / root;
  return cost;
}

// The scene's non-degenerate triangles must lie in the exactly traced range (accel.h): a
// coordinate beyond ±kMaxCoordinate is named with its triangle; a scene whose largest magnitude
// is below kMinSceneScale is refused as a whole.
void check_traceable_range(const Scene& scene, const std::vector<Box>& boxes, const std::vector<std::uint32_t>& idx) {
  auto mag = [](const Box& b) {
    return std::max({std::fabs(b.lo.x), std::fabs(b.lo.y), std::fabs(b.lo.z), std::fabs(b.hi.x), std::fabs(b.hi.y),
                     std::fabs(b.hi.z)});
  };
  float largest = 0;
  for (std::uint32_t i : idx) {
    const float m = mag(boxes[i]);
    if (m > kMaxCoordinate) {
      for (std::uint32_t v : scene.triangles[i]) {
        const Vec3f& p = scene.vertices[v];
        for (float c : {p.x, p.y, p.z})
          if (std::fabs(c) > kMaxCoordinate) {
            char buf[256];
            std::snprintf(buf, sizeof buf,
                          ": coordinate %.9g of vertex %u (triangle %u) is beyond +-2^40 (%.3g), the range mbvh traces "
                          "exactly (float products of three coordinates would overflow); rescale the scene",
                          double(c), v, i, double(kMaxCoordinate));
            throw Error(scene.name + buf);
          }
      }
    }
    largest = std::max(largest, m);
  }
  if (largest < kMinSceneScale) {
    char buf[256];
    std::snprintf(buf, sizeof buf,
                  ": the largest coordinate magnitude is %.9g, below 2^-36 (%.3g), the smallest scene scale mbvh traces "
                  "exactly (float products of three coordinates would underflow); rescale the scene",
                  double(largest), double(kMinSceneScale));
    throw Error(scene.name + buf);
  }
}

}  // namespace

std::unique_ptr<Accel> Accel::build(const Scene& scene, const BuildOptions& opt_in) {
  const auto t0 = std::chrono::steady_clock::now();
  // -- what the build is given: indices in range, finite vertices, a usable SAH cost
  scene.validate();
  if (!std::isfinite(opt_in.traversal_cost) || opt_in.traversal_cost < 0)
    throw Error("BuildOptions::traversal_cost " + std::to_string(opt_in.traversal_cost) + " must be finite and >= 0");
  std::unique_ptr<Accel> acc(new Accel());
  acc->opt_ = opt_in;
  BuildOptions& opt = acc->opt_;
  opt.depth_cap = std::clamp(opt.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP));
  opt.max_leaf = std::max(opt.max_leaf, 1u);
  acc->scene_triangles_ = scene.triangles.size();

  // -- primitive boxes and centroids; degenerate (zero-area) triangles never reach a leaf
  const std::size_t n = scene.triangles.size();
  std::vector<Box> boxes(n);
  std::vector<Vec3f> cents(n);
  std::vector<std::uint8_t> keep(n);
  parallel_for(n, 65536, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) {
      const auto& t = scene.triangles[i];
      const Vec3f& a = scene.vertices[t[0]];
      const Vec3f& bb = scene.vertices[t[1]];
      const Vec3f& c = scene.vertices[t[2]];
      const double e1[3] = {double(bb.x) - a.x, double(bb.y) - a.y, double(bb.z) - a.z};
      const double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
      const double cx = e1[1] * e2[2] - e1[2] * e2[1], cy = e1[2] * e2[0] - e1[0] * e2[2],
                   cz = e1[0] * e2[1] - e1[1] * e2[0];
      keep[i] = (cx != 0 || cy != 0 || cz != 0) ? 1 : 0;
      Box bx;
      bx.grow(a);
      bx.grow(bb);
      bx.grow(c);
      boxes[i] = bx;
      cents[i] = bx.center();
    }
  });
  auto report = [&opt](double f) {
    if (opt.progress) opt.progress(f);
  };
  report(0.05);
  std::vector<std::uint32_t> idx;
  idx.reserve(n);
  for (std::size_t i = 0; i < n; ++i)
    if (keep[i]) idx.push_back(static_cast<std::uint32_t>(i));
  acc->bvh2_.degenerate = n - idx.size();
  if (idx.empty())
    throw Error(scene.name + ": the scene has no non-degenerate triangle (" + std::to_string(n) + " triangles, " +
                std::to_string(acc->bvh2_.degenerate) + " degenerate)");
  if (idx.size() > 0x7FFFFFF0u) throw Error(scene.name + ": too many triangles for 32-bit references");
  check_traceable_range(scene, boxes, idx);

  Bvh2& out = acc->bvh2_;
  if (opt.quality == BuildQuality::high) {
    // -- spatial splits (sbvh.cpp): idx becomes the leaf slots' prims, a prim possibly repeated
    SbvhResult r = build_sbvh(scene, opt, boxes, idx);
    r.bvh.degenerate = out.degenerate;
    out = std::move(r.bvh);
    acc->leaves_ = std::move(r.leaves);
    idx = std::move(r.prims);
  } else {
    // -- top of the tree, breadth-first, with parallel binning
    Builder builder(opt, boxes, cents, idx);
    std::vector<TmpNode> upper(1);
    upper[0].begin = 0;
    upper[0].end = static_cast<std::uint32_t>(idx.size());
    upper[0].depth = 0;
    for (std::uint32_t p : idx) {
      upper[0].box.grow(boxes[p]);
      upper[0].cbox.grow(cents[p]);
    }
    const std::size_t threads = resolve_threads(opt.threads);
    const std::size_t small = std::max<std::size_t>(4096, idx.size() / (8 * threads));
    std::vector<std::int32_t> subtree_of;
    std::vector<std::size_t> jobs;
    for (std::size_t k = 0; k < upper.size(); ++k) {
      if (k > 0 && upper[k].end - upper[k].begin <= small) {
        jobs.push_back(k);
        continue;
      }
      builder.split(upper, k, true);
    }
    // the root is always an inner node: a one-leaf scene gets a root with one leaf child
    if (upper[0].leaf) {
      TmpNode leaf = upper[0];
      leaf.depth = 1;
      upper[0].leaf = false;
      upper[0].forced = false;
      upper[0].child[0] = 1;
      upper.push_back(leaf);
    }
    subtree_of.assign(upper.size(), -1);
    std::vector<std::vector<TmpNode>> subtrees(jobs.size());
    for (std::size_t j = 0; j < jobs.size(); ++j) subtree_of[jobs[j]] = static_cast<std::int32_t>(j);

    // -- remaining subtrees, one per task
    report(0.25);
    std::atomic<std::size_t> built{0};
    parallel_for(jobs.size(), 1, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t j = b; j < e; ++j) {
        subtrees[j].push_back(upper[jobs[j]]);
        builder.build_subtree(subtrees[j]);
        report(0.25 + 0.7 * static_cast<double>(++built) / static_cast<double>(jobs.size()));
      }
    });

    // -- flatten depth-first; leaves come out in index-array order
    Flattener fl{upper, subtrees, subtree_of, out, acc->leaves_};
    {
      const TmpNode& r = upper[0];
      out.nodes.push_back({r.box, {MBVH_EMPTY, MBVH_EMPTY}, MBVH_NONE, 0});
      std::uint32_t h[2] = {0, 0};
      for (int side = 0; side < 2; ++side)
        if (r.child[side] >= 0) out.nodes[0].child[side] = fl.emit(upper, static_cast<std::size_t>(r.child[side]), 0, h[side]);
      out.nodes[0].height = 1 + std::max(h[0], h[1]);
    }
  }
  acc->tris_.resize(idx.size());
  for (std::size_t i = 0; i < idx.size(); ++i) {
    const auto& t = scene.triangles[idx[i]];
    Tri& d = acc->tris_[i];
    const Vec3f* v[3] = {&scene.vertices[t[0]], &scene.vertices[t[1]], &scene.vertices[t[2]]};
    float* rows[3] = {d.v0, d.v1, d.v2};
    for (int k = 0; k < 3; ++k) {
      rows[k][0] = v[k]->x;
      rows[k][1] = v[k]->y;
      rows[k][2] = v[k]->z;
      rows[k][3] = 0.0f;
    }
    std::memcpy(&d.v0[3], &idx[i], 4);
  }
  acc->bounds_ = out.nodes[0].box;

  // -- statistics and hash
  LayoutStats& st = acc->binary_stats_;
  st.layout = "binary";
  st.nodes = out.nodes.size();
  st.leaves = acc->leaves_.size();
  st.depth = out.nodes[0].height;
  st.sah_cost = sah_of_binary(out, acc->leaves_, opt.traversal_cost);
  st.bytes = out.nodes.size() * sizeof(Bvh2::Node) + acc->leaves_.size() * (sizeof(Leaf) + sizeof(Box)) +
             acc->tris_.size() * sizeof(Tri);
  st.bitstack_bits = st.depth;
  if (st.depth > opt.depth_cap) throw Error("internal: binary depth " + std::to_string(st.depth) + " exceeds the cap");
  std::uint64_t h = hash_bytes(out.nodes.data(), out.nodes.size() * sizeof(Bvh2::Node));
  h = hash_bytes(acc->leaves_.data(), acc->leaves_.size() * sizeof(Leaf), h);
  h = hash_bytes(acc->tris_.data(), acc->tris_.size() * sizeof(Tri), h);
  acc->hash_ = h;
  st.build_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
  report(1.0);
  return acc;
}

const Mbvh2& Accel::mbvh2() const {
  std::call_once(once2_, [this] { mbvh2_ = make_mbvh2(bvh2_, leaves_); });
  return mbvh2_;
}

void Accel::make_layout(Layout l) const {
  if (l == Layout::mbvh2) mbvh2();
  else if (l == Layout::mbvh4) mbvh4();
  else mbvh8();
}

const Mbvh8& Accel::mbvh8() const {
  std::call_once(once8_, [this] { mbvh8_ = make_mbvh8(bvh2_, leaves_); });
  return mbvh8_;
}

const Mbvh4& Accel::mbvh4() const {
  std::call_once(once4_, [this] { mbvh4_ = make_mbvh4(bvh2_, leaves_); });
  return mbvh4_;
}

const TriPacks& Accel::tri_packs() const {
  std::call_once(oncep_, [this] { packs_ = make_tri_packs(tris_, leaves_); });
  return packs_;
}

const Mbvh4Wide& Accel::mbvh4_wide() const {
  std::call_once(once4w_, [this] { mbvh4w_ = make_mbvh4_wide(mbvh4()); });
  return mbvh4w_;
}

}  // namespace mbvh

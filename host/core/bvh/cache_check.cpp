// SPDX-License-Identifier: MIT
// cache_check.cpp — a loaded BVH cache entry's tree and triangle records checked against what a
// build makes (cache_check.h): nothing in a file, checksum or not, is trusted before this passes.
#include "host/core/bvh/cache_check.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <mutex>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/triangles.h"
#include "host/core/parallel.h"
#include "mbvh/accel.h"

namespace mbvh::build {

namespace {

bool box_in_range(const Box& b) {
  for (float c : {b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y, b.hi.z})
    if (!(std::fabs(c) <= kMaxCoordinate)) return false;  // NaN fails too
  return b.lo.x <= b.hi.x && b.lo.y <= b.hi.y && b.lo.z <= b.hi.z;
}

bool contains(const Box& outer, const Box& in) {
  return outer.lo.x <= in.lo.x && outer.lo.y <= in.lo.y && outer.lo.z <= in.lo.z && in.hi.x <= outer.hi.x &&
         in.hi.y <= outer.hi.y && in.hi.z <= outer.hi.z;
}

bool contains(const Box& b, const float* p) {
  return b.lo.x <= p[0] && p[0] <= b.hi.x && b.lo.y <= p[1] && p[1] <= b.hi.y && b.lo.z <= p[2] && p[2] <= b.hi.z;
}

// The first problem a parallel pass finds (the lowest index, so the message does not depend on
// the thread count).
struct FirstProblem {
  std::mutex m;
  std::size_t at = SIZE_MAX;
  std::string what;
  std::atomic<bool> any{false};
  void set(std::size_t i, std::string w) {
    std::lock_guard<std::mutex> lock(m);
    if (i < at) at = i, what = std::move(w);
    any.store(true, std::memory_order_relaxed);
  }
};

}  // namespace

std::string check_tree(const Bvh2& b, const std::vector<Leaf>& leaves, std::size_t tris) {
  const std::size_t n = b.nodes.size(), nl = leaves.size();
  if (n == 0) return "no tree nodes";
  if (b.leaf_boxes.size() != nl) return "leaf boxes and leaves differ in number";
  if (n > std::size_t(INT32_MAX) || nl > std::size_t(INT32_MAX)) return "more nodes or leaves than references can name";
  if (b.nodes[0].parent != MBVH_NONE) return "the root's parent link is " + std::to_string(b.nodes[0].parent) + ", not none";
  std::vector<std::uint8_t> seen_node(n, 0), seen_leaf(nl, 0);
  for (std::size_t i = 0; i < n; ++i) {
    const Bvh2::Node& d = b.nodes[i];
    auto node = [i] { return "node " + std::to_string(i); };
    if (!box_in_range(d.box)) return node() + "'s box is empty, not finite or beyond the traced range";
    std::uint32_t h = 0;
    for (int k = 0; k < 2; ++k) {
      const std::int32_t c = d.child[k];
      auto slot = [&node, k] { return node() + "'s child " + std::to_string(k); };
      if (c == MBVH_EMPTY) {
        if (i != 0 || k != 1 || n != 1) return slot() + " is empty (only a one-leaf root's second slot may be)";
        continue;
      }
      const Box* cb;
      std::uint32_t ch;
      if (c >= 0) {
        const auto ci = static_cast<std::size_t>(c);
        if (ci <= i || ci >= n || seen_node[ci]++) return slot() + " (node " + std::to_string(c) + ") is out of order, out of range or shared";
        if (b.nodes[ci].parent != static_cast<std::int32_t>(i))
          return "node " + std::to_string(ci) + "'s parent link is " + std::to_string(b.nodes[ci].parent) + ", not its parent " +
                 std::to_string(i);
        cb = &b.nodes[ci].box;
        ch = b.nodes[ci].height;
      } else {
        const auto li = static_cast<std::size_t>(~c);
        if (li >= nl || seen_leaf[li]++) return slot() + " (leaf " + std::to_string(li) + ") is out of range or shared";
        cb = &b.leaf_boxes[li];
        ch = 0;
      }
      if (!contains(d.box, *cb)) return node() + "'s box does not contain its child " + std::to_string(k) + "'s";
      h = std::max(h, ch + 1);
    }
    if (d.height != h) return node() + "'s height is " + std::to_string(d.height) + ", its children make it " + std::to_string(h);
  }
  for (std::size_t i = 1; i < n; ++i)
    if (!seen_node[i]) return "node " + std::to_string(i) + " is unreachable";
  if (b.nodes[0].height > MBVH_BINARY_DEPTH_CAP) return "deeper than the depth cap";
  std::vector<std::uint8_t> covered(tris, 0);
  for (std::size_t i = 0; i < nl; ++i) {
    const Leaf& l = leaves[i];
    auto leaf = [i] { return "leaf " + std::to_string(i); };
    if (!seen_leaf[i]) return leaf() + " is unreachable";
    if (!box_in_range(b.leaf_boxes[i])) return leaf() + "'s box is empty, not finite or beyond the traced range";
    if (l.count == 0 || l.first > tris || l.count > tris - l.first) return leaf() + "'s triangle range is empty or out of range";
    for (std::size_t t = l.first; t < std::size_t(l.first) + l.count; ++t)
      if (covered[t]++) return leaf() + " shares triangle record " + std::to_string(t) + " with another leaf";
  }
  for (std::size_t t = 0; t < tris; ++t)
    if (!covered[t]) return "triangle record " + std::to_string(t) + " is in no leaf";
  return "";
}

std::string check_records(const Scene& scene, const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris,
                          bool spatial, std::size_t degenerate, unsigned threads, Box& bounds) {
  const std::size_t n = scene.triangle_count();
  constexpr std::size_t grain = 65536;
  // -- the scene's triangles: which the build keeps (state 1), which it leaves out as degenerate
  //    (0); their box; anything the build refuses
  std::vector<std::uint8_t> state(n, 0);
  const std::size_t chunks = (n + grain - 1) / grain;
  std::vector<Box> cbox(chunks);
  std::vector<std::size_t> cdeg(chunks, 0);
  std::atomic<bool> invalid{false};
  with_triangles(scene, [&](const auto& src) {
    parallel_for(n, grain, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
      Box box;
      std::size_t deg = 0;
      for (std::size_t i = lo; i < hi; ++i) {
        Vec3f v0, v1, v2;
        if (!src.get_checked(i, v0, v1, v2) || !finite(v0, v1, v2)) {
          invalid = true;
          continue;
        }
        if (!has_area(v0, v1, v2)) {
          ++deg;
          continue;
        }
        state[i] = 1;
        box.grow(v0), box.grow(v1), box.grow(v2);
      }
      cbox[lo / grain] = box;
      cdeg[lo / grain] = deg;
    });
  });
  if (invalid) return "the scene has a triangle the build refuses (an index out of range or a non-finite vertex)";
  Box all;
  std::size_t deg = 0;
  for (std::size_t c = 0; c < chunks; ++c) all.grow(cbox[c]), deg += cdeg[c];
  if (deg != degenerate)
    return "it counts " + std::to_string(degenerate) + " degenerate triangles, the scene has " + std::to_string(deg);
  if (deg == n) return "the scene has no non-degenerate triangle";
  float largest = 0;
  for (float c : {all.lo.x, all.lo.y, all.lo.z, all.hi.x, all.hi.y, all.hi.z}) largest = std::max(largest, std::fabs(c));
  if (!(largest <= kMaxCoordinate) || largest < kMinSceneScale) return "the scene's coordinates leave the exactly traced range";

  // -- every record against the scene's triangle it names, and against its leaf's box
  FirstProblem bad;
  with_triangles(scene, [&](const auto& src) {
    parallel_for(leaves.size(), 1024, threads, [&](std::size_t lo, std::size_t hi, unsigned) {
      for (std::size_t li = lo; li < hi && !bad.any.load(std::memory_order_relaxed); ++li) {
        const Leaf& l = leaves[li];
        const Box& lb = b.leaf_boxes[li];
        for (std::size_t t = l.first; t < std::size_t(l.first) + l.count; ++t) {
          const Tri& r = tris[t];
          std::uint32_t prim;
          std::memcpy(&prim, &r.v0[3], 4);
          auto rec = [t] { return "triangle record " + std::to_string(t); };
          if (prim >= n || !state[prim]) {
            bad.set(t, rec() + " names " + (prim >= n ? "no triangle of the scene" : "a degenerate triangle") + " (" + std::to_string(prim) + ")");
            break;
          }
          Vec3f v0, v1, v2;
          src.get(prim, v0, v1, v2);
          Tri want;
          fill_tri(want, v0, v1, v2, prim);
          if (std::memcmp(&want, &r, sizeof(Tri)) != 0) {
            bad.set(t, rec() + " is not the scene's triangle " + std::to_string(prim));
            break;
          }
          const float* v[3] = {r.v0, r.v1, r.v2};
          std::uint8_t mask = 0;
          for (int k = 0; k < 3; ++k)
            if (contains(lb, v[k])) mask = static_cast<std::uint8_t>(mask | (2u << k));
          if (!spatial && mask != 0xE) {
            bad.set(t, rec() + " lies outside the box of leaf " + std::to_string(li));
            break;
          }
          const std::uint8_t was = std::atomic_ref<std::uint8_t>(state[prim]).fetch_or(static_cast<std::uint8_t>(mask | 0x10));
          if (!spatial && (was & 0x10)) {
            bad.set(t, rec() + " repeats triangle " + std::to_string(prim));
            break;
          }
        }
      }
    });
  });
  if (bad.any) return bad.what;
  // -- every kept triangle referenced (and, SBVH, each vertex inside a leaf box holding it)
  for (std::size_t i = 0; i < n; ++i)
    if (state[i] && !(state[i] & 0x10)) return "the scene's triangle " + std::to_string(i) + " is in no leaf";
    else if (state[i] && spatial && (state[i] & 0xE) != 0xE)
      return "the scene's triangle " + std::to_string(i) + " is not covered by its leaves' boxes";
  if (!spatial && tris.size() != n - deg) return "it holds " + std::to_string(tris.size()) + " triangle records, the scene " + std::to_string(n - deg);
  bounds = all;
  return "";
}

}  // namespace mbvh::build

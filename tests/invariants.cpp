// SPDX-License-Identifier: MIT
// invariants.cpp — the builder invariants every test of a build checks: every triangle in exactly one
// leaf, boxes contain their children, parent/sibling links consistent, depth within the bitstack's
// cap, the layouts and packs the backends read equal to the binary tree.
#include "tests/invariants.h"

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>

#include "host/core/bvh/builder.h"  // tri_box
#include "host/core/bvh/wide_node.h"  // slot_box
#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/backend.h"
#include "host/tools/check.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "host/tools/raygen.h"
#include "mbvh/trace.h"
#include "tests/backends.h"
#include "tests/helpers.h"

namespace mbvh_test {

using namespace mbvh;
using mbvh::build::slot_box;
using mbvh::build::tri_box;

bool contains(const Box& outer, const Box& inner) {
  for (int a = 0; a < 3; ++a)
    if (!(outer.lo[a] <= inner.lo[a] && inner.hi[a] <= outer.hi[a])) return false;
  return true;
}

namespace {

Box leaf_tris_box(const Accel& acc, std::int32_t ref) {
  const Leaf& l = acc.leaves()[static_cast<std::size_t>(~ref)];
  Box b;
  for (std::uint32_t i = l.first; i < l.first + l.count; ++i) b.grow(tri_box(acc.tris()[i]));
  return b;
}

}  // namespace

void check_invariants(const Scene& scene, const Accel& acc) {
  // -- leaves partition the leaf-ordered triangles; every non-degenerate triangle once
  std::size_t covered = 0;
  for (const Leaf& l : acc.leaves()) {
    REQUIRE(l.first == covered);
    REQUIRE(l.count >= 1);
    covered += l.count;
  }
  REQUIRE(covered == acc.tris().size());
  std::vector<std::uint32_t> prims;
  for (const Tri& t : acc.tris()) prims.push_back(tri_prim(t));
  std::sort(prims.begin(), prims.end());
  REQUIRE(std::adjacent_find(prims.begin(), prims.end()) == prims.end());
  REQUIRE(prims.size() + acc.bvh2().degenerate == scene.triangles.size());
  for (const Tri& t : acc.tris()) {  // the stored vertices are the file's, and not degenerate
    const auto& f = scene.triangles[tri_prim(t)];
    REQUIRE(t.v1[0] == scene.vertices[f[1]].x);
    REQUIRE(t.v2[2] == scene.vertices[f[2]].z);
  }

  // -- MBVH2: boxes, links, depth
  const Mbvh2& m2 = acc.mbvh2();
  const Bvh2& b = acc.bvh2();
  REQUIRE(m2.nodes.size() == b.nodes.size());
  REQUIRE(m2.nodes[0].link[0] == MBVH_NONE);
  std::vector<int> leaf_refs2(acc.leaves().size(), 0);
  for (std::size_t i = 0; i < m2.nodes.size(); ++i) {
    const Node2& n = m2.nodes[i];
    for (int k = 0; k < 2; ++k) {
      const std::int32_t c = n.link[2 + k];
      if (c == MBVH_EMPTY) {
        REQUIRE(i == 0);  // only a one-leaf root has an empty slot
        continue;
      }
      const float* xy = k == 0 ? n.c0 : n.c1;
      Box cb;
      cb.lo = {xy[0], xy[2], n.zz[2 * k]};
      cb.hi = {xy[1], xy[3], n.zz[2 * k + 1]};
      if (c >= 0) {
        const Node2& ch = m2.nodes[static_cast<std::size_t>(c)];
        REQUIRE(ch.link[0] == static_cast<std::int32_t>(i));
        REQUIRE(ch.link[1] == n.link[2 + (1 - k)]);
        REQUIRE(contains(cb, b.nodes[static_cast<std::size_t>(c)].box));
        for (int g = 0; g < 2; ++g)
          if (ch.link[2 + g] != MBVH_EMPTY) REQUIRE(contains(cb, b.box(ch.link[2 + g])));
      } else {
        ++leaf_refs2[static_cast<std::size_t>(~c)];
        REQUIRE(contains(cb, leaf_tris_box(acc, c)));
      }
    }
  }
  for (int r : leaf_refs2) REQUIRE(r == 1);
  REQUIRE(m2.stats.depth <= MBVH_BINARY_DEPTH_CAP);
  REQUIRE(m2.stats.depth <= MBVH_MBVH2_LEVEL_CAP);

  // -- MBVH4: boxes, cyclic sibling links, depth
  const Mbvh4& m4 = acc.mbvh4();
  REQUIRE(m4.nodes[0].parent == MBVH_NONE);
  std::vector<int> leaf_refs4(acc.leaves().size(), 0);
  std::vector<int> inner_refs4(m4.nodes.size(), 0);
  for (std::size_t i = 0; i < m4.nodes.size(); ++i) {
    const Node4& n = m4.nodes[i];
    for (int s = 0; s < 4; ++s) {
      const std::int32_t c = n.child[s];
      if (c == MBVH_EMPTY) {
        REQUIRE(slot_box(n, s).empty());
        continue;
      }
      if (c >= 0) {
        ++inner_refs4[static_cast<std::size_t>(c)];
        const Node4& ch = m4.nodes[static_cast<std::size_t>(c)];
        REQUIRE(ch.parent == static_cast<std::int32_t>(i));
        for (int k = 0; k < 3; ++k) REQUIRE(ch.sib[k] == n.child[(s + 1 + k) & 3]);
        for (int g = 0; g < 4; ++g)
          if (ch.child[g] != MBVH_EMPTY) REQUIRE(contains(slot_box(n, s), slot_box(ch, g)));
      } else {
        ++leaf_refs4[static_cast<std::size_t>(~c)];
        REQUIRE(contains(slot_box(n, s), leaf_tris_box(acc, c)));
      }
    }
  }
  for (int r : leaf_refs4) REQUIRE(r == 1);
  for (std::size_t i = 1; i < inner_refs4.size(); ++i) REQUIRE(inner_refs4[i] == 1);
  REQUIRE(m4.stats.depth <= MBVH_MBVH4_LEVEL_CAP);
  REQUIRE(m4.stats.bitstack_bits <= 63);
  REQUIRE(m2.stats.leaves == m4.stats.leaves);

  // -- MBVH8: boxes, parents, every leaf once, depth within the stack's reach
  const Mbvh8& m8 = acc.mbvh8();
  REQUIRE(m8.nodes[0].parent == MBVH_NONE);
  std::vector<int> leaf_refs8(acc.leaves().size(), 0);
  for (std::size_t i = 0; i < m8.nodes.size(); ++i) {
    const Node8& n = m8.nodes[i];
    for (int s = 0; s < 8; ++s) {
      const std::int32_t c = n.child[s];
      if (c == MBVH_EMPTY) {
        REQUIRE(slot_box(n, s).empty());
      } else if (c >= 0) {
        const Node8& ch = m8.nodes[static_cast<std::size_t>(c)];
        REQUIRE(ch.parent == static_cast<std::int32_t>(i));
        for (int g = 0; g < 8; ++g)
          if (ch.child[g] != MBVH_EMPTY) REQUIRE(contains(slot_box(n, s), slot_box(ch, g)));
      } else {
        ++leaf_refs8[static_cast<std::size_t>(~c)];
        REQUIRE(contains(slot_box(n, s), leaf_tris_box(acc, c)));
      }
    }
  }
  for (int r : leaf_refs8) REQUIRE(r == 1);
  REQUIRE(m8.stats.depth <= MBVH_MBVH8_LEVEL_CAP);
  REQUIRE(1 + 7 * m8.stats.depth <= MBVH_STACK8_ENTRIES);
  REQUIRE(m8.stats.bitstack_bits <= 128);  // the MBVH8 bitstack's 128-bit word

  // -- SIMD leaf packs: each leaf's triangles, in order, four to a pack, padding lanes empty
  const TriPacks& packs = acc.tri_packs();
  REQUIRE(packs.leaves.size() == acc.leaves().size());
  for (std::size_t i = 0; i < packs.leaves.size(); ++i) {
    const Leaf& l = acc.leaves()[i];
    REQUIRE(packs.leaves[i].count == l.count);
    for (std::uint32_t k = 0; k < (l.count + 3) / 4 * 4; ++k) {
      const Tri4& p = packs.packs[packs.leaves[i].first + k / 4];
      if (k >= l.count) {
        REQUIRE(p.prim[k % 4] == MBVH_MISS_PRIM);
        REQUIRE(std::isnan(p.v[0][k % 4]));
        continue;
      }
      const Tri& t = acc.tris()[l.first + k];
      REQUIRE(p.prim[k % 4] == tri_prim(t));
      const float* vert[3] = {t.v0, t.v1, t.v2};
      for (int v = 0; v < 3; ++v)
        for (int a = 0; a < 3; ++a) REQUIRE(p.v[3 * v + a][k % 4] == vert[v][a]);
    }
  }
  // -- the fast precision's packs (TriPacks::mt): the same slots, each pass's triangles as v0 and
  // the edges v1 - v0, v2 - v0 (the same float bits), eight-lane blocks where the leaf's pass is
  // eight wide (k + 4 < count), a Tri4 slot for its last one to four
  const AlignedVector<Tri4>& mt = packs.mt();
  REQUIRE(mt.size() == packs.packs.size());
  for (std::size_t i = 0; i < packs.leaves.size(); ++i) {
    const Leaf& l = acc.leaves()[i];
    for (std::uint32_t k = 0; k < l.count; ++k) {
      const std::uint32_t block = k / 8 * 8;
      const bool wide = block + 4 < l.count;
      const float* slot = reinterpret_cast<const float*>(&mt[packs.leaves[i].first + (wide ? block : k) / 4]);
      const int lanes = wide ? 8 : 4, lane = static_cast<int>(wide ? k - block : k % 4);
      const Tri& t = acc.tris()[l.first + k];
      std::uint32_t id;
      std::memcpy(&id, slot + 9 * lanes + lane, 4);
      REQUIRE(id == tri_prim(t));
      for (int a = 0; a < 3; ++a) {
        const float want[3] = {t.v0[a], t.v1[a] - t.v0[a], t.v2[a] - t.v0[a]};
        for (int v = 0; v < 3; ++v) REQUIRE(std::memcmp(&slot[(3 * v + a) * lanes + lane], &want[v], 4) == 0);
      }
    }
  }
}


}  // namespace mbvh_test

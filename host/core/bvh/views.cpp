// SPDX-License-Identifier: MIT
// views.cpp — the backend-specific views of a build, made from its layouts: the MBVH4 records
// rewritten 16 wide (Node4W) and the leaves' triangles as 4-wide SoA packs (Tri4).
#include <cstring>
#include <limits>

#include "host/core/bvh/wide_node.h"
#include "host/core/layouts.h"

namespace mbvh {

Mbvh4Wide make_mbvh4_wide(const Mbvh4& m) {
  Mbvh4Wide w;
  w.nodes.resize(m.nodes.size());
  for (std::size_t i = 0; i < m.nodes.size(); ++i) {
    const Node4& n = m.nodes[i];
    Node4W& o = w.nodes[i];
    const std::int32_t link[4] = {n.parent, n.sib[0], n.sib[1], n.sib[2]};
    build::set_view_boxes(o, n);
    for (int s = 0; s < 4; ++s) {  // lane 3: the child reference below its box, a link above
      std::memcpy(&o.lo[s][3], &n.child[s], 4);
      std::memcpy(&o.hi[s][3], &link[s], 4);
    }
  }
  return w;
}

TriPacks make_tri_packs(const AlignedVector<Tri>& tris, const std::vector<Leaf>& leaves) {
  TriPacks p;
  p.leaves.reserve(leaves.size());
  std::size_t total = 0;
  for (const Leaf& l : leaves) total += (l.count + 3) / 4;
  Tri4 empty;
  for (auto& row : empty.v)
    for (float& x : row) x = std::numeric_limits<float>::quiet_NaN();
  for (auto& id : empty.prim) id = MBVH_MISS_PRIM;
  p.packs.assign(total, empty);
  std::size_t next = 0;
  for (const Leaf& l : leaves) {
    p.leaves.push_back(Leaf{static_cast<std::uint32_t>(next), l.count});
    for (std::uint32_t k = 0; k < l.count; ++k) {
      const Tri& t = tris[l.first + k];
      Tri4& o = p.packs[next + k / 4];
      const float* vert[3] = {t.v0, t.v1, t.v2};
      for (int i = 0; i < 3; ++i)
        for (int a = 0; a < 3; ++a) o.v[3 * i + a][k % 4] = vert[i][a];
      std::memcpy(&o.prim[k % 4], &t.v0[3], 4);
    }
    next += (l.count + 3) / 4;
  }
  return p;
}

void write_mt_packs(const TriPacks& p, AlignedVector<Tri4>& out) {
  if (out.size() != p.packs.size()) out = AlignedVector<Tri4>(p.packs.size());
  std::copy(p.packs.begin(), p.packs.end(), out.begin());  // v0 and the prim ids of the four-lane slots
  // two slots are one eight-lane block (9 rows of 8 floats and 8 ids), each row 32-byte aligned
  // (slot k starts 160 k bytes into the cache-aligned array)
  static_assert(sizeof(Tri4) == 160, "a slot is 5 rows of 32 bytes");
  for (const Leaf& l : p.leaves) {
    std::uint32_t k = 0;
    for (; k + 4 < l.count; k += 8) {  // SimdKernelsT::leaf's eight-lane passes
      const Tri4* s = &p.packs[l.first + k / 4];
      float* o = reinterpret_cast<float*>(&out[l.first + k / 4]);
      for (int lane = 0; lane < 8; ++lane) {
        const Tri4& t = s[lane >> 2];
        const int j = lane & 3;
        for (int a = 0; a < 3; ++a) {
          o[8 * a + lane] = t.v[a][j];
          o[8 * (3 + a) + lane] = t.v[3 + a][j] - t.v[a][j];
          o[8 * (6 + a) + lane] = t.v[6 + a][j] - t.v[a][j];
        }
        std::memcpy(o + 72 + lane, &t.prim[j], 4);
      }
    }
    if (k < l.count) {  // the last one to four: one four-lane slot
      Tri4& o = out[l.first + k / 4];
      for (int j = 0; j < 4; ++j)
        for (int a = 0; a < 3; ++a) {
          o.v[3 + a][j] -= o.v[a][j];
          o.v[6 + a][j] -= o.v[a][j];
        }
    }
  }
}

const AlignedVector<Tri4>& TriPacks::mt() const {
  std::call_once(mt_->once, [this] { write_mt_packs(*this, mt_->packs); });
  return mt_->packs;
}

void TriPacks::refresh_mt() {
  // in place (the same leaves, the same size): what points into the copy keeps pointing at it
  if (mt_ && !mt_->packs.empty()) write_mt_packs(*this, mt_->packs);
}

}  // namespace mbvh

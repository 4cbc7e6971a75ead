// SPDX-License-Identifier: MIT
// traverse.h — one ray through a .mlod model (model.cpp drives it over batches): an ordered stack
// traversal of the binary nodes of format.h, whose inner nodes hold their two children's boxes
// (Aila & Laine, "Understanding the Efficiency of Ray Traversal on GPUs", HPG 2009), with the LOD
// voxels of Áfra ("Interactive ray tracing of large models using voxel hierarchies", CGF 31(1),
// 2012): a child whose box is small against the ray's footprint at its entry is hit as a voxel
// at that entry, and a child in a block that is not resident is replaced by its voxel, the finest
// LOD resident.
//
// The arithmetic is the exact contract's (host/core/trace/intersect.h): prepare_ray, box_test
// against tcull = tmax * kCullSlack, tri_test with tmax = the best t so far, the reference's
// rule for a new best (host/core/trace/scalar_kernels.h visit_leaf) and its culling of popped
// entries beyond tmax * kCullSlack. Every triangle with t <= the answer's t lies in boxes entered
// before tmax * kCullSlack, so the closest hit is the lexicographic min of (t, prim) over the
// triangles tri_test accepts whatever the visiting order: at full detail, cpu-scalar's answer.
// A voxel is a candidate with prim MBVH_MISS_PRIM in that order (a triangle at the same t wins).
#pragma once
#include <cstdint>
#include <cstring>

#include "host/core/lod/cache.h"
#include "host/core/lod/format.h"
#include "host/core/lod/voxel.h"
#include "host/core/trace/intersect.h"
#include "mbvh/error.h"
#include "mbvh/lod.h"

namespace mbvh::lod::detail {

/// The arrays of one resident raw block.
struct BlockView {
  const std::byte* base = nullptr;
  const format::Node* nodes = nullptr;
  const format::Voxel* voxels = nullptr;
  const format::Link* links = nullptr;
  const Tri* tris = nullptr;
  std::uint32_t index = 0;
  void set(const std::byte* raw) {
    format::BlockHead h;
    std::memcpy(&h, raw, sizeof h);
    const format::BlockLayout l = format::block_layout(h);
    base = raw;
    nodes = reinterpret_cast<const format::Node*>(raw + l.nodes);
    voxels = reinterpret_cast<const format::Voxel*>(raw + l.voxels);
    links = reinterpret_cast<const format::Link*>(raw + l.links);
    tris = reinterpret_cast<const Tri*>(raw + l.tris);
    index = h.index;
  }
};

/// A pending child: node `node`'s child `slot` in the block at `block`, entered at `d`.
struct Entry {
  const format::Node* node;
  const std::byte* block;
  float d;
  std::uint32_t slot;
};

/// What a link to a block that is not resident does.
enum class OnMissing : std::uint8_t {
  force,  ///< hit the link child's voxel (Hit::forced), go on
  defer,  ///< the ray is deferred (its answer is discarded; the caller loads the block and retraces)
};

/// Per batch: the model's root and limits, and the trace's options.
struct TraceContext {
  BlockCache* cache = nullptr;
  const std::byte* root_block = nullptr;
  std::uint32_t root_node = 0;
  std::uint64_t step_limit = 0;  ///< more node visits than the file's nodes: a cycle (a damaged file)
  unsigned stack_entries = 0;
  OnMissing on_missing = OnMissing::force;
  bool lod = false;
  float quality = 0;
  const std::string* path = nullptr;  ///< for messages
};

/// One ray's answer before its attributes are filled in (finish_hit).
struct RayAnswer {
  Hit hit;                     ///< t, u, v, prim, kind; voxel: every field
  const Tri* tri = nullptr;    ///< triangle hit: its record (valid until the next fetch or end_frame)
  std::uint32_t tri_block = 0;
  bool deferred = false;
};

[[noreturn]] inline void throw_damaged_traversal(const TraceContext& c, std::uint32_t block, const char* what) {
  throw Error(*c.path + ": block " + std::to_string(block) + ": " + what);
}

/// The voxel hit of node n's child `slot` (block bv) at entry d: the entering face is the axis
/// whose near slab is the entry (the largest near distance), or for a ray starting inside the box
/// (the entry is tmin) the axis of the direction's largest component; face = 2 axis + (0 for a
/// ray going +axis, which enters the -axis face; 1 otherwise).
inline void voxel_hit(const RayPre& r, const BlockView& bv, const format::Node& n, unsigned slot, float d, bool forced,
                      Hit& h) {
  const format::Voxel& vx = bv.voxels[n.aux[slot]];
  int axis = -1;
  float best = -INFINITY;
  for (int a = 0; a < 3; ++a) {
    const float near = r.neg[a] ? n.hi[slot][a] : n.lo[slot][a];
    const float tn = (near - r.o[a]) * r.inv[a];
    if (tn > best) best = tn, axis = a;
  }
  if (axis < 0 || !(best >= d)) axis = r.kz;
  const unsigned face = 2u * unsigned(axis) + (r.d[axis] > 0.0f ? 0u : 1u);
  h = Hit{};
  h.t = d;
  h.prim = MBVH_MISS_PRIM;
  h.kind = HitKind::voxel;
  h.face = static_cast<std::uint8_t>(face);
  h.depth = static_cast<std::uint16_t>(vx.depth > 0xffffu ? 0xffffu : vx.depth);
  h.forced = forced;
  h.normal = decode_normal(vx.face[face] & 0xffffu);
  h.albedo = decode_rgb565(vx.face[face] >> 16);
  h.box.lo = {n.lo[slot][0], n.lo[slot][1], n.lo[slot][2]};
  h.box.hi = {n.hi[slot][0], n.hi[slot][1], n.hi[slot][2]};
  const auto node_index = static_cast<std::uint64_t>(&n - bv.nodes);
  h.node = std::uint64_t(bv.index) << 32 | node_index << 1 | slot;
}

/// The largest extent of node n's child `slot`'s box.
inline float child_extent(const format::Node& n, unsigned slot) {
  const float ex = n.hi[slot][0] - n.lo[slot][0], ey = n.hi[slot][1] - n.lo[slot][1], ez = n.hi[slot][2] - n.lo[slot][2];
  return ex > ey ? (ex > ez ? ex : ez) : (ey > ez ? ey : ez);
}

/// Whether the LOD metric accepts node n's child `slot` (with a voxel) entered at d: its box's
/// largest extent <= quality * (width0 + spread * d), the ray cone's width there.
inline bool lod_accepts(const format::Node& n, unsigned slot, float d, float quality, const RayCone& cone) {
  return child_extent(n, slot) <= quality * (cone.width0 + cone.spread * d);
}

/// Traces one prepared ray. `cone` null: no LOD for this ray. `stack` has c.stack_entries entries.
template <bool Any>
inline void trace_ray(const TraceContext& c, const RayPre& r, const RayCone* cone, Entry* stack, RayAnswer& ans) {
  using namespace format;
  Hit& best = ans.hit;
  best = Hit{};
  float tmax = r.tmax;
  const bool lod = c.lod && cone != nullptr && c.quality > 0;
  RayCone cn{};
  if (lod) cn = *cone;
  BlockView bv;
  bv.set(c.root_block);
  const Node* n = bv.nodes + c.root_node;
  unsigned sp = 0;
  std::uint64_t steps = 0;
  // the child being visited (when n is null): node pn's child ps, entered at pd
  const Node* pn = nullptr;
  unsigned ps = 0;
  float pd = 0;
  for (;;) {
    if (n) {
      // -- an inner node: test both children, take voxels the metric accepts, go nearer first
      if (++steps > c.step_limit) throw_damaged_traversal(c, bv.index, "the hierarchy has a cycle (more node visits than nodes)");
      const float tcull = tmax * kCullSlack;
      float d[2];
      bool h[2];
      for (unsigned s = 0; s < 2; ++s)
        h[s] = (n->ref[s] & kRefKind) != kRefEmpty &&
               box_test(r, n->lo[s][0], n->hi[s][0], n->lo[s][1], n->hi[s][1], n->lo[s][2], n->hi[s][2], tcull, d[s]);
      if (lod)
        for (unsigned s = 0; s < 2; ++s) {
          if (!h[s] || (n->ref[s] & kRefKind) == kRefLeaf || n->aux[s] == kNoVoxel) continue;
          if (!lod_accepts(*n, s, d[s], c.quality, cn)) continue;
          h[s] = false;  // not descended: the voxel stands for the subtree
          if (d[s] <= tmax && d[s] < best.t) {
            voxel_hit(r, bv, *n, s, d[s], false, best);
            ans.tri = nullptr;
            tmax = d[s];
            if constexpr (Any) return;
          }
        }
      if (h[0] || h[1]) {
        unsigned s = h[0] ? 0u : 1u;
        if (h[0] && h[1]) {
          s = d[1] < d[0] ? 1u : 0u;
          if (sp == c.stack_entries) throw_damaged_traversal(c, bv.index, "the hierarchy is deeper than the header's depth");
          stack[sp++] = Entry{n, bv.base, d[1 - s], 1 - s};
        }
        pn = n;
        ps = s;
        pd = d[s];
      }
      n = nullptr;  // visit the chosen child below, or pop
    }
    if (pn) {
      const std::uint32_t ref = pn->ref[ps];
      const std::uint32_t idx = ref & kRefIndex;
      switch (ref & kRefKind) {
        case kRefInner: n = bv.nodes + idx; break;
        case kRefLeaf: {
          const std::uint32_t end = idx + pn->aux[ps];
          for (std::uint32_t i = idx; i < end; ++i) {
            float t, u, v;
            if (!tri_test(r, bv.tris[i], tmax, t, u, v)) continue;
            const std::uint32_t prim = tri_prim(bv.tris[i]);
            if (t < best.t || prim < best.prim) {  // t <= best.t holds: equal t -> smaller prim id
              best.t = t, best.u = u, best.v = v, best.prim = prim;
              best.kind = HitKind::triangle;
              ans.tri = bv.tris + i;
              ans.tri_block = bv.index;
              tmax = t;
              if constexpr (Any) return;
            }
          }
          break;
        }
        case kRefLink: {
          const Link& l = bv.links[idx];
          if (const std::byte* p = c.cache->get(l.block)) {
            bv.set(p);
            n = bv.nodes + l.node;
          } else if (c.on_missing == OnMissing::force) {
            if (pn->aux[ps] == kNoVoxel) throw_damaged_traversal(c, bv.index, "a link child has no voxel");
            if (pd <= tmax && pd < best.t) {
              voxel_hit(r, bv, *pn, ps, pd, true, best);
              ans.tri = nullptr;
              tmax = pd;
              if constexpr (Any) return;
            }
          } else {
            ans.deferred = true;
            if constexpr (Any) return;  // the first hit of a fully resident traversal is not known yet
          }
          break;
        }
        default: break;  // empty
      }
      pn = nullptr;
      if (n) continue;
    }
    // -- pop, culling entries beyond the best hit
    for (;;) {
      if (sp == 0) return;
      const Entry e = stack[--sp];
      if (!Any && e.d > tmax * kCullSlack) continue;
      if (e.block != bv.base) bv.set(e.block);
      pn = e.node;
      ps = e.slot;
      pd = e.d;
      break;
    }
  }
}

}  // namespace mbvh::lod::detail

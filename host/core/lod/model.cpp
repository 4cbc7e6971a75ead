// SPDX-License-Identifier: MIT
// model.cpp — lod::Model (mbvh/lod.h): a .mlod file behind its block cache (cache.h), traced ray
// batch by ray batch with traverse.h on the worker pool.
//
// Missing blocks. With LOD and asynchronous loading a ray never waits: a link to a block that is
// not resident is hit as its voxel (Hit::forced) and the block is requested (end_frame hands the
// requests to the I/O threads). At full detail, and with LOD in synchronous mode, such a ray is
// deferred instead: after the pass the requested blocks are loaded (BlockCache::fetch_requested)
// and the deferred rays are traced again from the root, until none is deferred. A ray's answer
// does not depend on which other blocks were resident (the closest hit is the lexicographic min of
// (t, prim) over what the traversal reaches; an any-hit ray stops at its first missing block), so
// the answers are the same at any thread count and any budget. When a round completes no ray
// within the model's block depth (the budget cannot hold what the deferred rays need at once),
// the rays are retraced in halves, down to one ray; one ray that cannot complete is an Error at
// full detail ("raise --memory") and takes the forced voxels in synchronous LOD mode.
#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <memory>
#include <mutex>

#include "host/core/lod/cache.h"
#include "host/core/lod/format.h"
#include "host/core/lod/traverse.h"
#include "host/core/parallel.h"
#include "mbvh/error.h"
#include "mbvh/lod.h"

namespace mbvh::lod {

namespace {

using detail::Entry;
using detail::OnMissing;
using detail::RayAnswer;
using detail::TraceContext;

/// The most binary levels a model may have (the stack of a traversal holds one entry a level).
constexpr std::uint32_t kMaxDepth = 4096;
/// Rays per work item of a trace pass.
constexpr std::size_t kChunk = 256;
/// The most triangles voxel_triangles collects (it is for tests of small subtrees).
constexpr std::size_t kMaxVoxelTriangles = std::size_t(1) << 24;

std::string hex(std::uint64_t v) {
  char b[32];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
  return b;
}

class ModelImpl final : public Model {
public:
  ModelImpl(const std::string& path, const CacheOptions& opt) : cache_(path, opt) {
    const format::FileHeader& h = cache_.header();
    const auto& dir = cache_.directory();
    if (h.depth > kMaxDepth)
      throw Error(path + ": the header's depth " + std::to_string(h.depth) + " exceeds " + std::to_string(kMaxDepth) +
                  " binary levels (a damaged header)");
    if (h.root_block >= dir.size())
      throw Error(path + ": the header's root block " + std::to_string(h.root_block) + " is not in the directory (" +
                  std::to_string(dir.size()) + " blocks)");
    root_ = cache_.get(h.root_block);
    if (!root_) throw Error(path + ": the root block " + std::to_string(h.root_block) + " is not resident after open (it must be pinned)");
    format::BlockHead bh;
    std::memcpy(&bh, root_, sizeof bh);
    if (h.root_node >= bh.treelets)
      throw Error(path + ": the header's root node " + std::to_string(h.root_node) + " is not a treelet root of block " +
                  std::to_string(h.root_block) + " (" + std::to_string(bh.treelets) + " treelets)");
    for (const auto& e : dir) max_block_depth_ = std::max<std::uint32_t>(max_block_depth_, e.depth);
    info_ = model_info(path, h);
    bounds_ = info_.bounds;
  }

  void trace(std::span<const Ray> rays, std::span<const RayCone> cones, const TraceOptions& opt, std::vector<Hit>& out,
             std::vector<Surface>* surfaces) override {
    if (!cones.empty() && cones.size() != rays.size())
      throw Error(cache_.path() + ": trace: " + std::to_string(cones.size()) + " ray cones for " + std::to_string(rays.size()) +
                  " rays (one per ray, or none)");
    if (opt.query != Query::closest && opt.query != Query::any)
      throw Error(cache_.path() + ": trace: an unknown query (TraceOptions::query)");
    if (std::isnan(opt.quality)) throw Error(cache_.path() + ": trace: the LOD quality is NaN (TraceOptions::quality)");
    out.assign(rays.size(), Hit{});
    if (surfaces) surfaces->assign(rays.size(), Surface{});
    if (rays.empty()) return;

    TraceContext c = context(opt);
    const bool sync = cache_.options().synchronous;
    c.on_missing = opt.lod && !sync ? OnMissing::force : OnMissing::defer;
    const bool any = opt.query == Query::any;

    std::vector<std::uint32_t> pending(rays.size());
    for (std::size_t i = 0; i < rays.size(); ++i) pending[i] = static_cast<std::uint32_t>(i);
    std::vector<std::uint8_t> deferred(rays.size(), 0);
    std::size_t group = pending.size();
    unsigned idle_rounds = 0;  // rounds in a row that completed no ray
    const unsigned patience = max_block_depth_ + 2;
    for (;;) {
      const std::size_t active = std::min(group, pending.size());
      pass(c, any, rays, cones, std::span<const std::uint32_t>(pending.data(), active), out, surfaces, deferred);
      std::vector<std::uint32_t> next;
      for (std::size_t k = 0; k < active; ++k)
        if (deferred[pending[k]]) next.push_back(pending[k]);
      const std::size_t completed = active - next.size();
      next.insert(next.end(), pending.begin() + static_cast<std::ptrdiff_t>(active), pending.end());
      pending.swap(next);
      if (pending.empty()) return;

      const std::uint64_t loads_before = cache_.stats().loads;
      load_requested(!opt.lod);
      const bool loaded = cache_.stats().loads != loads_before;
      if (completed > 0) {
        idle_rounds = 0;
        group = std::min(pending.size(), group * 2);
        continue;
      }
      if (loaded && ++idle_rounds <= patience) continue;  // the rays get one block deeper a round
      if (group > 1) {  // more than the budget holds at once: fewer rays a round
        group = std::max<std::size_t>(1, group / 2);
        idle_rounds = 0;
        continue;
      }
      // one ray (or no block to load) and still no answer
      if (!opt.lod) {
        const std::vector<std::uint32_t> damaged = cache_.damaged();
        if (!damaged.empty()) {
          const std::string why = cache_.damage(damaged.front());
          throw Error((why.empty() ? cache_.path() + ": block " + std::to_string(damaged.front()) + " is damaged" : why) +
                      ": full detail cannot be traced through it");
        }
        throw Error(cache_.path() + ": the budget of " + std::to_string(cache_.stats().budget) +
                    " bytes is too small to trace at full detail: ray " + std::to_string(pending.front()) +
                    " needs more blocks at once than fit beside the pinned ones (" + std::to_string(info_.pinned_bytes) +
                    " bytes; blocks up to " + std::to_string(info_.block_bytes) + " bytes); raise --memory");
      }
      // synchronous LOD: what cannot be loaded is replaced by its voxel, the finest LOD resident
      c.on_missing = OnMissing::force;
      pass(c, any, rays, cones, pending, out, surfaces, deferred);
      return;
    }
  }

  void end_frame() override { cache_.end_frame(); }
  void wait_idle() override { cache_.wait_idle(); }
  CacheStats stats() const override { return cache_.stats(); }
  ModelInfo info() const override { return info_; }
  const Box& bounds() const override { return bounds_; }
  std::uint64_t triangles() const override { return info_.triangles; }
  std::vector<Vec3f> albedos() const override { return cache_.albedos(); }
  std::vector<std::uint32_t> damaged_blocks() const override { return cache_.damaged(); }

  std::vector<Surface> voxel_triangles(std::uint64_t node) override {
    using namespace format;
    const auto& dir = cache_.directory();
    const auto block = static_cast<std::uint32_t>(node >> 32);
    const auto index = static_cast<std::uint32_t>((node & 0xffffffffu) >> 1);
    const unsigned slot = static_cast<unsigned>(node & 1u);
    const auto bad = [&](const std::string& why) {
      return Error(cache_.path() + ": voxel_triangles: node id " + hex(node) + ": " + why);
    };
    if (block >= dir.size()) throw bad("block " + std::to_string(block) + " is not in the directory");
    struct Item {
      std::uint32_t block, ref, count;
    };
    std::vector<Item> work;
    {
      detail::BlockView bv;
      bv.set(resident(block));
      format::BlockHead h;
      std::memcpy(&h, bv.base, sizeof h);
      if (index >= h.nodes) throw bad("node " + std::to_string(index) + " is not in block " + std::to_string(block));
      const Node& n = bv.nodes[index];
      work.push_back({block, n.ref[slot], n.aux[slot]});
    }
    std::vector<Surface> out;
    while (!work.empty()) {
      const Item it = work.back();
      work.pop_back();
      const std::uint32_t kind = it.ref & kRefKind, idx = it.ref & kRefIndex;
      if (kind == kRefEmpty) continue;
      detail::BlockView bv;
      bv.set(resident(it.block));  // valid until the next resident() call
      if (kind == kRefLink) {
        const Link l = bv.links[idx];
        work.push_back({l.block, kRefInner | l.node, 0});
      } else if (kind == kRefInner) {
        const Node& n = bv.nodes[idx];
        for (unsigned s = 0; s < 2; ++s) work.push_back({it.block, n.ref[s], n.aux[s]});
      } else {
        if (out.size() + it.count > kMaxVoxelTriangles)
          throw bad("the subtree holds more than " + std::to_string(kMaxVoxelTriangles) + " triangles");
        for (std::uint32_t i = idx; i < idx + it.count; ++i) {
          Surface s;
          const Tri& t = bv.tris[i];
          for (int k = 0; k < 3; ++k) s.v[k] = t.v0[k], s.v[3 + k] = t.v1[k], s.v[6 + k] = t.v2[k];
          out.push_back(s);
        }
      }
    }
    return out;
  }

private:
  TraceContext context(const TraceOptions& opt) {
    TraceContext c;
    c.cache = &cache_;
    c.root_block = root_;
    c.root_node = cache_.header().root_node;
    c.step_limit = cache_.header().nodes + 1;
    c.stack_entries = cache_.header().depth + 1;
    c.lod = opt.lod;
    c.quality = opt.quality;
    c.path = &cache_.path();
    return c;
  }

  // One pass over rays `which`: answers of completed rays into out (and surfaces), deferred[i]
  // set for the others.
  void pass(TraceContext& c, bool any, std::span<const Ray> rays, std::span<const RayCone> cones,
            std::span<const std::uint32_t> which, std::vector<Hit>& out, std::vector<Surface>* surfaces,
            std::vector<std::uint8_t>& deferred) {
    const auto& albedo = cache_.albedos();
    c.root_block = cache_.get(cache_.header().root_block);  // pinned: always resident
    if (!c.root_block) throw Error(cache_.path() + ": the pinned root block is not resident");
    parallel_for(which.size(), kChunk, cache_.options().threads, [&](std::size_t b, std::size_t e, unsigned) {
      std::vector<Entry> stack(c.stack_entries);
      for (std::size_t k = b; k < e; ++k) {
        const std::uint32_t i = which[k];
        RayPre r;
        RayAnswer ans;
        if (prepare_ray(rays[i], r)) {
          const RayCone* cone = cones.empty() ? nullptr : &cones[i];
          if (any) detail::trace_ray<true>(c, r, cone, stack.data(), ans);
          else detail::trace_ray<false>(c, r, cone, stack.data(), ans);
        }
        deferred[i] = ans.deferred ? 1 : 0;
        if (ans.deferred) continue;
        Hit& h = out[i];
        h = ans.hit;
        if (h.kind == HitKind::triangle) {
          const Tri& t = *ans.tri;
          std::uint32_t a;
          std::memcpy(&a, &t.v1[3], 4);
          if (albedo.empty()) h.albedo = {kDefaultAlbedo, kDefaultAlbedo, kDefaultAlbedo};
          else if (a < albedo.size()) h.albedo = albedo[a];
          else
            throw Error(cache_.path() + ": block " + std::to_string(ans.tri_block) + ": a triangle's albedo index " +
                        std::to_string(a) + " is beyond the table's " + std::to_string(albedo.size()) + " entries");
          if (surfaces) {
            Surface& s = (*surfaces)[i];
            for (int q = 0; q < 3; ++q) s.v[q] = t.v0[q], s.v[3 + q] = t.v1[q], s.v[6 + q] = t.v2[q];
          }
        }
      }
    });
  }

  // Loads the blocks the deferred rays asked for. A round ends a frame of the cache (end_frame:
  // in synchronous mode fetch_requested, otherwise the I/O threads, waited for): the blocks the
  // round used are then the most recently used, so making room evicts the blocks of rays already
  // answered before those of the rays still waiting (within one frame every block has the same
  // stamp and the retraced rays evicted each other's blocks). At full detail a block found
  // damaged is an Error naming it.
  void load_requested(bool throw_on_damage) {
    const std::size_t damaged_before = cache_.damaged().size();
    cache_.end_frame();
    cache_.wait_idle();
    if (!throw_on_damage) return;
    const std::vector<std::uint32_t> d = cache_.damaged();
    if (d.size() > damaged_before) {
      const std::string why = cache_.damage(d[damaged_before]);
      throw Error(why.empty() ? cache_.path() + ": block " + std::to_string(d[damaged_before]) + " is damaged" : why);
    }
  }

  // Block b resident, loading it (and the blocks above it) synchronously; the pointer is valid
  // until the next call.
  const std::byte* resident(std::uint32_t b) {
    const auto& dir = cache_.directory();
    std::vector<std::uint32_t> chain;  // b, its parent, ..., the root
    for (std::uint32_t x = b;; x = dir[x].parent_block) {
      chain.push_back(x);
      if (dir[x].parent_block == x || chain.size() > dir.size()) break;
    }
    for (unsigned round = 0; round <= chain.size() + 1; ++round) {
      const std::byte* p = nullptr;
      for (auto it = chain.rbegin(); it != chain.rend(); ++it) {
        p = cache_.get(*it);
        if (!p) break;  // requested; its children cannot load before it
      }
      if (p) return p;
      cache_.fetch_requested(true);
    }
    throw Error(cache_.path() + ": block " + std::to_string(b) + " cannot be made resident within the budget of " +
                std::to_string(cache_.stats().budget) + " bytes");
  }

  static constexpr float kDefaultAlbedo = 0.7f;  // the renderer's kAlbedo (host/tools/render.cpp)

  BlockCache cache_;
  const std::byte* root_ = nullptr;
  std::uint32_t max_block_depth_ = 0;
  Box bounds_;
  ModelInfo info_;
};

}  // namespace

std::unique_ptr<Model> Model::open(const std::string& path, const CacheOptions& opt) {
  return std::make_unique<ModelImpl>(path, opt);
}

bool is_model_file(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  char magic[sizeof format::kMagic] = {};
  if (!f.read(magic, sizeof magic)) return false;
  return std::memcmp(magic, format::kMagic, sizeof magic) == 0;
}

}  // namespace mbvh::lod

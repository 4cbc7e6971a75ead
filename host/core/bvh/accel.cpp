// SPDX-License-Identifier: MIT
// accel.cpp — Accel itself: Accel::build (the record pass, then the builder BuildOptions::quality
// names, the flattened tree, its triangles and statistics), the accessors, the hash and the
// layouts made on first use; sah_of_binary, the binary tree's SAH statistic (also Accel::load's).
#include <algorithm>
#include <chrono>
#include <cmath>
#include <mutex>
#include <string>

#include "host/core/bvh/builder.h"
#include "host/core/bvh/reinsert.h"
#include "host/core/bvh/sbvh.h"
#include "host/core/enum_check.h"
#include "host/core/huge_pages.h"
#include "host/core/layouts.h"
#include "host/core/resources.h"
#include "mbvh/error.h"

namespace mbvh {

namespace build {

double sah_of_binary(const Bvh2& b, const std::vector<Leaf>& leaves, float ct, unsigned threads) {
  const double root = b.nodes[0].box.half_area();
  if (!(root > 0)) return 0;
  return sum_in_runs(
      b.nodes.size(), [&](std::size_t i) { return ct * b.nodes[i].box.half_area() / root; }, leaves.size(),
      [&](std::size_t i) { return double(leaves[i].count) * b.leaf_boxes[i].half_area() / root; }, threads);
}

}  // namespace build

std::unique_ptr<Accel> Accel::build(const Scene& scene, const BuildOptions& opt_in) try {
  using build::PrimRef;
  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  // -- what the build is given: indices in range and finite vertices (checked by the record
  //    pass below, Scene::validate naming the first fault), a usable SAH cost
  check_enum(opt_in.quality, "Accel::build: " + scene.display_name(), "BuildOptions::quality");
  if (!scene.meshes().empty() && !scene.triangles.empty()) scene.validate();
  if (!std::isfinite(opt_in.traversal_cost) || opt_in.traversal_cost < 0)
    throw Error("BuildOptions::traversal_cost " + std::to_string(opt_in.traversal_cost) + " must be finite and >= 0");
  // the free heap returned once the build's temporaries below are gone (destroyed before this),
  // when it has grown by more than about two builds since the last release (release_free_heap_above):
  // a repeated build mostly reuses the pages the last one freed, and the heap's drift over many
  // (about one build's layouts a build on conference) is returned every few builds. Not with a
  // context: the caller keeps memory for the next build.
  struct ReleaseOnReturn {
    bool release;
    std::uint64_t build_bytes;
    ~ReleaseOnReturn() {
      if (release) release_free_heap_above(2 * build_bytes);
    }
  } release_on_return{!opt_in.context, build_memory_estimate(scene.triangle_count(), scene.vertices.size())};
  using S = build::BuildContext_Store;
  std::unique_ptr<Accel> acc(new Accel());
  acc->impl_->opt_ = opt_in;
  BuildOptions& opt = acc->impl_->opt_;
  opt.depth_cap = std::clamp(opt.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP));
  opt.max_leaf = std::max(opt.max_leaf, 1u);
  acc->impl_->scene_triangles_ = scene.triangle_count();
  acc->impl_->geometry_offsets_.resize(scene.geometry_count() + 1);
  for (std::size_t g = 0; g <= scene.geometry_count(); ++g) acc->impl_->geometry_offsets_[g] = scene.geometry_offset(g);
  auto report = [&opt](double f) {
    if (opt.progress) opt.progress(f);
  };

  // -- one record per non-degenerate (non-zero area) triangle, in scene order, the scene checked
  //    on the way (prim_refs.cpp)
  build::PrimRefs refs = build::make_prim_refs(scene, opt.threads, build::take_from(opt, &S::prims));
  build::RawVector<PrimRef>& prims = refs.prims;
  acc->impl_->bvh2_.degenerate = refs.degenerate;
  const auto t_prep = Clock::now();
  report(0.05);

  Bvh2& out = acc->impl_->bvh2_;
  auto t_tree = Clock::now();
  if (opt.quality == BuildQuality::none) {
    // -- no hierarchy: the records' triangles in scene order, their bounds the records' (the same
    //    box a tree's root gets); no tree, no statistics of one
    acc->impl_->tris_ = build::take_from(opt, &S::tris);
    acc->impl_->tris_.resize(prims.size());
    advise_huge_pages(acc->impl_->tris_.data(), prims.size() * sizeof(Tri));  // written in full
    build::fill_tris(scene, prims, acc->impl_->tris_, opt.threads);
    build::give_back(opt, &S::prims, prims);
    acc->impl_->bounds_ = refs.root.box();
    const auto t_flat = Clock::now();
    LayoutStats& st = acc->impl_->binary_stats_;
    st.layout = "none";
    st.bytes = acc->impl_->tris_.size() * sizeof(Tri);
    auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
    st.build_ms = ms(t0, t_flat);
    st.phase_ms[0] = ms(t0, t_prep);
    st.phase_ms[2] = ms(t_prep, t_flat);  // the triangle records, as a tree's flatten phase writes them
    report(1.0);
    return acc;
  }
  if (opt.quality == BuildQuality::high) {
    // -- spatial splits (sbvh.cpp): a triangle may sit in several leaves (never twice in one)
    std::vector<Box> boxes(scene.triangle_count());
    std::vector<std::uint32_t> idx(prims.size());
    for (std::size_t i = 0; i < prims.size(); ++i) {
      const PrimRef& r = prims[i];
      idx[i] = r.prim;
      boxes[r.prim].lo = {r.lo[0], r.lo[1], r.lo[2]};
      boxes[r.prim].hi = {r.hi[0], r.hi[1], r.hi[2]};
    }
    SbvhResult r = build_high(scene, opt, boxes, idx);  // with and without spatial splits, reinserted: the lower SAH
    t_tree = Clock::now();
    r.bvh.degenerate = out.degenerate;
    out = std::move(r.bvh);
    acc->impl_->leaves_ = std::move(r.leaves);
    build::give_back(opt, &S::prims, prims);
    acc->impl_->tris_ = build::take_from(opt, &S::tris);
    acc->impl_->tris_.resize(r.prims.size());
    advise_huge_pages(acc->impl_->tris_.data(), r.prims.size() * sizeof(Tri));  // written in full
    build::fill_tris(scene, r.prims, acc->impl_->tris_, opt.threads);
  } else {
    // -- the binary tree
    build::Arenas arenas = opt.context ? opt.context->impl().take_arenas() : build::Arenas();
    // the triangle records' array, written only after the tree, is the binned SAH's partition
    // array meanwhile (48 bytes a record there, 32 needed): no array of its own to fault in
    acc->impl_->tris_ = build::take_from(opt, &S::tris);
    acc->impl_->tris_.resize(prims.size());
    advise_huge_pages(acc->impl_->tris_.data(), prims.size() * sizeof(Tri));  // written in full
    static_assert(sizeof(Tri) >= sizeof(PrimRef) && alignof(Tri) % alignof(PrimRef) == 0);
    PrimRef* scratch = reinterpret_cast<PrimRef*>(static_cast<void*>(acc->impl_->tris_.data()));
    // the flattened tree's arrays (nodes, leaf boxes, leaves): the LBVH writes them as it builds,
    // the binned SAH's flatten after the records are given back (it can reuse their memory)
    auto take_tree_arrays = [&] {
      out.nodes = build::take_from(opt, &S::nodes);
      out.leaf_boxes = build::take_from(opt, &S::leaf_boxes);
      acc->impl_->leaves_ = build::take_from(opt, &S::leaves);
    };
    if (opt.quality == BuildQuality::low) {
      // -- the LBVH writes the flattened tree itself (leaves in record order), then the triangle
      //    records (the records are in leaf order once the tree is built)
      take_tree_arrays();
      build::build_lbvh(prims, refs.root, refs.croot, opt, arenas, out, acc->impl_->leaves_, scratch);
      t_tree = Clock::now();
      build::fill_tris(scene, prims, acc->impl_->tris_, opt.threads);
      build::give_back(opt, &S::prims, prims);
    } else {
      build::build_binned_sah(prims, refs.root, refs.croot, opt, arenas, scratch);
      t_tree = Clock::now();

      // -- the triangle records (the records are in leaf order once the tree is built), then the
      //    records' array freed: the flatten's arrays below can take its memory
      build::fill_tris(scene, prims, acc->impl_->tris_, opt.threads);
      build::give_back(opt, &S::prims, prims);

      // -- flatten depth-first; leaves come out in record order
      take_tree_arrays();
      build::flatten(arenas, out, acc->impl_->leaves_, opt.threads);
    }

    if (opt.context) opt.context->impl().give_arenas(std::move(arenas));
    arenas = build::Arenas();
  }
  acc->impl_->bounds_ = out.nodes[0].box;
  const auto t_flat = Clock::now();

  // -- statistics (the hash is made on first use: Accel::hash)
  LayoutStats& st = acc->impl_->binary_stats_;
  st.layout = "binary";
  st.nodes = out.nodes.size();
  st.leaves = acc->impl_->leaves_.size();
  st.depth = out.nodes[0].height;
  st.sah_cost = build::sah_of_binary(out, acc->impl_->leaves_, opt.traversal_cost, opt.threads);
  st.bytes = out.nodes.size() * sizeof(Bvh2::Node) + acc->impl_->leaves_.size() * (sizeof(Leaf) + sizeof(Box)) +
             acc->impl_->tris_.size() * sizeof(Tri);
  st.bitstack_bits = st.depth;
  if (st.depth > opt.depth_cap) throw Error("internal: binary depth " + std::to_string(st.depth) + " exceeds the cap");
  const auto t1 = Clock::now();
  auto ms = [](Clock::time_point a, Clock::time_point b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  st.build_ms = ms(t0, t1);
  st.phase_ms[0] = ms(t0, t_prep);
  st.phase_ms[1] = ms(t_prep, t_tree);
  st.phase_ms[2] = ms(t_tree, t_flat);
  st.phase_ms[3] = ms(t_flat, t1);
  report(1.0);
  return acc;
} catch (const std::bad_alloc&) {  // the build's arrays, beyond the scene: named, not a bare std::bad_alloc
  throw_out_of_memory(scene.display_name() + ": the BVH build of its " +
                          std::to_string(scene.triangle_count()) + " triangles",
                      build_memory_estimate(scene.triangle_count(), scene.vertices.size()));
}

Accel::Accel() : impl_(std::make_unique<Impl>()) {}

Accel::~Accel() {
  // a build's output arrays go back to its context (BuildContext), for the next build to reuse
  if (!impl_ || !impl_->opt_.context) return;
  using S = build::BuildContext_Store;
  const BuildOptions& o = impl_->opt_;
  build::give_back(o, &S::nodes, impl_->bvh2_.nodes);
  build::give_back(o, &S::leaf_boxes, impl_->bvh2_.leaf_boxes);
  build::give_back(o, &S::leaves, impl_->leaves_);
  build::give_back(o, &S::tris, impl_->tris_);
  build::give_back(o, &S::node4, impl_->mbvh4_.nodes);
}

BuildContext::BuildContext() : impl_(std::make_unique<Impl>()) {}
BuildContext::~BuildContext() = default;

std::size_t BuildContext::retained_bytes() const { return impl_->bytes(); }

void BuildContext::release() {
  std::lock_guard<std::mutex> lock(impl_->m);
  impl_->s = build::BuildContext_Store();
}

build::Arenas BuildContext::Impl::take_arenas() {
  std::lock_guard<std::mutex> lock(m);
  build::Arenas a = std::move(s.arenas);
  s.arenas = build::Arenas();
  a.upper.clear();
  a.subtree_of.clear();
  a.subtrees.clear();
  return a;
}

void BuildContext::Impl::give_arenas(build::Arenas&& a) {
  std::lock_guard<std::mutex> lock(m);
  s.arenas = std::move(a);  // the latest build's (its node block fits its scene)
  a = build::Arenas();
}

std::size_t BuildContext::Impl::bytes() const {
  std::lock_guard<std::mutex> lock(m);
  auto cap = [](const auto& v) { return v.capacity() * sizeof(typename std::decay_t<decltype(v)>::value_type); };
  std::size_t b = cap(s.prims) + cap(s.scratch) + cap(s.nodes) + cap(s.leaf_boxes) + cap(s.leaves) + cap(s.tris) +
                  cap(s.node4) + cap(s.arenas.upper) + cap(s.arenas.subtree_of) + cap(s.arenas.subtrees) +
                  s.arenas.block.capacity_bytes();
  return b;
}

bool Accel::has_hierarchy() const { return impl_->opt_.quality != BuildQuality::none; }

void Accel::require_hierarchy(const char* what) const {
  if (has_hierarchy()) return;
  throw Error(std::string("Accel::") + what +
              ": this build has no hierarchy (quality none): only the dacrt backend traces it; build with quality low, "
              "medium or high");
}

const Bvh2& Accel::bvh2() const {
  require_hierarchy("bvh2");
  return impl_->bvh2_;
}
const AlignedVector<Tri>& Accel::tris() const { return impl_->tris_; }
const std::vector<Leaf>& Accel::leaves() const {
  require_hierarchy("leaves");
  return impl_->leaves_;
}
std::size_t Accel::degenerate_triangles() const { return impl_->bvh2_.degenerate; }
const Box& Accel::bounds() const { return impl_->bounds_; }
std::size_t Accel::scene_triangles() const { return impl_->scene_triangles_; }
std::size_t Accel::geometry_count() const { return impl_->geometry_offsets_.size() - 1; }

GeomPrim Accel::geometry_of(std::uint32_t prim) const {
  const std::vector<std::uint64_t>& o = impl_->geometry_offsets_;
  if (prim >= o.back()) return {};
  const std::size_t g = geometry_index(o.data(), o.size() - 1, prim);
  return {static_cast<std::uint32_t>(g), static_cast<std::uint32_t>(prim - o[g])};
}
const LayoutStats& Accel::binary_stats() const { return impl_->binary_stats_; }
const BuildOptions& Accel::options() const { return impl_->opt_; }
std::uint64_t Accel::hash() const {
  if (!impl_->hash_known_.load(std::memory_order_acquire)) {
    std::lock_guard<std::mutex> lock(impl_->hash_m_);
    if (!impl_->hash_known_.load(std::memory_order_relaxed)) {
      impl_->hash_ = build::hash_build(impl_->bvh2_, impl_->leaves_, impl_->tris_, impl_->opt_.threads);
      impl_->hash_known_.store(true, std::memory_order_release);
    }
  }
  return impl_->hash_;
}
std::uint64_t Accel::generation() const { return impl_->generation_; }
double Accel::last_refit_ms() const { return impl_->refit_ms_; }

namespace {

template <class V>
std::size_t bytes_of(const V& v) {
  return v.size() * sizeof(typename V::value_type);
}
std::size_t tree_bytes(const Bvh2& b, const std::vector<Leaf>& leaves) {
  return bytes_of(b.nodes) + bytes_of(b.leaf_boxes) + bytes_of(leaves);
}

}  // namespace

Accel::MemoryStats Accel::memory() const {
  const Impl& m = *impl_;
  MemoryStats s;
  s.tree = tree_bytes(m.bvh2_, m.leaves_);
  s.nodes = bytes_of(m.mbvh2_.nodes) + bytes_of(m.mbvh4_.nodes) + bytes_of(m.mbvh8_.nodes) + bytes_of(m.mbvh4w_.nodes);
  s.triangles = bytes_of(m.tris_);
  s.packs = bytes_of(m.packs_.packs) + bytes_of(m.packs_.leaves) + m.packs_.mt_bytes();
  std::lock_guard<std::mutex> lock(m.variants_m_);
  for (const auto& [block, v] : m.variants_) {
    const LeafVariant::Bytes b = v->bytes();
    s.nodes += b.nodes;
    s.packs += b.packs;
  }
  return s;
}

const Mbvh2& Accel::mbvh2() const {
  require_hierarchy("mbvh2");
  std::call_once(impl_->once2_, [this] {
    impl_->mbvh2_ = make_mbvh2(impl_->bvh2_, impl_->leaves_);
  });
  return impl_->mbvh2_;
}

void Accel::make_layout(Layout l) const {
  check_enum(l, "Accel::make_layout", "the layout");
  require_hierarchy("make_layout");
  if (l == Layout::mbvh2) mbvh2();
  else if (l == Layout::mbvh4) mbvh4();
  else mbvh8();
}

const Mbvh8& Accel::mbvh8() const {
  require_hierarchy("mbvh8");
  std::call_once(impl_->once8_, [this] {
    impl_->mbvh8_ = make_mbvh8(impl_->bvh2_, impl_->leaves_, impl_->opt_.threads);
  });
  return impl_->mbvh8_;
}

const Mbvh4& Accel::mbvh4() const {
  require_hierarchy("mbvh4");
  std::call_once(impl_->once4_, [this] {
    // the nodes in the context's array where there is one (taken empty, every node written)
    impl_->mbvh4_ = build::make_mbvh4(impl_->bvh2_, impl_->leaves_, impl_->opt_.threads,
                                      build::take_from(impl_->opt_, &build::BuildContext_Store::node4));
  });
  return impl_->mbvh4_;
}

const TriPacks& Accel::tri_packs() const {
  require_hierarchy("tri_packs");
  std::call_once(impl_->oncep_, [this] {
    impl_->packs_ = make_tri_packs(impl_->tris_, impl_->leaves_);
  });
  return impl_->packs_;
}

const Mbvh4Wide& Accel::mbvh4_wide() const {
  require_hierarchy("mbvh4_wide");
  std::call_once(impl_->once4w_, [this] { impl_->mbvh4w_ = make_mbvh4_wide(mbvh4()); });
  return impl_->mbvh4w_;
}

}  // namespace mbvh

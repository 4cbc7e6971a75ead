// SPDX-License-Identifier: MIT
// tinybvh_backend.cpp — the `tinybvh` peer backend: tinybvh 1.6.7's CPU layouts (jbikker/tinybvh,
// MIT, a single header; ../shared/peers/tinybvh), the fastest open single-header CPU BVH library,
// built from the same triangles and traced on the same rays and threads, so `mbvh bench` times it
// beside the cpu backend and Embree in one run and `mbvh check` uses it as one more witness.
//
// Its layouts answer under mbvh's labels of the same width: `--layout mbvh8` is tinybvh's
// BVH8_CPU (8-wide nodes, AVX2 + FMA), `--layout mbvh4` its BVH4_CPU (4-wide, SSE), both with
// 4-triangle leaves, each built by tinybvh's default builder (binned SAH, then its collapse) from
// the build's triangles, each prim once; traversal `stack` (its ordered single-ray stack
// traversal: Intersect, IsOccluded). Its triangle test is Möller–Trumbore with an approximate
// reciprocal, not watertight, so it runs in `--precision fast` only (the peer of the cpu
// backend's fast mode and of `embree --precision fast`): its answers are compared, and its misses
// counted, not required to be bit-identical. tinybvh has no tmin: a ray starts at o + tmin d
// (tinybvh_kernels.cpp). No per-ray counters; its stack is its own (state B 0).
//
// The library is compiled in one translation unit for AVX2 + FMA (tinybvh_kernels.cpp); this one
// is portable code, and the backend starts only on a CPU with AVX2 and FMA.
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "backends/common/build_stamp.h"
#include "backends/tinybvh/tinybvh_backends.h"
#include "backends/tinybvh/tinybvh_kernels.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/intersect.h"  // tri_prim
#include "mbvh/backend.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

/// Whether this CPU runs tinybvh's kernels: AVX2 and FMA.
bool has_avx2_fma() { return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma"); }

/// The tinybvh.build setting: default (its Build: binned SAH) or hq (its BuildHQ: spatial
/// splits); anything else refused by name.
bool tinybvh_hq(const BackendOptions& o) {
  const std::string v = o.get("tinybvh.build", "default");
  if (v == "default" || v == "hq") return v == "hq";
  throw Error("backend setting tinybvh.build='" + v + "': expected default or hq (tinybvh's Build or BuildHQ)");
}

class TinybvhBackend final : public Backend {
public:
  explicit TinybvhBackend(const BackendOptions& o) : threads_(resolve_threads(o.threads)), hq_(tinybvh_hq(o)) {}

  std::string name() const override { return "tinybvh"; }
  std::string describe() const override {
    return std::string("tinybvh: tinybvh 1.6.7 BVH8_CPU (--layout mbvh8) and BVH4_CPU (--layout mbvh4), "
                       "Intersect/IsOccluded (Moeller-Trumbore, not watertight: --precision fast), built by ") +
           (hq_ ? "BuildHQ (spatial splits)" : "Build (binned SAH)") + ", " + std::to_string(threads_) + " thread(s)";
  }
  /// Only `fast`: tinybvh's test is not watertight (robust and exact are mbvh's contracts).
  bool supports_precision(Precision p) const override { return p == Precision::fast; }
  /// mbvh8 = BVH8_CPU, mbvh4 = BVH4_CPU; its one traversal, a stack.
  bool supports(Layout l, Traversal t) const override {
    return (l == Layout::mbvh8 || l == Layout::mbvh4) && t == Traversal::stack;
  }
  std::vector<std::pair<Layout, Traversal>> fastest(Query) const override {
    return {{Layout::mbvh8, Traversal::stack}, {Layout::mbvh4, Traversal::stack}};
  }
  bool peer() const override { return true; }
  std::size_t state_bytes(const TraceOptions&) const override { return 0; }

  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    if (built_.stale(acc)) {  // both layouts' trees are stale
      tree_[0].reset();
      tree_[1].reset();
      built_ = {};
    }
    const int w = width_index(opt.layout);
    if (tree_[w] || acc.tris().empty()) {
      built_.mark(acc);
      return;
    }
    // each prim once (a --quality high build repeats split triangles), in the build's leaf order
    const auto& all = acc.tris();
    const bool repeats = all.size() + acc.bvh2().degenerate > acc.scene_triangles();
    std::vector<std::uint8_t> seen(repeats ? acc.scene_triangles() : 0, 0);
    std::vector<float> xyz;
    std::vector<std::uint32_t> prims;
    xyz.reserve(9 * all.size());
    prims.reserve(all.size());
    for (const Tri& t : all) {
      const std::uint32_t prim = tri_prim(t);
      if (repeats) {
        if (seen[prim]) continue;
        seen[prim] = 1;
      }
      for (const float* v : {t.v0, t.v1, t.v2}) xyz.insert(xyz.end(), v, v + 3);
      prims.push_back(prim);
    }
    tree_[w] = tinybvh_peer::build_tree(w == 1 ? tinybvh_peer::Width::bvh8 : tinybvh_peer::Width::bvh4, hq_, xyz,
                                        std::move(prims));
    built_.mark(acc);
  }

  void trace_batch(const Accel&, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    out.reset(rays.size(), opt);  // hits only are written: every other ray stays a miss
    const tinybvh_peer::Tree* tree = tree_[width_index(opt.layout)].get();
    const bool any = opt.query == Query::any;
    std::vector<std::size_t> invalid(threads_, 0);  // per worker
    parallel_for(rays.size(), kTraceChunk, threads_, [&](std::size_t b, std::size_t e, unsigned worker) {
      if (!tree) {  // no triangles: every ray misses; the invalid ones are still counted
        for (std::size_t i = b; i < e; ++i) invalid[worker] += ray_valid(rays[i]) ? 0 : 1;
        return;
      }
      if (any) tree->any(rays, b, e, out.occluded.data(), invalid[worker]);
      else tree->closest(rays, b, e, out.hits.data(), invalid[worker]);
    });
    for (std::size_t n : invalid) out.invalid += n;
  }

private:
  static int width_index(Layout l) { return l == Layout::mbvh8 ? 1 : 0; }

  unsigned threads_;
  bool hq_;  ///< tinybvh.build=hq
  std::unique_ptr<tinybvh_peer::Tree> tree_[2];  // BVH4_CPU, BVH8_CPU
  BuildStamp built_;  // the build the trees are of
};

}  // namespace

void register_tinybvh_backend() {
  BackendInfo info;
  info.name = "tinybvh";
  info.summary = "peer: tinybvh 1.6.7 BVH8_CPU (--layout mbvh8) / BVH4_CPU (mbvh4) Intersect/IsOccluded, not watertight "
                 "(--precision fast only)";
  info.make = [](const BackendOptions& o) -> std::unique_ptr<Backend> {
    if (!has_avx2_fma()) throw Error("backend 'tinybvh' cannot start: this CPU has no AVX2 and FMA");
    return std::make_unique<TinybvhBackend>(o);
  };
  info.missing_hardware = [] { return has_avx2_fma() ? std::string() : std::string("this CPU has no AVX2 and FMA"); };
  info.settings = {{"tinybvh.build", "tinybvh's builder: default (Build: binned SAH, the default) or hq (BuildHQ: "
                                     "spatial splits)"}};
  register_backend(std::move(info));
}

}  // namespace mbvh

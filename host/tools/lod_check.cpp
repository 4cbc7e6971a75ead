// SPDX-License-Identifier: MIT
// lod_check.cpp — the check behind `mbvh lod check`: a model's full-detail answers against
// cpu-scalar's and the brute force's on the in-core build of the same triangles, classified as
// run_check (check.cpp) classifies a backend's.
#include "host/tools/lod_check.h"

#include <cstdio>

#include "host/core/parallel.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"

namespace mbvh {

namespace {

std::string hex(std::uint64_t v) {
  char b[32];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(v));
  return b;
}

}  // namespace

std::size_t LodCheckReport::failures() const {
  std::size_t f = 0;
  for (const auto& k : kinds) f += k.report.mismatches() + k.leaks;
  return f;
}

std::string LodCheckReport::text(const std::vector<std::vector<Ray>>& rays) const {
  std::string s;
  char line[512];
  for (std::size_t i = 0; i < kinds.size(); ++i) {
    const LodCheckKind& k = kinds[i];
    std::snprintf(line, sizeof line, "== %s against %s: %s rays\n", model.c_str(), source.c_str(), to_string(k.kind));
    s += line;
    s += k.report.table(i < rays.size() ? std::span<const Ray>(rays[i]) : std::span<const Ray>());
    std::snprintf(line, sizeof line, "bit-identical to cpu-scalar: %zu of %zu closest hits (%.4f %%)\n", k.bit_identical,
                  k.compared, 100.0 * k.bit_identical_share());
    s += line;
    if (k.kind == RayKind::inside) {
      std::snprintf(line, sizeof line, "leaks (valid rays from inside the closed mesh that hit nothing): %zu (cpu-scalar: %zu)\n",
                    k.leaks, k.reference_leaks);
      s += line;
    }
    s += "\n";
  }
  std::snprintf(line, sizeof line, "cache: %llu loads, %llu evictions, peak %llu of %llu bytes\n",
                static_cast<unsigned long long>(cache.loads), static_cast<unsigned long long>(cache.evictions),
                static_cast<unsigned long long>(cache.peak_bytes), static_cast<unsigned long long>(cache.budget));
  s += line;
  const std::size_t f = failures();
  s += f == 0 ? "result: zero genuine mismatches, no leak\n" : "result: " + std::to_string(f) + " genuine mismatches or leaks\n";
  return s;
}

void check_model_source(const lod::Model& model, const lod::TriangleSource& src) {
  const lod::ModelInfo in = model.info();
  if (in.source_hash != src.hash() || in.triangles != src.count())
    throw Error(in.path + " was built from another source: its header records " + std::to_string(in.triangles) +
                " triangles with source hash " + hex(in.source_hash) + ", while " + src.name() + " has " +
                std::to_string(src.count()) + " triangles with hash " + hex(src.hash()));
}

LodCheckReport run_lod_check(lod::Model& model, const Scene& scene, const Accel& acc, const LodCheckOptions& opt,
                             std::vector<std::vector<Ray>>* rays_out, const std::function<void(const std::string&)>& log) {
  LodCheckReport rep;
  rep.model = model.info().path;
  rep.source = scene.name;
  rep.triangles = model.triangles();
  const unsigned threads = opt.cache.threads;
  for (const RayKind kind : opt.kinds) {
    LodCheckKind k;
    k.kind = kind;
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = opt.count;
    ro.seed = opt.seed;
    ro.threads = threads;
    if (log) log(std::string("generating ") + to_string(kind) + " rays");
    const std::vector<Ray> rays = generate_rays(scene, acc, ro);
    CheckReport& cr = k.report;
    cr.rays = rays.size();
    for (const Ray& r : rays) cr.invalid += ray_valid(r) ? 0 : 1;

    // -- the model at full detail, and cpu-scalar
    if (log) log("tracing the model at full detail");
    lod::TraceOptions lc;
    lc.lod = false;
    std::vector<lod::Hit> lh, la;
    model.trace(rays, {}, lc, lh);
    lc.query = Query::any;
    model.trace(rays, {}, lc, la);
    std::vector<Hit> mc(rays.size());
    std::vector<std::uint8_t> mo(rays.size()), mc_occ(rays.size());
    for (std::size_t i = 0; i < rays.size(); ++i) {
      if (lh[i].kind == lod::HitKind::voxel || la[i].kind == lod::HitKind::voxel)
        throw Error(rep.model + ": ray " + std::to_string(i) + " hit a voxel at full detail");
      mc[i] = lh[i].plain();
      mo[i] = la[i].kind == lod::HitKind::triangle ? 1 : 0;
      mc_occ[i] = mc[i].prim != MBVH_MISS_PRIM ? 1 : 0;
    }
    if (log) log("tracing cpu-scalar");
    TraceOutput rc, ra;
    TraceOptions to;
    trace_reference(acc, rays, to, rc, threads);
    to.query = Query::any;
    trace_reference(acc, rays, to, ra, threads);

    // -- brute force on a spread subset
    const std::vector<std::size_t> sub = spread_indices(rays.size(), opt.brute_rays);
    cr.brute_rays = sub.size();
    std::vector<Hit> brute(sub.size());
    if (log && !sub.empty()) log("brute force on " + std::to_string(sub.size()) + " rays");
    parallel_for(sub.size(), 16, threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) brute[i] = brute_force(acc, rays[sub[i]]);
    });
    std::vector<std::uint8_t> brute_occ(brute.size());
    for (std::size_t i = 0; i < brute.size(); ++i) brute_occ[i] = brute[i].prim != MBVH_MISS_PRIM;

    // -- the rules of run_check: the oracle's ties, and float differences settled by the oracle
    const TieRule oracle = oracle_tie_rule(acc, rays);
    const TieRule settle_hits = oracle_settlement(acc, rays, oracle);
    const auto occlusion_legit = [&](std::uint8_t flag, const std::vector<Hit>* own, std::size_t ray, const Hit& o) {
      if ((flag != 0) == (o.prim != MBVH_MISS_PRIM)) return true;
      if (o.prim != MBVH_MISS_PRIM && compare_occlusion(1, 0, o, rays[ray]) == Verdict::tie) return true;
      if (!flag || !own) return false;
      const Hit& h = (*own)[ray];
      return h.prim != MBVH_MISS_PRIM && (compare_hits(h, o) != Verdict::mismatch || oracle(ray, h, o));
    };
    const auto settle_occlusion = [&](const std::vector<std::uint8_t>& a, const std::vector<Hit>* own_a,
                                      const std::vector<std::uint8_t>& b, const std::vector<Hit>* own_b) -> TieRule {
      return [&, own_a, own_b](std::size_t ray, const Hit&, const Hit&) {
        const Hit o = brute_force(acc, rays[ray]);
        return occlusion_legit(a[ray], own_a, ray, o) && occlusion_legit(b[ray], own_b, ray, o);
      };
    };
    const std::string model_c = "lod/full-detail/closest", model_a = "lod/full-detail/any";
    const std::string ref_c = "cpu-scalar/closest", ref_a = "cpu-scalar/any";
    const auto add = [&](Comparison c, const std::string& a, const std::string& b) {
      c.a = a;
      c.b = b;
      cr.comparisons.push_back(std::move(c));
    };
    // against cpu-scalar, every ray
    Comparison cc = compare_hit_arrays(mc, rc.hits, {}, settle_hits);
    k.bit_identical = cc.bit_identical;
    k.compared = cc.rays;
    add(std::move(cc), model_c, ref_c);
    add(compare_occlusion_arrays(mo, ra.occluded, rc.hits, rays, {}, {}, settle_occlusion(mo, &mc, ra.occluded, &rc.hits)),
        model_a, ref_a);
    add(compare_occlusion_arrays(mo, mc_occ, rc.hits, rays, {}, {}, settle_occlusion(mo, &mc, mc_occ, &mc)), model_a,
        "occluded = closest hit exists");
    // against the brute force, on the subset: the model and the reference
    if (!sub.empty()) {
      std::vector<Hit> float_closest;
      for (std::size_t i : sub) float_closest.push_back(rc.hits[i]);
      const auto against_brute = [&](const std::vector<Hit>& hits, const std::vector<std::uint8_t>& occ,
                                     const std::string& lc_label, const std::string& la_label) {
        std::vector<Hit> h;
        std::vector<std::uint8_t> o;
        for (std::size_t i : sub) h.push_back(hits[i]), o.push_back(occ[i]);
        add(compare_hit_arrays(h, brute, sub, oracle), lc_label, "brute force (double)");
        const TieRule any_tie = [&, own = &hits](std::size_t ray, const Hit& fc, const Hit& oracle_hit) {
          return oracle(ray, fc, oracle_hit) || occlusion_legit(occ[ray], own, ray, oracle_hit);
        };
        add(compare_occlusion_arrays(o, brute_occ, brute, rays, sub, float_closest, any_tie), la_label, "brute force (double)");
      };
      against_brute(mc, mo, model_c, model_a);
      against_brute(rc.hits, ra.occluded, ref_c, ref_a);
    }
    // leaks: inside rays of a closed mesh that hit nothing
    if (kind == RayKind::inside)
      for (std::size_t i = 0; i < rays.size(); ++i)
        if (ray_valid(rays[i])) {
          k.leaks += mc[i].prim == MBVH_MISS_PRIM;
          k.reference_leaks += rc.hits[i].prim == MBVH_MISS_PRIM;
        }
    rep.kinds.push_back(std::move(k));
    if (rays_out) rays_out->push_back(rays);
  }
  rep.cache = model.stats();
  return rep;
}

}  // namespace mbvh

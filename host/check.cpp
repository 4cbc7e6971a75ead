// check.cpp — the cross-check behind `mbvh check` and the equivalence tests.
#include "host/check.h"

#include <cstdio>
#include <map>
#include <memory>

#include "host/backend.h"
#include "host/error.h"
#include "host/parallel.h"

namespace mbvh {

std::string CheckVariant::label() const {
  return backend + "/" + to_string(opt.layout) + "/" + to_string(opt.traversal) + "/" + to_string(opt.query);
}

std::size_t CheckReport::mismatches() const {
  std::size_t m = 0;
  for (const auto& c : comparisons) m += c.mismatches;
  return m;
}

std::vector<std::size_t> spread_indices(std::size_t n, std::size_t k) {
  std::vector<std::size_t> idx;
  if (k >= n) {
    for (std::size_t i = 0; i < n; ++i) idx.push_back(i);
    return idx;
  }
  for (std::size_t i = 0; i < k; ++i) idx.push_back(static_cast<std::size_t>(static_cast<double>(i) * static_cast<double>(n) / static_cast<double>(k)));
  return idx;
}

TieRule oracle_tie_rule(const Accel& acc, std::span<const Ray> rays) {
  auto prim_to_tri = std::make_shared<std::vector<std::uint32_t>>(acc.scene_triangles(), UINT32_MAX);
  for (std::size_t i = 0; i < acc.tris().size(); ++i) (*prim_to_tri)[tri_prim(acc.tris()[i])] = static_cast<std::uint32_t>(i);
  return [&acc, rays, prim_to_tri](std::size_t ray, const Hit& a, const Hit& oracle) {
    if (a.prim == MBVH_MISS_PRIM || oracle.prim == MBVH_MISS_PRIM || a.prim >= prim_to_tri->size()) return false;
    RayPre r;
    if (!prepare_ray(rays[ray], r)) return false;
    const double t = plane_t_double(r, acc.tris()[(*prim_to_tri)[a.prim]]);
    return ulp_distance(static_cast<float>(t), oracle.t) <= 4;
  };
}

std::string CheckReport::table(std::span<const Ray> batch) const {
  std::string s;
  char line[512];
  std::snprintf(line, sizeof line, "%zu rays (%zu invalid, defined misses), %zu checked by brute force\n", this->rays,
                invalid, brute_rays);
  s += line;
  std::snprintf(line, sizeof line, "%-34s %-34s %9s %9s %6s %10s %9s %6s\n", "answer", "compared with", "rays", "equal",
                "ties", "mismatch", "bit-same", "t-ulp");
  s += line;
  for (const auto& c : comparisons) {
    std::snprintf(line, sizeof line, "%-34s %-34s %9zu %9zu %6zu %10zu %9zu %6u\n", c.a.c_str(), c.b.c_str(), c.rays, c.equal,
                  c.ties, c.mismatches, c.bit_identical, c.max_t_ulps);
    s += line;
  }
  for (const auto& c : comparisons)
    for (std::size_t i : c.first_mismatches) {
      const Ray& r = batch[i];
      std::snprintf(line, sizeof line,
                    "  mismatch %s vs %s: ray %zu o=(%.9g %.9g %.9g) d=(%.9g %.9g %.9g) t=[%.9g, %.9g]\n", c.a.c_str(),
                    c.b.c_str(), i, r.ox, r.oy, r.oz, r.dx, r.dy, r.dz, r.tmin, r.tmax);
      s += line;
    }
  s += mismatches() == 0 ? "result: zero genuine mismatches\n" : "result: " + std::to_string(mismatches()) + " genuine mismatches\n";
  return s;
}

CheckReport run_check(const Accel& acc, std::span<const Ray> rays, const CheckOptions& opt,
                      const std::function<void(const std::string&)>& log) {
  CheckReport rep;
  rep.rays = rays.size();
  for (const Ray& r : rays) rep.invalid += ray_valid(r) ? 0 : 1;
  BackendOptions bo;
  bo.threads = opt.threads;
  std::map<std::string, std::unique_ptr<Backend>> backends;
  for (const auto& name : opt.grid.backends) backends[name] = make_backend(name, bo);

  // -- run every variant
  struct Run {
    CheckVariant v;
    TraceOutput out;
  };
  std::vector<Run> runs;
  for (Query q : opt.grid.queries)
    for (const auto& name : opt.grid.backends)
      for (Layout l : opt.grid.layouts)
        for (Traversal t : opt.grid.traversals) {
          Run run;
          run.v.backend = name;
          run.v.opt.layout = l;
          run.v.opt.traversal = t;
          run.v.opt.query = q;
          Backend& b = *backends[name];
          if (!b.supports(l, t)) throw Error("backend '" + name + "' does not support " + to_string(l) + "/" + to_string(t));
          if (log) log("tracing " + run.v.label());
          b.trace(acc, rays, run.v.opt, run.out);
          runs.push_back(std::move(run));
        }

  // -- brute force on a spread subset
  const std::vector<std::size_t> sub = spread_indices(rays.size(), opt.brute_rays);
  rep.brute_rays = sub.size();
  std::vector<Hit> brute(sub.size());
  if (!sub.empty()) {
    if (log) log("brute force on " + std::to_string(sub.size()) + " rays");
    parallel_for(sub.size(), 16, opt.threads, [&](std::size_t b, std::size_t e, unsigned) {
      for (std::size_t i = b; i < e; ++i) brute[i] = brute_force(acc, rays[sub[i]]);
    });
  }
  std::vector<Ray> sub_rays;
  for (std::size_t i : sub) sub_rays.push_back(rays[i]);

  // -- compare
  const Run* ref_closest = nullptr;
  const Run* ref_any = nullptr;
  for (const Run& r : runs) {
    if (r.v.opt.query == Query::closest && !ref_closest) ref_closest = &r;
    if (r.v.opt.query == Query::any && !ref_any) ref_any = &r;
  }
  auto label = [](const Run& r) { return r.v.label(); };
  std::vector<Hit> closest_for_any;  // classification help for any-hit differences
  if (ref_closest) closest_for_any = ref_closest->out.hits;
  else if (ref_any) {
    TraceOutput o;
    TraceOptions c;
    trace_reference(acc, rays, c, o, opt.threads);
    closest_for_any = std::move(o.hits);
  }
  std::vector<std::uint8_t> closest_occ(closest_for_any.size());
  for (std::size_t i = 0; i < closest_for_any.size(); ++i) closest_occ[i] = closest_for_any[i].prim != MBVH_MISS_PRIM;
  std::vector<std::uint8_t> brute_occ(brute.size());
  for (std::size_t i = 0; i < brute.size(); ++i) brute_occ[i] = brute[i].prim != MBVH_MISS_PRIM;

  for (const Run& r : runs) {
    const bool any = r.v.opt.query == Query::any;
    const Run* ref = any ? ref_any : ref_closest;
    // against the reference variant, all rays
    if (&r != ref) {
      Comparison c = any ? compare_occlusion_arrays(r.out.occluded, ref->out.occluded, closest_for_any, rays)
                         : compare_hit_arrays(r.out.hits, ref->out.hits);
      c.a = label(r);
      c.b = label(*ref);
      rep.comparisons.push_back(std::move(c));
    }
    // any hit against closest hit: occluded iff a closest hit exists
    if (any) {
      Comparison c = compare_occlusion_arrays(r.out.occluded, closest_occ, closest_for_any, rays);
      c.a = label(r);
      c.b = "occluded = closest hit exists";
      rep.comparisons.push_back(std::move(c));
    }
    // against brute force, on the subset
    if (!sub.empty()) {
      std::vector<Hit> h;
      std::vector<std::uint8_t> o;
      for (std::size_t i : sub) {
        if (any) o.push_back(r.out.occluded[i]);
        else h.push_back(r.out.hits[i]);
      }
      Comparison c = any ? compare_occlusion_arrays(o, brute_occ, brute, rays, sub)
                         : compare_hit_arrays(h, brute, sub, oracle_tie_rule(acc, rays));
      c.a = label(r);
      c.b = "brute force (double)";
      rep.comparisons.push_back(std::move(c));
    }
  }
  return rep;
}

}  // namespace mbvh

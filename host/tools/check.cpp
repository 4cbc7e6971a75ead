// SPDX-License-Identifier: MIT
// check.cpp — the cross-check behind `mbvh check` and the equivalence tests.
#include "host/tools/check.h"

#include <cmath>
#include <cstdio>
#include <map>
#include <memory>

#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "host/core/layouts.h"
#include "host/core/parallel.h"
#include "host/core/trace/traverse.h"
#include "host/tools/variants.h"

namespace mbvh {

std::string CheckVariant::label() const {
  return backend + "/" + layout_label(opt) + "/" + to_string(opt.traversal) + "/" + to_string(opt.query) +
         (opt.precision == Precision::robust ? "" : std::string("/") + to_string(opt.precision));
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

namespace {

double norm3(const double v[3]) { return std::sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2]); }
double max_abs3(const float v[3]) { return std::max(std::fabs(v[0]), std::max(std::fabs(v[1]), std::fabs(v[2]))); }

// |cos| of the angle between the ray and the triangle's normal, and whether the ray lies in the
// plane within the rounding of its own direction (the first case of ill_conditioned). A
// direction built as a difference of float points of size |o| (a camera target, a light, a hit
// point), L apart, is good to about 2^-24 |o| / L radians; L is at least the distance from the
// origin to the triangle's nearest vertex, so that distance bounds the slack. (Dividing by |d|
// instead, as this did before, made every ray of a scene at 1e30 "in plane": lost hits became
// ties.)
bool in_plane(const RayPre& r, const Tri& t, double& cosine) {
  const float* P[3] = {t.v0, t.v1, t.v2};
  double e1[3], e2[3];
  for (int k = 0; k < 3; ++k) {
    e1[k] = double(P[1][k]) - P[0][k];
    e2[k] = double(P[2][k]) - P[0][k];
  }
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  const double d[3] = {r.d[0], r.d[1], r.d[2]};
  const double nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
  const double dlen = norm3(d);
  cosine = std::fabs(nd) / (norm3(n) * dlen);
  double near = INFINITY;
  for (const float* p : P) {
    const double w[3] = {double(p[0]) - r.o[0], double(p[1]) - r.o[1], double(p[2]) - r.o[2]};
    near = std::min(near, norm3(w));
  }
  const double slack = 0x1p-20 + 8 * 0x1p-24 * (max_abs3(r.o) / near + 1.0);
  return !(cosine > slack);
}

// True where float and double may legitimately disagree about hitting triangle t:
// - the ray lies in the triangle's plane within the rounding of its own direction (a direction
//   built as a difference of floats of size |o| is only good to 2^-24 |o| / |d| radians);
// - the ray crosses the plane within a few ulps (of the coordinates' size) of an edge line,
//   measured as a distance (barycentrics cannot: on a needle b = 0.002 was 2e-9 from the edge)
//   and widened by 1/cos, as the crossing point of a grazing float ray moves by ulps / cos.
bool ill_conditioned(const RayPre& r, const Tri& t) {
  const float* P[3] = {t.v0, t.v1, t.v2};
  double cosine = 0;
  if (in_plane(r, t, cosine)) return true;
  const double d[3] = {r.d[0], r.d[1], r.d[2]};
  const double th = plane_t_double(r, t);
  const double scale = std::max({max_abs3(r.o), max_abs3(P[0]), max_abs3(P[1]), max_abs3(P[2])});
  const double p[3] = {r.o[0] + th * d[0], r.o[1] + th * d[1], r.o[2] + th * d[2]};
  for (int k = 0; k < 3; ++k) {  // distance from p to the line through edge (P[k], P[k+1])
    const float* a = P[k];
    const float* b = P[(k + 1) % 3];
    const double ab[3] = {double(b[0]) - a[0], double(b[1]) - a[1], double(b[2]) - a[2]};
    const double ap[3] = {p[0] - a[0], p[1] - a[1], p[2] - a[2]};
    const double c[3] = {ap[1] * ab[2] - ap[2] * ab[1], ap[2] * ab[0] - ap[0] * ab[2], ap[0] * ab[1] - ap[1] * ab[0]};
    const double len = norm3(ab);
    if (len > 0 && norm3(c) / len <= 16 * 0x1p-24 * scale / cosine) return true;
  }
  return false;
}


// The build's triangle of a hit (null for a miss or an unknown prim).
std::function<const Tri*(const Hit&)> tri_lookup(const Accel& acc) {
  auto prim_to_tri = std::make_shared<std::vector<std::uint32_t>>(acc.scene_triangles(), UINT32_MAX);
  for (std::size_t i = 0; i < acc.tris().size(); ++i) (*prim_to_tri)[tri_prim(acc.tris()[i])] = static_cast<std::uint32_t>(i);
  return [&acc, prim_to_tri](const Hit& h) -> const Tri* {
    if (h.prim == MBVH_MISS_PRIM || h.prim >= prim_to_tri->size() || (*prim_to_tri)[h.prim] == UINT32_MAX) return nullptr;
    return &acc.tris()[(*prim_to_tri)[h.prim]];
  };
}

}  // namespace

std::function<bool(const Ray&, const Hit&)> in_plane_rule(const Accel& acc) {
  return [tri_of = tri_lookup(acc)](const Ray& ray, const Hit& h) {
    RayPre r;
    double cosine = 0;
    const Tri* t = tri_of(h);
    return t && prepare_ray(ray, r) && in_plane(r, *t, cosine);
  };
}

TieRule oracle_tie_rule(const Accel& acc, std::span<const Ray> rays) {
  auto tri_of = tri_lookup(acc);
  return [rays, tri_of](std::size_t ray, const Hit& a, const Hit& oracle) {
    const Ray& ray_in = rays[ray];
    RayPre r;
    if (!prepare_ray(ray_in, r)) return false;
    for (const Hit* h : {&a, &oracle})
      if (const Tri* t = tri_of(*h); t && ill_conditioned(r, *t)) return true;
    if (a.prim == MBVH_MISS_PRIM || oracle.prim == MBVH_MISS_PRIM) {  // a lone hit at the interval's ends
      const Hit& h = a.prim == MBVH_MISS_PRIM ? oracle : a;
      if (h.prim == MBVH_MISS_PRIM) return false;  // no hit at all (t = inf is not "at" tmax = inf)
      return ulp_distance(h.t, ray_in.tmin) <= kTieUlps || ulp_distance(h.t, ray_in.tmax) <= kTieUlps;
    }
    // two hits on other prims, the nearer within kTieUlps of tmin (the float test accepted it and
    // the double one put it just before tmin, or the reverse) or the farther within kTieUlps of tmax
    if (ulp_distance(std::min(a.t, oracle.t), ray_in.tmin) <= kTieUlps ||
        ulp_distance(std::max(a.t, oracle.t), ray_in.tmax) <= kTieUlps)
      return true;
    const Tri* ta = tri_of(a);  // coplanar overlap: a's prim at the oracle's distance
    return ta && ulp_distance(static_cast<float>(plane_t_double(r, *ta)), oracle.t) <= kTieUlps;
  };
}

TieRule oracle_settlement(const Accel& acc, std::span<const Ray> rays, TieRule oracle) {
  return [&acc, rays, oracle = std::move(oracle)](std::size_t ray, const Hit& a, const Hit& b) {
    const Hit o = brute_force(acc, rays[ray]);
    for (const Hit* h : {&a, &b})
      if (compare_hits(*h, o) == Verdict::mismatch && !oracle(ray, *h, o)) return false;
    return true;
  };
}

std::string CheckReport::table(std::span<const Ray> batch) const {
  std::string s;
  char line[512];
  std::snprintf(line, sizeof line, "%zu rays (%zu invalid, defined misses), %zu checked by brute force\n", this->rays,
                invalid, brute_rays);
  s += line;
  std::snprintf(line, sizeof line, "%-40s %-40s %9s %9s %6s %10s %9s %6s\n", "answer", "compared with", "rays", "equal",
                "ties", "mismatch", "bit-same", "t-ulp");
  s += line;
  for (const auto& c : comparisons) {
    std::snprintf(line, sizeof line, "%-40s %-40s %9zu %9zu %6zu %10zu %9zu %6u\n", c.a.c_str(), c.b.c_str(), c.rays, c.equal,
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
  BackendOptions bo = opt.backend;
  bo.threads = opt.threads;
  const auto backends = make_backends(opt.grid, bo);

  // -- run every variant
  struct Run {
    CheckVariant v;
    TraceOutput out;
  };
  std::vector<Run> runs;
  for_each_variant(opt.grid, backends, [&](const std::string& name, Backend& b, const TraceOptions& o) {
    Run run;
    run.v.backend = name;
    run.v.opt = o;
    if (log) log("tracing " + run.v.label());
    b.trace(acc, rays, run.v.opt, run.out);
    if (opt.on_trace) opt.on_trace(run.v, run.out);
    runs.push_back(std::move(run));
  });

  if (runs.empty()) throw Error(no_variant_message(opt.grid, backends));

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
    if (acc.has_hierarchy()) {
      trace_reference(acc, rays, c, o, opt.threads);
    } else {
      // no hierarchy (quality none; every backend here traces without one): the closest hits of
      // the reference variant's own backend and options. They only classify any-hit differences
      // (an edge, the interval's ends); every answer is still compared with the brute force below
      c = ref_any->v.opt;
      c.query = Query::closest;
      backends.at(ref_any->v.backend)->trace(acc, rays, c, o);
    }
    closest_for_any = std::move(o.hits);
  }
  std::vector<std::uint8_t> closest_occ(closest_for_any.size());
  for (std::size_t i = 0; i < closest_for_any.size(); ++i) closest_occ[i] = closest_for_any[i].prim != MBVH_MISS_PRIM;
  std::vector<std::uint8_t> brute_occ(brute.size());
  for (std::size_t i = 0; i < brute.size(); ++i) brute_occ[i] = brute[i].prim != MBVH_MISS_PRIM;

  // the same for every variant: the oracle's tie rule and the float closest hits on the subset
  const TieRule oracle = oracle_tie_rule(acc, rays);
  std::vector<Hit> float_closest;
  if (!closest_for_any.empty())
    for (std::size_t i : sub) float_closest.push_back(closest_for_any[i]);

  // A difference between two float answers that the rules above cannot explain is settled by the
  // oracle, computed for that ray: when each answer equals the brute force's or is a classified tie
  // with it, both are legitimate (e.g. a ray starting on a surface: a hit at t = tmin or none), so
  // the difference is a tie. Bit-exact backends never get here; a peer library (embree) does.
  const TieRule settle_hits = oracle_settlement(acc, rays, oracle);
  // An occlusion flag is legitimate if it agrees with the oracle, if the oracle's hit is on an edge
  // or at the interval's ends, or if it reports a hit and the same variant's own closest hit is
  // legitimate (e.g. a hit at t = tmin the oracle does not count).
  auto own_closest = [&](const Run& r) -> const std::vector<Hit>* {
    for (const Run& c : runs)
      if (c.v.opt.query == Query::closest && c.v.backend == r.v.backend && c.v.opt.layout == r.v.opt.layout &&
          c.v.opt.traversal == r.v.opt.traversal && c.v.opt.precision == r.v.opt.precision)
        return &c.out.hits;
    return nullptr;
  };
  auto occlusion_legit = [&](std::uint8_t flag, const std::vector<Hit>* own, std::size_t ray, const Hit& o) {
    if ((flag != 0) == (o.prim != MBVH_MISS_PRIM)) return true;
    if (o.prim != MBVH_MISS_PRIM && compare_occlusion(1, 0, o, rays[ray]) == Verdict::tie) return true;
    if (!flag || !own) return false;
    const Hit& h = (*own)[ray];
    return h.prim != MBVH_MISS_PRIM && (compare_hits(h, o) != Verdict::mismatch || oracle(ray, h, o));
  };
  auto settle_occlusion = [&](const std::vector<std::uint8_t>& a, const std::vector<Hit>* own_a,
                              const std::vector<std::uint8_t>& b, const std::vector<Hit>* own_b) -> TieRule {
    return [&, own_a, own_b](std::size_t ray, const Hit&, const Hit&) {
      const Hit o = brute_force(acc, rays[ray]);
      return occlusion_legit(a[ray], own_a, ray, o) && occlusion_legit(b[ray], own_b, ray, o);
    };
  };

  for (const Run& r : runs) {
    const bool any = r.v.opt.query == Query::any;
    const Run* ref = any ? ref_any : ref_closest;
    // against the reference variant, all rays
    if (&r != ref) {
      Comparison c = any ? compare_occlusion_arrays(r.out.occluded, ref->out.occluded, closest_for_any, rays, {}, {},
                                                    settle_occlusion(r.out.occluded, own_closest(r), ref->out.occluded,
                                                                     own_closest(*ref)))
                         : compare_hit_arrays(r.out.hits, ref->out.hits, {}, settle_hits);
      c.a = label(r);
      c.b = label(*ref);
      rep.comparisons.push_back(std::move(c));
    }
    // any hit against closest hit: occluded iff a closest hit exists
    if (any) {
      const std::vector<Hit>* ref_hits = ref_closest ? &ref_closest->out.hits : nullptr;
      Comparison c = compare_occlusion_arrays(r.out.occluded, closest_occ, closest_for_any, rays, {}, {},
                                              settle_occlusion(r.out.occluded, own_closest(r), closest_occ, ref_hits));
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
      const std::vector<Hit>* own = any ? own_closest(r) : nullptr;
      const TieRule any_tie = [&, own](std::size_t ray, const Hit& fc, const Hit& oracle_hit) {
        return oracle(ray, fc, oracle_hit) || occlusion_legit(r.out.occluded[ray], own, ray, oracle_hit);
      };
      Comparison c = any ? compare_occlusion_arrays(o, brute_occ, brute, rays, sub, float_closest, any_tie)
                         : compare_hit_arrays(h, brute, sub, oracle);
      c.a = label(r);
      c.b = "brute force (double)";
      rep.comparisons.push_back(std::move(c));
    }
  }
  return rep;
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// compare.cpp — tie classification of DESIGN.md's numerical contract.
#include "mbvh/compare.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>

#include "mbvh/error.h"

namespace mbvh {

std::uint32_t ulp_distance(float a, float b) {
  if (a == b) return 0;
  if (std::isnan(a) || std::isnan(b) || std::isinf(a) || std::isinf(b)) return UINT32_MAX;
  auto key = [](float f) {
    std::int32_t i;
    std::memcpy(&i, &f, 4);
    return i < 0 ? static_cast<std::int64_t>(INT32_MIN) - i : static_cast<std::int64_t>(i);
  };
  const std::int64_t d = key(a) - key(b);
  return static_cast<std::uint32_t>(std::min<std::int64_t>(d < 0 ? -d : d, UINT32_MAX));
}

bool on_edge(const Hit& h) {
  if (h.prim == MBVH_MISS_PRIM) return false;
  const float b0 = 1.0f - h.u - h.v;
  return std::min(b0, std::min(h.u, h.v)) <= kEdgeBarycentric;
}

Verdict compare_hits(const Hit& a, const Hit& b) {
  if (a.prim == b.prim) return Verdict::equal;
  const bool ha = a.prim != MBVH_MISS_PRIM, hb = b.prim != MBVH_MISS_PRIM;
  if (ha && hb) {
    if (ulp_distance(a.t, b.t) <= kTieUlps) return Verdict::tie;
    return on_edge(a.t < b.t ? a : b) ? Verdict::tie : Verdict::mismatch;
  }
  return on_edge(ha ? a : b) ? Verdict::tie : Verdict::mismatch;
}

Verdict compare_occlusion(std::uint8_t a, std::uint8_t b, const Hit& closest, const Ray& ray) {
  if (a == b) return Verdict::equal;
  if (closest.prim == MBVH_MISS_PRIM) return Verdict::mismatch;
  if (on_edge(closest) || ulp_distance(closest.t, ray.tmax) <= kTieUlps ||
      ulp_distance(closest.t, ray.tmin) <= kTieUlps)
    return Verdict::tie;
  return Verdict::mismatch;
}

bool wrong_answer(const Hit& a, const Hit& o, const Ray& ray) {
  const bool ha = a.prim != MBVH_MISS_PRIM, ho = o.prim != MBVH_MISS_PRIM;
  if (ha != ho) {
    const float t = ha ? a.t : o.t;
    return !(ulp_distance(t, ray.tmax) <= kTieUlps || ulp_distance(t, ray.tmin) <= kTieUlps);
  }
  if (!ha || a.prim == o.prim) return false;
  return std::fabs(a.t - o.t) > 0x1p-10f * std::max(std::fabs(a.t), std::fabs(o.t));
}

void Comparison::add(std::size_t ray, Verdict v) {
  ++rays;
  if (v == Verdict::equal) ++equal;
  else if (v == Verdict::tie) ++ties;
  else {
    ++mismatches;
    if (first_mismatches.size() < 8) first_mismatches.push_back(ray);
  }
}

namespace {

// The arrays a comparison walks must line up: `what` answers of each side, one closest hit (and
// one index) per answer where given, every index naming a ray of the batch. Throws Error.
void require_aligned(const char* fn, std::size_t a, std::size_t b, std::size_t index, std::size_t closest,
                     std::size_t closest_alt, std::span<const std::size_t> idx, std::size_t rays, bool need_rays) {
  auto bad = [fn](const std::string& what) { throw Error(std::string(fn) + ": " + what); };
  if (a != b) bad("the answer arrays differ in size (" + std::to_string(a) + " and " + std::to_string(b) + ")");
  if (index && index != a) bad(std::to_string(index) + " indices for " + std::to_string(a) + " answers");
  if (closest != SIZE_MAX && closest != a) bad(std::to_string(closest) + " closest hits for " + std::to_string(a) + " answers");
  if (closest_alt && closest_alt != a) bad(std::to_string(closest_alt) + " alternative closest hits for " + std::to_string(a) + " answers");
  if (!need_rays) return;
  if (idx.empty() && rays != a) bad(std::to_string(rays) + " rays for " + std::to_string(a) + " answers");
  for (std::size_t i = 0; i < idx.size(); ++i)
    if (idx[i] >= rays) bad("index " + std::to_string(i) + " names ray " + std::to_string(idx[i]) + " of " + std::to_string(rays));
}

}  // namespace

Comparison compare_hit_arrays(std::span<const Hit> a, std::span<const Hit> b, std::span<const std::size_t> index,
                              const TieRule& tie) {
  require_aligned("compare_hit_arrays", a.size(), b.size(), index.size(), SIZE_MAX, 0, index, 0, false);
  Comparison c;
  const std::size_t n = a.size();
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t ray = index.empty() ? i : index[i];
    if (std::memcmp(&a[i], &b[i], sizeof(Hit)) == 0) ++c.bit_identical;
    if (a[i].prim == b[i].prim && a[i].prim != MBVH_MISS_PRIM) c.max_t_ulps = std::max(c.max_t_ulps, ulp_distance(a[i].t, b[i].t));
    Verdict v = compare_hits(a[i], b[i]);
    if (v == Verdict::mismatch && tie && tie(ray, a[i], b[i])) v = Verdict::tie;
    c.add(ray, v);
  }
  return c;
}

Comparison compare_occlusion_arrays(std::span<const std::uint8_t> a, std::span<const std::uint8_t> b,
                                    std::span<const Hit> closest, std::span<const Ray> rays,
                                    std::span<const std::size_t> index, std::span<const Hit> closest_alt,
                                    const TieRule& tie) {
  require_aligned("compare_occlusion_arrays", a.size(), b.size(), index.size(), closest.size(), closest_alt.size(), index,
                  rays.size(), true);
  Comparison c;
  const std::size_t n = a.size();
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t ray = index.empty() ? i : index[i];
    if (a[i] == b[i]) ++c.bit_identical;
    Verdict v = compare_occlusion(a[i], b[i], closest[i], rays[ray]);
    if (v == Verdict::mismatch && !closest_alt.empty()) v = compare_occlusion(a[i], b[i], closest_alt[i], rays[ray]);
    if (v == Verdict::mismatch && tie && tie(ray, closest_alt.empty() ? closest[i] : closest_alt[i], closest[i]))
      v = Verdict::tie;
    c.add(ray, v);
  }
  return c;
}

}  // namespace mbvh

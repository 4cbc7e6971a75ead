// SPDX-License-Identifier: MIT
// compare.h — ray-by-ray comparison of answers: equal, a classified tie (equal t within kTieUlps
// with another prim, or a hit on a triangle's edge or vertex), or a genuine mismatch.
#pragma once
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include "mbvh/mbvh_layout.h"

namespace mbvh {

enum class Verdict { equal, tie, mismatch };

/// Distance in units in the last place between two finite floats of any sign (inf: 0 if equal).
std::uint32_t ulp_distance(float a, float b);

/// Two distances this many ulp apart or closer are a tie: the rounding two correct float
/// traversals may disagree by (compare_hits, compare_occlusion, wrong_answer, check's oracle rule).
constexpr std::uint32_t kTieUlps = 4;

/// A hit lies on an edge or vertex if its smallest barycentric is at most this.
constexpr float kEdgeBarycentric = 1e-5f;
bool on_edge(const Hit& h);

/// Two closest-hit answers for the same ray. Same prim (or both miss): equal, whatever t
/// (t differences of one prim are measured apart, see Comparison::max_t_ulps). Different prims:
/// a tie if both hit within kTieUlps of each other or the nearer hit lies on an edge/vertex
/// (another triangle sharing it may win by rounding), else a mismatch.
Verdict compare_hits(const Hit& a, const Hit& b);

/// Two any-hit answers; `closest` is a closest-hit answer for the same ray (e.g. brute force):
/// a difference is a tie when that hit is on an edge or within kTieUlps of tmin/tmax.
Verdict compare_occlusion(std::uint8_t a, std::uint8_t b, const Hit& closest, const Ray& ray);

/// The run-time-vs-error benchmark's verdict on answer `a` against the oracle's `o` for `ray`:
/// stricter than compare_hits, which forgives any miss next to an edge. Wrong when one hits and the
/// other does not (unless the hit lies within kTieUlps of tmin or tmax, the interval's closed ends) —
/// a ray leaking through a shared edge is wrong; or when both hit at distances more than 2^-10
/// apart relative to the distance (another surface). Another prim at the same distance (the
/// neighbour across a shared edge, coplanar triangles) is right.
bool wrong_answer(const Hit& a, const Hit& o, const Ray& ray);

/// Counts over a batch, with the first few genuine mismatches.
struct Comparison {
  std::string a, b;                 ///< what was compared, for reports
  std::size_t rays = 0, equal = 0, ties = 0, mismatches = 0;
  std::size_t bit_identical = 0;    ///< rays whose answers are equal bit for bit
  std::uint32_t max_t_ulps = 0;     ///< largest t difference between hits on the same prim
  std::vector<std::size_t> first_mismatches;  ///< ray indices (at most 8)
  void add(std::size_t ray, Verdict v);
};

/// Reclassifies a would-be mismatch (ray index, answer a, answer b) as a tie when it returns true.
using TieRule = std::function<bool(std::size_t, const Hit&, const Hit&)>;

/// Compares answers a[i] and b[i] of ray index[i] (or i). Throws Error unless a and b (and index,
/// when given) have the same size.
Comparison compare_hit_arrays(std::span<const Hit> a, std::span<const Hit> b, std::span<const std::size_t> index = {},
                              const TieRule& tie = {});
/// `closest` (and, if given, `closest_alt`, e.g. a float answer next to the oracle's) are aligned
/// with a and b; a difference is a tie if either closest hit makes it one. `rays` is the whole
/// batch, indexed through `index`. Throws Error unless the arrays line up (a, b, closest and the
/// given index and closest_alt of one size; without index, as many rays; every index < rays).
Comparison compare_occlusion_arrays(std::span<const std::uint8_t> a, std::span<const std::uint8_t> b,
                                    std::span<const Hit> closest, std::span<const Ray> rays,
                                    std::span<const std::size_t> index = {}, std::span<const Hit> closest_alt = {},
                                    const TieRule& tie = {});

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// lod_check.h — `mbvh lod check`: a .mlod model's full-detail answers (LOD off) against the
// in-core build of its source, ray by ray, with the classified-tie machinery of `mbvh check`
// (check.h, compare.h): against cpu-scalar, closest and any hit, and against the double-precision
// brute force on a spread subset; inside rays on a closed mesh also count leaks.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "mbvh/accel.h"
#include "mbvh/lod.h"
#include "mbvh/scene.h"

namespace mbvh {

struct LodCheckOptions {
  std::vector<RayKind> kinds{RayKind::primary};
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  std::size_t brute_rays = 2000;  ///< rays spread over each batch checked by brute force (SIZE_MAX: all)
  lod::CacheOptions cache;        ///< the model's budget and threads (tracing, ray generation, the reference)
};

/// One ray kind's comparisons (CheckReport's table), the share of closest hits equal bit for bit
/// to cpu-scalar's, and the leaks of inside rays (valid rays from inside a closed mesh that hit
/// nothing; 0 for other kinds).
struct LodCheckKind {
  RayKind kind = RayKind::primary;
  CheckReport report;
  std::size_t bit_identical = 0, compared = 0;  ///< closest hits: model vs cpu-scalar
  std::size_t leaks = 0, reference_leaks = 0;
  double bit_identical_share() const { return compared ? double(bit_identical) / double(compared) : 1.0; }
};

struct LodCheckReport {
  std::string model, source;
  std::uint64_t triangles = 0;
  std::vector<LodCheckKind> kinds;
  lod::CacheStats cache;
  /// Genuine mismatches of every kind plus the model's leaks.
  std::size_t failures() const;
  /// `check`'s table per kind, with the bit-identical share and the leaks.
  std::string text(const std::vector<std::vector<Ray>>& rays) const;
};

/// Throws Error unless the model was built from these triangles: the header's source hash and
/// triangle count equal `src`'s (the message names both).
void check_model_source(const lod::Model& model, const lod::TriangleSource& src);

/// Checks `model` (opened with opt.cache) against the in-core `scene` and its build `acc` (the
/// same triangles; the caller checks that with check_model_source): for each kind, generates the
/// rays (raygen, as `mbvh check`), traces the model at full detail and cpu-scalar, closest and any
/// hit, and compares them. `rays_out` (if set) receives each kind's rays, for the report. Throws
/// Error on a damaged block (naming it) or a budget too small for full detail.
LodCheckReport run_lod_check(lod::Model& model, const Scene& scene, const Accel& acc, const LodCheckOptions& opt,
                             std::vector<std::vector<Ray>>* rays_out = nullptr,
                             const std::function<void(const std::string&)>& log = {});

}  // namespace mbvh

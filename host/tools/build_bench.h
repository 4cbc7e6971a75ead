// SPDX-License-Identifier: MIT
// build_bench.h — the build benchmark: build time of our builder (Accel::build, then the MBVH4
// collapse) and of the embree peer (rtcCommitScene on the build's triangles, each prim once, with
// the triangle copy), median of fresh builds each; our tree's SAH cost; and, asked for, the same
// diffuse rays traced on this tree and on one of another quality, side by side.
#pragma once
#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/accel.h"
#include "mbvh/scene.h"

namespace mbvh {

/// The side-by-side trace: this tree against one of quality `quality`, passes interleaved.
struct VersusOptions {
  std::string quality;          ///< "": no side-by-side trace
  std::string backend = "cpu";
  std::size_t count = 200000;   ///< diffuse rays
  unsigned passes = 15;
  bool has_camera = false;      ///< the rays' camera (else one framing the scene)
  Camera camera;
};

struct BuildBenchOptions {
  BuildOptions build;
  unsigned repeats = 5;  ///< fresh builds timed per builder
  /// Also time `repeats` rebuilds in one kept BuildContext (after two untimed builds in it), each
  /// made while the previous Accel is alive (`acc = Accel::build(...)`, as a frame loop does).
  bool rebuild = false;
  VersusOptions versus;
};

struct VersusResult {
  std::string quality, backend;
  std::size_t rays = 0;
  unsigned passes = 0;
  std::vector<double> mrays, versus_mrays;  ///< per pass: this tree, the other tree
  std::vector<double> ratios;               ///< per pass pair: this tree's speed over the other's
  double sah_binary = 0;                    ///< the other tree's
};

struct BuildBenchReport {
  std::string scene;
  std::size_t triangles = 0;
  unsigned threads = 0;
  BuildQuality quality = BuildQuality::medium;
  unsigned repeats = 0;
  std::uint64_t hash = 0;
  std::size_t references = 0;
  double sah_binary = 0, sah_mbvh4 = 0;
  std::vector<double> build_ms;               ///< ours, build + MBVH4, every repeat
  std::vector<double> phase_ms[5];            ///< ours by phase, every repeat: records, tree, flatten, stats, MBVH4
  /// Minor page faults of the process (getrusage ru_minflt, every thread) during each build: ours
  /// (build + MBVH4) and Embree's (rtcCommitScene with the triangle copy).
  std::vector<double> faults, embree_faults;
  std::vector<double> rebuild_ms, rebuild_faults;  ///< the rebuilds in a kept context (rebuild)
  std::vector<double> rebuild_phase_ms[5];          ///< the rebuilds by phase, as phase_ms
  std::optional<std::vector<double>> embree_build_ms;  ///< every repeat; none where embree is not built in
  std::optional<VersusResult> versus;
};

/// Times the builds of `scene` (and the side-by-side trace, when asked). Throws Error when the
/// two trees' hits differ.
BuildBenchReport run_build_bench(const Scene& scene, const BuildBenchOptions& o);

/// The report as JSON text (`mbvh build-bench --json`): medians, every repeat, phases, versus.
std::string build_bench_json(const BuildBenchReport& r);

}  // namespace mbvh

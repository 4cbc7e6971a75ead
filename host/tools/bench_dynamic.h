// SPDX-License-Identifier: MIT
// bench_dynamic.h — `mbvh bench --dynamic`: frames of a moving scene (displace.h), each traced
// after its structure is brought up to date one of three ways — rebuilt, refitted, or updated as
// a flat build for a backend that traces without a hierarchy — on the same rays, every frame's
// answers verified against the reference on that frame's geometry.
#pragma once
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "host/tools/raygen.h"
#include "host/tools/variants.h"
#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/scene.h"

namespace mbvh {

/// How a frame's structure is brought up to date before the frame's rays are traced:
/// rebuild: Accel::build of the moved scene (a backend that needs a hierarchy);
/// refit: Accel::refit of the build kept from the first frame (the same backends);
/// update: Accel::refit of a flat build (BuildQuality::none: the validated triangles, no
/// hierarchy), kept from the first frame (a backend whose BackendInfo::needs_hierarchy is false).
enum class FrameMode { rebuild, refit, update };
const char* to_string(FrameMode m);  ///< "rebuild+trace", "refit+trace", "update+trace"

struct DynamicOptions {
  /// The backends; per backend, every layout x traversal x precision of the lists it supports
  /// (with `first_layout`, per traversal only the first layout of the list it has). A backend
  /// supporting none of them runs its own first supported layout and traversal (dacrt: the
  /// `dacrt` traversal), so the defaults need no backend's name. `grid.queries` empty: each
  /// kind's own query (shadow rays any hit, primary rays closest hit); else every kind traces
  /// each of those queries, as separate variants.
  VariantGrid grid;
  bool first_layout = true;
  std::vector<RayKind> kinds{RayKind::primary, RayKind::shadow};  ///< primary and shadow only
  unsigned frames = 10;   ///< timed frames, after one untimed warm-up frame (the unmoved scene)
  unsigned width = 1024, height = 768;  ///< the primary rays' image (image_rays)
  std::size_t count = 0;  ///< > 0: generate_rays' `count` primary rays (a square image) instead
  std::uint64_t seed = 1;
  unsigned threads = 0;   ///< the backends' threads (the builds take theirs from `build`)
  BuildOptions build;     ///< every build and refit (its progress callback is not used)
  BackendOptions backend;
  bool has_camera = false;  ///< primary rays from `camera` instead of default_camera
  Camera camera;
};

/// One timed frame of one lane (backend variant x mode).
struct DynamicFrame {
  unsigned frame = 0;
  double total_ms = 0;               ///< update_ms + the trace times
  double update_ms = 0;              ///< the rebuild, refit or flat update
  std::vector<double> trace_ms;      ///< per kind (DynamicRecord::kinds), Backend::trace
  std::vector<std::size_t> rays;     ///< per kind (shadow rays: the frame's primary hits)
  std::size_t verify_mismatches = 0;
  std::int64_t peak_extra_bytes = -1;  ///< resident peak during the step over the resident size before it; -1 unmeasured
};

/// One lane's frames and their medians.
struct DynamicRecord {
  std::string scene, backend, isa, device, layout, traversal, precision, mode;
  std::string build;  ///< the quality of the builds the lane makes or refits (update: none)
  std::vector<std::string> kinds, queries;  ///< per kind traced: its ray kind and query
  unsigned threads = 0, frames = 0;
  double median_ms = 0, min_ms = 0, max_ms = 0;  ///< of the frames' total_ms
  double median_update_ms = 0;
  std::vector<double> median_trace_ms;  ///< per kind
  double mrays_per_s = 0;               ///< median rays per frame / median_ms (the update counted)
  /// median_ms over the median_ms of the first update lane on the same kinds and queries (a
  /// backend without a hierarchy): (rebuild+trace)/(update+trace) and (refit+trace)/(update+trace); 0: none.
  double time_vs_update = 0;
  /// refit lanes: median_ms over their backend's rebuild lane's; 0: not a refit lane.
  double time_vs_rebuild = 0;
  /// Resident bytes the lane keeps between frames (its kept build, the backend's copies of it),
  /// measured over its warm-up frame; and the largest resident peak of a timed step above the
  /// resident size before it (a rebuild's new build, a leaf regrouping, the trace's own arrays).
  /// -1: not measured (no /proc/self/clear_refs).
  std::int64_t held_bytes = -1, peak_extra_bytes = -1;
  std::size_t verify_mismatches = 0;  ///< over every frame, the warm-up frame included
  std::vector<DynamicFrame> per_frame;
  /// No genuine mismatch in any frame, except in the fast precision (its error is by design).
  bool verified() const;
};

struct DynamicReport {
  std::string machine, cpu, compiler, flags;
  std::string scene;
  std::size_t triangles = 0;
  std::size_t left_out = 0;  ///< degenerate triangles left out of the moving scene
  std::vector<DynamicRecord> records;
  std::string table() const;   ///< the medians, then the frames' total ms, one column per lane
  std::string json() const;    ///< BenchReport's document: the run's keys and `records`
  std::string csv() const;     ///< records_csv(json()): the per-frame lists stay in the JSON
  bool verified() const;
};

/// Runs DynamicOptions::frames frames of `scene` (built as `acc`, which fixes the displacement's
/// extent, the camera and the light) without its degenerate triangles (without_degenerate: a
/// displacement would give them area, which a refit refuses; they are never hit, and the
/// answers' prim ids are those of the scene without them; DynamicReport::left_out counts them):
/// frame f moves every vertex by displace_vertices(f); an
/// untimed reference build of the moved scene makes the frame's shadow rays (from its primary
/// hits) and reference answers; then every lane's step (its update, then one trace per kind) is
/// timed, the lanes in an order rotated frame by frame, and its answers are verified. Throws
/// Error for a kind other than primary and shadow, a backend that cannot start, or a scene the
/// builds refuse. `progress(done, total)` after each frame.
DynamicReport run_dynamic(const Scene& scene, const Accel& acc, const DynamicOptions& opt,
                          const std::function<void(std::size_t done, std::size_t total)>& progress = {});

}  // namespace mbvh

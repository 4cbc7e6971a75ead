// SPDX-License-Identifier: MIT
// args.h — the options of `trace` and `render`, which `mbvh` and `mbvh-mpi` (host/cli/mpi) both
// register: one set of options and checks for both programs.
#pragma once
#include "host/cli/common.h"
#include "host/tools/render.h"

namespace mbvh::cli {

/// `trace`'s options.
struct TraceArgs {
  SceneArgs scene;
  RayArgs rays;
  DeviceArgs dev;
  std::string backend = "cpu", layout = "auto", traversal = "auto", query = "closest", out, precision = "robust";
  bool stats = false;
  void add(CLI::App* c);
  /// The trace options these arguments name, resolved for `backend` (auto: its fastest), with
  /// layout and traversal set to the resolved names; throws Error when the backend lacks them.
  TraceOptions options(const Backend& backend);
};

/// `render`'s options.
struct RenderArgs {
  SceneArgs scene;
  DeviceArgs dev;
  std::string backend = "cpu", layout = "auto", traversal = "auto", mode = "path", out;
  std::string precision = "robust", pfm, reference, curve;
  RenderOptions o;
  std::vector<float> camera, light;
  void add(CLI::App* c);
  /// The render options of these arguments, resolved for `backend` (auto: its fastest closest-hit
  /// pair), and --reference read into `reference`.
  RenderOptions options(const Backend& backend, std::vector<float>& reference) const;
};

}  // namespace mbvh::cli

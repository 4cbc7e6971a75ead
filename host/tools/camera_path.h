// SPDX-License-Identifier: MIT
// camera_path.h — the cameras of a multi-frame render (`mbvh render MODEL --frames N`): a camera
// path file, or an orbit around a model's bounds.
#pragma once
#include <string>
#include <vector>

#include "host/tools/raygen.h"

namespace mbvh {

/// A camera path file: one camera per line, "ex,ey,ez,tx,ty,tz[,fov]" as the --camera option takes
/// it (camera_argument writes it; spaces around the commas are allowed, fov defaults to 60); empty
/// lines and lines starting with '#' are skipped. Throws Error naming the file and the line for a
/// malformed number, a wrong count, a camera_problem, a file of no cameras or one over 64 MiB.
std::vector<Camera> read_camera_path(const std::string& path);

/// `frames` cameras on a circle around the box: the first is default_camera(b); each next one
/// turns the eye by 360/frames degrees about the vertical (+y) axis through the box's centre, at
/// the same height and distance, looking at the centre (fov 60). frames >= 1.
std::vector<Camera> orbit_path(const Box& b, unsigned frames);

}  // namespace mbvh

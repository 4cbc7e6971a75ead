// SPDX-License-Identifier: MIT
// framing.h — the camera `mbvh render` uses when none is given: from inside a scene whose
// geometry walls its bounding box (a room, a cathedral, an atrium open to the sky, a Cornell box
// open at the front), from outside anything else (an object), as default_camera frames it.
#pragma once
#include <functional>
#include <string>
#include <vector>

#include "host/tools/raygen.h"

namespace mbvh {

/// How the default camera was chosen.
struct Framing {
  Camera camera;
  bool inside = false;  ///< the scene was judged enclosed: the eye is inside its box (or in its opening)
  unsigned walled = 0;  ///< sides of the bounding box its geometry walls (0 to 6)
  std::string rule;     ///< one line: what was decided and why
};

/// Traces `rays` for their closest hits: one Hit per ray, in order.
using ClosestHits = std::function<void(const std::vector<Ray>&, std::vector<Hit>&)>;

/// The default camera of a scene with bounding box `b`, whose geometry `trace` traces (+y is up).
/// 1. A side of the box is walled when at least 90% of a 16 x 16 grid of rays shot straight into
///    the box from just outside that side hit geometry within a tenth of the box's depth: a wall
///    (an object's silhouette covers less of its box: a sphere's 79%, the Stanford bunny's less;
///    through an open side the rays hit the far wall, too deep).
/// 2. Walled on at least 5 sides: enclosed. The view runs along a horizontal axis: through the
///    open vertical side if exactly one is open (a Cornell box's front), else along the longer
///    one (x on a tie), from its low end. The eye is on that axis's centre line, 40% of the
///    box's height above its floor, at the first of 10%, 20%, ... 50% of the way along (through an
///    opening: 0%, in the opening, 10%, ... 50%) whose view
///    is free (the median distance to the first hit of 9 rays across the middle of the view is
///    at least a third of the way to the far side; else the freest of them); it looks level at
///    the far side, fov 60 degrees.
/// 3. Otherwise: default_camera(b), outside.
/// Deterministic: 1,536 + up to 54 rays, the same on every backend whose hit distances agree
/// (all of mbvh's). Requires a non-empty box.
Framing frame_scene(const Box& b, const ClosestHits& trace);

/// `c` as the --camera option takes it: "ex,ey,ez,tx,ty,tz,fov", each float in its shortest form
/// that reads back to the same float (the same camera, so the same image).
std::string camera_argument(const Camera& c);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// framing.cpp — the default camera of `mbvh render` (framing.h): walled sides of the bounding
// box decide inside or outside; inside, a level view along the room from its open or short end.
#include "host/tools/framing.h"

#include <algorithm>
#include <charconv>
#include <cmath>

namespace mbvh {
namespace {

constexpr unsigned kGrid = 16;             // probe rays per side: kGrid x kGrid
constexpr double kWalledFraction = 0.9;    // of a side's probes that must hit a wall
constexpr float kWallDepth = 0.1f;         // of the box's depth: how far in a wall may be
constexpr unsigned kEnclosedSides = 5;     // walled sides of an enclosed scene
constexpr double kEyeHeight = 0.4;         // of the box's height, above its floor
constexpr double kFreeView = 1.0 / 3.0;    // of the way to the far side, the median view ray must travel

const char* side_name(int axis, int dir) {
  static const char* names[3][2] = {{"-x", "+x"}, {"-y", "+y"}, {"-z", "+z"}};
  return names[axis][dir];
}

// How far outside the box the probe rays start.
float probe_margin(const Box& b) {
  const Vec3f e = b.extent();
  return 0.01f * std::max({e.x, e.y, e.z});
}

// The probe rays of side (axis, dir: 0 low, 1 high): a grid over the side, each ray starting
// just outside it and pointing straight into the box.
std::vector<Ray> side_probes(const Box& b, int axis, int dir) {
  const Vec3f e = b.extent();
  const float margin = probe_margin(b);
  const int u = (axis + 1) % 3, v = (axis + 2) % 3;
  std::vector<Ray> rays;
  rays.reserve(kGrid * kGrid);
  for (unsigned i = 0; i < kGrid; ++i)
    for (unsigned j = 0; j < kGrid; ++j) {
      Vec3f o, d;
      o[axis] = dir ? b.hi[axis] + margin : b.lo[axis] - margin;
      o[u] = b.lo[u] + e[u] * (static_cast<float>(i) + 0.5f) / kGrid;
      o[v] = b.lo[v] + e[v] * (static_cast<float>(j) + 0.5f) / kGrid;
      d[axis] = dir ? -1.0f : 1.0f;
      rays.push_back(Ray{o.x, o.y, o.z, 0.0f, d.x, d.y, d.z, INFINITY});
    }
  return rays;
}

// The median first-hit distance of 9 rays over the middle of the view (a miss: infinity).
float median_free_distance(const Camera& c, const ClosestHits& trace) {
  std::vector<Ray> rays;
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) rays.push_back(camera_ray(c, 0.25 + 0.25 * i, 0.25 + 0.25 * j));
  std::vector<Hit> hits;
  trace(rays, hits);
  std::vector<float> t;
  for (const Hit& h : hits) t.push_back(h.prim == MBVH_MISS_PRIM ? INFINITY : h.t);  // the rays' directions are unit vectors
  std::nth_element(t.begin(), t.begin() + 4, t.end());
  return t[4];
}

std::string shortest(float v) {
  char buf[32];
  const auto r = std::to_chars(buf, buf + sizeof buf, v);
  return std::string(buf, r.ptr);
}

}  // namespace

std::string camera_argument(const Camera& c) {
  return shortest(c.eye.x) + "," + shortest(c.eye.y) + "," + shortest(c.eye.z) + "," + shortest(c.target.x) + "," +
         shortest(c.target.y) + "," + shortest(c.target.z) + "," + shortest(c.fov_deg);
}

Framing frame_scene(const Box& b, const ClosestHits& trace) {
  Framing f;
  // -- which sides of the box the geometry walls
  bool walled[3][2] = {};
  std::string open;
  std::vector<Hit> hits;
  for (int axis = 0; axis < 3; ++axis)
    for (int dir = 0; dir < 2; ++dir) {
      trace(side_probes(b, axis, dir), hits);
      // a wall: a hit within a tenth of the box's depth (not the far side seen through an opening)
      const float wall = probe_margin(b) + kWallDepth * b.extent()[axis];
      const auto hit = std::count_if(hits.begin(), hits.end(), [wall](const Hit& h) { return h.prim != MBVH_MISS_PRIM && h.t <= wall; });
      walled[axis][dir] = static_cast<double>(hit) >= kWalledFraction * kGrid * kGrid;
      if (walled[axis][dir]) ++f.walled;
      else open += std::string(open.empty() ? "" : ", ") + side_name(axis, dir);
    }
  const std::string sides = "walled on " + std::to_string(f.walled) + " of its 6 sides" + (open.empty() ? "" : " (open: " + open + ")");
  if (f.walled < kEnclosedSides) {
    f.camera = default_camera(b);
    f.rule = "outside: the scene's box is " + sides + ", fewer than " + std::to_string(kEnclosedSides);
    return f;
  }
  // -- enclosed: the view axis and the end the eye starts from
  f.inside = true;
  int axis = 0, from = 0;  // the view runs from side (axis, from) towards the opposite one
  unsigned open_vertical = 0;
  for (int a : {0, 2})
    for (int d = 0; d < 2; ++d)
      if (!walled[a][d]) ++open_vertical, axis = a, from = d;
  const Vec3f e = b.extent();
  std::string why = "through its open " + std::string(side_name(axis, from)) + " side";
  unsigned first = 0;  // in tenths of the way: through an opening, from the opening itself
  if (open_vertical != 1) {
    first = 1;
    axis = e.z > e.x ? 2 : 0;
    from = 0;
    why = "along its longer horizontal axis from " + std::string(side_name(axis, 0));
  }
  const int across = 2 - axis;  // the other horizontal axis
  // -- the eye: the first position along the view whose view is free
  const float far = from ? b.lo[axis] : b.hi[axis], start = from ? b.hi[axis] : b.lo[axis];
  float best = -1;
  unsigned best_at = 0;
  for (unsigned k = first; k <= 5; ++k) {
    Camera c;
    c.eye[axis] = start + (far - start) * 0.1f * static_cast<float>(k);
    c.eye[across] = b.center()[across];
    c.eye.y = b.lo.y + static_cast<float>(kEyeHeight) * e.y;
    c.target = c.eye;
    c.target[axis] = far;
    const float free = median_free_distance(c, trace);
    const float needed = static_cast<float>(kFreeView) * std::fabs(far - c.eye[axis]);
    if (free >= needed) {
      best_at = k, f.camera = c;
      break;
    }
    if (free > best) best = free, best_at = k, f.camera = c;
  }
  f.rule = "inside: the scene's box is " + sides + "; the view runs " + why + ", the eye " +
           std::to_string(10 * best_at) + "% of the way along, 40% up";
  return f;
}

}  // namespace mbvh

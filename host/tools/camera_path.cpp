// SPDX-License-Identifier: MIT
// camera_path.cpp — camera path files and orbits (camera_path.h).
#include "host/tools/camera_path.h"

#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <fstream>
#include <numbers>
#include <sstream>

#include "host/core/resources.h"
#include "mbvh/error.h"

namespace mbvh {

std::vector<Camera> read_camera_path(const std::string& path) {
  constexpr std::uint64_t kMaxBytes = 64ull << 20;  // a million cameras and more: a path, not a data set
  const std::uint64_t size = regular_file_size(path, "camera path");
  if (size > kMaxBytes) throw Error(path + ": a camera path file of " + format_bytes(size) + " (at most 64 MiB)");
  std::ifstream in(path);
  if (!in) throw Error(path + ": cannot open the camera path file");
  std::vector<Camera> cams;
  std::string line;
  for (std::size_t no = 1; std::getline(in, line); ++no) {
    const std::string where = path + ":" + std::to_string(no);
    std::size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    std::vector<float> v;
    std::stringstream ss(line);
    for (std::string item; std::getline(ss, item, ',');) {
      const std::size_t b = item.find_first_not_of(" \t\r"), e = item.find_last_not_of(" \t\r");
      const std::string t = b == std::string::npos ? std::string() : item.substr(b, e - b + 1);
      char* end = nullptr;
      errno = 0;
      const float x = std::strtof(t.c_str(), &end);
      if (t.empty() || *end != '\0' || errno == ERANGE || !std::isfinite(x))
        throw Error(where + ": '" + t + "' is not a finite number (a camera is ex,ey,ez,tx,ty,tz[,fov])");
      v.push_back(x);
    }
    if (v.size() != 6 && v.size() != 7)
      throw Error(where + ": " + std::to_string(v.size()) + " numbers (a camera is ex,ey,ez,tx,ty,tz[,fov])");
    Camera c;
    c.eye = {v[0], v[1], v[2]};
    c.target = {v[3], v[4], v[5]};
    if (v.size() == 7) c.fov_deg = v[6];
    if (const std::string p = camera_problem(c); !p.empty()) throw Error(where + ": " + p);
    cams.push_back(c);
  }
  if (in.bad()) throw Error(path + ": read error");
  if (cams.empty()) throw Error(path + ": no camera in the camera path file");
  return cams;
}

std::vector<Camera> orbit_path(const Box& b, unsigned frames) {
  if (frames == 0) throw Error("orbit_path: no frames");
  const Camera first = default_camera(b);
  const Vec3f ctr = b.center();
  const double dx = double(first.eye.x) - ctr.x, dz = double(first.eye.z) - ctr.z;
  std::vector<Camera> cams;
  for (unsigned k = 0; k < frames; ++k) {
    if (k == 0) {
      cams.push_back(first);
      continue;
    }
    const double a = 2.0 * std::numbers::pi * k / frames, ca = std::cos(a), sa = std::sin(a);
    Camera c = first;
    c.eye = Vec3f{static_cast<float>(ctr.x + ca * dx + sa * dz), first.eye.y, static_cast<float>(ctr.z - sa * dx + ca * dz)};
    cams.push_back(c);
  }
  return cams;
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// fuzz_rays.cpp — libFuzzer target for the ray-file reader and the traversal of arbitrary rays:
// any bytes either give rays or throw mbvh::Error, and every 32-byte record taken as a ray (NaN, inf, denormal, ±0, any
// tmin/tmax) traces to a defined answer on every layout and traversal, or is refused by all of
// them as outside the exactly traced range.
#include <cstddef>
#include <cstdint>
#include <cstring>
#include <memory>
#include <vector>

#include "mbvh/error.h"
#include "mbvh/rays.h"
#include "mbvh/trace.h"

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  static const mbvh::Scene scene = mbvh::load_scene("gen:cube:4");
  static const std::unique_ptr<mbvh::Accel> acc = mbvh::Accel::build(scene);
  // the reader: any bytes give rays or an Error (it refuses foreign formats and non-finite values)
  try {
    (void)mbvh::rays_from_bytes("fuzz", reinterpret_cast<const char*>(data), size);
  } catch (const mbvh::Error&) {
  }
  // the traversal: the bytes taken as records whatever the reader says, so NaN, inf, denormal,
  // ±0 and any tmin/tmax still reach every layout and traversal
  std::vector<mbvh::Ray> rays(size / sizeof(mbvh::Ray));
  if (!rays.empty()) std::memcpy(rays.data(), data, rays.size() * sizeof(mbvh::Ray));
  // A valid ray outside the exactly traced range (check_ray_range) is refused with an Error, by
  // every layout and traversal alike.
  for (const mbvh::Ray& r : rays) {
    mbvh::Hit ref{};
    bool refused = false;
    try {
      ref = mbvh::trace_one(*acc, r, {});
    } catch (const mbvh::Error&) {
      refused = true;
    }
    if (refused && !mbvh::ray_valid(r)) __builtin_trap();  // an invalid ray is a defined miss, never refused
    for (mbvh::Layout l : {mbvh::Layout::mbvh2, mbvh::Layout::mbvh4})
      for (mbvh::Traversal t : {mbvh::Traversal::stack, mbvh::Traversal::bitstack}) {
        mbvh::Hit h{};
        try {
          h = mbvh::trace_one(*acc, r, mbvh::TraceOptions{l, t, mbvh::Query::closest, false});
        } catch (const mbvh::Error&) {
          if (!refused) __builtin_trap();
          continue;
        }
        if (refused) __builtin_trap();
        if (h.t != ref.t && !(h.t != h.t && ref.t != ref.t)) __builtin_trap();  // every traversal: the same t
        if (!mbvh::ray_valid(r) && h.prim != MBVH_MISS_PRIM) __builtin_trap();
      }
  }
  return 0;
}

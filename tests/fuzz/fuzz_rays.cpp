// SPDX-License-Identifier: MIT
// fuzz_rays.cpp — libFuzzer target for the ray-file reader and the traversal of arbitrary rays:
// any bytes either give rays or throw mbvh::Error, and every 32-byte record taken as a ray (NaN, inf, denormal, ±0, any
// tmin/tmax) traces to a defined answer on every layout and traversal.
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
  for (const mbvh::Ray& r : rays) {
    const mbvh::Hit ref = mbvh::trace_one(*acc, r, {});
    for (mbvh::Layout l : {mbvh::Layout::mbvh2, mbvh::Layout::mbvh4})
      for (mbvh::Traversal t : {mbvh::Traversal::stack, mbvh::Traversal::bitstack}) {
        const mbvh::Hit h = mbvh::trace_one(*acc, r, mbvh::TraceOptions{l, t, mbvh::Query::closest, false});
        if (h.t != ref.t && !(h.t != h.t && ref.t != ref.t)) __builtin_trap();  // every traversal: the same t
        if (!mbvh::ray_valid(r) && h.prim != MBVH_MISS_PRIM) __builtin_trap();
      }
  }
  return 0;
}

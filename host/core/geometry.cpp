// SPDX-License-Identifier: MIT
// geometry.cpp — the geometry API's traces (mbvh/geometry.h): a backend's answers, staged in a
// per-thread TraceOutput that is reused, written into the caller's spans, prim ids mapped to
// (geometry, triangle) by the build's geometry ranges.
#include "mbvh/geometry.h"

#include <algorithm>
#include <string>

#include "mbvh/error.h"

namespace mbvh {

namespace {

/// The staging output of this thread: it keeps its capacity, so a repeated trace allocates nothing.
TraceOutput& scratch() {
  thread_local TraceOutput out;
  return out;
}

void check_size(const char* what, std::size_t rays, std::size_t room, const char* unit) {
  if (rays != room)
    throw Error(std::string("mbvh::") + what + ": " + std::to_string(rays) + " rays but the output span holds " +
                std::to_string(room) + " " + unit + "; it must hold exactly one per ray");
}

/// Runs the backend's trace of `rays` with `opt` (query set, statistics off) into the scratch.
const TraceOutput& run(Backend& backend, const Accel& accel, std::span<const Ray> rays, TraceOptions opt, Query query) {
  opt.query = query;
  opt.stats = false;
  TraceOutput& out = scratch();
  backend.trace(accel, rays, opt, out);
  const std::size_t got = query == Query::closest ? out.hits.size() : out.occluded.size();
  if (got != rays.size())
    throw Error("backend " + backend.name() + " returned " + std::to_string(got) + " answers for " +
                std::to_string(rays.size()) + " rays");
  return out;
}

}  // namespace

GeomHit to_geom_hit(const Accel& accel, const Hit& hit) {
  const GeomPrim g = accel.geometry_of(hit.prim);
  return {hit.t, hit.u, hit.v, g.geom_id, g.prim_id};
}

void intersect(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<GeomHit> hits,
               const TraceOptions& opt) {
  check_size("intersect", rays.size(), hits.size(), "hits");
  if (rays.empty()) return;
  const TraceOutput& out = run(backend, accel, rays, opt, Query::closest);
  for (std::size_t i = 0; i < rays.size(); ++i) hits[i] = to_geom_hit(accel, out.hits[i]);
}

void intersect(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<Hit> hits,
               const TraceOptions& opt) {
  check_size("intersect", rays.size(), hits.size(), "hits");
  if (rays.empty()) return;
  const TraceOutput& out = run(backend, accel, rays, opt, Query::closest);
  std::copy(out.hits.begin(), out.hits.end(), hits.begin());
}

void occluded(Backend& backend, const Accel& accel, std::span<const Ray> rays, std::span<std::uint8_t> occluded,
              const TraceOptions& opt) {
  check_size("occluded", rays.size(), occluded.size(), "flags");
  if (rays.empty()) return;
  const TraceOutput& out = run(backend, accel, rays, opt, Query::any);
  std::copy(out.occluded.begin(), out.occluded.end(), occluded.begin());
}

GeomHit intersect1(Backend& backend, const Accel& accel, const Ray& ray, const TraceOptions& opt) {
  GeomHit h;
  intersect(backend, accel, std::span<const Ray>(&ray, 1), std::span<GeomHit>(&h, 1), opt);
  return h;
}

bool occluded1(Backend& backend, const Accel& accel, const Ray& ray, const TraceOptions& opt) {
  std::uint8_t o = 0;
  occluded(backend, accel, std::span<const Ray>(&ray, 1), std::span<std::uint8_t>(&o, 1), opt);
  return o != 0;
}

}  // namespace mbvh

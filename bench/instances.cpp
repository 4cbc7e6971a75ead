// SPDX-License-Identifier: MIT
// instances.cpp — `mbvh-instances-bench MESH [INSTANCES] [FLAT_INSTANCES] [RAYS] [REPEATS] [THREADS]`:
// instancing (InstanceScene, mbvh/instance.h) against the same triangles flattened. A grid of
// INSTANCES copies of MESH (random rotations, scales 0.8-1.25 with a mild non-uniform part, every
// third one mirrored) is traced on `cpu`: random rays (origins in the instances' bounds, uniform
// directions) and primary rays of a camera framing them, closest and any hit. For the first
// FLAT_INSTANCES of them (a flattened build of all INSTANCES may not fit in memory) the same
// triangles are flattened to world space (InstanceScene::flatten), built once (Accel::build) and
// traced on the same rays with the same single-ray kernels (RayQuery, its default traversals) on
// the same threads, and with the batch trace (Backend::trace, MBVH8 ordered stack / bitstack): the
// ratio is instanced / the faster flattened. Before timing, the instanced answers are compared
// with the flattened ones (compare_flattened: every ray) and with the double brute force over the
// flattened triangles (a sample of rays). Every time is the median of REPEATS passes.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "host/core/parallel.h"
#include "mbvh/backends.h"
#include "mbvh/mbvh.h"

using namespace mbvh;
using Clock = std::chrono::steady_clock;

namespace {

double median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

template <class F>
double time_median(int repeats, F&& f) {
  f();  // warm-up
  std::vector<double> t;
  for (int r = 0; r < repeats; ++r) {
    const auto t0 = Clock::now();
    f();
    t.push_back(std::chrono::duration<double>(Clock::now() - t0).count());
  }
  return median(t);
}

std::vector<Instance> grid(std::size_t n, const Box& mesh_box, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0, 1);
  const Vec3f e = mesh_box.extent(), c = mesh_box.center();
  const float step = 1.3f * std::max({e.x, e.y, e.z});
  const auto side = static_cast<std::size_t>(std::ceil(std::cbrt(double(n))));
  std::vector<Instance> out;
  for (std::size_t i = 0; i < n; ++i) {
    const float x = step * float(i % side), y = step * float((i / side) % side), z = step * float(i / (side * side));
    const float s = 0.8f + 0.45f * u(rng);
    const Affine scale = Affine::scale((i % 3 == 0 ? -s : s), s * (0.9f + 0.2f * u(rng)), s);
    const Affine rot = Affine::rotation(u(rng) - 0.5f, 1.0f, u(rng) - 0.5f, 6.2831853f * u(rng));
    out.push_back({0, Affine::translation(x, y, z) * rot * scale * Affine::translation(-c.x, -c.y, -c.z)});
  }
  return out;
}

std::vector<Ray> random_rays(const Box& b, std::size_t n, std::uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::uniform_real_distribution<float> u(0, 1);
  std::vector<Ray> rays(n);
  for (Ray& r : rays) {
    const float z = 2 * u(rng) - 1, phi = 6.2831853f * u(rng), s = std::sqrt(std::max(0.0f, 1 - z * z));
    r = Ray{b.lo.x + u(rng) * (b.hi.x - b.lo.x), b.lo.y + u(rng) * (b.hi.y - b.lo.y), b.lo.z + u(rng) * (b.hi.z - b.lo.z), 0,
            s * std::cos(phi), s * std::sin(phi), z, INFINITY};
  }
  return rays;
}

/// A pinhole camera outside the box, looking at its centre from the front and a little above.
std::vector<Ray> primary_rays(const Box& b, std::size_t n) {
  const auto w = static_cast<std::size_t>(std::sqrt(double(n)));
  const Vec3f c = b.center(), e = b.extent();
  const float diag = std::sqrt(e.x * e.x + e.y * e.y + e.z * e.z);
  const float eye[3] = {c.x + 0.35f * diag, c.y + 0.45f * diag, c.z + 1.1f * diag};
  float f[3] = {c.x - eye[0], c.y - eye[1], c.z - eye[2]};
  const float fl = std::sqrt(f[0] * f[0] + f[1] * f[1] + f[2] * f[2]);
  for (float& x : f) x /= fl;
  float r[3] = {f[2], 0, -f[0]};  // f x up(0,1,0), normalised
  const float rl = std::sqrt(r[0] * r[0] + r[2] * r[2]);
  r[0] /= rl, r[2] /= rl;
  const float up[3] = {r[1] * f[2] - r[2] * f[1], r[2] * f[0] - r[0] * f[2], r[0] * f[1] - r[1] * f[0]};
  const float tan_half = 0.45f;
  std::vector<Ray> rays;
  for (std::size_t y = 0; y < w; ++y)
    for (std::size_t x = 0; x < w; ++x) {
      const float sx = tan_half * (2 * (float(x) + 0.5f) / float(w) - 1), sy = tan_half * (1 - 2 * (float(y) + 0.5f) / float(w));
      rays.push_back(Ray{eye[0], eye[1], eye[2], 0, f[0] + sx * r[0] + sy * up[0], f[1] + sx * r[1] + sy * up[1],
                         f[2] + sx * r[2] + sy * up[2], INFINITY});
    }
  return rays;
}

}  // namespace

int main(int argc, char** argv) try {
  if (argc < 2) {
    std::fprintf(stderr, "usage: %s MESH [INSTANCES] [FLAT_INSTANCES] [RAYS] [REPEATS] [THREADS]\n", argv[0]);
    return 2;
  }
  const std::size_t n = argc > 2 ? std::stoul(argv[2]) : 1000;
  const std::size_t nflat = argc > 3 ? std::stoul(argv[3]) : 100;
  const std::size_t nrays = argc > 4 ? std::stoul(argv[4]) : 262144;
  const int repeats = argc > 5 ? std::stoi(argv[5]) : 5;
  const unsigned threads = argc > 6 ? static_cast<unsigned>(std::stoul(argv[6])) : 0;
  register_builtin_backends();
  auto cpu = make_backend("cpu");
  BuildOptions bo;
  bo.threads = threads;
  const std::shared_ptr<const Accel> mesh = Accel::build(load_scene(argv[1]), bo);
  const std::vector<Instance> all = grid(n, mesh->bounds(), 42);
  std::printf("mesh %s: %zu triangles; backend %s (%s); threads %u; rays per kind %zu; repeats %d\n", argv[1],
              mesh->scene_triangles(), cpu->runs_as().c_str(), cpu->describe().c_str(), resolve_threads(threads), nrays,
              repeats);
  std::printf("| instances | rays | query | instanced Mrays/s | flattened RayQuery Mrays/s | flattened batch Mrays/s | ratio "
              "(instanced / faster flattened) |\n|---|---|---|---|---|---|---|\n");
  for (const std::size_t count : {nflat, n}) {
    const std::vector<Instance> inst(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(std::min(count, n)));
    const auto tb = Clock::now();
    const InstanceScene s = InstanceScene::build(*cpu, {mesh}, inst, threads);
    const double build_ms = std::chrono::duration<double, std::milli>(Clock::now() - tb).count();
    const bool flat_too = count == nflat;
    std::unique_ptr<Accel> flat_acc;
    Scene flat;
    if (flat_too) {
      flat = s.flatten();
      const auto tf = Clock::now();
      flat_acc = Accel::build(flat, bo);
      std::printf("(%zu instances: top level %.2f ms; flattened %zu triangles built in %.1f s)\n", count, build_ms,
                  flat.triangle_count(), std::chrono::duration<double>(Clock::now() - tf).count());
    } else {
      std::printf("(%zu instances: top level %.2f ms, %zu triangles instanced; not flattened)\n", count, build_ms,
                  std::size_t(s.flat_offset(count)));
    }
    RayQuery fq;
    if (flat_too) fq = cpu->ray_query(*flat_acc);
    for (const char* kind : {"random", "primary"}) {
      const std::vector<Ray> rays = std::string(kind) == "random" ? random_rays(s.bounds(), nrays, 7) : primary_rays(s.bounds(), nrays);
      for (const Query q : {Query::closest, Query::any}) {
        InstanceOutput out;
        const double ti = time_median(repeats, [&] { s.trace(rays, q, out); });
        double tq = NAN, tb2 = NAN;
        if (flat_too) {
          std::vector<Hit> fh(q == Query::closest ? rays.size() : 0);
          std::vector<std::uint8_t> fo(q == Query::any ? rays.size() : 0);
          tq = time_median(repeats, [&] {
            parallel_for(rays.size(), kTraceChunk, threads, [&](std::size_t b, std::size_t e, unsigned) {
              for (std::size_t k = b; k < e; ++k) {
                if (q == Query::closest) fh[k] = fq.intersect(rays[k]);
                else fo[k] = fq.occluded(rays[k]) ? 1 : 0;
              }
            });
          });
          TraceOptions to = fq.options(q);
          TraceOutput bout;
          tb2 = time_median(repeats, [&] { cpu->trace(*flat_acc, rays, to, bout); });
          // -- answers: every ray against the flattened BVH, a sample against the double brute force
          if (q == Query::closest) {
            const Comparison c = compare_flattened(s, flat, rays, out.hits, fh);
            const std::size_t sample = std::min<std::size_t>(rays.size(), 200);
            std::vector<Hit> brute(sample);
            const std::size_t stride = rays.size() / sample;
            std::vector<Ray> srays(sample);
            std::vector<InstanceHit> shits(sample);
            for (std::size_t k = 0; k < sample; ++k) srays[k] = rays[k * stride], shits[k] = out.hits[k * stride];
            parallel_for(sample, 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
              for (std::size_t k = b; k < e; ++k) brute[k] = brute_force(*flat_acc, srays[k]);
            });
            const Comparison cb = compare_flattened(s, flat, srays, shits, brute);
            std::printf("(%s %s, %zu instances: vs flattened BVH %zu equal, %zu ties, %zu mismatches of %zu; vs double "
                        "brute force %zu equal, %zu ties, %zu mismatches of %zu sampled)\n",
                        kind, to_string(q), count, c.equal, c.ties, c.mismatches, c.rays, cb.equal, cb.ties,
                        cb.mismatches, cb.rays);
          } else {
            std::size_t diff = 0;
            for (std::size_t k = 0; k < rays.size(); ++k) diff += out.occluded[k] != fo[k] ? 1 : 0;
            std::printf("(%s %s, %zu instances: %zu of %zu occlusion flags differ from the flattened BVH's)\n", kind,
                        to_string(q), count, diff, rays.size());
          }
        }
        const double mi = double(rays.size()) / ti / 1e6;
        const double mq = double(rays.size()) / tq / 1e6, mb = double(rays.size()) / tb2 / 1e6;
        if (flat_too)
          std::printf("| %zu | %s | %s | %.2f | %.2f | %.2f | %.3f |\n", count, kind, to_string(q), mi, mq, mb,
                      mi / std::max(mq, mb));
        else
          std::printf("| %zu | %s | %s | %.2f | - | - | - |\n", count, kind, to_string(q), mi);
        std::fflush(stdout);
      }
    }
    if (count == n) break;
  }
  return 0;
} catch (const std::exception& e) {
  std::fprintf(stderr, "error: %s\n", e.what());
  return 1;
}

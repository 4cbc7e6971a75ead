// SPDX-License-Identifier: MIT
// test_data_parallel.cpp — mbvh::mpi's data-parallel mode on 2 and 3 ranks (cmake/mpi_tests.cmake):
// partition balance and ids, trace_data_parallel's answers against one process's cpu-scalar on
// the whole scene (bytes equal but for classified ties, settled by the double brute force as
// `mbvh check` does), ordered against broadcast forwarding, a rank without rays, more ranks than
// triangles, degenerate triangles, a scene of views, an invalid ray, and load_scene_part's memory
// share. Any failed check on any rank ends every rank with MPI_Abort(1).
//
//   mpiexec -n P mbvh-mpi-tests                      the checks
//   mpiexec -n P mbvh-mpi-tests bench SCENE COUNT    times and forwards per ray (not a test)
#include <mpi.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "host/core/resources.h"
#include "tests/helpers.h"
#include "host/tools/check.h"
#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/backends.h"
#include "mbvh/compare.h"
#include "mbvh/error.h"
#include "mbvh/mpi.h"
#include "mbvh/trace.h"

namespace {

using namespace mbvh;
using mbvh::mpi::Comm;
using mbvh::mpi::Forwarding;

int g_rank = 0;

[[noreturn]] void fail(const char* file, int line, const std::string& what) {
  std::fprintf(stderr, "rank %d: FAILED %s:%d: %s\n", g_rank, file, line, what.c_str());
  std::fflush(stderr);
  MPI_Abort(MPI_COMM_WORLD, 1);
  std::abort();
}
#define CHECK(cond, ...)                                                         \
  do {                                                                           \
    if (!(cond)) fail(__FILE__, __LINE__, std::string(#cond " ") + __VA_ARGS__); \
  } while (0)

void note(const std::string& s) {
  if (g_rank == 0) std::printf("%s\n", s.c_str()), std::fflush(stdout);
}

std::string scenes_dir() { return MBVH_SCENES_DIR; }

// Rank 0's rays on every rank (MPI_Bcast).
void share(std::vector<Ray>& rays) {
  unsigned long long n = rays.size();
  MPI_Bcast(&n, 1, MPI_UNSIGNED_LONG_LONG, 0, MPI_COMM_WORLD);
  rays.resize(n);
  MPI_Bcast(rays.data(), static_cast<int>(n * sizeof(Ray)), MPI_BYTE, 0, MPI_COMM_WORLD);
}

// The answers of trace_data_parallel for `rays` (the same on every rank), each rank owning a
// contiguous slice (rank `idle`, if any, none), gathered in ray order on rank 0; the forward
// statistics summed over the ranks (rounds: the largest).
struct DpRun {
  std::vector<Hit> hits;
  std::vector<std::uint8_t> occluded;
  unsigned long long invalid = 0, rays = 0, forwards = 0;
  unsigned rounds = 0;
  double seconds = 0;
};

DpRun run_dp(Backend& backend, const mpi::Part& part, const std::vector<Ray>& rays, const TraceOptions& opt,
             Forwarding f, int idle = -1) {
  const int P = part.ranks, me = part.rank;
  const int owners = idle >= 0 && P > 1 ? P - 1 : P;
  auto slot = [&](int r) { return idle >= 0 && P > 1 ? (r == idle ? -1 : (r > idle ? r - 1 : r)) : r; };
  auto begin = [&](int s) { return rays.size() * s / owners; };
  const int s = slot(me);
  const std::size_t b = s < 0 ? 0 : begin(s), e = s < 0 ? 0 : begin(s + 1);
  TraceOutput out;
  MPI_Barrier(MPI_COMM_WORLD);
  const double t0 = MPI_Wtime();
  mpi::trace_data_parallel(Comm{}, backend, part, std::span<const Ray>(rays.data() + b, e - b), opt, out, nullptr, f);
  DpRun run;
  run.seconds = MPI_Wtime() - t0;
  MPI_Allreduce(MPI_IN_PLACE, &run.seconds, 1, MPI_DOUBLE, MPI_MAX, MPI_COMM_WORLD);
  const mpi::ForwardStats st = mpi::last_forward_stats();
  CHECK(st.rays == e - b, "");
  unsigned long long v[3] = {out.invalid, st.rays, st.forwards};
  MPI_Allreduce(MPI_IN_PLACE, v, 3, MPI_UNSIGNED_LONG_LONG, MPI_SUM, MPI_COMM_WORLD);
  run.invalid = v[0], run.rays = v[1], run.forwards = v[2];
  unsigned rmin = st.rounds, rmax = st.rounds;
  MPI_Allreduce(MPI_IN_PLACE, &rmin, 1, MPI_UNSIGNED, MPI_MIN, MPI_COMM_WORLD);
  MPI_Allreduce(MPI_IN_PLACE, &rmax, 1, MPI_UNSIGNED, MPI_MAX, MPI_COMM_WORLD);
  CHECK(rmin == rmax, "rounds differ between ranks: " + std::to_string(rmin) + " and " + std::to_string(rmax));
  CHECK(rmax <= static_cast<unsigned>(P) + 0u, "rounds " + std::to_string(rmax) + " > ranks");
  run.rounds = rmax;
  // -- gather in ray order on rank 0
  const bool any = opt.query == Query::any;
  const int each = any ? 1 : static_cast<int>(sizeof(Hit));
  const int mine = static_cast<int>((e - b) * each);
  std::vector<int> counts(P), displs(P);
  MPI_Gather(&mine, 1, MPI_INT, counts.data(), 1, MPI_INT, 0, MPI_COMM_WORLD);
  int total = 0;
  for (int r = 0; r < P; ++r) displs[r] = total, total += counts[r];
  std::vector<unsigned char> all(me == 0 ? total : 0);
  const void* src = any ? static_cast<const void*>(out.occluded.data()) : static_cast<const void*>(out.hits.data());
  MPI_Gatherv(src, mine, MPI_BYTE, all.data(), counts.data(), displs.data(), MPI_BYTE, 0, MPI_COMM_WORLD);
  if (me == 0) {
    CHECK(static_cast<std::size_t>(total) == rays.size() * each, "");
    if (any)
      run.occluded.assign(all.begin(), all.end());
    else {
      run.hits.resize(rays.size());
      std::memcpy(run.hits.data(), all.data(), all.size());
    }
  }
  return run;
}

// Rank 0: `run`'s answers against one process's cpu-scalar on the whole scene. Zero genuine
// mismatches after the oracle's settlement (check.cpp's rules), at least 99.99 % of the rays'
// answers equal bit for bit.
void compare_with_one_process(const Accel* whole_on_root, Backend& reference, const std::vector<Ray>& rays,
                              const TraceOptions& opt, const DpRun& run, const std::string& label) {
  if (g_rank != 0) return;
  const Accel& whole = *whole_on_root;
  TraceOutput ref;
  reference.trace(whole, rays, opt, ref);
  std::size_t bit_same = 0, hits = 0;
  Comparison c;
  if (opt.query == Query::closest) {
    const TieRule settle = oracle_settlement(whole, rays, oracle_tie_rule(whole, rays));
    c = compare_hit_arrays(run.hits, ref.hits, {}, settle);
    for (std::size_t i = 0; i < rays.size(); ++i)
      bit_same += std::memcmp(&run.hits[i], &ref.hits[i], sizeof(Hit)) == 0, hits += run.hits[i].prim != MBVH_MISS_PRIM;
  } else {
    TraceOutput closest;
    TraceOptions co = opt;
    co.query = Query::closest;
    reference.trace(whole, rays, co, closest);
    // a flag differing from the reference's is legitimate if it agrees with the brute force, or
    // the brute force's hit lies on an edge or at the interval's ends (compare_occlusion's ties)
    const TieRule settle = [&](std::size_t i, const Hit&, const Hit&) {
      const Hit o = brute_force(whole, rays[i]);
      for (std::uint8_t f : {run.occluded[i], ref.occluded[i]})
        if ((f != 0) != (o.prim != MBVH_MISS_PRIM) &&
            !(o.prim != MBVH_MISS_PRIM && compare_occlusion(1, 0, o, rays[i]) == Verdict::tie))
          return false;
      return true;
    };
    c = compare_occlusion_arrays(run.occluded, ref.occluded, closest.hits, rays, {}, {}, settle);
    for (std::size_t i = 0; i < rays.size(); ++i)
      bit_same += run.occluded[i] == ref.occluded[i], hits += run.occluded[i];
  }
  char line[400];
  std::snprintf(
      line, sizeof line,
      "  %-44s %6zu rays, %6zu hit: %6zu bit-same, %zu ties, %zu mismatches; rounds %u, forwards/ray %.3f, %.3f s",
      label.c_str(), rays.size(), hits, bit_same, c.ties, c.mismatches, run.rounds,
      run.rays ? double(run.forwards) / double(run.rays) : 0.0, run.seconds);
  note(line);
  CHECK(c.mismatches == 0, label + ": " + std::to_string(c.mismatches) + " genuine mismatches, first ray " +
                               std::to_string(c.first_mismatches.empty() ? 0 : c.first_mismatches[0]));
  CHECK(double(bit_same) >= 0.9999 * double(rays.size()),
        label + ": only " + std::to_string(bit_same) + " of " + std::to_string(rays.size()) + " answers bit-identical");
}

// Rank 0 builds the whole scene and makes the rays; every rank gets them.
std::vector<Ray> make_rays(const Scene& scene, const Accel* whole, RayKind kind, std::size_t count) {
  std::vector<Ray> rays;
  if (g_rank == 0) {
    RayGenOptions o;
    o.kind = kind;
    o.count = count;
    o.seed = 7;
    o.threads = 1;
    rays = generate_rays(scene, *whole, o);
  }
  share(rays);
  return rays;
}

// -- the checks

// The partition: every non-degenerate triangle on exactly one rank, ids ascending, counts
// balanced, boxes those of the parts, the whole scene's bounds.
void check_partition(const Scene& scene, const mpi::Part& part, std::size_t non_degenerate) {
  const int P = part.ranks;
  CHECK(part.rank_triangles.size() == static_cast<std::size_t>(P) &&
            part.rank_bounds.size() == static_cast<std::size_t>(P),
        "");
  std::uint64_t sum = 0, largest = 0;
  for (std::uint64_t c : part.rank_triangles) sum += c, largest = std::max(largest, c);
  CHECK(sum == non_degenerate, std::to_string(sum) + " vs " + std::to_string(non_degenerate));
  if (non_degenerate >= 10u * P)
    CHECK(double(largest) <= 1.1 * double(non_degenerate) / P,
          "largest part " + std::to_string(largest) + " of " + std::to_string(non_degenerate));
  CHECK(part.local_to_global.size() == part.rank_triangles[part.rank], "");
  CHECK(std::is_sorted(part.local_to_global.begin(), part.local_to_global.end()), "");
  CHECK(std::adjacent_find(part.local_to_global.begin(), part.local_to_global.end()) == part.local_to_global.end(), "");
  CHECK(part.scene.triangle_count() == part.local_to_global.size() + (part.anchor != MBVH_MISS_PRIM), "");
  CHECK(part.scene.vertices.empty(), "the part copied the vertex array");
  for (std::size_t i = 0; i < part.local_to_global.size(); ++i) {  // the same triangle, by global id
    Vec3f a, b, c, x, y, z;
    scene.triangle(part.local_to_global[i], a, b, c);
    part.scene.triangle(i, x, y, z);
    CHECK(std::memcmp(&a, &x, 12) == 0 && std::memcmp(&b, &y, 12) == 0 && std::memcmp(&c, &z, 12) == 0, "");
  }
  CHECK((part.accel != nullptr) == !part.local_to_global.empty(), "");
  // every id on one rank only: the sum of the ids and of their squares over the ranks
  unsigned long long s[2] = {0, 0};
  for (std::uint32_t id : part.local_to_global) s[0] += id, s[1] += 1ull * id * id;
  MPI_Allreduce(MPI_IN_PLACE, s, 2, MPI_UNSIGNED_LONG_LONG, MPI_SUM, MPI_COMM_WORLD);
  unsigned long long w[2] = {0, 0};
  for (std::size_t p = 0; p < scene.triangle_count(); ++p) {
    if (!mbvh_test::zero_area(scene, p)) w[0] += p, w[1] += 1ull * p * p;
  }
  CHECK(s[0] == w[0] && s[1] == w[1], "the parts' ids are not the non-degenerate triangles once each");
  Box all;
  for (const Box& b : part.rank_bounds) all.grow(b);
  CHECK(std::memcmp(&all, &part.scene_bounds, sizeof(Box)) == 0, "");
}

// One scene: partition, then every kind and query against one process, ordered and broadcast.
void check_scene(const std::string& spec, const std::vector<RayKind>& kinds, std::size_t count, bool broadcast_too) {
  const Scene scene = mpi::load_scene_part(spec, static_cast<unsigned>(Comm{}.size()));
  BuildOptions bo;
  bo.threads = 1;
  std::unique_ptr<Accel> whole;
  if (g_rank == 0) whole = Accel::build(scene, bo);
  unsigned long long nd = whole ? scene.triangle_count() - whole->degenerate_triangles() : 0;
  MPI_Bcast(&nd, 1, MPI_UNSIGNED_LONG_LONG, 0, MPI_COMM_WORLD);
  const mpi::Part part = mpi::partition(Comm{}, scene, bo);
  check_partition(scene, part, nd);
  if (whole)
    CHECK(std::memcmp(&whole->bounds(), &part.scene_bounds, sizeof(Box)) == 0, "scene bounds differ from one build's");
  std::string parts;
  for (int r = 0; r < part.ranks; ++r) {
    const Box& b = part.rank_bounds[r];
    char line[200];
    std::snprintf(line, sizeof line, "\n  part %d: %llu triangles, box (%g %g %g) - (%g %g %g)", r,
                  static_cast<unsigned long long>(part.rank_triangles[r]), b.lo.x, b.lo.y, b.lo.z, b.hi.x, b.hi.y,
                  b.hi.z);
    parts += line;
  }
  note(spec + ": " + std::to_string(nd) + " triangles on " + std::to_string(part.ranks) + " ranks" + parts);
  auto backend = make_backend("cpu-scalar", BackendOptions{1, {}});
  for (RayKind k : kinds) {
    const std::vector<Ray> rays = make_rays(scene, whole.get(), k, count);
    for (Query q : {Query::closest, Query::any}) {
      TraceOptions opt;
      opt.query = q;
      const std::string label = spec.substr(spec.rfind('/') + 1) + " " + to_string(k) + " " + to_string(q);
      const DpRun ordered = run_dp(*backend, part, rays, opt, Forwarding::ordered, k == RayKind::shadow ? 0 : -1);
      CHECK(ordered.invalid == 0 || k != RayKind::primary, "");
      compare_with_one_process(whole.get(), *backend, rays, opt, ordered, label + " ordered");
      if (!broadcast_too) continue;
      const DpRun all = run_dp(*backend, part, rays, opt, Forwarding::broadcast);
      CHECK(all.rounds <= 1, "");
      compare_with_one_process(whole.get(), *backend, rays, opt, all, label + " broadcast");
      CHECK(ordered.forwards <= all.forwards, label + ": ordered forwards " + std::to_string(ordered.forwards) +
                                                  " > broadcast's " + std::to_string(all.forwards));
    }
  }
}

// A scene of one triangle: on 2 and 3 ranks, all but one rank hold nothing; a ray through it,
// one beside it, and an invalid one, counted once.
void check_one_triangle() {
  Scene s;
  s.name = "one triangle";
  s.vertices = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}};
  s.triangles = {{0, 1, 2}};
  const mpi::Part part = mpi::partition(Comm{}, s, BuildOptions{});
  check_partition(s, part, 1);
  std::vector<Ray> rays = {Ray{0.25f, 0.25f, 1, 0, 0, 0, -1, INFINITY}, Ray{2, 2, 1, 0, 0, 0, -1, INFINITY},
                           Ray{NAN, 0, 1, 0, 0, 0, -1, INFINITY}, Ray{0.25f, 0.25f, 1, 0, 0, 0, -1, 0.5f}};
  auto backend = make_backend("cpu-scalar", BackendOptions{1, {}});
  for (Forwarding f : {Forwarding::ordered, Forwarding::broadcast}) {
    TraceOptions opt;
    const DpRun c = run_dp(*backend, part, rays, opt, f, part.ranks - 1);
    CHECK(c.invalid == 1, "invalid rays counted " + std::to_string(c.invalid) + " times");
    CHECK(c.forwards == 1, std::to_string(c.forwards));
    if (g_rank == 0) {
      CHECK(c.hits[0].prim == 0 && c.hits[0].t == 1.0f, "");
      CHECK(c.hits[1].prim == MBVH_MISS_PRIM && c.hits[2].prim == MBVH_MISS_PRIM && c.hits[3].prim == MBVH_MISS_PRIM,
            "");
    }
    opt.query = Query::any;
    const DpRun a = run_dp(*backend, part, rays, opt, f);
    CHECK(a.invalid == 1, "");
    if (g_rank == 0) CHECK(a.occluded == std::vector<std::uint8_t>({1, 0, 0, 0}), "");
  }
  note("one triangle: " + std::to_string(part.ranks) + " ranks, an invalid ray counted once");
}

// A scene of views (two meshes over one vertex buffer, a stride of 16): the part keeps the
// geometries apart and the global ids right.
void check_views() {
  const Scene owned = load_scene("gen:sphere:24");
  std::vector<float> v;
  for (const Vec3f& p : owned.vertices) v.insert(v.end(), {p.x, p.y, p.z, 0.0f});
  std::vector<std::uint32_t> idx;
  for (const auto& t : owned.triangles) idx.insert(idx.end(), {t[0], t[1], t[2]});
  Scene views;
  views.name = "two views";
  const std::size_t half = owned.triangles.size() / 2;
  views.add_mesh(MeshView{v.data(), owned.vertices.size(), 16, idx.data(), half, 12});
  views.add_mesh(
      MeshView{v.data(), owned.vertices.size(), 16, idx.data() + 3 * half, owned.triangles.size() - half, 12});
  const mpi::Part part = mpi::partition(Comm{}, views, BuildOptions{});
  check_partition(views, part, owned.triangles.size());
  std::unique_ptr<Accel> whole = g_rank == 0 ? Accel::build(views) : nullptr;
  const std::vector<Ray> rays = make_rays(views, whole.get(), RayKind::random, 4000);
  auto backend = make_backend("cpu-scalar", BackendOptions{1, {}});
  TraceOptions opt;
  const DpRun r = run_dp(*backend, part, rays, opt, Forwarding::ordered);
  compare_with_one_process(whole.get(), *backend, rays, opt, r, "two views random closest ordered");
}

float largest_magnitude(const Box& b) {
  return std::max({std::fabs(b.lo.x), std::fabs(b.lo.y), std::fabs(b.lo.z), std::fabs(b.hi.x), std::fabs(b.hi.y),
                   std::fabs(b.hi.z)});
}

// A part of tiny coordinates beside a scene of unit ones: half the triangles within 2^-38 of the
// origin (alone, below kMinSceneScale: Accel::build would refuse them), half near (1, 1, 1). The
// part builds the anchor with them, and a ray with a long direction, which the whole scene accepts
// but the tiny part's own range would refuse (S^3 / D below kMinRayCube), is traced as in one process.
void check_tiny_part() {
  Scene s;
  s.name = "tiny and unit";
  const float e = 0x1p-44f;
  for (int i = 0; i < 64; ++i) {  // tiny: a fan of slivers in z = 0; unit: a row of triangles in z = 1
    const float x = e * static_cast<float>(i);
    const std::uint32_t v = static_cast<std::uint32_t>(s.vertices.size());
    s.vertices.insert(s.vertices.end(), {{x, 0, 0}, {x + e, 0, 0}, {x, e, 0}});
    s.triangles.push_back({v, v + 1, v + 2});
  }
  for (int i = 0; i < 64; ++i) {
    const float x = 1 + 0.01f * static_cast<float>(i);
    const std::uint32_t v = static_cast<std::uint32_t>(s.vertices.size());
    s.vertices.insert(s.vertices.end(), {{x, 1, 1}, {x + 0.01f, 1, 1}, {x, 1.01f, 1}});
    s.triangles.push_back({v, v + 1, v + 2});
  }
  const mpi::Part part = mpi::partition(Comm{}, s, BuildOptions{});
  check_partition(s, part, s.triangles.size());
  int anchored = part.anchor != MBVH_MISS_PRIM;
  MPI_Allreduce(MPI_IN_PLACE, &anchored, 1, MPI_INT, MPI_SUM, MPI_COMM_WORLD);
  CHECK(anchored >= 1, "no part of tiny coordinates built the anchor");
  if (part.anchor != MBVH_MISS_PRIM)
    CHECK(largest_magnitude(part.accel->bounds()) == largest_magnitude(part.scene_bounds), "");
  std::unique_ptr<Accel> whole = g_rank == 0 ? Accel::build(s) : nullptr;
  std::vector<Ray> rays;
  for (int i = 0; i < 64; ++i)  // down onto the slivers, directions 2^28 long; and onto the unit row
    rays.push_back(Ray{e * (static_cast<float>(i) + 0.25f), e * 0.25f, 1, 0, 0, 0, -0x1p28f, INFINITY});
  for (int i = 0; i < 64; ++i)
    rays.push_back(Ray{1.0025f + 0.01f * static_cast<float>(i), 1.0025f, 2, 0, 0, 0, -1, INFINITY});
  auto backend = make_backend("cpu-scalar", BackendOptions{1, {}});
  for (Query q : {Query::closest, Query::any}) {
    TraceOptions opt;
    opt.query = q;
    const DpRun r = run_dp(*backend, part, rays, opt, Forwarding::ordered);
    compare_with_one_process(whole.get(), *backend, rays, opt, r, std::string("tiny part ") + to_string(q));
    if (g_rank == 0 && q == Query::closest)
      for (std::size_t i = 0; i < rays.size(); ++i) CHECK(r.hits[i].prim == i, "ray " + std::to_string(i));
  }
}

// load_scene_part counts 1/parts of the build: a budget that refuses the whole build admits a
// quarter of it (each rank on its own: not collective).
void check_memory_share() {
  const std::string spec = "gen:hairball:19200";  // 100 tubes of 102 vertices: the generator's estimate is exact
  const Scene s = load_scene(spec);
  const std::uint64_t t = s.triangles.size(), v = s.vertices.size();
  const std::uint64_t whole = scene_memory_estimate(t, v), build = build_memory_estimate(t, v);
  const std::uint64_t limit = whole - build / 2;  // the scene and half a build
  const char* before = std::getenv("MBVH_MEMORY_LIMIT");
  const std::string saved = before ? before : "";
  setenv("MBVH_MEMORY_LIMIT", std::to_string(limit).c_str(), 1);
  bool refused = false;
  try {
    load_scene(spec);
  } catch (const Error& e) {
    refused = std::string(e.what()).find("needs about") != std::string::npos;
  }
  CHECK(refused, "load_scene was not refused under MBVH_MEMORY_LIMIT=" + std::to_string(limit));
  std::string error;
  try {
    const Scene part = mpi::load_scene_part(spec, 4);
    CHECK(part.triangles.size() == t, "");
  } catch (const Error& e) {
    error = e.what();
  }
  CHECK(error.empty(), "load_scene_part(4) refused: " + error);
  CHECK(build_share() == 1, "the share outlived load_scene_part");
  try {  // the share is gone: the whole build is refused again
    load_scene(spec);
    refused = false;
  } catch (const Error&) {
    refused = true;
  }
  CHECK(refused, "load_scene after load_scene_part was not refused");
  if (before)
    setenv("MBVH_MEMORY_LIMIT", saved.c_str(), 1);
  else
    unsetenv("MBVH_MEMORY_LIMIT");
  note("memory share: MBVH_MEMORY_LIMIT=" + std::to_string(limit) + " refuses load_scene, admits load_scene_part(4)");
}

// `bench SCENE COUNT`: one process's cpu-scalar (rank 0, one thread) against the ordered and
// broadcast data-parallel traces of primary and diffuse rays, with rounds and forwards per ray.
void bench(const std::string& spec, std::size_t count) {
  const Scene scene = mpi::load_scene_part(spec, static_cast<unsigned>(Comm{}.size()));
  BuildOptions bo;
  bo.threads = 1;
  std::unique_ptr<Accel> whole;
  if (g_rank == 0) whole = Accel::build(scene, bo);
  const mpi::Part part = mpi::partition(Comm{}, scene, bo);
  auto backend = make_backend("cpu-scalar", BackendOptions{1, {}});
  for (RayKind k : {RayKind::primary, RayKind::diffuse}) {
    const std::vector<Ray> rays = make_rays(scene, whole.get(), k, count);
    for (Query q : {Query::closest, Query::any}) {
      TraceOptions opt;
      opt.query = q;
      double one = 0;
      if (g_rank == 0) {
        TraceOutput o;
        backend->trace(*whole, rays, opt, o);  // warm: the layout made
        const double t0 = MPI_Wtime();
        backend->trace(*whole, rays, opt, o);
        one = MPI_Wtime() - t0;
      }
      for (Forwarding f : {Forwarding::ordered, Forwarding::broadcast}) {
        run_dp(*backend, part, rays, opt, f);  // warm
        const DpRun r = run_dp(*backend, part, rays, opt, f);
        char line[300];
        std::snprintf(line, sizeof line,
                      "%s %s %s %s on %d ranks: %.3f s (one process, one thread: %.3f s), rounds %u, forwards/ray %.3f",
                      spec.c_str(), to_string(k), to_string(q), mpi::to_string(f), part.ranks, r.seconds, one, r.rounds,
                      double(r.forwards) / double(r.rays));
        note(line);
      }
    }
  }
}

}  // namespace

int main(int argc, char** argv) {
  MPI_Init(&argc, &argv);
  MPI_Comm_rank(MPI_COMM_WORLD, &g_rank);
  try {
    register_builtin_backends();
    if (argc == 4 && std::string(argv[1]) == "bench") {
      bench(argv[2], std::stoull(argv[3]));
    } else {
      check_memory_share();
      check_one_triangle();
      check_views();
      check_tiny_part();
      check_scene("gen:needles:3000", {RayKind::primary, RayKind::random}, 10000, true);
      check_scene("gen:hairball:100000", {RayKind::primary, RayKind::shadow, RayKind::diffuse}, 20000, true);
      check_scene(scenes_dir() + "/conference.obj.zst", {RayKind::primary, RayKind::shadow, RayKind::diffuse}, 30000,
                  true);
      note("data-parallel: all checks passed");
    }
  } catch (const std::exception& e) {
    std::fprintf(stderr, "rank %d: FAILED: %s\n", g_rank, e.what());
    std::fflush(stderr);
    MPI_Abort(MPI_COMM_WORLD, 1);
  }
  MPI_Finalize();
  return 0;
}

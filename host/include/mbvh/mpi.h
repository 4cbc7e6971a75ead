// SPDX-License-Identifier: MIT
// mpi.h — mbvh beyond one process, on MPI (library mbvh::mpi, CMake MBVH_MPI; find_package(mbvh
// COMPONENTS mpi)). The core library and the `mbvh` program never link libmpi: only this library
// and the `mbvh-mpi` program do.
//
// Two ways to spread work over the ranks of a communicator:
//  - replicated (ray-parallel): every rank holds the whole scene and the same BVH (shared_accel:
//    one rank builds, the others read the same build and every rank checks its hash); the rays are
//    split in fixed batches (trace). Each ray is traced by the same traversal on the same tree as in
//    one process, so the answers are bit-identical to one process at any rank and thread count.
//  - data-parallel: each rank builds the BVH of one part of the scene (partition: Morton-ordered
//    groups of equal triangle counts, global prim ids kept); rays are forwarded between the ranks
//    in bulk-synchronous rounds (trace_data_parallel), nearest part first, with the best hit so
//    far, and the ray's owner keeps the lexicographic minimum of (t, prim): the one-process answer
//    except at the order-dependent ties of docs/backends.md (a box culled by a shrunken tmax).
// Every function here is collective: every rank of the communicator calls it, in the same order.
// Errors are thrown as mbvh::Error on the rank that found them; a program turns one into
// MPI_Abort (mbvh-mpi: exit status 2, the rank named), since the other ranks wait in a collective.
#pragma once
#include <mpi.h>

#include <array>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"

namespace mbvh::mpi {

/// A communicator (MPI_COMM_WORLD by default; not owned).
struct Comm {
  MPI_Comm comm = MPI_COMM_WORLD;
  int rank() const;
  int size() const;
  bool root() const { return rank() == 0; }
};

/// What this rank spent in MPI calls (wall seconds, bytes it sent and received, calls), added to
/// by every function that takes one: `mbvh-mpi bench` reports it against the wall time.
struct Traffic {
  double seconds = 0;
  std::uint64_t bytes_sent = 0, bytes_received = 0;
  std::uint64_t calls = 0;
  void add(const Traffic& o) {
    seconds += o.seconds;
    bytes_sent += o.bytes_sent;
    bytes_received += o.bytes_received;
    calls += o.calls;
  }
};

// -- replicated: every rank holds the scene and one BVH

/// The BVH of `scene` (every rank passes the same scene and options), built once: the root builds
/// it through the cache in `cache.dir` (Accel::build_cached), then the others read that entry (a
/// rank on another host without the directory builds and writes its own); every rank's
/// Accel::hash() is then compared (an Error names the ranks that differ). An empty cache.dir: a
/// private directory under $TMPDIR (else /tmp), removed before this returns.
std::unique_ptr<Accel> shared_accel(const Comm& comm, const Scene& scene, const BuildOptions& opt,
                                    const Accel::CacheOptions& cache, Accel::CacheReport* report = nullptr,
                                    Traffic* traffic = nullptr);

/// How trace() and render tiles split the work: fixed batches, dealt round-robin (static: batch
/// i to rank i mod P), or claimed at run time (dynamic: each rank takes the batches of its static
/// share first and then steals from the rank with the most left, OSPRay's queue with stealing;
/// one-sided MPI atomics, no rank serves requests).
enum class Schedule { static_batches, dynamic };
const char* to_string(Schedule s);
Schedule parse_schedule(const std::string& s);  ///< "static" or "dynamic"; throws Error otherwise

/// The dynamic schedule's work queue: `total` items (batches, tiles) in P queues, queue r holding
/// the contiguous share [total*r/P, total*(r+1)/P) of rank r. next() takes the next item of this
/// rank's queue and, once that is empty, steals from the queue with the most items left, until
/// every queue is empty (-1). The counters live in a window on rank 0, changed by one-sided atomic
/// fetch-and-add (MPI_Fetch_and_op): no rank serves requests. Collective construction and
/// destruction; next() is called by each rank alone, any number of times.
class WorkQueue {
public:
  WorkQueue(const Comm& comm, std::uint64_t total, Traffic* traffic = nullptr);
  ~WorkQueue();
  WorkQueue(const WorkQueue&) = delete;
  WorkQueue& operator=(const WorkQueue&) = delete;
  std::int64_t next();
  /// The first item of rank r's queue (r = P: total).
  std::uint64_t queue_begin(int r) const;

private:
  Comm comm_;
  std::uint64_t total_;
  Traffic* traffic_;
  MPI_Win win_ = MPI_WIN_NULL;
};

struct ScheduleOptions {
  Schedule schedule = Schedule::static_batches;
  std::size_t batch = 65536;  ///< rays per batch (at least 1)
  /// Where every rank runs on one host: rays and answers through a window of shared memory (MPI-3,
  /// two copies a byte). False: as messages, as across hosts (MPI_Scatterv and MPI_Gatherv, or
  /// one-sided MPI_Get for the dynamic schedule).
  bool shared_memory = true;
};

/// Traces `rays` (read on the root only; the other ranks pass an empty span) on every rank's
/// `backend` over the replicated `acc`, in batches; `out` (on the root) receives every ray's
/// answer in ray order, bit for bit what backend.trace gives in one process. opt.stats is refused.
void trace(const Comm& comm, Backend& backend, const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt,
           TraceOutput& out, const ScheduleOptions& schedule = {}, Traffic* traffic = nullptr);

// -- data-parallel: every rank holds the scene's mesh and the BVH of its part

/// Loads a scene that will be partitioned over `parts` ranks: load_scene, with its memory check
/// counting the scene and 1/parts of one build of it (each rank builds only its part): under
/// MBVH_MEMORY_LIMIT=B, a scene whose build load_scene refuses in one process may load on each of
/// `parts` ranks. Not collective (each rank loads on its own); parts 0 counts as 1. Throws as
/// load_scene does.
Scene load_scene_part(const std::string& path_or_spec, unsigned parts);

/// This rank's part of the scene: the triangles it owns, their BVH and every rank's bounds.
struct Part {
  int rank = 0, ranks = 1;
  Box scene_bounds;                        ///< of the whole scene's non-degenerate triangles
  std::vector<Box> rank_bounds;            ///< every rank's part (an empty box: no triangle)
  std::vector<std::uint64_t> rank_triangles;  ///< every rank's triangle count
  std::vector<std::uint32_t> local_to_global; ///< this rank's triangles' global prim ids, ascending
  /// The anchor: a triangle of the whole scene (global id) that reaches its largest coordinate
  /// magnitude, built into this part as one more triangle (local id local_to_global.size(), last)
  /// when the part's own triangles all lie nearer the origin; MBVH_MISS_PRIM when not. The exactly
  /// traced range is the scene's (Accel::build's kMinSceneScale, check_ray_range's S): without it a
  /// part of small coordinates could refuse its build or a ray the whole scene accepts. It is a
  /// real triangle, answered with its global id (as the part that owns it answers), so the owner's
  /// minimum is unchanged; rank_bounds and the routing leave it out.
  std::uint32_t anchor = 0xFFFFFFFFu;
  Scene scene;                             ///< this rank's triangles (views into the whole scene's mesh)
  /// The vertex indices of this rank's triangles (local triangle i: global local_to_global[i]),
  /// then the anchor's if any, which `scene`'s views read; the vertices are the whole scene's, not copied.
  std::vector<std::array<std::uint32_t, 3>> indices;
  std::unique_ptr<Accel> accel;            ///< their BVH; null when this rank has no triangle
};

/// Splits `scene` (every rank passes the same) into comm.size() parts of equal triangle counts, in
/// Morton order of the triangles' centroids, and builds this rank's part with `opt`. The whole
/// scene must outlive the Part (its scene views the mesh). Degenerate (zero-area) triangles go to
/// no part (no build keeps them: they are never hit); the others keep their global prim ids. With
/// fewer triangles than ranks some ranks get none (accel null, an empty box). Throws Error as
/// Scene::validate and Accel::build do (a triangle too small to trace is named by its global id),
/// and when the ranks' scenes differ (their triangle counts do). Cost: O(T log T) on every rank
/// (the sort), one build of T/P triangles, one MPI_Allgather of P boxes.
Part partition(const Comm& comm, const Scene& scene, const BuildOptions& opt, Traffic* traffic = nullptr);

/// How trace_data_parallel forwards rays. ordered: the parts in order of the ray's entry into
/// their boxes, one a round, each with the best t so far as tmax, until no part left can hold a
/// nearer hit (closest) or one occludes the ray (any) — the design of docs/mpi.md. broadcast: the
/// baseline, every ray sent at once to every part whose box it enters, with its own tmax (one
/// round; more forwards and more work per ray, the same answers up to the same ties).
enum class Forwarding { ordered, broadcast };
const char* to_string(Forwarding f);
Forwarding parse_forwarding(const std::string& s);  ///< "ordered" or "broadcast"; throws Error otherwise

/// Traces `rays` (this rank's own: any number, empty included) over every rank's part: each ray
/// visits the parts its box test reaches, nearest entry first, each with its best t so far, in
/// bulk-synchronous rounds (MPI_Alltoallv), until no part left can hold a nearer hit (closest) or
/// one part occludes it (any). `out` receives this rank's answers, in its ray order, global prim
/// ids; out.invalid counts this rank's invalid rays (defined misses, never forwarded). The answers
/// are one process's on the whole scene except the order-dependent ties of docs/backends.md.
/// opt.stats is refused; every rank passes the same options and backend. Throws Error (on the rank
/// that owns the ray) for a ray outside the range traced exactly in the whole scene (as
/// check_ray_range against its bounds); a part never refuses a ray the whole scene accepts (its
/// build has the scene's range: Part::anchor).
/// Cost: at most P rounds of an MPI_Alltoall, two MPI_Alltoallv and an MPI_Allreduce; each ray is traced on the
/// parts it visits.
void trace_data_parallel(const Comm& comm, Backend& backend, const Part& part, std::span<const Ray> rays,
                         const TraceOptions& opt, TraceOutput& out, Traffic* traffic = nullptr,
                         Forwarding forwarding = Forwarding::ordered);

/// What the last trace_data_parallel call on this rank did: rounds (exchange rounds, the same on
/// every rank), this rank's own rays, and forwards (this rank's own rays sent to a part, its own
/// included: a ray that visits three parts counts three). forwards / rays is what the ordered
/// forwarding saves over broadcast.
struct ForwardStats {
  unsigned rounds = 0;
  std::uint64_t rays = 0, forwards = 0;
};
ForwardStats last_forward_stats();

}  // namespace mbvh::mpi

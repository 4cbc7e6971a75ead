// SPDX-License-Identifier: MIT
// data_parallel.cpp — mbvh::mpi's data-parallel mode (mbvh/mpi.h): every rank holds the whole
// scene's mesh and the BVH of one part of it (partition: Morton-ordered groups of equal triangle
// counts, global prim ids kept), and rays travel to the parts in bulk-synchronous rounds
// (trace_data_parallel), each ray's owner keeping the lexicographic minimum of (t, prim).
//
// Ray forwarding between the owners of scene parts follows the data-parallel schedulers of
// Reinhard & Jansen (1995) and Navrátil et al. (EGPGV 2012), here in its bulk-synchronous form:
// one MPI_Alltoallv of rays and one of answers a round, each ray sent to the nearest part it has
// not visited whose box it enters within its best t so far (docs/mpi.md, "Data-parallel").
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <numeric>
#include <string>
#include <utility>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/resources.h"
#include "host/core/trace/intersect.h"
#include "host/core/trace/ray_range.h"
#include "host/mpi/calls.h"
#include "mbvh/error.h"
#include "mbvh/mpi.h"

namespace mbvh::mpi {

Scene load_scene_part(const std::string& path_or_spec, unsigned parts) {
  const ScopedBuildShare share(parts);
  return load_scene(path_or_spec);
}

const char* to_string(Forwarding f) { return f == Forwarding::broadcast ? "broadcast" : "ordered"; }

Forwarding parse_forwarding(const std::string& s) {
  if (s == "ordered") return Forwarding::ordered;
  if (s == "broadcast") return Forwarding::broadcast;
  throw Error("unknown forwarding '" + s + "' (known: ordered, broadcast)");
}

namespace {

// -- MPI helpers: a contiguous datatype of one record, the count exchange and MPI_Alltoallv

// A committed MPI datatype of `bytes` contiguous bytes (one ray, one hit): counts and
// displacements then count records, not bytes, so a round may move up to INT_MAX records a rank.
class Contiguous {
 public:
  Contiguous(std::size_t bytes, Traffic* t) {
    detail::call(t, "MPI_Type_contiguous", 0, 0,
                 [&] { return MPI_Type_contiguous(static_cast<int>(bytes), MPI_BYTE, &type_); });
    try {
      detail::call(t, "MPI_Type_commit", 0, 0, [&] { return MPI_Type_commit(&type_); });
    } catch (...) {
      MPI_Type_free(&type_);
      throw;
    }
  }
  // A destructor cannot throw: the one MPI call here not made through detail::call.
  ~Contiguous() { MPI_Type_free(&type_); }
  Contiguous(const Contiguous&) = delete;
  Contiguous& operator=(const Contiguous&) = delete;
  MPI_Datatype get() const { return type_; }

 private:
  MPI_Datatype type_ = MPI_DATATYPE_NULL;
};

// Every rank tells every other how many records it sends it (MPI_Alltoall): returns what this
// rank receives from each.
std::vector<std::uint64_t> exchange_counts(const Comm& comm, const std::vector<std::uint64_t>& send, Traffic* t) {
  const std::size_t P = send.size();
  std::vector<int> s(P), r(P, 0);
  for (std::size_t d = 0; d < P; ++d) s[d] = detail::count(send[d], "records sent to one rank in a round");
  detail::call(t, "MPI_Alltoall", 4 * P, 4 * P,
               [&] { return MPI_Alltoall(s.data(), 1, MPI_INT, r.data(), 1, MPI_INT, comm.comm); });
  return std::vector<std::uint64_t>(r.begin(), r.end());
}

// MPI_Alltoallv of records of type `type`: `send` holds the records for rank 0, then rank 1, ...
// (send_counts), and the result those from rank 0, then rank 1, ... (recv_counts). Counts and
// displacements beyond INT_MAX records are an Error. Bytes counted in `t`: those to and from
// other ranks (a rank's records to itself do not leave it).
template <class T>
void alltoallv(const Comm& comm, const Contiguous& type, const std::vector<T>& send,
               const std::vector<std::uint64_t>& send_counts, const std::vector<std::uint64_t>& recv_counts, int me,
               const char* what, Traffic* t, std::vector<T>& recv) {
  const std::size_t P = send_counts.size();
  std::vector<int> sc(P), sd(P), rc(P), rd(P);
  std::uint64_t so = 0, ro = 0, sent = 0, received = 0;
  for (std::size_t d = 0; d < P; ++d) {
    sc[d] = detail::count(send_counts[d], what);
    rc[d] = detail::count(recv_counts[d], what);
    sd[d] = detail::count(so, what);
    rd[d] = detail::count(ro, what);
    so += send_counts[d];
    ro += recv_counts[d];
    if (static_cast<int>(d) != me) sent += send_counts[d] * sizeof(T), received += recv_counts[d] * sizeof(T);
  }
  static_cast<void>(detail::count(so, what));  // the totals too: where the last rank's records end
  static_cast<void>(detail::count(ro, what));
  recv.resize(ro);
  detail::call(t, "MPI_Alltoallv", sent, received, [&] {
    return MPI_Alltoallv(send.data(), sc.data(), sd.data(), type.get(), recv.data(), rc.data(), rd.data(), type.get(),
                         comm.comm);
  });
}

// -- partition: Morton order of the centroids, equal counts

// Spreads the low 21 bits of v to every third bit of a 63-bit word (bit i to bit 3i).
std::uint64_t spread21(std::uint64_t v) {
  v &= 0x1FFFFFu;
  v = (v | (v << 32)) & 0x1F00000000FFFFull;
  v = (v | (v << 16)) & 0x1F0000FF0000FFull;
  v = (v | (v << 8)) & 0x100F00F00F00F00Full;
  v = (v | (v << 4)) & 0x10C30C30C30C30C3ull;
  v = (v | (v << 2)) & 0x1249249249249249ull;
  return v;
}

// The largest coordinate magnitude of a box: check_ray_range's S.
float largest(const Box& b) {
  return std::max({std::fabs(b.lo.x), std::fabs(b.lo.y), std::fabs(b.lo.z), std::fabs(b.hi.x), std::fabs(b.hi.y),
                   std::fabs(b.hi.z)});
}

// The whole scene's non-degenerate triangles (the build's rule: twice_area_sq != 0) in Morton
// order of the centres of their boxes (21 bits an axis of the centres' bounds; equal codes by prim
// id): the same order on every rank; and the first triangle that reaches the scene's largest
// coordinate magnitude (the anchor, Part::anchor). A triangle with area too small to trace is
// refused as Accel::build refuses it, by its global id. Two passes over the triangles (the
// centres' bounds, then the codes), so the only array is the sorted (code, prim) pairs: 16 bytes
// a triangle, freed before the part's build.
struct MortonOrder {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;
  std::uint32_t anchor = MBVH_MISS_PRIM;
};

MortonOrder morton_order(const Scene& scene) {
  const std::size_t n = scene.triangle_count();
  auto bounds = [&](std::size_t i, Box& box) {  // false: degenerate
    Vec3f a, b, d;
    scene.triangle(i, a, b, d);
    const double a2 = build::twice_area_sq(a, b, d);
    if (a2 == 0) return false;
    if (build::too_small(a2)) build::throw_too_small(scene, static_cast<std::uint32_t>(i), "");
    box = Box{};
    box.grow(a), box.grow(b), box.grow(d);
    return true;
  };
  MortonOrder out;
  Box cb;
  std::size_t kept = 0;
  float top = -1;
  for (std::size_t i = 0; i < n; ++i)
    if (Box box; bounds(i, box)) {
      cb.grow(box.center()), ++kept;
      if (largest(box) > top) top = largest(box), out.anchor = static_cast<std::uint32_t>(i);
    }
  float scale[3];
  for (int a = 0; a < 3; ++a) {
    const float ext = cb.hi[a] - cb.lo[a];
    scale[a] = ext > 0 ? 2097152.0f / ext : 0.0f;
  }
  std::vector<std::pair<std::uint64_t, std::uint32_t>>& keyed = out.keyed;
  keyed.reserve(kept);
  for (std::size_t i = 0; i < n; ++i) {
    Box box;
    if (!bounds(i, box)) continue;
    const Vec3f c = box.center();
    std::uint64_t code = 0;
    for (int a = 0; a < 3; ++a) {
      const float f = (c[a] - cb.lo[a]) * scale[a];
      code |= spread21(std::min<std::uint64_t>(2097151u, static_cast<std::uint64_t>(f > 0 ? f : 0))) << (2 - a);
    }
    keyed.push_back({code, static_cast<std::uint32_t>(i)});
  }
  std::sort(keyed.begin(), keyed.end());
  return out;
}

// The views of the triangles `ids` (global ids; local triangle i is ids[i]): their vertex indices
// copied into part.indices, one view a run of one geometry of the whole scene, over that
// geometry's own vertex buffer (the whole scene's; not copied).
void make_views(const Scene& scene, const std::vector<std::uint32_t>& ids, Part& part) {
  part.indices.resize(ids.size());
  std::vector<std::pair<std::size_t, std::size_t>> runs;  // (geometry, first local triangle)
  for (std::size_t i = 0; i < ids.size(); ++i) {
    if (scene.meshes().empty()) {
      part.indices[i] = scene.triangles[ids[i]];
      if (runs.empty()) runs.push_back({0, 0});
      continue;
    }
    const GeomPrim g = scene.geometry_of(ids[i]);
    part.indices[i] = scene.meshes()[g.geom_id].triangle(g.prim_id);
    if (runs.empty() || runs.back().first != g.geom_id) runs.push_back({g.geom_id, i});
  }
  for (std::size_t r = 0; r < runs.size(); ++r) {  // part.indices is complete: its buffer no longer moves
    const std::size_t first = runs[r].second, end = r + 1 < runs.size() ? runs[r + 1].second : ids.size();
    MeshView v;
    if (scene.meshes().empty()) {
      v.vertices = &scene.vertices.data()->x;
      v.vertex_count = scene.vertices.size();
    } else {
      const MeshView& m = scene.meshes()[runs[r].first];
      v.vertices = m.vertices, v.vertex_count = m.vertex_count, v.vertex_stride = m.vertex_stride;
    }
    v.indices = part.indices[first].data();
    v.triangle_count = end - first;
    part.scene.add_mesh(v);
  }
}

// One rank's part as every rank learns it (MPI_Allgather): its box and triangle count, and the
// content hash of the whole scene it partitioned (the ranks must have loaded the same scene).
struct PartRecord {
  float lo[3], hi[3];
  std::uint64_t triangles;
  std::uint64_t scene_hash;
};
static_assert(sizeof(PartRecord) == 40);

// -- trace: per ray, the parts its box test reaches, by entry distance

// The parts a ray's conservative slab test reaches within its tmax * S (the traversals' culling
// of a box, host/core/trace/intersect.h), in order of entry distance, then part: parts[first[i] ..
// first[i + 1]) for ray i. An invalid ray reaches none. A box's entry does not depend on tmax, so
// a later round tests a part against a shrunken tmax by its entry alone (entry <= best t * S).
struct Reach {
  std::vector<std::size_t> first;
  std::vector<float> entry;
  std::vector<std::uint32_t> part;
};

void reach(const Part& part, std::span<const Ray> rays, std::size_t& invalid, Reach& r) {
  r.first.clear(), r.entry.clear(), r.part.clear();
  r.first.reserve(rays.size() + 1);
  r.entry.reserve(rays.size()), r.part.reserve(rays.size());  // at least one part a ray, mostly
  r.first.push_back(0);
  std::vector<std::pair<float, std::uint32_t>> hit;
  for (const Ray& ray : rays) {
    RayPre p;
    hit.clear();
    if (!prepare_ray(ray, p)) {
      ++invalid;
    } else {
      for (std::size_t q = 0; q < part.rank_bounds.size(); ++q) {
        const Box& b = part.rank_bounds[q];
        float entry;
        if (!b.empty() && box_test(p, b.lo.x, b.hi.x, b.lo.y, b.hi.y, b.lo.z, b.hi.z, p.tmax * kCullSlack, entry))
          hit.push_back({entry, static_cast<std::uint32_t>(q)});
      }
      if (hit.size() > 1) std::sort(hit.begin(), hit.end());
    }
    for (const auto& [e, q] : hit) r.entry.push_back(e), r.part.push_back(q);
    r.first.push_back(r.entry.size());
  }
}

// This part's answers to the rays it received: closest hits with global prim ids, or occlusion
// flags. Every ray came valid for the whole scene (its owner checked it); Backend::trace checks
// it again against this part's build, whose largest coordinate is the scene's (Part::anchor), so
// that check passes every ray the owner's did.
void trace_part(Backend& backend, const Part& part, const std::vector<Ray>& rays, const TraceOptions& opt,
                TraceOutput& out) {
  if (rays.empty()) {
    out.hits.clear(), out.occluded.clear();
    return;
  }
  if (!part.accel)
    throw Error("data-parallel trace (rank " + std::to_string(part.rank) +
                "): internal: " + std::to_string(rays.size()) + " rays came to a rank without triangles");
  backend.trace(*part.accel, rays, opt, out);
  if (opt.query == Query::any) return;
  const std::size_t own = part.local_to_global.size();
  for (Hit& h : out.hits)
    if (h.prim != MBVH_MISS_PRIM) h.prim = h.prim < own ? part.local_to_global[h.prim] : part.anchor;
}

// What trace_data_parallel keeps between calls, so a repeated trace of as many rays touches no
// fresh memory (on these machines a first-touched page costs microseconds, as much as tracing a
// ray): the per-ray reach and cursors, a round's sends and receipts, this part's answers.
struct ForwardScratch {
  Reach rc;
  std::vector<std::size_t> cursor;
  std::vector<std::pair<std::uint32_t, std::uint32_t>> sends;
  std::vector<std::uint32_t> owner_index;
  std::vector<Ray> forwarded, in;
  TraceOutput answers;
  std::vector<Hit> hits_back;
  std::vector<std::uint8_t> occluded_back;
};
ForwardScratch g_scratch;  // trace_data_parallel is not reentrant (MPI calls from one thread, g_last)

ForwardStats g_last;  // last_forward_stats: this process's last trace_data_parallel

}  // namespace

Part partition(const Comm& comm, const Scene& scene, const BuildOptions& opt, Traffic* traffic) {
  const int P = comm.size(), me = comm.rank();
  scene.validate();
  Part part;
  part.rank = me, part.ranks = P;
  part.scene.name = scene.display_name() + " (part " + std::to_string(me) + " of " + std::to_string(P) + ")";

  // -- the non-degenerate triangles in Morton order, cut into P runs of equal counts (differing
  //    by one at most); this rank's run in ascending prim order
  std::uint32_t anchor = MBVH_MISS_PRIM;
  {
    const MortonOrder mo = morton_order(scene);
    const std::vector<std::pair<std::uint64_t, std::uint32_t>>& order = mo.keyed;
    anchor = mo.anchor;
    const std::uint64_t K = order.size();
    if (K == 0)
      throw Error(scene.display_name() + ": the scene has no non-degenerate triangle (" +
                  std::to_string(scene.triangle_count()) + " triangles)");
    auto begin = [&](std::uint64_t r) { return K * r / static_cast<std::uint64_t>(P); };
    part.rank_triangles.resize(P);
    for (int r = 0; r < P; ++r) part.rank_triangles[r] = begin(r + 1) - begin(r);
    part.local_to_global.reserve(part.rank_triangles[me]);
    for (std::uint64_t k = begin(me); k < begin(me + 1); ++k) part.local_to_global.push_back(order[k].second);
    std::sort(part.local_to_global.begin(), part.local_to_global.end());
  }

  // -- this rank's box; a part whose coordinates all lie below the scene's largest one builds the
  //    anchor too, so its build has the scene's range (Part::anchor)
  Box own, anchor_box;
  for (std::uint32_t id : part.local_to_global) {
    Vec3f a, b, c;
    scene.triangle(id, a, b, c);
    own.grow(a), own.grow(b), own.grow(c);
  }
  if (!part.local_to_global.empty()) {
    Vec3f a, b, c;
    scene.triangle(anchor, a, b, c);
    anchor_box.grow(a), anchor_box.grow(b), anchor_box.grow(c);
    if (largest(own) < largest(anchor_box)) part.anchor = anchor;
  }

  // -- this rank's triangles as views of the whole scene's mesh, and their BVH
  if (part.anchor == MBVH_MISS_PRIM) {
    make_views(scene, part.local_to_global, part);
  } else {
    std::vector<std::uint32_t> ids = part.local_to_global;
    ids.push_back(part.anchor);
    make_views(scene, ids, part);
  }
  if (!part.local_to_global.empty()) part.accel = Accel::build(part.scene, opt);

  // -- every rank's box (MPI_Allgather), and the counts checked: ranks given other scenes differ there
  PartRecord mine{};
  for (int a = 0; a < 3; ++a) mine.lo[a] = own.lo[a], mine.hi[a] = own.hi[a];
  mine.triangles = part.local_to_global.size();
  mine.scene_hash = scene.hash();
  std::vector<PartRecord> all(P);
  detail::call(traffic, "MPI_Allgather", sizeof(PartRecord) * (P - 1), sizeof(PartRecord) * (P - 1), [&] {
    return MPI_Allgather(&mine, sizeof(PartRecord), MPI_BYTE, all.data(), sizeof(PartRecord), MPI_BYTE, comm.comm);
  });
  part.rank_bounds.resize(P);
  for (int r = 0; r < P; ++r) {
    if (all[r].scene_hash != mine.scene_hash)
      throw Error("partition (rank " + std::to_string(me) + "): rank " + std::to_string(r) +
                  " loaded another scene than this rank's " + scene.display_name() +
                  " (another content hash): every rank must load the same scene");
    if (all[r].triangles != part.rank_triangles[r])
      throw Error("partition (rank " + std::to_string(me) + "): rank " + std::to_string(r) + " holds " +
                  std::to_string(all[r].triangles) + " triangles where this rank's scene gives it " +
                  std::to_string(part.rank_triangles[r]) + ": the ranks partition different scenes");
    Box& b = part.rank_bounds[r];
    if (all[r].triangles == 0) continue;  // an empty box
    b.lo = {all[r].lo[0], all[r].lo[1], all[r].lo[2]};
    b.hi = {all[r].hi[0], all[r].hi[1], all[r].hi[2]};
    part.scene_bounds.grow(b);
  }
  return part;
}

void trace_data_parallel(const Comm& comm, Backend& backend, const Part& part, std::span<const Ray> rays,
                         const TraceOptions& asked, TraceOutput& out, Traffic* traffic, Forwarding forwarding) {
  const int P = comm.size(), me = comm.rank();
  const std::string who = "data-parallel trace (rank " + std::to_string(me) + ")";
  g_last = ForwardStats{};
  // -- checks: options, the part, the rays against the whole scene's range
  check_trace_options(asked, who);
  if (asked.stats)
    throw Error(who +
                ": statistics (TraceOptions::stats) are not collected across ranks; trace in one process for them");
  const TraceOptions opt = resolve_options(backend, asked);
  const bool any = opt.query == Query::any;
  if (part.ranks != P || part.rank != me || part.rank_bounds.size() != static_cast<std::size_t>(P))
    throw Error(who + ": the part was made for rank " + std::to_string(part.rank) + " of " +
                std::to_string(part.ranks) + ", not for this communicator's rank " + std::to_string(me) + " of " +
                std::to_string(P));
  check_ray_range(part.scene_bounds, rays, backend.name());
  if (rays.size() > UINT32_MAX)  // the rounds name a ray by a 32-bit index
    throw Error(who + ": " + std::to_string(rays.size()) +
                " rays in one call; at most 2^32 - 1 a rank (trace them in batches)");
  out.reset(rays.size(), opt);

  // -- per ray, the parts it reaches, nearest entry first; a cursor into them
  ForwardScratch& sc = g_scratch;
  reach(part, rays, out.invalid, sc.rc);
  const Reach& rc = sc.rc;
  std::vector<std::size_t>& cursor = sc.cursor;
  cursor.assign(rc.first.begin(), rc.first.end() - 1);
  const Contiguous ray_type(sizeof(Ray), traffic), hit_type(sizeof(Hit), traffic);
  const Contiguous flag_type(1, traffic);
  ForwardStats st;
  st.rays = rays.size();

  auto& sends = sc.sends;  // (part, ray) of this round
  for (;;) {
    // -- this round's forwards: ordered, the ray's next part if its entry lies within the best t
    //    so far (closest; any hit: until occluded); broadcast, every part it reaches, at once
    sends.clear();
    for (std::size_t i = 0; i < rays.size(); ++i) {
      const std::size_t end = rc.first[i + 1];
      if (any && out.occluded[i]) continue;
      if (forwarding == Forwarding::broadcast) {
        for (; cursor[i] < end; ++cursor[i]) sends.push_back({rc.part[cursor[i]], static_cast<std::uint32_t>(i)});
        continue;
      }
      if (cursor[i] == end) continue;
      const float tcull = (any || out.hits[i].prim == MBVH_MISS_PRIM ? rays[i].tmax : out.hits[i].t) * kCullSlack;
      if (!(rc.entry[cursor[i]] <= tcull)) {
        cursor[i] = end;  // the parts further on are entered later still: done
        continue;
      }
      sends.push_back({rc.part[cursor[i]++], static_cast<std::uint32_t>(i)});
    }
    std::uint64_t mine = sends.size(), total = 0;
    detail::call(traffic, "MPI_Allreduce", 8, 8,
                 [&] { return MPI_Allreduce(&mine, &total, 1, MPI_UINT64_T, MPI_SUM, comm.comm); });
    if (total == 0) break;
    ++st.rounds;
    st.forwards += mine;

    // -- the rays, by destination part (32 bytes each: the answers return in the order the rays
    //    came, so the owner knows each answer's ray by its position, owner_index, and sends no
    //    index); tmax: the best t so far (tri_test accepts t = tmax, so a hit at the best t with a
    //    smaller prim is still found), else the ray's own
    std::vector<std::uint64_t> send_counts(P, 0), at(P, 0);
    for (const auto& s : sends) ++send_counts[s.first];
    for (int q = 1; q < P; ++q) at[q] = at[q - 1] + send_counts[q - 1];
    std::vector<std::uint32_t>& owner_index = sc.owner_index;  // by position sent: the ray's index here
    std::vector<Ray>& forwarded = sc.forwarded;
    owner_index.resize(sends.size());
    forwarded.resize(sends.size());
    for (const auto& [q, i] : sends) {
      const std::uint64_t k = at[q]++;
      owner_index[k] = i;
      forwarded[k] = rays[i];
      if (!any && forwarding == Forwarding::ordered && out.hits[i].prim != MBVH_MISS_PRIM)
        forwarded[k].tmax = out.hits[i].t;
    }
    const std::vector<std::uint64_t> recv_counts = exchange_counts(comm, send_counts, traffic);
    alltoallv(comm, ray_type, forwarded, send_counts, recv_counts, me, "rays forwarded in a round", traffic, sc.in);

    // -- this part's answers, back to the owners in the order they came
    trace_part(backend, part, sc.in, opt, sc.answers);
    if (any) {
      const std::vector<std::uint8_t>& back = sc.occluded_back;
      alltoallv(comm, flag_type, sc.answers.occluded, recv_counts, send_counts, me, "answers returned in a round", traffic,
                sc.occluded_back);
      for (std::size_t k = 0; k < back.size(); ++k) out.occluded[owner_index[k]] |= back[k];
      continue;
    }
    const std::vector<Hit>& back = sc.hits_back;
    alltoallv(comm, hit_type, sc.answers.hits, recv_counts, send_counts, me, "answers returned in a round", traffic,
              sc.hits_back);
    // -- the owner keeps the lexicographic minimum of (t, global prim)
    for (std::size_t k = 0; k < back.size(); ++k) {
      const Hit& h = back[k];
      Hit& best = out.hits[owner_index[k]];
      if (h.prim != MBVH_MISS_PRIM &&
          (best.prim == MBVH_MISS_PRIM || h.t < best.t || (h.t == best.t && h.prim < best.prim)))
        best = h;
    }
  }
  g_last = st;
}

ForwardStats last_forward_stats() { return g_last; }

}  // namespace mbvh::mpi

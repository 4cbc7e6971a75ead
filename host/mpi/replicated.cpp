// SPDX-License-Identifier: MIT
// replicated.cpp — the replicated (ray-parallel) mode of mbvh/mpi.h: one BVH built once and
// shared through the BVH cache, rays traced in fixed batches on every rank, the answers gathered
// in ray order. The work split follows OSPRay's MPI module (static round-robin, or a dynamic queue
// with stealing: modules/mpi, MPILoadBalancer); the answers do not depend on it.
#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <system_error>

#include "host/mpi/calls.h"
#include "mbvh/mpi.h"

namespace mbvh::mpi {

namespace {

using detail::call;
using detail::count;

// A record of `bytes` bytes as one MPI datatype, so counts are records, not bytes (a batch of
// more than 2^31 bytes stays within MPI's int counts).
struct RecordType {
  MPI_Datatype type = MPI_DATATYPE_NULL;
  explicit RecordType(int bytes) {
    MPI_Type_contiguous(bytes, MPI_BYTE, &type);
    MPI_Type_commit(&type);
  }
  ~RecordType() {
    if (type != MPI_DATATYPE_NULL) MPI_Type_free(&type);
  }
  RecordType(const RecordType&) = delete;
  RecordType& operator=(const RecordType&) = delete;
};

// The root's string on every rank.
std::string broadcast(const Comm& comm, std::string s, Traffic* t) {
  std::uint64_t n = s.size();
  call(t, "MPI_Bcast (length)", 8, 8, [&] { return MPI_Bcast(&n, 1, MPI_UINT64_T, 0, comm.comm); });
  s.resize(n);
  call(t, "MPI_Bcast (string)", n, n, [&] { return MPI_Bcast(s.data(), count(n, "MPI_Bcast"), MPI_CHAR, 0, comm.comm); });
  return s;
}

// A private directory for one shared build: made by the root, removed by the root after every
// rank has read the entry.
std::string private_dir() {
  const char* tmp = std::getenv("TMPDIR");
  std::string templ = std::string(tmp && *tmp ? tmp : "/tmp") + "/mbvh-mpi-XXXXXX";
  if (!::mkdtemp(templ.data())) throw Error("mbvh-mpi: cannot make a private directory " + templ + " for the shared BVH");
  return templ;
}

}  // namespace

std::unique_ptr<Accel> shared_accel(const Comm& comm, const Scene& scene, const BuildOptions& opt,
                                    const Accel::CacheOptions& cache, Accel::CacheReport* report, Traffic* t) {
  // quality none has no tree to share: every rank makes it in O(n), as a cache read would cost
  if (opt.quality == BuildQuality::none) return Accel::build(scene, opt);
  Accel::CacheOptions c = cache;
  const bool temporary = c.dir.empty();
  if (temporary) c.dir = broadcast(comm, comm.root() ? private_dir() : std::string(), t);
  BuildOptions quiet = opt;
  if (!comm.root()) quiet.progress = nullptr;  // progress is the root's
  std::unique_ptr<Accel> acc;
  Accel::CacheReport mine;
  // the root builds (or reads) the entry first; then the others read it: one build, not P
  if (comm.root()) acc = Accel::build_cached(scene, quiet, c, &mine);
  call(t, "MPI_Barrier (build)", 0, 0, [&] { return MPI_Barrier(comm.comm); });
  if (!comm.root()) acc = Accel::build_cached(scene, quiet, c, &mine);
  call(t, "MPI_Barrier (read)", 0, 0, [&] { return MPI_Barrier(comm.comm); });
  if (temporary && comm.root()) {
    std::error_code ec;
    std::filesystem::remove_all(c.dir, ec);  // nothing of ours is left behind; a failure is harmless
  }
  if (temporary) mine.path.clear();  // the private directory is gone: no cache to name
  if (report) *report = mine;
  // every rank traces the same tree: the hashes must agree
  const std::uint64_t h = acc->hash();
  std::uint64_t lo = 0, hi = 0;
  call(t, "MPI_Allreduce (hash)", 8, 8, [&] { return MPI_Allreduce(&h, &lo, 1, MPI_UINT64_T, MPI_MIN, comm.comm); });
  call(t, "MPI_Allreduce (hash)", 8, 8, [&] { return MPI_Allreduce(&h, &hi, 1, MPI_UINT64_T, MPI_MAX, comm.comm); });
  if (lo != hi)
    throw Error("the ranks' BVHs differ (hash " + std::to_string(h) + " on rank " + std::to_string(comm.rank()) +
                "; the ranks must load the same scene with the same options)");
  return acc;
}

WorkQueue::WorkQueue(const Comm& comm, std::uint64_t total, Traffic* t) : comm_(comm), total_(total), traffic_(t) {
  // MPI_Win_allocate, not MPI_Win_create over our own memory: Open MPI's shared-memory one-sided
  // component (osc/sm, the one a single host gets) serves allocated windows only
  const std::size_t n = comm.root() ? static_cast<std::size_t>(comm.size()) : 0;
  std::int64_t* base = nullptr;
  call(t, "MPI_Win_allocate (work queue)", 0, 0, [&] {
    return MPI_Win_allocate(static_cast<MPI_Aint>(n * sizeof(std::int64_t)), sizeof(std::int64_t), MPI_INFO_NULL,
                            comm.comm, &base, &win_);
  });
  for (std::size_t r = 0; r < n; ++r) base[r] = static_cast<std::int64_t>(queue_begin(static_cast<int>(r)));
  call(t, "MPI_Barrier (work queue)", 0, 0, [&] { return MPI_Barrier(comm.comm); });  // the counters are set
  call(t, "MPI_Win_lock_all (work queue)", 0, 0, [&] { return MPI_Win_lock_all(0, win_); });
}

WorkQueue::~WorkQueue() {
  MPI_Win_unlock_all(win_);
  MPI_Win_free(&win_);  // collective: every rank has taken its last item
}

std::uint64_t WorkQueue::queue_begin(int r) const {
  return total_ * static_cast<std::uint64_t>(r) / static_cast<std::uint64_t>(comm_.size());
}

std::int64_t WorkQueue::next() {
  const std::int64_t one = 1;
  Traffic* t = traffic_;
  auto take = [&](int q) {  // the next item of queue q, or -1 when it is empty
    std::int64_t got = 0;
    call(t, "MPI_Fetch_and_op (work queue)", 8, 8, [&] { return MPI_Fetch_and_op(&one, &got, MPI_INT64_T, 0, q, MPI_SUM, win_); });
    call(t, "MPI_Win_flush (work queue)", 0, 0, [&] { return MPI_Win_flush(0, win_); });
    return got < static_cast<std::int64_t>(queue_begin(q + 1)) ? got : std::int64_t(-1);
  };
  const int P = comm_.size();
  std::int64_t item = take(comm_.rank());
  while (item < 0) {  // steal from the queue with the most items left
    std::vector<std::int64_t> next(static_cast<std::size_t>(P));
    call(t, "MPI_Get (work queue)", 0, static_cast<std::uint64_t>(P) * 8, [&] {
      return MPI_Get(next.data(), P, MPI_INT64_T, 0, 0, P, MPI_INT64_T, win_);
    });
    call(t, "MPI_Win_flush (work queue)", 0, 0, [&] { return MPI_Win_flush(0, win_); });
    int victim = -1;
    std::int64_t most = 0;
    for (int q = 0; q < P; ++q)
      if (const std::int64_t left = static_cast<std::int64_t>(queue_begin(q + 1)) - next[static_cast<std::size_t>(q)]; left > most) {
        most = left;
        victim = q;
      }
    if (victim < 0) return -1;  // every queue is empty
    item = take(victim);
  }
  return item;
}

void trace(const Comm& comm, Backend& backend, const Accel& acc, std::span<const Ray> rays, const TraceOptions& asked,
           TraceOutput& out, const ScheduleOptions& sched, Traffic* t) {
  if (asked.stats) throw Error("mbvh::mpi::trace: statistics (TraceOptions::stats) are not gathered over ranks");
  if (sched.batch == 0) throw Error("mbvh::mpi::trace: the batch size must be at least 1");
  const TraceOptions opt = resolve_options(backend, asked);
  const bool any = opt.query == Query::any;
  const int P = comm.size(), me = comm.rank();
  // -- the ray count and batches, from the root; the root checks the range once, naming the ray
  std::uint64_t n = comm.root() ? rays.size() : 0;
  if (comm.root() && acc.has_hierarchy()) check_ray_range(acc, rays, backend.name());
  call(t, "MPI_Bcast (ray count)", 8, 8, [&] { return MPI_Bcast(&n, 1, MPI_UINT64_T, 0, comm.comm); });
  const std::uint64_t batch = sched.batch, batches = (n + batch - 1) / batch;
  auto batch_rays = [&](std::uint64_t b) { return std::min(batch, n - b * batch); };
  const RecordType ray_t(sizeof(Ray)), res_t(any ? 1 : static_cast<int>(sizeof(Hit)));
  const std::size_t res_bytes = any ? 1 : sizeof(Hit);
  // -- which batches this rank traces, and their rays
  std::vector<std::uint64_t> mine;  // batch indices, in the order traced
  std::vector<Ray> local;
  if (sched.schedule == Schedule::static_batches) {
    // batch b on rank b mod P; the root packs each rank's batches together for one MPI_Scatterv
    for (std::uint64_t b = static_cast<std::uint64_t>(me); b < batches; b += static_cast<std::uint64_t>(P))
      mine.push_back(b);
    std::vector<int> counts(static_cast<std::size_t>(P), 0), displs(static_cast<std::size_t>(P), 0);
    std::vector<Ray> packed;
    if (comm.root()) {
      packed.reserve(n);
      for (int r = 0; r < P; ++r) {
        displs[static_cast<std::size_t>(r)] = count(packed.size(), "MPI_Scatterv (rays)");
        for (std::uint64_t b = static_cast<std::uint64_t>(r); b < batches; b += static_cast<std::uint64_t>(P))
          packed.insert(packed.end(), rays.begin() + static_cast<std::ptrdiff_t>(b * batch),
                        rays.begin() + static_cast<std::ptrdiff_t>(b * batch + batch_rays(b)));
        counts[static_cast<std::size_t>(r)] = count(packed.size(), "MPI_Scatterv (rays)") - displs[static_cast<std::size_t>(r)];
      }
    }
    std::uint64_t mine_n = 0;
    for (std::uint64_t b : mine) mine_n += batch_rays(b);
    local.resize(mine_n);
    call(t, "MPI_Scatterv (rays)", comm.root() ? (n - mine_n) * sizeof(Ray) : 0, comm.root() ? 0 : mine_n * sizeof(Ray), [&] {
      return MPI_Scatterv(packed.data(), counts.data(), displs.data(), ray_t.type, local.data(),
                          count(mine_n, "MPI_Scatterv (rays)"), ray_t.type, 0, comm.comm);
    });
  } else {
    // dynamic: batches from the work queue (its own share first, then stolen); each batch's rays
    // read from the root's window (one-sided: no rank serves requests)
    WorkQueue queue(comm, batches, t);
    MPI_Win rwin = MPI_WIN_NULL;
    Ray* exposed = nullptr;  // the root's copy of the rays, in an allocated window (see WorkQueue)
    call(t, "MPI_Win_allocate (rays)", 0, 0, [&] {
      return MPI_Win_allocate(static_cast<MPI_Aint>(comm.root() ? n * sizeof(Ray) : 0), sizeof(Ray), MPI_INFO_NULL,
                              comm.comm, &exposed, &rwin);
    });
    if (comm.root()) std::copy(rays.begin(), rays.end(), exposed);
    struct Window {  // freed however this leaves
      MPI_Win& w;
      ~Window() { MPI_Win_free(&w); }
    } window{rwin};
    call(t, "MPI_Barrier (rays)", 0, 0, [&] { return MPI_Barrier(comm.comm); });  // the rays are in place
    call(t, "MPI_Win_lock_all", 0, 0, [&] { return MPI_Win_lock_all(0, rwin); });
    for (std::int64_t b; (b = queue.next()) >= 0;) {
      const std::uint64_t ub = static_cast<std::uint64_t>(b), k = batch_rays(ub);
      mine.push_back(ub);
      local.resize(local.size() + k);
      call(t, "MPI_Get (rays)", 0, comm.root() ? 0 : k * sizeof(Ray), [&] {
        return MPI_Get(local.data() + local.size() - k, count(k, "MPI_Get (rays)"), ray_t.type, 0,
                       static_cast<MPI_Aint>(ub * batch), count(k, "MPI_Get (rays)"), ray_t.type, rwin);
      });
      call(t, "MPI_Win_flush", 0, 0, [&] { return MPI_Win_flush(0, rwin); });
    }
    call(t, "MPI_Win_unlock_all", 0, 0, [&] { return MPI_Win_unlock_all(rwin); });
  }
  // -- trace this rank's rays: one call, so the backend's threads share all of them
  TraceOutput part;
  backend.trace(acc, local, opt, part);
  // -- gather: which batches each rank traced, then their answers, placed in ray order
  std::uint64_t invalid = part.invalid, total_invalid = 0;
  call(t, "MPI_Reduce (invalid)", 8, 8, [&] { return MPI_Reduce(&invalid, &total_invalid, 1, MPI_UINT64_T, MPI_SUM, 0, comm.comm); });
  const int nb = count(mine.size(), "MPI_Gather (batches)");
  std::vector<int> nbs(comm.root() ? static_cast<std::size_t>(P) : 0), bdispl(nbs.size(), 0);
  call(t, "MPI_Gather (batch counts)", 4, comm.root() ? 4u * static_cast<unsigned>(P) : 0, [&] {
    return MPI_Gather(&nb, 1, MPI_INT, nbs.data(), 1, MPI_INT, 0, comm.comm);
  });
  std::vector<std::uint64_t> all_batches;
  std::vector<int> rcounts(nbs.size(), 0), rdispl(nbs.size(), 0);
  if (comm.root()) {
    int sum = 0;
    for (std::size_t r = 0; r < nbs.size(); ++r) {
      bdispl[r] = sum;
      sum += nbs[r];
    }
    all_batches.resize(static_cast<std::size_t>(sum));
  }
  call(t, "MPI_Gatherv (batch ids)", mine.size() * 8, comm.root() ? all_batches.size() * 8 : 0, [&] {
    return MPI_Gatherv(mine.data(), nb, MPI_UINT64_T, all_batches.data(), nbs.data(), bdispl.data(), MPI_UINT64_T, 0,
                       comm.comm);
  });
  std::vector<char> gathered;
  if (comm.root()) {
    std::uint64_t at = 0;
    std::size_t k = 0;
    for (std::size_t r = 0; r < nbs.size(); ++r) {
      rdispl[r] = count(at, "MPI_Gatherv (answers)");
      for (int j = 0; j < nbs[r]; ++j) at += batch_rays(all_batches[k++]);
      rcounts[r] = count(at, "MPI_Gatherv (answers)") - rdispl[r];
    }
    gathered.resize(at * res_bytes);
  }
  const void* send = any ? static_cast<const void*>(part.occluded.data()) : static_cast<const void*>(part.hits.data());
  call(t, "MPI_Gatherv (answers)", comm.root() ? 0 : local.size() * res_bytes, comm.root() ? (n - local.size()) * res_bytes : 0, [&] {
    return MPI_Gatherv(send, count(local.size(), "MPI_Gatherv (answers)"), res_t.type, gathered.data(), rcounts.data(),
                       rdispl.data(), res_t.type, 0, comm.comm);
  });
  if (!comm.root()) {
    out = TraceOutput{};
    return;
  }
  out.reset(n, opt);
  char* dst = any ? reinterpret_cast<char*>(out.occluded.data()) : reinterpret_cast<char*>(out.hits.data());
  std::uint64_t from = 0;
  for (std::uint64_t b : all_batches) {
    const std::uint64_t k = batch_rays(b);
    std::copy_n(gathered.data() + from * res_bytes, k * res_bytes, dst + b * batch * res_bytes);
    from += k;
  }
  out.invalid = total_invalid;
}

}  // namespace mbvh::mpi

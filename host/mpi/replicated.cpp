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
  // without a cache directory the BVH passes through a private one: an error there says so
  auto build = [&] {
    try {
      return Accel::build_cached(scene, quiet, c, &mine);
    } catch (const Error& e) {
      if (!temporary) throw;
      throw Error(std::string(e.what()) + " (the BVH passes from rank 0 to the others through a private directory "
                  "under $TMPDIR, which must hold it: give --cache DIR elsewhere, or another TMPDIR)");
    }
  };
  if (comm.root()) acc = build();
  call(t, "MPI_Barrier (build)", 0, 0, [&] { return MPI_Barrier(comm.comm); });
  if (!comm.root()) acc = build();
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
  MPI_Win_set_errhandler(win_, MPI_ERRORS_RETURN);  // a failure is an Error (calls.h), not an abort
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

// What trace() keeps between calls, so a repeated trace of as many rays touches no fresh memory
// (on these machines a first-touched page costs microseconds: fresh buffers for 1M rays cost as much
// as tracing them): this rank's rays and answers, the gathered answers and, for the dynamic
// schedule, the root's window of rays. Freed when MPI_Finalize begins (an attribute of
// MPI_COMM_SELF), while MPI_Win_free can still be called.
// A window kept between calls (see Scratch): allocated by MPI_Win_allocate (Open MPI's
// single-host one-sided component, osc/sm, serves allocated windows only) or, `shared`, by
// MPI_Win_allocate_shared (every rank reads and writes the root's segment directly). Only the root's
// segment has bytes. ensure() is collective; every rank passes the same arguments.
struct KeptWindow {
  MPI_Comm comm = MPI_COMM_NULL;
  MPI_Win win = MPI_WIN_NULL;
  char* base = nullptr;  ///< the root's segment (on every rank, for a shared window)
  std::uint64_t bytes = 0;
  void free() {
    if (win != MPI_WIN_NULL) {
      MPI_Win_unlock_all(win);
      MPI_Win_free(&win);  // collective over comm
    }
    comm = MPI_COMM_NULL;
    base = nullptr;
    bytes = 0;
  }
  void ensure(const Comm& c, std::uint64_t need, bool shared, Traffic* t) {
    if (win != MPI_WIN_NULL) {
      int same = MPI_UNEQUAL;
      MPI_Comm_compare(comm, c.comm, &same);
      if (same == MPI_IDENT && need <= bytes) return;
      free();
    }
    const MPI_Aint size = static_cast<MPI_Aint>(c.root() ? need : 0);
    call(t, shared ? "MPI_Win_allocate_shared" : "MPI_Win_allocate", 0, 0, [&] {
      return shared ? MPI_Win_allocate_shared(size, 1, MPI_INFO_NULL, c.comm, &base, &win)
                    : MPI_Win_allocate(size, 1, MPI_INFO_NULL, c.comm, &base, &win);
    });
    if (shared && !c.root()) {  // the root's segment, mapped here
      MPI_Aint sz = 0;
      int unit = 0;
      call(t, "MPI_Win_shared_query", 0, 0, [&] { return MPI_Win_shared_query(win, 0, &sz, &unit, &base); });
    }
    MPI_Win_set_errhandler(win, MPI_ERRORS_RETURN);  // a failure is an Error (calls.h), not an abort
    comm = c.comm;
    bytes = need;
    call(t, "MPI_Win_lock_all", 0, 0, [&] { return MPI_Win_lock_all(0, win); });  // one epoch, open while kept
  }
};

// What trace() keeps between calls, so a repeated trace of as many rays touches no fresh memory
// (on these machines a first-touched page costs microseconds: fresh buffers for 1M rays cost as much
// as tracing them): this rank's rays and answers, the dynamic schedule's window of rays, the
// static schedule's shared window on one host, and whether the communicator is on one host.
// Freed when MPI_Finalize begins (an attribute of MPI_COMM_SELF), while windows can still be freed.
struct Scratch {
  std::vector<Ray> rays;
  TraceOutput part;
  std::vector<char> gathered;
  std::vector<std::uint64_t> batches;
  KeptWindow rays_window, shared;
  MPI_Comm host_comm = MPI_COMM_NULL;  ///< the communicator one_host was found for
  bool one_host = false;
  /// Whether every rank of `c` runs on this host (can share memory): found once per communicator.
  bool on_one_host(const Comm& c, Traffic* t) {
    int same = MPI_UNEQUAL;
    if (host_comm != MPI_COMM_NULL) MPI_Comm_compare(host_comm, c.comm, &same);
    if (same != MPI_IDENT) {
      MPI_Comm node = MPI_COMM_NULL;
      call(t, "MPI_Comm_split_type", 0, 0, [&] { return MPI_Comm_split_type(c.comm, MPI_COMM_TYPE_SHARED, 0, MPI_INFO_NULL, &node); });
      int n = 0, all = 0;
      MPI_Comm_size(node, &n);
      MPI_Comm_free(&node);
      n = n == c.size() ? 1 : 0;  // every rank must agree
      call(t, "MPI_Allreduce (one host)", 4, 4, [&] { return MPI_Allreduce(&n, &all, 1, MPI_INT, MPI_MIN, c.comm); });
      one_host = all == 1;
      host_comm = c.comm;
    }
    return one_host;
  }
};

Scratch& scratch() {
  static Scratch* s = [] {
    auto* p = new Scratch;
    int key = MPI_KEYVAL_INVALID;
    MPI_Comm_create_keyval(MPI_COMM_NULL_COPY_FN,
                           [](MPI_Comm, int, void* v, void*) {
                             auto* sc = static_cast<Scratch*>(v);
                             sc->rays_window.free();
                             sc->shared.free();
                             delete sc;
                             return MPI_SUCCESS;
                           },
                           &key, nullptr);
    MPI_Comm_set_attr(MPI_COMM_SELF, key, p);
    return p;
  }();
  return *s;
}

// backend.trace of one rank's rays [lo, lo + rays.size()) of the call; an Error (a ray out of the
// traced range) names the rays' place in the call
void trace_share(Backend& backend, const Accel& acc, std::span<const Ray> rays, std::uint64_t lo, const TraceOptions& opt,
                 TraceOutput& out) {
  try {
    backend.trace(acc, rays, opt, out);
  } catch (const Error& e) {
    throw Error("rays " + std::to_string(lo) + " to " + std::to_string(lo + rays.size()) + " of the call (ray i there is ray " +
                std::to_string(lo) + " + i): " + e.what());
  }
}

void trace(const Comm& comm, Backend& backend, const Accel& acc, std::span<const Ray> rays, const TraceOptions& asked,
           TraceOutput& out, const ScheduleOptions& sched, Traffic* t) {
  if (asked.stats) throw Error("mbvh::mpi::trace: statistics (TraceOptions::stats) are not gathered over ranks");
  if (sched.batch == 0) throw Error("mbvh::mpi::trace: the batch size must be at least 1");
  const TraceOptions opt = resolve_options(backend, asked);
  const bool any = opt.query == Query::any;
  const int P = comm.size(), me = comm.rank();
  Scratch& sc = scratch();
  // -- the ray count and batches, from the root
  std::uint64_t n = comm.root() ? rays.size() : 0;
  call(t, "MPI_Bcast (ray count)", 8, 8, [&] { return MPI_Bcast(&n, 1, MPI_UINT64_T, 0, comm.comm); });
  const std::uint64_t batch = sched.batch, batches = (n + batch - 1) / batch;
  auto batch_rays = [&](std::uint64_t b) { return std::min(batch, n - b * batch); };
  // static: rank r's share, the rays [share(r), share(r+1)): equal contiguous shares (the batch size
  // is the dynamic schedule's unit of work)
  auto share = [&](int r) { return n * static_cast<std::uint64_t>(r) / static_cast<std::uint64_t>(P); };
  const RecordType ray_t(sizeof(Ray)), res_t(any ? 1 : static_cast<int>(sizeof(Hit)));
  const std::size_t res_bytes = any ? 1 : sizeof(Hit);
  auto answer_bytes = [&](TraceOutput& o) {
    return any ? reinterpret_cast<char*>(o.occluded.data()) : reinterpret_cast<char*>(o.hits.data());
  };
  auto resize = [&](TraceOutput& o, std::uint64_t k) {  // the answers of k rays (kept: the first ones)
    if (any) o.occluded.resize(k);
    else o.hits.resize(k);
  };
  std::uint64_t invalid = 0;
  if (P == 1) {  // one rank: the backend's trace, nothing to send
    trace_share(backend, acc, rays, 0, opt, out);
    invalid = out.invalid;
  } else if (sched.shared_memory && sc.on_one_host(comm, t)) {
    // every rank on this host: the other ranks' rays and answers pass through a window of shared
    // memory (MPI-3) in the root's segment: the root copies the rays in, each rank traces straight
    // from it and copies its answers there, and the root copies those into `out` (two copies a
    // byte, where MPI_Scatterv and MPI_Gatherv make four); the root traces its own batches from the
    // caller's array. Static: each rank its contiguous share of the batches, traced in one call;
    // dynamic: a batch at a time from the work queue.
    const bool dynamic = sched.schedule == Schedule::dynamic;
    sc.shared.ensure(comm, n * (sizeof(Ray) + res_bytes), true, t);
    Ray* srays = reinterpret_cast<Ray*>(sc.shared.base);
    char* sanswers = sc.shared.base + n * sizeof(Ray);
    // the rays the other ranks may trace: all of them (dynamic), or theirs (static)
    if (comm.root()) std::copy(rays.begin() + static_cast<std::ptrdiff_t>(dynamic ? 0 : share(1)), rays.end(), srays + (dynamic ? 0 : share(1)));
    auto sync = [&](const char* what) {  // the window's stores before the barrier, seen after it
      call(t, "MPI_Win_sync", 0, 0, [&] { return MPI_Win_sync(sc.shared.win); });
      call(t, what, 0, 0, [&] { return MPI_Barrier(comm.comm); });
      call(t, "MPI_Win_sync", 0, 0, [&] { return MPI_Win_sync(sc.shared.win); });
    };
    sync("MPI_Barrier (rays in the shared window)");
    std::uint64_t traced = 0;
    // traces rays [lo, lo + k): the root's straight into `out`, the others' into the window
    auto trace_rays = [&](std::uint64_t lo, std::uint64_t k) {
      if (comm.root()) {
        if (!dynamic) {  // its share, in one call, straight into `out`
          trace_share(backend, acc, rays.subspan(lo, k), lo, opt, out);
          invalid += out.invalid;
          return;
        }
        trace_share(backend, acc, rays.subspan(lo, k), lo, opt, sc.part);
        std::copy_n(answer_bytes(sc.part), k * res_bytes, answer_bytes(out) + lo * res_bytes);
      } else {
        trace_share(backend, acc, std::span<const Ray>(srays + lo, k), lo, opt, sc.part);
        std::copy_n(answer_bytes(sc.part), k * res_bytes, sanswers + lo * res_bytes);
      }
      invalid += sc.part.invalid;
      traced += k;
    };
    std::vector<std::uint8_t> roots;  // the root's: which batches it traced itself
    if (!dynamic) {
      trace_rays(share(me), share(me + 1) - share(me));
    } else {
      if (comm.root()) {
        out.reset(n, opt);
        roots.assign(batches, 0);
      }
      WorkQueue queue(comm, batches, t);
      for (std::int64_t b; (b = queue.next()) >= 0;) {
        const std::uint64_t ub = static_cast<std::uint64_t>(b);
        trace_rays(ub * batch, batch_rays(ub));
        if (comm.root()) roots[ub] = 1;
      }
    }
    if (t && !comm.root()) {  // moved through shared memory: counted as MPI_Scatterv and MPI_Gatherv would count them
      t->bytes_received += traced * sizeof(Ray);
      t->bytes_sent += traced * res_bytes;
    }
    sync("MPI_Barrier (answers in the shared window)");
    if (comm.root()) {
      std::uint64_t moved = 0;
      if (!dynamic) {
        resize(out, n);
        moved = n - share(1);
        std::copy_n(sanswers + share(1) * res_bytes, moved * res_bytes, answer_bytes(out) + share(1) * res_bytes);
      } else {
        for (std::uint64_t b = 0; b < batches; ++b)
          if (!roots[b]) {
            std::copy_n(sanswers + b * batch * res_bytes, batch_rays(b) * res_bytes, answer_bytes(out) + b * batch * res_bytes);
            moved += batch_rays(b);
          }
      }
      if (t) {
        t->bytes_sent += moved * sizeof(Ray);
        t->bytes_received += moved * res_bytes;
      }
    }
  } else if (sched.schedule == Schedule::static_batches) {
    // static: each rank its contiguous share, sent with one MPI_Scatterv straight from the caller's
    // array; the root traces its share straight into `out`, and the others' answers are gathered
    // after it (no packing, no staging copy)
    std::vector<int> counts(static_cast<std::size_t>(P)), displs(static_cast<std::size_t>(P));
    for (int r = 0; r < P; ++r) {
      displs[static_cast<std::size_t>(r)] = count(share(r), "MPI_Scatterv (rays)");
      counts[static_cast<std::size_t>(r)] = count(share(r + 1) - share(r), "MPI_Scatterv (rays)");
    }
    const std::uint64_t mine = share(me + 1) - share(me);
    if (!comm.root()) sc.rays.resize(mine);
    call(t, "MPI_Scatterv (rays)", comm.root() ? (n - mine) * sizeof(Ray) : 0, comm.root() ? 0 : mine * sizeof(Ray), [&] {
      return MPI_Scatterv(rays.data(), counts.data(), displs.data(), ray_t.type, comm.root() ? MPI_IN_PLACE : sc.rays.data(),
                          count(mine, "MPI_Scatterv (rays)"), ray_t.type, 0, comm.comm);
    });
    // one trace call, so the backend's threads share all of this rank's rays
    TraceOutput& mine_out = comm.root() ? out : sc.part;
    trace_share(backend, acc, comm.root() ? rays.subspan(0, mine) : std::span<const Ray>(sc.rays), share(me), opt, mine_out);
    invalid = mine_out.invalid;
    if (comm.root()) resize(out, n);
    call(t, "MPI_Gatherv (answers)", comm.root() ? 0 : mine * res_bytes, comm.root() ? (n - mine) * res_bytes : 0, [&] {
      return MPI_Gatherv(comm.root() ? MPI_IN_PLACE : answer_bytes(sc.part), count(mine, "MPI_Gatherv (answers)"), res_t.type,
                         comm.root() ? answer_bytes(out) : nullptr, counts.data(), displs.data(), res_t.type, 0, comm.comm);
    });
  } else {
    // dynamic: a batch at a time from the work queue (its own share first, then stolen), its rays
    // read from the root's window (one-sided: no rank serves requests; the window is kept between
    // calls), traced, its answers kept for the gather
    sc.rays_window.ensure(comm, n * sizeof(Ray), false, t);  // every rank knows n: they agree
    if (comm.root()) std::copy(rays.begin(), rays.end(), reinterpret_cast<Ray*>(sc.rays_window.base));
    call(t, "MPI_Win_sync", 0, 0, [&] { return MPI_Win_sync(sc.rays_window.win); });
    call(t, "MPI_Barrier (rays)", 0, 0, [&] { return MPI_Barrier(comm.comm); });  // the rays are in place
    sc.batches.clear();
    sc.gathered.clear();
    std::uint64_t traced = 0;
    {
      WorkQueue queue(comm, batches, t);
      for (std::int64_t b; (b = queue.next()) >= 0;) {
        const std::uint64_t ub = static_cast<std::uint64_t>(b), k = batch_rays(ub);
        sc.batches.push_back(ub);
        std::span<const Ray> batch_rays_of_b;
        if (comm.root()) {
          batch_rays_of_b = rays.subspan(ub * batch, k);
        } else {
          sc.rays.resize(k);
          call(t, "MPI_Get (rays)", 0, k * sizeof(Ray), [&] {
            return MPI_Get(sc.rays.data(), count(k, "MPI_Get (rays)"), ray_t.type, 0,
                           static_cast<MPI_Aint>(ub * batch * sizeof(Ray)), count(k, "MPI_Get (rays)"), ray_t.type,
                           sc.rays_window.win);
          });
          call(t, "MPI_Win_flush", 0, 0, [&] { return MPI_Win_flush(0, sc.rays_window.win); });
          batch_rays_of_b = sc.rays;
        }
        trace_share(backend, acc, batch_rays_of_b, ub * batch, opt, sc.part);
        invalid += sc.part.invalid;
        const char* a = answer_bytes(sc.part);
        sc.gathered.insert(sc.gathered.end(), a, a + k * res_bytes);
        traced += k;
      }
    }
    // -- gather: which batches each rank traced, then their answers, placed in ray order
    const int nb = count(sc.batches.size(), "MPI_Gather (batches)");
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
    call(t, "MPI_Gatherv (batch ids)", sc.batches.size() * 8, comm.root() ? all_batches.size() * 8 : 0, [&] {
      return MPI_Gatherv(sc.batches.data(), nb, MPI_UINT64_T, all_batches.data(), nbs.data(), bdispl.data(), MPI_UINT64_T,
                         0, comm.comm);
    });
    std::vector<char> gathered;  // the root's: every rank's answers, rank by rank
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
    call(t, "MPI_Gatherv (answers)", comm.root() ? 0 : traced * res_bytes, comm.root() ? (n - traced) * res_bytes : 0, [&] {
      return MPI_Gatherv(sc.gathered.data(), count(traced, "MPI_Gatherv (answers)"), res_t.type, gathered.data(),
                         rcounts.data(), rdispl.data(), res_t.type, 0, comm.comm);
    });
    if (comm.root()) {
      out.reset(n, opt);
      char* answers = answer_bytes(out);
      std::uint64_t from = 0;
      for (std::uint64_t b : all_batches) {
        const std::uint64_t k = batch_rays(b);
        std::copy_n(gathered.data() + from * res_bytes, k * res_bytes, answers + b * batch * res_bytes);
        from += k;
      }
    }
  }
  std::uint64_t total_invalid = 0;
  call(t, "MPI_Reduce (invalid)", 8, 8, [&] { return MPI_Reduce(&invalid, &total_invalid, 1, MPI_UINT64_T, MPI_SUM, 0, comm.comm); });
  if (comm.root()) out.invalid = total_invalid;
  else out = TraceOutput{};
}

}  // namespace mbvh::mpi

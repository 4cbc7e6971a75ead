// SPDX-License-Identifier: MIT
// parallel.cpp — parallel_for on a persistent worker pool with an atomic chunk counter.
//
// The pool's threads are started once (grown on demand up to the largest request) and sleep on a
// condition variable between calls, so a call creates no thread. Before it sleeps, a worker that
// took part in the last call polls for the next one for up to kSpin (yielding its core now and
// then, for pools larger than the machine), and the caller polls for the workers' end the same way: a
// build makes many short calls in a row, and a thread woken from its condition variable costs a
// futex wake and a reschedule each time (far more than a poll on a virtual machine, whose idle
// cores halt). The caller is worker 0 and runs chunks too. Chunk semantics are those of the
// per-call threads before: chunk c covers [c * grain, min(n, (c + 1) * grain)), claimed
// dynamically, so results may depend only on the chunk index. Safe re-entry: a call made from
// inside a running parallel_for (a pool worker, or the caller while it works) runs its chunks
// inline on that thread; a call from another thread while the pool is busy gets threads of its
// own for that call (the previous behaviour) instead of waiting. At exit the pool's destructor
// wakes and joins every worker (nothing leaks under ASan/LSan). A task runner set by the caller
// (mbvh/tasks.h) replaces the pool: the job's workers become its tasks.
#include "host/core/parallel.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <exception>
#include <mutex>
#include <thread>
#include <memory>
#include <vector>

#include "mbvh/tasks.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace mbvh {

unsigned resolve_threads(unsigned threads) {
  if (threads == 0) threads = std::thread::hardware_concurrency();
  return std::clamp(threads, 1u, kMaxThreads);
}

namespace {

/// One parallel_for call: its chunks, the shared counter and the first exception.
struct Job {
  const std::function<void(std::size_t, std::size_t, unsigned)>* fn;
  std::size_t n, grain, chunks;
  unsigned workers;
  std::atomic<std::size_t> next{0};
  std::exception_ptr error;
  std::mutex error_mutex;

  void work(unsigned w) {
    for (;;) {
      const std::size_t c = next.fetch_add(1);
      if (c >= chunks) return;
      try {
        (*fn)(c * grain, std::min(n, (c + 1) * grain), w);
      } catch (...) {
        std::lock_guard<std::mutex> lock(error_mutex);
        if (!error) error = std::current_exception();
        next = chunks;
      }
    }
  }
};

/// How long a pool thread polls before it sleeps (see the top of this file): longer than the gaps
/// between a build's calls, short enough that an idle pool soon stops using its cores.
constexpr auto kSpin = std::chrono::microseconds(300);

/// Polls `ready` until it holds or kSpin has passed (the caller then waits on its condition
/// variable, which returns at once where `ready` held).
template <class Ready>
void spin_until(Ready&& ready) {
  const auto until = std::chrono::steady_clock::now() + kSpin;
  for (unsigned k = 1;; ++k) {
    if (ready()) return;
#if defined(__SSE2__)
    _mm_pause();
#endif
    if (k % 64 != 0) continue;
    if (std::chrono::steady_clock::now() >= until) return;
    std::this_thread::yield();  // where threads outnumber cores, let a runnable one have this core
  }
}

/// True on a pool worker, and on a caller while it runs its own share of a job.
thread_local bool t_in_parallel = false;

struct InParallel {
  bool saved = t_in_parallel;
  InParallel() { t_in_parallel = true; }
  ~InParallel() { t_in_parallel = saved; }
};

class Pool {
public:
  ~Pool() {
    {
      std::lock_guard<std::mutex> lock(m_);
      stop_ = true;
    }
    wake_.notify_all();
    for (std::thread& t : threads_) t.join();
  }

  /// Runs `job` on the caller and job.workers - 1 pool threads; false (nothing run) when another
  /// caller holds the pool.
  bool try_run(Job& job) {
    std::unique_lock<std::mutex> submit(submit_, std::try_to_lock);
    if (!submit.owns_lock()) return false;
    {
      std::lock_guard<std::mutex> lock(m_);
      while (threads_.size() + 1 < job.workers) {
        const unsigned id = static_cast<unsigned>(threads_.size()) + 1;
        threads_.emplace_back([this, id] { loop(id); });
      }
      job_ = &job;
      pending_ = job.workers - 1;
      ++generation_;
    }
    wake_.notify_all();
    {
      InParallel inside;
      job.work(0);
    }
    spin_until([this] { return pending_.load(std::memory_order_acquire) == 0; });
    std::unique_lock<std::mutex> lock(m_);
    done_.wait(lock, [this] { return pending_ == 0; });
    job_ = nullptr;
    return true;
  }

private:
  void loop(unsigned id) {
    t_in_parallel = true;
    std::uint64_t seen = 0;
    bool worked = false;  // whether this thread took part in the last call: only then it polls
    std::unique_lock<std::mutex> lock(m_);
    for (;;) {
      if (worked && !stop_ && generation_ == seen) {  // poll for the next call before sleeping
        lock.unlock();
        spin_until([&] { return stop_.load(std::memory_order_relaxed) || generation_.load(std::memory_order_relaxed) != seen; });
        lock.lock();
      }
      wake_.wait(lock, [&] { return stop_ || generation_ != seen; });
      if (stop_) return;
      seen = generation_;
      Job* job = job_;
      worked = job != nullptr && id < job->workers;
      if (!worked) continue;
      lock.unlock();
      job->work(id);
      lock.lock();
      if (--pending_ == 0) done_.notify_one();
    }
  }

  std::mutex submit_;  ///< held by the one caller the pool serves
  std::mutex m_;
  std::condition_variable wake_, done_;
  std::vector<std::thread> threads_;
  Job* job_ = nullptr;
  // written under m_, atomic so that spin_until may read them without it
  std::atomic<unsigned> pending_{0};
  std::atomic<std::uint64_t> generation_{0};
  std::atomic<bool> stop_{false};
};

Pool& pool() {
  static Pool p;  // destroyed at exit: its workers are joined
  return p;
}

std::mutex g_runner_mutex;
std::shared_ptr<const TaskRunner> g_runner;  ///< null: the pool

std::shared_ptr<const TaskRunner> task_runner() {
  std::lock_guard<std::mutex> lock(g_runner_mutex);
  return g_runner;
}

}  // namespace

TaskRunner set_task_runner(TaskRunner runner) {
  auto next = runner ? std::make_shared<const TaskRunner>(std::move(runner)) : nullptr;
  std::lock_guard<std::mutex> lock(g_runner_mutex);
  std::swap(g_runner, next);
  return next ? *next : TaskRunner{};
}

void parallel_for(std::size_t n, std::size_t grain, unsigned threads,
                  const std::function<void(std::size_t, std::size_t, unsigned)>& fn) {
  if (n == 0) return;
  grain = std::max<std::size_t>(grain, 1);
  Job job;
  job.fn = &fn;
  job.n = n;
  job.grain = grain;
  job.chunks = (n + grain - 1) / grain;
  job.workers = static_cast<unsigned>(std::min<std::size_t>(resolve_threads(threads), job.chunks));
  if (job.workers <= 1 || t_in_parallel) {
    job.workers = 1;  // one worker, or a nested call: inline on this thread
    job.work(0);
  } else if (const std::shared_ptr<const TaskRunner> runner = task_runner()) {
    // the caller's scheduler: one task per worker, each claiming chunks (Job::work catches)
    (*runner)(job.workers, [&job](std::size_t w) {
      if (w >= job.workers) return;  // not one of the tasks asked for
      InParallel inside;
      job.work(static_cast<unsigned>(w));
    });
    InParallel inside;
    job.work(0);  // chunks a runner left unclaimed (it skipped a task): run here, now that no task runs
  } else if (!pool().try_run(job)) {
    std::vector<std::thread> extra;  // the pool serves another caller: threads for this call
    for (unsigned w = 1; w < job.workers; ++w)
      extra.emplace_back([&job, w] {
        t_in_parallel = true;
        job.work(w);
      });
    {
      InParallel inside;
      job.work(0);
    }
    for (std::thread& t : extra) t.join();
  }
  if (job.error) std::rethrow_exception(job.error);
}

}  // namespace mbvh

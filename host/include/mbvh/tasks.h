// SPDX-License-Identifier: MIT
// tasks.h — an optional task hook: the caller's scheduler (oneTBB, a renderer's job system) runs
// mbvh's parallel work instead of mbvh's own worker pool.
//
// Every parallel loop of the library (the builds, refit, batch traces, the checks) is one call of
// the runner with `count` tasks, count = the loop's workers (at most the `threads` asked, at most
// its chunks). Each task claims chunks of the loop until none remain, so the answers never depend
// on which thread ran which task, and a runner that runs the tasks one after another on fewer
// threads (or on the calling thread alone) is correct too, only slower. A loop started from inside
// a task runs inline on that task's thread.
//
//   mbvh::set_task_runner([](std::size_t count, const std::function<void(std::size_t)>& task) {
//     tbb::parallel_for(std::size_t(0), count, [&](std::size_t i) { task(i); });
//   });
#pragma once
#include <cstddef>
#include <functional>

namespace mbvh {

/// Runs task(i) for every i in [0, count), on any threads, in any order, several at once or not,
/// and returns when every one has returned. The tasks do not throw (the library catches what its
/// work throws and rethrows it on the thread that started the loop, after the runner returns).
using TaskRunner = std::function<void(std::size_t count, const std::function<void(std::size_t)>& task)>;

/// Sets the runner (an empty one: mbvh's own worker pool, the default) and returns the one it
/// replaces. Thread-safe; a loop already running finishes with the runner it started with.
TaskRunner set_task_runner(TaskRunner runner);

}  // namespace mbvh

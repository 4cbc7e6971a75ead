// SPDX-License-Identifier: MIT
// test_hostile_inputs.cpp — library misuse, loaders and CLI options under hostile input.
#include <catch2/catch.hpp>

#include "tests/helpers.h"

#include <cmath>
#include <cstring>
#include <exception>
#include <mutex>
#include <span>
#include <thread>
#include <vector>

#include "host/tools/raygen.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"
#include "mbvh/trace.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

bool same_answers(const TraceOutput& a, const TraceOutput& b) {
  return a.hits.size() == b.hits.size() && a.occluded == b.occluded && a.invalid == b.invalid &&
         (a.hits.empty() || std::memcmp(a.hits.data(), b.hits.data(), a.hits.size() * sizeof(Hit)) == 0);
}

}  // namespace

TEST_CASE("hostile: several threads tracing on one backend object give the single-threaded answers",
          "[reliability][hostile]") {
  const Scene s = load_scene("gen:sphere:24");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 3000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (const std::string& name : mbvh_test::all_backends().backends) {
    INFO("backend " << name);
    auto backend = make_backend(name, BackendOptions{});
    // two option sets, so that concurrent calls also switch the backend's prepared layout and query
    const Traversal t = backend->supports(Layout::mbvh4, Traversal::stack) ? Traversal::stack : Traversal::bitstack;
    const Layout other = backend->supports(Layout::mbvh2, t) ? Layout::mbvh2 : Layout::mbvh4;
    const TraceOptions opts[2] = {TraceOptions{Layout::mbvh4, t, Query::closest, false},
                                  TraceOptions{other, t, Query::any, false}};
    TraceOutput want[2];
    {
      auto fresh = make_backend(name, BackendOptions{});
      for (int k = 0; k < 2; ++k) fresh->trace(*acc, rays, opts[k], want[k]);
    }
    constexpr int kThreads = 4, kRounds = 4;
    std::vector<int> wrong(kThreads, 0);
    std::vector<std::string> errors(kThreads);
    std::vector<std::thread> pool;
    for (int i = 0; i < kThreads; ++i)
      pool.emplace_back([&, i] {
        try {
          for (int r = 0; r < kRounds; ++r) {
            const int k = (i + r) % 2;
            TraceOutput out;
            backend->trace(*acc, rays, opts[k], out);
            wrong[i] += !same_answers(out, want[k]);
          }
        } catch (const std::exception& e) {
          errors[i] = e.what();
        }
      });
    for (auto& th : pool) th.join();
    backend.reset();  // Vulkan's validation reports what it saw while tearing down
    for (int i = 0; i < kThreads; ++i) {
      INFO("thread " << i);
      CHECK(errors[i] == "");
      CHECK(wrong[i] == 0);
    }
    if (const auto info = [&] {
          for (const BackendInfo& b : list_backends())
            if (b.name == name) return b;
          return BackendInfo{};
        }();
        info.pending_problems)
      CHECK(info.pending_problems().empty());
  }
}

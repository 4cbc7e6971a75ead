// SPDX-License-Identifier: MIT
// test_planted_leak.cpp — a leak on purpose, to prove the sanitizer stage still catches leaks in
// our own code while the Vulkan drivers are kept mapped (vk_runtime.cpp). Hidden from the normal
// runs ([.] tag); CMakeLists.txt registers it in sanitizer builds only, as a test that passes when
// LeakSanitizer reports exactly this allocation and nothing from a driver.
#include <catch2/catch.hpp>

#include <cstdio>
#include <memory>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/config.h"
#include "mbvh/backend.h"
#include "host/tools/raygen.h"
#include "mbvh/scene.h"

namespace {

// noinline: LeakSanitizer's report must name this function.
[[gnu::noinline]] void mbvh_planted_leak() {
  volatile int* lost = new int[25];  // 100 bytes, never freed
  lost[0] = 1;
  std::printf("planted a 100-byte leak at %p\n", static_cast<void*>(const_cast<int*>(lost)));
}

}  // namespace

TEST_CASE("sanitizers: a planted leak in our code is caught (expected to fail under LeakSanitizer)", "[.planted-leak]") {
#ifdef MBVH_HAVE_VULKAN
  {  // the drivers are loaded, traced with and unloaded first: their allocations must not be reported
    const mbvh::Scene scene = mbvh::load_scene("gen:sphere:8");
    const std::unique_ptr<mbvh::Accel> acc = mbvh::Accel::build(scene);
    const std::unique_ptr<mbvh::Backend> backend = mbvh::make_backend("vulkan");
    mbvh::RayGenOptions ro;
    ro.count = 256;
    const std::vector<mbvh::Ray> rays = mbvh::generate_rays(scene, *acc, ro);
    mbvh::TraceOptions opt;
    opt.layout = mbvh::Layout::mbvh2;
    mbvh::TraceOutput out;
    backend->trace(*acc, rays, opt, out);
    REQUIRE(out.hits.size() == rays.size());
  }
#endif
  mbvh_planted_leak();
  SUCCEED();
}

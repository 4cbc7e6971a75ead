// SPDX-License-Identifier: MIT
// backends.cpp — registers every backend compiled into this build, and names the ones that are
// not, with the reason, so `--backend NAME` can say why it cannot start.
#include "backends/cpu/cpu_backends.h"
#include "mbvh/backend.h"
#include "mbvh/backends.h"
#include "mbvh/config.h"
#ifdef MBVH_HAVE_OPENCL
#include "backends/opencl/opencl_backends.h"
#endif
#ifdef MBVH_HAVE_VULKAN
#include "backends/vulkan/vulkan_backends.h"
#endif
#ifdef MBVH_HAVE_EMBREE
#include "backends/embree/embree_backends.h"
#endif
#ifdef MBVH_HAVE_TINYBVH
#include "backends/tinybvh/tinybvh_backends.h"
#endif

namespace mbvh {

namespace {

// A backend this build does not have: listed, with why, so `--backend NAME` can say it.
[[maybe_unused]] void not_built(const char* name, const char* summary, const char* why) {
  BackendInfo info;
  info.name = name;
  info.summary = summary;
  info.unavailable = why;
  register_backend(std::move(info));
}

}  // namespace

void register_builtin_backends() {
  register_cpu_backends();
#ifdef MBVH_HAVE_OPENCL
  register_opencl_backends();
#else
  not_built("opencl", "16-wide MIC-style MBVH4 traversal on OpenCL (PoCL)",
            "this build has no OpenCL backend (configure with -DMBVH_OPENCL=ON or AUTO and the OpenCL headers and ICD "
            "loader installed)");
#endif
#ifdef MBVH_HAVE_VULKAN
  register_vulkan_backends();
#else
  not_built("vulkan", "GPU-style MBVH2 traversal in a GLSL compute shader (lavapipe)",
            "this build has no Vulkan backend (configure with -DMBVH_VULKAN=ON or AUTO and the Vulkan loader headers and "
            "glslangValidator installed)");
#endif
#ifdef MBVH_HAVE_EMBREE
  register_embree_backend();
#else
  not_built("embree", "peer: Embree 3 robust single-ray queries",
            "this build has no Embree peer (install Debian's libembree-dev and reconfigure)");
#endif
#ifdef MBVH_HAVE_TINYBVH
  register_tinybvh_backend();
#else
  not_built("tinybvh", "peer: tinybvh 1.6.7 BVH8_CPU / BVH4_CPU single-ray queries, not watertight", MBVH_TINYBVH_WHY);
#endif
}

}  // namespace mbvh

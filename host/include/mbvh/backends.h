// SPDX-License-Identifier: MIT
// backends.h — registering the backends of this build, for a program that links them (not
// included by mbvh/mbvh.h: the core, mbvh::core, defines none of these). The core knows no
// backend: a program registers the ones it links, once, before make_backend or list_backends.
//   mbvh::register_builtin_backends();   // mbvh::mbvh: every backend this build has
//   mbvh::register_cpu_backends();       // mbvh::cpu only: cpu-scalar, cpu, cpu-avx2, cpu-avx512, dacrt, dacrt-scalar
// Registering twice replaces the entries (harmless). Thread-safe.
#pragma once
#include "mbvh/config.h"

namespace mbvh {

/// mbvh::mbvh: registers every backend of this build (the cpu backends always; opencl, vulkan and
/// embree when built, or as "not built", with the reason, when not).
void register_builtin_backends();

/// mbvh::cpu: cpu-scalar (the reference traversals), cpu (the best SIMD ISA of this machine),
/// cpu-avx2 and cpu-avx512.
void register_cpu_backends();
#ifdef MBVH_HAVE_OPENCL
/// mbvh::opencl: opencl, opencl-wide (the 16-wide MIC-style kernel), opencl-lane.
void register_opencl_backends();
#endif
#ifdef MBVH_HAVE_VULKAN
/// mbvh::vulkan: vulkan (the GLSL compute shader).
void register_vulkan_backends();
#endif
#ifdef MBVH_HAVE_EMBREE
/// mbvh::embree: the embree peer (Embree 3's own BVH and robust queries), for comparison.
void register_embree_backend();
#endif

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// vulkan_backends.h — registers the `vulkan` backend (built when MBVH_VULKAN is on).
#pragma once

namespace mbvh {
void register_vulkan_backends();
}  // namespace mbvh

// vulkan_backends.h — registers the `vulkan` backend (built when MBVH_VULKAN is on).
#pragma once
#include <cstddef>

namespace mbvh {
void register_vulkan_backends();
/// Validation-layer warnings and errors seen so far in this process (0 without the layer); the
/// tests check it after each backend is destroyed, when teardown messages can no longer throw.
std::size_t vulkan_validation_message_count();
}  // namespace mbvh

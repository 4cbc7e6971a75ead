// SPDX-License-Identifier: MIT
// vk_runtime.h — the Vulkan backend's host plumbing below the Backend interface: errors that
// name the failing call and its VkResult, the instance (with the Khronos validation layer and a
// message counter when asked), physical-device discovery and the `--vk-device` choice.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <string>
#include <vector>

namespace mbvh::vk {

/// "VK_ERROR_OUT_OF_DEVICE_MEMORY" etc. ("VkResult N" for a code it does not know).
std::string result_name(VkResult r);
/// Throws mbvh::Error("Vulkan: CALL failed: NAME (code)[: what]").
[[noreturn]] void fail(const char* call, VkResult r, const std::string& what = "");
inline void check(VkResult r, const char* call) {
  if (r != VK_SUCCESS) fail(call, r);
}

/// Whether the validation layer is asked for: `--vk-validation`, or MBVH_VK_VALIDATION=1 in the
/// environment (the tests set it).
bool validation_requested(bool flag);

/// Takes (and clears) the validation-layer warnings and errors raised in this process since the
/// last take, in order.
std::vector<std::string> take_validation_messages();

/// The VkInstance, with VK_LAYER_KHRONOS_validation and a debug messenger that records every
/// warning and error (instance creation and destruction included) when `validation` is set.
/// Throws Error saying what to install when there is no loader, no driver or no layer.
class Instance {
public:
  explicit Instance(bool validation);
  ~Instance();
  Instance(const Instance&) = delete;
  Instance& operator=(const Instance&) = delete;
  VkInstance get() const { return instance_; }
  bool validation() const { return validation_; }

private:
  VkInstance instance_ = VK_NULL_HANDLE;
  VkDebugUtilsMessengerEXT messenger_ = VK_NULL_HANDLE;
  bool validation_ = false;
};

/// One physical device, as `mbvh devices` lists it.
struct DeviceEntry {
  VkPhysicalDevice device = VK_NULL_HANDLE;
  unsigned index = 0;
  std::string name, driver_name, driver_info;
  VkPhysicalDeviceType type = VK_PHYSICAL_DEVICE_TYPE_OTHER;
  std::uint32_t api_version = 0;
  /// The device offers VK_KHR_ray_query (hardware ray tracing from compute shaders; mbvh does
  /// not use it, `mbvh devices` reports it for comparisons with its own traversal).
  bool ray_query = false;
  std::string type_name() const;  ///< "discrete gpu", "integrated gpu", "cpu", ...
  std::string describe() const;   ///< "0 NAME (cpu; DRIVER DRIVER_INFO, Vulkan 1.3.230)"
};

/// Every physical device. Throws Error saying how to install a driver when there is none.
std::vector<DeviceEntry> list_devices(VkInstance instance);

/// The device `selector` names (backends/common/device_choice.h): "" = a discrete GPU if there is one, then
/// an integrated or virtual GPU, then the first device; "N" = the N-th; "gpu" = the first of
/// those GPUs, "cpu" = the first CPU device (lavapipe); else a part of its name.
const DeviceEntry& choose_device(const std::vector<DeviceEntry>& devices, const std::string& selector);

}  // namespace mbvh::vk

// SPDX-License-Identifier: MIT
// vk_device.cpp — see vk_device.h.
#include "backends/vulkan/vk_device.h"

#include <algorithm>
#include <cstdio>
#include <mutex>
#include <set>
#include <vector>

#include "mbvh/error.h"
#include "mbvh/log.h"

namespace mbvh::vk {

Device::Device(const Instance& instance, const DeviceRequest& request) {
  try {
    init(instance, request);
  } catch (...) {
    release();
    throw;
  }
}

Device::~Device() { release(); }

void Device::init(const Instance& instance, const DeviceRequest& o) {
  // -- the device the selector names, said once
  const std::vector<DeviceEntry> devices = list_devices(instance.get());
  entry_ = choose_device(devices, o.selector);
  {  // say which device, once per device in a process
    static std::mutex m;
    static std::set<unsigned> said;
    const std::lock_guard<std::mutex> lock(m);
    if (said.insert(entry_.index).second)
      log_message(LogLevel::info, "vulkan: Vulkan device " + entry_.describe() +
                                      (o.selector.empty() && devices.size() > 1
                                           ? " (chosen from " + std::to_string(devices.size()) +
                                                 " devices; pick one with the vulkan.device setting, --vk-device)"
                                           : std::string()));
  }

  // -- what the shader needs
  const VkPhysicalDevice pd = entry_.device;
  const std::string& name = entry_.name;
  if (entry_.api_version < VK_API_VERSION_1_2)
    throw Error("Vulkan device " + name + " supports only Vulkan " + std::to_string(VK_API_VERSION_MAJOR(entry_.api_version)) +
                "." + std::to_string(VK_API_VERSION_MINOR(entry_.api_version)) + "; the backend needs 1.2");
  VkPhysicalDeviceFeatures features{};
  vkGetPhysicalDeviceFeatures(pd, &features);
  if (!features.shaderInt64) throw Error("Vulkan device " + name + " lacks shaderInt64 (the 64-bit bitstack)");
  if (!features.shaderFloat64)
    throw Error("Vulkan device " + name +
                " lacks shaderFloat64 (the watertight test's exact fallback and correctly rounded division)");
  VkPhysicalDeviceVulkan12Properties p12{};
  p12.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_2_PROPERTIES;
  VkPhysicalDeviceVulkan11Properties p11{};
  p11.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_VULKAN_1_1_PROPERTIES;
  p11.pNext = &p12;
  VkPhysicalDeviceProperties2 props{};
  props.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
  props.pNext = &p11;
  vkGetPhysicalDeviceProperties2(pd, &props);
  if (!p12.shaderSignedZeroInfNanPreserveFloat32)
    throw Error("Vulkan device " + name +
                " lacks shaderSignedZeroInfNanPreserveFloat32: without it -0, inf and NaN need not survive, and the "
                "answers would not be exact (TRAVERSAL.md §9)");
  const VkPhysicalDeviceLimits& lim = props.properties.limits;
  if (lim.maxPerStageDescriptorStorageBuffers < o.storage_descriptors ||
      lim.maxPerStageDescriptorSampledImages < o.texel_descriptors)
    throw Error("Vulkan device " + name + " allows " + std::to_string(lim.maxPerStageDescriptorStorageBuffers) +
                " storage buffers and " + std::to_string(lim.maxPerStageDescriptorSampledImages) +
                " sampled images per stage; the shader binds " + std::to_string(o.storage_descriptors) + " and " +
                std::to_string(o.texel_descriptors));
  VkFormatProperties fp;
  vkGetPhysicalDeviceFormatProperties(pd, VK_FORMAT_R32G32B32A32_UINT, &fp);
  if (!(fp.bufferFeatures & VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT))
    throw Error("Vulkan device " + name + " cannot read R32G32B32A32_UINT uniform texel buffers (the node array)");

  // -- the limits that size bindings and batches
  limits_.range = lim.maxStorageBufferRange;
  limits_.texel_range = std::size_t(lim.maxTexelBufferElements) * 16;
  if (o.max_binding_bytes) {
    limits_.range = std::min<std::size_t>(limits_.range, o.max_binding_bytes);
    limits_.texel_range = std::min<std::size_t>(limits_.texel_range, o.max_binding_bytes);
  }
  limits_.texel_align = lim.minTexelBufferOffsetAlignment;
  limits_.max_alloc = p11.maxMemoryAllocationSize;
  limits_.max_batch = std::min<std::size_t>({o.max_batch, limits_.range / 32, limits_.max_alloc / 32,
                                             std::size_t(lim.maxComputeWorkGroupCount[0]) * o.local_size});
  if (limits_.max_batch < o.local_size)
    throw Error("Vulkan device " + name + ": a storage-buffer binding of " + std::to_string(limits_.range) + " bytes" +
                (o.max_binding_bytes && o.max_binding_bytes < lim.maxStorageBufferRange
                     ? std::string(" (the vulkan.max-binding-bytes cap)")
                     : std::string(" (maxStorageBufferRange)")) +
                " holds fewer rays than one work-group of " + std::to_string(o.local_size) + " (" +
                std::to_string(std::size_t(o.local_size) * 32) + " bytes needed at least)");
  vkGetPhysicalDeviceMemoryProperties(pd, &memory_);

  // -- a queue family with compute
  std::uint32_t nq = 0;
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &nq, nullptr);
  std::vector<VkQueueFamilyProperties> qf(nq);
  vkGetPhysicalDeviceQueueFamilyProperties(pd, &nq, qf.data());
  family_ = nq;
  for (std::uint32_t i = 0; i < nq && family_ == nq; ++i)
    if (qf[i].queueFlags & VK_QUEUE_COMPUTE_BIT) family_ = i;
  if (family_ == nq) throw Error("Vulkan device " + name + " has no compute queue");
  timestamp_bits_ = qf[family_].timestampValidBits;  // 0: the family writes no timestamps
  timestamp_period_ = lim.timestampPeriod;

  // -- the logical device and its queue
  const float priority = 1.0f;
  VkDeviceQueueCreateInfo qi{};
  qi.sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO;
  qi.queueFamilyIndex = family_;
  qi.queueCount = 1;
  qi.pQueuePriorities = &priority;
  VkPhysicalDeviceFeatures enabled{};
  enabled.shaderInt64 = VK_TRUE;
  enabled.shaderFloat64 = VK_TRUE;
  VkDeviceCreateInfo di{};
  di.sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO;
  di.queueCreateInfoCount = 1;
  di.pQueueCreateInfos = &qi;
  di.pEnabledFeatures = &enabled;
  check(vkCreateDevice(pd, &di, nullptr, &device_), "vkCreateDevice");
  vkGetDeviceQueue(device_, family_, 0, &queue_);

  // -- one command buffer, its fence, and the timestamps
  VkCommandPoolCreateInfo pi{};
  pi.sType = VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO;
  pi.flags = VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT;
  pi.queueFamilyIndex = family_;
  check(vkCreateCommandPool(device_, &pi, nullptr, &pool_), "vkCreateCommandPool");
  VkCommandBufferAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO;
  ai.commandPool = pool_;
  ai.level = VK_COMMAND_BUFFER_LEVEL_PRIMARY;
  ai.commandBufferCount = 1;
  check(vkAllocateCommandBuffers(device_, &ai, &cmd_), "vkAllocateCommandBuffers");
  VkFenceCreateInfo fi{};
  fi.sType = VK_STRUCTURE_TYPE_FENCE_CREATE_INFO;
  check(vkCreateFence(device_, &fi, nullptr, &fence_), "vkCreateFence");
  if (timestamp_bits_ > 0) {  // two timestamps around each dispatch (last_device_seconds)
    VkQueryPoolCreateInfo qpi{};
    qpi.sType = VK_STRUCTURE_TYPE_QUERY_POOL_CREATE_INFO;
    qpi.queryType = VK_QUERY_TYPE_TIMESTAMP;
    qpi.queryCount = 2;
    check(vkCreateQueryPool(device_, &qpi, nullptr, &timestamps_), "vkCreateQueryPool");
  }
}

void Device::release() noexcept {
  if (device_ == VK_NULL_HANDLE) return;
  vkDeviceWaitIdle(device_);
  if (timestamps_) vkDestroyQueryPool(device_, timestamps_, nullptr);
  if (fence_) vkDestroyFence(device_, fence_, nullptr);
  if (pool_) vkDestroyCommandPool(device_, pool_, nullptr);
  vkDestroyDevice(device_, nullptr);
  device_ = VK_NULL_HANDLE;
}

void Device::begin() {
  check(vkResetCommandBuffer(cmd_, 0), "vkResetCommandBuffer");
  VkCommandBufferBeginInfo bi{};
  bi.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
  bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
  check(vkBeginCommandBuffer(cmd_, &bi), "vkBeginCommandBuffer");
}

void Device::barrier(VkPipelineStageFlags src_stage, VkAccessFlags src, VkPipelineStageFlags dst_stage, VkAccessFlags dst) {
  VkMemoryBarrier mb{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, src, dst};
  vkCmdPipelineBarrier(cmd_, src_stage, dst_stage, 0, 1, &mb, 0, nullptr, 0, nullptr);
}

void Device::buffer_barrier(VkBuffer b, std::size_t bytes, VkPipelineStageFlags src_stage, VkAccessFlags src,
                            VkPipelineStageFlags dst_stage, VkAccessFlags dst) {
  VkBufferMemoryBarrier bb{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER, nullptr, src, dst, VK_QUEUE_FAMILY_IGNORED,
                           VK_QUEUE_FAMILY_IGNORED, b, 0, bytes};
  vkCmdPipelineBarrier(cmd_, src_stage, dst_stage, 0, 0, nullptr, 1, &bb, 0, nullptr);
}

void Device::copy(VkBuffer from, VkBuffer to, std::size_t bytes) {
  const VkBufferCopy region{0, 0, bytes};
  vkCmdCopyBuffer(cmd_, from, to, 1, &region);
}

void Device::submit_and_wait() {
  check(vkEndCommandBuffer(cmd_), "vkEndCommandBuffer");
  VkSubmitInfo si{};
  si.sType = VK_STRUCTURE_TYPE_SUBMIT_INFO;
  si.commandBufferCount = 1;
  si.pCommandBuffers = &cmd_;
  // the submit orders every host write made before it (rays, counters, mapped uploads) before
  // the commands it submits (host write ordering guarantee)
  check(vkQueueSubmit(queue_, 1, &si, fence_), "vkQueueSubmit");
  // the fence orders the commands' completion before the host reads the mapped results
  const VkResult r = vkWaitForFences(device_, 1, &fence_, VK_TRUE, UINT64_MAX);
  if (r == VK_ERROR_DEVICE_LOST)
    fail("vkWaitForFences", r, "the device was lost during a dispatch of at most " + std::to_string(limits_.max_batch) +
                                   " rays (a driver timeout on a slow device?)");
  check(r, "vkWaitForFences");
  check(vkResetFences(device_, 1, &fence_), "vkResetFences");
}

void Device::wait_idle() {
  if (device_) check(vkDeviceWaitIdle(device_), "vkDeviceWaitIdle");
}

void Device::reset_timestamps() { vkCmdResetQueryPool(cmd_, timestamps_, 0, 2); }

void Device::write_timestamp(VkPipelineStageFlagBits stage, std::uint32_t index) {
  vkCmdWriteTimestamp(cmd_, stage, timestamps_, index);
}

double Device::timestamp_seconds() {
  std::uint64_t ticks[2] = {};  // the fence has signalled: both are written
  check(vkGetQueryPoolResults(device_, timestamps_, 0, 2, sizeof ticks, ticks, sizeof ticks[0],
                              VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT),
        "vkGetQueryPoolResults");
  // only timestamp_bits_ of a tick count are valid: the difference modulo 2^bits survives a wrap
  const std::uint64_t mask = timestamp_bits_ >= 64 ? ~std::uint64_t(0) : (std::uint64_t(1) << timestamp_bits_) - 1;
  return double((ticks[1] - ticks[0]) & mask) * double(timestamp_period_) * 1e-9;
}

}  // namespace mbvh::vk

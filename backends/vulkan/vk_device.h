// SPDX-License-Identifier: MIT
// vk_device.h — the Vulkan backend's device: the chosen physical device checked for what the
// shader needs (Vulkan 1.2, 64-bit integers and floats, SignedZeroInfNanPreserve, the descriptor
// counts, RGBA32UI texel buffers), the limits that size bindings and batches, the logical device
// with one compute queue, and the one command buffer every upload and dispatch records into
// (barriers, copies, timestamps, submit and wait).
#pragma once
#include <vulkan/vulkan.h>

#include <cstddef>
#include <cstdint>
#include <string>

#include "backends/vulkan/vk_runtime.h"

namespace mbvh::vk {

/// What the backend asks of a device.
struct DeviceRequest {
  std::string selector;                    ///< `--vk-device` (choose_device)
  std::size_t max_binding_bytes = 0;       ///< caps both binding ranges when non-zero (tests)
  std::uint32_t local_size = 64;           ///< the shader's work-group size
  std::size_t max_batch = 0;               ///< rays per dispatch at most, before the device's limits
  std::uint32_t storage_descriptors = 0;   ///< storage-buffer descriptors the shader binds
  std::uint32_t texel_descriptors = 0;     ///< uniform texel-buffer descriptors the shader binds
};

/// The device's limits as the backend uses them.
struct DeviceLimits {
  std::size_t range = 0;        ///< bytes of one storage-buffer binding (maxStorageBufferRange, capped)
  std::size_t texel_range = 0;  ///< bytes of one RGBA32UI texel-buffer binding (maxTexelBufferElements * 16, capped)
  std::size_t texel_align = 16; ///< minTexelBufferOffsetAlignment
  std::size_t max_alloc = 0;    ///< maxMemoryAllocationSize
  std::size_t max_batch = 0;    ///< rays per dispatch: within the request, the range, the allocation limit
                                ///< and the work-group count
};

/// The logical device with one compute queue, one resettable command buffer, a fence and (where
/// the queue family has timestamps) a two-entry timestamp query pool. Says which device it chose
/// on stderr, once per device in a process. Throws Error naming what the device lacks, or the
/// failing call and its VkResult.
class Device {
public:
  Device(const Instance& instance, const DeviceRequest& request);
  ~Device();
  Device(const Device&) = delete;
  Device& operator=(const Device&) = delete;

  VkDevice get() const { return device_; }
  const DeviceEntry& entry() const { return entry_; }
  const std::string& name() const { return entry_.name; }
  const DeviceLimits& limits() const { return limits_; }
  const VkPhysicalDeviceMemoryProperties& memory() const { return memory_; }

  /// The command buffer, recorded between begin() and submit_and_wait().
  VkCommandBuffer cmd() const { return cmd_; }
  /// Resets the command buffer and begins a one-time submission.
  void begin();
  /// A global memory barrier.
  void barrier(VkPipelineStageFlags src_stage, VkAccessFlags src, VkPipelineStageFlags dst_stage, VkAccessFlags dst);
  /// A buffer memory barrier over the first `bytes` of `b`.
  void buffer_barrier(VkBuffer b, std::size_t bytes, VkPipelineStageFlags src_stage, VkAccessFlags src,
                      VkPipelineStageFlags dst_stage, VkAccessFlags dst);
  /// The first `bytes` of `from` into `to`.
  void copy(VkBuffer from, VkBuffer to, std::size_t bytes);
  /// Ends, submits and waits for the command buffer.
  void submit_and_wait();
  /// vkDeviceWaitIdle, checked.
  void wait_idle();

  /// Whether the queue family writes timestamps (timestampValidBits > 0).
  bool has_timestamps() const { return timestamps_ != VK_NULL_HANDLE; }
  /// Records the reset of both timestamps (only with has_timestamps()).
  void reset_timestamps();
  /// Records timestamp `index` (0 or 1) at `stage` (only with has_timestamps()).
  void write_timestamp(VkPipelineStageFlagBits stage, std::uint32_t index);
  /// Seconds between timestamps 0 and 1 by the device's clock, once a submission that wrote both
  /// has been waited for.
  double timestamp_seconds();

private:
  void init(const Instance& instance, const DeviceRequest& request);
  void release() noexcept;

  DeviceEntry entry_;
  DeviceLimits limits_;
  VkPhysicalDeviceMemoryProperties memory_{};
  std::uint32_t family_ = 0;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  VkQueryPool timestamps_ = VK_NULL_HANDLE;  ///< two timestamps per dispatch; none without timestampValidBits
  std::uint32_t timestamp_bits_ = 0;         ///< valid bits of a timestamp on the queue family (0: none)
  float timestamp_period_ = 1;               ///< nanoseconds per timestamp tick
};

}  // namespace mbvh::vk

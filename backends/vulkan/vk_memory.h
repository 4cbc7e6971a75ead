// SPDX-License-Identifier: MIT
// vk_memory.h — the Vulkan backend's memory: buffers and the memory they live in, the build's
// arrays uploaded (through the mapping where device-local memory is host-visible, else a staging
// copy), arrays over one binding's range split into power-of-two chunks, and the per-batch
// buffers of rays and results (in place in host-visible memory, or staged through upload and
// readback buffers as on a discrete GPU).
#pragma once
#include <vulkan/vulkan.h>

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "backends/vulkan/vk_device.h"

namespace mbvh::vk {

/// "12.3 MiB".
std::string mib(std::size_t bytes);

/// MBVH_VK_STAGING set and not "0", or `flag`.
bool staging_requested(bool flag);

/// Where a buffer's memory lives: device-local where the device has it (the build's arrays, the
/// staged path's batch buffers); host-visible and coherent for the host to write (upload staging:
/// write-combined is fine); host-visible and coherent, host-cached where available, for the host
/// to read (the direct path's batch buffers, counters, readback staging).
enum class Memory { device, upload, host };

struct Buffer {
  VkBuffer buffer = VK_NULL_HANDLE;
  VkDeviceMemory memory = VK_NULL_HANDLE;
  void* mapped = nullptr;
  VkMemoryPropertyFlags flags = 0;  ///< of the memory type it was allocated from
  std::size_t size = 0;
};

/// A chunked array: one buffer, bound as `count` descriptors of 2^shift records each (texel
/// arrays: one buffer view per chunk).
struct Chunked {
  Buffer buf;
  std::uint32_t count = 1, shift = 0;
  std::size_t chunk_bytes = 0;
  std::vector<VkBufferView> views;
};

/// A buffer of `bytes` in memory `where` (Memory), mapped where that memory is host-visible.
/// Throws Error naming `what` when it exceeds maxMemoryAllocationSize or the allocation fails.
Buffer make_buffer(const Device& dev, std::size_t bytes, VkBufferUsageFlags usage, Memory where, const std::string& what);
/// Unmaps and frees `b` (idle), and empties it.
void destroy(const Device& dev, Buffer& b) noexcept;
/// Destroys the views and the buffer of `c` (idle), and empties it.
void destroy(const Device& dev, Chunked& c) noexcept;

/// One of the build's arrays in device-local memory: written through the mapping where the
/// memory is host-visible (lavapipe), else through a staging buffer and a copy (submitted and
/// waited for).
Buffer upload(Device& dev, const std::string& what, const void* data, std::size_t bytes);

/// An array of `n` records split into power-of-two chunks that each fit one binding's `range`
/// (texel arrays: RGBA32UI buffer views, one per chunk), at most MBVH_VK_CHUNK_BINDINGS of them.
Chunked upload_chunked(Device& dev, const std::string& what, const void* data, std::size_t n, std::size_t record,
                       std::size_t range, bool texels);

/// The rays, hits, occlusion flags and statistics of a batch: in host-visible memory where
/// device-local memory is host-visible (unified memory: the shader reads and writes them in
/// place), else in device-local memory beside host-visible staging buffers the dispatch copies
/// through (staged).
struct BatchBuffers {
  Buffer rays, hits, occ, stats;                    ///< what the shader binds
  Buffer rays_up, hits_down, occ_down, stats_down;  ///< staged path: upload and readback staging
  std::size_t cap = 0;                              ///< rays they hold
  bool staged = true;  ///< device-local, moved by the staging buffers

  /// Makes room for `n` rays (idle); `force_staging` takes the staged path whatever the memory.
  /// Returns whether the buffers were made anew (their descriptors must be written again).
  bool ensure(Device& dev, std::size_t n, bool force_staging);
  void destroy(const Device& dev) noexcept;

  /// What the host writes and reads: the staging buffers on the staged path, else the batch buffers.
  void* rays_in() const { return (staged ? rays_up : rays).mapped; }
  const void* hits_out() const { return (staged ? hits_down : hits).mapped; }
  const void* occ_out() const { return (staged ? occ_down : occ).mapped; }
  const void* stats_out() const { return (staged ? stats_down : stats).mapped; }
};

}  // namespace mbvh::vk

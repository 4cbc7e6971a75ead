// SPDX-License-Identifier: MIT
// vk_memory.cpp — see vk_memory.h.
#include "backends/vulkan/vk_memory.h"

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>

#include "mbvh/error.h"
#include "mbvh/mbvh_layout.h"

namespace mbvh::vk {

std::string mib(std::size_t bytes) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f MiB", double(bytes) / (1024.0 * 1024.0));
  return b;
}

bool staging_requested(bool flag) {
  if (flag) return true;
  const char* env = std::getenv("MBVH_VK_STAGING");
  return env && *env && std::strcmp(env, "0") != 0;
}

namespace {

std::uint32_t memory_type(const Device& dev, std::uint32_t bits, VkMemoryPropertyFlags required,
                          VkMemoryPropertyFlags preferred) {
  const VkPhysicalDeviceMemoryProperties& m = dev.memory();
  for (VkMemoryPropertyFlags want : {required | preferred, required})
    for (std::uint32_t i = 0; i < m.memoryTypeCount; ++i)
      if ((bits & (1u << i)) && (m.memoryTypes[i].propertyFlags & want) == want) return i;
  throw Error("Vulkan device " + dev.name() + " has no memory type with the needed properties");
}

}  // namespace

Buffer make_buffer(const Device& dev, std::size_t bytes, VkBufferUsageFlags usage, Memory where, const std::string& what) {
  const std::size_t max_alloc = dev.limits().max_alloc;
  if (bytes > max_alloc)
    throw Error("vulkan: " + what + " (" + mib(bytes) + ") exceeds maxMemoryAllocationSize (" + mib(max_alloc) + ") of " +
                dev.name() + "; use a smaller scene or another device");
  const VkDevice device = dev.get();
  Buffer b;
  b.size = std::max<std::size_t>(bytes, 16);
  VkBufferCreateInfo bi{};
  bi.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
  bi.size = b.size;
  bi.usage = usage;
  bi.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
  check(vkCreateBuffer(device, &bi, nullptr, &b.buffer), ("vkCreateBuffer(" + what + ", " + mib(bytes) + ")").c_str());
  VkMemoryRequirements req;
  vkGetBufferMemoryRequirements(device, b.buffer, &req);
  VkMemoryAllocateInfo ai{};
  ai.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
  ai.allocationSize = req.size;
  const VkMemoryPropertyFlags coherent = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
  if (where == Memory::device)
    ai.memoryTypeIndex = memory_type(dev, req.memoryTypeBits, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
  else  // upload: any coherent host-visible type (write-combined is fine); host: cached preferred
    ai.memoryTypeIndex =
        memory_type(dev, req.memoryTypeBits, coherent, where == Memory::host ? VK_MEMORY_PROPERTY_HOST_CACHED_BIT : 0);
  const VkResult r = vkAllocateMemory(device, &ai, nullptr, &b.memory);
  if (r != VK_SUCCESS) {
    destroy(dev, b);
    fail("vkAllocateMemory", r, what + ", " + mib(bytes));
  }
  try {
    check(vkBindBufferMemory(device, b.buffer, b.memory, 0), "vkBindBufferMemory");
    b.flags = dev.memory().memoryTypes[ai.memoryTypeIndex].propertyFlags;
    if (b.flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT)
      check(vkMapMemory(device, b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped), "vkMapMemory");
  } catch (...) {
    destroy(dev, b);
    throw;
  }
  return b;
}

void destroy(const Device& dev, Buffer& b) noexcept {
  if (b.mapped) vkUnmapMemory(dev.get(), b.memory);
  if (b.buffer) vkDestroyBuffer(dev.get(), b.buffer, nullptr);
  if (b.memory) vkFreeMemory(dev.get(), b.memory, nullptr);
  b = Buffer{};
}

void destroy(const Device& dev, Chunked& c) noexcept {
  for (VkBufferView v : c.views) vkDestroyBufferView(dev.get(), v, nullptr);
  destroy(dev, c.buf);
  c = Chunked{};
}

Buffer upload(Device& dev, const std::string& what, const void* data, std::size_t bytes) {
  Buffer b = make_buffer(dev, bytes,
                         VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                             VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                         Memory::device, what);
  if (bytes == 0) return b;
  Buffer staging;
  try {
    if (b.mapped) {
      std::memcpy(b.mapped, data, bytes);  // coherent or not, made visible by the next submit
      if (!(b.flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)) {
        VkMappedMemoryRange r{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, b.memory, 0, VK_WHOLE_SIZE};
        check(vkFlushMappedMemoryRanges(dev.get(), 1, &r), "vkFlushMappedMemoryRanges");
      }
      return b;
    }
    staging = make_buffer(dev, bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, Memory::upload, what + " (staging)");
    std::memcpy(staging.mapped, data, bytes);
    dev.begin();
    dev.copy(staging.buffer, b.buffer, bytes);
    // orders: the copy's writes before any later dispatch's shader reads of this array
    dev.barrier(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
                VK_ACCESS_SHADER_READ_BIT);
    dev.submit_and_wait();
  } catch (...) {  // neither buffer outlives a failed upload
    destroy(dev, staging);
    destroy(dev, b);
    throw;
  }
  destroy(dev, staging);
  return b;
}

Chunked upload_chunked(Device& dev, const std::string& what, const void* data, std::size_t n, std::size_t record,
                       std::size_t range, bool texels) {
  constexpr std::uint32_t kChunks = MBVH_VK_CHUNK_BINDINGS;
  Chunked c;
  c.shift = 0;
  while ((record << (c.shift + 1)) <= range && c.shift < 30) ++c.shift;
  c.chunk_bytes = record << c.shift;
  if (c.chunk_bytes > range || (texels && c.chunk_bytes % dev.limits().texel_align != 0))
    throw Error("vulkan: " + what + ": one record does not fit a binding of " + dev.name());
  const std::size_t chunks = std::max<std::size_t>(1, (n + (std::size_t(1) << c.shift) - 1) >> c.shift);
  const char* limit = texels ? "maxTexelBufferElements" : "maxStorageBufferRange";
  if (chunks > kChunks)
    throw Error("vulkan: " + what + " (" + mib(n * record) + ") needs " + std::to_string(chunks) + " bindings of " +
                mib(c.chunk_bytes) + " (" + limit + " " + mib(range) + " of " + dev.name() + "); the shader has " +
                std::to_string(kChunks) + "; use a smaller scene or another device");
  c.count = static_cast<std::uint32_t>(chunks);
  c.buf = upload(dev, what, data, n * record);
  if (texels)
    for (std::uint32_t k = 0; k < c.count; ++k) {
      VkBufferViewCreateInfo vi{};
      vi.sType = VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO;
      vi.buffer = c.buf.buffer;
      vi.format = VK_FORMAT_R32G32B32A32_UINT;
      vi.offset = k * c.chunk_bytes;
      vi.range = std::min(c.chunk_bytes, c.buf.size - vi.offset);
      VkBufferView v = VK_NULL_HANDLE;
      const VkResult r = vkCreateBufferView(dev.get(), &vi, nullptr, &v);
      if (r != VK_SUCCESS) {
        destroy(dev, c);
        fail("vkCreateBufferView", r, what + ", chunk " + std::to_string(k));
      }
      c.views.push_back(v);
    }
  return c;
}

bool BatchBuffers::ensure(Device& dev, std::size_t n, bool force_staging) {
  if (n <= cap) return false;
  dev.wait_idle();
  destroy(dev);
  cap = 0;
  const std::size_t bytes[4] = {n * sizeof(Ray), n * sizeof(Hit), n * sizeof(std::uint32_t), n * sizeof(StatsRecord)};
  const char* what[4] = {"rays", "hits", "occlusion flags", "per-ray statistics"};
  Buffer* batch[4] = {&rays, &hits, &occ, &stats};
  const VkBufferUsageFlags u = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
  if (!force_staging) {  // device-local memory that is host-visible too: today's direct path
    Buffer probe = make_buffer(dev, 16, u, Memory::device, "rays (memory probe)");
    staged = !(probe.flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT);
    vk::destroy(dev, probe);
  }
  if (!staged) {
    for (int i = 0; i < 4; ++i) *batch[i] = make_buffer(dev, bytes[i], u, Memory::host, what[i]);
  } else {
    const VkBufferUsageFlags tu = u | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
    for (int i = 0; i < 4; ++i) *batch[i] = make_buffer(dev, bytes[i], tu, Memory::device, what[i]);
    rays_up = make_buffer(dev, bytes[0], VK_BUFFER_USAGE_TRANSFER_SRC_BIT, Memory::upload, "rays (upload staging)");
    Buffer* down[3] = {&hits_down, &occ_down, &stats_down};
    for (int i = 1; i < 4; ++i)
      *down[i - 1] = make_buffer(dev, bytes[i], VK_BUFFER_USAGE_TRANSFER_DST_BIT, Memory::host,
                                 std::string(what[i]) + " (readback staging)");
  }
  cap = n;
  return true;
}

void BatchBuffers::destroy(const Device& dev) noexcept {
  for (Buffer* b : {&rays, &hits, &occ, &stats, &rays_up, &hits_down, &occ_down, &stats_down}) vk::destroy(dev, *b);
}

}  // namespace mbvh::vk

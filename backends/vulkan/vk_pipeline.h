// SPDX-License-Identifier: MIT
// vk_pipeline.h — the Vulkan backend's pipelines: the embedded shader module (shaders/trace.comp),
// the descriptor set layout of the bindings MBVH_VK_BINDING_*, the pipeline layout with the
// push-constant range of TracePush, the one descriptor set and its writes, and one compute
// pipeline per variant from the specialisation constants MBVH_VK_SPEC_* (all in mbvh_layout.h),
// made on first use and kept.
#pragma once
#include <vulkan/vulkan.h>

#include <cstdint>
#include <map>
#include <tuple>

#include "backends/vulkan/vk_memory.h"
#include "mbvh/mbvh_layout.h"

namespace mbvh::vk {

constexpr std::uint32_t kBindings = MBVH_VK_BINDINGS;
constexpr std::uint32_t kChunks = MBVH_VK_CHUNK_BINDINGS;  ///< descriptors of the node and triangle bindings
/// The descriptor count of binding `i`: the chunked arrays have kChunks.
constexpr std::uint32_t descriptors_of(std::uint32_t i) {
  return i == MBVH_VK_BINDING_NODES || i == MBVH_VK_BINDING_TRIS ? kChunks : 1;
}
/// Storage-buffer descriptors of the set: every binding but the node texels, the triangles chunked.
constexpr std::uint32_t kStorageDescriptors = kBindings - 2 + kChunks;
/// Uniform texel-buffer descriptors of the set: the node chunks.
constexpr std::uint32_t kTexelDescriptors = kChunks;

/// One pipeline's specialisation: the MBVH_VK_SPEC_* values but the work-group size.
struct Variant {
  bool mbvh4 = false, bitstack = true, any = false, stats = false, fast = false;
  std::uint32_t node_chunks = 1, node_shift = 0, tri_chunks = 1, tri_shift = 0;
  auto key() const {
    return std::make_tuple(mbvh4, bitstack, any, stats, fast, node_chunks, node_shift, tri_chunks, tri_shift);
  }
};

/// What the descriptor set binds: a buffer per single binding, the chunked arrays.
struct Bindings {
  VkBuffer rays, hits, occluded, stats, counters, leaves;
  const Chunked* nodes;  ///< the traced layout's node texels
  const Chunked* tris;
};

/// The shader module, set and pipeline layouts, the descriptor set and the pipelines, destroyed
/// with it (the device idle).
class Pipelines {
public:
  Pipelines(const Device& dev, std::uint32_t local_size);
  ~Pipelines();
  Pipelines(const Pipelines&) = delete;
  Pipelines& operator=(const Pipelines&) = delete;

  /// The pipeline of `v`, made on first use.
  VkPipeline get(const Variant& v);
  /// Points the descriptor set at `b`; chunks past an array's end repeat chunk 0 (bound, never
  /// read: the shader's switch). The set must not be in use.
  void write(const Bindings& b);
  /// Records binding `pipe`, the descriptor set and the push constants into the device's command
  /// buffer.
  void bind(VkPipeline pipe, const TracePush& push) const;

private:
  void init();
  void release() noexcept;

  const Device& dev_;
  const std::uint32_t local_size_;
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout pipeline_layout_ = VK_NULL_HANDLE;
  VkDescriptorPool descriptor_pool_ = VK_NULL_HANDLE;
  VkDescriptorSet set_ = VK_NULL_HANDLE;
  VkShaderModule shader_ = VK_NULL_HANDLE;
  std::map<decltype(Variant{}.key()), VkPipeline> pipelines_;
};

}  // namespace mbvh::vk

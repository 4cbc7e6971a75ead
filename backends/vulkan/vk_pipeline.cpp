// SPDX-License-Identifier: MIT
// vk_pipeline.cpp — see vk_pipeline.h.
#include "backends/vulkan/vk_pipeline.h"

#include <algorithm>
#include <utility>
#include <vector>

#include "trace_spv.h"  // kTraceSpv: shaders/trace.comp compiled by glslangValidator (CMakeLists.txt)

namespace mbvh::vk {

Pipelines::Pipelines(const Device& dev, std::uint32_t local_size) : dev_(dev), local_size_(local_size) {
  try {
    init();
  } catch (...) {
    release();
    throw;
  }
}

Pipelines::~Pipelines() { release(); }

void Pipelines::init() {
  const VkDevice device = dev_.get();
  // descriptor layout (MBVH_VK_BINDING_*): storage buffers, but the node chunks as uniform
  // texel buffers
  VkDescriptorSetLayoutBinding b[kBindings]{};
  for (std::uint32_t i = 0; i < kBindings; ++i) {
    b[i].binding = i;
    b[i].descriptorType =
        i == MBVH_VK_BINDING_NODES ? VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER : VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    b[i].descriptorCount = descriptors_of(i);
    b[i].stageFlags = VK_SHADER_STAGE_COMPUTE_BIT;
  }
  VkDescriptorSetLayoutCreateInfo li{};
  li.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_LAYOUT_CREATE_INFO;
  li.bindingCount = kBindings;
  li.pBindings = b;
  check(vkCreateDescriptorSetLayout(device, &li, nullptr, &set_layout_), "vkCreateDescriptorSetLayout");
  // the push constants: MBVH_VK_PUSH_MEMBERS, as TracePush
  VkPushConstantRange pcr{VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(TracePush)};
  VkPipelineLayoutCreateInfo pli{};
  pli.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
  pli.setLayoutCount = 1;
  pli.pSetLayouts = &set_layout_;
  pli.pushConstantRangeCount = 1;
  pli.pPushConstantRanges = &pcr;
  check(vkCreatePipelineLayout(device, &pli, nullptr, &pipeline_layout_), "vkCreatePipelineLayout");
  // the one descriptor set
  const VkDescriptorPoolSize ps[2] = {{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kStorageDescriptors},
                                      {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, kTexelDescriptors}};
  VkDescriptorPoolCreateInfo dpi{};
  dpi.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
  dpi.maxSets = 1;
  dpi.poolSizeCount = 2;
  dpi.pPoolSizes = ps;
  check(vkCreateDescriptorPool(device, &dpi, nullptr, &descriptor_pool_), "vkCreateDescriptorPool");
  VkDescriptorSetAllocateInfo dsi{};
  dsi.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
  dsi.descriptorPool = descriptor_pool_;
  dsi.descriptorSetCount = 1;
  dsi.pSetLayouts = &set_layout_;
  check(vkAllocateDescriptorSets(device, &dsi, &set_), "vkAllocateDescriptorSets");
  // the shader
  VkShaderModuleCreateInfo si{};
  si.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
  si.codeSize = sizeof kTraceSpv;
  si.pCode = kTraceSpv;
  check(vkCreateShaderModule(device, &si, nullptr, &shader_), "vkCreateShaderModule");
}

void Pipelines::release() noexcept {
  const VkDevice device = dev_.get();
  if (device == VK_NULL_HANDLE) return;
  for (auto& [key, p] : pipelines_) vkDestroyPipeline(device, p, nullptr);
  pipelines_.clear();
  if (shader_) vkDestroyShaderModule(device, shader_, nullptr);
  if (descriptor_pool_) vkDestroyDescriptorPool(device, descriptor_pool_, nullptr);
  if (pipeline_layout_) vkDestroyPipelineLayout(device, pipeline_layout_, nullptr);
  if (set_layout_) vkDestroyDescriptorSetLayout(device, set_layout_, nullptr);
  shader_ = VK_NULL_HANDLE;
  descriptor_pool_ = VK_NULL_HANDLE;
  pipeline_layout_ = VK_NULL_HANDLE;
  set_layout_ = VK_NULL_HANDLE;
}

VkPipeline Pipelines::get(const Variant& v) {
  if (auto it = pipelines_.find(v.key()); it != pipelines_.end()) return it->second;
  std::uint32_t spec[MBVH_VK_SPECS]{};  // by constant id, 4 bytes each (VkBool32 for the flags)
  spec[MBVH_VK_SPEC_BITSTACK] = v.bitstack;
  spec[MBVH_VK_SPEC_ANY] = v.any;
  spec[MBVH_VK_SPEC_STATS] = v.stats;
  spec[MBVH_VK_SPEC_NODE_CHUNKS] = v.node_chunks;
  spec[MBVH_VK_SPEC_NODE_SHIFT] = v.node_shift;
  spec[MBVH_VK_SPEC_TRI_CHUNKS] = v.tri_chunks;
  spec[MBVH_VK_SPEC_TRI_SHIFT] = v.tri_shift;
  spec[MBVH_VK_SPEC_LOCAL_SIZE] = local_size_;
  spec[MBVH_VK_SPEC_FAST] = v.fast;
  spec[MBVH_VK_SPEC_MBVH4] = v.mbvh4;
  VkSpecializationMapEntry e[MBVH_VK_SPECS];  // constant_id i at offset 4 i
  for (std::uint32_t i = 0; i < MBVH_VK_SPECS; ++i) e[i] = {i, i * 4u, 4};
  VkSpecializationInfo si{MBVH_VK_SPECS, e, sizeof spec, spec};
  VkComputePipelineCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_COMPUTE_PIPELINE_CREATE_INFO;
  ci.stage.sType = VK_STRUCTURE_TYPE_PIPELINE_SHADER_STAGE_CREATE_INFO;
  ci.stage.stage = VK_SHADER_STAGE_COMPUTE_BIT;
  ci.stage.module = shader_;
  ci.stage.pName = "main";
  ci.stage.pSpecializationInfo = &si;
  ci.layout = pipeline_layout_;
  VkPipeline p = VK_NULL_HANDLE;
  check(vkCreateComputePipelines(dev_.get(), VK_NULL_HANDLE, 1, &ci, nullptr, &p), "vkCreateComputePipelines");
  pipelines_.emplace(v.key(), p);
  return p;
}

void Pipelines::write(const Bindings& bind) {
  const Chunked& nodes = *bind.nodes;
  const Chunked& tris = *bind.tris;
  std::vector<VkDescriptorBufferInfo> info(kBindings);  // per binding; the triangle chunks after them
  const std::pair<std::uint32_t, VkBuffer> buffers[] = {
      {MBVH_VK_BINDING_RAYS, bind.rays},         {MBVH_VK_BINDING_HITS, bind.hits},
      {MBVH_VK_BINDING_OCCLUDED, bind.occluded}, {MBVH_VK_BINDING_STATS, bind.stats},
      {MBVH_VK_BINDING_COUNTERS, bind.counters}, {MBVH_VK_BINDING_LEAVES, bind.leaves}};
  for (const auto& [i, b] : buffers) info[i] = {b, 0, VK_WHOLE_SIZE};
  for (std::uint32_t k = 0; k < kChunks; ++k) {
    const std::size_t off = k < tris.count ? k * tris.chunk_bytes : 0;
    info.push_back({tris.buf.buffer, off, std::min(tris.chunk_bytes, tris.buf.size - off)});
  }
  VkBufferView views[kChunks];
  for (std::uint32_t k = 0; k < kChunks; ++k) views[k] = nodes.views[k < nodes.count ? k : 0];
  VkWriteDescriptorSet w[kBindings]{};
  for (std::uint32_t i = 0; i < kBindings; ++i) {
    w[i].sType = VK_STRUCTURE_TYPE_WRITE_DESCRIPTOR_SET;
    w[i].dstSet = set_;
    w[i].dstBinding = i;
    w[i].descriptorCount = descriptors_of(i);
    if (i == MBVH_VK_BINDING_NODES) {
      w[i].descriptorType = VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER;
      w[i].pTexelBufferView = views;
      continue;
    }
    w[i].descriptorType = VK_DESCRIPTOR_TYPE_STORAGE_BUFFER;
    w[i].pBufferInfo = i == MBVH_VK_BINDING_TRIS ? &info[kBindings] : &info[i];
  }
  vkUpdateDescriptorSets(dev_.get(), kBindings, w, 0, nullptr);
}

void Pipelines::bind(VkPipeline pipe, const TracePush& push) const {
  const VkCommandBuffer cmd = dev_.cmd();
  vkCmdBindPipeline(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipe);
  vkCmdBindDescriptorSets(cmd, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_layout_, 0, 1, &set_, 0, nullptr);
  vkCmdPushConstants(cmd, pipeline_layout_, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof push, &push);
}

}  // namespace mbvh::vk

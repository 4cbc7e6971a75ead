// SPDX-License-Identifier: MIT
// vulkan_backend.cpp — the `vulkan` backend: the GPU path of TRAVERSAL.md §9 — the bitstack of
// Áfra & Szirmay-Kalos 2014 and its stack-based twin over MBVH2 (Aila & Laine node, 1 bit per
// level) and MBVH4 (SoA node, 3-bit skip codes) — as a GLSL compute shader (shaders/trace.comp,
// SPIR-V embedded at build time) on any Vulkan 1.2 device: lavapipe here, a real GPU where there
// is one. Headless: no window, no surface.
//
// Per build, the leaves and triangles are uploaded once, and each layout's nodes the first time
// a trace asks for that layout (device-local memory, by a staging copy where it is not
// host-visible); all are reused across calls. The nodes are read as a uniform texel buffer
// (RGBA32UI; shaders/trace.comp says why), the rest as std430 storage buffers. An array over the
// device's maxTexelBufferElements or maxStorageBufferRange is bound as power-of-two chunks of one
// buffer (up to MBVH_VK_CHUNK_BINDINGS descriptors each); rays go through in batches within the
// range, the allocation limit and the work-group count. Where device-local memory is host-visible
// (unified memory: lavapipe) a batch's rays and results live in host-visible memory the shader
// reads and writes in place; elsewhere (a discrete GPU) they live in device-local memory, and each
// batch's command buffer copies the rays in from an upload staging buffer before the dispatch and
// the results out to a host-cached readback buffer after it (MBVH_VK_STAGING=1 forces this path).
// One pipeline per (layout, traversal, query, statistics, accuracy mode, chunk counts), from
// specialization constants, made on first use and kept. Bindings, specialization constant ids
// and counters: host/include/mbvh/mbvh_layout.h.
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <map>
#include <mutex>
#include <set>
#include <tuple>

#include "backends/vulkan/vk_runtime.h"
#include "backends/vulkan/vulkan_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "trace_spv.h"  // kTraceSpv: shaders/trace.comp compiled by glslangValidator (CMakeLists.txt)

namespace mbvh {
namespace {

using vk::check;

constexpr std::uint32_t kLocalSize = 64;                   // lavapipe: 8 to 1024 measured within noise
constexpr std::size_t kMaxBatch = std::size_t(1) << 21;    // rays per dispatch (64 MiB of rays)
constexpr std::uint32_t kBindings = MBVH_VK_BINDINGS;
constexpr std::uint32_t kChunks = MBVH_VK_CHUNK_BINDINGS;  // descriptors of the node and triangle bindings
constexpr std::uint32_t kStorageBindings = kBindings - 1;  // every binding but the node texels
/// The descriptor count of binding `i`: the chunked arrays have kChunks.
constexpr std::uint32_t descriptors_of(std::uint32_t i) {
  return i == MBVH_VK_BINDING_NODES || i == MBVH_VK_BINDING_TRIS ? kChunks : 1;
}

std::string mib(std::size_t bytes) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f MiB", double(bytes) / (1024.0 * 1024.0));
  return b;
}

/// Where a buffer's memory lives: device-local where the device has it (the build's arrays, the
/// staged path's batch buffers); host-visible and coherent for the host to write (upload staging:
/// write-combined is fine); host-visible and coherent, host-cached where available, for the host
/// to read (the direct path's batch buffers, counters, readback staging).
enum class Memory { device, upload, host };

/// MBVH_VK_STAGING set and not "0".
bool staging_requested(bool flag) {
  if (flag) return true;
  const char* env = std::getenv("MBVH_VK_STAGING");
  return env && *env && std::strcmp(env, "0") != 0;
}

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

class VulkanBackend final : public Backend {
public:
  explicit VulkanBackend(const BackendOptions& o)
      : instance_(vk::validation_requested(o.vk_validation)), force_staging_(staging_requested(o.vk_staging)) {
    try {
      init(o);
    } catch (...) {
      release();
      throw;
    }
  }

  // Messages raised while tearing down cannot be thrown: they stay pending, and the CLI and the
  // tests take them (BackendInfo::pending_problems) and fail.
  ~VulkanBackend() override { release(); }

  std::string name() const override { return "vulkan"; }
  std::string describe() const override {
    std::string s = "vulkan: MBVH2 and MBVH4 GPU-style traversal (GLSL compute, SPIR-V); Vulkan device " +
                    dev_.describe() + (instance_.validation() ? "; validation layer on" : "");
    if (acc_) {  // how the current build is bound
      for (Layout l : {Layout::mbvh2, Layout::mbvh4})
        if (const Chunked& n = nodes(l); n.buf.buffer != VK_NULL_HANDLE)
          s += std::string("; ") + (l == Layout::mbvh2 ? "MBVH2" : "MBVH4") + " nodes in " + std::to_string(n.count) +
               " texel binding(s) of " + mib(n.chunk_bytes);
      s += "; triangles in " + std::to_string(tris_.count) + " storage binding(s) of " + mib(tris_.chunk_bytes) +
           ", batches of " + std::to_string(max_batch_) + " rays";
      if (cap_)
        s += staged_ ? "; rays and results staged through host-visible buffers"
                     : "; rays and results in host-visible memory";
    }
    return s;
  }
  bool supports(Layout l, Traversal t) const override {
    return (l == Layout::mbvh2 || l == Layout::mbvh4) && (t == Traversal::stack || t == Traversal::bitstack);
  }
  bool supports_precision(Precision) const override { return true; }
  double last_device_seconds() const override { return device_seconds_; }

  /// Uploads the build's leaves and triangles (once per build) and the node array of
  /// `opt.layout` (once per build and layout), and binds that layout's nodes.
  void prepare(const Accel& acc, const TraceOptions& opt) override {
    if (opt.layout != Layout::mbvh2 && opt.layout != Layout::mbvh4)
      throw Error("vulkan: layout " + std::string(to_string(opt.layout)) + " is not implemented (the GPU path is MBVH2 "
                  "and MBVH4)");
    if (&acc != acc_ || acc.hash() != hash_ || acc.generation() != generation_) {  // a new build: drop the old one's arrays
      wait_idle();
      destroy(nodes2_);
      destroy(nodes4_);
      destroy(tris_);
      destroy(leaves_);
      acc_ = nullptr;
      descriptors_dirty_ = true;
    }
    if (Chunked& n = nodes(opt.layout); n.buf.buffer == VK_NULL_HANDLE) {
      if (opt.layout == Layout::mbvh4) {
        const auto& v = acc.mbvh4().nodes;
        n = upload_chunked("the MBVH4 node array", v.data(), v.size(), sizeof(Node4), texel_range_, true);
      } else {
        const auto& v = acc.mbvh2().nodes;
        n = upload_chunked("the MBVH2 node array", v.data(), v.size(), sizeof(Node2), texel_range_, true);
      }
      descriptors_dirty_ = true;
    }
    if (acc_ == nullptr) {
      tris_ = upload_chunked("the triangle array", acc.tris().data(), acc.tris().size(), sizeof(Tri), range_, false);
      const std::size_t leaf_bytes = acc.leaves().size() * sizeof(Leaf);
      if (leaf_bytes > range_)
        throw Error("vulkan: the leaf array (" + mib(leaf_bytes) + ") exceeds maxStorageBufferRange (" + mib(range_) +
                    ") of " + dev_.name + "; use a smaller scene or another device");
      leaves_ = upload("the leaf array", acc.leaves().data(), leaf_bytes);
      acc_ = &acc;
      hash_ = acc.hash();
      generation_ = acc.generation();
    }
    if (bound_ != opt.layout) {
      bound_ = opt.layout;
      descriptors_dirty_ = true;
    }
    report_validation();
  }

  void trace(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    if (!supports(opt.layout, opt.traversal))
      throw Error("vulkan: " + std::string(to_string(opt.layout)) + " " + to_string(opt.traversal) +
                  " traversal is not implemented (the GPU path is MBVH2 and MBVH4, stack and bitstack)");
    device_seconds_ = -1;
    prepare(acc, opt);
    const bool any = opt.query == Query::any;
    out.reset(rays.size(), opt);
    if (rays.empty()) return;

    const VkPipeline pipe = pipeline(opt.layout == Layout::mbvh4, opt.traversal == Traversal::bitstack, any, opt.stats,
                                     opt.precision == Precision::fast);
    const std::size_t batch = std::min(rays.size(), max_batch_);
    ensure_batch_buffers(batch);
    if (descriptors_dirty_) write_descriptors();
    std::memset(counters_.mapped, 0, MBVH_COUNTERS * sizeof(std::uint32_t));
    // what the host writes and reads: the staging buffers on the staged path, else the batch buffers
    void* rays_in = (staged_ ? rays_up_ : rays_).mapped;
    const void* hits_out = (staged_ ? hits_down_ : hits_).mapped;
    const void* occ_out = (staged_ ? occ_down_ : occ_).mapped;
    const void* stats_out = (staged_ ? stats_down_ : stats_).mapped;
    double dispatch_seconds = 0;  // the dispatches' summed time on the device's clock (timestamps)
    for (std::size_t b = 0; b < rays.size(); b += batch) {
      const std::size_t n = std::min(batch, rays.size() - b);
      std::memcpy(rays_in, rays.data() + b, n * sizeof(Ray));
      dispatch_seconds += run(pipe, static_cast<std::uint32_t>(n), any, opt.stats);
      if (any) {
        const auto* occ = static_cast<const std::uint32_t*>(occ_out);
        for (std::size_t i = 0; i < n; ++i) out.occluded[b + i] = static_cast<std::uint8_t>(occ[i]);
      } else {
        std::memcpy(out.hits.data() + b, hits_out, n * sizeof(Hit));
      }
      if (opt.stats) {
        const auto* s = static_cast<const StatsRecord*>(stats_out);
        for (std::size_t i = 0; i < n; ++i)
          out.stats[b + i] = RayStats{s[i].nodes,  s[i].box_tests, s[i].leaves,   s[i].tris,
                                      s[i].climbs, s[i].retests,   s[i].max_depth};
      }
    }
    const auto* counters = static_cast<const std::uint32_t*>(counters_.mapped);
    out.invalid = counters[MBVH_COUNTER_INVALID];
    if (timestamps_ != VK_NULL_HANDLE) device_seconds_ = dispatch_seconds;
    report_validation();
    if (counters[MBVH_COUNTER_OVERFLOW] != 0)
      throw Error("vulkan: " + std::to_string(counters[MBVH_COUNTER_OVERFLOW]) + " rays overflowed the traversal stack: the tree is deeper "
                  "than its cap (corrupt build)");
  }

private:
  void init(const BackendOptions& o) {
    const std::vector<vk::DeviceEntry> devices = vk::list_devices(instance_.get());
    dev_ = vk::choose_device(devices, o.vk_device);
    {  // say which device, once per device in a process
      static std::mutex m;
      static std::set<unsigned> said;
      const std::lock_guard<std::mutex> lock(m);
      if (said.insert(dev_.index).second)
        std::fprintf(stderr, "vulkan: Vulkan device %s%s\n", dev_.describe().c_str(),
                     o.vk_device.empty() && devices.size() > 1
                         ? (" (chosen from " + std::to_string(devices.size()) + " devices; pick one with --vk-device)").c_str()
                         : "");
    }
    const VkPhysicalDevice pd = dev_.device;
    if (dev_.api_version < VK_API_VERSION_1_2)
      throw Error("Vulkan device " + dev_.name + " supports only Vulkan " + std::to_string(VK_API_VERSION_MAJOR(dev_.api_version)) +
                  "." + std::to_string(VK_API_VERSION_MINOR(dev_.api_version)) + "; the backend needs 1.2");
    VkPhysicalDeviceFeatures features{};
    vkGetPhysicalDeviceFeatures(pd, &features);
    if (!features.shaderInt64) throw Error("Vulkan device " + dev_.name + " lacks shaderInt64 (the 64-bit bitstack)");
    if (!features.shaderFloat64)
      throw Error("Vulkan device " + dev_.name +
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
      throw Error("Vulkan device " + dev_.name +
                  " lacks shaderSignedZeroInfNanPreserveFloat32: without it -0, inf and NaN need not survive, and the "
                  "answers would not be exact (TRAVERSAL.md §9)");
    const VkPhysicalDeviceLimits& lim = props.properties.limits;
    if (lim.maxPerStageDescriptorStorageBuffers < kStorageBindings - 1 + kChunks ||
        lim.maxPerStageDescriptorSampledImages < kChunks)
      throw Error("Vulkan device " + dev_.name + " allows " + std::to_string(lim.maxPerStageDescriptorStorageBuffers) +
                  " storage buffers and " + std::to_string(lim.maxPerStageDescriptorSampledImages) +
                  " sampled images per stage; the shader binds " + std::to_string(kStorageBindings - 1 + kChunks) + " and " +
                  std::to_string(kChunks));
    VkFormatProperties fp;
    vkGetPhysicalDeviceFormatProperties(pd, VK_FORMAT_R32G32B32A32_UINT, &fp);
    if (!(fp.bufferFeatures & VK_FORMAT_FEATURE_UNIFORM_TEXEL_BUFFER_BIT))
      throw Error("Vulkan device " + dev_.name + " cannot read R32G32B32A32_UINT uniform texel buffers (the node array)");
    range_ = lim.maxStorageBufferRange;
    texel_range_ = std::size_t(lim.maxTexelBufferElements) * 16;
    if (o.vk_max_binding_bytes) {
      range_ = std::min<std::size_t>(range_, o.vk_max_binding_bytes);
      texel_range_ = std::min<std::size_t>(texel_range_, o.vk_max_binding_bytes);
    }
    texel_align_ = lim.minTexelBufferOffsetAlignment;
    max_alloc_ = p11.maxMemoryAllocationSize;
    max_batch_ = std::min<std::size_t>({kMaxBatch, range_ / 32, max_alloc_ / 32,
                                        std::size_t(lim.maxComputeWorkGroupCount[0]) * kLocalSize});
    if (max_batch_ < kLocalSize) throw Error("Vulkan device " + dev_.name + ": storage-buffer range too small");
    vkGetPhysicalDeviceMemoryProperties(pd, &memory_);

    // a queue family with compute
    std::uint32_t nq = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &nq, nullptr);
    std::vector<VkQueueFamilyProperties> qf(nq);
    vkGetPhysicalDeviceQueueFamilyProperties(pd, &nq, qf.data());
    family_ = nq;
    for (std::uint32_t i = 0; i < nq && family_ == nq; ++i)
      if (qf[i].queueFlags & VK_QUEUE_COMPUTE_BIT) family_ = i;
    if (family_ == nq) throw Error("Vulkan device " + dev_.name + " has no compute queue");
    timestamp_bits_ = qf[family_].timestampValidBits;  // 0: the family writes no timestamps
    timestamp_period_ = lim.timestampPeriod;

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
    check(vkCreateDescriptorSetLayout(device_, &li, nullptr, &set_layout_), "vkCreateDescriptorSetLayout");
    VkPushConstantRange pcr{VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof(TracePush)};  // MBVH_VK_PUSH_MEMBERS
    VkPipelineLayoutCreateInfo pli{};
    pli.sType = VK_STRUCTURE_TYPE_PIPELINE_LAYOUT_CREATE_INFO;
    pli.setLayoutCount = 1;
    pli.pSetLayouts = &set_layout_;
    pli.pushConstantRangeCount = 1;
    pli.pPushConstantRanges = &pcr;
    check(vkCreatePipelineLayout(device_, &pli, nullptr, &pipeline_layout_), "vkCreatePipelineLayout");
    const VkDescriptorPoolSize ps[2] = {{VK_DESCRIPTOR_TYPE_STORAGE_BUFFER, kStorageBindings - 1 + kChunks},
                                        {VK_DESCRIPTOR_TYPE_UNIFORM_TEXEL_BUFFER, kChunks}};
    VkDescriptorPoolCreateInfo dpi{};
    dpi.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_POOL_CREATE_INFO;
    dpi.maxSets = 1;
    dpi.poolSizeCount = 2;
    dpi.pPoolSizes = ps;
    check(vkCreateDescriptorPool(device_, &dpi, nullptr, &descriptor_pool_), "vkCreateDescriptorPool");
    VkDescriptorSetAllocateInfo dsi{};
    dsi.sType = VK_STRUCTURE_TYPE_DESCRIPTOR_SET_ALLOCATE_INFO;
    dsi.descriptorPool = descriptor_pool_;
    dsi.descriptorSetCount = 1;
    dsi.pSetLayouts = &set_layout_;
    check(vkAllocateDescriptorSets(device_, &dsi, &set_), "vkAllocateDescriptorSets");
    VkShaderModuleCreateInfo si{};
    si.sType = VK_STRUCTURE_TYPE_SHADER_MODULE_CREATE_INFO;
    si.codeSize = sizeof kTraceSpv;
    si.pCode = kTraceSpv;
    check(vkCreateShaderModule(device_, &si, nullptr, &shader_), "vkCreateShaderModule");
    counters_ = make_buffer(MBVH_COUNTERS * sizeof(std::uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT, Memory::host,
                            "counters");
    report_validation();
  }

  void release() noexcept {
    if (device_ == VK_NULL_HANDLE) return;
    vkDeviceWaitIdle(device_);
    destroy(nodes2_);
    destroy(nodes4_);
    destroy(tris_);
    for (Buffer* b : {&leaves_, &rays_, &hits_, &occ_, &stats_, &counters_}) destroy(*b);
    for (Buffer* b : {&rays_up_, &hits_down_, &occ_down_, &stats_down_}) destroy(*b);
    for (auto& [key, p] : pipelines_) vkDestroyPipeline(device_, p, nullptr);
    pipelines_.clear();
    if (shader_) vkDestroyShaderModule(device_, shader_, nullptr);
    if (descriptor_pool_) vkDestroyDescriptorPool(device_, descriptor_pool_, nullptr);
    if (pipeline_layout_) vkDestroyPipelineLayout(device_, pipeline_layout_, nullptr);
    if (set_layout_) vkDestroyDescriptorSetLayout(device_, set_layout_, nullptr);
    if (timestamps_) vkDestroyQueryPool(device_, timestamps_, nullptr);
    if (fence_) vkDestroyFence(device_, fence_, nullptr);
    if (pool_) vkDestroyCommandPool(device_, pool_, nullptr);
    vkDestroyDevice(device_, nullptr);
    device_ = VK_NULL_HANDLE;
  }

  /// Throws Error with every validation message raised since the last report.
  void report_validation() {
    if (!instance_.validation()) return;
    const std::vector<std::string> m = vk::take_validation_messages();
    if (m.empty()) return;
    std::string text = "vulkan: the validation layer reported " + std::to_string(m.size()) + " message(s):";
    for (const std::string& s : m) text += "\n  " + s;
    throw Error(text);
  }

  void wait_idle() {
    if (device_) check(vkDeviceWaitIdle(device_), "vkDeviceWaitIdle");
  }

  std::uint32_t memory_type(std::uint32_t bits, VkMemoryPropertyFlags required, VkMemoryPropertyFlags preferred) const {
    for (VkMemoryPropertyFlags want : {required | preferred, required})
      for (std::uint32_t i = 0; i < memory_.memoryTypeCount; ++i)
        if ((bits & (1u << i)) && (memory_.memoryTypes[i].propertyFlags & want) == want) return i;
    throw Error("Vulkan device " + dev_.name + " has no memory type with the needed properties");
  }

  /// A buffer of `bytes` in memory `where` (Memory), mapped where that memory is host-visible.
  Buffer make_buffer(std::size_t bytes, VkBufferUsageFlags usage, Memory where, const std::string& what) {
    if (bytes > max_alloc_)
      throw Error("vulkan: " + what + " (" + mib(bytes) + ") exceeds maxMemoryAllocationSize (" + mib(max_alloc_) +
                  ") of " + dev_.name + "; use a smaller scene or another device");
    Buffer b;
    b.size = std::max<std::size_t>(bytes, 16);
    VkBufferCreateInfo bi{};
    bi.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    bi.size = b.size;
    bi.usage = usage;
    bi.sharingMode = VK_SHARING_MODE_EXCLUSIVE;
    check(vkCreateBuffer(device_, &bi, nullptr, &b.buffer), ("vkCreateBuffer(" + what + ", " + mib(bytes) + ")").c_str());
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(device_, b.buffer, &req);
    VkMemoryAllocateInfo ai{};
    ai.sType = VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO;
    ai.allocationSize = req.size;
    const VkMemoryPropertyFlags coherent = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    if (where == Memory::device)
      ai.memoryTypeIndex = memory_type(req.memoryTypeBits, 0, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
    else  // upload: any coherent host-visible type (write-combined is fine); host: cached preferred
      ai.memoryTypeIndex =
          memory_type(req.memoryTypeBits, coherent, where == Memory::host ? VK_MEMORY_PROPERTY_HOST_CACHED_BIT : 0);
    const VkResult r = vkAllocateMemory(device_, &ai, nullptr, &b.memory);
    if (r != VK_SUCCESS) {
      destroy(b);
      vk::fail("vkAllocateMemory", r, what + ", " + mib(bytes));
    }
    check(vkBindBufferMemory(device_, b.buffer, b.memory, 0), "vkBindBufferMemory");
    b.flags = memory_.memoryTypes[ai.memoryTypeIndex].propertyFlags;
    if (b.flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT)
      check(vkMapMemory(device_, b.memory, 0, VK_WHOLE_SIZE, 0, &b.mapped), "vkMapMemory");
    return b;
  }

  void destroy(Chunked& c) noexcept {
    for (VkBufferView v : c.views) vkDestroyBufferView(device_, v, nullptr);
    destroy(c.buf);
    c = Chunked{};
  }

  void destroy(Buffer& b) noexcept {
    if (b.mapped) vkUnmapMemory(device_, b.memory);
    if (b.buffer) vkDestroyBuffer(device_, b.buffer, nullptr);
    if (b.memory) vkFreeMemory(device_, b.memory, nullptr);
    b = Buffer{};
  }

  /// The build's arrays: written through the mapping where the memory is host-visible (lavapipe),
  /// else through a staging buffer and a copy.
  Buffer upload(const std::string& what, const void* data, std::size_t bytes) {
    Buffer b = make_buffer(bytes,
                           VK_BUFFER_USAGE_STORAGE_BUFFER_BIT | VK_BUFFER_USAGE_UNIFORM_TEXEL_BUFFER_BIT |
                               VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                           Memory::device, what);
    if (bytes == 0) return b;
    if (b.mapped) {
      std::memcpy(b.mapped, data, bytes);  // coherent or not, made visible by the next submit
      if (!(b.flags & VK_MEMORY_PROPERTY_HOST_COHERENT_BIT)) {
        VkMappedMemoryRange r{VK_STRUCTURE_TYPE_MAPPED_MEMORY_RANGE, nullptr, b.memory, 0, VK_WHOLE_SIZE};
        check(vkFlushMappedMemoryRanges(device_, 1, &r), "vkFlushMappedMemoryRanges");
      }
      return b;
    }
    Buffer staging = make_buffer(bytes, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, Memory::upload, what + " (staging)");
    std::memcpy(staging.mapped, data, bytes);
    begin();
    const VkBufferCopy region{0, 0, bytes};
    vkCmdCopyBuffer(cmd_, staging.buffer, b.buffer, 1, &region);
    // orders: the copy's writes before any later dispatch's shader reads of this array
    barrier(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT,
            VK_ACCESS_SHADER_READ_BIT);
    submit_and_wait();
    destroy(staging);
    return b;
  }

  /// An array of `n` records split into power-of-two chunks that each fit one binding's `range`
  /// (texel arrays: RGBA32UI buffer views, one per chunk).
  Chunked upload_chunked(const std::string& what, const void* data, std::size_t n, std::size_t record,
                         std::size_t range, bool texels) {
    Chunked c;
    c.shift = 0;
    while ((record << (c.shift + 1)) <= range && c.shift < 30) ++c.shift;
    c.chunk_bytes = record << c.shift;
    if (c.chunk_bytes > range || (texels && c.chunk_bytes % texel_align_ != 0))
      throw Error("vulkan: " + what + ": one record does not fit a binding of " + dev_.name);
    const std::size_t chunks = std::max<std::size_t>(1, (n + (std::size_t(1) << c.shift) - 1) >> c.shift);
    const char* limit = texels ? "maxTexelBufferElements" : "maxStorageBufferRange";
    if (chunks > kChunks)
      throw Error("vulkan: " + what + " (" + mib(n * record) + ") needs " + std::to_string(chunks) + " bindings of " +
                  mib(c.chunk_bytes) + " (" + limit + " " + mib(range) + " of " + dev_.name + "); the shader has " +
                  std::to_string(kChunks) + "; use a smaller scene or another device");
    c.count = static_cast<std::uint32_t>(chunks);
    c.buf = upload(what, data, n * record);
    if (texels)
      for (std::uint32_t k = 0; k < c.count; ++k) {
        VkBufferViewCreateInfo vi{};
        vi.sType = VK_STRUCTURE_TYPE_BUFFER_VIEW_CREATE_INFO;
        vi.buffer = c.buf.buffer;
        vi.format = VK_FORMAT_R32G32B32A32_UINT;
        vi.offset = k * c.chunk_bytes;
        vi.range = std::min(c.chunk_bytes, c.buf.size - vi.offset);
        VkBufferView v = VK_NULL_HANDLE;
        const VkResult r = vkCreateBufferView(device_, &vi, nullptr, &v);
        if (r != VK_SUCCESS) {
          destroy(c);
          vk::fail("vkCreateBufferView", r, what + ", chunk " + std::to_string(k));
        }
        c.views.push_back(v);
      }
    return c;
  }

  /// The rays, hits, occlusion flags and statistics of a batch of `n` rays: in host-visible memory
  /// where device-local memory is host-visible (unified memory: the shader reads and writes them
  /// in place), else in device-local memory beside host-visible staging buffers (run copies).
  void ensure_batch_buffers(std::size_t n) {
    if (n <= cap_) return;
    wait_idle();
    for (Buffer* b : {&rays_, &hits_, &occ_, &stats_, &rays_up_, &hits_down_, &occ_down_, &stats_down_}) destroy(*b);
    const std::size_t bytes[4] = {n * sizeof(Ray), n * sizeof(Hit), n * sizeof(std::uint32_t),
                                  n * sizeof(StatsRecord)};
    const char* what[4] = {"rays", "hits", "occlusion flags", "per-ray statistics"};
    Buffer* batch[4] = {&rays_, &hits_, &occ_, &stats_};
    const VkBufferUsageFlags u = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    if (!force_staging_) {  // device-local memory that is host-visible too: today's direct path
      Buffer probe = make_buffer(16, u, Memory::device, "rays (memory probe)");
      staged_ = !(probe.flags & VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT);
      destroy(probe);
    }
    if (!staged_) {
      for (int i = 0; i < 4; ++i) *batch[i] = make_buffer(bytes[i], u, Memory::host, what[i]);
    } else {
      const VkBufferUsageFlags tu = u | VK_BUFFER_USAGE_TRANSFER_SRC_BIT | VK_BUFFER_USAGE_TRANSFER_DST_BIT;
      for (int i = 0; i < 4; ++i) *batch[i] = make_buffer(bytes[i], tu, Memory::device, what[i]);
      rays_up_ = make_buffer(bytes[0], VK_BUFFER_USAGE_TRANSFER_SRC_BIT, Memory::upload, "rays (upload staging)");
      Buffer* down[3] = {&hits_down_, &occ_down_, &stats_down_};
      for (int i = 1; i < 4; ++i)
        *down[i - 1] = make_buffer(bytes[i], VK_BUFFER_USAGE_TRANSFER_DST_BIT, Memory::host,
                                   std::string(what[i]) + " (readback staging)");
    }
    cap_ = n;
    descriptors_dirty_ = true;
  }

  /// The node array of a layout (MBVH2 or MBVH4); empty until a trace asks for that layout.
  Chunked& nodes(Layout l) { return l == Layout::mbvh4 ? nodes4_ : nodes2_; }
  const Chunked& nodes(Layout l) const { return l == Layout::mbvh4 ? nodes4_ : nodes2_; }

  void write_descriptors() {
    // chunks past an array's end repeat chunk 0: bound, never read (the shader's switch)
    const Chunked& bound = nodes(bound_);
    std::vector<VkDescriptorBufferInfo> info(kBindings);  // per binding; the triangle chunks after them
    const std::pair<std::uint32_t, const Buffer*> buffers[] = {
        {MBVH_VK_BINDING_RAYS, &rays_},         {MBVH_VK_BINDING_HITS, &hits_},
        {MBVH_VK_BINDING_OCCLUDED, &occ_},      {MBVH_VK_BINDING_STATS, &stats_},
        {MBVH_VK_BINDING_COUNTERS, &counters_}, {MBVH_VK_BINDING_LEAVES, &leaves_}};
    for (const auto& [i, b] : buffers) info[i] = {b->buffer, 0, VK_WHOLE_SIZE};
    for (std::uint32_t k = 0; k < kChunks; ++k) {
      const std::size_t off = k < tris_.count ? k * tris_.chunk_bytes : 0;
      info.push_back({tris_.buf.buffer, off, std::min(tris_.chunk_bytes, tris_.buf.size - off)});
    }
    VkBufferView views[kChunks];
    for (std::uint32_t k = 0; k < kChunks; ++k) views[k] = bound.views[k < bound.count ? k : 0];
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
    vkUpdateDescriptorSets(device_, kBindings, w, 0, nullptr);
    descriptors_dirty_ = false;
  }

  VkPipeline pipeline(bool mbvh4, bool bitstack, bool any, bool stats, bool fast) {
    const Chunked& n = nodes(bound_);
    const auto key = std::make_tuple(mbvh4, bitstack, any, stats, fast, n.count, tris_.count);
    if (auto it = pipelines_.find(key); it != pipelines_.end()) return it->second;
    std::uint32_t spec[MBVH_VK_SPECS]{};  // by constant id, 4 bytes each (VkBool32 for the flags)
    spec[MBVH_VK_SPEC_BITSTACK] = bitstack;
    spec[MBVH_VK_SPEC_ANY] = any;
    spec[MBVH_VK_SPEC_STATS] = stats;
    spec[MBVH_VK_SPEC_NODE_CHUNKS] = n.count;
    spec[MBVH_VK_SPEC_NODE_SHIFT] = n.shift;
    spec[MBVH_VK_SPEC_TRI_CHUNKS] = tris_.count;
    spec[MBVH_VK_SPEC_TRI_SHIFT] = tris_.shift;
    spec[MBVH_VK_SPEC_LOCAL_SIZE] = kLocalSize;
    spec[MBVH_VK_SPEC_FAST] = fast;
    spec[MBVH_VK_SPEC_MBVH4] = mbvh4;
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
    check(vkCreateComputePipelines(device_, VK_NULL_HANDLE, 1, &ci, nullptr, &p), "vkCreateComputePipelines");
    pipelines_.emplace(key, p);
    return p;
  }

  void begin() {
    check(vkResetCommandBuffer(cmd_, 0), "vkResetCommandBuffer");
    VkCommandBufferBeginInfo bi{};
    bi.sType = VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO;
    bi.flags = VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT;
    check(vkBeginCommandBuffer(cmd_, &bi), "vkBeginCommandBuffer");
  }

  void barrier(VkPipelineStageFlags src_stage, VkAccessFlags src, VkPipelineStageFlags dst_stage, VkAccessFlags dst) {
    VkMemoryBarrier mb{VK_STRUCTURE_TYPE_MEMORY_BARRIER, nullptr, src, dst};
    vkCmdPipelineBarrier(cmd_, src_stage, dst_stage, 0, 1, &mb, 0, nullptr, 0, nullptr);
  }

  void submit_and_wait() {
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
      vk::fail("vkWaitForFences", r, "the device was lost during a dispatch of at most " + std::to_string(max_batch_) +
                                         " rays (a driver timeout on a slow device?)");
    check(r, "vkWaitForFences");
    check(vkResetFences(device_, 1, &fence_), "vkResetFences");
  }

  /// A buffer memory barrier over the first `bytes` of `b`.
  void buffer_barrier(const Buffer& b, std::size_t bytes, VkPipelineStageFlags src_stage, VkAccessFlags src,
                      VkPipelineStageFlags dst_stage, VkAccessFlags dst) {
    VkBufferMemoryBarrier bb{VK_STRUCTURE_TYPE_BUFFER_MEMORY_BARRIER, nullptr, src, dst, VK_QUEUE_FAMILY_IGNORED,
                             VK_QUEUE_FAMILY_IGNORED, b.buffer, 0, bytes};
    vkCmdPipelineBarrier(cmd_, src_stage, dst_stage, 0, 0, nullptr, 1, &bb, 0, nullptr);
  }

  /// The first `bytes` of `from` into `to`.
  void copy(const Buffer& from, const Buffer& to, std::size_t bytes) {
    const VkBufferCopy region{0, 0, bytes};
    vkCmdCopyBuffer(cmd_, from.buffer, to.buffer, 1, &region);
  }

  /// One dispatch of `n` rays from the ray buffer (on the staged path, copied in before it and the
  /// results the query `any` and `stats` ask for copied out after it); returns its execution time
  /// in seconds by the device's clock (the timestamps around it), 0 where the queue family has no
  /// timestamps.
  double run(VkPipeline pipe, std::uint32_t n, bool any, bool stats) {
    const std::size_t ray_bytes = n * sizeof(Ray);
    // the results the host reads: hits or occlusion flags, and statistics when asked for
    std::vector<std::pair<const Buffer*, const Buffer*>> out{
        any ? std::make_pair(&occ_, &occ_down_) : std::make_pair(&hits_, &hits_down_)};
    if (stats) out.emplace_back(&stats_, &stats_down_);
    const auto bytes_of = [&](const Buffer* b) {
      const std::size_t record = b == &hits_ ? sizeof(Hit)
                                 : b == &occ_ ? sizeof(std::uint32_t)
                                              : sizeof(StatsRecord);
      return n * record;
    };
    begin();
    if (timestamps_) vkCmdResetQueryPool(cmd_, timestamps_, 0, 2);
    if (staged_) {
      copy(rays_up_, rays_, ray_bytes);
      // orders: the copy's writes of the rays before the dispatch's shader reads of them
      buffer_barrier(rays_, ray_bytes, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                     VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    }
    vkCmdBindPipeline(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, pipe);
    vkCmdBindDescriptorSets(cmd_, VK_PIPELINE_BIND_POINT_COMPUTE, pipeline_layout_, 0, 1, &set_, 0, nullptr);
    TracePush push{};
    push.count = n;
    vkCmdPushConstants(cmd_, pipeline_layout_, VK_SHADER_STAGE_COMPUTE_BIT, 0, sizeof push, &push);
    // timestamps: before the dispatch starts (on the staged path, once the rays' copy has
    // completed), and once every earlier command has completed
    if (timestamps_)
      vkCmdWriteTimestamp(cmd_, staged_ ? VK_PIPELINE_STAGE_TRANSFER_BIT : VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
                          timestamps_, 0);
    vkCmdDispatch(cmd_, (n + kLocalSize - 1) / kLocalSize, 1, 1);
    if (timestamps_) vkCmdWriteTimestamp(cmd_, VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, timestamps_, 1);
    if (staged_) {
      // orders: the shader's writes of the results before the copies' reads of them
      for (const auto& [dev, host] : out)
        buffer_barrier(*dev, bytes_of(dev), VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                       VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
      for (const auto& [dev, host] : out) copy(*dev, *host, bytes_of(dev));
      // orders: the copies' writes of the readback buffers before the host reads them
      barrier(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_HOST_BIT,
              VK_ACCESS_HOST_READ_BIT);
    }
    // orders: the shader's writes (hits, flags, statistics, counters) before the host reads them
    barrier(VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_HOST_BIT,
            VK_ACCESS_HOST_READ_BIT);
    submit_and_wait();
    if (!timestamps_) return 0;
    std::uint64_t ticks[2] = {};  // the fence has signalled: both are written
    check(vkGetQueryPoolResults(device_, timestamps_, 0, 2, sizeof ticks, ticks, sizeof ticks[0],
                                VK_QUERY_RESULT_64_BIT | VK_QUERY_RESULT_WAIT_BIT),
          "vkGetQueryPoolResults");
    // only timestamp_bits_ of a tick count are valid: the difference modulo 2^bits survives a wrap
    const std::uint64_t mask = timestamp_bits_ >= 64 ? ~std::uint64_t(0) : (std::uint64_t(1) << timestamp_bits_) - 1;
    return double((ticks[1] - ticks[0]) & mask) * double(timestamp_period_) * 1e-9;
  }

  vk::Instance instance_;
  vk::DeviceEntry dev_;
  VkPhysicalDeviceMemoryProperties memory_{};
  std::size_t range_ = 0, texel_range_ = 0, texel_align_ = 16, max_alloc_ = 0, max_batch_ = 0;
  std::uint32_t family_ = 0;
  VkDevice device_ = VK_NULL_HANDLE;
  VkQueue queue_ = VK_NULL_HANDLE;
  VkCommandPool pool_ = VK_NULL_HANDLE;
  VkCommandBuffer cmd_ = VK_NULL_HANDLE;
  VkFence fence_ = VK_NULL_HANDLE;
  VkQueryPool timestamps_ = VK_NULL_HANDLE;  ///< two timestamps per dispatch; none without timestampValidBits
  std::uint32_t timestamp_bits_ = 0;         ///< valid bits of a timestamp on the queue family (0: none)
  float timestamp_period_ = 1;               ///< nanoseconds per timestamp tick
  double device_seconds_ = -1;               ///< last_device_seconds()
  VkDescriptorSetLayout set_layout_ = VK_NULL_HANDLE;
  VkPipelineLayout pipeline_layout_ = VK_NULL_HANDLE;
  VkDescriptorPool descriptor_pool_ = VK_NULL_HANDLE;
  VkDescriptorSet set_ = VK_NULL_HANDLE;
  VkShaderModule shader_ = VK_NULL_HANDLE;
  std::map<std::tuple<bool, bool, bool, bool, bool, std::uint32_t, std::uint32_t>, VkPipeline> pipelines_;
  bool descriptors_dirty_ = true;
  const Accel* acc_ = nullptr;
  std::uint64_t hash_ = 0;
  std::uint64_t generation_ = 0;  // Accel::generation() of the uploaded arrays (refit bumps it)
  Chunked nodes2_, nodes4_, tris_;
  Layout bound_ = Layout::mbvh2;  ///< whose nodes the descriptor set binds
  Buffer leaves_;
  std::size_t cap_ = 0;
  const bool force_staging_;  ///< BackendOptions::vk_staging or MBVH_VK_STAGING=1
  bool staged_ = true;        ///< the batch buffers are device-local, moved by the staging buffers below
  Buffer rays_, hits_, occ_, stats_, counters_;
  Buffer rays_up_, hits_down_, occ_down_, stats_down_;  ///< staged path: upload and readback staging
};

std::vector<std::string> device_lines() {
  const vk::Instance instance(vk::validation_requested(false));
  const std::vector<vk::DeviceEntry> devices = vk::list_devices(instance.get());
  const vk::DeviceEntry& chosen = vk::choose_device(devices, "");
  std::vector<std::string> lines;
  for (const vk::DeviceEntry& d : devices)
    lines.push_back(d.describe() + (d.ray_query ? ", VK_KHR_ray_query" : ", no VK_KHR_ray_query") +
                    (&d == &chosen ? "  [default]" : ""));
  return lines;
}

}  // namespace

void register_vulkan_backends() {
  BackendInfo info;
  info.name = "vulkan";
  info.summary = "GPU-style MBVH2 and MBVH4 stack and bitstack traversal in a GLSL compute shader (lavapipe here)";
  info.make = [](const BackendOptions& o) -> std::unique_ptr<Backend> { return std::make_unique<VulkanBackend>(o); };
  info.devices = &device_lines;
  info.pending_problems = &vk::take_validation_messages;
  register_backend(std::move(info));
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// vulkan_backend.cpp — the `vulkan` backend: the GPU path of TRAVERSAL.md §9 — the bitstack of
// Áfra & Szirmay-Kalos 2014 and its stack-based twin over MBVH2 (Aila & Laine node, 1 bit per
// level) and MBVH4 (SoA node, 3-bit skip codes) — as a GLSL compute shader (shaders/trace.comp,
// SPIR-V embedded at build time) on any Vulkan 1.2 device: lavapipe on a CPU, or a GPU.
// Headless: no window, no surface.
//
// The Backend here orchestrates three pieces: the device (vk_device.h: the checked physical
// device, its limits, the queue and the command buffer), memory (vk_memory.h: buffers, uploads,
// chunked arrays, the batch buffers) and the pipelines (vk_pipeline.h: shader module, layouts,
// descriptor set, one pipeline per variant).
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
// specialization constants, made on first use and kept. Bindings, specialization constant ids,
// push constants, counters and the statistics record: host/include/mbvh/mbvh_layout.h.
#include <algorithm>
#include <cstring>
#include <utility>

#include "backends/common/build_stamp.h"
#include "backends/vulkan/vk_device.h"
#include "backends/vulkan/vk_memory.h"
#include "backends/vulkan/vk_pipeline.h"
#include "backends/vulkan/vk_runtime.h"
#include "backends/vulkan/vulkan_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

using vk::Buffer;
using vk::Chunked;
using vk::mib;

constexpr std::uint32_t kLocalSize = 64;                 // a CPU device (lavapipe) runs any size alike
constexpr std::size_t kMaxBatch = std::size_t(1) << 21;  // rays per dispatch (64 MiB of rays)

vk::DeviceRequest device_request(const BackendOptions& o) {
  vk::DeviceRequest r;
  r.selector = o.get("vulkan.device");
  r.max_binding_bytes = o.get_size("vulkan.max-binding-bytes");
  r.local_size = kLocalSize;
  r.max_batch = kMaxBatch;
  r.storage_descriptors = vk::kStorageDescriptors;
  r.texel_descriptors = vk::kTexelDescriptors;
  return r;
}

class VulkanBackend final : public Backend {
public:
  explicit VulkanBackend(const BackendOptions& o)
      : instance_(vk::validation_requested(o.get_flag("vulkan.validation"))),
        dev_(instance_, device_request(o)),
        pipelines_(dev_, kLocalSize),
        force_staging_(vk::staging_requested(o.get_flag("vulkan.staging"))) {
    try {
      counters_ = vk::make_buffer(dev_, MBVH_COUNTERS * sizeof(std::uint32_t), VK_BUFFER_USAGE_STORAGE_BUFFER_BIT,
                                  vk::Memory::host, "counters");
      report_validation();
    } catch (...) {
      release();
      throw;
    }
  }

  // Messages raised while tearing down cannot be thrown: they stay pending, and the CLI and the
  // tests take them (BackendInfo::pending_problems) and fail. The pipelines, then the device, go
  // after the buffers (members in reverse order).
  ~VulkanBackend() override { release(); }

  std::string name() const override { return "vulkan"; }
  std::string describe() const override {
    std::string s = "vulkan: MBVH2 and MBVH4 GPU-style traversal (GLSL compute, SPIR-V); Vulkan device " +
                    dev_.entry().describe() + (instance_.validation() ? "; validation layer on" : "");
    if (uploaded_.acc) {  // how the current build is bound
      for (Layout l : {Layout::mbvh2, Layout::mbvh4})
        if (const Chunked& n = nodes(l); n.buf.buffer != VK_NULL_HANDLE)
          s += std::string("; ") + (l == Layout::mbvh2 ? "MBVH2" : "MBVH4") + " nodes in " + std::to_string(n.count) +
               " texel binding(s) of " + mib(n.chunk_bytes);
      s += "; triangles in " + std::to_string(tris_.count) + " storage binding(s) of " + mib(tris_.chunk_bytes) +
           ", batches of " + std::to_string(dev_.limits().max_batch) + " rays";
      if (batch_.cap)
        s += batch_.staged ? "; rays and results staged through host-visible buffers"
                           : "; rays and results in host-visible memory";
    }
    return s;
  }
  bool supports(Layout l, Traversal t) const override {
    return (l == Layout::mbvh2 || l == Layout::mbvh4) && (t == Traversal::stack || t == Traversal::bitstack);
  }
  bool supports_precision(Precision) const override { return true; }

  /// Uploads the build's leaves and triangles (once per build) and the node array of
  /// `opt.layout` (once per build and layout), and binds that layout's nodes.
  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    if (opt.layout != Layout::mbvh2 && opt.layout != Layout::mbvh4)
      throw Error("vulkan: layout " + std::string(to_string(opt.layout)) + " is not implemented (the GPU path is MBVH2 "
                  "and MBVH4)");
    const vk::DeviceLimits& lim = dev_.limits();
    if (uploaded_.stale(acc)) {  // a new build: drop the old one's arrays
      dev_.wait_idle();
      release_build();
      uploaded_ = {};
      descriptors_dirty_ = true;
    }
    if (Chunked& n = nodes(opt.layout); n.buf.buffer == VK_NULL_HANDLE) {
      if (opt.layout == Layout::mbvh4) {
        const auto& v = acc.mbvh4().nodes;
        n = vk::upload_chunked(dev_, "the MBVH4 node array", v.data(), v.size(), sizeof(Node4), lim.texel_range, true);
      } else {
        const auto& v = acc.mbvh2().nodes;
        n = vk::upload_chunked(dev_, "the MBVH2 node array", v.data(), v.size(), sizeof(Node2), lim.texel_range, true);
      }
      descriptors_dirty_ = true;
    }
    if (!uploaded_.acc) {
      tris_ = vk::upload_chunked(dev_, "the triangle array", acc.tris().data(), acc.tris().size(), sizeof(Tri), lim.range,
                                 false);
      const std::size_t leaf_bytes = acc.leaves().size() * sizeof(Leaf);
      if (leaf_bytes > lim.range)
        throw Error("vulkan: the leaf array (" + mib(leaf_bytes) + ") exceeds maxStorageBufferRange (" + mib(lim.range) +
                    ") of " + dev_.name() + "; use a smaller scene or another device");
      leaves_ = vk::upload(dev_, "the leaf array", acc.leaves().data(), leaf_bytes);
      uploaded_.mark(acc);
    }
    if (bound_ != opt.layout) {
      bound_ = opt.layout;
      descriptors_dirty_ = true;
    }
    report_validation();
  }

  /// Writes every ray's answer (and statistics, when asked) from the device.
  void trace_batch(const Accel&, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    const bool any = opt.query == Query::any;
    vk::Variant v;
    v.mbvh4 = opt.layout == Layout::mbvh4;
    v.bitstack = opt.traversal == Traversal::bitstack;
    v.any = any;
    v.stats = opt.stats;
    v.fast = opt.precision == Precision::fast;
    v.node_chunks = nodes(bound_).count;
    v.node_shift = nodes(bound_).shift;
    v.tri_chunks = tris_.count;
    v.tri_shift = tris_.shift;
    const VkPipeline pipe = pipelines_.get(v);
    const std::size_t batch = std::min(rays.size(), dev_.limits().max_batch);
    if (batch_.ensure(dev_, batch, force_staging_)) descriptors_dirty_ = true;
    if (descriptors_dirty_) write_descriptors();
    std::memset(counters_.mapped, 0, MBVH_COUNTERS * sizeof(std::uint32_t));
    double dispatch_seconds = 0;  // the dispatches' summed time on the device's clock (timestamps)
    for (std::size_t b = 0; b < rays.size(); b += batch) {
      const std::size_t n = std::min(batch, rays.size() - b);
      std::memcpy(batch_.rays_in(), rays.data() + b, n * sizeof(Ray));
      dispatch_seconds += run(pipe, static_cast<std::uint32_t>(n), any, opt.stats);
      if (any) {
        const auto* occ = static_cast<const std::uint32_t*>(batch_.occ_out());
        for (std::size_t i = 0; i < n; ++i) out.occluded[b + i] = static_cast<std::uint8_t>(occ[i]);
      } else {
        std::memcpy(out.hits.data() + b, batch_.hits_out(), n * sizeof(Hit));
      }
      if (opt.stats) {
        const auto* s = static_cast<const StatsRecord*>(batch_.stats_out());
        for (std::size_t i = 0; i < n; ++i)
          out.stats[b + i] = RayStats{s[i].nodes,  s[i].box_tests, s[i].leaves,   s[i].tris,
                                      s[i].climbs, s[i].retests,   s[i].max_depth};
      }
    }
    const auto* counters = static_cast<const std::uint32_t*>(counters_.mapped);
    out.invalid = counters[MBVH_COUNTER_INVALID];
    if (dev_.has_timestamps()) set_device_seconds(dispatch_seconds);
    report_validation();
    if (counters[MBVH_COUNTER_OVERFLOW] != 0)
      throw Error("vulkan: " + std::to_string(counters[MBVH_COUNTER_OVERFLOW]) + " rays overflowed the traversal stack: the tree is deeper "
                  "than its cap (corrupt build)");
  }

private:
  /// The build's arrays, freed (the device idle).
  void release_build() noexcept {
    vk::destroy(dev_, nodes2_);
    vk::destroy(dev_, nodes4_);
    vk::destroy(dev_, tris_);
    vk::destroy(dev_, leaves_);
  }

  /// Every buffer, freed once the device is idle.
  void release() noexcept {
    if (dev_.get() == VK_NULL_HANDLE) return;
    vkDeviceWaitIdle(dev_.get());
    release_build();
    batch_.destroy(dev_);
    vk::destroy(dev_, counters_);
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

  /// The node array of a layout (MBVH2 or MBVH4); empty until a trace asks for that layout.
  Chunked& nodes(Layout l) { return l == Layout::mbvh4 ? nodes4_ : nodes2_; }
  const Chunked& nodes(Layout l) const { return l == Layout::mbvh4 ? nodes4_ : nodes2_; }

  void write_descriptors() {
    pipelines_.write({batch_.rays.buffer, batch_.hits.buffer, batch_.occ.buffer, batch_.stats.buffer, counters_.buffer,
                      leaves_.buffer, &nodes(bound_), &tris_});
    descriptors_dirty_ = false;
  }

  /// One dispatch of `n` rays from the ray buffer (on the staged path, copied in before it and the
  /// results the query `any` and `stats` ask for copied out after it); returns its execution time
  /// in seconds by the device's clock (the timestamps around it), 0 where the queue family has no
  /// timestamps.
  double run(VkPipeline pipe, std::uint32_t n, bool any, bool stats) {
    const bool staged = batch_.staged;
    const std::size_t ray_bytes = n * sizeof(Ray);
    // the results the host reads: hits or occlusion flags, and statistics when asked for
    std::vector<std::pair<const Buffer*, const Buffer*>> out{
        any ? std::make_pair(&batch_.occ, &batch_.occ_down) : std::make_pair(&batch_.hits, &batch_.hits_down)};
    if (stats) out.emplace_back(&batch_.stats, &batch_.stats_down);
    const auto bytes_of = [&](const Buffer* b) {
      const std::size_t record = b == &batch_.hits ? sizeof(Hit)
                                 : b == &batch_.occ ? sizeof(std::uint32_t)
                                                    : sizeof(StatsRecord);
      return n * record;
    };
    dev_.begin();
    if (dev_.has_timestamps()) dev_.reset_timestamps();
    if (staged) {
      dev_.copy(batch_.rays_up.buffer, batch_.rays.buffer, ray_bytes);
      // orders: the copy's writes of the rays before the dispatch's shader reads of them
      dev_.buffer_barrier(batch_.rays.buffer, ray_bytes, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT,
                          VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_READ_BIT);
    }
    TracePush push{};
    push.count = n;
    pipelines_.bind(pipe, push);
    // timestamps: before the dispatch starts (on the staged path, once the rays' copy has
    // completed), and once every earlier command has completed
    if (dev_.has_timestamps())
      dev_.write_timestamp(staged ? VK_PIPELINE_STAGE_TRANSFER_BIT : VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, 0);
    vkCmdDispatch(dev_.cmd(), (n + kLocalSize - 1) / kLocalSize, 1, 1);
    if (dev_.has_timestamps()) dev_.write_timestamp(VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, 1);
    if (staged) {
      // orders: the shader's writes of the results before the copies' reads of them
      for (const auto& [dev, host] : out)
        dev_.buffer_barrier(dev->buffer, bytes_of(dev), VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT,
                            VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_READ_BIT);
      for (const auto& [dev, host] : out) dev_.copy(dev->buffer, host->buffer, bytes_of(dev));
      // orders: the copies' writes of the readback buffers before the host reads them
      dev_.barrier(VK_PIPELINE_STAGE_TRANSFER_BIT, VK_ACCESS_TRANSFER_WRITE_BIT, VK_PIPELINE_STAGE_HOST_BIT,
                   VK_ACCESS_HOST_READ_BIT);
    }
    // orders: the shader's writes (hits, flags, statistics, counters) before the host reads them
    dev_.barrier(VK_PIPELINE_STAGE_COMPUTE_SHADER_BIT, VK_ACCESS_SHADER_WRITE_BIT, VK_PIPELINE_STAGE_HOST_BIT,
                 VK_ACCESS_HOST_READ_BIT);
    dev_.submit_and_wait();
    return dev_.has_timestamps() ? dev_.timestamp_seconds() : 0;
  }

  vk::Instance instance_;
  vk::Device dev_;
  vk::Pipelines pipelines_;
  const bool force_staging_;  ///< the vulkan.staging setting or MBVH_VK_STAGING=1
  bool descriptors_dirty_ = true;
  BuildStamp uploaded_;  ///< the build of the leaves and triangles on the device
  Chunked nodes2_, nodes4_, tris_;
  Layout bound_ = Layout::mbvh2;  ///< whose nodes the descriptor set binds
  Buffer leaves_;
  vk::BatchBuffers batch_;
  Buffer counters_;
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
  info.summary = "GPU-style MBVH2 and MBVH4 stack and bitstack traversal in a GLSL compute shader (any Vulkan 1.2 device)";
  info.make = [](const BackendOptions& o) -> std::unique_ptr<Backend> { return std::make_unique<VulkanBackend>(o); };
  info.devices = &device_lines;
  info.pending_problems = &vk::take_validation_messages;
  info.settings = {
      {"vulkan.device", "the device, an index or a name substring (`--vk-device`; default: the backend's choice, printed)"},
      {"vulkan.validation", "1: the Khronos validation layer on, any message an error (`--vk-validation`; also "
                            "MBVH_VK_VALIDATION=1)"},
      {"vulkan.staging", "1: rays and results in device-local memory moved through staging buffers even where "
                         "device-local memory is host-visible (lavapipe), as on a discrete GPU (also MBVH_VK_STAGING=1)"},
      {"vulkan.max-binding-bytes", "caps a storage-buffer binding below maxStorageBufferRange (0: no cap), so the "
                                   "split-buffer path runs on small scenes"}};
  register_backend(std::move(info));
}

}  // namespace mbvh

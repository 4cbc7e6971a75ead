// SPDX-License-Identifier: MIT
// opencl_backend.cpp — the `opencl` backends: the 16-wide MIC path of TRAVERSAL.md §8 (MBVH4,
// skip-code bitstack and its stack twin; Áfra & Szirmay-Kalos 2014) and the GPU-style MBVH2
// traversal, as OpenCL C kernels (shaders/trace.cl, embedded at build time) on any OpenCL device
// (PoCL on a CPU). `opencl-wide` tests a node's four children with one 16-lane operation,
// `opencl-lane` with four scalar slab tests per work-item (the ray-per-lane mapping); `opencl`
// takes the one that suits the device (Mapping below): the 16-wide test on a CPU device, where it
// is the faster of the two, the scalar test on a GPU, whose lanes are the rays.
//
// Every kernel runs one ray per work-item. The mapping also sizes the work-groups: fixed on a CPU
// (where any size runs alike), from the kernel's preferred multiple on a GPU (a warp
// or wavefront), so full groups of rays share a SIMT unit.
//
// Per build, the layout is uploaded once and reused across calls; rays go through in batches
// that fit the device's CL_DEVICE_MAX_MEM_ALLOC_SIZE; programs are built on first use per
// (statistics on/off, node test) and kept.
#include <algorithm>
#include <cstdio>
#include <cstring>
#include <iterator>
#include <map>
#include <mutex>
#include <set>
#include <utility>

#include "backends/common/build_stamp.h"
#include "backends/opencl/cl_runtime.h"
#include "backends/opencl/opencl_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/log.h"
#include "trace_cl.h"  // kTraceCl: shaders/trace.cl with mbvh_layout.h inlined (cmake/embed_cl.cmake)

namespace mbvh {
namespace {

using cl::Buffer;
using cl::check;

constexpr std::size_t kCpuLocalSize = 64;   // a CPU device runs any size alike
constexpr std::size_t kGpuLocalTarget = 128;  // rays per GPU work-group: 4 warps of 32, 2 wavefronts of 64
constexpr std::size_t kMaxLocalSize = 1024;   // the largest work-group either mapping asks for
constexpr std::size_t kMaxBatch = std::size_t(1) << 21;  // rays per dispatch (64 MiB of rays)

std::string mib(std::size_t bytes) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f MiB", double(bytes) / (1024.0 * 1024.0));
  return b;
}

// The node test a backend name asks for: its own (`opencl-wide`, `opencl-lane`) or the device's.
enum class NodeTest { by_device, wide, lane };

// How the kernels map onto the device: which node test, and how work-groups are sized.
struct Mapping {
  bool gpu = false;   // work-groups from the kernel's preferred multiple (else kCpuLocalSize)
  bool wide = true;   // the 16-lane node test (MBVH_WIDE=1)

  // `forced`: the opencl.mapping setting ("", "auto", "cpu" or "gpu")
  static Mapping choose(const cl::DeviceEntry& dev, NodeTest test, const std::string& forced) {
    if (!forced.empty() && forced != "auto" && forced != "cpu" && forced != "gpu")
      throw Error("opencl.mapping (--cl-mapping) '" + forced + "': expected auto, cpu or gpu");
    Mapping m;
    m.gpu = forced == "gpu" || ((forced.empty() || forced == "auto") && (dev.type & CL_DEVICE_TYPE_GPU) != 0);
    m.wide = test == NodeTest::wide || (test == NodeTest::by_device && !m.gpu);
    return m;
  }
  std::string describe() const {
    return std::string(wide ? "16-wide MBVH4 node test" : "ray-per-lane scalar MBVH4 node test") +
           ", MBVH2 GPU-style; " +
           (gpu ? "GPU mapping (one ray per work-item, " + std::to_string(kGpuLocalTarget) +
                      " per work-group in multiples of the kernel's preferred size)"
                : "CPU mapping (one ray per work-item, " + std::to_string(kCpuLocalSize) + " per work-group)");
  }
};

class OpenClBackend final : public Backend {
public:
  OpenClBackend(std::string name, NodeTest test, const BackendOptions& o) : name_(std::move(name)) {
    const std::vector<cl::DeviceEntry> devices = cl::list_devices();
    dev_ = cl::choose_device(devices, o.get("opencl.device"));
    map_ = Mapping::choose(dev_, test, o.get("opencl.mapping"));
    {  // say which device, once per backend and device in a process
      static std::mutex m;
      static std::set<std::string> said;
      const std::lock_guard<std::mutex> lock(m);
      if (said.insert(name_ + " " + dev_.id()).second)
        log_message(LogLevel::info,
                    name_ + ": OpenCL device " + dev_.describe() +
                        (o.get("opencl.device").empty() && devices.size() > 1
                             ? " (chosen from " + std::to_string(devices.size()) +
                                   " devices; pick one with the opencl.device setting, --cl-device)"
                             : std::string()) +
                        "; " + (map_.gpu ? "GPU mapping" : "CPU mapping"));
    }
    // exactness needs correctly rounded float division and double for the watertight fallback
    if (!(cl::device_value<cl_device_fp_config>(dev_.device, CL_DEVICE_SINGLE_FP_CONFIG) &
          CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT))
      throw Error("OpenCL device " + dev_.device_name +
                  " lacks correctly rounded float division (CL_FP_CORRECTLY_ROUNDED_DIVIDE_SQRT), which bit-exact "
                  "answers need (TRAVERSAL.md §10.2)");
    if (cl::device_value<cl_device_fp_config>(dev_.device, CL_DEVICE_DOUBLE_FP_CONFIG) == 0)
      throw Error("OpenCL device " + dev_.device_name +
                  " has no double precision (cl_khr_fp64), which the watertight test's exact fallback needs");
    max_alloc_ = cl::device_value<cl_ulong>(dev_.device, CL_DEVICE_MAX_MEM_ALLOC_SIZE);
    cl_int err = CL_SUCCESS;
    ctx_ = cl::Context(clCreateContext(nullptr, 1, &dev_.device, nullptr, nullptr, &err));
    check(err, "clCreateContext");
    // profiling on: each trace kernel's start and end on the device's clock (last_device_seconds)
    queue_ = cl::Queue(clCreateCommandQueue(ctx_.get(), dev_.device, CL_QUEUE_PROFILING_ENABLE, &err));
    check(err, "clCreateCommandQueue");
  }

  std::string name() const override { return name_; }
  std::string runs_as() const override { return map_.wide ? "opencl-wide" : "opencl-lane"; }
  std::string describe() const override {
    return name_ + ": " + map_.describe() + "; OpenCL device " + dev_.describe();
  }
  bool supports(Layout l, Traversal t) const override {
    return l != Layout::mbvh8 && (t == Traversal::stack || t == Traversal::bitstack);
  }
  bool supports_precision(Precision) const override { return true; }

  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    program(opt.stats, opt.precision == Precision::fast);
    if (uploaded_.stale(acc)) {
      n2_.reset();
      n4_.reset();
      leaves_ = upload("the leaf array", acc.leaves().data(), acc.leaves().size() * sizeof(Leaf));
      tris_ = upload("the triangle array", acc.tris().data(), acc.tris().size() * sizeof(Tri));
      uploaded_.mark(acc);
    }
    if (opt.layout == Layout::mbvh2 && !n2_) {
      const auto& n = acc.mbvh2().nodes;
      n2_ = upload("the MBVH2 node array", n.data(), n.size() * sizeof(Node2));
    }
    if (opt.layout == Layout::mbvh4 && !n4_) {
      const auto& n = acc.mbvh4_wide().nodes;
      n4_ = upload("the MBVH4 node array", n.data(), n.size() * sizeof(Node4W));
    }
  }

  /// Writes every ray's answer (and statistics, when asked) from the device.
  void trace_batch(const Accel&, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    const bool any = opt.query == Query::any;
    const std::string kname = std::string(to_string(opt.layout)) + "_" + to_string(opt.traversal) + "_" + to_string(opt.query);
    const Kernel& kern = kernel(opt.stats, opt.precision == Precision::fast, kname);
    cl_kernel k = kern.kernel.get();
    const std::size_t local = kern.local;
    const std::size_t batch = std::min(rays.size(), max_batch());
    ensure_batch_buffers(batch, opt.stats);
    const cl_uint zero[MBVH_COUNTERS] = {};
    check(clEnqueueWriteBuffer(queue_.get(), counters_.get(), CL_FALSE, 0, sizeof zero, zero, 0, nullptr, nullptr),
          "clEnqueueWriteBuffer(counters)");
    const cl_mem nodes = opt.layout == Layout::mbvh2 ? n2_.get() : n4_.get();
    std::vector<StatsRecord> stats;
    cl_ulong kernel_ns = 0;  // the trace kernels' summed execution time (CL_QUEUE_PROFILING_ENABLE)
    for (std::size_t b = 0; b < rays.size(); b += batch) {
      const std::size_t n = std::min(batch, rays.size() - b);
      // in-order queue: the write completes before the kernel, the kernel before the reads
      check(clEnqueueWriteBuffer(queue_.get(), rays_.get(), CL_FALSE, 0, n * sizeof(Ray), rays.data() + b, 0, nullptr,
                                 nullptr),
            "clEnqueueWriteBuffer(rays)");
      const cl_uint count = static_cast<cl_uint>(n);
      const std::pair<cl_uint, cl_mem> buffers[] = {
          {MBVH_CL_ARG_NODES, nodes},         {MBVH_CL_ARG_LEAVES, leaves_.get()}, {MBVH_CL_ARG_TRIS, tris_.get()},
          {MBVH_CL_ARG_RAYS, rays_.get()},    {MBVH_CL_ARG_HITS, hits_.get()},     {MBVH_CL_ARG_OCCLUDED, occ_.get()},
          {MBVH_CL_ARG_STATS, stats_.get()},  {MBVH_CL_ARG_COUNTERS, counters_.get()}};
      static_assert(std::size(buffers) + 1 == MBVH_CL_ARGS, "every kernel argument is set");
      for (const auto& [i, mem] : buffers) check(clSetKernelArg(k, i, sizeof(cl_mem), &mem), "clSetKernelArg");
      check(clSetKernelArg(k, MBVH_CL_ARG_COUNT, sizeof count, &count), "clSetKernelArg");
      const std::size_t global = (n + local - 1) / local * local;  // no non-uniform groups
      cl_event ran = nullptr;
      check(clEnqueueNDRangeKernel(queue_.get(), k, 1, nullptr, &global, &local, 0, nullptr, &ran),
            "clEnqueueNDRangeKernel");
      const cl::Event kernel_event(ran);
      if (any)
        check(clEnqueueReadBuffer(queue_.get(), occ_.get(), CL_FALSE, 0, n, out.occluded.data() + b, 0, nullptr, nullptr),
              "clEnqueueReadBuffer(occluded)");
      else
        check(clEnqueueReadBuffer(queue_.get(), hits_.get(), CL_FALSE, 0, n * sizeof(Hit), out.hits.data() + b, 0, nullptr,
                                  nullptr),
              "clEnqueueReadBuffer(hits)");
      if (opt.stats) {
        stats.resize(n);
        check(clEnqueueReadBuffer(queue_.get(), stats_.get(), CL_TRUE, 0, n * sizeof(StatsRecord), stats.data(), 0, nullptr,
                                  nullptr),
              "clEnqueueReadBuffer(stats)");
        for (std::size_t i = 0; i < n; ++i) {
          const StatsRecord& s = stats[i];
          out.stats[b + i] = RayStats{s.nodes, s.box_tests, s.leaves, s.tris, s.climbs, s.retests, s.max_depth};
        }
      }
      // the next batch rewrites the ray buffer: wait for this one (host memory stays valid)
      check(clFinish(queue_.get()), "clFinish");
      kernel_ns += profiled_ns(kernel_event.get());
    }
    cl_uint counters[MBVH_COUNTERS];
    check(clEnqueueReadBuffer(queue_.get(), counters_.get(), CL_TRUE, 0, sizeof counters, counters, 0, nullptr, nullptr),
          "clEnqueueReadBuffer(counters)");
    out.invalid = counters[MBVH_COUNTER_INVALID];
    set_device_seconds(double(kernel_ns) * 1e-9);
    if (counters[MBVH_COUNTER_OVERFLOW] != 0)
      throw Error(name_ + ": " + std::to_string(counters[MBVH_COUNTER_OVERFLOW]) + " rays overflowed the traversal stack: the tree is deeper "
                  "than its cap (corrupt build)");
  }

private:
  struct Kernel {
    cl::Kernel kernel;
    std::size_t local = kCpuLocalSize;  // work-items per work-group (Mapping)
  };
  struct Built {
    cl::Program program;
    std::map<std::string, Kernel> kernels;
  };

  // A finished command's execution time on the device's clock, in nanoseconds.
  static cl_ulong profiled_ns(cl_event e) {
    cl_ulong start = 0, end = 0;
    check(clGetEventProfilingInfo(e, CL_PROFILING_COMMAND_START, sizeof start, &start, nullptr),
          "clGetEventProfilingInfo(CL_PROFILING_COMMAND_START)");
    check(clGetEventProfilingInfo(e, CL_PROFILING_COMMAND_END, sizeof end, &end, nullptr),
          "clGetEventProfilingInfo(CL_PROFILING_COMMAND_END)");
    return end > start ? end - start : 0;
  }

  std::size_t max_batch() const {
    return std::max<std::size_t>(kMaxLocalSize, std::min<std::size_t>(kMaxBatch, max_alloc_ / sizeof(StatsRecord)));
  }

  Buffer upload(const std::string& what, const void* data, std::size_t bytes) {
    if (bytes > max_alloc_)
      throw Error(name_ + ": " + what + " (" + mib(bytes) + ") exceeds CL_DEVICE_MAX_MEM_ALLOC_SIZE (" + mib(max_alloc_) +
                  ") of " + dev_.device_name + "; use a smaller scene or another device");
    cl_int err = CL_SUCCESS;
    Buffer b(clCreateBuffer(ctx_.get(), CL_MEM_READ_ONLY | CL_MEM_COPY_HOST_PTR, std::max<std::size_t>(bytes, 16),
                            bytes ? const_cast<void*>(data) : zeros_, &err));
    check(err, ("clCreateBuffer(" + what + ", " + mib(bytes) + ")").c_str());
    return b;
  }

  Buffer device_buffer(std::size_t bytes, cl_mem_flags flags, const char* what) {
    cl_int err = CL_SUCCESS;
    Buffer b(clCreateBuffer(ctx_.get(), flags, std::max<std::size_t>(bytes, 16), nullptr, &err));
    check(err, (std::string("clCreateBuffer(") + what + ", " + mib(bytes) + ")").c_str());
    return b;
  }

  void ensure_batch_buffers(std::size_t n, bool stats) {
    if (n > cap_) {
      rays_ = device_buffer(n * sizeof(Ray), CL_MEM_READ_ONLY, "rays");
      hits_ = device_buffer(n * sizeof(Hit), CL_MEM_WRITE_ONLY, "hits");
      occ_ = device_buffer(n, CL_MEM_WRITE_ONLY, "occluded");
      stats_.reset();
      cap_ = n;
    }
    if (!stats_ || (stats && stats_cap_ < cap_)) {
      stats_cap_ = stats ? cap_ : 0;
      stats_ = device_buffer(stats_cap_ * sizeof(StatsRecord), CL_MEM_WRITE_ONLY, "per-ray statistics");
    }
    if (!counters_) counters_ = device_buffer(MBVH_COUNTERS * sizeof(cl_uint), CL_MEM_READ_WRITE, "counters");
  }

  // fast: the `fast` accuracy mode (MBVH_FAST: relaxed box test, Möller–Trumbore with mad and the
  // device's default division precision); otherwise correctly rounded division, no contraction
  Built& program(bool stats, bool fast) {
    Built& b = built_[(stats ? 1 : 0) + (fast ? 2 : 0)];
    if (!b.program) {
      const std::string options = std::string(fast ? "-cl-mad-enable -DMBVH_FAST=1" : "-cl-fp32-correctly-rounded-divide-sqrt") +
                                  " -DMBVH_STATS=" + (stats ? "1" : "0") + " -DMBVH_WIDE=" + (map_.wide ? "1" : "0");
      b.program = cl::build_program(ctx_.get(), dev_, kTraceCl, options);
    }
    return b;
  }

  const Kernel& kernel(bool stats, bool fast, const std::string& name) {
    Built& b = program(stats, fast);
    auto it = b.kernels.find(name);
    if (it == b.kernels.end()) {
      cl_int err = CL_SUCCESS;
      Kernel k{cl::Kernel(clCreateKernel(b.program.get(), name.c_str(), &err))};
      check(err, ("clCreateKernel(" + name + ")").c_str());
      if (map_.gpu) k.local = gpu_local_size(k.kernel.get(), name);
      it = b.kernels.emplace(name, std::move(k)).first;
    }
    return it->second;
  }

  // GPU mapping: kGpuLocalTarget rounded up to the kernel's preferred work-group multiple (the
  // warp or wavefront), then down to what the kernel can launch (its registers and private
  // memory bound CL_KERNEL_WORK_GROUP_SIZE); said once per backend and device.
  std::size_t gpu_local_size(cl_kernel k, const std::string& name) const {
    std::size_t multiple = 0, most = 0;
    check(clGetKernelWorkGroupInfo(k, dev_.device, CL_KERNEL_PREFERRED_WORK_GROUP_SIZE_MULTIPLE, sizeof multiple,
                                   &multiple, nullptr),
          "clGetKernelWorkGroupInfo(CL_KERNEL_PREFERRED_WORK_GROUP_SIZE_MULTIPLE)");
    check(clGetKernelWorkGroupInfo(k, dev_.device, CL_KERNEL_WORK_GROUP_SIZE, sizeof most, &most, nullptr),
          "clGetKernelWorkGroupInfo(CL_KERNEL_WORK_GROUP_SIZE)");
    multiple = std::max<std::size_t>(multiple, 1);
    most = std::min(std::max<std::size_t>(most, 1), kMaxLocalSize);
    std::size_t local = (kGpuLocalTarget + multiple - 1) / multiple * multiple;
    if (local > most) local = most >= multiple ? most / multiple * multiple : most;
    static std::mutex m;
    static std::set<std::string> said;
    const std::lock_guard<std::mutex> lock(m);
    if (said.insert(name_ + " " + dev_.id() + " " + std::to_string(local)).second)
      log_message(LogLevel::info, name_ + ": GPU mapping: " + std::to_string(local) + " work-items per work-group (" + name +
                                      ": preferred multiple " + std::to_string(multiple) + ", at most " +
                                      std::to_string(most) + ")");
    return local;
  }

  std::string name_;
  cl::DeviceEntry dev_;
  Mapping map_;
  cl_ulong max_alloc_ = 0;
  cl::Context ctx_;
  cl::Queue queue_;
  Built built_[4];  // [stats + 2 * fast]
  BuildStamp uploaded_;  // the build of the leaves, triangles and nodes on the device
  Buffer n2_, n4_, leaves_, tris_;
  std::size_t cap_ = 0, stats_cap_ = 0;
  Buffer rays_, hits_, occ_, stats_, counters_;
  alignas(16) unsigned char zeros_[16] = {};
};

std::vector<std::string> device_lines() {
  const std::vector<cl::DeviceEntry> devices = cl::list_devices();
  const cl::DeviceEntry& chosen = cl::choose_device(devices, "");
  std::vector<std::string> lines;
  for (const cl::DeviceEntry& d : devices) lines.push_back(d.describe() + (&d == &chosen ? "  [default]" : ""));
  return lines;
}

void add(const char* name, const char* summary, NodeTest test, const char* alias_of = "") {
  BackendInfo info;
  info.name = name;
  info.summary = summary;
  info.alias_of = alias_of;
  info.make = [name, test](const BackendOptions& o) -> std::unique_ptr<Backend> {
    return std::make_unique<OpenClBackend>(name, test, o);
  };
  info.devices = &device_lines;
  info.settings = {{"opencl.device", "the device, PLATFORM:DEVICE or a name substring (`--cl-device`; default: the "
                                     "backend's choice, printed)"},
                   {"opencl.mapping", "auto (by the device's type), cpu (the 16-wide node test, fixed work-groups) or gpu "
                                      "(the scalar node test, work-groups from the kernel's preferred multiple); "
                                      "`--cl-mapping`"}};
  register_backend(std::move(info));
}

}  // namespace

void register_opencl_backends() {
  // `opencl` is opencl-wide on a CPU device, where tests run it under that name; on a
  // GPU it takes the lane test (Mapping)
  add("opencl", "MBVH4 and MBVH2 on OpenCL, mapped for the device: the 16-wide MIC path on a CPU, ray per lane on a GPU",
      NodeTest::by_device, "opencl-wide");
  add("opencl-wide", "OpenCL, MBVH4 node test as one 16-lane operation (TRAVERSAL.md §8)", NodeTest::wide);
  add("opencl-lane", "OpenCL, MBVH4 node test as four scalar slab tests per work-item (ray per lane)", NodeTest::lane);
}

}  // namespace mbvh

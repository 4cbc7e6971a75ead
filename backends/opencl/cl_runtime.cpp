// SPDX-License-Identifier: MIT
// cl_runtime.cpp — OpenCL errors, device discovery and choice, program builds (cl_runtime.h).
#include "backends/opencl/cl_runtime.h"
#include "backends/common/device_choice.h"

#include <algorithm>
#include <cctype>
#include <cstdlib>

#include "mbvh/error.h"

#ifndef CL_PLATFORM_NOT_FOUND_KHR
#define CL_PLATFORM_NOT_FOUND_KHR -1001
#endif

namespace mbvh::cl {

std::string error_name(cl_int err) {
  switch (err) {
#define MBVH_CL_ERR(x) \
  case x: return #x;
    MBVH_CL_ERR(CL_SUCCESS)
    MBVH_CL_ERR(CL_DEVICE_NOT_FOUND)
    MBVH_CL_ERR(CL_DEVICE_NOT_AVAILABLE)
    MBVH_CL_ERR(CL_COMPILER_NOT_AVAILABLE)
    MBVH_CL_ERR(CL_MEM_OBJECT_ALLOCATION_FAILURE)
    MBVH_CL_ERR(CL_OUT_OF_RESOURCES)
    MBVH_CL_ERR(CL_OUT_OF_HOST_MEMORY)
    MBVH_CL_ERR(CL_PROFILING_INFO_NOT_AVAILABLE)
    MBVH_CL_ERR(CL_MEM_COPY_OVERLAP)
    MBVH_CL_ERR(CL_IMAGE_FORMAT_MISMATCH)
    MBVH_CL_ERR(CL_IMAGE_FORMAT_NOT_SUPPORTED)
    MBVH_CL_ERR(CL_BUILD_PROGRAM_FAILURE)
    MBVH_CL_ERR(CL_MAP_FAILURE)
    MBVH_CL_ERR(CL_MISALIGNED_SUB_BUFFER_OFFSET)
    MBVH_CL_ERR(CL_EXEC_STATUS_ERROR_FOR_EVENTS_IN_WAIT_LIST)
    MBVH_CL_ERR(CL_COMPILE_PROGRAM_FAILURE)
    MBVH_CL_ERR(CL_LINKER_NOT_AVAILABLE)
    MBVH_CL_ERR(CL_LINK_PROGRAM_FAILURE)
    MBVH_CL_ERR(CL_DEVICE_PARTITION_FAILED)
    MBVH_CL_ERR(CL_KERNEL_ARG_INFO_NOT_AVAILABLE)
    MBVH_CL_ERR(CL_INVALID_VALUE)
    MBVH_CL_ERR(CL_INVALID_DEVICE_TYPE)
    MBVH_CL_ERR(CL_INVALID_PLATFORM)
    MBVH_CL_ERR(CL_INVALID_DEVICE)
    MBVH_CL_ERR(CL_INVALID_CONTEXT)
    MBVH_CL_ERR(CL_INVALID_QUEUE_PROPERTIES)
    MBVH_CL_ERR(CL_INVALID_COMMAND_QUEUE)
    MBVH_CL_ERR(CL_INVALID_HOST_PTR)
    MBVH_CL_ERR(CL_INVALID_MEM_OBJECT)
    MBVH_CL_ERR(CL_INVALID_IMAGE_FORMAT_DESCRIPTOR)
    MBVH_CL_ERR(CL_INVALID_IMAGE_SIZE)
    MBVH_CL_ERR(CL_INVALID_SAMPLER)
    MBVH_CL_ERR(CL_INVALID_BINARY)
    MBVH_CL_ERR(CL_INVALID_BUILD_OPTIONS)
    MBVH_CL_ERR(CL_INVALID_PROGRAM)
    MBVH_CL_ERR(CL_INVALID_PROGRAM_EXECUTABLE)
    MBVH_CL_ERR(CL_INVALID_KERNEL_NAME)
    MBVH_CL_ERR(CL_INVALID_KERNEL_DEFINITION)
    MBVH_CL_ERR(CL_INVALID_KERNEL)
    MBVH_CL_ERR(CL_INVALID_ARG_INDEX)
    MBVH_CL_ERR(CL_INVALID_ARG_VALUE)
    MBVH_CL_ERR(CL_INVALID_ARG_SIZE)
    MBVH_CL_ERR(CL_INVALID_KERNEL_ARGS)
    MBVH_CL_ERR(CL_INVALID_WORK_DIMENSION)
    MBVH_CL_ERR(CL_INVALID_WORK_GROUP_SIZE)
    MBVH_CL_ERR(CL_INVALID_WORK_ITEM_SIZE)
    MBVH_CL_ERR(CL_INVALID_GLOBAL_OFFSET)
    MBVH_CL_ERR(CL_INVALID_EVENT_WAIT_LIST)
    MBVH_CL_ERR(CL_INVALID_EVENT)
    MBVH_CL_ERR(CL_INVALID_OPERATION)
    MBVH_CL_ERR(CL_INVALID_BUFFER_SIZE)
    MBVH_CL_ERR(CL_INVALID_GLOBAL_WORK_SIZE)
    MBVH_CL_ERR(CL_INVALID_PROPERTY)
    MBVH_CL_ERR(CL_INVALID_COMPILER_OPTIONS)
    MBVH_CL_ERR(CL_INVALID_LINKER_OPTIONS)
    MBVH_CL_ERR(CL_PLATFORM_NOT_FOUND_KHR)
#undef MBVH_CL_ERR
    default: return "CL error " + std::to_string(err);
  }
}

void fail(const char* call, cl_int err, const std::string& what) {
  throw Error(std::string("OpenCL: ") + call + " failed: " + error_name(err) + " (" + std::to_string(err) + ")" +
              (what.empty() ? "" : ": " + what));
}

// A string query (clGetDeviceInfo, clGetPlatformInfo): size, then text, trailing NULs and blanks cut.
template <class Object>
static std::string info_string(cl_int(CL_API_CALL* get)(Object, cl_uint, std::size_t, void*, std::size_t*), Object o,
                               cl_uint what, const char* call) {
  std::size_t n = 0;
  check(get(o, what, 0, nullptr, &n), call);
  std::string s(n, '\0');
  check(get(o, what, n, s.data(), nullptr), call);
  while (!s.empty() && (s.back() == '\0' || s.back() == ' ')) s.pop_back();
  return s;
}

std::string device_string(cl_device_id d, cl_device_info what) {
  return info_string(&clGetDeviceInfo, d, what, "clGetDeviceInfo");
}

static std::string platform_string(cl_platform_id p, cl_platform_info what) {
  return info_string(&clGetPlatformInfo, p, what, "clGetPlatformInfo");
}

std::string DeviceEntry::id() const { return std::to_string(platform_index) + ":" + std::to_string(device_index); }

std::string DeviceEntry::type_name() const {
  if (type & CL_DEVICE_TYPE_GPU) return "gpu";
  if (type & CL_DEVICE_TYPE_ACCELERATOR) return "accelerator";
  if (type & CL_DEVICE_TYPE_CPU) return "cpu";
  return "other";
}

std::string DeviceEntry::describe() const {
  return id() + " " + device_name + " (" + type_name() + "; " + platform_name + ", " + device_version + ", driver " +
         driver_version + ")";
}

std::vector<DeviceEntry> list_devices() {
  cl_uint np = 0;
  const cl_int err = clGetPlatformIDs(0, nullptr, &np);
  if (err == CL_PLATFORM_NOT_FOUND_KHR || (err == CL_SUCCESS && np == 0)) {
    const char* vendors = std::getenv("OCL_ICD_VENDORS");
    throw Error(std::string("no OpenCL platform found (clGetPlatformIDs: ") + error_name(err) +
                "): install an OpenCL driver, e.g. Debian's pocl-opencl-icd (scripts/demo and scripts/test do); the "
                "ICD loader looks for drivers in " +
                (vendors ? std::string("OCL_ICD_VENDORS=") + vendors : std::string("/etc/OpenCL/vendors")));
  }
  check(err, "clGetPlatformIDs");
  std::vector<cl_platform_id> platforms(np);
  check(clGetPlatformIDs(np, platforms.data(), nullptr), "clGetPlatformIDs");
  std::vector<DeviceEntry> out;
  for (cl_uint p = 0; p < np; ++p) {
    cl_uint nd = 0;
    const cl_int e = clGetDeviceIDs(platforms[p], CL_DEVICE_TYPE_ALL, 0, nullptr, &nd);
    if (e == CL_DEVICE_NOT_FOUND) continue;
    check(e, "clGetDeviceIDs");
    std::vector<cl_device_id> devs(nd);
    check(clGetDeviceIDs(platforms[p], CL_DEVICE_TYPE_ALL, nd, devs.data(), nullptr), "clGetDeviceIDs");
    for (cl_uint d = 0; d < nd; ++d) {
      DeviceEntry e2;
      e2.platform = platforms[p];
      e2.device = devs[d];
      e2.platform_index = p;
      e2.device_index = d;
      e2.platform_name = platform_string(platforms[p], CL_PLATFORM_NAME);
      e2.platform_version = platform_string(platforms[p], CL_PLATFORM_VERSION);
      e2.device_name = device_string(devs[d], CL_DEVICE_NAME);
      e2.device_version = device_string(devs[d], CL_DEVICE_VERSION);
      e2.driver_version = device_string(devs[d], CL_DRIVER_VERSION);
      e2.type = device_value<cl_device_type>(devs[d], CL_DEVICE_TYPE);
      out.push_back(std::move(e2));
    }
  }
  if (out.empty()) throw Error("OpenCL: " + std::to_string(np) + " platform(s) but no device");
  return out;
}

const DeviceEntry& choose_device(const std::vector<DeviceEntry>& devices, const std::string& selector) {
  std::vector<DeviceCandidate> c;
  for (const DeviceEntry& d : devices)
    c.push_back({d.id(), {d.device_name, d.platform_name},
                 (d.type & CL_DEVICE_TYPE_GPU) ? 0 : (d.type & CL_DEVICE_TYPE_ACCELERATOR) ? 1 : 2, d.describe(),
                 {d.type_name()}});
  return devices[choose_device_index(c, selector, "OpenCL", "opencl.device (--cl-device)")];
}

Program build_program(cl_context ctx, const DeviceEntry& dev, const std::string& source, const std::string& options) {
  const char* src = source.c_str();
  const std::size_t len = source.size();
  cl_int err = CL_SUCCESS;
  Program prog(clCreateProgramWithSource(ctx, 1, &src, &len, &err));
  check(err, "clCreateProgramWithSource");
  err = clBuildProgram(prog.get(), 1, &dev.device, options.c_str(), nullptr, nullptr);
  if (err != CL_SUCCESS) {
    std::size_t n = 0;
    std::string log;
    if (clGetProgramBuildInfo(prog.get(), dev.device, CL_PROGRAM_BUILD_LOG, 0, nullptr, &n) == CL_SUCCESS && n > 1) {
      log.resize(n);
      clGetProgramBuildInfo(prog.get(), dev.device, CL_PROGRAM_BUILD_LOG, n, log.data(), nullptr);
      while (!log.empty() && (log.back() == '\0' || log.back() == '\n')) log.pop_back();
    }
    fail("clBuildProgram", err,
         "the kernel program did not build on " + dev.describe() + "\n  options: " + options + "\n  build log:\n" +
             (log.empty() ? std::string("(empty)") : log));
  }
  return prog;
}

}  // namespace mbvh::cl

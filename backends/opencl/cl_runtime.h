// SPDX-License-Identifier: MIT
// cl_runtime.h — the OpenCL backend's host plumbing below the Backend interface: owning
// handles, errors that name the failing call and its code, platform/device discovery and the
// `--cl-device` choice, and program builds that report the build log and options.
#pragma once
#ifndef CL_TARGET_OPENCL_VERSION
#define CL_TARGET_OPENCL_VERSION 120
#endif
#include <CL/cl.h>

#include <string>
#include <utility>
#include <vector>

namespace mbvh::cl {

/// "CL_INVALID_VALUE" etc. ("CL error -N" for a code it does not know).
std::string error_name(cl_int err);
/// Throws mbvh::Error("OpenCL: CALL failed: NAME (code)[: what]").
[[noreturn]] void fail(const char* call, cl_int err, const std::string& what = "");
inline void check(cl_int err, const char* call) {
  if (err != CL_SUCCESS) fail(call, err);
}

/// An owning OpenCL handle (context, queue, program, kernel, buffer, event): released once.
template <class T, cl_int (*Release)(T)>
class Handle {
public:
  Handle() = default;
  explicit Handle(T h) : h_(h) {}
  Handle(Handle&& o) noexcept : h_(std::exchange(o.h_, nullptr)) {}
  Handle& operator=(Handle&& o) noexcept {
    if (this != &o) {
      reset();
      h_ = std::exchange(o.h_, nullptr);
    }
    return *this;
  }
  Handle(const Handle&) = delete;
  Handle& operator=(const Handle&) = delete;
  ~Handle() { reset(); }
  void reset() {
    if (h_) Release(h_);
    h_ = nullptr;
  }
  T get() const { return h_; }
  explicit operator bool() const { return h_ != nullptr; }

private:
  T h_ = nullptr;
};
using Context = Handle<cl_context, clReleaseContext>;
using Queue = Handle<cl_command_queue, clReleaseCommandQueue>;
using Program = Handle<cl_program, clReleaseProgram>;
using Kernel = Handle<cl_kernel, clReleaseKernel>;
using Buffer = Handle<cl_mem, clReleaseMemObject>;
using Event = Handle<cl_event, clReleaseEvent>;

/// One device of one platform, as `mbvh devices` lists it.
struct DeviceEntry {
  cl_platform_id platform = nullptr;
  cl_device_id device = nullptr;
  unsigned platform_index = 0, device_index = 0;
  std::string platform_name, platform_version, device_name, device_version, driver_version;
  cl_device_type type = 0;
  std::string id() const;           ///< "P:D"
  std::string type_name() const;    ///< "gpu", "cpu", "accelerator", ...
  std::string describe() const;     ///< "0:0 NAME (cpu; PLATFORM, DEVICE_VERSION, driver DRIVER)"
};

/// Every device of every platform. Throws Error saying how to install a driver when the ICD
/// loader finds no platform, and naming the call on any other failure.
std::vector<DeviceEntry> list_devices();

/// The device `selector` names: "" = the only device, else the first GPU, else the first
/// accelerator, else the first device (the choice is reported by the caller, never silent);
/// "P:D" = platform P, device D; "N" = the N-th device listed; "gpu", "cpu", "accelerator" = the
/// first device of that type; anything else = the first device whose device or platform name
/// contains it (case-insensitive). Throws Error listing the
/// devices when nothing matches.
const DeviceEntry& choose_device(const std::vector<DeviceEntry>& devices, const std::string& selector);

/// String and scalar device queries.
std::string device_string(cl_device_id d, cl_device_info what);
template <class T>
T device_value(cl_device_id d, cl_device_info what) {
  T v{};
  check(clGetDeviceInfo(d, what, sizeof v, &v, nullptr), "clGetDeviceInfo");
  return v;
}

/// Creates and builds a program from source. On a failed build throws Error with the device,
/// the options and the full build log.
Program build_program(cl_context ctx, const DeviceEntry& dev, const std::string& source, const std::string& options);

}  // namespace mbvh::cl

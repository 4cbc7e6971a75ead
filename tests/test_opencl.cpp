// SPDX-License-Identifier: MIT
// test_opencl.cpp — what the OpenCL backends promise beyond the shared equivalence tests (which
// run them on every scene, ray kind and variant): clear errors for a kernel that does not build,
// a missing platform and an unknown --cl-device; the device choice; the GPU mapping (forced on
// this CPU device); rays over several batches.
#include <catch2/catch.hpp>

#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "backends/opencl/cl_runtime.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "host/tools/raygen.h"
#include "tests/backends.h"

using namespace mbvh;

TEST_CASE("opencl: a kernel that does not build reports the device - options and build log", "[opencl]") {
  const std::vector<cl::DeviceEntry> devices = cl::list_devices();
  const cl::DeviceEntry& dev = cl::choose_device(devices, "");
  cl_int err = CL_SUCCESS;
  cl::Context ctx(clCreateContext(nullptr, 1, &dev.device, nullptr, nullptr, &err));
  REQUIRE(err == CL_SUCCESS);
  std::string msg;
  try {
    cl::build_program(ctx.get(), dev, "kernel void broken(global int* x) { x[0] = undeclared_name; }\n",
                      "-DMBVH_TEST_OPTION=7");
  } catch (const Error& e) {
    msg = e.what();
  }
  INFO(msg);
  CHECK(msg.find("clBuildProgram failed: CL_BUILD_PROGRAM_FAILURE") != std::string::npos);
  CHECK(msg.find("options: -DMBVH_TEST_OPTION=7") != std::string::npos);
  CHECK(msg.find("build log:") != std::string::npos);
  CHECK(msg.find("undeclared_name") != std::string::npos);  // the compiler's own diagnostic
  CHECK(msg.find(dev.device_name) != std::string::npos);
}

TEST_CASE("opencl: no platform is a clear error - in devices and when tracing", "[opencl]") {
  mbvh_test::TempDir empty;  // an ICD vendor directory with no driver in it
  const std::string env = "OCL_ICD_VENDORS=" + empty.path.string();
  const auto d = mbvh_test::run_cli("devices", env);
  INFO(d.output);
  CHECK(d.code == 0);
  CHECK(d.output.find("opencl") != std::string::npos);
  CHECK(d.output.find("cannot start: no OpenCL platform found") != std::string::npos);
  CHECK(d.output.find("pocl-opencl-icd") != std::string::npos);
  CHECK(d.output.find("cpu-scalar   ready") != std::string::npos);  // the other backends still work
  const auto t = mbvh_test::run_cli("trace gen:cube:4 --count 10 --backend opencl", env);
  INFO(t.output);
  CHECK(t.code == 2);
  CHECK(t.output.find("mbvh: error: no OpenCL platform found") != std::string::npos);
}

TEST_CASE("opencl: --cl-device chooses by index - platform:device or name - and lists the devices when nothing matches",
          "[opencl]") {
  // the choice rule on a made-up list: a GPU is preferred over the CPU when nothing is asked for
  std::vector<cl::DeviceEntry> list(3);
  const char* names[] = {"Some CPU", "Big GPU", "Other CPU"};
  const cl_device_type types[] = {CL_DEVICE_TYPE_CPU, CL_DEVICE_TYPE_GPU, CL_DEVICE_TYPE_CPU};
  for (unsigned i = 0; i < 3; ++i) {
    list[i].platform_index = i / 2;
    list[i].device_index = i % 2;
    list[i].device_name = names[i];
    list[i].platform_name = i < 2 ? "Vendor A" : "Vendor B";
    list[i].type = types[i];
  }
  CHECK(&cl::choose_device(list, "") == &list[1]);
  CHECK(&cl::choose_device(list, "1:0") == &list[2]);
  CHECK(&cl::choose_device(list, "0") == &list[0]);
  CHECK(&cl::choose_device(list, "other") == &list[2]);
  CHECK(&cl::choose_device(list, "vendor b") == &list[2]);
  CHECK(&cl::choose_device(list, "gpu") == &list[1]);  // by type, case-insensitive
  CHECK(&cl::choose_device(list, "CPU") == &list[0]);
  CHECK_THROWS_WITH(cl::choose_device(list, "accelerator"), Catch::Contains("no OpenCL device matches"));
  CHECK_THROWS_WITH(cl::choose_device(list, "7:7"), Catch::Contains("no OpenCL device matches opencl.device (--cl-device) '7:7'") &&
                                                     Catch::Contains("1:0 Other CPU"));

  // the real program: the choice is printed, and a wrong one is an error listing the devices
  mbvh_test::check_device_flag("opencl", "--cl-device", "0:0", "opencl: OpenCL device 0:0 ", "OpenCL", "\n  0:0 ");
}

TEST_CASE("opencl: the GPU mapping - ray per lane and work-groups from the kernel's preferred multiple - gives the "
          "reference's bytes",
          "[opencl]") {
  // --cl-mapping gpu forces on this CPU device what a GPU device gets by default: `opencl` takes
  // the scalar node test and sizes its work-groups from the kernel (a partial last group too)
  BackendOptions o;
  o.set("opencl.mapping", "gpu");
  auto gpu = make_backend("opencl", o);
  CHECK(gpu->describe().find("ray-per-lane scalar MBVH4 node test") != std::string::npos);
  CHECK(gpu->describe().find("GPU mapping") != std::string::npos);
  o.set("opencl.mapping", "cpu");
  CHECK(make_backend("opencl", o)->describe().find("16-wide MBVH4 node test, MBVH2 GPU-style; CPU mapping") !=
        std::string::npos);
  o.set("opencl.mapping", "gpu");
  CHECK(make_backend("opencl-wide", o)->describe().find("16-wide MBVH4 node test, MBVH2 GPU-style; GPU mapping") !=
        std::string::npos);  // a named node test keeps it; the work-groups follow the mapping
  o.set("opencl.mapping", "simd");
  CHECK_THROWS_WITH(make_backend("opencl", o), Catch::Contains("opencl.mapping (--cl-mapping) 'simd': expected auto, cpu or gpu"));

  const Scene s = load_scene(mbvh_test::scene_path("bun_zipper.ply.zst"));
  const auto acc = Accel::build(s);
  for (RayKind kind : {RayKind::primary, RayKind::diffuse, RayKind::random}) {
    RayGenOptions ro;
    ro.kind = kind;
    ro.count = 20000 + 37;  // not a multiple of any work-group size
    const std::vector<Ray> rays = generate_rays(s, *acc, ro);
    for (Layout l : {Layout::mbvh2, Layout::mbvh4})
      mbvh_test::check_against_reference(*gpu, *acc, rays, l, {Traversal::stack, Traversal::bitstack});
  }

  // the real program: --cl-device by type, the mapping said
  const auto r = mbvh_test::run_cli("trace gen:cube:4 --count 1000 --backend opencl --cl-device cpu --cl-mapping gpu");
  INFO(r.output);
  CHECK(r.code == 0);
  CHECK(r.output.find("opencl: OpenCL device 0:0 ") != std::string::npos);
  CHECK(r.output.find("; GPU mapping") != std::string::npos);
  CHECK(r.output.find("opencl: GPU mapping: ") != std::string::npos);  // the work-group size, from the kernel
}

TEST_CASE("opencl: rays over several dispatch batches come back in order", "[opencl]") {
  const Scene s = load_scene("gen:sphere:16");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = (std::size_t(1) << 21) + 12345;  // one full batch of 2^21 rays and a partial one
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  for (const char* name : {"opencl-wide", "opencl-lane"}) {
    auto b = make_backend(name);
    mbvh_test::check_against_reference(*b, *acc, rays, Layout::mbvh4, {Traversal::bitstack});
  }
}

TEST_CASE("opencl: mbvh bench times it beside cpu - verified - with its state and the ratio to cpu", "[opencl]") {
  // backends x layouts x traversals x queries
  mbvh_test::check_bench_beside_cpu("opencl", "--layout mbvh2,mbvh4 --traversal stack,bitstack", 2 * 2 * 2 * 2, 8, {"OpenCL device"});
}

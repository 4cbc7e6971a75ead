// SPDX-License-Identifier: MIT
// test_vulkan.cpp — what the Vulkan backend promises beyond the shared equivalence tests (which
// run it on every scene, ray kind and variant, with the validation layer on: CMakeLists.txt sets
// MBVH_VK_VALIDATION=1 for every test): the layer's messages are caught; arrays split over
// several bindings (a scene over lavapipe's 128 MiB maxStorageBufferRange, and small scenes with
// the binding range capped) and rays over several batches give cpu-scalar's answers; clear
// errors for a missing driver and an unknown --vk-device; bench records beside cpu. Every check
// covers both layouts the shader traverses, MBVH2 and MBVH4. The batches go both ways: in
// lavapipe's host-visible memory, and staged through copies as on a discrete GPU (vulkan.staging).
#include <catch2/catch.hpp>

#include <cstdlib>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "backends/vulkan/vk_runtime.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "host/tools/raygen.h"
#include "tests/backends.h"

using namespace mbvh;

namespace {

constexpr Layout kLayouts[] = {Layout::mbvh2, Layout::mbvh4};

// every variant the backend has, bit for bit against the reference
void check_against_reference(Backend& b, const Accel& acc, const std::vector<Ray>& rays) {
  for (Layout l : kLayouts) mbvh_test::check_against_reference(b, acc, rays, l, {Traversal::stack, Traversal::bitstack});
}

TraceOptions layout_options(Layout l) {
  TraceOptions o;
  o.layout = l;
  return o;
}

}  // namespace

TEST_CASE("vulkan: the validation layer is on in the tests and its messages are caught", "[vulkan]") {
  REQUIRE(vk::validation_requested(false));  // MBVH_VK_VALIDATION=1 from CMakeLists.txt
  CHECK(vk::take_validation_messages().empty());
  {  // a buffer of size 0: a validation error the layer must report (the call still goes through)
    vk::Instance instance(true);
    const std::vector<vk::DeviceEntry> devices = vk::list_devices(instance.get());
    const float priority = 1.0f;
    VkDeviceQueueCreateInfo qi{};
    qi.sType = VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO;
    qi.queueCount = 1;
    qi.pQueuePriorities = &priority;
    VkDeviceCreateInfo di{};
    di.sType = VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO;
    di.queueCreateInfoCount = 1;
    di.pQueueCreateInfos = &qi;
    VkDevice device = VK_NULL_HANDLE;
    REQUIRE(vkCreateDevice(devices.front().device, &di, nullptr, &device) == VK_SUCCESS);
    VkBufferCreateInfo bi{};
    bi.sType = VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO;
    bi.size = 0;
    bi.usage = VK_BUFFER_USAGE_STORAGE_BUFFER_BIT;
    VkBuffer buffer = VK_NULL_HANDLE;
    vkCreateBuffer(device, &bi, nullptr, &buffer);
    if (buffer != VK_NULL_HANDLE) vkDestroyBuffer(device, buffer, nullptr);
    vkDestroyDevice(device, nullptr);
  }
  const std::vector<std::string> m = vk::take_validation_messages();
  std::string all;
  for (const std::string& s : m) all += s + "\n";
  INFO(all);
  CHECK(all.find("VUID-VkBufferCreateInfo-size-00912") != std::string::npos);

  // and a clean run of the backend raises none
  const Scene s = load_scene("gen:sphere:16");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.count = 1000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  {
    auto b = make_backend("vulkan");
    check_against_reference(*b, *acc, rays);
  }
  const std::vector<std::string> after = vk::take_validation_messages();
  CHECK(after.empty());
}

TEST_CASE("vulkan: arrays over the binding range are split - rays over several batches come back in order - "
          "directly and staged",
          "[vulkan]") {
  // capped binding range: nodes and triangles each in several chunks, rays in many batches
  const Scene s = load_scene("gen:soup:20000");
  const auto acc = Accel::build(s);
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 50000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  BackendOptions bo;
  bo.set("vulkan.max-binding-bytes", std::to_string(256 * 1024));
  // lavapipe's device-local memory is host-visible: direct unless staging is forced
  const bool staged = GENERATE(false, true);
  bo.set("vulkan.staging", staged ? "1" : "0");
  INFO((staged ? "staged" : "direct (or MBVH_VK_STAGING set)"));
  auto b = make_backend("vulkan", bo);
  b->prepare(*acc, layout_options(Layout::mbvh2));
  const std::string d2 = b->describe();
  b->prepare(*acc, layout_options(Layout::mbvh4));
  const std::string d = b->describe();
  INFO(d);
  // 256 KiB = 4096 MBVH2 nodes of 64 B, 2048 MBVH4 nodes of 128 B; 5461 triangles of 48 B,
  // rounded down to 4096; 8192 rays of 32 B
  const std::size_t node2_chunks = (acc->mbvh2().nodes.size() + 4095) / 4096,
                    node4_chunks = (acc->mbvh4().nodes.size() + 2047) / 2048,
                    tri_chunks = (acc->tris().size() + 4095) / 4096;
  REQUIRE(node2_chunks > 1);
  REQUIRE(node4_chunks > 1);
  REQUIRE(tri_chunks > 1);
  CHECK(d2.find("MBVH4 nodes") == std::string::npos);  // a layout's nodes are uploaded when a trace asks for it
  CHECK(d.find("MBVH2 nodes in " + std::to_string(node2_chunks) + " texel binding(s) of 0.2 MiB") != std::string::npos);
  CHECK(d.find("MBVH4 nodes in " + std::to_string(node4_chunks) + " texel binding(s) of 0.2 MiB") != std::string::npos);
  CHECK(d.find("triangles in " + std::to_string(tri_chunks) + " storage binding(s) of 0.2 MiB") != std::string::npos);
  CHECK(d.find("batches of 8192 rays") != std::string::npos);
  check_against_reference(*b, *acc, rays);  // switches between the layouts' node arrays
  const std::string after = b->describe();
  INFO(after);
  if (staged)
    CHECK(after.find("; rays and results staged through host-visible buffers") != std::string::npos);
  else if (!std::getenv("MBVH_VK_STAGING"))
    CHECK(after.find("; rays and results in host-visible memory") != std::string::npos);
  CHECK(vk::take_validation_messages().empty());

  // more chunks than the shader has bindings: a clear error naming the array and the limit
  BackendOptions tiny;
  tiny.set("vulkan.max-binding-bytes", std::to_string(16 * 1024));
  auto t = make_backend("vulkan", tiny);
  for (Layout l : kLayouts)
    CHECK_THROWS_WITH(t->prepare(*acc, layout_options(l)),
                      Catch::Contains(std::string("the ") + (l == Layout::mbvh2 ? "MBVH2" : "MBVH4") + " node array") &&
                          Catch::Contains("bindings of") && Catch::Contains("the shader has 8"));
}

TEST_CASE("vulkan: a scene whose node and triangle arrays exceed 128 MiB traces exactly", "[vulkan][large][heavy]") {
  // 3M triangles: 144 MB of triangles and about 136 MB of MBVH2 nodes, over lavapipe's 128 MiB
  // maxStorageBufferRange: the triangles are split over two storage bindings. Leaves priced per
  // triangle (leaf block 1) keep the node array this large.
  const Scene s = load_scene("gen:soup:3000000");
  BuildOptions bo;
  bo.leaf_block = 1;
  const auto acc = Accel::build(s, bo);
  REQUIRE(acc->tris().size() * sizeof(Tri) > (std::size_t(128) << 20));
  REQUIRE(acc->mbvh2().nodes.size() * sizeof(Node2) > (std::size_t(128) << 20));
  RayGenOptions ro;
  ro.kind = RayKind::random;
  ro.count = 20000;
  const std::vector<Ray> rays = generate_rays(s, *acc, ro);
  auto b = make_backend("vulkan");
  b->prepare(*acc, layout_options(Layout::mbvh2));
  INFO(b->describe());
  CHECK(b->describe().find("triangles in 2 storage binding(s)") != std::string::npos);
  check_against_reference(*b, *acc, rays);
}

TEST_CASE("vulkan: no driver is a clear error - in devices and when tracing", "[vulkan]") {
  mbvh_test::TempDir dir;
  const std::string env = "VK_ICD_FILENAMES=" + dir.file("none.json") + " VK_DRIVER_FILES=" + dir.file("none.json");
  const auto d = mbvh_test::run_cli("devices", env);
  INFO(d.output);
  CHECK(d.code == 0);
  CHECK(d.output.find("vulkan       cannot start:") != std::string::npos);
  CHECK(d.output.find("mesa-vulkan-drivers") != std::string::npos);
  CHECK(d.output.find("cpu-scalar   ready") != std::string::npos);  // the other backends still work
  const auto t = mbvh_test::run_cli("trace gen:cube:4 --count 10 --backend vulkan", env);
  INFO(t.output);
  CHECK(t.code == 2);
  CHECK(t.output.find("mesa-vulkan-drivers") != std::string::npos);
}

TEST_CASE("vulkan: --vk-device chooses by index or name - prints the choice - and lists the devices when nothing "
          "matches",
          "[vulkan]") {
  std::vector<vk::DeviceEntry> list(3);
  const char* names[] = {"llvmpipe", "Big GPU", "Small GPU"};
  const VkPhysicalDeviceType types[] = {VK_PHYSICAL_DEVICE_TYPE_CPU, VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU,
                                        VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU};
  for (unsigned i = 0; i < 3; ++i) {
    list[i].index = i;
    list[i].name = names[i];
    list[i].type = types[i];
  }
  CHECK(&vk::choose_device(list, "") == &list[1]);  // a discrete GPU first
  list[1].type = VK_PHYSICAL_DEVICE_TYPE_CPU;
  CHECK(&vk::choose_device(list, "") == &list[2]);  // then an integrated one
  CHECK(&vk::choose_device(list, "0") == &list[0]);
  CHECK(&vk::choose_device(list, "small") == &list[2]);
  CHECK(&vk::choose_device(list, "gpu") == &list[2]);  // by type: the best-ranked GPU (list[1] is a CPU now)
  CHECK(&vk::choose_device(list, "CPU") == &list[0]);
  list[1].type = VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU;
  CHECK(&vk::choose_device(list, "gpu") == &list[1]);
  CHECK(&vk::choose_device(list, "integrated gpu") == &list[2]);
  CHECK_THROWS_WITH(vk::choose_device(list, "7"),
                    Catch::Contains("no Vulkan device matches vulkan.device (--vk-device) '7'") && Catch::Contains("2 Small GPU"));

  // the real program: the choice is printed (and no validation message), a wrong one lists the devices
  mbvh_test::check_device_flag("vulkan", "--vk-device", "llvmpipe", "vulkan: Vulkan device 0 llvmpipe", "Vulkan",
                               "\n  0 llvmpipe");
}

TEST_CASE("vulkan: mbvh devices says whether each device offers VK_KHR_ray_query", "[vulkan]") {
  const auto d = mbvh_test::run_cli("devices");
  INFO(d.output);
  REQUIRE(d.code == 0);
  // lavapipe (Mesa 22.3) has no ray queries; a device line says so either way
  CHECK(d.output.find("llvmpipe") != std::string::npos);
  CHECK(d.output.find("(cpu; llvmpipe") != std::string::npos);
  CHECK(d.output.find(", no VK_KHR_ray_query") != std::string::npos);
}

TEST_CASE("vulkan: mbvh bench times it beside cpu - verified - with its state and the ratio to cpu", "[vulkan]") {
  // backends x layouts x traversals x queries
  mbvh_test::check_bench_beside_cpu("vulkan", "--layout mbvh2,mbvh4 --traversal stack,bitstack", 2 * 2 * 2 * 2, 8,
                                    {"Vulkan device", "validation layer on"});
}

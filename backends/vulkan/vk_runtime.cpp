// SPDX-License-Identifier: MIT
// vk_runtime.cpp — see vk_runtime.h.
#include "backends/vulkan/vk_runtime.h"

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <mutex>
#include <string_view>
#include <utility>

#if defined(__SANITIZE_ADDRESS__)
#include <dlfcn.h>
#include <link.h>
#endif

#include "backends/common/device_choice.h"
#include "mbvh/error.h"

namespace mbvh::vk {

std::string result_name(VkResult r) {
  switch (r) {
#define MBVH_VK_RESULT(x) \
  case x: return #x;
    MBVH_VK_RESULT(VK_SUCCESS)
    MBVH_VK_RESULT(VK_NOT_READY)
    MBVH_VK_RESULT(VK_TIMEOUT)
    MBVH_VK_RESULT(VK_INCOMPLETE)
    MBVH_VK_RESULT(VK_ERROR_OUT_OF_HOST_MEMORY)
    MBVH_VK_RESULT(VK_ERROR_OUT_OF_DEVICE_MEMORY)
    MBVH_VK_RESULT(VK_ERROR_INITIALIZATION_FAILED)
    MBVH_VK_RESULT(VK_ERROR_DEVICE_LOST)
    MBVH_VK_RESULT(VK_ERROR_MEMORY_MAP_FAILED)
    MBVH_VK_RESULT(VK_ERROR_LAYER_NOT_PRESENT)
    MBVH_VK_RESULT(VK_ERROR_EXTENSION_NOT_PRESENT)
    MBVH_VK_RESULT(VK_ERROR_FEATURE_NOT_PRESENT)
    MBVH_VK_RESULT(VK_ERROR_INCOMPATIBLE_DRIVER)
    MBVH_VK_RESULT(VK_ERROR_TOO_MANY_OBJECTS)
    MBVH_VK_RESULT(VK_ERROR_FORMAT_NOT_SUPPORTED)
    MBVH_VK_RESULT(VK_ERROR_FRAGMENTED_POOL)
    MBVH_VK_RESULT(VK_ERROR_UNKNOWN)
    MBVH_VK_RESULT(VK_ERROR_OUT_OF_POOL_MEMORY)
    MBVH_VK_RESULT(VK_ERROR_INVALID_EXTERNAL_HANDLE)
    MBVH_VK_RESULT(VK_ERROR_FRAGMENTATION)
    MBVH_VK_RESULT(VK_ERROR_INVALID_OPAQUE_CAPTURE_ADDRESS)
    MBVH_VK_RESULT(VK_ERROR_INVALID_SHADER_NV)
#undef MBVH_VK_RESULT
    default: return "VkResult " + std::to_string(static_cast<int>(r));
  }
}

void fail(const char* call, VkResult r, const std::string& what) {
  throw Error(std::string("Vulkan: ") + call + " failed: " + result_name(r) + " (" + std::to_string(static_cast<int>(r)) +
              ")" + (what.empty() ? "" : ": " + what));
}

bool validation_requested(bool flag) {
  if (flag) return true;
  const char* env = std::getenv("MBVH_VK_VALIDATION");
  return env && *env && std::strcmp(env, "0") != 0;
}

namespace {

std::mutex g_messages_mutex;
std::vector<std::string> g_messages;

VKAPI_ATTR VkBool32 VKAPI_CALL on_message(VkDebugUtilsMessageSeverityFlagBitsEXT severity,
                                          VkDebugUtilsMessageTypeFlagsEXT, const VkDebugUtilsMessengerCallbackDataEXT* data,
                                          void*) {
  const char* level = severity & VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT ? "error" : "warning";
  std::string text = std::string("Vulkan validation ") + level + ": " + (data && data->pMessage ? data->pMessage : "");
  const std::lock_guard<std::mutex> lock(g_messages_mutex);
  g_messages.push_back(std::move(text));
  return VK_FALSE;  // the call goes on; the backend reports the message as a failure
}

VkDebugUtilsMessengerCreateInfoEXT messenger_info() {
  VkDebugUtilsMessengerCreateInfoEXT m{};
  m.sType = VK_STRUCTURE_TYPE_DEBUG_UTILS_MESSENGER_CREATE_INFO_EXT;
  m.messageSeverity = VK_DEBUG_UTILS_MESSAGE_SEVERITY_WARNING_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_SEVERITY_ERROR_BIT_EXT;
  m.messageType = VK_DEBUG_UTILS_MESSAGE_TYPE_GENERAL_BIT_EXT | VK_DEBUG_UTILS_MESSAGE_TYPE_VALIDATION_BIT_EXT |
                  VK_DEBUG_UTILS_MESSAGE_TYPE_PERFORMANCE_BIT_EXT;
  m.pfnUserCallback = &on_message;
  return m;
}

const char* const kLayer = "VK_LAYER_KHRONOS_validation";

#if defined(__SANITIZE_ADDRESS__)
// Sanitizer builds only. The Vulkan loader dlcloses every driver and layer when an instance is
// destroyed. A driver that keeps an allocation in its globals (lavapipe: one small realloc per
// process) then holds it from unmapped memory: LeakSanitizer finds no root and can
// name no module ("<unknown module>"), so no suppression could match it without matching every
// leak. Instead the drivers and layers stay mapped (RTLD_NODELETE), as in a process that keeps
// Vulkan loaded: their globals stay roots, and a leak in our own code still fails the run (the
// planted-leak test in scripts/test proves it).
void keep_vulkan_modules_mapped() {
  std::vector<std::string> names;
  dl_iterate_phdr(
      [](dl_phdr_info* info, std::size_t, void* out) {
        const char* name = info->dlpi_name;
        if (name && (std::strstr(name, "libvulkan_") || std::strstr(name, "libVkLayer_")))
          static_cast<std::vector<std::string>*>(out)->emplace_back(name);
        return 0;
      },
      &names);
  for (const std::string& n : names) dlopen(n.c_str(), RTLD_NOW | RTLD_NOLOAD | RTLD_NODELETE);  // outside the loader lock
}
#endif

// What is wrong with the driver manifests the loader reads (VK_ICD_FILENAMES or VK_DRIVER_FILES,
// else the system's icd.d folders), "" when nothing is: a truncated or empty manifest makes the
// loader fail with a code that names something else (VK_ERROR_OUT_OF_HOST_MEMORY, no device).
// A cheap completeness check, not a JSON parser: the braces outside strings must balance.
std::string manifest_problems() {
  std::vector<std::string> files;
  const char* env = std::getenv("VK_ICD_FILENAMES");
  const char* which = "VK_ICD_FILENAMES";
  if (!env || !*env) env = std::getenv("VK_DRIVER_FILES"), which = "VK_DRIVER_FILES";
  if (env && *env) {
    std::string list = env;
    for (std::size_t a = 0; a <= list.size();) {
      std::size_t b = list.find(':', a);
      if (b == std::string::npos) b = list.size();
      if (b > a) files.push_back(list.substr(a, b - a));
      a = b + 1;
    }
  } else {
    which = nullptr;
    for (const char* dir : {"/etc/vulkan/icd.d", "/usr/share/vulkan/icd.d", "/usr/local/share/vulkan/icd.d"}) {
      std::error_code ec;
      for (const auto& e : std::filesystem::directory_iterator(dir, ec))
        if (e.path().extension() == ".json") files.push_back(e.path().string());
    }
  }
  std::string out;
  for (const std::string& f : files) {
    std::error_code ec;
    if (std::filesystem::is_directory(f, ec)) continue;  // the loader reads a folder's manifests itself
    std::ifstream in(f, std::ios::binary);
    std::string problem;
    if (!in) {
      problem = "cannot be read";
    } else {
      std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
      int depth = 0;
      bool str = false, esc = false, opened = false;
      for (char c : text) {
        if (str) {
          if (esc) esc = false;
          else if (c == '\\') esc = true;
          else if (c == '"') str = false;
        } else if (c == '"') {
          str = true;
        } else if (c == '{') {
          ++depth, opened = true;
        } else if (c == '}') {
          --depth;
        }
      }
      if (text.find_first_not_of(" \t\r\n") == std::string::npos) problem = "is empty";
      else if (!opened || depth != 0 || str) problem = "is not complete JSON (truncated? its braces do not balance)";
    }
    if (!problem.empty())
      out += std::string("\n  the driver manifest ") + f + (which ? std::string(" (") + which + ")" : std::string()) + " " +
             problem + ": the Vulkan loader cannot use it";
  }
  return out;
}

}  // namespace

std::vector<std::string> take_validation_messages() {
  const std::lock_guard<std::mutex> lock(g_messages_mutex);
  return std::exchange(g_messages, {});
}

Instance::Instance(bool validation) : validation_(validation) {
  VkApplicationInfo app{};
  app.sType = VK_STRUCTURE_TYPE_APPLICATION_INFO;
  app.pApplicationName = "mbvh";
  app.pEngineName = "mbvh";
  app.apiVersion = VK_API_VERSION_1_2;
  VkInstanceCreateInfo ci{};
  ci.sType = VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO;
  ci.pApplicationInfo = &app;
  const VkDebugUtilsMessengerCreateInfoEXT mi = messenger_info();
  const char* ext = VK_EXT_DEBUG_UTILS_EXTENSION_NAME;
  if (validation_) {
    std::uint32_t n = 0;
    check(vkEnumerateInstanceLayerProperties(&n, nullptr), "vkEnumerateInstanceLayerProperties");
    std::vector<VkLayerProperties> layers(n);
    check(vkEnumerateInstanceLayerProperties(&n, layers.data()), "vkEnumerateInstanceLayerProperties");
    bool found = false;
    for (const VkLayerProperties& l : layers) found = found || std::strcmp(l.layerName, kLayer) == 0;
    if (!found)
      throw Error(std::string("Vulkan validation was asked for (--vk-validation or MBVH_VK_VALIDATION) but ") + kLayer +
                  " is not installed: install Debian's vulkan-validationlayers (scripts/test does)");
    ci.enabledLayerCount = 1;
    ci.ppEnabledLayerNames = &kLayer;
    ci.enabledExtensionCount = 1;
    ci.ppEnabledExtensionNames = &ext;
    ci.pNext = &mi;  // instance creation and destruction are checked too
  }
  const VkResult r = vkCreateInstance(&ci, nullptr, &instance_);
  if (r != VK_SUCCESS) {  // what the loader said through the messenger belongs to this error
    std::string said;
    for (const std::string& m : take_validation_messages()) said += "\n  " + m;
    fail("vkCreateInstance", r,
         (r == VK_ERROR_INCOMPATIBLE_DRIVER ? "no Vulkan driver found: install one, e.g. Debian's mesa-vulkan-drivers "
                                              "(lavapipe; scripts/demo and scripts/test do)"
                                            : std::string("")) +
             said + manifest_problems());
  }
#if defined(__SANITIZE_ADDRESS__)
  keep_vulkan_modules_mapped();
#endif
  if (validation_) {
    auto create = reinterpret_cast<PFN_vkCreateDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkCreateDebugUtilsMessengerEXT"));
    const VkResult m = create ? create(instance_, &mi, nullptr, &messenger_) : VK_ERROR_EXTENSION_NOT_PRESENT;
    if (m != VK_SUCCESS) {
      vkDestroyInstance(instance_, nullptr);
      fail("vkCreateDebugUtilsMessengerEXT", m);
    }
  }
}

Instance::~Instance() {
  if (messenger_ != VK_NULL_HANDLE) {
    auto destroy = reinterpret_cast<PFN_vkDestroyDebugUtilsMessengerEXT>(
        vkGetInstanceProcAddr(instance_, "vkDestroyDebugUtilsMessengerEXT"));
    if (destroy) destroy(instance_, messenger_, nullptr);
  }
  if (instance_ != VK_NULL_HANDLE) vkDestroyInstance(instance_, nullptr);
}

std::string DeviceEntry::type_name() const {
  switch (type) {
    case VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU: return "discrete gpu";
    case VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU: return "integrated gpu";
    case VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU: return "virtual gpu";
    case VK_PHYSICAL_DEVICE_TYPE_CPU: return "cpu";
    default: return "other";
  }
}

std::string DeviceEntry::describe() const {
  return std::to_string(index) + " " + name + " (" + type_name() + "; " + driver_name + " " + driver_info + ", Vulkan " +
         std::to_string(VK_API_VERSION_MAJOR(api_version)) + "." + std::to_string(VK_API_VERSION_MINOR(api_version)) + "." +
         std::to_string(VK_API_VERSION_PATCH(api_version)) + ")";
}

std::vector<DeviceEntry> list_devices(VkInstance instance) {
  std::uint32_t n = 0;
  check(vkEnumeratePhysicalDevices(instance, &n, nullptr), "vkEnumeratePhysicalDevices");
  if (n == 0) {
    const char* icd = std::getenv("VK_ICD_FILENAMES");
    if (!icd) icd = std::getenv("VK_DRIVER_FILES");
    throw Error(std::string("no Vulkan device found: install a Vulkan driver, e.g. Debian's mesa-vulkan-drivers "
                            "(lavapipe; scripts/demo and scripts/test do); the loader looks for drivers in ") +
                (icd ? std::string("VK_ICD_FILENAMES/VK_DRIVER_FILES=") + icd : std::string("/usr/share/vulkan/icd.d")) +
                manifest_problems());
  }
  std::vector<VkPhysicalDevice> pds(n);
  check(vkEnumeratePhysicalDevices(instance, &n, pds.data()), "vkEnumeratePhysicalDevices");
  std::vector<DeviceEntry> out;
  for (std::uint32_t i = 0; i < n; ++i) {
    VkPhysicalDeviceDriverProperties driver{};
    driver.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_DRIVER_PROPERTIES;
    VkPhysicalDeviceProperties2 p{};
    p.sType = VK_STRUCTURE_TYPE_PHYSICAL_DEVICE_PROPERTIES_2;
    VkPhysicalDeviceProperties base{};
    vkGetPhysicalDeviceProperties(pds[i], &base);
    if (base.apiVersion >= VK_API_VERSION_1_2) {
      p.pNext = &driver;
      vkGetPhysicalDeviceProperties2(pds[i], &p);
    }
    DeviceEntry e;
    e.device = pds[i];
    e.index = i;
    e.name = base.deviceName;
    e.type = base.deviceType;
    e.api_version = base.apiVersion;
    e.driver_name = driver.driverName[0] ? driver.driverName : "driver";
    e.driver_info = driver.driverInfo;
    std::uint32_t next = 0;
    check(vkEnumerateDeviceExtensionProperties(pds[i], nullptr, &next, nullptr), "vkEnumerateDeviceExtensionProperties");
    std::vector<VkExtensionProperties> exts(next);
    check(vkEnumerateDeviceExtensionProperties(pds[i], nullptr, &next, exts.data()), "vkEnumerateDeviceExtensionProperties");
    for (const VkExtensionProperties& x : exts)
      e.ray_query = e.ray_query || std::string_view(x.extensionName) == VK_KHR_RAY_QUERY_EXTENSION_NAME;
    out.push_back(std::move(e));
  }
  return out;
}

const DeviceEntry& choose_device(const std::vector<DeviceEntry>& devices, const std::string& selector) {
  std::vector<DeviceCandidate> c;
  for (const DeviceEntry& d : devices) {
    const int rank = d.type == VK_PHYSICAL_DEVICE_TYPE_DISCRETE_GPU     ? 0
                     : d.type == VK_PHYSICAL_DEVICE_TYPE_INTEGRATED_GPU ? 1
                     : d.type == VK_PHYSICAL_DEVICE_TYPE_VIRTUAL_GPU    ? 2
                                                                        : 3;
    std::vector<std::string> types{d.type_name()};
    if (rank <= 2) types.push_back("gpu");
    c.push_back({std::to_string(d.index), {d.name, d.driver_name}, rank, d.describe(), types});
  }
  return devices[choose_device_index(c, selector, "Vulkan", "vulkan.device (--vk-device)")];
}

}  // namespace mbvh::vk

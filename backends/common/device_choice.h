// SPDX-License-Identifier: MIT
// device_choice.h — the one rule by which a device backend picks its device from a selector
// (`--cl-device`, `--vk-device`), shared by the OpenCL and Vulkan backends.
#pragma once
#include <algorithm>
#include <cctype>
#include <string>
#include <vector>

#include "mbvh/error.h"

namespace mbvh {

/// One device as a backend lists it.
struct DeviceCandidate {
  std::string id;                  ///< exact selector ("P:D" for OpenCL, the index for Vulkan)
  std::vector<std::string> names;  ///< matched case-insensitively by a name selector
  int rank = 0;                    ///< default choice: the lowest rank, first listed among equals
  std::string line;                ///< the line `mbvh devices` prints
  std::vector<std::string> types;  ///< kind words a selector may name ("gpu", "cpu", ...), lower case
};

/// The index of the device `selector` names: "" = the default (lowest rank); the id; "N" = the
/// N-th device listed; a kind word ("gpu", "cpu", ...: one of DeviceCandidate::types) = the
/// lowest-ranked device of that kind; anything else = the first device one of whose names
/// contains it (case-insensitive). Throws Error listing the devices when nothing matches.
inline std::size_t choose_device_index(const std::vector<DeviceCandidate>& devices, const std::string& selector,
                                       const std::string& api, const std::string& flag) {
  if (devices.empty()) throw Error("no " + api + " device");
  if (selector.empty()) {
    std::size_t best = 0;
    for (std::size_t i = 1; i < devices.size(); ++i)
      if (devices[i].rank < devices[best].rank) best = i;
    return best;
  }
  for (std::size_t i = 0; i < devices.size(); ++i)
    if (devices[i].id == selector) return i;
  const auto lower = [](std::string s) {
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  };
  if (std::all_of(selector.begin(), selector.end(), [](char c) { return std::isdigit(static_cast<unsigned char>(c)); })) {
    if (selector.size() < 10) {
      const std::size_t n = std::stoul(selector);
      if (n < devices.size()) return n;
    }
  } else {
    std::size_t typed = devices.size();
    for (std::size_t i = 0; i < devices.size(); ++i)
      if (std::find(devices[i].types.begin(), devices[i].types.end(), lower(selector)) != devices[i].types.end() &&
          (typed == devices.size() || devices[i].rank < devices[typed].rank))
        typed = i;
    if (typed < devices.size()) return typed;
    for (std::size_t i = 0; i < devices.size(); ++i)
      for (const std::string& name : devices[i].names)
        if (lower(name).find(lower(selector)) != std::string::npos) return i;
  }
  std::string list;
  for (const DeviceCandidate& d : devices) list += "\n  " + d.line;
  throw Error("no " + api + " device matches " + flag + " '" + selector + "'; the devices are:" + list);
}

}  // namespace mbvh

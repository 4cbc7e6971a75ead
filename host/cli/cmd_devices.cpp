// SPDX-License-Identifier: MIT
// cmd_devices.cpp — `mbvh devices`: the backends of this build, their devices, their settings
// (--set) and whether they can start.
#include "host/cli/commands.h"

namespace mbvh::cli {

namespace {

int run_devices(const DeviceArgs& dev) {
  const BackendOptions opt = dev.options(0);  // a malformed --set is a usage error, before any backend
  for (const BackendInfo& b : list_backends()) {
    if (!b.make) {
      say("%-12s not built: %s\n", b.name.c_str(), b.unavailable.c_str());
      continue;
    }
    try {
      auto be = make_backend(b.name, opt);  // its settings checked as everywhere else
      say("%-12s ready: %s%s\n", b.name.c_str(), be->describe().c_str(),
          b.alias_of.empty() ? "" : (" (= " + b.alias_of + ")").c_str());
      if (b.devices && b.alias_of.empty())
        for (const std::string& d : b.devices()) say("%-12s   device %s\n", "", d.c_str());
    } catch (const std::exception& e) {
      say("%-12s cannot start: %s\n", b.name.c_str(), e.what());
    }
    if (b.alias_of.empty())  // listed whether it starts or not: a device setting may be what it needs
      for (const BackendSetting& s : b.settings) say("%-12s   setting %s: %s\n", "", s.name.c_str(), s.help.c_str());
  }
  return 0;
}

}  // namespace

Command add_devices(CLI::App& app) {
  auto dev = std::make_shared<DeviceArgs>();
  auto* c = app.add_subcommand("devices", "list the backends of this build, their devices and whether they can start");
  dev->add(c);
  return {c, [dev] { return run_devices(*dev); }};
}

}  // namespace mbvh::cli

// SPDX-License-Identifier: MIT
// cmd_devices.cpp — `mbvh devices`: the backends of this build, their devices, their settings
// (--set) and whether they can start; `--ready` and `--resolve NAME` answer the same for scripts.
#include <cstdio>

#include "host/cli/commands.h"

namespace mbvh::cli {

namespace {

struct DevicesArgs {
  DeviceArgs dev;
  bool ready = false;
  std::string resolve;
};

// The table: every registered backend, ready or why not, its devices and its settings.
int print_table(const BackendOptions& opt) {
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

// --ready: one name a line, every backend that starts here, each once under its own name
// (runnable_backends, each started); why a runnable one fails to start goes to standard error.
int print_ready(const BackendOptions& opt) {
  for (const std::string& name : runnable_backends()) {
    try {
      make_backend(name, opt);
      std::printf("%s\n", name.c_str());
    } catch (const std::exception& e) {
      std::fprintf(stderr, "mbvh: %s cannot start: %s\n", name.c_str(), e.what());
    }
  }
  return 0;
}

// --resolve NAME: the backend NAME runs as here (`cpu`: cpu-avx512 or cpu-avx2), once it starts;
// a backend that cannot start is an error, as everywhere.
int print_resolved(const std::string& name, const BackendOptions& opt) {
  std::printf("%s\n", make_backend(name, opt)->runs_as().c_str());
  return 0;
}

}  // namespace

Command add_devices(CLI::App& app) {
  auto a = std::make_shared<DevicesArgs>();
  auto* c = app.add_subcommand("devices", "list the backends of this build, their devices and whether they can start");
  a->dev.add(c);
  auto* ready = c->add_flag("--ready", a->ready,
                            "print only the backends that start here, one name a line, each once under its own name "
                            "(`cpu` as the ISA backend it stands for)");
  c->add_option("--resolve", a->resolve, "print the backend NAME runs as here (cpu: cpu-avx512 or cpu-avx2); an error "
                                         "when it cannot start")
      ->type_name("NAME")
      ->excludes(ready);
  return {c, [a] {
            const BackendOptions opt = a->dev.options(0);  // a malformed --set is a usage error, before any backend
            if (a->ready) return print_ready(opt);
            if (!a->resolve.empty()) return print_resolved(a->resolve, opt);
            return print_table(opt);
          }};
}

}  // namespace mbvh::cli

// SPDX-License-Identifier: MIT
// registry.cpp — the backend registry: names to factories. The core registers nothing: the
// program (or the user) registers the backends it links (mbvh/backends.h).
#include <mutex>

#include "mbvh/backend.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

std::vector<BackendInfo>& table() {
  static std::vector<BackendInfo> t;
  return t;
}

std::recursive_mutex& table_mutex() {
  static std::recursive_mutex m;
  return m;
}

}  // namespace

void register_backend(BackendInfo info) {
  std::lock_guard<std::recursive_mutex> lock(table_mutex());
  for (auto& b : table())
    if (b.name == info.name) {
      b = std::move(info);
      return;
    }
  table().push_back(std::move(info));
}

std::vector<BackendInfo> list_backends() {
  std::lock_guard<std::recursive_mutex> lock(table_mutex());
  return table();
}

std::unique_ptr<Backend> make_backend(const std::string& name, const BackendOptions& opt) {
  for (const BackendInfo& b : list_backends()) {
    if (b.name != name) continue;
    if (!b.make) throw Error("backend '" + name + "' is not available in this build: " + b.unavailable);
    return b.make(opt);
  }
  std::string known;
  for (const BackendInfo& b : list_backends()) known += (known.empty() ? "" : ", ") + b.name;
  if (known.empty())
    throw Error("unknown backend '" + name + "': no backend is registered (link mbvh::mbvh and call "
                "mbvh::register_builtin_backends(), or a backend's own register function; mbvh/backends.h)");
  throw Error("unknown backend '" + name + "' (known: " + known + ")");
}

}  // namespace mbvh

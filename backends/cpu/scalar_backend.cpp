// SPDX-License-Identifier: MIT
// scalar_backend.cpp — the `cpu-scalar` backend: the host's reference traversals (MBVH2 and
// MBVH4, stack and bitstack, closest and any hit) multi-threaded over ray batches. The portable
// kernels: `cpu` runs them too where there are no SIMD ones (simd_backend.cpp).
#include <algorithm>
#include <string>
#include <utility>

#include "backends/cpu/cpu_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "host/core/parallel.h"

namespace mbvh {
namespace {

class ScalarBackend final : public Backend {
public:
  ScalarBackend(std::string name, const BackendOptions& o)
      : name_(std::move(name)), threads_(resolve_threads(o.threads)), own_block_(cpu_leaf_block(o, 1)) {}
  std::string name() const override { return name_; }
  std::string describe() const override {
    return name_ + ": reference scalar traversals, " + std::to_string(threads_) + " thread(s)";
  }
  std::string isa() const override { return "scalar"; }
  std::string runs_as() const override { return "cpu-scalar"; }
  bool supports(Layout l, Traversal t) const override { return reference_supports(l, t); }
  std::vector<std::pair<Layout, Traversal>> fastest(Query q) const override { return reference_fastest(q); }
  bool supports_precision(Precision) const override { return true; }
  /// The reference traces any leaf variant asked for; its own choice is the build's leaves (or
  /// cpu.leaf-block).
  unsigned leaf_block(const TraceOptions& opt) const override { return opt.leaf_block ? opt.leaf_block : own_block_; }
  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    if (opt.leaf_block > 1) acc.leaf_variant(opt.leaf_block).make_layout(opt.layout);
    else acc.make_layout(opt.layout);
  }
  void trace_batch(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    trace_reference(acc, rays, opt, out, threads_);
  }

private:
  std::string name_;  ///< cpu-scalar, or `cpu` where that runs the portable kernels
  unsigned threads_;
  unsigned own_block_;
};

}  // namespace

BackendInfo cpu_scalar_info(const std::string& name) {
  BackendInfo info;
  info.name = name;
  info.summary = "scalar reference traversals (MBVH2/MBVH4, stack/bitstack), multi-threaded";
  info.make = [name](const BackendOptions& o) { return std::unique_ptr<Backend>(new ScalarBackend(name, o)); };
  info.settings = {cpu_leaf_block_setting("1"), cpu_packet_hybrid_setting("; cpu-scalar traces every ray alone"),
                   cpu_mic_setting("; cpu-scalar traces the reference's box test")};
  return info;
}

void register_cpu_scalar_backend() { register_backend(cpu_scalar_info("cpu-scalar")); }

}  // namespace mbvh

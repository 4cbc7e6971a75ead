// SPDX-License-Identifier: MIT
// dacrt_backend.cpp — the `dacrt` backends: divide-and-conquer ray tracing without an acceleration
// structure (Áfra, EG 2012; the thesis' chapter 6; backends/cpu/dacrt/recursion.h). `dacrt` runs the
// SIMD policy of the best ISA this CPU has (the cpu backends' per-ISA build, isa_kernels.cpp),
// `dacrt-scalar` the portable one; both give the same bytes. Where there is no SIMD ISA (as for
// `cpu`: simd_backend.cpp), `dacrt` is dacrt-scalar under a second name. They read only the build's triangles
// (Accel::tris) and trace any build, a hierarchy's or one of quality none.
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <string>

#include "backends/cpu/cpu_backends.h"
#include "backends/cpu/dacrt/recursion.h"
#include "mbvh/backends.h"
#include "mbvh/error.h"

namespace mbvh {
namespace {

std::string ratio_text(float r) {
  char t[32];
  std::snprintf(t, sizeof t, "%g", static_cast<double>(r));
  return t;
}

std::vector<BackendSetting> dacrt_settings() {
  const DacrtSettings d;
  return {
      {"dacrt.partition", "how a step splits its triangles: adaptive (SAH where active rays per triangle exceed dacrt.ratio, "
                          "else the middle of the centroid bounds; the default), sah or middle"},
      {"dacrt.ratio", "active rays per triangle above which adaptive partitioning takes the SAH (default " + ratio_text(d.ratio) + ")"},
      {"dacrt.bins", "SAH bins per axis, 2 to 64 (default " + std::to_string(d.bins) + ")"},
      {"dacrt.leaf-rays", "intersect naively below this many active rays (default " + std::to_string(d.leaf_rays) + ")"},
      {"dacrt.leaf-tris", "intersect naively at this many triangles or fewer (default " + std::to_string(d.leaf_tris) + ")"},
      {"dacrt.ordered", "the near half first, by the first active ray's direction sign (1, the default) or always the lower half (0)"},
      {"dacrt.chunk", "rays per independent task (default " + std::to_string(d.chunk) +
                          "): a batch is cut into such chunks in ray order, the same at any thread count"},
  };
}

std::size_t bounded(const BackendOptions& o, const char* name, std::size_t fallback, std::size_t lo, std::size_t hi) {
  const std::size_t v = o.get_size(name, fallback);
  if (v < lo || v > hi)
    throw Error(std::string("backend setting ") + name + "=" + o.get(name) + ": must be " + std::to_string(lo) + " to " +
                std::to_string(hi));
  return v;
}

DacrtSettings parse_settings(const BackendOptions& o) {
  DacrtSettings s;
  const std::string p = o.get("dacrt.partition", "adaptive");
  if (p == "adaptive") s.partition = DacrtSettings::Partition::adaptive;
  else if (p == "sah") s.partition = DacrtSettings::Partition::sah;
  else if (p == "middle") s.partition = DacrtSettings::Partition::middle;
  else throw Error("backend setting dacrt.partition=" + p + ": expected adaptive, sah or middle");
  if (const std::string r = o.get("dacrt.ratio"); !r.empty()) {
    char* end = nullptr;
    errno = 0;
    const double v = std::strtod(r.c_str(), &end);
    if (end == r.c_str() || *end != '\0' || errno != 0 || !std::isfinite(v) || !(v >= 0.0) || v > 1e9)
      throw Error("backend setting dacrt.ratio=" + r + ": expected a number from 0 to 1e9");
    s.ratio = static_cast<float>(v);
  }
  s.bins = static_cast<unsigned>(bounded(o, "dacrt.bins", s.bins, 2, 64));
  s.leaf_rays = static_cast<unsigned>(bounded(o, "dacrt.leaf-rays", s.leaf_rays, 1, 1u << 24));
  s.leaf_tris = static_cast<unsigned>(bounded(o, "dacrt.leaf-tris", s.leaf_tris, 1, 1u << 24));
  s.ordered = o.get_flag("dacrt.ordered", s.ordered);
  s.chunk = bounded(o, "dacrt.chunk", s.chunk, 1, std::size_t(1) << 31);
  return s;
}

const char* partition_name(DacrtSettings::Partition p) {
  return p == DacrtSettings::Partition::adaptive ? "adaptive" : p == DacrtSettings::Partition::sah ? "sah" : "middle";
}

class DacrtBackend final : public Backend {
public:
  DacrtBackend(std::string name, const CpuKernels* k, const BackendOptions& o)
      : name_(std::move(name)), kernels_(k), threads_(resolve_threads(o.threads)), s_(parse_settings(o)) {}
  std::string name() const override { return name_; }
  std::string describe() const override {
    const std::string ratio = ratio_text(s_.ratio);
    return name_ + ": divide-and-conquer ray tracing, no hierarchy (" +
           (kernels_ ? std::string(kernels_->isa) + " filter of 8 rays a pass, leaves of 64 rays a triangle"
                     : std::string("scalar filter and leaves")) +
           "), partition " + partition_name(s_.partition) + " (ratio " + ratio + ", " + std::to_string(s_.bins) +
           " bins), leaves below " + std::to_string(s_.leaf_rays) + " rays or at " + std::to_string(s_.leaf_tris) +
           " triangles, " + (s_.ordered ? "ordered" : "unordered") + ", chunks of " + std::to_string(s_.chunk) + " rays, " +
           std::to_string(threads_) + " thread(s)";
  }
  std::string isa() const override { return kernels_ ? kernels_->isa : "scalar"; }
  std::string runs_as() const override { return kernels_ ? name_ : "dacrt-scalar"; }
  bool supports(Layout, Traversal t) const override { return t == Traversal::dacrt; }
  bool supports_precision(Precision) const override { return true; }
  /// The working set per ray: its filter record, id and side record (dacrt/recursion.h; the
  /// scalar policy's side is the prepared ray and its best hit).
  std::size_t state_bytes(const TraceOptions&) const override {
    return sizeof(dacrt::RayRec) + sizeof(std::uint32_t) + (kernels_ ? kDacrtSimdSideBytes : sizeof(RayPre) + sizeof(Hit));
  }

protected:
  /// Nothing is made ahead: the triangles' boxes are computed by every trace (O(triangles), in
  /// parallel), so a refit or another build needs no bookkeeping; the buffers they and the rays'
  /// records go in are kept between calls.
  void do_prepare(const Accel&, const TraceOptions&) override {}
  void trace_batch(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    if (kernels_) kernels_->dacrt(acc, rays, opt, out, threads_, s_, buffers_);
    else dacrt_scalar(acc, rays, opt, out, threads_, s_, buffers_);
  }

private:
  std::string name_;
  const CpuKernels* kernels_;  ///< null: the scalar policy
  unsigned threads_;
  DacrtSettings s_;
  /// The kernel's buffers, kept between calls: a batch no larger than the last allocates nothing.
  DacrtBuffers buffers_;
};

BackendInfo dacrt_info(const std::string& name, const CpuKernels* k) {
  BackendInfo info;
  info.name = name;
  info.make = [name, k](const BackendOptions& o) { return std::unique_ptr<Backend>(new DacrtBackend(name, k, o)); };
  info.needs_hierarchy = false;
  info.settings = dacrt_settings();
  return info;
}

}  // namespace

void register_dacrt_backends() {
  // `dacrt`: the best ISA's kernels; without one (choose_cpu_kernels), dacrt-scalar's under this
  // name, with a notice; a bad MBVH_CPU_ISA stops it
  const CpuChoice best = choose_cpu_kernels();
  if (!best.portable_because.empty()) {
    register_portable_alias(dacrt_info("dacrt", nullptr), "dacrt-scalar", best.portable_because);
  } else {
    BackendInfo simd = dacrt_info("dacrt", best.kernels);
    simd.summary = "divide-and-conquer ray tracing without a hierarchy (thesis ch. 6), the best ISA of this CPU";
    if (!best.kernels) {
      simd.make = [e = best.error](const BackendOptions&) -> std::unique_ptr<Backend> {
        throw Error("backend 'dacrt' cannot start: " + e);
      };
      simd.missing_hardware = [e = best.error] { return e; };
    }
    register_backend(std::move(simd));
  }
  BackendInfo scalar = dacrt_info("dacrt-scalar", nullptr);
  scalar.summary = "divide-and-conquer ray tracing without a hierarchy, portable scalar reference of the recursion";
  register_backend(std::move(scalar));
}

}  // namespace mbvh

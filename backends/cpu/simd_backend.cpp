// SPDX-License-Identifier: MIT
// simd_backend.cpp — the `cpu` backends: `cpu-avx2` and `cpu-avx512` run the per-ISA kernels of
// isa_kernels.cpp; `cpu` picks the best this machine has, chosen once from CPUID. Forcing an
// ISA the machine lacks fails with a clear message. MBVH_CPU_ISA caps the ISA (as Embree's `isa=`
// setting does): avx2 makes the AVX-512 kernels count as absent, as on an AVX2-only machine;
// scalar makes both count as absent, as on a CPU without AVX2. Where there are no SIMD kernels (such
// a CPU, that cap, or a build without them: any target but x86-64), `cpu` runs cpu-scalar's
// portable kernels and says so in the log.
#include <cstdlib>
#include <cstring>
#include <string>

#include "backends/cpu/cpu_backends.h"
#include "host/core/layouts.h"
#include "mbvh/backend.h"
#include "mbvh/config.h"
#include "mbvh/error.h"
#include "host/core/parallel.h"

namespace mbvh {

#ifdef MBVH_HAVE_CPU_SIMD
extern const CpuKernels cpu_kernels_avx2;
extern const CpuKernels cpu_kernels_avx512;
#endif

namespace {

// MBVH_CPU_ISA: unset or empty = the best this CPU has; avx2 = no AVX-512; scalar = no SIMD
// kernels; avx512 = as unset. Any other value stops every SIMD backend and `cpu` with a message
// naming it (registration cannot throw).
enum class IsaCap { best, avx2, scalar, invalid };
IsaCap isa_cap() {
  const char* cap = std::getenv("MBVH_CPU_ISA");
  if (!cap || !*cap || std::strcmp(cap, "avx512") == 0) return IsaCap::best;
  if (std::strcmp(cap, "avx2") == 0) return IsaCap::avx2;
  return std::strcmp(cap, "scalar") == 0 ? IsaCap::scalar : IsaCap::invalid;
}
std::string invalid_cap_message() {
  return std::string("MBVH_CPU_ISA=") + std::getenv("MBVH_CPU_ISA") +
         " is not an ISA: set scalar, avx2 or avx512, or unset it for the best this CPU has";
}

}  // namespace

#ifdef MBVH_HAVE_CPU_SIMD
namespace {

bool has_avx2() {
  const IsaCap cap = isa_cap();
  return (cap == IsaCap::best || cap == IsaCap::avx2) && __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
bool has_avx512() {
  return isa_cap() == IsaCap::best && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512vl");
}

/// `cpu` on a machine with AVX-512 and AVX2: the ISA each query and traversal kind runs, the
/// faster one as measured on the AMD Zen 4 (512-bit operations as two 256-bit halves; the table
/// and its method in docs/benchmarks.md, "AVX-512"). A kind where the two measured alike within
/// noise keeps AVX-512, the build the CPU's best ISA names. cpu-avx2 and cpu-avx512 always run
/// their own.
struct IsaChoice {
  Query query;
  bool packets;  ///< the packet traversals (packet-ranged, packet-partition, packet), else single rays
  bool avx512;   ///< the AVX-512 kernels, else AVX2's
};
constexpr IsaChoice kIsaTable[] = {
    {Query::closest, true, true},  // 16-lane packets
    {Query::any, true, true},
    {Query::closest, false, true},  // single rays: the same 8-lane kernels either way
    {Query::any, false, true},
};
/// `cpu` on AVX-512 with cpu.mic unset: the MBVH4 traversals that run the MIC path (mic.h), those
/// it measured faster on (the AMD Zen 4; benchmarks.md, "AVX-512", the MIC path): the any-hit
/// MBVH4 stack (1.04-1.08x the 4-lane test on the interiors' shadow rays in two runs, 0.97-0.98x
/// on the bunny's). Everywhere else the 4-lane test measured faster. The MIC path reads two records
/// per node (Node4 and Node4W), so where the nodes leave the caches (the hairballs) it is slower
/// than the 4-lane test (docs/backends.md, issue 36's fourth round); no scene statistic tried
/// separates those scenes from the ones it gains on.
struct MicChoice {
  Query query;
  Traversal traversal;
};
constexpr MicChoice kMicTable[] = {{Query::any, Traversal::stack}};
bool choose_mic(const TraceOptions& o) {
  if (o.layout != Layout::mbvh4) return false;
  for (const MicChoice& c : kMicTable)
    if (c.query == o.query && c.traversal == o.traversal) return true;
  return false;
}
bool choose_avx512(Query q, Traversal t) {
  for (const IsaChoice& c : kIsaTable)
    if (c.query == q && c.packets == is_packet(t)) return c.avx512;
  return true;
}

class SimdBackend final : public Backend {
public:
  /// `avx2`: for `cpu` where `k` is the AVX-512 kernels, AVX2's, which kIsaTable's rows may pick.
  SimdBackend(std::string name, const CpuKernels& k, const BackendOptions& o, const CpuKernels* avx2 = nullptr)
      : name_(std::move(name)), kernels_(k), avx2_(avx2), threads_(resolve_threads(o.threads)),
        own_block_(cpu_leaf_block(o, kOwnLeafBlock)), hybrid_(o.get_flag("cpu.packet-hybrid", true)),
        mic_(o.get_flag("cpu.mic", false)), mic_auto_(avx2 && o.get("cpu.mic").empty()) {
    if (mic_ && std::strcmp(kernels_.isa, "avx512") != 0)
      throw Error("backend setting cpu.mic=" + o.get("cpu.mic") + ": the MIC path (MBVH4 nodes tested in 16 lanes) needs the "
                  "AVX-512 kernels, and backend '" + name_ + "' runs cpu-" + kernels_.isa + "'s");
  }
  std::string name() const override { return name_; }
  std::string describe() const override {
    return name_ + ": " + kernels_.isa + " node tests (MBVH4: 4 boxes, MBVH8: 8 at once), SIMD leaves 8 triangles per pass (leaf block " +
           std::to_string(own_block_) + "), packets of " + std::to_string(kernels_.packet_rays) + " rays (SIMD rays of " +
           std::to_string(kernels_.packet_lanes) + ")" +
           (hybrid_ ? "" : " (no hybrid switch)") + (mic_ ? ", the MIC path for MBVH4 (a node in 16 lanes)" : "") + ", " +
           std::to_string(threads_) + " thread(s)";
  }
  std::string isa() const override { return kernels_.isa; }
  std::string runs_as() const override { return std::string("cpu-") + kernels_.isa; }
  bool supports(Layout l, Traversal t) const override { return reference_supports(l, t); }
  bool supports_precision(Precision) const override { return true; }
  /// Leaves regrouped for the four-triangle SIMD leaf packs unless asked otherwise: fewer, fuller
  /// leaves and packs, so fewer cache lines and nodes per ray.
  static constexpr unsigned kOwnLeafBlock = 4;
  unsigned leaf_block(const TraceOptions& opt) const override { return opt.leaf_block ? opt.leaf_block : own_block_; }
  /// Everything made once per build happens here, outside the timed trace: the layout and the
  /// leaves' SIMD packs of the leaf variant traced (and their `fast` copy), and the copy of its nodes whose leaf
  /// references locate the packs (TraceView::packed_refs; all kept by the Accel; later calls
  /// are free).
  void do_prepare(const Accel& acc, const TraceOptions& opt) override {
    const unsigned block = leaf_block(opt);
    // the `fast` precision's leaves read their own copy of the packs (TriPacks::mt), counted
    // traces the leaf table
    const bool fast_packs = opt.precision == Precision::fast && !opt.stats;
    if (block > 1) {
      const LeafVariant& v = acc.leaf_variant(block);
      v.make_layout(opt.layout);
      v.packed_nodes(opt.layout, acc.tris());  // also the packs
      if (fast_packs) v.tri_packs(acc.tris()).mt();
      if ((mic_ || mic_auto_) && opt.layout == Layout::mbvh4) v.mbvh4_wide();
    } else {
      acc.make_layout(opt.layout);
      const TriPacks& packs = acc.tri_packs();
      if (fast_packs) packs.mt();
      if ((mic_ || mic_auto_) && opt.layout == Layout::mbvh4) acc.mbvh4_wide();
    }
  }
  void trace_batch(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out) override {
    const CpuKernels& k = kernels_for(opt.query, opt.traversal);
    const bool mic = mic_ || (mic_auto_ && &k == &kernels_ && choose_mic(opt));  // kMicTable's choice for `cpu`
    k.trace(acc, rays, opt, out, threads_, hybrid_, mic);
  }
  /// The single-ray query: this ISA's kernels, the views resolved now (Backend::ray_query has
  /// prepared the build for both queries).
  RayQueryKernels ray_query_kernels(const Accel& acc, const TraceOptions& closest, const TraceOptions& any) override {
    return kernels_for(Query::closest, closest.traversal).ray_query(acc, closest, any, mic_);
  }

private:
  /// The kernels query q with traversal t runs: kIsaTable's choice for `cpu`, else this backend's.
  const CpuKernels& kernels_for(Query q, Traversal t) const {
    return avx2_ && !choose_avx512(q, t) ? *avx2_ : kernels_;
  }
  std::string name_;
  const CpuKernels& kernels_;
  const CpuKernels* avx2_;
  unsigned threads_;
  unsigned own_block_;  ///< cpu.leaf-block (default kOwnLeafBlock)
  bool hybrid_;         ///< cpu.packet-hybrid (default on)
  bool mic_;            ///< cpu.mic (default off): the MIC path for MBVH4 (backends/cpu/simd/mic.h)
  /// `cpu` on AVX-512 with cpu.mic unset: the MIC path where kMicTable says it measured faster
  bool mic_auto_;
};

// Registers `name` running kernels `k` where `available()`; elsewhere it refuses to start, saying
// `missing`, and tests skip it (missing hardware, not a failure).
void add(const char* name, const char* summary, const CpuKernels& k, bool (*available)(), std::string missing,
         const char* alias_of = "", const CpuKernels* avx2 = nullptr) {
  BackendInfo info;
  info.name = name;
  info.alias_of = alias_of;
  info.summary = summary;
  info.make = [name, &k, available, missing, avx2](const BackendOptions& o) -> std::unique_ptr<Backend> {
    if (!available()) throw Error(std::string("backend '") + name + "' cannot start: " + missing);
    return std::make_unique<SimdBackend>(name, k, o, avx2);
  };
  info.missing_hardware = [available, missing] { return available() ? std::string() : std::string(missing); };
  info.settings = {cpu_leaf_block_setting("4"), cpu_packet_hybrid_setting(), cpu_mic_setting()};
  register_backend(std::move(info));
}

}  // namespace

CpuChoice choose_cpu_kernels() {
  CpuChoice c;
  const IsaCap cap = isa_cap();
  if (cap == IsaCap::invalid) c.error = invalid_cap_message();
  else if (has_avx512()) c.kernels = &cpu_kernels_avx512;
  else if (has_avx2()) c.kernels = &cpu_kernels_avx2;
  else if (cap == IsaCap::scalar) c.portable_because = "MBVH_CPU_ISA=scalar turns the SIMD kernels off";
  else c.portable_because = "this CPU has no AVX2 and FMA";
  return c;
}

void register_cpu_simd_backends() {
  const IsaCap cap = isa_cap();
  const auto why = [cap](const char* missing) {
    return cap == IsaCap::invalid ? invalid_cap_message() : std::string(missing);
  };
  add("cpu-avx2", "SIMD MBVH4/MBVH8 node tests and leaves, AVX2 build", cpu_kernels_avx2, &has_avx2,
      why(cap == IsaCap::scalar ? "AVX2 is turned off by MBVH_CPU_ISA=scalar" : "this CPU has no AVX2 and FMA"));
  add("cpu-avx512", "SIMD MBVH4/MBVH8 node tests and leaves, AVX-512 build", cpu_kernels_avx512, &has_avx512,
      why(cap == IsaCap::avx2 || cap == IsaCap::scalar
              ? (cap == IsaCap::avx2 ? "AVX-512 is turned off by MBVH_CPU_ISA=avx2" : "AVX-512 is turned off by MBVH_CPU_ISA=scalar")
              : "this CPU has no AVX-512F/VL"));
  // `cpu`: the best ISA; without one, cpu-scalar under this name (with a notice); a bad
  // MBVH_CPU_ISA stops it as it stops the ISA backends
  const CpuChoice best = choose_cpu_kernels();
  if (!best.portable_because.empty()) {
    register_portable_alias(cpu_scalar_info("cpu"), "cpu-scalar", best.portable_because);
    return;
  }
  const bool avx512 = best.kernels == &cpu_kernels_avx512;
  // with AVX-512, per query and traversal kind the ISA that measured faster (kIsaTable)
  add("cpu", "SIMD MBVH4/MBVH8 node tests and leaves, the best ISA of this CPU (AVX-512, else AVX2, else cpu-scalar)",
      avx512 ? cpu_kernels_avx512 : cpu_kernels_avx2, avx512 ? &has_avx512 : &has_avx2, why(""),
      avx512 ? "cpu-avx512" : "cpu-avx2", avx512 && has_avx2() ? &cpu_kernels_avx2 : nullptr);
}

#else  // the portable build: no SIMD kernels; `cpu` is cpu-scalar

CpuChoice choose_cpu_kernels() {
  CpuChoice c;
  if (isa_cap() == IsaCap::invalid) c.error = invalid_cap_message();
  else c.portable_because = "this build has no SIMD kernels for " MBVH_TARGET_PROCESSOR " (they are x86-64's: MBVH_CPU_SIMD)";
  return c;
}

void register_cpu_simd_backends() {
  for (const char* name : {"cpu-avx2", "cpu-avx512"}) {
    BackendInfo info;
    info.name = name;
    info.summary = "SIMD MBVH4/MBVH8 node tests and leaves, x86-64 only";
    info.unavailable = "this build has no x86 SIMD kernels (a build for " MBVH_TARGET_PROCESSOR "; MBVH_CPU_SIMD is x86-64 only)";
    register_backend(std::move(info));
  }
  const CpuChoice c = choose_cpu_kernels();
  if (!c.error.empty()) {  // a bad MBVH_CPU_ISA: `cpu` cannot start, naming it
    BackendInfo info = cpu_scalar_info("cpu");
    info.make = [e = c.error](const BackendOptions&) -> std::unique_ptr<Backend> { throw Error("backend 'cpu' cannot start: " + e); };
    info.missing_hardware = [e = c.error] { return e; };
    register_backend(std::move(info));
    return;
  }
  register_portable_alias(cpu_scalar_info("cpu"), "cpu-scalar", c.portable_because);
}

#endif

}  // namespace mbvh

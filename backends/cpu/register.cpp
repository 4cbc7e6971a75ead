// SPDX-License-Identifier: MIT
// register.cpp — mbvh::cpu's registration entry point (mbvh/backends.h), the cpu family's
// shared settings (cpu.leaf-block, cpu.packet-hybrid, cpu.mic) and the portable fallback's second names.
#include <string>
#include <utility>

#include "backends/cpu/cpu_backends.h"
#include "mbvh/backends.h"
#include "mbvh/error.h"
#include "mbvh/log.h"

namespace mbvh {

unsigned cpu_leaf_block(const BackendOptions& o, unsigned fallback) {
  const std::size_t b = o.get_size("cpu.leaf-block", fallback);
  if (b < 1 || b > 64)
    throw Error("backend setting cpu.leaf-block=" + o.get("cpu.leaf-block") + ": the leaf block must be 1 to 64");
  return static_cast<unsigned>(b);
}

BackendSetting cpu_leaf_block_setting(const char* fallback) {
  return {"cpu.leaf-block", std::string("the leaves traced: the build's regrouped for leaf tests of N triangles "
                                        "(1: the build's own; default ") + fallback + ")"};
}

BackendSetting cpu_packet_hybrid_setting(const char* note) {
  return {"cpu.packet-hybrid", std::string("packet traversals: a packet of incoherent rays is traced ray by ray (1, the default) "
                                           "or every packet as a packet (0)") + note};
}

BackendSetting cpu_mic_setting(const char* note) {
  return {"cpu.mic", std::string("the MIC path: MBVH4 traversals test a node's four children in 16 lanes on the 16-wide "
                                 "view, one 512-bit operation per row (1; AVX-512 only) or four boxes in 4 lanes (0, the default)") +
                         note};
}

void register_portable_alias(BackendInfo info, const std::string& portable, const std::string& because) {
  const std::string notice = "backend '" + info.name + "' runs " + portable + ", the portable kernels: " + because;
  info.alias_of = portable;
  info.summary = "the best kernels of this machine; here " + portable + "'s portable ones (" + because + ")";
  info.make = [make = std::move(info.make), notice](const BackendOptions& o) {
    std::unique_ptr<Backend> b = make(o);  // settings refused before the notice
    log_message(LogLevel::info, notice);
    return b;
  };
  register_backend(std::move(info));
}

void register_cpu_backends() {
  register_cpu_scalar_backend();
  register_cpu_simd_backends();
  register_dacrt_backends();
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// backends.h — the backends a test runs on: every backend built into this binary; one whose
// hardware this machine lacks (e.g. AVX-512) is skipped with the reason printed, and one that
// is built but cannot start for any other reason fails the test; an alias (`cpu`) is tested
// under the name it stands for. A peer without the robust contract (tinybvh: fast precision only)
// is left out of these sweeps, which trace in robust precision; its own tests cover it.
#pragma once
#include <catch2/catch.hpp>

#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <nlohmann/json.hpp>

#include "host/tools/variants.h"
#include "mbvh/backend.h"
#include "tests/helpers.h"

namespace mbvh_test {

/// MBVH_TEST_BACKENDS (comma-separated names), when set, narrows the tests to those backends:
/// scripts/test reruns the cpu backend's tests with AVX-512 turned off that way.
inline bool backend_selected(const std::string& name) {
  const char* only = std::getenv("MBVH_TEST_BACKENDS");
  if (!only || !*only) return true;
  const std::string list = std::string(",") + only + ",";
  return list.find("," + name + ",") != std::string::npos;
}

inline mbvh::VariantGrid all_backends() {
  mbvh::VariantGrid g;
  g.backends.clear();
  std::vector<std::string> left_out;
  for (const std::string& name : mbvh::runnable_backends(&left_out)) {
    if (!backend_selected(name)) {
      std::printf("backend %s left out: not in MBVH_TEST_BACKENDS\n", name.c_str());
      continue;
    }
    INFO("backend " << name);
    std::unique_ptr<mbvh::Backend> b;
    REQUIRE_NOTHROW(b = mbvh::make_backend(name));
    if (!b->supports_precision(mbvh::Precision::robust)) {  // a peer without the contract (tinybvh):
      std::printf("backend %s left out: no robust precision (a peer tested on its own)\n", name.c_str());
      continue;  // tests/test_peer_tinybvh.cpp
    }
    g.backends.push_back(name);
  }
  for (const std::string& why : left_out) std::printf("backend left out: %s\n", why.c_str());
  REQUIRE(!g.backends.empty());
  return g;
}

/// all_backends() for the [sanitizer-cpu] tier (the largest stress and range tests): under the sanitizers
/// (mbvh_test::sanitized()) the instrumented cpu backends only (cpu-scalar and the cpu backend of this
/// machine's ISA, those MBVH_TEST_BACKENDS selects): the device backends' traversals run in PoCL's
/// and lavapipe's own code, which the sanitizers do not see, and their host code runs in every other
/// test; elsewhere every backend.
inline mbvh::VariantGrid sanitizer_cpu_backends() {
  mbvh::VariantGrid g = all_backends();
  if (!sanitized()) return g;
  std::vector<std::string> cpu;
  for (const std::string& name : g.backends)
    if (name.rfind("cpu-", 0) == 0) cpu.push_back(name);
    else std::printf("backend %s left out: a [sanitizer-cpu] test under the sanitizers\n", name.c_str());
  REQUIRE(!cpu.empty());
  g.backends = cpu;
  return g;
}

/// The SIMD cpu backends this machine runs (cpu-avx2, cpu-avx512; MBVH_TEST_BACKENDS narrows them):
/// the backends with a single-ray query (RayQuery), so the ones instancing traces on too.
inline std::vector<std::string> simd_cpu_backends() {
  std::vector<std::string> names;
  for (const std::string& n : mbvh::runnable_backends())
    if (n.rfind("cpu-avx", 0) == 0 && backend_selected(n)) names.push_back(n);
  return names;
}

/// The backends of this run that have the MIC path (`cpu.mic`: the AVX-512 kernels, cpu-avx512):
/// none on a machine without AVX-512, or where MBVH_CPU_ISA or MBVH_TEST_BACKENDS leaves it out —
/// each time with the reason printed (missing hardware is a skip, not a failure).
inline std::vector<std::string> mic_backends() {
  std::vector<std::string> names;
  for (const mbvh::BackendInfo& b : mbvh::list_backends()) {
    if (b.name != "cpu-avx512") continue;
    const std::string why = !b.make ? b.unavailable : b.missing_hardware ? b.missing_hardware() : std::string();
    if (!why.empty()) std::printf("MIC path (cpu.mic) skipped: cpu-avx512: %s\n", why.c_str());
    else if (!backend_selected(b.name)) std::printf("MIC path (cpu.mic) skipped: cpu-avx512 is not in MBVH_TEST_BACKENDS\n");
    else names.push_back(b.name);
  }
  return names;
}

/// `o` with the backend's own traversal where it has none of the hierarchy's (dacrt, which traces
/// the triangles without one): a test written for the hierarchy's traversals runs such a backend on
/// its own, which gives the reference's answers (up to the classified ties of another visit order).
inline mbvh::TraceOptions own_traversal(const mbvh::Backend& b, mbvh::TraceOptions o) {
  if (!b.supports(o.layout, o.traversal) && b.supports(o.layout, mbvh::Traversal::dacrt)) o.traversal = mbvh::Traversal::dacrt;
  return o;
}

/// `g` with the packet traversals added (cpu-scalar traces them as their stack twin, the SIMD
/// cpu backends as packets; the other backends do not have them).
inline mbvh::VariantGrid with_packets(mbvh::VariantGrid g) {
  g.traversals.push_back(mbvh::Traversal::packet_ranged);
  g.traversals.push_back(mbvh::Traversal::packet_partition);
  return g;
}

/// Backend options that make the SIMD cpu backends trace every packet as a packet (no hybrid
/// switch to single rays): the stress tests' adversarial rays are incoherent.
inline mbvh::BackendOptions packets_always() { return mbvh::BackendOptions{}.set("cpu.packet-hybrid", "0"); }

/// The device flag of a device backend, through the real program: `--FLAG GOOD` traces and
/// prints PRINTED (the choice); a name that matches nothing fails with an error that lists the
/// devices, LISTED among them.
inline void check_device_flag(const std::string& backend, const std::string& flag, const std::string& good,
                              const std::string& printed, const std::string& api, const std::string& listed) {
  const auto ok = run_cli("trace gen:cube:4 --count 100 --backend " + backend + " " + flag + " " + good);
  INFO(ok.output);
  CHECK(ok.code == 0);
  CHECK(ok.output.find(printed) != std::string::npos);
  CHECK(ok.output.find("error") == std::string::npos);
  const auto bad = run_cli("trace gen:cube:4 --count 100 --backend " + backend + " " + flag + " no-such-device");
  INFO(bad.output);
  CHECK(bad.code == 2);
  CHECK(bad.output.find("no " + api + " device matches ") != std::string::npos);
  CHECK(bad.output.find(flag + ") 'no-such-device'; the devices are:") != std::string::npos);
  CHECK(bad.output.find(listed) != std::string::npos);
}

/// `backend` gives the reference's bytes on `rays` for each traversal of `layout`, closest and any hit.
inline void check_against_reference(mbvh::Backend& backend, const mbvh::Accel& acc, const std::vector<mbvh::Ray>& rays,
                                    mbvh::Layout layout, std::initializer_list<mbvh::Traversal> traversals) {
  using namespace mbvh;
  for (Traversal t : traversals)
    for (Query q : {Query::closest, Query::any}) {
      INFO(backend.name() << " " << to_string(layout) << " " << to_string(t) << " " << to_string(q));
      const TraceOptions o{layout, t, q, false};
      TraceOutput ref, got;
      trace_reference(acc, rays, o, ref, 0);
      backend.trace(acc, rays, o, got);
      if (q == Query::closest) {
        REQUIRE(got.hits.size() == rays.size());
        CHECK(std::memcmp(ref.hits.data(), got.hits.data(), rays.size() * sizeof(Hit)) == 0);
      } else {
        CHECK(got.occluded == ref.occluded);
      }
    }
}

/// `mbvh bench --backend cpu,BACKEND ARGS --json`: `records` records, all verified, with the
/// traversal state, and BACKEND's (`expected` of them) with a ratio to cpu, a device line
/// containing each of `device_words` and a device-clock speed no lower than the end-to-end one
/// (cpu's: none), shown in the table's "dev Mr/s" column.
inline void check_bench_beside_cpu(const std::string& backend, const std::string& args, std::size_t records,
                                   std::size_t expected, std::initializer_list<const char*> device_words) {
  TempDir dir;
  const std::string json = dir.file("b.json");
  const auto r = run_cli("bench gen:soup:20000 --count 5000 --warmup 0 --kinds primary --backend cpu," + backend + " " + args +
                         " --query closest,any --json " + json);
  INFO(r.output);
  REQUIRE(r.code == 0);
  CHECK_THAT(r.output, Catch::Contains("dev Mr/s"));
  const auto j = nlohmann::json::parse(std::ifstream(json));
  REQUIRE(j["records"].size() == records);
  std::size_t mine = 0;
  for (const auto& rec : j["records"]) {
    CHECK(rec["verify_mismatches"].get<int>() == 0);
    CHECK(rec["state_bytes_per_ray"].get<int>() == (rec["traversal"] == "stack" ? 264 : 12));
    CHECK(rec["nodes_per_ray"].get<double>() > 0);
    if (rec["backend"] == "cpu") {
      CHECK((rec["isa"] == "avx512" || rec["isa"] == "avx2"));  // the best this CPU has
      CHECK(rec["device_mrays_per_s"].is_null());             // no device clock to read
    }
    if (rec["backend"] == backend) {
      ++mine;
      CHECK(rec["vs_cpu"].get<double>() > 0);
      // the device time (the trace kernels alone) is part of the end-to-end time: no slower
      REQUIRE(rec["device_mrays_per_s"].is_number());
      CHECK(rec["device_mrays_per_s"].get<double>() > 0);
      CHECK(rec["device_mrays_per_s"].get<double>() >= rec["mrays_per_s"].get<double>());
      for (const char* w : device_words) CHECK(rec["device"].get<std::string>().find(w) != std::string::npos);
    }
  }
  CHECK(mine == expected);
}

}  // namespace mbvh_test

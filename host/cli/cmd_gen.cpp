// SPDX-License-Identifier: MIT
// cmd_gen.cpp — `mbvh gen`: write a scene's triangles to a .mtri file, a large generated one
// streamed (gen:mandelbulb:RES[:K]) without ever holding it.
#include <cctype>
#include <chrono>

#include "host/cli/commands.h"
#include "host/core/io/mtri.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "host/tools/resident.h"

namespace mbvh::cli {

namespace {

struct GenArgs {
  std::string source, out;
  unsigned threads = 0;
};

int run_gen(const GenArgs& a) {
  const std::string lower = [&] {
    std::string s = a.out;
    for (char& c : s) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    return s;
  }();
  if (lower.size() < 6 || lower.compare(lower.size() - 5, 5, ".mtri") != 0)
    throw Error("-o " + a.out + ": the output is a .mtri file and must be named NAME.mtri (scenes are told apart by their names)");
  const OutputTarget out{"-o", a.out};
  prepare_outputs({out}, {{"source", a.source}});
  const auto t0 = std::chrono::steady_clock::now();
  const MtriWritten w = write_mtri(a.source, out, a.threads);
  const double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  say("wrote %llu triangles (%s) to %s in %.2f s on %u threads\n", static_cast<unsigned long long>(w.count),
      format_bytes(w.bytes).c_str(), a.out.c_str(), s, resolve_threads(a.threads));
  say("bounds [%g %g %g] .. [%g %g %g], content hash %016llx\n", static_cast<double>(w.bounds.lo.x),
      static_cast<double>(w.bounds.lo.y), static_cast<double>(w.bounds.lo.z), static_cast<double>(w.bounds.hi.x),
      static_cast<double>(w.bounds.hi.y), static_cast<double>(w.bounds.hi.z), static_cast<unsigned long long>(w.hash));
  const std::int64_t peak = status_bytes("VmHWM:");
  say("%s; peak resident memory %s%s\n", w.streamed ? "streamed" : "loaded in core, then written",
      peak < 0 ? "unknown" : format_bytes(static_cast<std::uint64_t>(peak)).c_str(),
      w.buffer_bytes ? (", the largest slab " + format_bytes(w.buffer_bytes)).c_str() : "");
  return 0;
}

}  // namespace

Command add_gen(CLI::App& app) {
  auto a = std::make_shared<GenArgs>();
  auto* c = app.add_subcommand("gen", "write a scene's triangles to a .mtri file (gen:mandelbulb:RES[:K] streamed, "
                                      "never held whole; the same bytes at any --threads)");
  c->add_option("source", a->source, "gen:mandelbulb:RES[:K], any other gen: spec, or a scene file")->required();
  c->add_option("-o,--output", a->out, "the .mtri file to write")->required();
  c->add_option("--threads", a->threads, "worker threads (0 = all hardware threads)")->check(integer_in(0, kMaxThreads));
  return {c, [a] { return run_gen(*a); }};
}

}  // namespace mbvh::cli

// SPDX-License-Identifier: MIT
// cmd_lod.cpp — `mbvh lod`: the out-of-core LOD model (mbvh/lod.h; docs/massive.md): `lod build`
// writes a .mlod from any triangle source, `lod info` prints its header, `lod check`
// (cmd_lod_check.cpp) checks its full-detail answers against the in-core reference.
#include <sys/stat.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>

#include <nlohmann/json.hpp>

#include "host/cli/commands.h"
#include "host/cli/progress.h"
#include "host/core/lod/cache.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "host/tools/resident.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

namespace {

struct LodBuildArgs {
  std::string source, out, memory, block = "256K", temp, quality = "medium";
  int zstd_level = 3;
  unsigned threads = 0;
};

CLI::Validator size_check() {
  return CLI::Validator(
      [](std::string& v) {
        std::uint64_t b = 0;
        return parse_size(v, b) ? std::string() : "'" + v + "' is not a size (bytes, or with a K, M, G or T suffix, e.g. 8G)";
      },
      "SIZE");
}

int run_lod_build(const LodBuildArgs& a) {
  std::string lower = a.out;
  for (char& c : lower) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (lower.size() < 6 || lower.compare(lower.size() - 5, 5, ".mlod") != 0)
    throw Error("-o " + a.out + ": the output is a .mlod model and must be named NAME.mlod");
  prepare_outputs({OutputTarget{"-o", a.out}}, {{"source", a.source}});
  lod::BuildOptions o;
  if (!a.memory.empty()) parse_size(a.memory, o.memory_budget);  // checked by the option's validator
  std::uint64_t block = 0;
  parse_size(a.block, block);
  if (block < (16u << 10) || block > (256u << 20)) throw Error("--block " + a.block + ": a block must be 16K to 256M");
  o.block_bytes = static_cast<unsigned>(block);
  o.zstd_level = a.zstd_level;
  o.temp_dir = a.temp;
  o.threads = a.threads;
  o.tree.quality = parse_quality(a.quality);
  o.tree.threads = a.threads;
  if (!a.temp.empty()) {
    struct stat st {};
    if (::stat(a.temp.c_str(), &st) != 0 || !S_ISDIR(st.st_mode)) throw Error("--temp " + a.temp + ": not a directory");
  }
  // the time of each phase, for the report
  std::vector<std::pair<std::string, double>> phases;
  auto t_phase = std::chrono::steady_clock::now();
  std::unique_ptr<Progress> bar;  // on a terminal: one bar a phase
  o.progress = [&](const std::string& phase, double f) {
    if (phases.empty() || phases.back().first != phase) {
      const auto now = std::chrono::steady_clock::now();
      if (!phases.empty()) phases.back().second = std::chrono::duration<double>(now - t_phase).count();
      t_phase = now;
      phases.emplace_back(phase, 0.0);
      if (bar) bar->finish();
      bar = phase == "done" ? nullptr : std::make_unique<Progress>("lod build: " + phase, 1000);
    }
    if (bar) bar->update(static_cast<std::size_t>(std::clamp(f, 0.0, 1.0) * 1000));
  };
  const auto src = lod::open_triangles(a.source, a.threads);
  const lod::BuildReport r = lod::build(*src, a.out, o);
  if (bar) bar->finish();
  bar.reset();
  std::string times;
  for (const auto& [name, s] : phases)
    if (name != "done") {
      char t[64];
      std::snprintf(t, sizeof t, "%.2f s", s);
      times += (times.empty() ? "" : ", ") + name + " " + t;
    }
  say("wrote %s: %llu triangles in %llu bucket%s, %llu nodes, %llu voxels, %llu treelets in %llu blocks, depth %u\n",
      a.out.c_str(), static_cast<unsigned long long>(r.triangles), static_cast<unsigned long long>(r.buckets),
      r.buckets == 1 ? "" : "s", static_cast<unsigned long long>(r.nodes), static_cast<unsigned long long>(r.voxels),
      static_cast<unsigned long long>(r.treelets), static_cast<unsigned long long>(r.blocks), r.depth);
  say("raw %s, file %s (compression %.2fx), pinned %s; %.2f s on %u threads\n", format_bytes(r.raw_bytes).c_str(),
      format_bytes(r.file_bytes).c_str(), r.file_bytes ? static_cast<double>(r.raw_bytes) / static_cast<double>(r.file_bytes) : 0.0,
      format_bytes(r.pinned_bytes).c_str(), r.seconds, resolve_threads(a.threads));
  say("phases: %s\n", times.c_str());
  const std::int64_t peak = status_bytes("VmHWM:");
  say("peak resident memory %s (budget %s)\n", peak < 0 ? "unknown" : format_bytes(static_cast<std::uint64_t>(peak)).c_str(),
      o.memory_budget ? format_bytes(o.memory_budget).c_str() : "the available memory");
  return 0;
}

Command add_lod_build(CLI::App& lod) {
  auto a = std::make_shared<LodBuildArgs>();
  auto* c = lod.add_subcommand("build", "build a .mlod model from SOURCE (.mtri, a scene file or a gen: spec) within --memory");
  c->add_option("source", a->source, "a .mtri file, gen:mandelbulb:RES[:K] (streamed), or any scene file or gen: spec (loaded)")
      ->required();
  c->add_option("-o,--output", a->out, "the .mlod file to write")->required();
  c->add_option("--memory", a->memory,
                "the memory the build may hold (bytes, or K, M, G, T); beyond one in-core build the model is cut into "
                "buckets through a temporary file (default: MBVH_MEMORY_LIMIT, else the available memory)")
      ->check(size_check());
  c->add_option("--block", a->block, "the largest uncompressed block (16K to 256M)")->check(size_check());
  c->add_option("--zstd-level", a->zstd_level, "zstd level of the blocks (1 to 19)")->check(integer_in(1, 19));
  c->add_option("--temp", a->temp, "directory of the temporary bucket file (default: the output's directory)");
  c->add_option("--threads", a->threads, "worker threads (0 = all hardware threads); the file does not depend on it")
      ->check(integer_in(0, kMaxThreads));
  c->add_option("--quality", a->quality, "the buckets' builder: low (LBVH) or medium (binned SAH)")
      ->check(CLI::IsMember({"low", "medium"}));
  return {c, [a] { return run_lod_build(*a); }};
}


struct LodInfoArgs {
  std::string model, json;
};

// `lod info`: the header, albedo table and directory are read and checked as the block cache
// reads them (lod::read_model_file); no block is loaded.
int run_lod_info(const LodInfoArgs& a) {
  prepare_outputs({{"--json", a.json, true}}, {{"model", a.model}});
  const lod::ModelFile f = lod::read_model_file(a.model);
  const lod::format::FileHeader& h = f.header;
  const std::uint64_t minimum = lod::minimum_budget(h);
  std::uint64_t stored = 0;
  unsigned max_depth = 0;
  for (const lod::format::DirEntry& e : f.directory) {
    stored += e.stored_bytes;
    max_depth = std::max<unsigned>(max_depth, e.depth);
  }
  const double ratio = stored ? double(h.raw_bytes) / double(stored) : 0;
  const auto count = [](std::uint64_t x) {  // 1234567 -> "1,234,567"
    const std::string d = std::to_string(x);
    std::string s;
    for (std::size_t i = 0; i < d.size(); ++i) {
      if (i > 0 && (d.size() - i) % 3 == 0) s += ',';
      s += d[i];
    }
    return s;
  };
  const auto bytes = [&](std::uint64_t x) { return count(x) + " bytes" + (x < 1024 ? "" : " (" + format_bytes(x) + ")"); };
  char hash[32];
  std::snprintf(hash, sizeof hash, "%016llx", static_cast<unsigned long long>(h.source_hash));
  say("%s: .mlod version %u (mbvh %u.%u.%u)\n", a.model.c_str(), h.version, h.library_version >> 16,
      (h.library_version >> 8) & 0xff, h.library_version & 0xff);
  const std::uint64_t degenerate = h.triangles - h.tri_records;
  const std::string rest = degenerate ? ", " + count(degenerate) + " degenerate: in none" : "";
  say("triangles        %s (%s in leaves%s)\n", count(h.triangles).c_str(), count(h.tri_records).c_str(), rest.c_str());
  say("nodes            %s (voxels %s, links %s)\n", count(h.nodes).c_str(), count(h.voxels).c_str(), count(h.links).c_str());
  say("blocks           %s (treelets %s, block depth up to %u)\n", count(h.blocks).c_str(), count(h.treelets).c_str(), max_depth);
  say("depth            %u binary levels\n", h.depth);
  say("bounds           (%g, %g, %g) .. (%g, %g, %g)\n", double(h.bounds[0]), double(h.bounds[1]), double(h.bounds[2]),
      double(h.bounds[3]), double(h.bounds[4]), double(h.bounds[5]));
  say("block_bytes      %s\n", bytes(h.block_bytes).c_str());
  say("raw bytes        %s\n", bytes(h.raw_bytes).c_str());
  say("stored bytes     %s (zstd; compression ratio raw / stored %.2f)\n", bytes(stored).c_str(), ratio);
  say("file bytes       %s\n", bytes(h.file_bytes).c_str());
  say("pinned           %s block%s, %s\n", count(h.pinned_blocks).c_str(), h.pinned_blocks == 1 ? "" : "s",
      bytes(h.pinned_bytes).c_str());
  say("minimum budget   %s (pinned + 2 x block_bytes, or the raw bytes if fewer)\n", bytes(minimum).c_str());
  say("albedos          %s\n", count(h.albedos).c_str());
  say("source hash      %s\n", hash);
  if (!a.json.empty()) {
    nlohmann::json j;
    j["path"] = a.model;
    j["version"] = h.version;
    j["library_version"] = std::to_string(h.library_version >> 16) + "." + std::to_string((h.library_version >> 8) & 0xff) + "." +
                           std::to_string(h.library_version & 0xff);
    j["triangles"] = h.triangles;
    j["tri_records"] = h.tri_records;
    j["nodes"] = h.nodes;
    j["voxels"] = h.voxels;
    j["links"] = h.links;
    j["blocks"] = h.blocks;
    j["treelets"] = h.treelets;
    j["block_depth"] = max_depth;
    j["depth"] = h.depth;
    j["bounds"] = {{"lo", {h.bounds[0], h.bounds[1], h.bounds[2]}}, {"hi", {h.bounds[3], h.bounds[4], h.bounds[5]}}};
    j["block_bytes"] = h.block_bytes;
    j["raw_bytes"] = h.raw_bytes;
    j["stored_bytes"] = stored;
    j["file_bytes"] = h.file_bytes;
    j["compression_ratio"] = ratio;
    j["pinned_blocks"] = h.pinned_blocks;
    j["pinned_bytes"] = h.pinned_bytes;
    j["minimum_budget"] = minimum;
    j["albedos"] = h.albedos;
    j["source_hash"] = hash;
    const std::string text = j.dump(2) + "\n";
    write_bytes_to({"--json", a.json, true}, text.data(), text.size());
  }
  return 0;
}

Command add_lod_info(CLI::App& lod) {
  auto a = std::make_shared<LodInfoArgs>();
  auto* c = lod.add_subcommand("info", "print a .mlod model's counts, sizes and pinned bytes");
  c->add_option("model", a->model, "the .mlod file")->required();
  c->add_option("--json", a->json, "also write them as JSON ('-': standard output)");
  return {c, [a] { return run_lod_info(*a); }};
}

}  // namespace

Command add_lod(CLI::App& app) {
  auto* lod = app.add_subcommand("lod", "out-of-core LOD models (.mlod): build, info, check");
  lod->require_subcommand(1);
  auto subs = std::make_shared<std::vector<Command>>(
      std::vector<Command>{add_lod_build(*lod), add_lod_info(*lod), add_lod_check(*lod)});
  return {lod, [subs] {
            for (const Command& c : *subs)
              if (*c.app) return c.run();
            return 2;
          }};
}

}  // namespace mbvh::cli

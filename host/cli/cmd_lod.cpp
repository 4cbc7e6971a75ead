// SPDX-License-Identifier: MIT
// cmd_lod.cpp — `mbvh lod`: the out-of-core LOD model (mbvh/lod.h; docs/massive.md): `lod build`
// writes a .mlod from any triangle source, `lod info` prints its header, `lod check`
// (cmd_lod_check.cpp) checks its full-detail answers against the in-core reference.
#include <nlohmann/json.hpp>

#include "host/cli/commands.h"
#include "host/core/lod/cache.h"
#include "host/core/resources.h"
#include "mbvh/lod.h"

namespace mbvh::cli {

namespace {

// TODO(lod build, lod info): the builder's helper fills these in.
Command add_lod_build(CLI::App& lod) {
  auto* c = lod.add_subcommand("build", "build a .mlod model from SOURCE (.mtri, a scene file or a gen: spec) within --memory");
  return {c, [] { throw Error("lod build: not built yet"); return 2; }};
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

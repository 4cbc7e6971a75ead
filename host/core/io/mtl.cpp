// SPDX-License-Identifier: MIT
// mtl.cpp — the MTL reader (mtl.h): `newmtl` and `Kd r [g b]` lines; every other statement of
// the format (Ka, Ks, Ns, maps, illum, ...) is skipped, since the renderer is diffuse only.
// Problems are warnings, never errors: a scene without its colours still renders, in grey.
#include "host/core/io/mtl.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <string_view>
#include <unordered_map>

#include "mbvh/error.h"
#include "mbvh/log.h"

namespace mbvh {
namespace {

std::string_view trim(std::string_view v) {
  const auto space = [](char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; };
  while (!v.empty() && space(v.front())) v.remove_prefix(1);
  while (!v.empty() && space(v.back())) v.remove_suffix(1);
  return v;
}

// The first problem of one library and how many there were: one warning line per file.
struct Problems {
  std::string first;
  std::size_t count = 0;
  void add(const std::string& where, const std::string& what) {
    if (count++ == 0) first = where + ": " + what;
  }
};

// A Kd line's values: "r", "r g b" (the MTL format's g and b default to r). False for anything
// else (spectral or xyz forms, bad or negative numbers).
bool parse_kd(std::string_view v, Vec3f& out) {
  float c[3];
  int n = 0;
  while (!(v = trim(v)).empty()) {
    if (n == 3) return false;
    const std::size_t end = std::min(v.find_first_of(" \t"), v.size());
    const auto r = std::from_chars(v.data(), v.data() + end, c[n]);
    if (r.ec != std::errc() || r.ptr != v.data() + end || !std::isfinite(c[n]) || c[n] < 0) return false;
    ++n;
    v.remove_prefix(end);
  }
  if (n != 1 && n != 3) return false;
  if (n == 1) c[1] = c[2] = c[0];
  out = {std::min(c[0], 1.0f), std::min(c[1], 1.0f), std::min(c[2], 1.0f)};
  return true;
}

// Reads one library's materials into `kd`: every `newmtl` name, grey unless a valid Kd follows
// (the first definition of a name wins, in the libraries' order).
void read_library(const std::string& path, std::unordered_map<std::string, Vec3f>& kd, Problems& problems) {
  const std::vector<char> data = read_file(path);
  const std::string_view text(data.data(), data.size());
  Vec3f* current = nullptr;  // the colour the next Kd sets (null: none, or a name defined before)
  bool have = false;         // a newmtl seen
  std::size_t line = 0;
  for (std::size_t at = 0; at < text.size();) {
    const std::size_t nl = std::min(text.find('\n', at), text.size());
    const std::string_view l = trim(text.substr(at, nl - at));
    at = nl + 1;
    ++line;
    if (l.empty() || l.front() == '#') continue;
    const std::size_t ke = std::min(l.find_first_of(" \t"), l.size());
    const std::string_view key = l.substr(0, ke), rest = trim(l.substr(ke));
    if (key == "newmtl") {
      const auto [it, fresh] = kd.try_emplace(std::string(rest), Material{}.diffuse);
      current = fresh ? &it->second : nullptr;
      have = true;
    } else if (key == "Kd") {
      Vec3f c;
      if (!have) problems.add(path + ":" + std::to_string(line), "Kd before any newmtl");
      else if (!parse_kd(rest, c))
        problems.add(path + ":" + std::to_string(line), "Kd '" + std::string(rest.substr(0, 40)) +
                                                            "' is not 1 or 3 non-negative numbers");
      else if (current) *current = c;
    }
  }
}

}  // namespace

void read_materials(Scene& s, const std::string& obj_path, const std::vector<ObjParser::Library>& libraries) {
  if (s.materials.empty()) return;
  const std::string who = s.display_name();
  if (libraries.empty()) {
    log_message(LogLevel::warning, who + ": uses " + std::to_string(s.materials.size()) +
                                       " materials but names no mtllib: they render grey");
    return;
  }
  // -- every library's Kd colours, missing and unreadable ones warned about
  std::unordered_map<std::string, Vec3f> kd;
  bool read_any = false;  // a library was read: names it lacks are worth a warning
  const std::filesystem::path dir = std::filesystem::path(obj_path).parent_path();
  for (const ObjParser::Library& lib : libraries) {
    const std::string where = who + ":" + std::to_string(lib.line);
    std::string path = (dir / lib.file).string();
    std::error_code ec;
    if (!std::filesystem::is_regular_file(path, ec) && std::filesystem::is_regular_file(path + ".zst", ec)) path += ".zst";
    if (!std::filesystem::is_regular_file(path, ec)) {
      log_message(LogLevel::warning, where + ": material library '" + lib.file + "' not found (looked for " + path +
                                         "): its materials render grey");
      continue;
    }
    Problems problems;
    try {
      read_library(path, kd, problems);
    } catch (const Error& e) {
      log_message(LogLevel::warning, where + ": material library '" + lib.file + "' unreadable (" + e.what() +
                                         "): its materials render grey");
      continue;
    }
    read_any = true;
    if (problems.count)
      log_message(LogLevel::warning, problems.first +
                                         (problems.count > 1 ? " (and " + std::to_string(problems.count - 1) + " more)" : "") +
                                         ": those materials render grey");
  }
  // -- the colours of the scene's materials; the names no library defines stay grey
  std::size_t undefined = 0;
  std::string first;
  for (Material& m : s.materials) {
    if (const auto it = kd.find(m.name); it != kd.end()) m.diffuse = it->second;
    else if (undefined++ == 0) first = m.name;
  }
  if (undefined && read_any)
    log_message(LogLevel::warning, who + ": " + std::to_string(undefined) + " of " + std::to_string(s.materials.size()) +
                                       " materials are in no material library (the first: '" + first + "'): they render grey");
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// helpers.h — shared test utilities: scene paths, temporary files, running the mbvh program.
#pragma once
#include <array>
#include <cstddef>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <exception>
#include <fstream>
#include <iterator>
#include <string>
#include <type_traits>

namespace mbvh_test {

// The facts of the build the tests run in (tests/build_config.cpp, compiled in each build: the
// other test files are the same objects in every build of the same sources, so the sanitizer
// build can link the Release build's, MBVH_TEST_OBJECTS_FROM in CMakeLists.txt).
/// The mbvh program of this build.
const char* built_cli_path();
/// The shared scenes' directory (../shared/scenes beside the sources).
const char* scenes_dir();
/// True in a build with the sanitizers (MBVH_SANITIZE): tests that trace many rays trace fewer.
bool sanitized();

/// A ray count for a test that traces many: under the sanitizers a quarter of `n` (at least
/// 1,000): more rays take no other code path there, only minutes.
inline std::size_t sanitized_rays(std::size_t n) {
  return sanitized() ? std::max<std::size_t>(n / 4, std::min<std::size_t>(n, 1000)) : n;
}

/// What `f()` throws as an Error (any type with what(): mbvh::Error), or "(no error)".
template <class F>
std::string error_of(F f) {
  try {
    f();
  } catch (const std::exception& e) {
    return e.what();
  }
  return "(no error)";
}

/// The bytes of the file at `path` (empty if it cannot be read).
inline std::string bytes_of(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), std::istreambuf_iterator<char>()};
}

/// Writes `bytes` to `path`, replacing it.
inline void put(const std::string& path, const std::string& bytes) { std::ofstream(path, std::ios::binary) << bytes; }

/// Whether triangle `prim` of `s` has zero area (its edges' cross product, in double, is zero):
/// a degenerate triangle, which a build keeps out of its leaves. Scene: any type with
/// triangle(prim, a, b, c) (mbvh::Scene).
template <class Scene>
bool zero_area(const Scene& s, std::size_t prim) {
  std::decay_t<decltype(s.vertices[0])> a{}, b{}, c{};
  s.triangle(prim, a, b, c);
  const double e1[3] = {double(b.x) - a.x, double(b.y) - a.y, double(b.z) - a.z};
  const double e2[3] = {double(c.x) - a.x, double(c.y) - a.y, double(c.z) - a.z};
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  return n[0] == 0 && n[1] == 0 && n[2] == 0;
}

inline std::string scene_path(const std::string& file) { return std::string(scenes_dir()) + "/" + file; }

/// A fresh temporary directory for one test, removed at scope exit.
struct TempDir {
  std::filesystem::path path;
  TempDir() {
    char tmpl[] = "/tmp/mbvh-test-XXXXXX";
    path = mkdtemp(tmpl);
  }
  ~TempDir() { std::filesystem::remove_all(path); }
  std::string file(const std::string& name) const { return (path / name).string(); }
  std::string write(const std::string& name, const std::string& bytes) const {
    std::ofstream(file(name), std::ios::binary) << bytes;
    return file(name);
  }
};

/// The mbvh program the CLI tests run: this build's, or the environment's MBVH_TEST_CLI (to run
/// the same tests against another build, e.g. an older one).
inline std::string cli_path() {
  const char* other = std::getenv("MBVH_TEST_CLI");
  return other && *other ? other : built_cli_path();
}

struct RunResult {
  int code = -1;
  std::string output;  // stdout and stderr
};

/// Runs a shell command line, capturing its standard output and standard error.
inline RunResult run_shell(const std::string& command) {
  RunResult r;
  FILE* p = popen((command + " 2>&1").c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  std::size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

/// Runs the mbvh program with `args` (a shell fragment), capturing its output; `env` (e.g.
/// "OCL_ICD_VENDORS=/x") is set for that run only. With `timeout_s` > 0 a run that takes longer
/// is killed and returns code 124 (a hang becomes a failure, not a stuck test).
inline RunResult run_cli(const std::string& args, const std::string& env = "", int timeout_s = 0) {
  return run_shell((timeout_s > 0 ? "timeout -k 5 " + std::to_string(timeout_s) + " " : std::string()) +
                   (env.empty() ? "" : "env " + env + " ") + cli_path() + " " + args);
}

}  // namespace mbvh_test

// helpers.h — shared test utilities: scene paths, temporary files, running the mbvh program.
#pragma once
#include <array>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <string>

namespace mbvh_test {

inline std::string scene_path(const std::string& file) { return std::string(MBVH_SCENES_DIR) + "/" + file; }

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

struct RunResult {
  int code = -1;
  std::string output;  // stdout and stderr
};

/// Runs the mbvh program with `args` (a shell fragment), capturing its output; `env` (e.g.
/// "OCL_ICD_VENDORS=/x") is set for that run only. With `timeout_s` > 0 a run that takes longer
/// is killed and returns code 124 (a hang becomes a failure, not a stuck test).
inline RunResult run_cli(const std::string& args, const std::string& env = "", int timeout_s = 0) {
  RunResult r;
  const std::string cmd = (timeout_s > 0 ? "timeout -k 5 " + std::to_string(timeout_s) + " " : std::string()) +
                          (env.empty() ? "" : "env " + env + " ") + std::string(MBVH_CLI_PATH) + " " + args + " 2>&1";
  FILE* p = popen(cmd.c_str(), "r");
  if (!p) return r;
  std::array<char, 4096> buf;
  std::size_t n;
  while ((n = std::fread(buf.data(), 1, buf.size(), p)) > 0) r.output.append(buf.data(), n);
  const int status = pclose(p);
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

}  // namespace mbvh_test

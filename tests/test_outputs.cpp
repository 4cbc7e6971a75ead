// SPDX-License-Identifier: MIT
// test_outputs.cpp — outputs never destroy anything: only regular files are replaced (never a
// FIFO, socket, directory or device node), symlinks are followed, the mode is kept, temporaries are
// unique and removed on errors and on SIGTERM, an output may not be an input, concurrent writers
// leave one complete file, write errors fail the run, and `-o -` is standard output. (Test names
// avoid ';', ',' and a leading '-': ctest passes them to Catch2 as a list item and an argument.)
#include <catch2/catch.hpp>

#include <fcntl.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/stat.h>
#include <sys/sysmacros.h>
#include <sys/un.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <set>
#include <thread>

#include "host/core/layouts.h"
#include "host/core/trace/traverse.h"
#include "mbvh/error.h"
#include "host/tools/raygen.h"
#include "tests/helpers.h"

using namespace mbvh;
using mbvh_test::run_cli;
using mbvh_test::TempDir;

namespace {

std::set<std::string> names_in(const TempDir& dir) {
  std::set<std::string> out;
  for (const auto& e : std::filesystem::directory_iterator(dir.path)) out.insert(e.path().filename().string());
  return out;
}

std::string slurp(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(f), {});
}

mode_t lmode(const std::string& path) {
  struct stat st {};
  REQUIRE(::lstat(path.c_str(), &st) == 0);
  return st.st_mode;
}

// A UNIX socket bound at `path` (kept open by the returned descriptor).
int make_socket(const std::string& path) {
  const int fd = ::socket(AF_UNIX, SOCK_STREAM, 0);
  REQUIRE(fd >= 0);
  sockaddr_un a{};
  a.sun_family = AF_UNIX;
  REQUIRE(path.size() < sizeof a.sun_path);
  std::memcpy(a.sun_path, path.c_str(), path.size() + 1);
  REQUIRE(::bind(fd, reinterpret_cast<const sockaddr*>(&a), sizeof a) == 0);
  return fd;
}

// Runs a shell script (the mbvh program as "$M"), output captured.
mbvh_test::RunResult run_sh(const std::string& script) {
  return mbvh_test::run_shell("M=" + mbvh_test::cli_path() + " sh -c '" + script + "'");
}

}  // namespace

TEST_CASE("outputs replace only regular files: FIFO socket directory and device node are refused", "[outputs]") {
  TempDir dir;
  const std::vector<Hit> hits = {{1.5f, 0.25f, 0.5f, 7}};
  const std::string fifo = dir.file("fifo"), sock = dir.file("sock"), sub = dir.file("sub"), dev = dir.file("null");
  REQUIRE(::mkfifo(fifo.c_str(), 0644) == 0);
  const int sfd = make_socket(sock);
  std::filesystem::create_directory(sub);
  dir.write("sub/kept", "x");
  REQUIRE(::mknod(dev.c_str(), S_IFCHR | 0666, makedev(1, 3)) == 0);  // a null device, in the temp dir only
  for (const auto& [path, kind] : {std::pair{fifo, "a FIFO"}, std::pair{sock, "a socket"}, std::pair{sub, "a directory"},
                                   std::pair{dev, "a character device"}}) {
    INFO(path);
    CHECK_THROWS_WITH(write_hits(path, hits), Catch::Contains(path) && Catch::Contains(std::string("is ") + kind) &&
                                                  Catch::Contains("only regular files"));
  }
  CHECK(S_ISFIFO(lmode(fifo)));
  CHECK(S_ISSOCK(lmode(sock)));
  CHECK(S_ISDIR(lmode(sub)));
  CHECK(slurp(dir.file("sub/kept")) == "x");
  CHECK(S_ISCHR(lmode(dev)));
  CHECK(names_in(dir) == std::set<std::string>{"fifo", "sock", "sub", "null"});  // no temporary left
  ::close(sfd);

  // the program refuses them before any work, naming the option
  const auto r = run_cli("rays gen:sphere:16 --count 100 -o " + fifo);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("-o " + fifo + ": is a FIFO") && !Catch::Contains("BVH built"));
  CHECK(S_ISFIFO(lmode(fifo)));
  const auto j = run_cli("info gen:sphere:16 --json " + dev);
  CHECK(j.code == 2);
  CHECK_THAT(j.output, Catch::Contains("--json " + dev + ": is a character device"));
  CHECK(S_ISCHR(lmode(dev)));
  const auto p = run_cli("render gen:sphere:16 --width 8 --height 8 --spp 1 -o " + dir.file("a.png") + " --pfm " + sub);
  CHECK(p.code == 2);
  CHECK_THAT(p.output, Catch::Contains("--pfm " + sub + ": is a directory") && !Catch::Contains("rendered"));
  CHECK_FALSE(std::filesystem::exists(dir.file("a.png")));
}

TEST_CASE("a symlinked output replaces the regular file it names and keeps the link", "[outputs]") {
  TempDir dir;
  const std::vector<Hit> hits = {{1.5f, 0.25f, 0.5f, 7}};
  std::filesystem::create_directory(dir.file("real"));
  dir.write("real/h.hits", "old");
  std::filesystem::create_symlink(dir.file("real/h.hits"), dir.file("link.hits"));
  write_hits(dir.file("link.hits"), hits);
  CHECK(std::filesystem::is_symlink(dir.file("link.hits")));
  CHECK(read_hits(dir.file("real/h.hits")).size() == 1);
  CHECK(names_in(dir) == std::set<std::string>{"real", "link.hits"});
  // a link to nothing or to a FIFO is refused, and nothing is created through it
  std::filesystem::create_symlink(dir.file("real/none.hits"), dir.file("dangling.hits"));
  CHECK_THROWS_WITH(write_hits(dir.file("dangling.hits"), hits), Catch::Contains("symbolic link to a missing file"));
  CHECK_FALSE(std::filesystem::exists(dir.file("real/none.hits")));
  REQUIRE(::mkfifo(dir.file("real/fifo").c_str(), 0644) == 0);
  std::filesystem::create_symlink(dir.file("real/fifo"), dir.file("fifo.hits"));
  CHECK_THROWS_WITH(write_hits(dir.file("fifo.hits"), hits), Catch::Contains("symbolic link to a FIFO"));
  CHECK(S_ISFIFO(lmode(dir.file("real/fifo"))));
  CHECK(names_in(dir) == std::set<std::string>{"real", "link.hits", "dangling.hits", "fifo.hits"});
}

TEST_CASE("a replaced output keeps its mode and its temporaries are unique and touch no other file", "[outputs]") {
  TempDir dir;
  const std::vector<Hit> hits = {{1.5f, 0.25f, 0.5f, 7}};
  const std::string out = dir.write("h.hits", "old");
  REQUIRE(::chmod(out.c_str(), 0640) == 0);
  // a file named like a fixed temporary (another run's, or a user's) is not ours to touch
  dir.write("h.hits.partial", "someone else's");
  write_hits(out, hits);
  CHECK((lmode(out) & 07777) == 0640);
  CHECK(read_hits(out).size() == 1);
  CHECK(slurp(dir.file("h.hits.partial")) == "someone else's");
  CHECK(names_in(dir) == std::set<std::string>{"h.hits", "h.hits.partial"});
  // a new file gets 0666 less the umask
  const mode_t mask = ::umask(0);
  ::umask(mask);
  write_hits(dir.file("new.hits"), hits);
  CHECK((lmode(dir.file("new.hits")) & 07777) == (0666 & ~mask));
}

TEST_CASE("an output that is also an input is refused before any work", "[outputs][cli]") {
  TempDir dir;
  const std::string rays = dir.file("r.rays");
  REQUIRE(run_cli("rays gen:sphere:16 --count 500 -o " + rays).code == 0);
  const std::string before = slurp(rays);
  std::filesystem::create_symlink(rays, dir.file("alias.rays"));
  for (const std::string& out : {rays, dir.file("alias.rays"), dir.path.string() + "/./r.rays"}) {
    const auto r = run_cli("trace gen:sphere:16 --rays " + rays + " -o " + out);
    INFO(r.output);
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("-o " + out + " is also the input --rays " + rays) && !Catch::Contains("BVH built"));
  }
  CHECK(slurp(rays) == before);
  // the scene file, a render's reference, and two outputs naming one file
  const std::string scene = dir.write("tri.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  auto r = run_cli("info " + scene + " --json " + scene);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("is also the input scene " + scene));
  CHECK(slurp(scene) == "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n");
  const std::string ref = dir.file("ref.pfm");
  REQUIRE(run_cli("render gen:sphere:16 --width 8 --height 8 --spp 1 -o " + dir.file("a.png") + " --pfm " + ref).code == 0);
  const std::string ref_bytes = slurp(ref);
  r = run_cli("render gen:sphere:16 --width 8 --height 8 --spp 1 -o " + dir.file("b.png") + " --reference " + ref +
              " --pfm " + ref);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--pfm " + ref + " is also the input --reference " + ref));
  CHECK(slurp(ref) == ref_bytes);
  r = run_cli("bench gen:soup:1000 --count 100 --json " + dir.file("x") + " --csv " + dir.file("x"));
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--json " + dir.file("x") + " and --csv " + dir.file("x") + " name the same file") &&
                           !Catch::Contains("Mrays/s"));
  CHECK_FALSE(std::filesystem::exists(dir.file("x")));
  CHECK_FALSE(std::filesystem::exists(dir.file("b.png")));
}

TEST_CASE("standard output: -o - writes the output there and the report to standard error", "[outputs][cli]") {
  TempDir dir;
  const std::string file = dir.file("f.rays");
  REQUIRE(run_cli("rays gen:sphere:16 --count 700 --seed 3 -o " + file).code == 0);
  // stdout goes to s.rays, stderr to log: run in the temp dir, so a file named '-' would show
  auto r = run_sh("cd " + dir.path.string() + " && \"$M\" rays gen:sphere:16 --count 700 --seed 3 -o - >s.rays 2>log");
  CHECK(r.code == 0);
  CHECK(slurp(dir.file("s.rays")) == slurp(file));
  CHECK_THAT(slurp(dir.file("log")), Catch::Contains("wrote 700 primary rays (seed 3) to standard output"));
  CHECK_FALSE(std::filesystem::exists(dir.file("-")));
  r = run_sh("cd " + dir.path.string() + " && \"$M\" bench gen:soup:1000 --count 200 --warmup 0 --kinds primary --json - >b.json 2>log");
  CHECK(r.code == 0);
  const auto j = nlohmann::json::parse(slurp(dir.file("b.json")));  // pure JSON: the table went to stderr
  CHECK(j["records"].size() > 0);
  CHECK_THAT(slurp(dir.file("log")), Catch::Contains("Mrays/s"));
  // one output at most on standard output; binary formats never to a terminal
  r = run_cli("render gen:sphere:16 --width 8 --height 8 --spp 1 -o - --pfm -");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("-o - and --pfm - both go to standard output"));
  if (::access("/usr/bin/script", X_OK) == 0) {  // util-linux script(1) gives the program a terminal
    r = run_sh("cd " + dir.path.string() + " && script -qec \"$M rays gen:sphere:16 --count 10 -o -\" /dev/null");
    CHECK(r.code == 2);
    CHECK_THAT(r.output, Catch::Contains("refusing to write a binary format to a terminal"));
    CHECK_FALSE(std::filesystem::exists(dir.file("-")));
  } else {
    WARN("script(1) not installed: the terminal refusal of -o - is not tested here");
  }
}

TEST_CASE("write errors fail the run and leave no output that looks complete", "[outputs][cli]") {
  TempDir dir;
  const std::string d = dir.path.string();
  // RLIMIT_FSIZE (ulimit -f, 512-byte blocks in sh) with SIGXFSZ ignored: writes past it fail (EFBIG)
  const std::string json = dir.write("i.json", "old\n");
  auto r = run_sh("ulimit -f 1; trap \"\" XFSZ; \"$M\" info gen:sphere:16 --json " + json);
  INFO(r.output);
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--json " + json + ": write failed"));
  CHECK(slurp(json) == "old\n");  // the old file untouched
  // render: the PNG (12 KiB) fits, the PFM (48 KiB) does not: neither is written
  r = run_sh("ulimit -f 40; trap \"\" XFSZ; \"$M\" render gen:sphere:16 --width 64 --height 64 --spp 1 -o " + d +
             "/img.png --pfm " + d + "/img.pfm");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("--pfm " + d + "/img.pfm: write failed"));
  CHECK(names_in(dir) == std::set<std::string>{"i.json"});
  // standard output is checked too: the report, and -o -
  r = run_sh("\"$M\" info gen:sphere:16 >/dev/full");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("standard output: write failed"));
  r = run_sh("\"$M\" rays gen:sphere:16 --count 100 -o - >/dev/full");
  CHECK(r.code == 2);
  CHECK_THAT(r.output, Catch::Contains("-o -: write to standard output failed"));
}

TEST_CASE("SIGTERM during a write removes the temporary", "[outputs][cli]") {
  TempDir dir;
  const std::string out = dir.file("big.rays"), cli = mbvh_test::cli_path();
  bool caught = false;
  for (int attempt = 0; attempt < 5 && !caught; ++attempt) {
    const pid_t pid = ::fork();
    REQUIRE(pid >= 0);
    if (pid == 0) {
      const int null = ::open("/dev/null", O_WRONLY);
      ::dup2(null, 1);
      ::dup2(null, 2);
      ::execl(cli.c_str(), cli.c_str(), "rays", "gen:sphere:16", "--kind", "random", "--count", "2000000", "-o",
              out.c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    // wait for a temporary (any file but the target) to appear, then terminate the writer
    int status = 0;
    for (;;) {
      bool temp = false;
      for (const std::string& n : names_in(dir)) temp |= n != "big.rays";
      if (temp) {
        ::kill(pid, SIGTERM);
        caught = true;
        break;
      }
      if (::waitpid(pid, &status, WNOHANG) == pid) break;  // finished before we saw it: try again
      std::this_thread::sleep_for(std::chrono::microseconds(500));
    }
    if (caught) {
      REQUIRE(::waitpid(pid, &status, 0) == pid);
      if (WIFEXITED(status) && WEXITSTATUS(status) == 0) caught = false;  // renamed before the signal
      else CHECK((WIFSIGNALED(status) && WTERMSIG(status) == SIGTERM));
    }
    std::filesystem::remove(out);
  }
  REQUIRE(caught);
  CHECK(names_in(dir).empty());
}

TEST_CASE("concurrent writers of one output leave one run's complete file", "[outputs][cli]") {
  TempDir dir;
  const std::string d = dir.path.string();
  constexpr int runs = 4, rounds = 4;
  std::vector<std::string> want(runs + 1);
  for (int i = 1; i <= runs; ++i) {
    REQUIRE(run_cli("rays gen:sphere:16 --kind random --count 300000 --seed " + std::to_string(i) + " -o " + d +
                    "/want" + std::to_string(i))
                .code == 0);
    want[i] = slurp(dir.file("want" + std::to_string(i)));
    std::filesystem::remove(dir.file("want" + std::to_string(i)));
  }
  for (int round = 0; round < rounds; ++round) {
    INFO("round " << round);
    const auto r = run_sh("cd " + d + " && for i in 1 2 3 4; do (\"$M\" rays gen:sphere:16 --kind random --count 300000 "
                          "--seed $i -o out.rays >log$i 2>&1; echo $? >rc$i) & done; wait");
    REQUIRE(r.code == 0);
    const std::string got = slurp(dir.file("out.rays"));
    int owner = 0;
    for (int i = 1; i <= runs; ++i)
      if (got == want[i]) owner = i;
    CHECK(owner != 0);  // byte for byte one run's complete output
    for (int i = 1; i <= runs; ++i) {
      const std::string is = std::to_string(i);
      const std::string log = slurp(dir.file("log" + is)), rc = slurp(dir.file("rc" + is));
      INFO("run " << i << ": exit " << rc << log);
      // each run succeeds, or says another writer's data replaced its own; the owner succeeded
      if (rc == "0\n") CHECK_THAT(log, Catch::Contains("wrote 300000 random rays"));
      else CHECK_THAT(log, Catch::Contains("another writer replaced the output"));
      if (i == owner) CHECK(rc == "0\n");
      std::filesystem::remove(dir.file("log" + is));
      std::filesystem::remove(dir.file("rc" + is));
    }
    CHECK(names_in(dir) == std::set<std::string>{"out.rays"});  // no temporary left
  }
}

// SPDX-License-Identifier: MIT
// output.cpp — the one writer of every mbvh output (output.h): target checks, unique temporaries
// renamed into place, their removal on errors and on SIGINT/SIGTERM/SIGHUP/SIGPIPE.
#include "host/core/io/output.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <climits>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <vector>

#include "mbvh/error.h"

namespace mbvh {

namespace output_detail {  // named, not anonymous: StreamedOutput::Impl holds Staged (-Wsubobject-linkage in unity builds)

// -- temporaries the signal handler removes: a fixed table of paths, no allocation in the handler

constexpr int kTempSlots = 16;  // outputs staged at once; a command has at most 3
struct TempSlot {
  std::atomic<bool> armed{false};
  char path[PATH_MAX];
};
static_assert(std::atomic<bool>::is_always_lock_free, "the signal handler reads the flags");
TempSlot g_temps[kTempSlots];
bool g_claimed[kTempSlots];
std::mutex g_temps_mutex;  // claiming and releasing slots (never taken by the handler)
constexpr int kCleanupSignals[] = {SIGINT, SIGTERM, SIGHUP, SIGPIPE};

extern "C" void remove_temporaries_and_reraise(int sig) {
  for (TempSlot& s : g_temps)
    if (s.armed.load(std::memory_order_acquire)) ::unlink(s.path);
  struct sigaction dfl {};
  dfl.sa_handler = SIG_DFL;
  sigemptyset(&dfl.sa_mask);
  ::sigaction(sig, &dfl, nullptr);
  ::raise(sig);  // blocked until the handler returns, then ends the process as it would have
}

// Installs the handler once, for the signals whose action is still the default (an ignored
// SIGHUP under nohup, or a caller's own handler, stays as it is).
void install_cleanup_handlers() {
  static std::once_flag once;
  std::call_once(once, [] {
    for (int sig : kCleanupSignals) {
      struct sigaction old {};
      if (::sigaction(sig, nullptr, &old) != 0 || (old.sa_flags & SA_SIGINFO) || old.sa_handler != SIG_DFL) continue;
      struct sigaction sa {};
      sa.sa_handler = remove_temporaries_and_reraise;
      sigemptyset(&sa.sa_mask);
      ::sigaction(sig, &sa, nullptr);
    }
  });
}

// 16 random hex digits for a temporary's name (O_EXCL decides; the randomness only keeps retries rare).
std::string random_hex() {
  thread_local std::mt19937_64 rng{std::random_device{}() ^ (std::uint64_t(::getpid()) << 32) ^
                                   std::uint64_t(std::chrono::steady_clock::now().time_since_epoch().count())};
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(rng()));
  return b;
}

// Blocks the cleanup signals in this thread for its lifetime, so that a temporary is never created
// without being registered.
class CleanupSignalsBlocked {
public:
  CleanupSignalsBlocked() {
    sigset_t set;
    sigemptyset(&set);
    for (int sig : kCleanupSignals) sigaddset(&set, sig);
    pthread_sigmask(SIG_BLOCK, &set, &old_);
  }
  ~CleanupSignalsBlocked() { pthread_sigmask(SIG_SETMASK, &old_, nullptr); }

private:
  sigset_t old_;
};

// The umask, read once before main (the umask(0)/umask(m) dance is not thread-safe later).
const mode_t g_umask = [] {
  const mode_t m = ::umask(0);
  ::umask(m);
  return m;
}();

// -- what a target is

std::string label(const OutputTarget& t) { return t.option.empty() ? t.path : t.option + " " + t.path; }

const char* kind_of(mode_t m) {
  if (S_ISDIR(m)) return "a directory";
  if (S_ISFIFO(m)) return "a FIFO";
  if (S_ISSOCK(m)) return "a socket";
  if (S_ISCHR(m)) return "a character device";
  if (S_ISBLK(m)) return "a block device";
  return "not a regular file";
}

// The directory a file is in ("." for a bare name).
std::string directory_of(const std::string& path) {
  const std::filesystem::path p(path);
  return p.has_parent_path() ? p.parent_path().string() : std::string(".");
}

// The file a target names: the path to replace (a symlink's final target) and, if it exists, its stat.
struct Resolved {
  std::string path;
  bool exists = false;
  bool replaces_link = false;  // a link at a target that does not follow links
  struct stat st {};
};

Resolved resolve(const OutputTarget& t) {
  const std::string where = label(t);
  const std::string refuse = "; mbvh writes only regular files and replaces nothing else";
  Resolved r;
  r.path = t.path;
  struct stat ls {};
  if (::lstat(t.path.c_str(), &ls) == 0) {
    if (S_ISLNK(ls.st_mode) && !t.follow_links) {
      r.replaces_link = true;  // the link is replaced, never followed: nothing of its target is read or written
      return r;
    }
    if (S_ISLNK(ls.st_mode)) {
      if (::stat(t.path.c_str(), &r.st) != 0)
        throw Error(where + ": is a symbolic link to a missing file (" + std::strerror(errno) +
                    "); mbvh follows a link only to an existing regular file");
      if (!S_ISREG(r.st.st_mode)) throw Error(where + ": is a symbolic link to " + kind_of(r.st.st_mode) + refuse);
      std::unique_ptr<char, void (*)(void*)> real(::realpath(t.path.c_str(), nullptr), &std::free);
      if (!real) throw Error(where + ": cannot resolve the symbolic link: " + std::strerror(errno));
      r.path = real.get();
    } else {
      if (!S_ISREG(ls.st_mode)) throw Error(where + ": is " + std::string(kind_of(ls.st_mode)) + refuse);
      r.st = ls;
    }
    r.exists = true;
    return r;
  }
  if (errno != ENOENT) throw Error(where + ": cannot inspect the output: " + std::strerror(errno));
  const std::string dir = directory_of(t.path);
  struct stat ds {};
  if (::stat(dir.c_str(), &ds) != 0)
    throw Error(where + ": cannot write into directory " + dir + ": " + std::strerror(errno));
  if (!S_ISDIR(ds.st_mode)) throw Error(where + ": " + dir + " is not a directory");
  return r;
}

bool same_file(const struct stat& a, const struct stat& b) { return a.st_dev == b.st_dev && a.st_ino == b.st_ino; }

std::string normalised(const std::string& path) {
  std::error_code ec;
  const auto p = std::filesystem::weakly_canonical(path, ec);
  return ec ? path : p.string();
}

// Writes all `size` bytes (short writes continued, EINTR retried); 0, or the errno of the failure.
int write_all(int fd, const void* data, std::size_t size) {
  const char* p = static_cast<const char*>(data);
  while (size > 0) {
    const ssize_t n = ::write(fd, p, size);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) return n == 0 ? EIO : errno;
    p += n;
    size -= static_cast<std::size_t>(n);
  }
  return 0;
}

// One output staged in a temporary beside its target; the destructor removes the temporary
// unless it was renamed into place.
class Staged {
public:
  Staged(const OutputTarget& t, const Resolved& r) : where_(label(t)), target_(r.path) {
    const std::string dir = directory_of(r.path);
    const std::string stem = dir + "/." + std::filesystem::path(r.path).filename().string().substr(0, 200) + ".";
    install_cleanup_handlers();
    {
      // The slot is armed with the name before the file exists: a process-directed signal may be
      // handled on any thread (the worker pool's, a driver's), not only this one, whose signals
      // are blocked here; the handler then removes the file or finds none. O_EXCL makes the file
      // ours; a name taken already is drawn again.
      CleanupSignalsBlocked blocked;
      for (int attempt = 0;; ++attempt) {
        temp_ = stem + random_hex() + ".partial";
        claim_slot();
        fd_ = ::open(temp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
        if (fd_ >= 0) break;
        const int err = errno;
        release_slot();
        temp_.clear();
        if (err != EEXIST || attempt == 99)
          throw Error(where_ + ": cannot create a temporary file in " + dir + ": " + std::strerror(err));
      }
    }
    if (r.exists && t.follow_links) replaced_ = r.st;
    follow_ = t.follow_links;
    shared_ = t.shared;
  }
  Staged(const Staged&) = delete;
  Staged& operator=(const Staged&) = delete;
  ~Staged() {
    if (fd_ >= 0) ::close(fd_);
    if (!renamed_ && !temp_.empty()) ::unlink(temp_.c_str());
    release_slot();
  }

  /// Gives the temporary the replaced file's mode and owner (or the umask's mode), writes, syncs
  /// and closes it; throws Error on any failure.
  void write(const void* data, std::size_t size) {
    begin();
    data_ = data;
    size_ = size;
    append(data, size);
    finish();
  }

  /// Gives the temporary the replaced file's mode and owner (or the umask's mode): the first step
  /// of a streamed write (append, patch, finish).
  void begin() {
    // the owner where permitted (root); otherwise the new file is ours, as with any program that
    // replaces a file
    if (replaced_ && (replaced_->st_uid != ::geteuid() || replaced_->st_gid != ::getegid()) &&
        ::fchown(fd_, replaced_->st_uid, replaced_->st_gid) != 0) {
    }
    if (::fchmod(fd_, replaced_ ? (replaced_->st_mode & 07777) : (0666 & ~g_umask)) != 0)
      fail("cannot set the mode of the temporary file");
  }
  /// Appends bytes to the temporary.
  void append(const void* data, std::size_t size) {
    if (const int e = write_all(fd_, data, size)) {
      errno = e;
      fail("write failed");
    }
  }
  /// Overwrites bytes already written at `offset` (a header written last).
  void patch(std::uint64_t offset, const void* data, std::size_t size) {
    const char* p = static_cast<const char*>(data);
    while (size > 0) {
      const ssize_t n = ::pwrite(fd_, p, size, static_cast<off_t>(offset));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        if (n == 0) errno = EIO;
        fail("write failed");
      }
      p += n;
      offset += static_cast<std::uint64_t>(n);
      size -= static_cast<std::size_t>(n);
    }
  }
  /// Syncs and closes the temporary.
  void finish() {
    if (::fsync(fd_) != 0) fail("write failed (fsync)");
    struct stat st {};
    if (::fstat(fd_, &st) != 0) fail("cannot stat the temporary file");
    written_ = st;
    const int fd = fd_;
    fd_ = -1;
    if (::close(fd) != 0) fail("write failed (close)");
  }

  /// Renames the temporary over the target, then confirms the target is still the file written.
  void commit(const OutputTarget& t) {
    const Resolved again = resolve(t);  // the target may have changed since it was checked
    if (again.path != target_) throw Error(where_ + ": the output changed while it was written (now " + again.path + ")");
    if (::rename(temp_.c_str(), target_.c_str()) != 0) fail("cannot rename the temporary file into place");
    renamed_ = true;
    release_slot();
    struct stat st {};
    const int got = follow_ ? ::stat(target_.c_str(), &st) : ::lstat(target_.c_str(), &st);
    if ((got != 0 || !same_file(st, written_)) && !(shared_ && holds_written_bytes()))
      throw Error(where_ + ": another writer replaced the output just after this run wrote it; the file holds "
                           "the other run's data, not this run's");
  }

private:
  // True when the target (not followed if it is a link) is a regular file holding exactly the
  // bytes this run wrote: another writer of a shared target renamed an equal file over ours.
  bool holds_written_bytes() const {
    const int fd = ::open(target_.c_str(), O_RDONLY | O_CLOEXEC | O_NOFOLLOW);
    if (fd < 0) return false;
    struct stat st {};
    bool equal = ::fstat(fd, &st) == 0 && S_ISREG(st.st_mode) && static_cast<std::uint64_t>(st.st_size) == size_;
    std::vector<char> buf(std::size_t(1) << 20);
    for (std::size_t off = 0; equal && off < size_;) {
      const ssize_t n = ::pread(fd, buf.data(), std::min(buf.size(), size_ - off), static_cast<off_t>(off));
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0 || std::memcmp(buf.data(), static_cast<const char*>(data_) + off, static_cast<std::size_t>(n)) != 0)
        equal = false;
      off += n > 0 ? static_cast<std::size_t>(n) : 0;
    }
    ::close(fd);
    return equal;
  }
  [[noreturn]] void fail(const std::string& what) {
    throw Error(where_ + ": " + what + ": " + std::strerror(errno));
  }
  void claim_slot() {
    if (temp_.size() >= PATH_MAX) return;  // not removable on a signal; still removed on errors
    std::lock_guard<std::mutex> lock(g_temps_mutex);
    for (int i = 0; i < kTempSlots; ++i)
      if (!g_claimed[i]) {
        g_claimed[i] = true;
        std::memcpy(g_temps[i].path, temp_.c_str(), temp_.size() + 1);
        g_temps[i].armed.store(true, std::memory_order_release);
        slot_ = i;
        return;
      }
  }
  void release_slot() {
    if (slot_ < 0) return;
    std::lock_guard<std::mutex> lock(g_temps_mutex);
    g_temps[slot_].armed.store(false, std::memory_order_release);
    g_claimed[slot_] = false;
    slot_ = -1;
  }

  std::string where_, target_, temp_;
  int fd_ = -1, slot_ = -1;
  bool renamed_ = false, follow_ = true, shared_ = false;
  const void* data_ = nullptr;  // the bytes written (shared targets compare them after the rename)
  std::size_t size_ = 0;
  std::optional<struct stat> replaced_;  // the file this output replaces, if it exists
  struct stat written_ {};
};

}  // namespace output_detail
using namespace output_detail;

void check_outputs(std::span<const OutputTarget> outputs, std::span<const InputFile> inputs) {
  struct Seen {
    std::string where, key;
    bool exists;
    struct stat st;
  };
  std::vector<Seen> ins, outs;
  for (const InputFile& in : inputs) {
    Seen s{in.option + " " + in.path, normalised(in.path), false, {}};
    s.exists = ::stat(in.path.c_str(), &s.st) == 0;
    ins.push_back(s);
  }
  const OutputTarget* to_stdout = nullptr;
  for (const OutputTarget& t : outputs) {
    if (t.path == "-") {
      if (to_stdout)
        throw Error(label(*to_stdout) + " and " + label(t) + " both go to standard output; only one output can");
      if (!t.text && ::isatty(STDOUT_FILENO))
        throw Error(label(t) + ": refusing to write a binary format to a terminal; redirect standard output or name a file");
      to_stdout = &t;
      continue;
    }
    const Resolved r = resolve(t);
    // a link that is replaced, not followed, is compared by its own name, not its target's
    const std::string key = r.replaces_link ? (std::filesystem::path(normalised(directory_of(r.path))) /
                                               std::filesystem::path(r.path).filename()).string()
                                            : normalised(r.path);
    Seen s{label(t), key, r.exists, r.st};
    const auto same = [&s](const Seen& o) { return s.exists && o.exists ? same_file(s.st, o.st) : s.key == o.key; };
    for (const Seen& in : ins)
      if (same(in))
        throw Error(s.where + " is also the input " + in.where +
                    ": an output must not replace an input of the same command");
    for (const Seen& o : outs)
      if (same(o)) throw Error(o.where + " and " + s.where + " name the same file; each output needs its own");
    outs.push_back(s);
  }
}

void write_outputs(std::span<const OutputWrite> outputs) {
  std::vector<OutputTarget> targets;
  for (const OutputWrite& o : outputs) targets.push_back(o.to);
  check_outputs(targets);
  // -- stage every file: nothing is replaced until all of them are written
  std::vector<std::unique_ptr<Staged>> staged(outputs.size());
  for (std::size_t i = 0; i < outputs.size(); ++i) {
    if (outputs[i].to.path == "-") continue;
    staged[i] = std::make_unique<Staged>(outputs[i].to, resolve(outputs[i].to));
    staged[i]->write(outputs[i].data, outputs[i].size);
  }
  // -- standard output, then the renames
  for (const OutputWrite& o : outputs)
    if (o.to.path == "-")
      if (const int e = write_all(STDOUT_FILENO, o.data, o.size))
        throw Error(label(o.to) + ": write to standard output failed: " + std::strerror(e));
  for (std::size_t i = 0; i < outputs.size(); ++i)
    if (staged[i]) staged[i]->commit(outputs[i].to);
}

// -- one output written as a stream

struct StreamedOutput::Impl {
  OutputTarget to;
  std::unique_ptr<Staged> staged;
};

StreamedOutput::StreamedOutput(const OutputTarget& to) : impl_(std::make_unique<Impl>()) {
  if (to.path == "-") throw Error(label(to) + ": this output is written as a stream and patched; name a file, not standard output");
  if (to.shared) throw Error(label(to) + ": a streamed output cannot be shared");
  const OutputTarget targets[1] = {to};
  check_outputs(targets);
  impl_->to = to;
  impl_->staged = std::make_unique<Staged>(to, resolve(to));
  impl_->staged->begin();
}

StreamedOutput::~StreamedOutput() = default;

void StreamedOutput::write(const void* data, std::size_t size) {
  if (!impl_->staged) throw Error(label(impl_->to) + ": written after commit");
  impl_->staged->append(data, size);
  bytes_ += size;
}

void StreamedOutput::patch(std::uint64_t offset, const void* data, std::size_t size) {
  if (!impl_->staged) throw Error(label(impl_->to) + ": written after commit");
  if (offset > bytes_ || size > bytes_ - offset) throw Error(label(impl_->to) + ": a patch beyond the bytes written");
  impl_->staged->patch(offset, data, size);
}

void StreamedOutput::commit() {
  if (!impl_->staged) throw Error(label(impl_->to) + ": committed twice");
  impl_->staged->finish();
  impl_->staged->commit(impl_->to);
  impl_->staged.reset();
}

}  // namespace mbvh

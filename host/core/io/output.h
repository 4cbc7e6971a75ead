// SPDX-License-Identifier: MIT
// output.h — every file mbvh writes: regular files only, replaced atomically through a unique
// temporary beside the target, never a device, FIFO, socket or directory; "-" is standard output.
#pragma once
#include <cstddef>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

namespace mbvh {

/// Where one output of a command goes: the option that named it (for messages; may be empty),
/// its path ("-": standard output) and whether the format is text (JSON, CSV), which may go to a
/// terminal, or binary (rays, hits, occlusion, PNG, PFM), which may not.
/// `follow_links` false (BVH cache entries): a symbolic link at `path` is never followed; it is
/// replaced by the new file (its target untouched), and the new file gets the umask's mode, not
/// the replaced file's mode or owner. `shared` (BVH cache entries): other writers may write the
/// same bytes to `path` at the same time; another writer's rename of an equal file over this
/// one's is not an error.
struct OutputTarget {
  std::string option;
  std::string path;
  bool text = false;
  bool follow_links = true;
  bool shared = false;
};

/// One input file of a command, for check_outputs: the option that named it and its path.
struct InputFile {
  std::string option;
  std::string path;
};

/// The bytes of one output.
struct OutputWrite {
  OutputTarget to;
  const void* data = nullptr;
  std::size_t size = 0;
};

/// Checks a command's outputs before it does any work; throws Error naming the option and path
/// when an output (a) exists and is not a regular file (directory, FIFO, socket, device) or is a
/// symbolic link to one or to nothing, (b) lies in a directory that does not exist, (c) is one of
/// `inputs` (same device and inode: symlinks, hard links and other spellings included) or names
/// the same file as another output, (d) is "-" for a second output, or for a binary format while
/// standard output is a terminal. Inputs that do not exist are left to their readers. Costs a
/// few stat calls.
void check_outputs(std::span<const OutputTarget> outputs, std::span<const InputFile> inputs = {});

/// Writes every output, all or none: each file goes to a new temporary `.NAME.XXXXXX.partial`
/// (mkstemp, in the target's directory) whose mode is the replaced file's (and its owner, where
/// permitted), or 0666 minus the umask for a new file; every write, fsync and close is checked;
/// "-" is written to standard output once every file is staged; then each temporary is renamed
/// over its target. A symbolic link is followed (unless `follow_links` is false: then the link
/// itself is replaced): the regular file it finally names is replaced and the link stays. On any failure no target has been touched (up to a failing rename, the last
/// step), the temporaries are removed and Error names the option and path; SIGINT, SIGTERM,
/// SIGHUP and SIGPIPE (where not ignored) remove them too before the signal ends the process.
/// After its rename each target must still be the file written: if another writer renamed over it
/// in between, Error says so — a run never reports another run's data as its own (a `shared`
/// target holding the same bytes as this run wrote is fine).
void write_outputs(std::span<const OutputWrite> outputs);

/// One output written as a stream, for files too large to hold (a generated .mtri): bytes are
/// appended to a temporary beside the target (as write_outputs stages them, with the same checks
/// and the same removal on errors and signals), earlier bytes may be patched (a header known
/// last), and commit() syncs it and renames it over the target. Destroyed without commit(), the
/// temporary is removed and the target untouched. Standard output ("-") and `shared` targets are
/// refused (Error naming the option and path), as is anything check_outputs refuses.
class StreamedOutput {
public:
  explicit StreamedOutput(const OutputTarget& to);
  ~StreamedOutput();
  StreamedOutput(const StreamedOutput&) = delete;
  StreamedOutput& operator=(const StreamedOutput&) = delete;
  /// Appends `size` bytes. Throws Error naming the output on a failed write.
  void write(const void* data, std::size_t size);
  /// Overwrites [offset, offset + size), which must lie within the bytes written so far.
  void patch(std::uint64_t offset, const void* data, std::size_t size);
  /// Syncs, closes and renames the temporary over the target (write_outputs' last steps).
  void commit();
  /// Bytes written so far.
  std::uint64_t bytes() const { return bytes_; }

private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::uint64_t bytes_ = 0;
};

}  // namespace mbvh

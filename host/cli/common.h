// SPDX-License-Identifier: MIT
// common.h — what every `mbvh` subcommand shares: the report (--quiet), outputs, option
// validators, scene loading and the BVH build (--cache, --quality), backend and device selection,
// variant grids and ray options.
#pragma once
#include <CLI/CLI.hpp>

#include <chrono>
#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "host/core/io/output.h"
#include "host/tools/raygen.h"
#include "host/tools/stats.h"
#include "host/tools/variants.h"
#include "mbvh/accel.h"
#include "mbvh/backend.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"

namespace mbvh::cli {

/// A subcommand: its CLI11 app (true once parsed) and what runs it. run() returns the exit
/// status (0 ok, 1 a genuine mismatch or an unverified timed result, 2 an error) and may throw
/// Error, which the program reports and turns into exit status 2.
struct Command {
  CLI::App* app = nullptr;
  std::function<int()> run;
};

// -- the report

/// --quiet: no report, errors only.
bool& quiet();
/// Prints to the report (standard output, or standard error once an output goes to standard
/// output), nothing under --quiet.
__attribute__((format(printf, 1, 2))) void say(const char* format, ...);

// -- outputs

/// Checks a command's outputs against each other and its inputs before any work (check_outputs),
/// and sends the report to standard error if one of them is '-'. Empty paths are options not
/// given; a generated scene (gen:...) is no input file. The files are kept for load_and_build:
/// the --cache entry may be none of them.
void prepare_outputs(std::vector<OutputTarget> outputs, std::vector<InputFile> inputs);
/// Writes one output (write_outputs).
void write_bytes_to(const OutputTarget& to, const void* data, std::size_t size);
/// How the report names an output: the path, or "standard output" for '-'.
std::string shown(const std::string& path);

// -- lists

/// The items of a comma-separated list; throws Error naming `option` (when given) and the list
/// when an item is empty (",", "a,,b", "a,", ""): such a list would name less than it seems to.
std::vector<std::string> split_list(const std::string& s, const std::string& option = "");
/// The items of a comma-separated list, each parsed by `parse`; throws Error on an empty list.
template <class T, class F>
std::vector<T> parse_list(const std::string& s, F parse) {
  std::vector<T> out;
  for (const auto& x : split_list(s)) out.push_back(parse(x));
  if (out.empty()) throw Error("empty list '" + s + "'");
  return out;
}

// -- numeric options: every one range-checked before conversion; CLI11 puts the option's name in
// front of a validator's message ("--count: ...") and exits with its validation code

/// An unsigned integer option in [lo, hi], `why` appended to the error. Refuses a sign, which
/// CLI11 would wrap into 2^64-1 for a 64-bit option, and any trailing text.
CLI::Validator integer_in(std::uint64_t lo, std::uint64_t hi, const std::string& why = "");
/// A finite number in [lo, hi] (as a float, when `as_float`: 1e39 is not a finite float).
CLI::Validator number_in(double lo, double hi, bool as_float = false);
/// Items of `bytes_each` bytes that fit in this machine's physical memory (the bound of the
/// count options: a larger count is an error naming the option, not a failed allocation).
std::uint64_t fits_in_memory(std::uint64_t bytes_each);
/// The bound of ray counts: a traced ray holds its 32-byte record, its 16-byte hit and copies.
constexpr std::uint64_t kBytesPerRay = 64;
/// The bound of image sizes: a pixel holds its radiance, a path's ray, hit and state.
constexpr std::uint64_t kBytesPerPixel = 256;
/// A ray count: at least 1, kBytesPerRay each within this machine's memory.
CLI::Validator ray_count();
/// Throws Error "WHAT: needs about X of memory (N rays, B bytes each ...), more than the Y available
/// (SOURCE)" when `items` of `bytes_each` exceed the memory budget (MBVH_MEMORY_LIMIT, else the
/// available memory): the check a command makes before it loads the scene and allocates its rays.
void require_ray_memory(const std::string& what, std::uint64_t items, std::uint64_t bytes_each = kBytesPerRay,
                        const char* unit = "rays");

// -- the scene and its BVH

/// The scene argument and the build options every scene command takes.
struct SceneArgs {
  std::string scene;
  unsigned threads = 0;
  unsigned max_leaf = BuildOptions{}.max_leaf;
  unsigned leaf_block = BuildOptions{}.leaf_block;
  std::string cache;
  std::string cache_max_size;  ///< --cache-max-size: empty for no bound
  std::string quality = to_string(BuildOptions{}.quality);
  void add(CLI::App* c);
  /// The build options of these arguments (no progress callback).
  BuildOptions build_options() const;
  /// Whether --quality was given (after parsing).
  bool quality_given() const;
  /// Without --quality: quality none when every one of `backends` (registry names) traces without
  /// a hierarchy (BackendInfo::needs_hierarchy false: dacrt), so no BVH is built for them.
  void no_hierarchy_for(const std::vector<std::string>& backends);

private:
  CLI::Option* quality_opt_ = nullptr;
};

struct Loaded {
  Scene scene;
  std::unique_ptr<Accel> acc;
  double load_ms = 0;
};

/// What makes the BVH in load_and_build instead of Accel::build / Accel::build_cached (mbvh-mpi:
/// one rank builds, the others read its build); it gets the --cache directory (empty without it).
using AccelMaker = std::function<std::unique_ptr<Accel>(const Scene&, const BuildOptions&, const Accel::CacheOptions&,
                                                        Accel::CacheReport*)>;

/// Loads the scene and builds (or reads from --cache) its BVH with a progress bar; reports the
/// scene, the build and its hash on standard error when `verbose` or with --cache.
Loaded load_and_build(const SceneArgs& a, bool verbose = true, const AccelMaker& make = {});

// -- backends and devices


/// --cl-device, --vk-device: which device the OpenCL and Vulkan backends use; --cl-mapping;
/// --vk-validation.
struct DeviceArgs {
  std::string cl_device, vk_device, cl_mapping = "auto";
  bool vk_validation = false;
  std::vector<std::string> settings;  ///< --set FAMILY.NAME=VALUE
  void add(CLI::App* c);
  /// The backend options of these choices, with `threads`; `quality` (the build's --quality, if
  /// given) becomes the embree peer's own build quality unless --set embree.quality says otherwise.
  BackendOptions options(unsigned threads, const std::string& quality = "") const;
};

/// --backend, --layout, --traversal, --query, --precision as comma-separated lists (check and
/// bench), with the device options.
struct GridArgs {
  DeviceArgs dev;
  std::string backends = "cpu", layouts = "mbvh2,mbvh4,mbvh8", traversals = "stack,bitstack,stack-ordered,bitstack-retest,stack-octant,bitstack-octant",
              queries = "closest,any", precisions = "robust";
  void add(CLI::App* c);
  /// The grid; starts every backend once to fail early, naming it ('all': every backend this
  /// machine runs).
  VariantGrid parse() const;
};

// -- rays and the camera

/// --camera eye x y z, target x y z [, fov].
void add_camera_option(CLI::App* c, std::vector<float>& camera);
/// --camera's values go in `cam`; a camera that cannot make rays is an error naming --camera.
void set_camera(const std::vector<float>& c, bool& has, Camera& cam);

/// A ray file or generated rays: --rays, --kind, --count, --seed, --camera.
struct RayArgs {
  std::string rays_file;
  std::string kind = "primary";
  std::size_t count = 100000;
  std::uint64_t seed = 1;
  std::vector<float> camera;
  /// Adds the options; --rays only when `allow_file`.
  void add(CLI::App* c, bool allow_file);
  /// The generator's options for rays of `kind`.
  RayGenOptions generator(const std::string& ray_kind, unsigned threads) const;
  /// The rays: read from --rays, or generated (--kind).
  std::vector<Ray> get(const Loaded& l, unsigned threads) const;
  /// Refuses --count, or the rays of the --rays file (by its size), beyond the memory budget
  /// (require_ray_memory): called before the scene is loaded and anything allocated.
  void check_memory() const;
};

}  // namespace mbvh::cli

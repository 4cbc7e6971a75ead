// SPDX-License-Identifier: MIT
// source.cpp — the triangle sources of the out-of-core builder (mbvh/lod.h TriangleSource): a
// .mtri file read in checked blocks, a gen:mandelbulb spec generated anew on every pass, and an
// in-core scene (loaded, or the caller's) read in chunks with its material colours.
#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstring>
#include <mutex>
#include <optional>

#include "host/core/gen/mandelbulb.h"
#include "host/core/io/mtri.h"
#include "host/core/layouts.h"  // hash_bytes
#include "host/core/lod/sources.h"
#include "host/core/resources.h"
#include "mbvh/error.h"

namespace mbvh::lod {

// -- the .mtri content hash of a stream

ContentHasher::ContentHasher() : block_(kMtriBlockBytes) {}

void ContentHasher::flush() {
  if (used_ == 0) return;
  table_.push_back(hash_bytes(block_.data(), used_, table_.size()));
  used_ = 0;
}

void ContentHasher::add(std::span<const SourceTri> tris) {
  const char* p = reinterpret_cast<const char*>(tris.data());
  std::size_t n = tris.size_bytes();
  while (n > 0) {  // records may straddle two blocks, as in the file
    const std::size_t take = std::min<std::size_t>(n, kMtriBlockBytes - used_);
    std::memcpy(block_.data() + used_, p, take);
    used_ += take;
    p += take;
    n -= take;
    if (used_ == kMtriBlockBytes) flush();
  }
  count_ += tris.size();
}

std::uint64_t ContentHasher::finish() {
  flush();
  return hash_bytes(table_.data(), table_.size() * sizeof(std::uint64_t), count_);
}

namespace {

// -- a .mtri file: its header gives the count, hash and bounds; every pass checks the blocks
class MtriSource final : public TriangleSource {
 public:
  explicit MtriSource(const std::string& path) : path_(path), r_(path) {}
  std::string name() const override { return path_; }
  std::uint64_t count() const override { return r_.count(); }
  std::uint64_t hash() const override { return r_.hash(); }
  void for_each_chunk(const ChunkFn& fn) const override { r_.for_each_chunk(fn); }
  const Box& bounds() const { return r_.bounds(); }

 private:
  std::string path_;
  MtriReader r_;
};

// -- gen:mandelbulb:RES[:K]: generated on every pass (the same triangles in the same order at any
//    thread count); its count and hash are known after the first complete pass
class MandelbulbSource final : public TriangleSource {
 public:
  MandelbulbSource(const std::string& spec, const MandelbulbOptions& o) : spec_(spec), o_(o) {}
  std::string name() const override { return spec_; }
  std::uint64_t count() const override {
    ensure_known();
    return count_;
  }
  std::uint64_t hash() const override {
    ensure_known();
    return hash_;
  }
  void for_each_chunk(const ChunkFn& fn) const override {
    ContentHasher h;
    generate_mandelbulb(o_, [&](std::uint64_t first, std::span<const SourceTri> t) {
      h.add(t);
      fn(first, t);
    });
    const std::uint64_t hash = h.finish();
    std::lock_guard lock(m_);
    if (!known_) count_ = h.count(), hash_ = hash, known_ = true;
  }
  /// The generator's grid, [-1.2, 1.2]^3: every vertex lies on one of its edges.
  Box bounds() const {
    Box b;
    b.lo = {-1.2f, -1.2f, -1.2f};
    b.hi = {1.2f, 1.2f, 1.2f};
    return b;
  }

 private:
  void ensure_known() const {
    {
      std::lock_guard lock(m_);
      if (known_) return;
    }
    for_each_chunk([](std::uint64_t, std::span<const SourceTri>) {});
  }
  std::string spec_;
  MandelbulbOptions o_;
  mutable std::mutex m_;
  mutable bool known_ = false;
  mutable std::uint64_t count_ = 0, hash_ = 0;
};

// -- an in-core scene, owned (loaded here) or the caller's (by reference)
class SceneSource final : public TriangleSource {
 public:
  explicit SceneSource(Scene&& s) : owned_(std::move(s)), s_(*owned_) { init(); }
  explicit SceneSource(const Scene& s) : s_(s) { init(); }
  std::string name() const override { return s_.display_name(); }
  std::uint64_t count() const override { return s_.triangle_count(); }
  std::uint64_t hash() const override {
    std::lock_guard lock(m_);
    if (!hashed_) {
      ContentHasher h;
      chunks([&h](std::uint64_t, std::span<const SourceTri> t) { h.add(t); });
      hash_ = h.finish();
      hashed_ = true;
    }
    return hash_;
  }
  void for_each_chunk(const ChunkFn& fn) const override { chunks(fn); }
  std::vector<Vec3f> albedos() const override { return table_; }
  std::uint32_t albedo_index(std::uint64_t prim) const override {
    if (table_.empty() || prim >= s_.triangle_materials.size()) return 0;
    const std::uint32_t m = s_.triangle_materials[prim];
    return m < s_.materials.size() ? m : grey_;
  }
  Box bounds() const { return s_.bounds(); }

 private:
  void init() {
    s_.validate();  // names the scene and the first bad triangle
    // the renderer's albedo (host/tools/render.cpp, surface()): the material's diffuse colour when
    // the materials cover every triangle and its index names one, else grey 0.7
    if (s_.triangle_count() > 0 && s_.triangle_materials.size() == s_.triangle_count()) {
      for (const Material& m : s_.materials) table_.push_back(m.diffuse);
      grey_ = static_cast<std::uint32_t>(table_.size());
      const bool any_grey = std::any_of(s_.triangle_materials.begin(), s_.triangle_materials.end(),
                                        [this](std::uint32_t m) { return m >= s_.materials.size(); });
      if (any_grey) table_.push_back(Vec3f{0.7f, 0.7f, 0.7f});
    }
  }
  void chunks(const ChunkFn& fn) const {
    constexpr std::size_t kChunk = 8192;
    std::vector<SourceTri> chunk;
    chunk.reserve(kChunk);
    const std::size_t n = s_.triangle_count();
    for (std::size_t first = 0; first < n; first += kChunk) {
      chunk.clear();
      const std::size_t end = std::min(n, first + kChunk);
      for (std::size_t i = first; i < end; ++i) {
        Vec3f a, b, c;
        s_.triangle(i, a, b, c);
        chunk.push_back({{a.x, a.y, a.z, b.x, b.y, b.z, c.x, c.y, c.z}});
      }
      fn(first, chunk);
    }
  }
  std::optional<Scene> owned_;
  const Scene& s_;
  std::vector<Vec3f> table_;
  std::uint32_t grey_ = 0;
  mutable std::mutex m_;
  mutable bool hashed_ = false;
  mutable std::uint64_t hash_ = 0;
};

bool ends_with_ci(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  for (std::size_t i = 0; i < suffix.size(); ++i)
    if (std::tolower(static_cast<unsigned char>(s[s.size() - suffix.size() + i])) != suffix[i]) return false;
  return true;
}

// Whether `path` is a regular file that begins with the .mtri magic (a FIFO or device is not opened).
bool has_mtri_magic(const std::string& path) {
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0 || !S_ISREG(st.st_mode)) return false;
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | O_NONBLOCK);
  if (fd < 0) return false;
  char head[8];
  const ssize_t got = ::pread(fd, head, sizeof head, 0);
  ::close(fd);
  return got == static_cast<ssize_t>(sizeof head) && is_mtri(head, sizeof head);
}

}  // namespace

std::unique_ptr<TriangleSource> open_triangles(const std::string& path_or_spec, unsigned threads) {
  if (path_or_spec.rfind("gen:", 0) == 0) {
    MandelbulbOptions mo;
    if (streamed_mandelbulb(path_or_spec.substr(4), mo)) {
      mo.threads = threads;
      return std::make_unique<MandelbulbSource>(path_or_spec, mo);
    }
  } else if ((ends_with_ci(path_or_spec, ".mtri")) || has_mtri_magic(path_or_spec)) {
    return std::make_unique<MtriSource>(path_or_spec);
  }
  Scene s = load_scene(path_or_spec);
  if (s.name.empty()) s.name = path_or_spec;
  return std::make_unique<SceneSource>(std::move(s));
}

std::unique_ptr<TriangleSource> triangles_of(const Scene& scene) { return std::make_unique<SceneSource>(scene); }

std::optional<Box> known_bounds(const TriangleSource& src) {
  if (const auto* m = dynamic_cast<const MtriSource*>(&src)) return m->bounds();
  if (const auto* g = dynamic_cast<const MandelbulbSource*>(&src)) return g->bounds();
  if (const auto* s = dynamic_cast<const SceneSource*>(&src)) return s->bounds();
  return std::nullopt;
}

}  // namespace mbvh::lod

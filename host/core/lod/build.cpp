// SPDX-License-Identifier: MIT
// build.cpp — the out-of-core builder of a .mlod model (mbvh/lod.h lod::build; format.h has the
// file; docs/massive.md, "The .mlod build", the algorithm and its measurements).
//
// 1. Pass 1 streams the source once: the checks Accel::build makes (finite, not too small, in the
//    traced range), the non-degenerate triangles' bounds (= Accel::bounds()) and a histogram of
//    their centroids on a Morton grid (Morton 1966; the order LBVH builds sort by, Lauterbach et
//    al. 2009).
// 2. The Morton range is split by its top bits (halving along x, y, z in turn) until every part
//    holds no more triangles than one in-core build can take within the budget: the parts are the
//    buckets, the splits the top tree over them. A model that fits whole is one bucket, read
//    straight from the source; otherwise pass 2 streams every triangle (36 B and its 32-bit prim
//    id) into its bucket's part of an unlinked temporary file, through one buffer per bucket.
// 3. Each bucket in Morton order becomes a Scene and is built by Accel::build (the one builder);
//    its voxels are summed bottom-up (doubles; a parent's sums are its children's), and its tree is
//    cut top-down into treelets filled breadth-first up to a block; the small complete subtrees
//    below a block are packed together into shared blocks. Blocks are assembled, compressed alone
//    with zstd (in parallel) and written in a fixed order, so the bytes do not depend on threads.
// 4. The top tree's voxels and blocks come last (their directory indices were reserved first, so
//    a parent block always precedes its children in the directory); then the directory, the
//    pinned blocks (the root block and the blocks nearest the root, breadth-first, while their raw
//    bytes stay within max(block bytes, raw bytes / 256)) and the header.
#include <fcntl.h>
#include <sys/stat.h>
#include <sys/statvfs.h>
#include <unistd.h>
#define ZSTD_STATIC_LINKING_ONLY  // ZSTD_getCParams, ZSTD_estimateCCtxSize_usingCParams: the batch's memory
#include <zstd.h>

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <deque>
#include <filesystem>
#include <numeric>
#include <optional>
#include <unordered_map>

#include "host/core/bvh/builder.h"  // twice_area_sq, too_small
#include "host/core/io/output.h"
#include "host/core/layouts.h"
#include "host/core/lod/format.h"
#include "host/core/lod/sources.h"
#include "host/core/lod/voxel.h"
#include "host/core/parallel.h"
#include "host/core/resources.h"
#include "host/core/source.h"
#include "mbvh/error.h"
#include "mbvh/version.h"

namespace mbvh::lod {

namespace fmt = format;

/// Bytes one bucket build holds per triangle at its peak: the bucket's Scene (3 unshared vertices
/// and the indices, 48 B) and prim ids (4 B), Accel::build's records and their scratch (64 B), the
/// arenas, the flattened tree and the leaf-ordered triangles (48 B): the measured peak of a
/// bucket's build (quality low, the larger) and a margin (docs/massive.md, "The .mlod build").
constexpr std::uint64_t kBucketBytesPerTriangle = 240;
/// A pass-2 record: the triangle and its prim id.
constexpr std::size_t kRecordBytes = sizeof(SourceTri) + 4;
/// The most triangles a .mlod holds: prim ids are 32 bits and MBVH_MISS_PRIM is none.
constexpr std::uint64_t kMaxModelTriangles = 0xFFFFFFFEull;

namespace {

using Clock = std::chrono::steady_clock;

std::string bytes_str(std::uint64_t b) { return format_bytes(b); }

// -- the Morton grid of pass 1 and 2

struct Grid {
  float lo[3] = {0, 0, 0};
  float scale[3] = {0, 0, 0};
  unsigned bits = 1;  // per axis
  std::uint32_t cells() const { return 1u << (3 * bits); }
  static std::uint32_t spread(std::uint32_t v) {  // bit i of v to bit 3i
    std::uint32_t r = 0;
    for (unsigned i = 0; i < 10; ++i) r |= ((v >> i) & 1u) << (3 * i);
    return r;
  }
  std::uint32_t code(const float c[3]) const {
    std::uint32_t q[3];
    const float top = static_cast<float>((1u << bits) - 1);
    for (int a = 0; a < 3; ++a) {
      float f = (c[a] - lo[a]) * scale[a];
      f = f >= 0 ? std::min(f, top) : 0.0f;  // a grid box that misses a centroid clamps it
      q[a] = static_cast<std::uint32_t>(f);
    }
    return spread(q[0]) | spread(q[1]) << 1 | spread(q[2]) << 2;
  }
  Vec3f cell_center(std::uint32_t code) const {
    std::uint32_t q[3] = {0, 0, 0};
    for (unsigned i = 0; i < bits; ++i)
      for (int a = 0; a < 3; ++a) q[a] |= ((code >> (3 * i + a)) & 1u) << i;
    Vec3f p;
    for (int a = 0; a < 3; ++a) p[a] = scale[a] > 0 ? lo[a] + (static_cast<float>(q[a]) + 0.5f) / scale[a] : lo[a];
    return p;
  }
};

// A triangle's record box and centroid as Accel::build's PrimRef gives them.
inline void centroid_of(const SourceTri& t, float c[3], float lo[3], float hi[3]) {
  for (int a = 0; a < 3; ++a) {
    lo[a] = std::min(std::min(t.v[a], t.v[3 + a]), t.v[6 + a]);
    hi[a] = std::max(std::max(t.v[a], t.v[3 + a]), t.v[6 + a]);
    c[a] = 0.5f * (lo[a] + hi[a]);
  }
}

inline double area2_of(const SourceTri& t) {
  return build::twice_area_sq(Vec3f{t.v[0], t.v[1], t.v[2]}, Vec3f{t.v[3], t.v[4], t.v[5]},
                              Vec3f{t.v[6], t.v[7], t.v[8]});
}

// -- the voxel sums of a subtree (format.h Voxel): per axis a, the weight area |n_a| of every
// triangle, its normal turned towards +a times the weight, and its albedo times the weight. The
// -a face has the same weights and colours and the opposite normal sum (a normal turned towards
// -a is the negative of the one turned towards +a), so three axes hold all six faces.
struct Sums {
  double w[3] = {0, 0, 0};
  double n[3][3] = {};
  double c[3][3] = {};
  double area = 0;
  double ca[3] = {0, 0, 0};  // area-weighted albedo: a face no triangle faces takes it
  std::uint64_t tris = 0;
  void add(const Sums& o) {
    for (int a = 0; a < 3; ++a) {
      w[a] += o.w[a];
      for (int k = 0; k < 3; ++k) n[a][k] += o.n[a][k], c[a][k] += o.c[a][k];
      ca[a] += o.ca[a];
    }
    area += o.area;
    tris += o.tris;
  }
  void add_triangle(const float* v0, const float* v1, const float* v2, const Vec3f& albedo) {
    const double e1[3] = {double(v1[0]) - v0[0], double(v1[1]) - v0[1], double(v1[2]) - v0[2]};
    const double e2[3] = {double(v2[0]) - v0[0], double(v2[1]) - v0[1], double(v2[2]) - v0[2]};
    const double cr[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
    const double len = std::sqrt(cr[0] * cr[0] + cr[1] * cr[1] + cr[2] * cr[2]);
    ++tris;
    if (!(len > 0)) return;
    const double u[3] = {cr[0] / len, cr[1] / len, cr[2] / len};
    const double al[3] = {albedo.x, albedo.y, albedo.z};
    const double ar = 0.5 * len;
    area += ar;
    for (int a = 0; a < 3; ++a) {
      const double wa = ar * std::fabs(u[a]);  // area |n . e_a|
      const double s = u[a] >= 0 ? wa : -wa;   // the normal turned towards +a, times the weight
      w[a] += wa;
      for (int k = 0; k < 3; ++k) n[a][k] += s * u[k], c[a][k] += wa * al[k];
      ca[a] += ar * al[a];
    }
  }
  fmt::Voxel voxel(std::uint32_t depth) const {
    fmt::Voxel v{};
    for (int a = 0; a < 3; ++a) {
      Vec3f nrm, col;
      if (w[a] > 0) {
        nrm = Vec3f{float(n[a][0]), float(n[a][1]), float(n[a][2])};
        col = Vec3f{float(c[a][0] / w[a]), float(c[a][1] / w[a]), float(c[a][2] / w[a])};
      } else {  // no triangle faces this axis: the face's own direction, the area-weighted colour
        nrm = Vec3f{a == 0 ? 1.0f : 0.0f, a == 1 ? 1.0f : 0.0f, a == 2 ? 1.0f : 0.0f};
        col = area > 0 ? Vec3f{float(ca[0] / area), float(ca[1] / area), float(ca[2] / area)} : Vec3f{0.7f, 0.7f, 0.7f};
      }
      v.face[2 * a + 1] = pack_face(nrm, col);
      v.face[2 * a] = pack_face(Vec3f{-nrm.x, -nrm.y, -nrm.z}, col);
    }
    v.triangles = static_cast<std::uint32_t>(std::min<std::uint64_t>(tris, 0xFFFFFFFFu));
    v.depth = depth;
    return v;
  }
};

// -- trees as the cut sees them: a node's two children, each inner (a node of the same tree), a
// leaf (count triangles), external (a link to another tree's root: a bucket under the top tree)
// or empty. Node indices are a preorder: a child's index is above its parent's.

enum ChildKind : std::uint8_t { kInner, kLeaf, kExt, kEmpty };
struct ChildRef {
  ChildKind kind = kEmpty;
  std::uint32_t index = 0;  // inner: node; leaf: the tree's leaf; ext: the external target
  std::uint32_t count = 0;  // leaf: triangles
};

// A bucket's tree: Accel's Bvh2 and leaves, its triangles' prim ids and albedo indices, its voxels.
struct BucketTree {
  const Bvh2* bvh = nullptr;
  const std::vector<Leaf>* leaves = nullptr;
  const AlignedVector<Tri>* tris = nullptr;
  const std::vector<std::uint32_t>* ids = nullptr;  // local prim -> global prim
  const TriangleSource* src = nullptr;
  bool albedo = false;
  std::vector<fmt::Voxel> vox;  // per node: its voxel as a child
  std::size_t size() const { return bvh->nodes.size(); }
  ChildRef child(std::uint32_t n, int side) const {
    const std::int32_t r = bvh->nodes[n].child[side];
    if (r >= 0) return {kInner, static_cast<std::uint32_t>(r), 0};
    if (r == MBVH_EMPTY) return {kEmpty, 0, 0};
    const Leaf& l = (*leaves)[static_cast<std::size_t>(~r)];
    return {kLeaf, static_cast<std::uint32_t>(~r), l.count};
  }
  Box box(std::uint32_t n, int side) const {
    const std::int32_t r = bvh->nodes[n].child[side];
    return r == MBVH_EMPTY ? Box{} : bvh->box(r);
  }
  const fmt::Voxel& voxel(std::uint32_t n, int side) const {
    return vox[static_cast<std::size_t>(bvh->nodes[n].child[side])];
  }
  fmt::Link ext(std::uint32_t) const { return {}; }
  void append_tris(std::uint32_t leaf, std::vector<Tri>& out) const {
    const Leaf& l = (*leaves)[leaf];
    for (std::uint32_t i = 0; i < l.count; ++i) {
      Tri t = (*tris)[l.first + i];
      std::uint32_t local;
      std::memcpy(&local, &t.v0[3], 4);
      const std::uint32_t global = (*ids)[local];
      const std::uint32_t alb = albedo ? src->albedo_index(global) : 0;
      const float zero = 0.0f;
      std::memcpy(&t.v0[3], &global, 4);
      std::memcpy(&t.v1[3], &alb, 4);
      std::memcpy(&t.v2[3], &zero, 4);
      out.push_back(t);
    }
  }
};

// The top tree over the buckets: its children inner (top nodes) or external (bucket roots).
struct TopTree {
  struct Node {
    ChildRef child[2];
    Box box;
  };
  std::vector<Node> nodes;
  std::vector<Box> bucket_box;
  std::vector<fmt::Voxel> node_vox, bucket_vox;
  std::vector<fmt::Link> bucket_link;
  std::size_t size() const { return nodes.size(); }
  ChildRef child(std::uint32_t n, int side) const { return nodes[n].child[side]; }
  Box box(std::uint32_t n, int side) const {
    const ChildRef c = nodes[n].child[side];
    return c.kind == kInner ? nodes[c.index].box : bucket_box[c.index];
  }
  const fmt::Voxel& voxel(std::uint32_t n, int side) const {
    const ChildRef c = nodes[n].child[side];
    return c.kind == kInner ? node_vox[c.index] : bucket_vox[c.index];
  }
  fmt::Link ext(std::uint32_t b) const { return bucket_link[b]; }
  void append_tris(std::uint32_t, std::vector<Tri>&) const {}
};

// -- cutting a tree into treelets and blocks

struct PlannedBlock {
  std::uint32_t index = 0, parent = 0, depth = 0;
  std::vector<std::uint32_t> roots;
  bool packed = false;  // complete subtrees (no links below them)
};

/// What one block holds, for its emitter.
struct BlockOut {
  std::uint32_t index = 0, parent = 0, depth = 0;
  std::vector<std::byte> raw;
  std::uint64_t nodes = 0, voxels = 0, links = 0, tris = 0, treelets = 0;
  std::vector<std::uint32_t> ext;  // external children linked from this block (the top tree: buckets)
};

template <class Tree>
class Cutter {
 public:
  // limit: the bytes a block's treelets may take (a block less its head and the padding before
  // its triangles)
  Cutter(const Tree& t, std::uint64_t limit) : t_(t), limit_(limit), full_(t.size()), local_(t.size(), kNotHere) {
    for (std::size_t i = t.size(); i-- > 0;) {  // preorder: children after their parent
      const auto n = static_cast<std::uint32_t>(i);
      std::uint64_t s = own(n);
      for (int side = 0; side < 2; ++side)
        if (const ChildRef c = t.child(n, side); c.kind == kInner) s += full_[c.index];
      full_[i] = s;
    }
  }

  /// Cuts the subtree of `root` into blocks numbered from `first`, the first one's parent block
  /// and depth given, in breadth-first order of the blocks (a parent before its children); calls
  /// emit(BlockOut&&) for each; returns the next free block index.
  template <class Emit>
  std::uint32_t run(std::uint32_t root, std::uint32_t first, std::uint32_t parent, std::uint32_t depth, Emit&& emit) {
    std::uint32_t next = first;
    std::deque<PlannedBlock> queue;
    PlannedBlock rb;
    rb.index = next++;
    rb.parent = parent;
    rb.depth = depth;
    rb.roots = {root};
    rb.packed = full_[root] <= limit_;
    queue.push_back(std::move(rb));
    std::vector<std::uint32_t> order, frontier;
    std::unordered_map<std::uint32_t, fmt::Link> links;
    while (!queue.empty()) {
      const PlannedBlock pb = std::move(queue.front());
      queue.pop_front();
      // -- the block's nodes: its treelet roots first, then each treelet's other nodes
      order.assign(pb.roots.begin(), pb.roots.end());
      frontier.clear();
      for (const std::uint32_t r : pb.roots) {
        if (pb.packed)
          whole(r, order);
        else
          treelet(r, order, frontier);
      }
      for (std::size_t i = 0; i < order.size(); ++i) local_[order[i]] = static_cast<std::uint32_t>(i);
      // -- the frontier's blocks: a subtree that fits a block whole is packed with its
      //    neighbours, a larger one gets a block of its own
      links.clear();
      PlannedBlock* open = nullptr;
      std::uint64_t open_bytes = 0;
      for (const std::uint32_t c : frontier) {
        if (full_[c] <= limit_) {
          if (!open || open_bytes + full_[c] > limit_) {
            PlannedBlock b;
            b.index = next++;
            b.parent = pb.index;
            b.depth = pb.depth + 1;
            b.packed = true;
            queue.push_back(std::move(b));
            open = &queue.back();
            open_bytes = 0;
          }
          links[c] = {open->index, static_cast<std::uint32_t>(open->roots.size())};
          open->roots.push_back(c);
          open_bytes += full_[c];
        } else {
          PlannedBlock b;
          b.index = next++;
          b.parent = pb.index;
          b.depth = pb.depth + 1;
          b.roots = {c};
          links[c] = {b.index, 0};
          queue.push_back(std::move(b));  // deque::push_back keeps `open` valid
        }
      }
      emit(assemble(pb, order, links));
      for (const std::uint32_t n : order) local_[n] = kNotHere;
    }
    return next;
  }

 private:
  std::uint64_t own(std::uint32_t n) const {
    std::uint64_t s = sizeof(fmt::Node);
    for (int side = 0; side < 2; ++side) {
      const ChildRef c = t_.child(n, side);
      if (c.kind == kInner)
        s += sizeof(fmt::Voxel);
      else if (c.kind == kExt)
        s += sizeof(fmt::Voxel) + sizeof(fmt::Link);
      else if (c.kind == kLeaf)
        s += std::uint64_t(c.count) * sizeof(Tri);
    }
    return s;
  }
  unsigned inner_children(std::uint32_t n) const {
    return (t_.child(n, 0).kind == kInner ? 1u : 0u) + (t_.child(n, 1).kind == kInner ? 1u : 0u);
  }
  // Every inner node below r, breadth-first.
  void whole(std::uint32_t r, std::vector<std::uint32_t>& order) const {
    std::size_t at = order.size();
    for (int side = 0; side < 2; ++side)
      if (const ChildRef c = t_.child(r, side); c.kind == kInner) order.push_back(c.index);
    for (; at < order.size(); ++at)
      for (int side = 0; side < 2; ++side)
        if (const ChildRef c = t_.child(order[at], side); c.kind == kInner) order.push_back(c.index);
  }
  // The treelet of r filled breadth-first within the limit (r itself always: a node whose own
  // bytes pass the limit gets an oversized block); the inner children left out go to `frontier`.
  void treelet(std::uint32_t r, std::vector<std::uint32_t>& order, std::vector<std::uint32_t>& frontier) const {
    std::uint64_t bytes = own(r) + sizeof(fmt::Link) * inner_children(r);
    std::deque<std::uint32_t> q;
    for (int side = 0; side < 2; ++side)
      if (const ChildRef c = t_.child(r, side); c.kind == kInner) q.push_back(c.index);
    while (!q.empty()) {
      const std::uint32_t n = q.front();
      q.pop_front();
      const std::uint64_t add = own(n) + sizeof(fmt::Link) * inner_children(n) - sizeof(fmt::Link);
      if (bytes + add > limit_) {
        frontier.push_back(n);
        continue;
      }
      bytes += add;
      order.push_back(n);
      for (int side = 0; side < 2; ++side)
        if (const ChildRef c = t_.child(n, side); c.kind == kInner) q.push_back(c.index);
    }
  }
  BlockOut assemble(const PlannedBlock& pb, const std::vector<std::uint32_t>& order,
                    const std::unordered_map<std::uint32_t, fmt::Link>& links) const {
    BlockOut out;
    out.index = pb.index;
    out.parent = pb.parent;
    out.depth = pb.depth;
    out.treelets = pb.roots.size();
    std::vector<fmt::Node> nodes(order.size());
    std::vector<fmt::Voxel> vox;
    std::vector<fmt::Link> lk;
    std::vector<Tri> tris;
    for (std::size_t i = 0; i < order.size(); ++i) {
      const std::uint32_t n = order[i];
      fmt::Node& d = nodes[i];
      std::memset(&d, 0, sizeof d);
      for (int side = 0; side < 2; ++side) {
        const ChildRef c = t_.child(n, side);
        const Box b = t_.box(n, side);
        d.lo[side][0] = b.lo.x, d.lo[side][1] = b.lo.y, d.lo[side][2] = b.lo.z;
        d.hi[side][0] = b.hi.x, d.hi[side][1] = b.hi.y, d.hi[side][2] = b.hi.z;
        switch (c.kind) {
          case kInner:
          case kExt: {
            if (c.kind == kInner) {
              if (const std::uint32_t at = local_[c.index]; at != kNotHere) {
                d.ref[side] = fmt::kRefInner | at;
              } else {
                d.ref[side] = fmt::kRefLink | static_cast<std::uint32_t>(lk.size());
                lk.push_back(links.at(c.index));
              }
            } else {
              d.ref[side] = fmt::kRefLink | static_cast<std::uint32_t>(lk.size());
              lk.push_back(t_.ext(c.index));
              out.ext.push_back(c.index);
            }
            d.aux[side] = static_cast<std::uint32_t>(vox.size());
            vox.push_back(t_.voxel(n, side));
            break;
          }
          case kLeaf:
            d.ref[side] = fmt::kRefLeaf | static_cast<std::uint32_t>(tris.size());
            d.aux[side] = c.count;
            t_.append_tris(c.index, tris);
            break;
          case kEmpty:
            d.ref[side] = fmt::kRefEmpty;
            d.aux[side] = 0;
            break;
        }
      }
    }
    fmt::BlockHead h{};
    h.magic = fmt::kBlockMagic;
    h.index = pb.index;
    h.nodes = static_cast<std::uint32_t>(nodes.size());
    h.voxels = static_cast<std::uint32_t>(vox.size());
    h.links = static_cast<std::uint32_t>(lk.size());
    h.tris = static_cast<std::uint32_t>(tris.size());
    h.treelets = static_cast<std::uint32_t>(pb.roots.size());
    const fmt::BlockLayout l = fmt::block_layout(h);
    out.raw.assign(l.end, std::byte{0});
    // an empty array's data() may be null, which memcpy may not be given even for 0 bytes
    const auto put = [&](std::uint64_t at, const auto& v) {
      if (!v.empty()) std::memcpy(out.raw.data() + at, v.data(), v.size() * sizeof(v[0]));
    };
    std::memcpy(out.raw.data(), &h, sizeof h);
    put(l.nodes, nodes);
    put(l.voxels, vox);
    put(l.links, lk);
    put(l.tris, tris);
    out.nodes = h.nodes, out.voxels = h.voxels, out.links = h.links, out.tris = h.tris;
    return out;
  }

  static constexpr std::uint32_t kNotHere = 0xFFFFFFFFu;
  const Tree& t_;
  std::uint64_t limit_;
  std::vector<std::uint64_t> full_;   // bytes of each subtree as one treelet
  std::vector<std::uint32_t> local_;  // a node's index in the block being assembled, else kNotHere
};

// -- compressing and writing blocks: a batch compressed on the pool, written in index order of
// arrival (the emitters' fixed order), every block 4 KiB aligned

class BlockWriter {
 public:
  /// Blocks a batch holds: compressed side by side on up to this many workers. A constant, so the
  /// memory the build plans for (and with it the buckets and the file) does not depend on threads.
  static constexpr unsigned kSlots = 8;
  BlockWriter(StreamedOutput& out, const std::string& path, int level, unsigned threads,
              std::vector<fmt::DirEntry>& dir)
      : out_(out),
        path_(path),
        level_(level),
        threads_(std::min(resolve_threads(threads), kSlots)),
        dir_(dir),
        ctx_(threads_, nullptr) {}
  ~BlockWriter() {
    for (ZSTD_CCtx* c : ctx_) ZSTD_freeCCtx(c);
  }
  void add(BlockOut&& b) {
    batch_.push_back(std::move(b));
    if (batch_.size() >= kSlots) flush();
  }
  void flush() {
    if (batch_.empty()) return;
    const std::size_t n = batch_.size();
    std::vector<std::vector<char>> packed(n);
    std::vector<std::uint64_t> sums(n);
    parallel_for(n, 1, threads_, [&](std::size_t b, std::size_t e, unsigned w) {
      if (!ctx_[w]) ctx_[w] = ZSTD_createCCtx();
      if (!ctx_[w]) throw Error(path_ + ": zstd could not make a compression context");
      for (std::size_t i = b; i < e; ++i) {
        const BlockOut& blk = batch_[i];
        sums[i] = hash_bytes(blk.raw.data(), blk.raw.size(), blk.index);
        packed[i].resize(ZSTD_compressBound(blk.raw.size()));
        const std::size_t got =
            ZSTD_compressCCtx(ctx_[w], packed[i].data(), packed[i].size(), blk.raw.data(), blk.raw.size(), level_);
        if (ZSTD_isError(got))
          throw Error(path_ + ": zstd failed on block " + std::to_string(blk.index) + ": " + ZSTD_getErrorName(got));
        packed[i].resize(got);
      }
    });
    static const std::vector<char> zeros(fmt::kAlign, 0);
    for (std::size_t i = 0; i < n; ++i) {
      const BlockOut& blk = batch_[i];
      if (dir_.size() <= blk.index) dir_.resize(blk.index + 1);
      fmt::DirEntry& d = dir_[blk.index];
      d.offset = out_.bytes();
      d.stored_bytes = static_cast<std::uint32_t>(packed[i].size());
      d.raw_bytes = static_cast<std::uint32_t>(blk.raw.size());
      d.checksum = sums[i];
      d.parent_block = blk.parent;
      d.depth = static_cast<std::uint16_t>(blk.depth);
      d.flags = 0;
      out_.write(packed[i].data(), packed[i].size());
      const std::uint64_t pad = fmt::align_up(out_.bytes()) - out_.bytes();
      if (pad) out_.write(zeros.data(), pad);
      stored_ += packed[i].size();
    }
    batch_.clear();
  }
  /// Bytes a batch holds at most: its raw blocks, their compressed copies and the contexts.
  static std::uint64_t memory(std::uint64_t block_bytes, int level) {
    const std::uint64_t ctx = ZSTD_estimateCCtxSize_usingCParams(ZSTD_getCParams(level, block_bytes, 0));
    return kSlots * (2 * block_bytes + 2 * fmt::kAlign + ctx);
  }

 private:
  StreamedOutput& out_;
  std::string path_;
  int level_;
  unsigned threads_;
  std::vector<fmt::DirEntry>& dir_;
  std::vector<ZSTD_CCtx*> ctx_;
  std::vector<BlockOut> batch_;
  std::uint64_t stored_ = 0;
};

// -- the unlinked temporary file of pass 2

class TempFile {
 public:
  TempFile(const std::string& dir, std::uint64_t need) {
    std::string tmpl = (std::filesystem::path(dir) / ".mbvh-lod-XXXXXX").string();
    if (!::mkdtemp(tmpl.data()))
      throw Error("--temp " + dir + ": cannot make a temporary directory there: " + std::strerror(errno));
    const std::string file = tmpl + "/buckets";
    fd_ = ::open(file.c_str(), O_RDWR | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
    const int err = errno;
    if (fd_ >= 0) ::unlink(file.c_str());  // the data lives while the file is open, and goes with it
    ::rmdir(tmpl.c_str());
    if (fd_ < 0) throw Error("--temp " + dir + ": cannot make a temporary file there: " + std::strerror(err));
    struct statvfs vs {};
    if (::fstatvfs(fd_, &vs) == 0) {
      const std::uint64_t free = std::uint64_t(vs.f_bavail) * vs.f_frsize;
      if (free < need) {
        ::close(fd_);
        throw Error("--temp " + dir + ": the bucket files need " + bytes_str(need) + " of disk, but only " +
                    bytes_str(free) + " is free there; name another directory with --temp");
      }
    }
    dir_ = dir;
  }
  ~TempFile() {
    if (fd_ >= 0) ::close(fd_);
  }
  std::uint64_t append(const void* p, std::size_t n) {
    const std::uint64_t at = size_;
    const char* c = static_cast<const char*>(p);
    while (n > 0) {
      const ssize_t w = ::pwrite(fd_, c, n, static_cast<off_t>(size_));
      if (w < 0 && errno == EINTR) continue;
      if (w <= 0) throw Error("--temp " + dir_ + ": writing the bucket file failed: " + std::strerror(errno));
      c += w, n -= static_cast<std::size_t>(w), size_ += static_cast<std::uint64_t>(w);
    }
    return at;
  }
  void read(void* p, std::size_t n, std::uint64_t off) const {
    char* c = static_cast<char*>(p);
    while (n > 0) {
      const ssize_t r = ::pread(fd_, c, n, static_cast<off_t>(off));
      if (r < 0 && errno == EINTR) continue;
      if (r <= 0)
        throw Error("--temp " + dir_ +
                    ": reading the bucket file failed: " + (r < 0 ? std::strerror(errno) : "short read"));
      c += r, n -= static_cast<std::size_t>(r), off += static_cast<std::uint64_t>(r);
    }
  }

 private:
  int fd_ = -1;
  std::uint64_t size_ = 0;
  std::string dir_;
};

// -- the plan: buckets as parts of the Morton range, the top tree as its splits

struct Bucket {
  std::uint32_t begin = 0, end = 0;                             // Morton codes [begin, end)
  std::uint64_t count = 0;                                      // non-degenerate triangles
  std::uint32_t depth = 0;                                      // of its root in the model (the root's children: 1)
  std::vector<std::pair<std::uint64_t, std::uint32_t>> chunks;  // its parts of the temporary file
};

}  // namespace

BuildReport build(const TriangleSource& src, const std::string& out_path, const BuildOptions& opt_in) {
  const auto t0 = Clock::now();
  const std::string name = src.name();
  BuildOptions opt = opt_in;
  auto progress = [&](const char* phase, double f) {
    if (opt.progress) opt.progress(phase, f);
  };
  // -- options
  if (opt.block_bytes < (16u << 10) || opt.block_bytes > (256u << 20))
    throw Error("--block " + std::to_string(opt.block_bytes) + ": a block must be 16K to 256M bytes");
  if (opt.zstd_level < 1 || opt.zstd_level > 19)
    throw Error("--zstd-level " + std::to_string(opt.zstd_level) + ": must be 1 to 19");
  if (opt.tree.quality != BuildQuality::low && opt.tree.quality != BuildQuality::medium)
    throw Error(
        std::string("--quality ") + to_string(opt.tree.quality) +
        ": a .mlod is built with quality low or medium (high may reference a triangle from several leaves, none "
        "builds no tree)");
  if (!std::isfinite(opt.tree.traversal_cost) || opt.tree.traversal_cost < 0)
    throw Error("BuildOptions::traversal_cost " + std::to_string(opt.tree.traversal_cost) + " must be finite and >= 0");
  const MemoryBudget mb = opt.memory_budget ? MemoryBudget{opt.memory_budget, "--memory"} : memory_budget();
  const std::uint64_t budget = mb.bytes;
  const unsigned threads = resolve_threads(opt.threads);
  opt.tree.threads = opt.threads;
  opt.tree.progress = nullptr;
  const std::string temp_dir = !opt.temp_dir.empty() ? opt.temp_dir
                                                     : (std::filesystem::path(out_path).has_parent_path()
                                                            ? std::filesystem::path(out_path).parent_path().string()
                                                            : std::string("."));
  // what the build holds besides its buckets: the compression batch, the directory and the plan
  const std::uint64_t reserve = (std::uint64_t(4) << 20) + BlockWriter::memory(opt.block_bytes, opt.zstd_level);
  // how messages name the budget, and a size to ask for (whole MiB, rounded up)
  const std::string budget_name = opt.memory_budget ? "--memory " + bytes_str(budget)
                                                    : "the memory budget " + bytes_str(budget) + " (" + mb.source + ")";
  auto at_least = [](std::uint64_t b) { return bytes_str((b + (1u << 20) - 1) / (1u << 20) * (1u << 20)); };
  if (budget <= reserve + 1024 * kBucketBytesPerTriangle)
    throw Error(
        name + ": " + budget_name + " is too small: the build needs " + bytes_str(reserve) +
        " to compress blocks (8 at a time) and room for a bucket of 1024 triangles; raise --memory to at least " +
        at_least(reserve + 1024 * kBucketBytesPerTriangle + 1));
  // triangles one bucket may hold: within the budget, and within one in-core scene
  const std::uint64_t cap = std::min<std::uint64_t>((budget - reserve) / kBucketBytesPerTriangle, kMaxTriangles);
  // the output is checked (and its temporary made) before any pass
  StreamedOutput out(OutputTarget{"", out_path});

  // -- pass 0: a box for the Morton grid, when the source does not know one
  Box gbox;
  if (const auto kb = known_bounds(src))
    gbox = *kb;
  else {
    progress("bounds", 0);
    src.for_each_chunk([&](std::uint64_t, std::span<const SourceTri> t) {
      for (const SourceTri& s : t)
        for (int k = 0; k < 3; ++k)
          if (std::isfinite(s.v[3 * k]) && std::isfinite(s.v[3 * k + 1]) && std::isfinite(s.v[3 * k + 2]))
            gbox.grow(Vec3f{s.v[3 * k], s.v[3 * k + 1], s.v[3 * k + 2]});
    });
  }
  Grid grid;
  {
    // the histogram takes at most 1/16 of the budget, at most 2^8 cells an axis
    grid.bits = 1;
    while (grid.bits < 8 && (std::uint64_t(1) << (3 * (grid.bits + 1))) * 4 <= budget / 16) ++grid.bits;
    for (int a = 0; a < 3; ++a) {
      const float lo = gbox.empty() ? 0.0f : gbox.lo[a], hi = gbox.empty() ? 0.0f : gbox.hi[a];
      grid.lo[a] = lo;
      const float ext = hi - lo;
      const float scale = ext > 0 ? static_cast<float>(1u << grid.bits) / ext : 0.0f;
      grid.scale[a] = std::isfinite(scale) ? scale : 0.0f;
    }
  }

  // -- pass 1: checks, counts, bounds, the centroid histogram
  std::vector<std::uint32_t> hist(grid.cells(), 0);
  std::uint64_t total = 0, kept = 0;
  build::FastBox bounds;
  float largest = 0;  // of the non-degenerate triangles, too small ones included
  std::optional<std::pair<std::uint64_t, SourceTri>> tiny, beyond;  // the first of each fault
  constexpr std::size_t kGrain = 4096;
  struct Part {
    build::FastBox box;
    float mag = 0;
    std::uint64_t tiny = UINT64_MAX, beyond = UINT64_MAX, bad = UINT64_MAX, kept = 0;
  };
  std::vector<std::uint32_t> codes;  // per triangle of a chunk: its cell, or UINT32_MAX (degenerate)
  std::vector<Part> parts;
  // codes of one chunk on the pool (pass 1 and 2 share it)
  auto classify = [&](std::uint64_t first, std::span<const SourceTri> t) {
    if (first + t.size() > kMaxModelTriangles)
      throw Error(name + ": more than " + std::to_string(kMaxModelTriangles) +
                  " triangles; a .mlod model names its triangles with 32-bit prim ids");
    codes.resize(t.size());
    parts.assign((t.size() + kGrain - 1) / kGrain, Part{});
    parallel_for(t.size(), kGrain, threads, [&](std::size_t b, std::size_t e, unsigned) {
      Part& p = parts[b / kGrain];
      for (std::size_t i = b; i < e; ++i) {
        const SourceTri& s = t[i];
        codes[i] = UINT32_MAX;
        bool finite = true;
        for (float v : s.v) finite = finite && std::isfinite(v);
        if (!finite) {
          p.bad = std::min<std::uint64_t>(p.bad, first + i);
          continue;
        }
        const double a2 = area2_of(s);
        if (a2 == 0) continue;
        float c[3], lo[3], hi[3];
        centroid_of(s, c, lo, hi);
        for (int a = 0; a < 3; ++a) p.mag = std::max({p.mag, std::fabs(lo[a]), std::fabs(hi[a])});
        if (build::too_small(a2)) {
          p.tiny = std::min<std::uint64_t>(p.tiny, first + i);
          continue;
        }
        for (int a = 0; a < 3; ++a)
          if (std::fabs(lo[a]) > kMaxCoordinate || std::fabs(hi[a]) > kMaxCoordinate)
            p.beyond = std::min<std::uint64_t>(p.beyond, first + i);
        p.box.grow_rows(lo, hi);
        ++p.kept;
        codes[i] = grid.code(c);
      }
    });
  };
  progress("pass 1", 0);
  src.for_each_chunk([&](std::uint64_t first, std::span<const SourceTri> t) {
    if (first != total)
      throw Error(name + ": the source's chunks are not in order (triangle " + std::to_string(first) + " after " +
                  std::to_string(total) + ")");
    classify(first, t);
    for (const Part& p : parts) {
      if (p.bad != UINT64_MAX)
        throw Error(name + ": triangle " + std::to_string(p.bad) +
                    " has a non-finite coordinate; vertices must be finite");
      if (p.tiny != UINT64_MAX && !tiny) tiny.emplace(p.tiny, t[p.tiny - first]);
      if (p.beyond != UINT64_MAX && !beyond) beyond.emplace(p.beyond, t[p.beyond - first]);
      bounds.grow(p.box);
      largest = std::max(largest, p.mag);
      kept += p.kept;
    }
    for (std::size_t i = 0; i < t.size(); ++i)
      if (codes[i] != UINT32_MAX) ++hist[codes[i]];
    total += t.size();
  });
  // the faults Accel::build refuses, in its order: a scene too small as a whole, a triangle too
  // small, a coordinate beyond the traced range
  if (tiny || kept > 0) {
    if (largest < kMinSceneScale) {
      char buf[256];
      std::snprintf(
          buf, sizeof buf,
          ": the largest coordinate magnitude is %.9g, below 2^-36 (%.3g), the smallest scene scale mbvh traces "
          "exactly (float products of three coordinates would underflow); rescale the scene",
          double(largest), double(kMinSceneScale));
      throw Error(name + buf);
    }
  }
  if (tiny) {
    const SourceTri& s = tiny->second;
    char buf[400];
    std::snprintf(
        buf, sizeof buf,
        ": triangle %llu has area %.3g, below 2^-110 (%.3g, accel.h kMinTriangleArea), the smallest triangle mbvh "
        "traces exactly (float products of its edges would underflow and rays pass through it); rescale the scene "
        "or remove the triangle",
        static_cast<unsigned long long>(tiny->first), 0.5 * std::sqrt(area2_of(s)), double(kMinTriangleArea));
    throw Error(name + buf);
  }
  if (beyond) {
    char buf[400];
    std::snprintf(
        buf, sizeof buf,
        ": triangle %llu has a coordinate beyond +-2^40 (%.3g), the range mbvh traces exactly (float products of "
        "three coordinates would overflow); rescale the scene",
        static_cast<unsigned long long>(beyond->first), double(kMaxCoordinate));
    throw Error(name + buf);
  }
  if (kept == 0)
    throw Error(name + ": the scene has no non-degenerate triangle (" + std::to_string(total) +
                " triangles, all degenerate)");
  progress("pass 1", 1);

  // -- the plan: the Morton range split by its top bits until every part fits a bucket
  for (std::size_t i = 1; i < hist.size(); ++i) hist[i] += hist[i - 1];  // prefix sums (kept < 2^32)
  auto count_of = [&](std::uint32_t b, std::uint32_t e) -> std::uint64_t {
    return hist[e - 1] - (b ? hist[b - 1] : 0);
  };
  std::vector<Bucket> buckets;
  TopTree top;
  // returns the child reference of the part [b, b + size)
  std::function<ChildRef(std::uint32_t, std::uint32_t, std::uint32_t)> plan = [&](std::uint32_t b, std::uint32_t size,
                                                                                  std::uint32_t depth) -> ChildRef {
    const std::uint64_t n = count_of(b, b + size);
    if (n == 0) return {kEmpty, 0, 0};
    if (n <= cap) {
      Bucket k;
      k.begin = b, k.end = b + size, k.count = n, k.depth = depth;
      buckets.push_back(std::move(k));
      return {kExt, static_cast<std::uint32_t>(buckets.size() - 1), 0};
    }
    if (size == 1) {
      const Vec3f p = grid.cell_center(b);
      char where[160];
      std::snprintf(where, sizeof where, " (around %.6g, %.6g, %.6g)", double(p.x), double(p.y), double(p.z));
      throw Error(name + ": " + std::to_string(n) + " triangles have their centroids in one cell of the " +
                  std::to_string(1u << grid.bits) + "^3 bucketing grid" + where + ", more than the " +
                  std::to_string(cap) + " one bucket holds within " + budget_name + "; raise --memory to at least " +
                  at_least(reserve + n * kBucketBytesPerTriangle));
    }
    // a split with an empty side is no node: the other side takes its place
    const std::uint64_t nl = count_of(b, b + size / 2);
    if (nl == 0) return plan(b + size / 2, size / 2, depth);
    if (nl == n) return plan(b, size / 2, depth);
    const std::uint32_t self = static_cast<std::uint32_t>(top.nodes.size());
    top.nodes.emplace_back();  // preorder: the node before its subtrees
    const ChildRef l = plan(b, size / 2, depth + 1);
    const ChildRef r = plan(b + size / 2, size / 2, depth + 1);
    top.nodes[self].child[0] = l;
    top.nodes[self].child[1] = r;
    return {kInner, self, 0};
  };
  const ChildRef root_ref = plan(0, grid.cells(), 0);
  hist = {};
  hist.shrink_to_fit();
  const bool bucketed = root_ref.kind == kInner;
  // a bucket's depth counts the top tree's levels above it; with one bucket its root is the root
  for (Bucket& k : buckets) k.depth = bucketed ? k.depth : 0;

  // -- the top tree's blocks: planned now (their indices come first), written last
  const std::uint64_t limit = opt.block_bytes - sizeof(fmt::BlockHead) - 16;
  std::uint32_t next_block = 0;
  std::vector<std::uint32_t> bucket_parent(buckets.size(), 0), bucket_block_depth(buckets.size(), 0);
  if (bucketed) {
    top.bucket_box.assign(buckets.size(), Box{});
    top.node_vox.assign(top.nodes.size(), fmt::Voxel{});
    top.bucket_vox.assign(buckets.size(), fmt::Voxel{});
    top.bucket_link.assign(buckets.size(), fmt::Link{});
    Cutter<TopTree> cut(top, limit);
    next_block = cut.run(0, 0, 0, 0, [&](BlockOut&& b) {
      for (const std::uint32_t k : b.ext) bucket_parent[k] = b.index, bucket_block_depth[k] = b.depth + 1;
    });
  }

  // -- the output: the header's place, the albedo table
  std::vector<char> zeros(fmt::kAlign, 0);
  out.write(zeros.data(), fmt::kHeaderBytes);
  const std::vector<Vec3f> albedos = src.albedos();
  const bool with_albedo = !albedos.empty();
  const std::uint64_t albedo_at = out.bytes();
  out.write(albedos.data(), albedos.size() * sizeof(Vec3f));
  const std::uint64_t albedo_hash_at = out.bytes();
  const std::uint64_t placeholder = 0;
  out.write(&placeholder, sizeof placeholder);
  out.write(zeros.data(), fmt::align_up(out.bytes()) - out.bytes());

  std::vector<fmt::DirEntry> dir;
  BlockWriter writer(out, out_path, opt.zstd_level, opt.threads, dir);
  BuildReport rep;
  rep.triangles = total;
  rep.buckets = buckets.size();
  std::uint64_t tri_records = 0;
  auto count_block = [&](const BlockOut& b) {
    rep.nodes += b.nodes, rep.voxels += b.voxels, rep.treelets += b.treelets, rep.raw_bytes += b.raw.size();
    tri_records += b.tris;
  };
  std::uint64_t links = 0;

  // -- pass 2: the triangles into their buckets' parts of the temporary file
  std::optional<TempFile> temp;
  if (bucketed) {
    temp.emplace(temp_dir, kept * kRecordBytes);
    const std::uint64_t room = budget > reserve ? budget - reserve : 0;
    std::uint64_t per = std::min<std::uint64_t>(std::uint64_t(1) << 20, room / 2 / buckets.size());
    per = per / kRecordBytes * kRecordBytes;
    if (per < 64 * kRecordBytes)
      throw Error(name + ": " + std::to_string(buckets.size()) + " buckets need more buffers than " + budget_name +
                  " leaves; raise --memory");
    std::vector<std::uint32_t> starts(buckets.size());
    for (std::size_t k = 0; k < buckets.size(); ++k) starts[k] = buckets[k].begin;
    std::vector<std::vector<char>> buf(buckets.size());
    std::vector<std::uint64_t> seen(buckets.size(), 0);
    auto spill = [&](std::size_t k) {
      if (buf[k].empty()) return;
      const std::uint64_t at = temp->append(buf[k].data(), buf[k].size());
      buckets[k].chunks.emplace_back(at, static_cast<std::uint32_t>(buf[k].size()));
      buf[k].clear();
    };
    std::uint64_t streamed = 0;
    progress("pass 2", 0);
    src.for_each_chunk([&](std::uint64_t first, std::span<const SourceTri> t) {
      classify(first, t);
      for (std::size_t i = 0; i < t.size(); ++i) {
        if (codes[i] == UINT32_MAX) continue;
        const auto it = std::upper_bound(starts.begin(), starts.end(), codes[i]);
        const std::size_t k = static_cast<std::size_t>(it - starts.begin()) - 1;
        if (it == starts.begin() || codes[i] >= buckets[k].end)
          throw Error(name + ": the source changed between passes (triangle " + std::to_string(first + i) + ")");
        std::vector<char>& b = buf[k];
        if (b.capacity() < per) b.reserve(per);
        const std::size_t at = b.size();
        b.resize(at + kRecordBytes);
        std::memcpy(b.data() + at, &t[i], sizeof(SourceTri));
        const auto id = static_cast<std::uint32_t>(first + i);
        std::memcpy(b.data() + at + sizeof(SourceTri), &id, 4);
        ++seen[k];
        if (b.size() + kRecordBytes > per) spill(k);
      }
      streamed += t.size();
      progress("pass 2", static_cast<double>(streamed) / static_cast<double>(total));
    });
    for (std::size_t k = 0; k < buckets.size(); ++k) spill(k);
    buf = {};
    for (std::size_t k = 0; k < buckets.size(); ++k)
      if (seen[k] != buckets[k].count)
        throw Error(name + ": the source changed between passes (bucket " + std::to_string(k) + " got " +
                    std::to_string(seen[k]) + " triangles, pass 1 counted " + std::to_string(buckets[k].count) + ")");
    release_free_heap();
  }

  // -- each bucket: read, built, its voxels summed, cut into blocks and written
  std::vector<Sums> bucket_sums(buckets.size());
  unsigned depth = 0;
  std::uint64_t done_tris = 0;
  for (std::size_t k = 0; k < buckets.size(); ++k) {
    progress("buckets", static_cast<double>(done_tris) / static_cast<double>(kept));
    done_tris += buckets[k].count;
    Bucket& bk = buckets[k];
    Scene scene;
    scene.name =
        bucketed ? name + " (bucket " + std::to_string(k) + " of " + std::to_string(buckets.size()) + ")" : name;
    std::vector<std::uint32_t> ids;
    allocating(scene.name, bk.count * 52, [&] {
      scene.vertices.reserve(3 * bk.count);
      scene.triangles.reserve(bk.count);
      ids.reserve(bk.count);
    });
    auto take = [&](const SourceTri& t, std::uint32_t id) {
      append_triangles(scene, std::span<const SourceTri>(&t, 1));
      ids.push_back(id);
    };
    if (!bucketed) {
      src.for_each_chunk([&](std::uint64_t first, std::span<const SourceTri> t) {
        classify(first, t);
        for (std::size_t i = 0; i < t.size(); ++i)
          if (codes[i] != UINT32_MAX) {
            if (ids.size() == bk.count) throw Error(name + ": the source changed between passes (more triangles)");
            take(t[i], static_cast<std::uint32_t>(first + i));
          }
      });
    } else {
      std::vector<char> rb;
      for (const auto& [at, n] : bk.chunks) {
        rb.resize(n);
        temp->read(rb.data(), n, at);
        for (std::size_t o = 0; o + kRecordBytes <= n; o += kRecordBytes) {
          SourceTri t;
          std::uint32_t id;
          std::memcpy(&t, rb.data() + o, sizeof t);
          std::memcpy(&id, rb.data() + o + sizeof t, 4);
          take(t, id);
        }
      }
      bk.chunks = {};
    }
    if (ids.size() != bk.count)
      throw Error(name + ": the source changed between passes (bucket " + std::to_string(k) + " has " +
                  std::to_string(ids.size()) + " triangles, pass 1 counted " + std::to_string(bk.count) + ")");
    codes = {};
    std::unique_ptr<Accel> acc = Accel::build(scene, opt.tree);
    scene = Scene();
    release_free_heap();
    const Bvh2& bvh = acc->bvh2();
    if (acc->degenerate_triangles() != 0)
      throw Error(name + ": internal: bucket " + std::to_string(k) + " built with degenerate triangles");
    depth = std::max(depth, bk.depth + bvh.nodes[0].height);

    // -- voxels bottom-up: subtrees in parallel below the top levels, each node's sums its children's
    BucketTree tree;
    tree.bvh = &bvh;
    tree.leaves = &acc->leaves();
    tree.tris = &acc->tris();
    tree.ids = &ids;
    tree.src = &src;
    tree.albedo = with_albedo;
    tree.vox.assign(bvh.nodes.size(), fmt::Voxel{});
    const Vec3f grey{0.7f, 0.7f, 0.7f};
    auto leaf_sums = [&](std::uint32_t leaf) {
      Sums s;
      const Leaf& l = acc->leaves()[leaf];
      for (std::uint32_t i = 0; i < l.count; ++i) {
        const Tri& t = acc->tris()[l.first + i];
        Vec3f al = grey;
        if (with_albedo) {
          std::uint32_t local;
          std::memcpy(&local, &t.v0[3], 4);
          const std::uint32_t a = src.albedo_index(ids[local]);
          al = a < albedos.size() ? albedos[a] : grey;
        }
        s.add_triangle(t.v0, t.v1, t.v2, al);
      }
      return s;
    };
    // node n's sums: its leaf children's, and `inner(child)` for its inner children
    const auto children_sums = [&](std::uint32_t n, auto&& inner) {
      Sums s;
      for (int side = 0; side < 2; ++side) {
        const std::int32_t r = bvh.nodes[n].child[side];
        if (r == MBVH_EMPTY) continue;
        if (r < 0)
          s.add(leaf_sums(static_cast<std::uint32_t>(~r)));
        else
          s.add(inner(static_cast<std::uint32_t>(r)));
      }
      return s;
    };
    std::function<Sums(std::uint32_t, std::uint32_t)> node_sums = [&](std::uint32_t n, std::uint32_t d) {
      const Sums s = children_sums(n, [&](std::uint32_t c) { return node_sums(c, d + 1); });
      tree.vox[n] = s.voxel(d);
      return s;
    };
    // the top levels' nodes whose subtrees are summed side by side
    std::vector<std::pair<std::uint32_t, std::uint32_t>> jobs;  // node, depth
    {
      std::vector<std::pair<std::uint32_t, std::uint32_t>> level{{0u, bk.depth}};
      std::vector<std::pair<std::uint32_t, std::uint32_t>> upper;
      while (!level.empty() && level.size() < 8 * threads) {
        std::vector<std::pair<std::uint32_t, std::uint32_t>> nextl;
        for (const auto& [n, d] : level) {
          upper.push_back({n, d});
          for (int side = 0; side < 2; ++side)
            if (const std::int32_t r = bvh.nodes[n].child[side]; r >= 0)
              nextl.push_back({static_cast<std::uint32_t>(r), d + 1});
        }
        level.swap(nextl);
      }
      jobs = level;
      std::vector<Sums> job_sums(jobs.size());
      parallel_for(jobs.size(), 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
        for (std::size_t j = b; j < e; ++j) job_sums[j] = node_sums(jobs[j].first, jobs[j].second);
      });
      std::unordered_map<std::uint32_t, const Sums*> done;
      for (std::size_t j = 0; j < jobs.size(); ++j) done[jobs[j].first] = &job_sums[j];
      std::vector<Sums> upper_sums(upper.size());
      for (std::size_t i = upper.size(); i-- > 0;) {  // children were appended after their parents
        const auto [n, d] = upper[i];
        const Sums s = children_sums(n, [&](std::uint32_t c) -> const Sums& { return *done.at(c); });
        tree.vox[n] = s.voxel(d);
        upper_sums[i] = s;
        done[n] = &upper_sums[i];
      }
      bucket_sums[k] = *done.at(0);
    }

    // -- blocks
    Cutter<BucketTree> cut(tree, limit);
    const std::uint32_t first = next_block;
    next_block =
        cut.run(0, first, bucketed ? bucket_parent[k] : 0, bucketed ? bucket_block_depth[k] : 0, [&](BlockOut&& b) {
          count_block(b);
          links += b.links;
          writer.add(std::move(b));
        });
    if (bucketed) {
      top.bucket_box[k] = acc->bounds();
      top.bucket_link[k] = {first, 0};
      top.bucket_vox[k] = bucket_sums[k].voxel(bk.depth);
    }
    acc.reset();
    ids = {};
    release_free_heap();
  }
  writer.flush();

  // -- the top tree: boxes and voxels bottom-up (its nodes are a preorder), then its blocks
  std::uint32_t root_block = 0;
  progress("top", 0);
  if (bucketed) {
    std::vector<Sums> ts(top.nodes.size());
    std::vector<std::uint32_t> tdepth(top.nodes.size(), 0);
    for (std::size_t i = 0; i < top.nodes.size(); ++i)
      for (const ChildRef& c : top.nodes[i].child)
        if (c.kind == kInner) tdepth[c.index] = tdepth[i] + 1;
    for (std::size_t i = top.nodes.size(); i-- > 0;) {
      Box b;
      for (const ChildRef& c : top.nodes[i].child) {
        if (c.kind == kInner) {
          ts[i].add(ts[c.index]);
          b.grow(top.nodes[c.index].box);
        } else {
          ts[i].add(bucket_sums[c.index]);
          b.grow(top.bucket_box[c.index]);
        }
      }
      top.nodes[i].box = b;
      top.node_vox[i] = ts[i].voxel(tdepth[i]);
    }
    Cutter<TopTree> cut(top, limit);
    cut.run(0, 0, 0, 0, [&](BlockOut&& b) {
      count_block(b);
      links += b.links;
      writer.add(std::move(b));
    });
    writer.flush();
  }
  rep.blocks = dir.size();
  rep.depth = depth;
  if (rep.blocks > 0xFFFFFFFFull) throw Error(out_path + ": more than 2^32 - 1 blocks; raise --block");

  // -- pinned: the root block, then the nearest blocks breadth-first while within the limit
  std::uint64_t largest_block = 0;
  for (const fmt::DirEntry& d : dir) largest_block = std::max<std::uint64_t>(largest_block, d.raw_bytes);
  const std::uint64_t pin_limit = std::max<std::uint64_t>(opt.block_bytes, rep.raw_bytes / 256);
  std::uint32_t pinned_blocks = 0;
  {
    std::vector<std::uint32_t> order(dir.size());
    std::iota(order.begin(), order.end(), 0u);
    std::stable_sort(order.begin(), order.end(),
                     [&](std::uint32_t a, std::uint32_t b) { return dir[a].depth < dir[b].depth; });
    std::uint64_t pinned = 0;
    std::uint32_t count = 0;
    for (const std::uint32_t b : order) {  // a block is pinned only under a pinned parent
      const bool root = b == root_block;
      if (!root && (!(dir[dir[b].parent_block].flags & fmt::kDirPinned) || pinned + dir[b].raw_bytes > pin_limit))
        continue;
      dir[b].flags |= fmt::kDirPinned;
      pinned += dir[b].raw_bytes;
      ++count;
    }
    rep.pinned_bytes = pinned;
    pinned_blocks = count;
  }

  // -- the directory, the header, the albedo table's hash
  fmt::FileHeader h{};
  std::memcpy(h.magic, fmt::kMagic, 8);
  h.version = fmt::kVersion;
  h.header_bytes = static_cast<std::uint32_t>(fmt::kHeaderBytes);
  h.node_bytes = sizeof(fmt::Node), h.voxel_bytes = sizeof(fmt::Voxel), h.link_bytes = sizeof(fmt::Link),
  h.tri_bytes = sizeof(Tri);
  h.triangles = total;
  h.tri_records = tri_records;
  h.nodes = rep.nodes, h.voxels = rep.voxels, h.links = links, h.blocks = rep.blocks, h.treelets = rep.treelets;
  const Box bb = bounds.box();
  h.bounds[0] = bb.lo.x, h.bounds[1] = bb.lo.y, h.bounds[2] = bb.lo.z;
  h.bounds[3] = bb.hi.x, h.bounds[4] = bb.hi.y, h.bounds[5] = bb.hi.z;
  h.block_bytes = static_cast<std::uint32_t>(std::max<std::uint64_t>(opt.block_bytes, largest_block));
  h.codec = fmt::kCodecZstd;
  h.depth = depth;
  h.albedos = static_cast<std::uint32_t>(albedos.size());
  h.source_hash = src.hash();
  {
    // the options that shape the file: the tree's (after Accel::build's clamping), the block size
    // and the zstd level; not threads, not the budget
    const std::uint32_t o[7] = {std::max(opt.tree.max_leaf, 1u),
                                std::clamp(opt.tree.bins, 2u, 64u),
                                std::max(opt.tree.leaf_block, 1u),
                                std::clamp(opt.tree.depth_cap, 1u, static_cast<unsigned>(MBVH_BINARY_DEPTH_CAP)),
                                static_cast<std::uint32_t>(opt.tree.quality),
                                opt.block_bytes,
                                static_cast<std::uint32_t>(opt.zstd_level)};
    h.options_hash = hash_bytes(&opt.tree.traversal_cost, sizeof(float), hash_bytes(o, sizeof o));
  }
  h.library_version = MBVH_VERSION_MAJOR << 16 | MBVH_VERSION_MINOR << 8 | MBVH_VERSION_PATCH;
  h.root_block = root_block;
  h.root_node = 0;
  h.pinned_blocks = pinned_blocks;
  h.pinned_bytes = rep.pinned_bytes;
  h.raw_bytes = rep.raw_bytes;
  h.albedo_offset = albedo_at;
  h.directory_offset = out.bytes();
  h.directory_bytes = dir.size() * sizeof(fmt::DirEntry) + 8;
  h.file_bytes = fmt::align_up(h.directory_offset + h.directory_bytes);
  h.checksum = hash_bytes(&h, offsetof(fmt::FileHeader, checksum));
  const std::uint64_t dsum = hash_bytes(dir.data(), dir.size() * sizeof(fmt::DirEntry), h.checksum);
  out.write(dir.data(), dir.size() * sizeof(fmt::DirEntry));
  out.write(&dsum, sizeof dsum);
  out.write(zeros.data(), h.file_bytes - out.bytes());
  const std::uint64_t asum = hash_bytes(albedos.data(), albedos.size() * sizeof(Vec3f), h.checksum);
  out.patch(albedo_hash_at, &asum, sizeof asum);
  out.patch(0, &h, sizeof h);
  out.commit();
  rep.file_bytes = h.file_bytes;
  rep.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  progress("done", 1);
  return rep;
}

}  // namespace mbvh::lod

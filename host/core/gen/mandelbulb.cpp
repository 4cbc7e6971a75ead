// SPDX-License-Identifier: MIT
// mandelbulb.cpp — the power-8 Mandelbulb's surface, streamed (mandelbulb.h).
//
// Field. The inside test iterates White and Nylander's triplex power 8 (D. White, P. Nylander,
// "The Mandelbulb", 2009) in the trig-free polynomial form given by I. Quilez ("Mandelbulb",
// iquilezles.org, 2009; y is the polar axis), in double, with bailout |w|^2 > 4: only + - * / and
// sqrt, which IEEE 754 rounds exactly, so the mesh is the same bits on every machine (the project
// compiles with -ffp-contract=off: no fused multiply-add changes a rounding).
//
// Polygonizer. Marching tetrahedra (the tetrahedral variant of Lorensen and Cline's marching
// cubes, SIGGRAPH 1987) on the Kuhn (Freudenthal) split of every cube into six tetrahedra
// around its main diagonal. The split is the same in every cube, so neighbouring cubes split
// their shared face along the same diagonal and the surface is the level set of one piecewise
// linear field: closed and manifold (every edge in exactly two triangles) by construction, with
// none of marching cubes' ambiguous faces. The field is binary, so a vertex is the midpoint of
// its edge, computed from integer grid coordinates: every triangle meeting at an edge gets the
// same float bits. Grid vertices on the domain's boundary count as outside, so the surface never
// leaves the domain. The price: about twice the triangles of marching cubes at a given RES.
//
// Sparse walk (coarse to fine). The grid is cut into blocks of kBlock^3 cells; the inside test is
// made first at the blocks' corners (the coarse grid). A block is refined (every vertex tested)
// when its corners disagree, or when one is near the surface in the escape-time sense: an
// outside corner that escaped late (at iteration K - 5 or later), or an inside corner whose
// orbit reached |w|^2 > 0.5 (the bailout is 4). Other blocks take their corners' common sign
// at every vertex except those shared with a refined block, which are tested, so the sign field
// is one well-defined field and the mesh stays closed whatever is skipped. What is conservative:
// the mesh is always closed, and every surface passing through a refined block is complete. What
// is not: a feature lying entirely inside a block whose eight corners agree and are all far in
// that escape-time sense (a thin filament or a small bubble between coarse samples) is not seen;
// nothing bounds the field between samples. tests/test_mtri.cpp checks the sparse walk's
// triangles against the dense walk's (every vertex tested): the same bytes at RES 64 and 128;
// docs/massive.md has the counts up to RES 512. The thresholds were chosen by that comparison:
// weaker ones missed part of the dense surface (docs/massive.md).
//
// Order and memory. Blocks are processed one z-layer of blocks at a time (a slab of kBlock cell
// layers), in (y, x) order within a layer, the layer's blocks cut into fixed chunks run on the
// pool; the chunks' triangles are concatenated in chunk order, so the stream is the same at any
// thread count. Memory: a few coarse planes and block-activity layers (O(RES^2 / kBlock^2)) and
// one slab's triangles.
#include "host/core/gen/mandelbulb.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include "host/core/parallel.h"
#include "mbvh/error.h"

namespace mbvh {

int mandelbulb_escape(double px, double py, double pz, unsigned iterations) {
  double peak;
  return mandelbulb_orbit(px, py, pz, iterations, peak);
}

int mandelbulb_orbit(double px, double py, double pz, unsigned iterations, double& peak) {
  double x = px, y = py, z = pz;
  peak = x * x + y * y + z * z;
  if (peak > 4) return 0;
  for (unsigned n = 1; n <= iterations; ++n) {
    const double x2 = x * x, y2 = y * y, z2 = z * z;
    const double x4 = x2 * x2, y4 = y2 * y2, z4 = z2 * z2;
    const double k3 = x2 + z2;
    const double k1 = x4 + y4 + z4 - 6.0 * y2 * z2 - 6.0 * x2 * y2 + 2.0 * z2 * x2;
    const double k4 = x2 - y2 + z2;
    double nx = px, nz = pz;
    // on the polar axis (x = z = 0) the x and z terms vanish (their limit); below 1e-60 k3^7
    // would underflow to 0 and make 0 * inf
    if (k3 > 1e-60) {
      const double k2 = 1.0 / std::sqrt(k3 * k3 * k3 * k3 * k3 * k3 * k3);
      nx = px + 64.0 * x * y * z * (x2 - z2) * k4 * (x4 - 6.0 * x2 * z2 + z4) * k1 * k2;
      nz = pz + -8.0 * y * k4 * (x4 * x4 - 28.0 * x4 * x2 * z2 + 70.0 * x4 * z4 - 28.0 * x2 * z2 * z4 + z4 * z4) * k1 * k2;
    }
    const double ny = py + -16.0 * y2 * k3 * k4 * k4 + k1 * k1;
    x = nx, y = ny, z = nz;
    const double r2 = x * x + y * y + z * z;
    peak = std::max(peak, r2);
    if (r2 > 4) return static_cast<int>(n);
  }
  return -1;
}

std::uint64_t mandelbulb_triangle_estimate(std::uint32_t res) {
  // above the measured counts (docs/massive.md: 131,004 at RES 64, growing x5.4-5.5 a doubling) by 20 % or more
  return static_cast<std::uint64_t>(1.2 * 131004.0 * std::pow(static_cast<double>(std::max<std::uint32_t>(res, 2)) / 64.0, 2.5)) +
         1000;
}

namespace {

constexpr std::uint32_t kBlock = 4;         // cells along each edge of a block of the sparse walk
constexpr std::size_t kChunkBlocks = 16;    // blocks per work item (the order does not depend on it: chunks are concatenated in order)

// Corner codes of the coarse grid.
constexpr std::uint8_t kInside = 1, kOutside = 2, kLate = 4;

class Walk {
public:
  Walk(const MandelbulbOptions& o) : o_(o), r_(o.res), nb_((o.res + kBlock - 1) / kBlock), nc_(nb_ + 1) {}

  MandelbulbStats run(const ChunkFn& emit) {
    std::vector<std::uint32_t> list;
    for (std::uint32_t bz = 0; bz < nb_; ++bz) {
      // -- the coarse planes and block activity this layer and its neighbours need; older ones dropped
      for (std::int64_t l = static_cast<std::int64_t>(bz) - 1; l <= bz + 1; ++l) activity(l);
      std::erase_if(act_, [bz](const auto& e) { return e.first + 1 < static_cast<std::int64_t>(bz); });
      std::erase_if(coarse_, [bz](const auto& e) { return e.first + 1 < static_cast<std::int64_t>(bz); });
      for (int d = 0; d < 3; ++d) layer_[d] = &act_.at(static_cast<std::int64_t>(bz) - 1 + d);
      layer_z_ = bz;
      // -- the blocks to polygonize: refined ones and their neighbours (the shell that closes the mesh)
      near_active(list);
      stats_.blocks += list.size();
      // -- fixed chunks on the pool, concatenated in chunk order
      const std::size_t chunks = (list.size() + kChunkBlocks - 1) / kChunkBlocks;
      std::vector<std::vector<SourceTri>> out(chunks);
      std::atomic<std::uint64_t> evals{0};
      parallel_for(list.size(), kChunkBlocks, o_.threads, [&](std::size_t lo, std::size_t hi, unsigned) {
        std::uint64_t e = 0;
        std::vector<SourceTri>& tris = out[lo / kChunkBlocks];
        for (std::size_t i = lo; i < hi; ++i) polygonize_block(list[i] % nb_, list[i] / nb_, bz, tris, e);
        evals += e;
      });
      stats_.evaluations += evals;
      std::uint64_t slab = 0;
      for (const auto& t : out) slab += t.size();
      stats_.peak_buffer = std::max<std::uint64_t>(stats_.peak_buffer, slab * sizeof(SourceTri));
      for (const auto& t : out) {
        if (t.empty()) continue;
        emit(stats_.triangles, t);
        stats_.triangles += t.size();
      }
    }
    return stats_;
  }

private:
  // -- the grid: vertex index i in 0..res, doubled (midpoint) index m in 0..2 res
  double grid(std::uint64_t m) const { return static_cast<double>(m) * 1.2 / static_cast<double>(r_) - 1.2; }
  bool boundary(std::uint32_t i, std::uint32_t j, std::uint32_t k) const {
    return i == 0 || j == 0 || k == 0 || i == r_ || j == r_ || k == r_;
  }
  int escape(std::uint32_t i, std::uint32_t j, std::uint32_t k) const {
    if (boundary(i, j, k)) return 0;
    return mandelbulb_escape(grid(2ull * i), grid(2ull * j), grid(2ull * k), o_.iterations);
  }
  std::uint32_t coarse_index(std::int64_t c) const { return static_cast<std::uint32_t>(std::min<std::int64_t>(c * kBlock, r_)); }

  // The coarse plane cz (corner codes, nc x nc), made on first use.
  const std::vector<std::uint8_t>& coarse(std::int64_t cz) {
    auto it = coarse_.find(cz);
    if (it != coarse_.end()) return it->second;
    std::vector<std::uint8_t>& p = coarse_[cz];
    p.assign(static_cast<std::size_t>(nc_) * nc_, 0);
    std::atomic<std::uint64_t> evals{0};
    parallel_for(nc_, 1, o_.threads, [&](std::size_t lo, std::size_t hi, unsigned) {
      for (std::size_t cy = lo; cy < hi; ++cy)
        for (std::uint32_t cx = 0; cx < nc_; ++cx) {
          const std::uint32_t i = coarse_index(cx), j = coarse_index(static_cast<std::int64_t>(cy)), k = coarse_index(cz);
          double peak = 0;
          const int n = boundary(i, j, k) ? 0 : mandelbulb_orbit(grid(2ull * i), grid(2ull * j), grid(2ull * k), o_.iterations, peak);
          const bool late = n >= 0 ? o_.late > 0 && static_cast<std::int64_t>(n) + o_.late >= o_.iterations + 1 : peak > o_.near_peak;
          p[cy * nc_ + cx] = static_cast<std::uint8_t>((n < 0 ? kInside : kOutside) | (late ? kLate : 0));
        }
      evals += (hi - lo) * nc_;
    });
    stats_.evaluations += evals;
    return p;
  }

  // Block activity of layer bz (nb x nb; 1: refined); layers outside the grid are all 0.
  const std::vector<std::uint8_t>& activity(std::int64_t bz) {
    auto it = act_.find(bz);
    if (it != act_.end()) return it->second;
    std::vector<std::uint8_t>& a = act_[bz];
    a.assign(static_cast<std::size_t>(nb_) * nb_, 0);
    if (bz < 0 || bz >= nb_) return a;
    if (o_.dense) {
      std::fill(a.begin(), a.end(), 1);
      return a;
    }
    const std::vector<std::uint8_t>& p0 = coarse(bz);
    const std::vector<std::uint8_t>& p1 = coarse(bz + 1);
    for (std::uint32_t by = 0; by < nb_; ++by)
      for (std::uint32_t bx = 0; bx < nb_; ++bx) {
        std::uint8_t c = 0;
        for (std::uint32_t d = 0; d < 4; ++d) {
          const std::size_t at = (by + (d >> 1)) * nc_ + bx + (d & 1);
          c = static_cast<std::uint8_t>(c | p0[at] | p1[at]);
        }
        a[by * nb_ + bx] = ((c & kInside) && (c & kOutside)) || (c & kLate);
      }
    return a;
  }

  // Whether block (bx, by, bz) is refined; bz within one layer of the layer being polygonized.
  bool active(std::int64_t bx, std::int64_t by, std::int64_t bz) const {
    if (bx < 0 || by < 0 || bx >= nb_ || by >= nb_) return false;
    return (*layer_[bz - layer_z_ + 1])[static_cast<std::size_t>(by) * nb_ + static_cast<std::size_t>(bx)] != 0;
  }
  // The blocks of layer layer_z_ with a refined block among their 26 neighbours or themselves, in
  // (y, x) order: the refined flags of the three layers or-ed, then dilated along x and along y.
  void near_active(std::vector<std::uint32_t>& list) {
    const std::size_t n = nb_;
    zor_.assign(n * n, 0);
    for (const auto* l : layer_)
      for (std::size_t i = 0; i < n * n; ++i) zor_[i] |= (*l)[i];
    row_.assign(n * n, 0);
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t x = 0; x < n; ++x)
        row_[y * n + x] = static_cast<std::uint8_t>(zor_[y * n + x] | (x > 0 ? zor_[y * n + x - 1] : 0) |
                                                    (x + 1 < n ? zor_[y * n + x + 1] : 0));
    list.clear();
    for (std::size_t y = 0; y < n; ++y)
      for (std::size_t x = 0; x < n; ++x)
        if (row_[y * n + x] | (y > 0 ? row_[(y - 1) * n + x] : 0) | (y + 1 < n ? row_[(y + 1) * n + x] : 0))
          list.push_back(static_cast<std::uint32_t>(y * n + x));
  }
  // Whether grid vertex (i, j, k) is a vertex of a refined block.
  bool in_active_block(std::uint32_t i, std::uint32_t j, std::uint32_t k) const {
    const std::uint32_t v[3] = {i, j, k};
    std::int64_t lo[3], hi[3];
    for (int a = 0; a < 3; ++a) {
      hi[a] = std::min<std::int64_t>(v[a] / kBlock, nb_ - 1);
      lo[a] = v[a] % kBlock == 0 && v[a] > 0 ? static_cast<std::int64_t>(v[a] / kBlock) - 1 : hi[a];
    }
    for (std::int64_t z = lo[2]; z <= hi[2]; ++z)
      for (std::int64_t y = lo[1]; y <= hi[1]; ++y)
        for (std::int64_t x = lo[0]; x <= hi[0]; ++x)
          if (active(x, y, z)) return true;
    return false;
  }

  void polygonize_block(std::uint32_t bx, std::uint32_t by, std::uint32_t bz, std::vector<SourceTri>& out,
                        std::uint64_t& evals) const {
    constexpr std::uint32_t V = kBlock + 1;
    const std::uint32_t x0 = bx * kBlock, y0 = by * kBlock, z0 = bz * kBlock;
    const std::uint32_t nx = std::min(kBlock, r_ - x0), ny = std::min(kBlock, r_ - y0), nz = std::min(kBlock, r_ - z0);
    // -- the sign field at the block's vertices: tested where a refined block holds the vertex,
    //    else the corners' common sign
    const bool refined = active(bx, by, bz);
    const bool common = !refined && (coarse_.at(bz)[by * nc_ + bx] & kInside) != 0;
    std::array<std::uint8_t, V * V * V> inside{};
    for (std::uint32_t k = 0; k <= nz; ++k)
      for (std::uint32_t j = 0; j <= ny; ++j)
        for (std::uint32_t i = 0; i <= nx; ++i) {
          bool in = common;
          if (refined || in_active_block(x0 + i, y0 + j, z0 + k)) {
            in = escape(x0 + i, y0 + j, z0 + k) < 0;
            ++evals;
          }
          inside[(k * V + j) * V + i] = in;
        }
    // -- marching tetrahedra, cell by cell in (z, y, x) order
    for (std::uint32_t k = 0; k < nz; ++k)
      for (std::uint32_t j = 0; j < ny; ++j)
        for (std::uint32_t i = 0; i < nx; ++i) {
          std::uint8_t c[8], any = 0, all = 1;
          for (int q = 0; q < 8; ++q) {
            c[q] = inside[((k + (q >> 2)) * V + j + ((q >> 1) & 1)) * V + i + (q & 1)];
            any |= c[q];
            all &= c[q];
          }
          if (any && !all) cell(x0 + i, y0 + j, z0 + k, c, out);
        }
  }

  // The six Kuhn tetrahedra of cell (i, j, k): corners 0, 1 << a, 1 << a | 1 << b, 7 for each
  // ordered pair of axes (a, b). Corner q is at (i + (q & 1), j + (q >> 1 & 1), k + (q >> 2 & 1)).
  void cell(std::uint32_t i, std::uint32_t j, std::uint32_t k, const std::uint8_t* c, std::vector<SourceTri>& out) const {
    static constexpr std::uint8_t kTets[6][4] = {{0, 1, 3, 7}, {0, 1, 5, 7}, {0, 2, 3, 7},
                                                 {0, 2, 6, 7}, {0, 4, 5, 7}, {0, 4, 6, 7}};
    using P = std::array<std::int64_t, 3>;  // doubled grid coordinates
    auto corner = [&](int q) { return P{2 * (i + (q & 1)), 2 * (j + ((q >> 1) & 1)), 2 * (k + ((q >> 2) & 1))}; };
    auto mid = [&](int a, int b) {
      const P pa = corner(a), pb = corner(b);
      return P{(pa[0] + pb[0]) / 2, (pa[1] + pb[1]) / 2, (pa[2] + pb[2]) / 2};
    };
    // Emits triangle (a, b, c), its normal turned along d (from inside to outside; exact in integers).
    auto emit = [&](P a, P b, P cc, const P& d) {
      const P u{b[0] - a[0], b[1] - a[1], b[2] - a[2]}, v{cc[0] - a[0], cc[1] - a[1], cc[2] - a[2]};
      const P n{u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
      if (n[0] * d[0] + n[1] * d[1] + n[2] * d[2] < 0) std::swap(b, cc);
      SourceTri t;
      const P* p[3] = {&a, &b, &cc};
      for (int r = 0; r < 3; ++r)
        for (int e = 0; e < 3; ++e) t.v[r * 3 + e] = static_cast<float>(grid(static_cast<std::uint64_t>((*p[r])[e])));
      out.push_back(t);
    };
    auto dir = [&](int from_in, int to_out) {
      const P a = corner(from_in), b = corner(to_out);
      return P{b[0] - a[0], b[1] - a[1], b[2] - a[2]};
    };
    for (const auto& t : kTets) {
      int in[4], out_[4], ni = 0, no = 0;
      for (int q : t) (c[q] ? in[ni++] : out_[no++]) = q;
      if (ni == 0 || no == 0) continue;
      if (ni == 1) {
        emit(mid(in[0], out_[0]), mid(in[0], out_[1]), mid(in[0], out_[2]), dir(in[0], out_[0]));
      } else if (no == 1) {
        emit(mid(out_[0], in[0]), mid(out_[0], in[1]), mid(out_[0], in[2]), dir(in[0], out_[0]));
      } else {  // a quad: in p, q; out r, s; the cycle pr, ps, qs, qr
        const P pr = mid(in[0], out_[0]), ps = mid(in[0], out_[1]), qs = mid(in[1], out_[1]), qr = mid(in[1], out_[0]);
        const P d = dir(in[0], out_[0]);
        emit(pr, ps, qs, d);
        emit(pr, qs, qr, d);
      }
    }
  }

  MandelbulbOptions o_;
  std::uint32_t r_, nb_, nc_;
  std::map<std::int64_t, std::vector<std::uint8_t>> coarse_, act_;
  const std::vector<std::uint8_t>* layer_[3] = {};  // activity of the layers bz - 1, bz, bz + 1
  std::int64_t layer_z_ = 0;                          // bz
  std::vector<std::uint8_t> zor_, row_;               // near_active's scratch
  MandelbulbStats stats_;
};

}  // namespace

MandelbulbStats generate_mandelbulb(const MandelbulbOptions& opt, const ChunkFn& emit) {
  if (opt.res < 2 || opt.res > 65536) throw Error("gen:mandelbulb: RES " + std::to_string(opt.res) + " must be in [2, 65536]");
  if (opt.iterations < 1 || opt.iterations > 64)
    throw Error("gen:mandelbulb: K " + std::to_string(opt.iterations) + " must be in [1, 64]");
  return Walk(opt).run(emit);
}

}  // namespace mbvh

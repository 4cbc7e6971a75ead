// SPDX-License-Identifier: MIT
// mandelbulb.h — the power-8 Mandelbulb as a triangle stream: the isosurface of its inside test
// on a RES^3 grid over [-1.2, 1.2]^3, generated z-slab by z-slab in a fixed order (the same
// triangles in the same order at any thread count), never held whole.
#pragma once
#include <cstdint>
#include <string>

#include "host/core/source.h"

namespace mbvh {

struct MandelbulbOptions {
  std::uint32_t res = 64;        ///< grid cells along each axis (>= 2)
  std::uint32_t iterations = 8;  ///< K: iterations of the inside test
  unsigned threads = 0;          ///< 0: every hardware thread; the output does not depend on it
  bool dense = false;            ///< evaluate every grid vertex (the reference of the sparse walk)
  /// The sparse walk refines a block whose corners disagree, or whose outside corner escaped at
  /// iteration K + 1 - late or later (0: none), or whose inside corner's orbit reached
  /// |w|^2 > near_peak (5: none). The spec's surface uses the defaults.
  unsigned late = 6;
  double near_peak = 0.5;
};

/// What one generation did (the triangles are what `emit` received).
struct MandelbulbStats {
  std::uint64_t triangles = 0;
  std::uint64_t evaluations = 0;   ///< inside tests made (coarse and fine, repeats included)
  std::uint64_t blocks = 0;        ///< blocks of the sparse walk polygonized
  std::uint64_t peak_buffer = 0;   ///< the largest slab of triangles held at once, in bytes
};

/// Iterations w <- w^8 + p from w = p (White and Nylander's triplex power, in its trig-free
/// polynomial form) until |w|^2 > 4: the iteration n in 0..K at which w_n escaped, or -1 when it
/// did not within K iterations (p is inside). Only + - * / and sqrt in double, so every IEEE
/// machine gets the same answer.
int mandelbulb_escape(double x, double y, double z, unsigned iterations);

/// mandelbulb_escape, also giving the largest |w|^2 of the orbit's points (up to the escape).
int mandelbulb_orbit(double x, double y, double z, unsigned iterations, double& peak);

/// Generates the surface and calls emit(first triangle index, triangles) slab by slab, in order.
/// Throws Error on a bad option; whatever `emit` throws ends the generation.
MandelbulbStats generate_mandelbulb(const MandelbulbOptions& opt, const ChunkFn& emit);

/// Whether `spec` (the part after "gen:") is a plain gen:mandelbulb spec (no @ modifiers), which
/// can be streamed; its options in `out` (threads untouched). Throws Error on bad parameters
/// (as generate_scene). Defined in scene_gen.cpp beside the other generators' parameters.
bool streamed_mandelbulb(const std::string& spec, MandelbulbOptions& out);

/// An upper estimate of the triangles of generate_mandelbulb at `res` (for memory checks made
/// before generating).
std::uint64_t mandelbulb_triangle_estimate(std::uint32_t res);

}  // namespace mbvh

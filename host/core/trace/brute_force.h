// SPDX-License-Identifier: MIT
// brute_force.h — internal: the brute-force oracle's kernels (brute_force.cpp; mbvh::brute_force
// is declared in <mbvh/trace.h>).
#pragma once

namespace mbvh {

/// The loop of mbvh::brute_force: `best` evaluates four triangles' edge functions in one 256-bit
/// step where the CPU has AVX2 (x86-64), `scalar` one triangle at a time. The same answers bit for
/// bit. Process-wide: for the tests that compare the two.
enum class BruteKernels { best, scalar };
void set_brute_kernels(BruteKernels k);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// cache_check.h — the checks a BVH cache entry passes before anything is made from it (cache.cpp):
// its tree is one a build makes (check_tree), and its triangle records are the scene's own
// (check_records). Each returns what is wrong, or an empty string.
#pragma once
#include <cstddef>
#include <string>
#include <vector>

#include "host/core/layouts.h"

namespace mbvh::build {

/// Structure of a loaded binary tree, as a build leaves it: node 0 is the root (parent link none);
/// every child reference is in range and names a node of higher index or a leaf, each inner node
/// but the root and every leaf exactly once; only the root's second slot may be empty (one leaf);
/// every parent link names the node that references it; every height is 1 + its children's
/// largest (a leaf 0); every box is finite, within ±kMaxCoordinate and contains its children's;
/// leaves hold at least one triangle and their ranges cover [0, `tris`) exactly once.
/// O(nodes + leaves + tris) time, one byte per triangle record.
std::string check_tree(const Bvh2& b, const std::vector<Leaf>& leaves, std::size_t tris);

/// The loaded triangle records against `scene` (which the caller has checked has as many
/// triangles as the records' prim ids may name): every record is byte for byte the record the
/// build makes of its scene triangle; every non-degenerate scene triangle is in a leaf (exactly
/// once; with `spatial` — SBVH, BuildQuality::high — at least once, and each of its vertices
/// inside the box of a leaf holding it), no degenerate one is; without `spatial` every vertex lies
/// in its leaf's box; the degenerate triangles number `degenerate`; the triangles are ones the
/// build accepts (finite, indices in range, within the traced range: accel.h). `bounds` gets the
/// box of the non-degenerate triangles (recomputed, never read from the file).
/// O(triangles), parallel over `threads`, one byte per scene triangle.
std::string check_records(const Scene& scene, const Bvh2& b, const std::vector<Leaf>& leaves, const AlignedVector<Tri>& tris,
                          bool spatial, std::size_t degenerate, unsigned threads, Box& bounds);

}  // namespace mbvh::build

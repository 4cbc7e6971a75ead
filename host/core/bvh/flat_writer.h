// SPDX-License-Identifier: MIT
// flat_writer.h — internal to host/core/bvh/: writing a tree built as an upper arena around
// subtrees built apart (the binned SAH's and the LBVH's parallel builds) into the flattened
// binary tree, depth-first, each node and leaf at a place fixed before it is written, so the
// subtrees can be written side by side once their places are known.
#pragma once
#include <algorithm>
#include <array>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <utility>
#include <vector>

#include "host/core/bvh/builder.h"
#include "host/core/huge_pages.h"
#include "host/core/parallel.h"

namespace mbvh {
namespace build {

/// v.resize(n) for each (vector, n) pair, with the new storage's pages first touched on up to
/// `threads` workers: resize value-initialises the elements on one thread, and the first touch of
/// a page (a fault) is the costly part of that, so the pages are faulted in parallel beforehand
/// (bytes written into storage the vector has allocated and not yet constructed; resize then
/// writes every element). The vectors' pages are touched in one parallel_for, and the vectors are
/// then resized side by side, one a task (each resize is serial; they are independent).
template <class... V>
void resize_touched(unsigned threads, std::pair<V*, std::size_t>... vs) {
  constexpr std::size_t kPage = 4096;
  std::array<std::pair<unsigned char*, std::size_t>, sizeof...(V)> runs{};  // first byte, pages
  std::size_t k = 0, pages = 0;
  auto reserve = [&](auto* v, std::size_t n) {
    if (n > v->capacity()) {
      v->reserve(n);
      unsigned char* from = reinterpret_cast<unsigned char*>(v->data() + v->size());
      const std::size_t bytes = (n - v->size()) * sizeof(typename std::remove_pointer_t<decltype(v)>::value_type);
      advise_huge_pages(from, bytes);
      runs[k] = {from, (bytes + kPage - 1) / kPage};
      pages += runs[k].second;
    }
    ++k;
  };
  (reserve(vs.first, vs.second), ...);
  parallel_for(pages, 64, threads, [&](std::size_t b, std::size_t e, unsigned) {
    std::size_t base = 0;  // the runs' pages numbered one after another
    for (const auto& [from, count] : runs) {
      for (std::size_t p = std::max(b, base); p < std::min(e, base + count); ++p) from[(p - base) * kPage] = 0;
      base += count;
    }
  });
  parallel_for(sizeof...(V), 1, threads, [&](std::size_t b, std::size_t e, unsigned) {
    for (std::size_t i = b; i < e; ++i) {
      std::size_t at = 0;  // vector i of the pack
      ((i == at++ ? vs.first->resize(vs.second) : void()), ...);
    }
  });
}

/// Writes arena nodes depth-first at fixed places of `out` (inner nodes from `node`, leaves from
/// `leaf`). On the upper arena (a std::vector<TmpNode>, whose node n holds subtree
/// (*subtree_of)[n] where that is not -1): place() finds where each subtree's inner nodes and
/// leaves start (`at`) and its root's parent, writing nothing; emit() writes the upper nodes and
/// leaves around the subtrees, each subtree root's reference and height taken from sub_ref and
/// sub_height. On a subtree's own arena, emit() writes it whole.
struct FlatWriter {
  Bvh2& out;
  std::vector<Leaf>& leaves;
  std::size_t node = 0, leaf = 0;
  std::size_t largest = 0, forced = 0;
  const std::vector<std::int32_t>* subtree_of = nullptr;                      // per upper node
  const std::vector<std::pair<std::size_t, std::size_t>>* sub_size = nullptr;  // per subtree: inner nodes, leaves
  const std::vector<std::int32_t>* sub_ref = nullptr;                         // per subtree: its root's reference
  const std::vector<std::uint32_t>* sub_height = nullptr;

  void place(const std::vector<TmpNode>& upper, std::size_t n, std::int32_t parent,
             std::vector<std::pair<std::size_t, std::size_t>>& at, std::vector<std::int32_t>& parent_of) {
    const TmpNode& t = upper[n];
    if ((*subtree_of)[n] >= 0) {
      const std::size_t j = static_cast<std::size_t>((*subtree_of)[n]);
      at[j] = {node, leaf};
      parent_of[j] = parent;
      node += (*sub_size)[j].first;
      leaf += (*sub_size)[j].second;
      return;
    }
    if (t.leaf) {
      ++leaf;
      return;
    }
    const std::int32_t self = static_cast<std::int32_t>(node++);
    for (int side = 0; side < 2; ++side)
      if (t.child[side] >= 0) place(upper, static_cast<std::size_t>(t.child[side]), self, at, parent_of);
  }

  /// Writes a subtree's arena (SubNodes) whole; returns the child reference of its node n.
  std::int32_t emit(const SubArena& arena, std::size_t n, std::int32_t parent, std::uint32_t& height) {
    const SubNode& t = arena[n];
    if (t.is_leaf()) {
      leaves[leaf] = {t.a, t.count()};
      out.leaf_boxes[leaf] = t.box();
      largest = std::max<std::size_t>(largest, t.count());
      forced += t.forced() ? 1 : 0;
      height = 0;
      return ~static_cast<std::int32_t>(leaf++);
    }
    const std::int32_t self = static_cast<std::int32_t>(node++);
    Bvh2::Node& d = out.nodes[static_cast<std::size_t>(self)];
    d = {t.box(), {MBVH_EMPTY, MBVH_EMPTY}, parent, 0};
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side) d.child[side] = emit(arena, std::size_t(t.a) + std::size_t(side), self, h[side]);
    height = 1 + std::max(h[0], h[1]);
    d.height = height;
    return self;
  }

  /// Returns the child reference of node n of the upper arena (or of the LBVH's).
  std::int32_t emit(const std::vector<TmpNode>& arena, std::size_t n, std::int32_t parent, std::uint32_t& height) {
    const TmpNode& t = arena[n];
    if (subtree_of && (*subtree_of)[n] >= 0) {
      const std::size_t j = static_cast<std::size_t>((*subtree_of)[n]);
      node += (*sub_size)[j].first;
      leaf += (*sub_size)[j].second;
      height = (*sub_height)[j];
      return (*sub_ref)[j];
    }
    if (t.leaf) {
      leaves[leaf] = {t.begin, t.end - t.begin};
      out.leaf_boxes[leaf] = t.box.box();
      largest = std::max<std::size_t>(largest, t.end - t.begin);
      forced += t.forced ? 1 : 0;
      height = 0;
      return ~static_cast<std::int32_t>(leaf++);
    }
    const std::int32_t self = static_cast<std::int32_t>(node++);
    Bvh2::Node& d = out.nodes[static_cast<std::size_t>(self)];
    d = {t.box.box(), {MBVH_EMPTY, MBVH_EMPTY}, parent, 0};
    std::uint32_t h[2] = {0, 0};
    for (int side = 0; side < 2; ++side)
      if (t.child[side] >= 0) d.child[side] = emit(arena, static_cast<std::size_t>(t.child[side]), self, h[side]);
    height = 1 + std::max(h[0], h[1]);
    d.height = height;
    return self;
  }
};

}  // namespace build
}  // namespace mbvh

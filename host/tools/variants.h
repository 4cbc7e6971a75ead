// SPDX-License-Identifier: MIT
// variants.h — the grid of traversal variants that check and bench walk (VariantGrid), and the
// walk itself: every query x precision x backend x layout x traversal a backend supports, in one
// order, written once.
#pragma once
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "mbvh/backend.h"
#include "mbvh/trace.h"

namespace mbvh {

/// A set of traversal variants: every backend x layout x traversal x query combination.
struct VariantGrid {
  std::vector<std::string> backends{"cpu-scalar"};
  std::vector<Layout> layouts{Layout::mbvh2, Layout::mbvh4, Layout::mbvh8};
  std::vector<Traversal> traversals{Traversal::stack, Traversal::bitstack, Traversal::stack_ordered,
                                    Traversal::bitstack_retest, Traversal::stack_octant,
                                    Traversal::bitstack_octant};
  std::vector<Query> queries{Query::closest, Query::any};
  std::vector<Precision> precisions{Precision::robust};
  std::size_t size() const {
    return backends.size() * layouts.size() * traversals.size() * queries.size() * precisions.size();
  }
};

/// The grid's backends by name, each started once with `options` (throws Error naming a backend
/// that is unknown, not built or cannot start).
std::map<std::string, std::unique_ptr<Backend>> make_backends(const VariantGrid& grid, const BackendOptions& options);

/// Calls fn(backend name, backend, options) for every variant of `grid` that its backend supports
/// (Backend::supports and supports_precision), in the order query, precision, backend, layout,
/// traversal (the outermost first): the order of check's table and bench's records. A backend
/// that supports Traversal::dacrt (on the grid's first layout) gets one dacrt variant per query
/// and precision, after its others, whether or not grid.traversals names dacrt; its layout is the
/// grid's first, which dacrt ignores (reports show "-", layout_label). `backends`
/// holds every backend of the grid (make_backends). Variants left out cost nothing.
void for_each_variant(const VariantGrid& grid, const std::map<std::string, std::unique_ptr<Backend>>& backends,
                      const std::function<void(const std::string& name, Backend& backend, const TraceOptions& options)>& fn);

/// Why `grid` has no variant at all (for_each_variant calls nothing): "no backend supports the
/// requested layout / traversal combinations", naming each backend that traces none of the grid's
/// precisions with the ones it has (a peer of fast precision only: tinybvh).
std::string no_variant_message(const VariantGrid& grid, const std::map<std::string, std::unique_ptr<Backend>>& backends);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// variants.h — the walk over a VariantGrid that check and bench share: every query x precision x
// backend x layout x traversal a backend supports, in one order, written once.
#pragma once
#include <functional>
#include <map>
#include <memory>
#include <string>

#include "mbvh/backend.h"
#include "mbvh/trace.h"

namespace mbvh {

/// The grid's backends by name, each started once with `options` (throws Error naming a backend
/// that is unknown, not built or cannot start).
std::map<std::string, std::unique_ptr<Backend>> make_backends(const VariantGrid& grid, const BackendOptions& options);

/// Calls fn(backend name, backend, options) for every variant of `grid` that its backend supports
/// (Backend::supports and supports_precision), in the order query, precision, backend, layout,
/// traversal (the outermost first): the order of check's table and bench's records. `backends`
/// holds every backend of the grid (make_backends). Variants left out cost nothing.
void for_each_variant(const VariantGrid& grid, const std::map<std::string, std::unique_ptr<Backend>>& backends,
                      const std::function<void(const std::string& name, Backend& backend, const TraceOptions& options)>& fn);

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// variants.cpp — the variant walk of check and bench (variants.h).
#include "host/tools/variants.h"

#include <algorithm>

#include "mbvh/error.h"

namespace mbvh {

std::map<std::string, std::unique_ptr<Backend>> make_backends(const VariantGrid& grid, const BackendOptions& options) {
  std::map<std::string, std::unique_ptr<Backend>> backends;
  for (const auto& name : grid.backends) backends[name] = make_backend(name, options);
  return backends;
}

void for_each_variant(const VariantGrid& grid, const std::map<std::string, std::unique_ptr<Backend>>& backends,
                      const std::function<void(const std::string&, Backend&, const TraceOptions&)>& fn) {
  for (Query q : grid.queries)
    for (Precision pr : grid.precisions)
      for (const auto& name : grid.backends) {
        Backend& b = *backends.at(name);
        const auto options = [&](Layout l, Traversal t) {
          TraceOptions o;
          o.layout = l;
          o.traversal = t;
          o.query = q;
          o.precision = pr;
          return o;
        };
        for (Layout l : grid.layouts)
          for (Traversal t : grid.traversals) {
            if (is_dacrt(t)) continue;  // once below
            TraceOptions o = options(l, t);
            if (l == Layout::automatic || t == Traversal::automatic) {  // auto: what the backend traces for it
              try {
                o = resolve_options(b, o);
              } catch (const Error&) {
                continue;  // no pair fits (a layout the backend lacks)
              }
              if (is_dacrt(o.traversal)) continue;  // once below
            }
            if (!b.supports(o.layout, o.traversal) || !b.supports_precision(pr)) continue;  // e.g. bitstack-retest on MBVH2
            fn(name, b, o);
          }
        // dacrt ignores the layout: one variant (on the grid's first layout), whatever the grid's
        // traversals, for a backend that has it
        if (!grid.layouts.empty() && b.supports(grid.layouts.front(), Traversal::dacrt) && b.supports_precision(pr))
          fn(name, b, options(grid.layouts.front(), Traversal::dacrt));
      }
}

std::string no_variant_message(const VariantGrid& grid, const std::map<std::string, std::unique_ptr<Backend>>& backends) {
  std::string s = "no backend supports the requested layout / traversal combinations";
  for (const auto& name : grid.backends) {
    const Backend& b = *backends.at(name);
    if (std::any_of(grid.precisions.begin(), grid.precisions.end(), [&](Precision p) { return b.supports_precision(p); }))
      continue;
    std::string has;
    for (Precision p : {Precision::robust, Precision::exact, Precision::fast})
      if (b.supports_precision(p)) has += std::string(has.empty() ? "" : ",") + to_string(p);
    s += "; backend '" + name + "' traces none of the precisions asked (it has --precision " + has + ")";
  }
  return s;
}

}  // namespace mbvh

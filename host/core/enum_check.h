// SPDX-License-Identifier: MIT
// enum_check.h — range checks of the public enums at the library's entry points: a value cast
// from an int (Query(7), BuildQuality(7)) is refused with an Error naming the argument and the
// value, before any switch or table indexed by it sees it.
#pragma once
#include <string>

#include "mbvh/accel.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"

namespace mbvh {

namespace enum_detail {
template <class E> struct Names;
// count: the concrete enumerators; has_auto: an `automatic` follows them (Layout, Traversal), which
// the entry points taking TraceOptions resolve (resolve_options) and everything past them refuses.
template <> struct Names<Layout> {
  static constexpr int count = 3;
  static constexpr bool has_auto = true;
  static constexpr const char* type = "Layout";
  static constexpr const char* known = "mbvh2, mbvh4, mbvh8";
};
template <> struct Names<Traversal> {
  static constexpr int count = 10;
  static constexpr bool has_auto = true;
  static constexpr const char* type = "Traversal";
  static constexpr const char* known =
      "stack, bitstack, stack-ordered, bitstack-retest, packet-ranged, packet-partition, packet, dacrt, stack-octant, bitstack-octant";
};
template <> struct Names<Query> {
  static constexpr bool has_auto = false;
  static constexpr int count = 2;
  static constexpr const char* type = "Query";
  static constexpr const char* known = "closest, any";
};
template <> struct Names<Precision> {
  static constexpr bool has_auto = false;
  static constexpr int count = 3;
  static constexpr const char* type = "Precision";
  static constexpr const char* known = "robust, exact, fast";
};
template <> struct Names<BuildQuality> {
  static constexpr bool has_auto = false;
  static constexpr int count = 4;
  static constexpr const char* type = "BuildQuality";
  static constexpr const char* known = "low, medium, high, none";
};
}  // namespace enum_detail

/// Throws Error "<where>: <argument> is <int>, not a <Type> (known: ...)" when `v` is none of
/// E's concrete enumerators (an unresolved `automatic` is refused too, naming it).
template <class E>
void check_enum(E v, const std::string& where, const char* argument);
/// check_enum, letting `automatic` pass (for the entry points that resolve it).
template <class E>
void check_enum_or_auto(E v, const std::string& where, const char* argument) {
  if (enum_detail::Names<E>::has_auto && static_cast<int>(v) == enum_detail::Names<E>::count) return;
  check_enum(v, where, argument);
}
template <class E>
void check_enum(E v, const std::string& where, const char* argument) {
  using N = enum_detail::Names<E>;
  const int i = static_cast<int>(v);
  if (N::has_auto && i == N::count)
    throw Error(where + ": " + argument + " is auto, which must be resolved for a backend first (mbvh::resolve_options)");
  if (i < 0 || i >= N::count)
    throw Error(where + ": " + argument + " is " + std::to_string(i) + ", not a " + N::type + " (known: " + N::known + ")");
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// names.cpp — the names of the public enums (Layout, BuildQuality, Precision, Query, Traversal)
// as the command line and the records spell them: to_string and the parse_* that reverses it.
#include <string>

#include "mbvh/accel.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"

namespace mbvh {

const char* to_string(Layout l) {
  switch (l) {
    case Layout::mbvh2: return "mbvh2";
    case Layout::mbvh4: return "mbvh4";
    case Layout::mbvh8: return "mbvh8";
    case Layout::automatic: return "auto";
  }
  return "?";
}

Layout parse_layout(const std::string& s) {
  if (s == "mbvh2") return Layout::mbvh2;
  if (s == "mbvh4") return Layout::mbvh4;
  if (s == "mbvh8") return Layout::mbvh8;
  if (s == "auto") return Layout::automatic;
  throw Error("unknown layout '" + s + "' (known: mbvh2, mbvh4, mbvh8, auto)");
}

const char* to_string(BuildQuality q) {
  switch (q) {
    case BuildQuality::low: return "low";
    case BuildQuality::medium: return "medium";
    case BuildQuality::high: return "high";
    case BuildQuality::none: return "none";
  }
  return "?";
}

BuildQuality parse_quality(const std::string& s) {
  if (s == "low") return BuildQuality::low;
  if (s == "medium") return BuildQuality::medium;
  if (s == "high") return BuildQuality::high;
  if (s == "none") return BuildQuality::none;
  throw Error("unknown build quality '" + s + "' (known: low, medium, high, none)");
}

const char* to_string(Precision p) {
  switch (p) {
    case Precision::robust: return "robust";
    case Precision::exact: return "exact";
    case Precision::fast: return "fast";
  }
  return "?";
}

Precision parse_precision(const std::string& s) {
  if (s == "robust") return Precision::robust;
  if (s == "exact") return Precision::exact;
  if (s == "fast") return Precision::fast;
  throw Error("unknown precision '" + s + "' (known: robust, exact, fast)");
}

const char* to_string(Query q) { return q == Query::closest ? "closest" : "any"; }
const char* to_string(Traversal t) {
  switch (t) {
    case Traversal::stack: return "stack";
    case Traversal::bitstack: return "bitstack";
    case Traversal::stack_ordered: return "stack-ordered";
    case Traversal::bitstack_retest: return "bitstack-retest";
    case Traversal::packet_ranged: return "packet-ranged";
    case Traversal::packet_partition: return "packet-partition";
    case Traversal::packet: return "packet";
    case Traversal::dacrt: return "dacrt";
    case Traversal::stack_octant: return "stack-octant";
    case Traversal::bitstack_octant: return "bitstack-octant";
    case Traversal::automatic: return "auto";
  }
  return "?";
}

const char* layout_label(const TraceOptions& opt) { return is_dacrt(opt.traversal) ? "-" : to_string(opt.layout); }

Query parse_query(const std::string& s) {
  if (s == "closest") return Query::closest;
  if (s == "any") return Query::any;
  throw Error("unknown query '" + s + "' (known: closest, any)");
}

Traversal parse_traversal(const std::string& s) {
  if (s == "stack") return Traversal::stack;
  if (s == "bitstack") return Traversal::bitstack;
  if (s == "stack-ordered") return Traversal::stack_ordered;
  if (s == "bitstack-retest") return Traversal::bitstack_retest;
  if (s == "packet-ranged") return Traversal::packet_ranged;
  if (s == "packet-partition") return Traversal::packet_partition;
  if (s == "packet") return Traversal::packet;
  if (s == "dacrt") return Traversal::dacrt;
  if (s == "stack-octant") return Traversal::stack_octant;
  if (s == "bitstack-octant") return Traversal::bitstack_octant;
  if (s == "auto") return Traversal::automatic;
  throw Error("unknown traversal '" + s +
              "' (known: stack, bitstack, stack-ordered, bitstack-retest, packet-ranged, packet-partition, packet, dacrt, "
              "stack-octant, bitstack-octant, auto)");
}

}  // namespace mbvh

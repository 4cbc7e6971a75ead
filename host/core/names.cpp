// SPDX-License-Identifier: MIT
// names.cpp — the names of the public enums (Layout, BuildQuality, Precision, Query, Traversal)
// as the command line and the records spell them: to_string and the parse_* that reverses it.
#include <string>

#include "mbvh/accel.h"
#include "mbvh/error.h"
#include "mbvh/trace.h"

namespace mbvh {

const char* to_string(Layout l) { return l == Layout::mbvh2 ? "mbvh2" : l == Layout::mbvh4 ? "mbvh4" : "mbvh8"; }

Layout parse_layout(const std::string& s) {
  if (s == "mbvh2") return Layout::mbvh2;
  if (s == "mbvh4") return Layout::mbvh4;
  if (s == "mbvh8") return Layout::mbvh8;
  throw Error("unknown layout '" + s + "' (known: mbvh2, mbvh4, mbvh8)");
}

const char* to_string(BuildQuality q) {
  return q == BuildQuality::low ? "low" : q == BuildQuality::medium ? "medium" : "high";
}

BuildQuality parse_quality(const std::string& s) {
  if (s == "low") return BuildQuality::low;
  if (s == "medium") return BuildQuality::medium;
  if (s == "high") return BuildQuality::high;
  throw Error("unknown build quality '" + s + "' (known: low, medium, high)");
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
  }
  return "?";
}

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
  throw Error("unknown traversal '" + s +
              "' (known: stack, bitstack, stack-ordered, bitstack-retest, packet-ranged, packet-partition, packet)");
}

}  // namespace mbvh

// SPDX-License-Identifier: MIT
// trace.h — the traversal options every backend takes, the outputs it fills, and the host's
// reference entry points: the scalar traversals over ray batches and the double-precision
// brute force that serves as the oracle.
#pragma once
#include <cmath>
#include <cstdint>
#include <functional>
#include <new>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "mbvh/accel.h"
#include "mbvh/mbvh_layout.h"

namespace mbvh {

/// Per-ray work counters.
struct RayStats {
  std::uint32_t nodes = 0;      ///< inner-node records visited
  std::uint32_t box_tests = 0;  ///< child boxes tested (2, 4 or 8 per MBVH2, MBVH4 or MBVH8 node)
  std::uint32_t leaves = 0;
  std::uint32_t tris = 0;       ///< triangle tests
  std::uint32_t climbs = 0;     ///< parent reads while backtracking (bitstack only)
  std::uint32_t retests = 0;    ///< parent nodes re-tested on a sibling move (bitstack-retest only)
  std::uint32_t max_depth = 0;  ///< peak stack entries (stack) or bitstack levels (bitstack)
  /// Packet traversals only (0 elsewhere): the SIMD operations (a node's pair of box tests, a
  /// triangle test) made on this ray's SIMD ray while the ray was active in it, and all made on
  /// its SIMD ray; the packets' SIMD utilisation is the sum of the first over the sum of the second.
  std::uint32_t lane_ops = 0;
  std::uint32_t group_ops = 0;
};

enum class Query { closest, any };
/// stack / bitstack: the skip-code bitstack of Áfra & Szirmay-Kalos and its stack twin (cyclic
/// order after the nearest child); bitstack_retest / stack_ordered: the bitstack with a parent
/// re-test (full distance order, culling; MBVH4 only) and its Embree-like ordered stack twin
/// (MBVH4 and MBVH8).
/// packet_ranged / packet_partition: coherent packets of rays (Áfra's thesis, ch. 2) over the
/// binary tree (MBVH2) of the build — ranged (Wald, Boulos & Shirley 2007) or partition
/// traversal (Overbeck, Ramamoorthi & Mark 2008) with interval-arithmetic frustum culling; an
/// incoherent packet goes ray by ray through `layout` (the hybrid switch). packet: the faster of
/// the two. In the robust and exact precisions every ray's answer is its single-ray traversal's
/// (closest hit: stack_ordered, any hit and MBVH2: stack) but for rare order-dependent ties
/// (docs/backends.md): the reference (cpu-scalar) traces packet traversals as that traversal,
/// ray by ray.
/// dacrt: divide-and-conquer ray tracing without a hierarchy (Afra 2012, after Keller & Waechter
/// 2011; thesis ch. 6): the dacrt backends trace any build, a build of BuildQuality::none too,
/// from its triangles alone, and ignore the layout (reports show it as "-"). Its answers are
/// packet_single_ray's traversal's up to the same classified ties; the reference traces it as that
/// traversal, ray by ray, on a build with a hierarchy (reference_supports is still false for it:
/// cpu-scalar and the SIMD cpu backends do not list it).
/// stack_octant (MBVH8 only; the C API's MBVH_TRAVERSAL_STACK_OCTANT): the stack walk of Fuetterling, Lojewski, Pfreundt
/// & Ebert (HPG 2017) — every node holds its children's order for each of the eight ray
/// direction octants (made once with the layout), and the walk pushes a node's hit children in
/// its ray's octant order, nearest on top, without sorting them; closest hit keeps each entry's
/// distance and culls it when popped beyond the best hit. The answers are every stack
/// traversal's.
/// bitstack_octant (MBVH8 only; MBVH_TRAVERSAL_BITSTACK_OCTANT): stack_octant's walk without a
/// stack — the MBVH8 bitstack's word keeps each level's pending children by their rank in the
/// octant order, and closest hit re-tests a parent's boxes on a backtrack (once a hit was found)
/// where the stack culls its entries: stack_octant's visit sequence (its stack twin).
/// automatic ("auto"): the backend's fastest exact traversal for the query (on the layout asked, or
/// with the layout it traces fastest when that is automatic too): Backend::fastest's ranking,
/// measured per backend and ISA (docs/library.md, "Defaults"), resolved by resolve_options before
/// anything is prepared or traced. The default of TraceOptions.
enum class Traversal { stack, bitstack, stack_ordered, bitstack_retest, packet_ranged, packet_partition, packet, dacrt, stack_octant, bitstack_octant, automatic };
/// Whether `t` traces packets of rays (the cpu backend's packet traversals).
inline bool is_packet(Traversal t) {
  return t == Traversal::packet_ranged || t == Traversal::packet_partition || t == Traversal::packet;
}
/// Whether `t` is the divide-and-conquer traversal (no hierarchy; the layout is ignored).
inline bool is_dacrt(Traversal t) { return t == Traversal::dacrt; }
/// The single-ray traversal whose answers a packet traversal gives, and which its hybrid switch
/// traces incoherent packets with: closest hit the ordered stack (the faster single-ray closest
/// hit on MBVH4 and MBVH8, docs/benchmarks.md), any hit and MBVH2 (no ordered stack) the stack.
/// The reference traces packet traversals as this traversal, ray by ray.
constexpr Traversal packet_single_ray(Layout l, bool any) {
  return any || l == Layout::mbvh2 ? Traversal::stack : Traversal::stack_ordered;
}
/// The stack-based twin a bitstack traversal must reproduce (itself for stack traversals; stack
/// for the packet traversals, whose every ray's answer is the stack traversal's; itself for dacrt,
/// which has no twin).
Traversal stack_twin(Traversal t);
/// Whether the reference traversals implement the pair (bitstack_retest: MBVH4 only;
/// stack_ordered: MBVH4 and MBVH8; dacrt: never, though trace_reference and trace_one accept it
/// and trace packet_single_ray's traversal for it, ray by ray).
bool reference_supports(Layout layout, Traversal traversal);
/// Accuracy mode (the run-time-vs-error benchmark). robust, the default: the conservative slab
/// test (Ize 2013) and the watertight triangle test (Woop et al. 2013). exact: answers bit-identical
/// on every backend, no FMA contraction, correctly rounded division — which robust already is in
/// mbvh (the same kernels; a separate name so a user can require it, and a backend that cannot
/// promise it, embree, refuses it). fast: the slab test without its far-plane widening and
/// Möller–Trumbore triangles (with FMA and an approximate reciprocal where the backend has them):
/// not bit-identical across backends, and it may leak through shared edges.
enum class Precision { robust, exact, fast };
const char* to_string(Precision p);
Precision parse_precision(const std::string& s);  ///< throws Error on an unknown name
const char* to_string(Query q);
const char* to_string(Traversal t);
Query parse_query(const std::string& s);          ///< throws Error on an unknown name
Traversal parse_traversal(const std::string& s);  ///< throws Error on an unknown name

/// What to trace. The defaults trace the backend's fastest exact traversal for the query
/// (Layout::automatic, Traversal::automatic; resolve_options says which): set layout and traversal
/// to trace a given one, e.g. MBVH4 bitstack, the stackless traversal of Áfra & Szirmay-Kalos.
struct TraceOptions {
  Layout layout = Layout::automatic;
  Traversal traversal = Traversal::automatic;
  Query query = Query::closest;
  bool stats = false;  ///< fill TraceOutput::stats (costs time; off compiles counters away)
  Precision precision = Precision::robust;  ///< accuracy mode
  /// Leaf policy: the build's leaves regrouped for leaf tests of this many triangles at once
  /// (Accel::leaf_variant; the same triangles and boxes, fewer and fuller leaves). 0: the
  /// backend's own choice (Backend::leaf_block: 4 on the SIMD cpu backends, whose leaf packs
  /// hold four triangles, tested eight per pass; 1, the build's own leaves, elsewhere); 1: the build's own.
  /// Answers agree across leaf blocks up to classified ties (DESIGN.md), bit for bit within one.
  unsigned leaf_block = 0;
};

/// The text a report shows for the layout of `opt`: "-" for dacrt (which ignores it), else its name.
const char* layout_label(const TraceOptions& opt);
/// Throws Error naming `who` and the value when opt.leaf_block is above 64 (every backend's and
/// the reference's trace call it first).
void check_leaf_block(const TraceOptions& opt, const std::string& who);
/// Throws Error naming `who`, the field and its value when one of opt's enums (layout,
/// traversal, query, precision) holds none of its enumerators (a value cast from an int), or
/// its leaf block is out of range (check_leaf_block). Backend::prepare and Backend::trace, the
/// reference's trace and the library's other entry points taking TraceOptions call it first.
void check_trace_options(const TraceOptions& opt, const std::string& who);

/// The reference's (cpu-scalar's) layout / traversal pairs, fastest first for query `q` (measured:
/// docs/library.md, "Defaults"): what the reference's entry points (trace_reference, trace_one)
/// resolve an automatic layout or traversal to, as Backend::fastest does for a backend.
std::vector<std::pair<Layout, Traversal>> reference_fastest(Query q);
/// `opt` with its automatic layout and traversal resolved by `ranking` (the first pair that keeps
/// what `opt` names and that `supports` holds for); unchanged when both are named. When no pair
/// fits (a layout or traversal the backend lacks), the automatic one becomes MBVH4 or stack, which
/// the caller's support check refuses naming what the backend has. Throws Error naming `who` for an
/// enum out of range (check_trace_options). Backend's resolve_options and the reference use it.
TraceOptions resolve_by(const std::vector<std::pair<Layout, Traversal>>& ranking,
                        const std::function<bool(Layout, Traversal)>& supports, TraceOptions opt, const std::string& who);

/// Throws Error naming the trace results of `n` rays (hits or occlusion flags, statistics if
/// asked) and their bytes: what a std::bad_alloc sizing a TraceOutput becomes.
[[noreturn]] void throw_trace_output_out_of_memory(std::size_t n, const TraceOptions& opt);

/// Results in ray order. Closest hit fills `hits`; any hit fills `occluded` (1 = occluded).
struct TraceOutput {
  std::vector<Hit> hits;
  std::vector<std::uint8_t> occluded;
  std::vector<RayStats> stats;  ///< per ray, only when TraceOptions::stats
  std::size_t invalid = 0;      ///< rays rejected as invalid (defined misses)

  /// Sized for `n` rays of these options (hits or occlusion flags, statistics if asked), all
  /// misses, no invalid rays: what every backend starts a trace from.
  void reset(std::size_t n, const TraceOptions& opt) try {
    const bool any = opt.query == Query::any;
    hits.assign(any ? 0 : n, Hit{INFINITY, 0.0f, 0.0f, MBVH_MISS_PRIM});  // miss_hit(), spelled out: no ISA code here
    occluded.assign(any ? n : 0, 0);
    stats.assign(opt.stats ? n : 0, RayStats{});
    invalid = 0;
  } catch (const std::bad_alloc&) {
    throw_trace_output_out_of_memory(n, opt);
  }

  /// As reset, for a backend that writes every ray's answer (and statistics, when asked) itself:
  /// sizes the arrays without filling them, so no serial pass over the output precedes a parallel
  /// trace (a reused output is not touched at all). Contents are unspecified until written.
  void resize_for(std::size_t n, const TraceOptions& opt) try {
    const bool any = opt.query == Query::any;
    hits.resize(any ? 0 : n);
    occluded.resize(any ? n : 0);
    stats.resize(opt.stats ? n : 0);
    invalid = 0;
  } catch (const std::bad_alloc&) {
    throw_trace_output_out_of_memory(n, opt);
  }
};

/// Bytes of traversal state one ray needs in the given layout and traversal (TRAVERSAL.md §5):
/// stack = entries * 4 + stack pointer + current node (ordered stack: 8-byte entries); bitstack =
/// current node + 64-bit word (MBVH8: 128-bit word); packets: the packet's stack per ray; dacrt:
/// 32, the ray record the recursion permutes (the dacrt backends' state_bytes adds the rest).
std::size_t state_bytes_per_ray(Layout layout, Traversal traversal);

/// Traces one ray with the scalar reference traversal (dacrt as packet_single_ray's traversal).
/// Throws Error on a build without a hierarchy (BuildQuality::none). If `stats` is given, counts work; if
/// `leaf_log` is given, appends every visited leaf reference in visit order.
Hit trace_one(const Accel& acc, const Ray& ray, const TraceOptions& opt, RayStats* stats = nullptr,
              std::vector<std::int32_t>* leaf_log = nullptr);

/// Traces a batch with the scalar reference traversals on `threads` workers (0 = all); dacrt and
/// the packet traversals as packet_single_ray's traversal, ray by ray. Throws Error on a build
/// without a hierarchy (BuildQuality::none).
/// `progress` (may be null) is called with the number of rays finished so far.
void trace_reference(const Accel& acc, std::span<const Ray> rays, const TraceOptions& opt, TraceOutput& out,
                     unsigned threads, const std::function<void(std::size_t)>& progress = {});

/// Double-precision brute force over every triangle of the build (degenerate ones excluded:
/// they have no area to hit): the watertight inside test in double, t from the plane equation
/// in double; the closest hit in [tmin, tmax] with t > 0, ties to the smaller prim id; a miss
/// for an invalid ray. Cost: one test per triangle.
Hit brute_force(const Accel& acc, const Ray& ray);

/// True if the ray is valid (see prepare_ray).
bool ray_valid(const Ray& ray);

/// Throws Error naming `who`, the ray's index, its direction and origin, and the limit, when a
/// valid ray of `rays` leaves the range traced exactly against `acc` (kMaxRayCube, kMinRayCube,
/// kMaxRayRatio in accel.h): a direction far from unit length for the scene's scale, or an origin
/// far beyond the scene. Invalid rays (defined misses) pass. Cost: a few operations a ray.
void check_ray_range(const Accel& acc, std::span<const Ray> rays, const std::string& who);

}  // namespace mbvh

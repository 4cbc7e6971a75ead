// SPDX-License-Identifier: MIT
/* mbvh_layout.h — the one declaration of every record shared by host C++, OpenCL C and GLSL:
 * rays, hits, triangles, leaves and the MBVH2 / MBVH4 nodes (TRAVERSAL.md §2); the numerical
 * constants every traversal shares; and the device dispatch contracts (Vulkan bindings,
 * specialisation constants and push constants, OpenCL kernel arguments, counters, the per-ray
 * statistics record), used by name on the host and in shaders/trace.comp and shaders/trace.cl.
 *
 * Rules (STYLE.md): rows of 16 bytes, integers in the 4th lane, no 3-vectors, bool, size_t or
 * pointers; every size is asserted on the host. A per-language prelude maps the scalar names and
 * the declaration macros: a 16-byte row MBVH_ROW(x) is `float x[4]` in C++ and OpenCL C and a
 * `vec4` in GLSL (one 16-byte load; std430 gives both the same offsets), MBVH_STRUCT/MBVH_END
 * spell `typedef struct T {...} T;` or GLSL's `struct T {...};`, and MBVH_FLOAT_BITS(b) is the float
 * whose bits are the uint32 b (std::bit_cast, as_float, uintBitsToFloat: exact in every language,
 * where a decimal or hexadecimal float literal would be a second spelling of the value).
 *
 * Child reference (int32, TRAVERSAL.md §2.1):
 *   ref >= 0          index of an inner-node record
 *   ref <  0          a leaf: ~ref is an index into the Leaf array (Aila–Laine's ~triAddr)
 *   ref == INT32_MIN  MBVH_EMPTY: an unused slot; its box is inverted (lo = +inf, hi = -inf)
 * The root is record 0, its parent MBVH_NONE (-1). A node's own box lives in its parent.
 */
#ifndef MBVH_LAYOUT_H
#define MBVH_LAYOUT_H

#if defined(__cplusplus)
#include <bit>
#include <cstddef>
#include <cstdint>
#define MBVH_NS_BEGIN namespace mbvh {
#define MBVH_NS_END }
typedef float mbvh_float;
typedef std::int32_t mbvh_int;
typedef std::uint32_t mbvh_uint;
#define MBVH_STRUCT(T) typedef struct T
#define MBVH_END(T) T;
#define MBVH_ROW(x) mbvh_float x[4]
#define MBVH_IROW(x) mbvh_int x[4]
#define MBVH_ROWS(x, n) mbvh_float x[n][4]
#define MBVH_FLOAT_BITS(b) std::bit_cast<float>(std::uint32_t(b))
#elif defined(__OPENCL_VERSION__)
#define MBVH_NS_BEGIN
#define MBVH_NS_END
typedef float mbvh_float;
typedef int mbvh_int;
typedef uint mbvh_uint;
#define MBVH_STRUCT(T) typedef struct T
#define MBVH_END(T) T;
#define MBVH_ROW(x) mbvh_float x[4]
#define MBVH_IROW(x) mbvh_int x[4]
#define MBVH_ROWS(x, n) mbvh_float x[n][4]
#define MBVH_FLOAT_BITS(b) as_float((uint)(b))
#elif defined(GL_core_profile)
#define MBVH_NS_BEGIN
#define MBVH_NS_END
#define mbvh_float float
#define mbvh_int int
#define mbvh_uint uint
#define MBVH_STRUCT(T) struct T
#define MBVH_END(T) ;
#define MBVH_ROW(x) vec4 x
#define MBVH_IROW(x) ivec4 x
#define MBVH_ROWS(x, n) vec4 x[n]
#define MBVH_FLOAT_BITS(b) uintBitsToFloat(b)
#endif

#define MBVH_NONE (-1)
#define MBVH_EMPTY (-2147483647 - 1)
#define MBVH_MISS_PRIM 0xFFFFFFFFu

/* Bitstack capacity (TRAVERSAL.md §3.5): one 64-bit word holds 64 MBVH2 levels and 21 MBVH4
 * levels (63 bits). The builder caps the binary depth at 42, and the depth-aware collapse keeps
 * MBVH4 within ceil(42/2) = 21 levels. */
#define MBVH_BINARY_DEPTH_CAP 42
#define MBVH_MBVH2_LEVEL_CAP 64
#define MBVH_MBVH4_LEVEL_CAP 21
/* MBVH8: three binary levels per level, ceil(42/3) = 14 levels (its bitstack word is 128 bits). */
#define MBVH_MBVH8_LEVEL_CAP 14
/* Stack capacities of the stack-based twins: one entry per level (MBVH2), 1 + 3 * levels (MBVH4). */
#define MBVH_STACK2_ENTRIES 64
#define MBVH_STACK4_ENTRIES 64
/* MBVH8 ordered stack: 1 + 7 * 14 = 99 entries at most. */
#define MBVH_STACK8_ENTRIES 128
/* Rays per packet of the cpu backend's packet traversals (8 SIMD rays of 8 lanes; a build may
 * set 128 or 256 to measure larger packets). */
#ifndef MBVH_PACKET_RAYS
#define MBVH_PACKET_RAYS 64
#endif

/* Storage-buffer bindings per split array on Vulkan (nodes, triangles): an array larger than a
 * device's maxStorageBufferRange is bound as up to this many power-of-two chunks (TRAVERSAL.md §9). */
#define MBVH_VK_CHUNK_BINDINGS 8

/* Numerical constants every traversal shares (TRAVERSAL.md §6, §7), declared once by their bits and
 * read through MBVH_FLOAT_BITS, so host/core/trace/intersect.h, shaders/trace.cl and
 * shaders/trace.comp use the same float, bit for bit: */
#define MBVH_FAR_FACTOR_BITS 0x3F800004u    /* K = 1 + 2^-21: widens the slab test's exit distances (Ize 2013) */
#define MBVH_CULL_SLACK_BITS 0x3F800003u    /* S = 1 + 3 * 2^-23: boxes are culled against tmax * S */
#define MBVH_UNIT_ROUNDOFF_BITS 0x33800000u /* u = 2^-24: the unit roundoff of the watertight test's error bounds */
#define MBVH_FAR_FACTOR MBVH_FLOAT_BITS(MBVH_FAR_FACTOR_BITS)
#define MBVH_CULL_SLACK MBVH_FLOAT_BITS(MBVH_CULL_SLACK_BITS)
#define MBVH_UNIT_ROUNDOFF MBVH_FLOAT_BITS(MBVH_UNIT_ROUNDOFF_BITS)

/* Counters of every device trace (Vulkan: binding MBVH_VK_BINDING_COUNTERS; OpenCL: kernel argument
 * MBVH_CL_ARG_COUNTERS), uint words zeroed by the host before each trace: */
#define MBVH_COUNTER_INVALID 0  /* rays rejected as invalid (defined misses) */
#define MBVH_COUNTER_OVERFLOW 1 /* rays whose traversal stack would overflow (a tree deeper than its cap) */
#define MBVH_COUNTERS 2

/* The Vulkan dispatch contract of shaders/trace.comp, used by name on both sides
 * (backends/vulkan). Descriptor bindings of set 0: */
#define MBVH_VK_BINDING_RAYS 0     /* Ray[], read */
#define MBVH_VK_BINDING_HITS 1     /* Hit[], closest hit */
#define MBVH_VK_BINDING_OCCLUDED 2 /* uint[], any hit: 1 = occluded */
#define MBVH_VK_BINDING_STATS 3    /* StatsRecord[] per ray */
#define MBVH_VK_BINDING_COUNTERS 4 /* uint[MBVH_COUNTERS]: MBVH_COUNTER_* */
#define MBVH_VK_BINDING_LEAVES 5   /* Leaf[] */
#define MBVH_VK_BINDING_NODES 6    /* the traced layout's nodes: MBVH_VK_CHUNK_BINDINGS RGBA32UI texel buffers */
#define MBVH_VK_BINDING_TRIS 7     /* Tri[]: MBVH_VK_CHUNK_BINDINGS storage-buffer chunks */
#define MBVH_VK_BINDINGS 8
/* Specialisation constant ids (each a 32-bit word; VkBool32 for the flags): */
#define MBVH_VK_SPEC_BITSTACK 0    /* bitstack traversal, else its stack twin */
#define MBVH_VK_SPEC_ANY 1         /* any hit (occlusion), else closest hit */
#define MBVH_VK_SPEC_STATS 2       /* per-ray counters */
#define MBVH_VK_SPEC_NODE_CHUNKS 3 /* node chunks bound */
#define MBVH_VK_SPEC_NODE_SHIFT 4  /* log2 of the nodes per chunk */
#define MBVH_VK_SPEC_TRI_CHUNKS 5
#define MBVH_VK_SPEC_TRI_SHIFT 6
#define MBVH_VK_SPEC_LOCAL_SIZE 7  /* local_size_x */
#define MBVH_VK_SPEC_FAST 8        /* the `fast` accuracy mode */
#define MBVH_VK_SPEC_MBVH4 9       /* the MBVH4 layout (Node4, skip codes), else MBVH2 (Node2) */
#define MBVH_VK_SPECS 10
/* The push-constant block (one VkPushConstantRange at offset 0, the compute stage): its members,
 * which trace.comp wraps in its `layout(push_constant)` block and the host in TracePush below. */
#define MBVH_VK_PUSH_MEMBERS \
  mbvh_uint count; /* rays in this dispatch */

/* The OpenCL kernel arguments of shaders/trace.cl (every kernel of MBVH_KERNEL has this order),
 * set by index in backends/opencl: */
#define MBVH_CL_ARG_NODES 0    /* the traced layout's nodes: Node2[] or Node4W[] (as float16[]) */
#define MBVH_CL_ARG_LEAVES 1   /* Leaf[] */
#define MBVH_CL_ARG_TRIS 2     /* Tri[] */
#define MBVH_CL_ARG_RAYS 3     /* Ray[] */
#define MBVH_CL_ARG_COUNT 4    /* uint: rays in this dispatch */
#define MBVH_CL_ARG_HITS 5     /* Hit[], closest hit */
#define MBVH_CL_ARG_OCCLUDED 6 /* uchar[], any hit: 1 = occluded */
#define MBVH_CL_ARG_STATS 7    /* StatsRecord[] per ray (written with MBVH_STATS=1) */
#define MBVH_CL_ARG_COUNTERS 8 /* uint[MBVH_COUNTERS]: MBVH_COUNTER_* */
#define MBVH_CL_ARGS 9

MBVH_NS_BEGIN

/* A ray as stored in a .rays file: 32 bytes, little-endian. */
MBVH_STRUCT(Ray) {
  mbvh_float ox, oy, oz, tmin;
  mbvh_float dx, dy, dz, tmax;
} MBVH_END(Ray)

/* A closest-hit answer as stored in a .hits file: 16 bytes. Miss: prim = MBVH_MISS_PRIM,
 * t = +inf. u, v weight vertices 1 and 2: point = (1-u-v)*v0 + u*v1 + v*v2. */
MBVH_STRUCT(Hit) {
  mbvh_float t, u, v;
  mbvh_uint prim;
} MBVH_END(Hit)

/* A triangle in leaf order: three vertices as rows; w of row 0 holds the file's prim id as bits. */
MBVH_STRUCT(Tri) {
  MBVH_ROW(v0); /* x, y, z, prim id (uint bits) */
  MBVH_ROW(v1); /* x, y, z, 0 */
  MBVH_ROW(v2); /* x, y, z, 0 */
} MBVH_END(Tri)

/* A leaf: a range of the leaf-ordered triangle array. Leaves have no node record. */
MBVH_STRUCT(Leaf) {
  mbvh_uint first, count;
} MBVH_END(Leaf)

/* MBVH2 node, 64 bytes (Aila & Laine 2009 layout; TRAVERSAL.md §2.2). parent/sibling are the
 * node's OWN links (sibling: the other child of the parent, possibly a leaf reference). */
MBVH_STRUCT(Node2) {
  MBVH_ROW(c0); /* child 0: lo.x, hi.x, lo.y, hi.y */
  MBVH_ROW(c1); /* child 1: lo.x, hi.x, lo.y, hi.y */
  MBVH_ROW(zz); /* c0.lo.z, c0.hi.z, c1.lo.z, c1.hi.z */
  MBVH_IROW(link); /* parent, sibling, child0, child1 */
} MBVH_END(Node2)

/* MBVH4 node, 128 bytes, SoA view (TRAVERSAL.md §2.3). sib[k] = parent.child[(slot+1+k) & 3],
 * where slot is this node's position in its parent (cyclic order used by the skip codes). */
MBVH_STRUCT(Node4) {
  MBVH_ROW(lo_x);
  MBVH_ROW(hi_x);
  MBVH_ROW(lo_y);
  MBVH_ROW(hi_y);
  MBVH_ROW(lo_z);
  MBVH_ROW(hi_z);
  MBVH_IROW(child);
  mbvh_int parent;
  mbvh_int sib[3];
} MBVH_END(Node4)

/* MBVH4 node, 128 bytes, 16-wide view (TRAVERSAL.md §2.4, §8): the SoA record's content as two
 * 64-byte halves of four rows, one row per child slot s, references as int32 bits in the w
 * lanes, so one 16-lane operation tests the four children's x, y and z slabs at once.
 *   lo[s] = (child s lo.x, lo.y, lo.z, child[s])
 *   hi[s] = (child s hi.x, hi.y, hi.z, link[s]),  link = (parent, sib[0], sib[1], sib[2]) */
MBVH_STRUCT(Node4W) {
  MBVH_ROWS(lo, 4);
  MBVH_ROWS(hi, 4);
} MBVH_END(Node4W)

/* MBVH8 node, 256 bytes (thesis ch. 3: 8-wide AVX single-ray traversal): the eight children's
 * slabs SoA, one 32-byte row per plane, then the references; empty slots as in MBVH4. Only the
 * cpu backends trace it (stack-based, no sibling links). pad's first 24 bytes: the children's
 * order per ray octant (Fuetterling et al. 2017), read by the octant traversals: octant
 * o = neg.x | neg.y << 1 | neg.z << 2 (a negative direction component) at byte 3 * o, 24 bits
 * little-endian, lane k's slot in bits 3k..3k+2, farthest first along the octant's direction
 * (slots with an empty box first); the other 4 bytes zero. */
MBVH_STRUCT(Node8) {
  mbvh_float lo_x[8];
  mbvh_float hi_x[8];
  mbvh_float lo_y[8];
  mbvh_float hi_y[8];
  mbvh_float lo_z[8];
  mbvh_float hi_z[8];
  mbvh_int child[8];
  mbvh_int parent;
  mbvh_int pad[7];
} MBVH_END(Node8)

/* Four triangles of one leaf, SoA, for the cpu backend's SIMD leaf test (backends/cpu): row
 * 3 * i + a holds axis a of vertex i for the four lanes, prim their prim ids. A leaf of n
 * triangles has ceil(n / 4) packs in leaf order; lanes past its end have NaN vertices and prim
 * MBVH_MISS_PRIM. 160 bytes. */
MBVH_STRUCT(Tri4) {
  MBVH_ROWS(v, 9);
  mbvh_uint prim[4];
} MBVH_END(Tri4)

/* One ray's statistics as a device writes them (both device backends): host RayStats
 * (mbvh/trace.h) in its order, padded to 32 bytes. max_depth counts bitstack levels (bitstack)
 * or stack entries (stack); retests stay 0 on the devices (no bitstack-retest there). */
MBVH_STRUCT(StatsRecord) {
  mbvh_uint nodes, box_tests, leaves, tris;
  mbvh_uint climbs, retests, max_depth, pad;
} MBVH_END(StatsRecord)

/* The Vulkan push constants (MBVH_VK_PUSH_MEMBERS) as the host passes them to vkCmdPushConstants. */
MBVH_STRUCT(TracePush) {
  MBVH_VK_PUSH_MEMBERS
} MBVH_END(TracePush)

MBVH_NS_END

#if defined(__cplusplus)
static_assert(sizeof(mbvh::Ray) == 32, "ray file record is 32 bytes");
static_assert(sizeof(mbvh::Hit) == 16, "hit file record is 16 bytes");
static_assert(sizeof(mbvh::Tri) == 48, "triangle is three 16-byte rows");
static_assert(sizeof(mbvh::Leaf) == 8, "leaf is (first, count)");
static_assert(sizeof(mbvh::Node2) == 64, "MBVH2 node is 64 bytes (Aila-Laine)");
static_assert(sizeof(mbvh::Node4) == 128, "MBVH4 node is 128 bytes");
static_assert(sizeof(mbvh::Node4W) == 128, "MBVH4 16-wide node is 128 bytes");
static_assert(sizeof(mbvh::Node8) == 256, "MBVH8 node is 256 bytes");
static_assert(sizeof(mbvh::Tri4) == 160, "SIMD leaf pack is ten 16-byte rows");
static_assert(sizeof(mbvh::StatsRecord) == 32, "per-ray statistics record is eight uint words");
static_assert(offsetof(mbvh::StatsRecord, climbs) == 16 && offsetof(mbvh::StatsRecord, max_depth) == 24,
              "statistics record words in RayStats order");
static_assert(sizeof(mbvh::TracePush) == 4 && offsetof(mbvh::TracePush, count) == 0, "push constants: the ray count");
static_assert(sizeof(mbvh::TracePush) <= 128, "push constants within Vulkan's guaranteed maxPushConstantsSize");
static_assert(MBVH_FAR_FACTOR == 1.0f + 0x1p-21f, "far factor 1 + 2^-21");
static_assert(MBVH_CULL_SLACK == 1.0f + 3 * 0x1p-23f, "culling slack 1 + 3 * 2^-23");
static_assert(MBVH_UNIT_ROUNDOFF == 0x1p-24f, "unit roundoff 2^-24");
static_assert(offsetof(mbvh::Node2, link) == 48, "MBVH2 links in the 4th row");
static_assert(offsetof(mbvh::Node4, child) == 96, "MBVH4 children at byte 96");
static_assert(offsetof(mbvh::Node4, parent) == 112, "MBVH4 parent at byte 112");
static_assert(offsetof(mbvh::Node4, sib) == 116, "MBVH4 siblings at bytes 116-127");
#endif

#endif /* MBVH_LAYOUT_H */

// SPDX-License-Identifier: MIT
/* trace.comp — the Vulkan backend's compute shader: the GPU path of TRAVERSAL.md §9, one
 * invocation per ray, with the bitstack of Áfra & Szirmay-Kalos ("Stackless Multi-BVH Traversal
 * for CPU, MIC and GPU Ray Tracing", CGF 2014) in a 64-bit word and its stack-based twin with a
 * fixed-size local stack; closest and any hit; over either layout (a specialisation constant):
 *  - MBVH2 (Aila & Laine 2009 node, both child boxes in one 64-byte record), 1 bit per level;
 *  - MBVH4 (128-byte SoA record, TRAVERSAL.md §2.3), 3-bit skip codes per level (§3.3, §4.3):
 *    the nearest hit child first, the others in cyclic slot order.
 * Both layouts share the ray set-up, the box test, the triangle tests and the leaf visit.
 *
 * Every operation repeats host/core/trace/intersect.h and host/core/trace/traverse.h in the same order
 * (TRAVERSAL.md §10), so answers are bit-identical to cpu-scalar's:
 *  - `precise` on every float expression (SPIR-V NoContraction: no FMA is formed);
 *  - SignedZeroInfNanPreserve for 32-bit floats (declared below), so -0, inf and NaN survive;
 *  - compare-and-select instead of min/max in the slab test, where a NaN must yield the
 *    other operand as in the reference;
 *  - GLSL division is only 2.5 ulp, so every float quotient is taken in double and rounded
 *    once to float: a float quotient is never within 2^-49 (relative) of a float rounding
 *    boundary, far more than double division's error, so the result is the correctly
 *    rounded float quotient on any device (lavapipe's float division is exact too).
 *
 * Loops are "while-while" (Aila & Laine, "Understanding the Efficiency of Ray Traversal on
 * GPUs", HPG 2009): a lane descends through inner nodes until it reaches a leaf, so the lanes of a
 * subgroup test their leaves together (1.4-1.5x faster than one node-or-leaf step per iteration).
 *
 * Specialization constants pick the variant (one pipeline per layout x traversal x query x
 * statistics x accuracy mode x chunk counts); the node and triangle arrays are bound as up to
 * MBVH_VK_CHUNK_BINDINGS chunks of 2^SHIFT records each, so arrays over a device's
 * maxTexelBufferElements or maxStorageBufferRange still fit.
 */
#version 460
#extension GL_GOOGLE_include_directive : require
#extension GL_ARB_gpu_shader_int64 : require
#extension GL_EXT_spirv_intrinsics : require

#include "mbvh_layout.h"

/* SPIR-V ExecutionMode SignedZeroInfNanPreserve (4461) for 32-bit floats, capability 4466 */
spirv_execution_mode(capabilities = [4466], 4461, 32);

/* the ids and the bindings below: the dispatch contract in mbvh_layout.h */
layout(constant_id = MBVH_VK_SPEC_BITSTACK) const bool BITSTACK = true; /* false: the stack twin */
layout(constant_id = MBVH_VK_SPEC_ANY) const bool ANY = false;          /* any hit (occlusion) instead of closest */
layout(constant_id = MBVH_VK_SPEC_STATS) const bool STATS = false;      /* per-ray counters */
layout(constant_id = MBVH_VK_SPEC_NODE_CHUNKS) const uint NODE_CHUNKS = 1;
layout(constant_id = MBVH_VK_SPEC_NODE_SHIFT) const uint NODE_SHIFT = 21;
layout(constant_id = MBVH_VK_SPEC_TRI_CHUNKS) const uint TRI_CHUNKS = 1;
layout(constant_id = MBVH_VK_SPEC_TRI_SHIFT) const uint TRI_SHIFT = 21;
layout(local_size_x_id = MBVH_VK_SPEC_LOCAL_SIZE) in;
layout(constant_id = MBVH_VK_SPEC_FAST) const bool FAST = false;   /* the `fast` accuracy mode (host relax_ray, tri_test_mt) */
layout(constant_id = MBVH_VK_SPEC_MBVH4) const bool MBVH4 = false; /* the MBVH4 layout, else MBVH2 */

layout(push_constant) uniform Push { MBVH_VK_PUSH_MEMBERS } pc; /* host: TracePush */

layout(std430, set = 0, binding = MBVH_VK_BINDING_RAYS) readonly buffer RayBuf { Ray rays[]; };
layout(std430, set = 0, binding = MBVH_VK_BINDING_HITS) writeonly buffer HitBuf { Hit hits[]; };
layout(std430, set = 0, binding = MBVH_VK_BINDING_OCCLUDED) writeonly buffer OccBuf { uint occluded[]; };
layout(std430, set = 0, binding = MBVH_VK_BINDING_STATS) writeonly buffer StatBuf { StatsRecord stats[]; };
layout(std430, set = 0, binding = MBVH_VK_BINDING_COUNTERS) buffer CounterBuf { uint counters[]; }; /* MBVH_COUNTER_* */
layout(std430, set = 0, binding = MBVH_VK_BINDING_LEAVES) readonly buffer LeafBuf { Leaf leaves[]; };
/* The nodes as a uniform texel buffer of RGBA32UI texels, one per 16-byte row: four per MBVH2
 * node, eight per MBVH4 node (Aila & Laine 2009 fetch their nodes through the texture path too):
 * on lavapipe a texel fetch gathers all lanes at once, where a storage-buffer load with a per-lane
 * address loops over the lanes (1.45x faster traversal, README). Integer texels carry the float
 * bits unchanged. */
layout(set = 0, binding = MBVH_VK_BINDING_NODES) uniform usamplerBuffer nodeTex[MBVH_VK_CHUNK_BINDINGS];
layout(std430, set = 0, binding = MBVH_VK_BINDING_TRIS) readonly buffer TriChunk { Tri t[]; } tris[MBVH_VK_CHUNK_BINDINGS];

/* Record i of a chunked array: chunk i >> SHIFT, record i & (2^SHIFT - 1) in it, read by
 * FETCH(chunk, record). Constant indices into the binding arrays need no descriptor-indexing
 * feature; with one chunk (a specialization constant) the switch folds away. */
#define CHUNKED(FETCH, CHUNKS, SHIFT, I)                                                             \
  if (CHUNKS == 1u) return FETCH(0, uint(I));                                                      \
  const uint o = uint(I) & ((1u << SHIFT) - 1u);                                                   \
  switch (uint(I) >> SHIFT) {                                                                      \
    case 0u: return FETCH(0, o);                                                                   \
    case 1u: return FETCH(1, o);                                                                   \
    case 2u: return FETCH(2, o);                                                                   \
    case 3u: return FETCH(3, o);                                                                   \
    case 4u: return FETCH(4, o);                                                                   \
    case 5u: return FETCH(5, o);                                                                   \
    case 6u: return FETCH(6, o);                                                                   \
    default: return FETCH(7, o);                                                                   \
  }

Node2 node_texels(usamplerBuffer t, uint o) {
  const int k = 4 * int(o);
  return Node2(uintBitsToFloat(texelFetch(t, k)), uintBitsToFloat(texelFetch(t, k + 1)),
               uintBitsToFloat(texelFetch(t, k + 2)), ivec4(texelFetch(t, k + 3)));
}
/* MBVH4: rows lo.x, hi.x, lo.y, hi.y, lo.z, hi.z, child[4], (parent, sib[0..2]) */
Node4 node4_texels(usamplerBuffer t, uint o) {
  const int k = 8 * int(o);
  const ivec4 l = ivec4(texelFetch(t, k + 7));
  return Node4(uintBitsToFloat(texelFetch(t, k)), uintBitsToFloat(texelFetch(t, k + 1)),
               uintBitsToFloat(texelFetch(t, k + 2)), uintBitsToFloat(texelFetch(t, k + 3)),
               uintBitsToFloat(texelFetch(t, k + 4)), uintBitsToFloat(texelFetch(t, k + 5)),
               ivec4(texelFetch(t, k + 6)), l.x, int[3](l.y, l.z, l.w));
}
#define NODE_FETCH(k, o) node_texels(nodeTex[k], o)
#define LINK_FETCH(k, o) ivec4(texelFetch(nodeTex[k], 4 * int(o) + 3))
#define NODE4_FETCH(k, o) node4_texels(nodeTex[k], o)
#define LINK4_FETCH(k, o) ivec4(texelFetch(nodeTex[k], 8 * int(o) + 7))
#define TRI_FETCH(k, o) tris[k].t[o]
Node2 node(int i) { CHUNKED(NODE_FETCH, NODE_CHUNKS, NODE_SHIFT, i) }
ivec4 node_links(int i) { CHUNKED(LINK_FETCH, NODE_CHUNKS, NODE_SHIFT, i) } /* parent, sibling, child0, child1 */
Node4 node4(int i) { CHUNKED(NODE4_FETCH, NODE_CHUNKS, NODE_SHIFT, i) }
ivec4 node4_links(int i) { CHUNKED(LINK4_FETCH, NODE_CHUNKS, NODE_SHIFT, i) } /* parent, sib[0], sib[1], sib[2] */
Tri tri_at(uint i) { CHUNKED(TRI_FETCH, TRI_CHUNKS, TRI_SHIFT, i) }

/* constants by their bits (exact; glslang folds no bit casts into constants); the far factor,
 * the culling slack and the unit roundoff are MBVH_FAR_FACTOR, MBVH_CULL_SLACK and
 * MBVH_UNIT_ROUNDOFF of mbvh_layout.h */
#define FLT_MIN_NORMAL uintBitsToFloat(0x00800000u) /* smallest normal float */
#define INF uintBitsToFloat(0x7F800000u)

struct RayPre {
  vec3 o, d, inv, invf;
  bvec3 neg;
  float tmin, tmax;
  int kx, ky, kz;
  float sx, sy, sz;
  vec3 ok; /* o[kx], o[ky], o[kz] */
};

/* (v[kx], v[ky], v[kz]) by selects: a per-lane index into a vector would go through memory */
float pick(vec3 v, int k) { return k == 0 ? v.x : k == 1 ? v.y : v.z; }
vec3 permute(RayPre r, vec3 v) { return vec3(pick(v, r.kx), pick(v, r.ky), pick(v, r.kz)); }

/* Per-ray counters, written as a StatsRecord (retests stay 0: no bitstack-retest here) */
uint st_nodes = 0u, st_boxes = 0u, st_leaves = 0u, st_tris = 0u, st_climbs = 0u, st_depth = 0u;

/* a / b correctly rounded (see the header comment) */
float div_rn(float a, float b) { return float(double(a) / double(b)); }

bool finite(float x) { return !isinf(x) && !isnan(x); }

/* §4.1 ray set-up, host prepare_ray */
bool prepare_ray(Ray r, out RayPre p) {
  p.o = vec3(0.0); p.d = vec3(0.0); p.inv = vec3(0.0); p.invf = vec3(0.0); p.neg = bvec3(false);
  p.tmin = 0.0; p.tmax = 0.0; p.kx = 0; p.ky = 0; p.kz = 0; p.sx = 0.0; p.sy = 0.0; p.sz = 0.0;
  p.ok = vec3(0.0);
  if (!finite(r.ox) || !finite(r.oy) || !finite(r.oz) || !finite(r.tmin) || !finite(r.dx) || !finite(r.dy) ||
      !finite(r.dz) || isnan(r.tmax))
    return false;
  if (!(r.tmin >= 0.0) || !(r.tmin <= r.tmax)) return false;
  const vec3 ad = abs(vec3(r.dx, r.dy, r.dz));
  int kz = 0;
  if (ad[1] > ad[kz]) kz = 1;
  if (ad[2] > ad[kz]) kz = 2;
  if (!(ad[kz] >= FLT_MIN_NORMAL) || isinf(ad[kz])) return false;
  p.o = vec3(r.ox, r.oy, r.oz);
  p.d = vec3(r.dx, r.dy, r.dz);
  precise float tmin0 = r.tmin + 0.0; /* -0 becomes +0 */
  p.tmin = tmin0;
  p.tmax = r.tmax;
  for (int a = 0; a < 3; ++a) {
    precise float inv = div_rn(1.0, p.d[a]);
    precise float invf = inv * MBVH_FAR_FACTOR;
    p.inv[a] = inv;
    p.neg[a] = (floatBitsToUint(p.d[a]) & 0x80000000u) != 0u;
    p.invf[a] = FAST ? inv : invf;
  }
  p.kz = kz;
  p.kx = (kz + 1) % 3;
  p.ky = (p.kx + 1) % 3;
  if (p.d[kz] < 0.0) { const int t = p.kx; p.kx = p.ky; p.ky = t; }
  p.sx = div_rn(p.d[p.kx], p.d[p.kz]);
  p.sy = div_rn(p.d[p.ky], p.d[p.kz]);
  p.sz = div_rn(1.0, p.d[p.kz]);
  p.ok = permute(p, p.o);
  return true;
}

float max_nan(float a, float b) { return a > b ? a : b; } /* NaN in a yields b */
float min_nan(float a, float b) { return a < b ? a : b; }

/* §6 conservative slab test, host box_test */
bool box_test(RayPre r, float lox, float hix, float loy, float hiy, float loz, float hiz, float tcull,
              out float entry) {
  const float nx = r.neg.x ? hix : lox, fx = r.neg.x ? lox : hix;
  const float ny = r.neg.y ? hiy : loy, fy = r.neg.y ? loy : hiy;
  const float nz = r.neg.z ? hiz : loz, fz = r.neg.z ? loz : hiz;
  precise float tnx = (nx - r.o.x) * r.inv.x, tfx = (fx - r.o.x) * r.invf.x;
  precise float tny = (ny - r.o.y) * r.inv.y, tfy = (fy - r.o.y) * r.invf.y;
  precise float tnz = (nz - r.o.z) * r.inv.z, tfz = (fz - r.o.z) * r.invf.z;
  const float te = max_nan(tnz, max_nan(tny, max_nan(tnx, r.tmin)));
  const float tx = min_nan(tfz, min_nan(tfy, min_nan(tfx, tcull)));
  precise float chord = tx - te;
  entry = ANY ? max_nan(chord, 0.0) : te;  /* any hit: the path length through the box (host box_test) */
  return te <= tx;
}

double plane_t_double(RayPre r, Tri tri) {
  precise dvec3 e1 = dvec3(tri.v1.xyz) - dvec3(tri.v0.xyz);
  precise dvec3 e2 = dvec3(tri.v2.xyz) - dvec3(tri.v0.xyz);
  precise dvec3 n = dvec3(e1.y * e2.z - e1.z * e2.y, e1.z * e2.x - e1.x * e2.z, e1.x * e2.y - e1.y * e2.x);
  precise dvec3 w = dvec3(tri.v0.xyz) - dvec3(r.o);
  precise double nd = n.x * double(r.d.x) + n.y * double(r.d.y) + n.z * double(r.d.z);
  precise double q = (n.x * w.x + n.y * w.y + n.z * w.z) / nd;
  return q;
}

/* §7 watertight test (Woop, Benthin & Wald 2013), host tri_test */
bool tri_test(RayPre r, Tri tri, float tmax, out float t_out, out float u_out, out float v_out) {
  t_out = 0.0; u_out = 0.0; v_out = 0.0;
  precise float X[3], Y[3], Z[3];
  for (int i = 0; i < 3; ++i) {
    const vec3 P = permute(r, i == 0 ? tri.v0.xyz : i == 1 ? tri.v1.xyz : tri.v2.xyz);
    precise float ax = P.x - r.ok.x;
    precise float ay = P.y - r.ok.y;
    precise float az = P.z - r.ok.z;
    X[i] = ax - r.sx * az;
    Y[i] = ay - r.sy * az;
    Z[i] = r.sz * az;
  }
  precise float U = X[2] * Y[1] - Y[2] * X[1];
  precise float V = X[0] * Y[2] - Y[0] * X[2];
  precise float W = X[1] * Y[0] - Y[1] * X[0];
  if (U == 0.0 || V == 0.0 || W == 0.0) {
    precise double Ud = double(X[2]) * double(Y[1]) - double(Y[2]) * double(X[1]);
    precise double Vd = double(X[0]) * double(Y[2]) - double(Y[0]) * double(X[2]);
    precise double Wd = double(X[1]) * double(Y[0]) - double(Y[1]) * double(X[0]);
    U = float(Ud);
    V = float(Vd);
    W = float(Wd);
  }
  if ((U < 0.0 || V < 0.0 || W < 0.0) && (U > 0.0 || V > 0.0 || W > 0.0)) return false;
  precise float det = U + V + W;
  if (det == 0.0) return false;
  precise float T = U * Z[0] + V * Z[1] + W * Z[2];
  const float t = div_rn(T, det);
  if (!(t >= r.tmin && t <= tmax)) return false;
  const float u = MBVH_UNIT_ROUNDOFF;
  const float g2 = div_rn(2.0 * u, 1.0 - 2.0 * u), g3 = div_rn(3.0 * u, 1.0 - 3.0 * u),
              g5 = div_rn(5.0 * u, 1.0 - 5.0 * u);
  const float maxZt = max(abs(Z[0]), max(abs(Z[1]), abs(Z[2])));
  const float maxXt = max(abs(X[0]), max(abs(X[1]), abs(X[2])));
  const float maxYt = max(abs(Y[0]), max(abs(Y[1]), abs(Y[2])));
  const float maxE = max(abs(U), max(abs(V), abs(W)));
  precise float dz = g3 * maxZt;
  precise float dx = g5 * (maxXt + maxZt);
  precise float dy = g5 * (maxYt + maxZt);
  precise float de = 2.0 * (g2 * maxXt * maxYt + dy * maxXt + dx * maxYt);
  precise float dt = 3.0 * (g3 * maxE * maxZt + de * maxZt + dz * maxE) * abs(div_rn(1.0, det));
  if (t <= dt && !(plane_t_double(r, tri) > 0.0)) return false;
  t_out = t;
  u_out = div_rn(V, det);
  v_out = div_rn(W, det);
  return true;
}

/* the `fast` mode: Möller & Trumbore 1997, host tri_test_mt; not `precise` (contraction allowed)
 * and the division the device's own */
bool tri_test_mt(RayPre r, Tri tri, float tmax, out float t_out, out float u_out, out float v_out) {
  t_out = 0.0; u_out = 0.0; v_out = 0.0;
  const vec3 e1 = tri.v1.xyz - tri.v0.xyz, e2 = tri.v2.xyz - tri.v0.xyz;
  const vec3 p = cross(r.d, e2);
  const float det = dot(e1, p);
  const vec3 s = r.o - tri.v0.xyz;
  const vec3 q = cross(s, e1);
  const float un = dot(s, p), vn = dot(r.d, q);
  if (det > 0.0 ? !(un >= 0.0 && vn >= 0.0 && un + vn <= det) : !(det < 0.0 && un <= 0.0 && vn <= 0.0 && un + vn >= det))
    return false;
  const float inv = 1.0 / det;
  const float t = dot(e2, q) * inv;
  if (!(t >= r.tmin && t <= tmax)) return false;
  t_out = t;
  u_out = un * inv;
  v_out = vn * inv;
  return true;
}

Hit miss_hit() { return Hit(INF, 0.0, 0.0, MBVH_MISS_PRIM); }

/* LEAF (§4): closest hit keeps the smallest (t, prim) and shrinks tmax; any hit stops (true). */
bool visit_leaf(int ref, RayPre r, inout float tmax, inout Hit best) {
  const Leaf l = leaves[~ref];
  if (STATS) ++st_leaves;
  for (uint i = l.first; i < l.first + l.count; ++i) {
    if (STATS) ++st_tris;
    const Tri tri = tri_at(i);
    float t, u, w;
    bool h;
    if (FAST) h = tri_test_mt(r, tri, tmax, t, u, w);
    else h = tri_test(r, tri, tmax, t, u, w);
    if (h) {
      const uint prim = floatBitsToUint(tri.v0.w);
      if (ANY) {
        best = Hit(t, u, w, prim);
        return true;
      }
      if (t < best.t || prim < best.prim) {
        best = Hit(t, u, w, prim);
        tmax = t;
      }
    }
  }
  return false;
}

/* both child boxes of an MBVH2 node: hit mask (bit k = child k) and entry distances */
uint test2(Node2 n, RayPre r, float tcull, out float d0, out float d1) {
  if (STATS) { ++st_nodes; st_boxes += 2u; }
  const bool h0 = box_test(r, n.c0.x, n.c0.y, n.c0.z, n.c0.w, n.zz.x, n.zz.y, tcull, d0);
  const bool h1 = box_test(r, n.c1.x, n.c1.y, n.c1.z, n.c1.w, n.zz.z, n.zz.w, tcull, d1);
  return (h0 ? 1u : 0u) | (h1 ? 2u : 0u);
}

/* child entered first: closest hit the nearer, any hit the longer chord, ties to child 0 */
int first_slot2(uint m, float d0, float d1) {
  if (m == 3u) return ANY ? (d1 > d0 ? 1 : 0) : (d1 < d0 ? 1 : 0);
  return (m & 1u) != 0u ? 0 : 1;
}

/* MBVH2 bitstack (§4.2), host trace_mbvh2_bitstack: one bit per level, set where the other child
 * is still to visit; backtracking climbs through the parent links and swaps to the sibling. */
/* backtracking (§4.2): climb while the level's bit is 0, then swap to the sibling; false when done */
bool backtrack2(inout int cur, inout int par, inout int sib, inout uint64_t bits, inout uint level) {
  while ((bits & 1ul) == 0ul) {
    if (bits == 0ul) return false;
    cur = par;
    const ivec4 l = node_links(cur);
    par = l.x;
    sib = l.y;
    bits >>= 1;
    if (STATS) { ++st_climbs; --level; }
  }
  bits ^= 1ul;
  const int t = cur;
  cur = sib;
  sib = t;
  return true;
}

Hit trace_bitstack(RayPre r) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  int cur = 0, par = MBVH_NONE, sib = MBVH_NONE;
  uint64_t bits = 0ul;
  uint level = 0u;
  for (;;) {
    while (cur >= 0) {
      const Node2 n = node(cur);
      float d0, d1;
      precise float tcull = tmax * MBVH_CULL_SLACK;
      const uint m = test2(n, r, tcull, d0, d1);
      if (m != 0u) {
        const int k = first_slot2(m, d0, d1);
        bits = (bits << 1) | (m == 3u ? 1ul : 0ul);
        if (STATS) { ++level; st_depth = max(st_depth, level); }
        par = cur;
        sib = n.link[2 + (1 - k)];
        cur = n.link[2 + k];
      } else if (!backtrack2(cur, par, sib, bits, level)) {
        return best;
      }
    }
    if (visit_leaf(cur, r, tmax, best)) return best;
    if (!backtrack2(cur, par, sib, bits, level)) return best;
  }
}

/* MBVH2 stack-based twin (§4.5): the farther hit child pushed, one entry per level */
Hit trace_stack(RayPre r) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  int stack[MBVH_STACK2_ENTRIES];
  uint sp = 0u;
  int cur = 0;
  for (;;) {
    while (cur >= 0) {
      const Node2 n = node(cur);
      float d0, d1;
      precise float tcull = tmax * MBVH_CULL_SLACK;
      const uint m = test2(n, r, tcull, d0, d1);
      if (m != 0u) {
        const int k = first_slot2(m, d0, d1);
        if (m == 3u) {
          if (sp + 1u > MBVH_STACK2_ENTRIES) { /* flag the ray rather than overflow */
            atomicAdd(counters[MBVH_COUNTER_OVERFLOW], 1u);
            return miss_hit();
          }
          stack[sp++] = n.link[2 + (1 - k)];
          if (STATS) st_depth = max(st_depth, sp);
        }
        cur = n.link[2 + k];
      } else {
        if (sp == 0u) return best;
        cur = stack[--sp];
      }
    }
    if (visit_leaf(cur, r, tmax, best)) return best;
    if (sp == 0u) return best;
    cur = stack[--sp];
  }
}

/* ---------------------------------------------------------------- MBVH4 (§4.3, §4.5) */

/* the four child boxes of an MBVH4 node, slot by slot in slot order (host test_boxes): hit mask
 * (bit s = slot s) and entry distances */
uint test4(Node4 n, RayPre r, float tcull, out vec4 d) {
  if (STATS) { ++st_nodes; st_boxes += 4u; }
  float d0, d1, d2, d3;
  const bool h0 = box_test(r, n.lo_x.x, n.hi_x.x, n.lo_y.x, n.hi_y.x, n.lo_z.x, n.hi_z.x, tcull, d0);
  const bool h1 = box_test(r, n.lo_x.y, n.hi_x.y, n.lo_y.y, n.hi_y.y, n.lo_z.y, n.hi_z.y, tcull, d1);
  const bool h2 = box_test(r, n.lo_x.z, n.hi_x.z, n.lo_y.z, n.hi_y.z, n.lo_z.z, n.hi_z.z, tcull, d2);
  const bool h3 = box_test(r, n.lo_x.w, n.hi_x.w, n.lo_y.w, n.hi_y.w, n.lo_z.w, n.hi_z.w, tcull, d3);
  d = vec4(d0, d1, d2, d3);
  return (h0 ? 1u : 0u) | (h1 ? 2u : 0u) | (h2 ? 4u : 0u) | (h3 ? 8u : 0u);
}

/* slot entered first (host first_slot4): closest hit the smallest entry distance, any hit the
 * longest chord, ties to the lower slot */
int first_slot4(uint m, vec4 d) {
  int i = findLSB(m);
  float di = i == 0 ? d.x : i == 1 ? d.y : i == 2 ? d.z : d.w;
  if (ANY) {  /* the longest chord (d holds chords), ties to the lower slot */
    if (i < 1 && (m & 2u) != 0u && d.y > di) { i = 1; di = d.y; }
    if (i < 2 && (m & 4u) != 0u && d.z > di) { i = 2; di = d.z; }
    if (i < 3 && (m & 8u) != 0u && d.w > di) i = 3;
    return i;
  }
  if (i < 1 && (m & 2u) != 0u && d.y < di) { i = 1; di = d.y; }
  if (i < 2 && (m & 4u) != 0u && d.z < di) { i = 2; di = d.z; }
  if (i < 3 && (m & 8u) != 0u && d.w < di) i = 3;
  return i;
}

/* rot(mask, i) (§3.3): bit k = slot (i + 1 + k) & 3, the entered slot's own bit dropped */
uint skip_code(uint m, int i) { return ((m >> (i + 1)) | (m << (3 - i))) & 7u; }

/* (v[j & 3], v[(j + 1) & 3], v[(j + 2) & 3], v[(j + 3) & 3]) by swizzles: a per-lane index into a
 * vector would go through memory */
ivec4 rotate(ivec4 v, int j) {
  j &= 3;
  return j == 0 ? v : j == 1 ? v.yzwx : j == 2 ? v.zwxy : v.wxyz;
}

/* The bitstack's registers S = (sib[0], sib[1], sib[2], cur) (§3.3 "cached registers": R): entering
 * slot i of a node is S = rotate(child, i + 1); moving to the k-th cyclic sibling is
 * S = rotate(S, k + 1) (cur = R[k], sib[j] = R[(k + 1 + j) & 3]). */

/* backtracking (§4.3), host trace_mbvh4_bitstack: climb while the level's code is 0 (cur = par,
 * its parent and siblings from its record), then skip to the first pending sibling and keep the
 * rest of the code relative to it; false when done */
bool backtrack4(inout ivec4 S, inout int par, inout uint64_t bits, inout uint level) {
  uint code;
  for (;;) {
    if (bits == 0ul) return false;
    code = uint(bits) & 7u;
    if (code != 0u) break;
    S.w = par;
    const ivec4 l = node4_links(par);
    par = l.x;
    S.xyz = l.yzw;
    bits >>= 3;
    if (STATS) { ++st_climbs; --level; }
  }
  const int k = findLSB(code);
  const uint rest = code >> (k + 1);
  bits ^= uint64_t(code ^ rest);
  S = rotate(S, k + 1);
  return true;
}

/* MBVH4 bitstack with skip codes (§4.3), host trace_mbvh4_bitstack: 3 bits per level */
Hit trace4_bitstack(RayPre r) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  ivec4 S = ivec4(MBVH_NONE, MBVH_NONE, MBVH_NONE, 0); /* sib[0..2], cur = the root */
  int par = MBVH_NONE;
  uint64_t bits = 0ul;
  uint level = 0u;
  for (;;) {
    while (S.w >= 0) {
      const Node4 n = node4(S.w);
      vec4 d;
      precise float tcull = tmax * MBVH_CULL_SLACK;
      const uint m = test4(n, r, tcull, d);
      if (m != 0u) {
        const int i = first_slot4(m, d);
        bits = (bits << 3) | uint64_t(skip_code(m, i)); /* push */
        if (STATS) { ++level; st_depth = max(st_depth, level); }
        par = S.w;
        S = rotate(n.child, i + 1);
      } else if (!backtrack4(S, par, bits, level)) {
        return best;
      }
    }
    if (visit_leaf(S.w, r, tmax, best)) return best;
    if (!backtrack4(S, par, bits, level)) return best;
  }
}

/* MBVH4 stack-based twin (§4.5), host trace_mbvh4_stack: enter the nearest hit child, push the
 * other hit children in reverse cyclic order so they pop in cyclic order */
Hit trace4_stack(RayPre r) {
  Hit best = miss_hit();
  float tmax = r.tmax;
  int stack[MBVH_STACK4_ENTRIES];
  uint sp = 0u;
  int cur = 0;
  for (;;) {
    while (cur >= 0) {
      const Node4 n = node4(cur);
      vec4 d;
      precise float tcull = tmax * MBVH_CULL_SLACK;
      const uint m = test4(n, r, tcull, d);
      if (m != 0u) {
        const int i = first_slot4(m, d);
        if (sp + 3u > MBVH_STACK4_ENTRIES) { /* flag the ray rather than overflow */
          atomicAdd(counters[MBVH_COUNTER_OVERFLOW], 1u);
          return miss_hit();
        }
        const uint code = skip_code(m, i); /* bit k: slot (i + 1 + k) & 3 was hit */
        const ivec4 c = rotate(n.child, i + 1);
        /* push the hit ones of c.z, c.y, c.x in that order: three unconditional stores of the
         * compacted sequence (entries past the pushed ones are dead), then sp += their count */
        stack[sp] = (code & 4u) != 0u ? c.z : (code & 2u) != 0u ? c.y : c.x;
        stack[sp + 1u] = (code & 6u) == 6u ? c.y : c.x;
        stack[sp + 2u] = c.x;
        sp += uint(bitCount(code));
        if (STATS) st_depth = max(st_depth, sp);
        cur = c.w;
      } else {
        if (sp == 0u) return best;
        cur = stack[--sp];
      }
    }
    if (visit_leaf(cur, r, tmax, best)) return best;
    if (sp == 0u) return best;
    cur = stack[--sp];
  }
}

void main() {
  const uint gid = gl_GlobalInvocationID.x;
  if (gid >= pc.count) return;
  RayPre r;
  Hit h = miss_hit();
  if (prepare_ray(rays[gid], r)) {
    if (MBVH4) h = BITSTACK ? trace4_bitstack(r) : trace4_stack(r);
    else h = BITSTACK ? trace_bitstack(r) : trace_stack(r);
  } else {
    atomicAdd(counters[MBVH_COUNTER_INVALID], 1u);
  }
  if (ANY) occluded[gid] = h.prim != MBVH_MISS_PRIM ? 1u : 0u;
  else hits[gid] = h;
  if (STATS) stats[gid] = StatsRecord(st_nodes, st_boxes, st_leaves, st_tris, st_climbs, 0u, st_depth, 0u);
}

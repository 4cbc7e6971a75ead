// SPDX-License-Identifier: MIT
/* trace.cl — the OpenCL backend's traversal kernels: one work-item per ray.
 *
 *  - MBVH4, the 16-wide MIC path (TRAVERSAL.md §8): one float16 operation tests the four
 *    children's x, y and z slabs of a Node4W record (two 64-byte loads); skip-code bitstack
 *    backtracking and its stack-based twin (Áfra & Szirmay-Kalos, "Stackless Multi-BVH
 *    Traversal for CPU, MIC and GPU Ray Tracing", CGF 2014). MBVH_WIDE=0 swaps the node test for
 *    four scalar slab tests (the ray-per-lane mapping), same record, same answers.
 *  - MBVH2, the GPU-style traversal (Aila & Laine 2009 node, 1-bit-per-level bitstack) and its
 *    stack twin, so both layouts can be cross-checked on one device.
 *
 * Every operation repeats host/core/trace/intersect.h and host/core/trace/traverse.h in the same order
 * (TRAVERSAL.md §10): contraction off, correctly rounded division (the host builds with
 * -cl-fp32-correctly-rounded-divide-sqrt), compare-and-select instead of fmin/fmax in the slab
 * tests, so every answer is bit-identical to cpu-scalar's.
 *
 * Build options: -DMBVH_STATS=0|1 (per-ray counters; 0 compiles them out), -DMBVH_WIDE=0|1,
 * -DMBVH_FAST=0|1 (the `fast` accuracy mode: no far-plane widening, Möller–Trumbore triangles,
 * contraction allowed; built with -cl-mad-enable and without correctly rounded division).
 * The layout header is inlined here when the source is embedded (CMake: embed_cl.cmake).
 */
#ifndef MBVH_FAST
#define MBVH_FAST 0
#endif
#if MBVH_FAST
#pragma OPENCL FP_CONTRACT ON
#else
#pragma OPENCL FP_CONTRACT OFF
#endif
#pragma OPENCL EXTENSION cl_khr_fp64 : enable

#include "mbvh_layout.h"

#ifndef MBVH_STATS
#define MBVH_STATS 0
#endif
#ifndef MBVH_WIDE
#define MBVH_WIDE 1
#endif

/* The far factor, the culling slack and the unit roundoff (MBVH_FAR_FACTOR, MBVH_CULL_SLACK,
 * MBVH_UNIT_ROUNDOFF) and the counters[] every kernel writes (MBVH_COUNTER_*) are declared in
 * mbvh_layout.h. */

typedef struct RayPre {
  float o[3], d[3], inv[3], invf[3];
  int neg[3];
  float tmin, tmax;
  int kx, ky, kz;
  float sx, sy, sz;
} RayPre;

/* Per-ray counters while tracing, written out as a StatsRecord (mbvh_layout.h) by finish(). */
typedef struct Stats {
  uint nodes, boxes, leaves, tris, climbs, retests, depth;
} Stats;

#if MBVH_STATS
#define STAT(x) x
#else
#define STAT(x)
#endif

/* §4.1 ray set-up, host prepare_ray */
static bool prepare_ray(const Ray r, RayPre* p) {
  if (!isfinite(r.ox) || !isfinite(r.oy) || !isfinite(r.oz) || !isfinite(r.tmin) || !isfinite(r.dx) ||
      !isfinite(r.dy) || !isfinite(r.dz) || isnan(r.tmax))
    return false;
  if (!(r.tmin >= 0.0f) || !(r.tmin <= r.tmax)) return false;
  const float ad[3] = {fabs(r.dx), fabs(r.dy), fabs(r.dz)};
  int kz = 0;
  if (ad[1] > ad[kz]) kz = 1;
  if (ad[2] > ad[kz]) kz = 2;
  if (!isnormal(ad[kz])) return false;
  p->o[0] = r.ox; p->o[1] = r.oy; p->o[2] = r.oz;
  p->d[0] = r.dx; p->d[1] = r.dy; p->d[2] = r.dz;
  p->tmin = r.tmin + 0.0f;
  p->tmax = r.tmax;
  for (int a = 0; a < 3; ++a) {
    p->inv[a] = 1.0f / p->d[a];
    p->neg[a] = signbit(p->d[a]) ? 1 : 0;
    p->invf[a] = MBVH_FAST ? p->inv[a] : p->inv[a] * MBVH_FAR_FACTOR; /* fast: host relax_ray */
  }
  p->kz = kz;
  p->kx = (kz + 1) % 3;
  p->ky = (p->kx + 1) % 3;
  if (p->d[kz] < 0.0f) { const int t = p->kx; p->kx = p->ky; p->ky = t; }
  p->sx = p->d[p->kx] / p->d[p->kz];
  p->sy = p->d[p->ky] / p->d[p->kz];
  p->sz = 1.0f / p->d[p->kz];
  return true;
}

static float max_nan(float a, float b) { return a > b ? a : b; } /* NaN in a yields b */
static float min_nan(float a, float b) { return a < b ? a : b; }

/* §6 conservative slab test, host box_test; chord (occlusion): *entry receives the path length
 * through the box, max_nan(exit - entry, 0), the order of an any-hit query's children */
static bool box_test(const RayPre* r, float lox, float hix, float loy, float hiy, float loz, float hiz, float tcull,
                     float* entry, const bool chord) {
  const float nx = r->neg[0] ? hix : lox, fx = r->neg[0] ? lox : hix;
  const float ny = r->neg[1] ? hiy : loy, fy = r->neg[1] ? loy : hiy;
  const float nz = r->neg[2] ? hiz : loz, fz = r->neg[2] ? loz : hiz;
  const float tnx = (nx - r->o[0]) * r->inv[0], tfx = (fx - r->o[0]) * r->invf[0];
  const float tny = (ny - r->o[1]) * r->inv[1], tfy = (fy - r->o[1]) * r->invf[1];
  const float tnz = (nz - r->o[2]) * r->inv[2], tfz = (fz - r->o[2]) * r->invf[2];
  const float te = max_nan(tnz, max_nan(tny, max_nan(tnx, r->tmin)));
  const float tx = min_nan(tfz, min_nan(tfy, min_nan(tfx, tcull)));
  *entry = chord ? max_nan(tx - te, 0.0f) : te;
  return te <= tx;
}

static double plane_t_double(const RayPre* r, global const Tri* tri) {
  const double e1[3] = {(double)tri->v1[0] - tri->v0[0], (double)tri->v1[1] - tri->v0[1], (double)tri->v1[2] - tri->v0[2]};
  const double e2[3] = {(double)tri->v2[0] - tri->v0[0], (double)tri->v2[1] - tri->v0[1], (double)tri->v2[2] - tri->v0[2]};
  const double n[3] = {e1[1] * e2[2] - e1[2] * e2[1], e1[2] * e2[0] - e1[0] * e2[2], e1[0] * e2[1] - e1[1] * e2[0]};
  const double w[3] = {(double)tri->v0[0] - r->o[0], (double)tri->v0[1] - r->o[1], (double)tri->v0[2] - r->o[2]};
  const double nd = n[0] * r->d[0] + n[1] * r->d[1] + n[2] * r->d[2];
  return (n[0] * w[0] + n[1] * w[1] + n[2] * w[2]) / nd;
}

/* §7 watertight test (Woop, Benthin & Wald 2013), host tri_test */
static bool tri_test(const RayPre* r, global const Tri* tri, float tmax, float* t_out, float* u_out, float* v_out) {
  float X[3], Y[3], Z[3];
  for (int i = 0; i < 3; ++i) {
    global const float* P = i == 0 ? tri->v0 : i == 1 ? tri->v1 : tri->v2;
    const float ax = P[r->kx] - r->o[r->kx];
    const float ay = P[r->ky] - r->o[r->ky];
    const float az = P[r->kz] - r->o[r->kz];
    X[i] = ax - r->sx * az;
    Y[i] = ay - r->sy * az;
    Z[i] = r->sz * az;
  }
  float U = X[2] * Y[1] - Y[2] * X[1];
  float V = X[0] * Y[2] - Y[0] * X[2];
  float W = X[1] * Y[0] - Y[1] * X[0];
  if (U == 0.0f || V == 0.0f || W == 0.0f) {
    U = (float)((double)X[2] * (double)Y[1] - (double)Y[2] * (double)X[1]);
    V = (float)((double)X[0] * (double)Y[2] - (double)Y[0] * (double)X[2]);
    W = (float)((double)X[1] * (double)Y[0] - (double)Y[1] * (double)X[0]);
  }
  if ((U < 0.0f || V < 0.0f || W < 0.0f) && (U > 0.0f || V > 0.0f || W > 0.0f)) return false;
  const float det = U + V + W;
  if (det == 0.0f) return false;
  const float T = U * Z[0] + V * Z[1] + W * Z[2];
  const float t = T / det;
  if (!(t >= r->tmin && t <= tmax)) return false;
  const float u = MBVH_UNIT_ROUNDOFF;
  const float g2 = 2 * u / (1 - 2 * u), g3 = 3 * u / (1 - 3 * u), g5 = 5 * u / (1 - 5 * u);
  const float maxZt = fmax(fabs(Z[0]), fmax(fabs(Z[1]), fabs(Z[2])));
  const float maxXt = fmax(fabs(X[0]), fmax(fabs(X[1]), fabs(X[2])));
  const float maxYt = fmax(fabs(Y[0]), fmax(fabs(Y[1]), fabs(Y[2])));
  const float maxE = fmax(fabs(U), fmax(fabs(V), fabs(W)));
  const float dz = g3 * maxZt;
  const float dx = g5 * (maxXt + maxZt);
  const float dy = g5 * (maxYt + maxZt);
  const float de = 2 * (g2 * maxXt * maxYt + dy * maxXt + dx * maxYt);
  const float dt = 3 * (g3 * maxE * maxZt + de * maxZt + dz * maxE) * fabs(1.0f / det);
  if (t <= dt && !(plane_t_double(r, tri) > 0.0)) return false;
  *t_out = t;
  *u_out = V / det;
  *v_out = W / det;
  return true;
}

/* the `fast` mode: Möller & Trumbore 1997, host tri_test_mt */
static bool tri_test_mt(const RayPre* r, global const Tri* tri, float tmax, float* t_out, float* u_out, float* v_out) {
  const float3 v0 = vload3(0, tri->v0), d = vload3(0, r->d), o = vload3(0, r->o);
  const float3 e1 = vload3(0, tri->v1) - v0, e2 = vload3(0, tri->v2) - v0;
  const float3 p = cross(d, e2);
  const float det = dot(e1, p);
  const float3 s = o - v0;
  const float3 q = cross(s, e1);
  const float un = dot(s, p), vn = dot(d, q);
  if (det > 0.0f ? !(un >= 0.0f && vn >= 0.0f && un + vn <= det) : !(det < 0.0f && un <= 0.0f && vn <= 0.0f && un + vn >= det))
    return false;
  const float inv = 1.0f / det;
  const float t = dot(e2, q) * inv;
  if (!(t >= r->tmin && t <= tmax)) return false;
  *t_out = t;
  *u_out = un * inv;
  *v_out = vn * inv;
  return true;
}

static Hit miss_hit(void) {
  Hit h;
  h.t = INFINITY; h.u = 0.0f; h.v = 0.0f; h.prim = MBVH_MISS_PRIM;
  return h;
}

/* LEAF (§4): closest hit keeps the smallest (t, prim) and shrinks tmax; any hit stops (true). */
static bool visit_leaf(global const Leaf* leaves, global const Tri* tris, int ref, const RayPre* r, float* tmax,
                       Hit* best, const bool any, Stats* st) {
  const Leaf l = leaves[~ref];
  STAT(++st->leaves;)
  for (uint i = l.first; i < l.first + l.count; ++i) {
    STAT(++st->tris;)
    float t, u, w;
#if MBVH_FAST
    if (tri_test_mt(r, &tris[i], *tmax, &t, &u, &w)) {
#else
    if (tri_test(r, &tris[i], *tmax, &t, &u, &w)) {
#endif
      const uint prim = as_uint(tris[i].v0[3]);
      if (any) {
        best->t = t; best->u = u; best->v = w; best->prim = prim;
        return true;
      }
      if (t < best->t || prim < best->prim) {
        best->t = t; best->u = u; best->v = w; best->prim = prim;
        *tmax = t;
      }
    }
  }
  return false;
}

static int lowest_slot(uint m) { return 31 - (int)clz(m & (0u - m)); }

/* ---------------------------------------------------------------- MBVH4, 16-wide view (§8) */

/* Per-ray constants of the 16-wide node test: (x, y, z, 0) repeated four times. */
typedef struct Wide {
  float16 o, inv, invf;
} Wide;

static Wide wide_setup(const RayPre* r) {
  Wide w;
  const float4 o = (float4)(r->o[0], r->o[1], r->o[2], 0.0f);
  const float4 i = (float4)(r->inv[0], r->inv[1], r->inv[2], 0.0f);
  const float4 f = (float4)(r->invf[0], r->invf[1], r->invf[2], 0.0f);
  w.o = (float16)(o, o, o, o);
  w.inv = (float16)(i, i, i, i);
  w.invf = (float16)(f, f, f, f);
  return w;
}

static float4 max_nan4(float4 a, float4 b) { return select(b, a, a > b); }
static float4 min_nan4(float4 a, float4 b) { return select(b, a, a < b); }

/* Tests the four children of node `cur`; returns the hit mask (bit s = slot s), writes the entry
 * distances and the child references. */
static uint test4(global const float16* N, int cur, const RayPre* r, const Wide* w, float tcull, float d[4],
                  int ch[4], const bool chord, Stats* st) {
  STAT(++st->nodes; st->boxes += 4;)
  const float16 Lraw = N[2 * cur], Uraw = N[2 * cur + 1];
  const int4 c = as_int4(Lraw.s37bf);
  ch[0] = c.x; ch[1] = c.y; ch[2] = c.z; ch[3] = c.w;
#if MBVH_WIDE
  /* clear the w lanes (references as bits: subnormals, infinities or NaNs) out of the arithmetic */
  const int16 xyz = (int16)(-1, -1, -1, 0, -1, -1, -1, 0, -1, -1, -1, 0, -1, -1, -1, 0);
  const float16 L = as_float16(as_int16(Lraw) & xyz), U = as_float16(as_int16(Uraw) & xyz);
  const float16 nearP = select(L, U, as_int16(w->inv)); /* U where the direction is negative */
  const float16 farP = select(U, L, as_int16(w->inv));
  const float16 tn = (nearP - w->o) * w->inv;
  const float16 tf = (farP - w->o) * w->invf;
  float4 entry = max_nan4(tn.s048c, (float4)(r->tmin));
  entry = max_nan4(tn.s159d, entry);
  entry = max_nan4(tn.s26ae, entry);
  float4 exit = min_nan4(tf.s048c, (float4)(tcull));
  exit = min_nan4(tf.s159d, exit);
  exit = min_nan4(tf.s26ae, exit);
  const int4 hit = entry <= exit;
  vstore4(chord ? max_nan4(exit - entry, (float4)(0.0f)) : entry, 0, d);
  return (uint)((hit.x & 1) | (hit.y & 2) | (hit.z & 4) | (hit.w & 8));
#else
  /* ray-per-lane mapping: four scalar slab tests on the same record */
  global const float* n = (global const float*)(N + 2 * cur);
  uint m = 0;
  for (int s = 0; s < 4; ++s)
    if (box_test(r, n[4 * s], n[16 + 4 * s], n[4 * s + 1], n[16 + 4 * s + 1], n[4 * s + 2], n[16 + 4 * s + 2], tcull,
                 &d[s], chord))
      m |= 1u << s;
  return m;
#endif
}

/* Slot entered first: closest hit the smallest entry, any hit the longest chord (d holds chords
 * then), ties to the lower slot (host first_slot4). */
static int first_slot4(uint m, const float d[4], const bool any) {
  int i = lowest_slot(m);
  for (int s = i + 1; s < 4; ++s)
    if (((m >> s) & 1u) && (any ? d[s] > d[i] : d[s] < d[i])) i = s;
  return i;
}

static ulong skip_code(uint m, int i) { return (ulong)(((m >> (i + 1)) | (m << (3 - i))) & 7u); }

/* MBVH4 bitstack with skip codes (§4.3), host trace_mbvh4_bitstack */
static Hit trace4_bitstack(global const float16* N, global const Leaf* leaves, global const Tri* tris, const RayPre* r,
                           const bool any, Stats* st) {
  Hit best = miss_hit();
  float tmax = r->tmax;
  const Wide w = wide_setup(r);
  global const int* links = (global const int*)N; /* link k of node x: links[32 * x + 16 + 4 * k + 3] */
  int cur = 0, par = MBVH_NONE;
  int sib[3] = {MBVH_NONE, MBVH_NONE, MBVH_NONE};
  ulong bits = 0;
  uint level = 0;
  for (;;) {
    if (cur >= 0) {
      float d[4];
      int ch[4];
      const uint m = test4(N, cur, r, &w, tmax * MBVH_CULL_SLACK, d, ch, any, st);
      if (m) {
        const int i = first_slot4(m, d, any);
        bits = (bits << 3) | skip_code(m, i);
        STAT(++level; st->depth = max(st->depth, level);)
        par = cur;
        for (int k = 0; k < 3; ++k) sib[k] = ch[(i + 1 + k) & 3];
        cur = ch[i];
        continue;
      }
    } else if (visit_leaf(leaves, tris, cur, r, &tmax, &best, any, st)) {
      return best;
    }
    ulong code;
    for (;;) {
      if (bits == 0) return best;
      code = bits & 7u;
      if (code != 0) break;
      cur = par;
      global const int* l = links + 32 * cur + 16;
      par = l[3];
      sib[0] = l[7];
      sib[1] = l[11];
      sib[2] = l[15];
      bits >>= 3;
      STAT(++st->climbs; --level;)
    }
    const int k = lowest_slot((uint)code);
    const ulong rest = code >> (k + 1);
    bits ^= code ^ rest;
    const int R[4] = {sib[0], sib[1], sib[2], cur};
    cur = R[k];
    for (int j = 0; j < 3; ++j) sib[j] = R[(k + 1 + j) & 3];
  }
}

/* MBVH4 stack twin (§4.5): the other hit children pushed in reverse cyclic order */
static Hit trace4_stack(global const float16* N, global const Leaf* leaves, global const Tri* tris, const RayPre* r,
                        const bool any, Stats* st, volatile global uint* counters) {
  Hit best = miss_hit();
  float tmax = r->tmax;
  const Wide w = wide_setup(r);
  int stack[MBVH_STACK4_ENTRIES];
  uint sp = 0;
  int cur = 0;
  for (;;) {
    if (cur >= 0) {
      float d[4];
      int ch[4];
      const uint m = test4(N, cur, r, &w, tmax * MBVH_CULL_SLACK, d, ch, any, st);
      if (m) {
        const int i = first_slot4(m, d, any);
        if (sp + 3 > MBVH_STACK4_ENTRIES) {
          atomic_inc(&counters[MBVH_COUNTER_OVERFLOW]);
          return miss_hit();
        }
        for (int k = 2; k >= 0; --k) {
          const int s = (i + 1 + k) & 3;
          if ((m >> s) & 1u) stack[sp++] = ch[s];
        }
        STAT(st->depth = max(st->depth, sp);)
        cur = ch[i];
        continue;
      }
    } else if (visit_leaf(leaves, tris, cur, r, &tmax, &best, any, st)) {
      return best;
    }
    if (sp == 0) return best;
    cur = stack[--sp];
  }
}

/* ---------------------------------------------------------------- MBVH2, GPU style (§4.2) */

static uint test2(global const Node2* n, const RayPre* r, float tcull, float d[2], const bool chord, Stats* st) {
  STAT(++st->nodes; st->boxes += 2;)
  const bool h0 = box_test(r, n->c0[0], n->c0[1], n->c0[2], n->c0[3], n->zz[0], n->zz[1], tcull, &d[0], chord);
  const bool h1 = box_test(r, n->c1[0], n->c1[1], n->c1[2], n->c1[3], n->zz[2], n->zz[3], tcull, &d[1], chord);
  return (h0 ? 1u : 0u) | (h1 ? 2u : 0u);
}

static int first_slot2(uint m, const float d[2], const bool any) {
  if (m == 3u) return any ? (d[1] > d[0] ? 1 : 0) : (d[1] < d[0] ? 1 : 0);
  return (m & 1u) ? 0 : 1;
}

static Hit trace2_bitstack(global const Node2* N, global const Leaf* leaves, global const Tri* tris, const RayPre* r,
                           const bool any, Stats* st) {
  Hit best = miss_hit();
  float tmax = r->tmax;
  int cur = 0, par = MBVH_NONE, sib = MBVH_NONE;
  ulong bits = 0;
  uint level = 0;
  for (;;) {
    if (cur >= 0) {
      global const Node2* n = &N[cur];
      float d[2];
      const uint m = test2(n, r, tmax * MBVH_CULL_SLACK, d, any, st);
      if (m) {
        const int k = first_slot2(m, d, any);
        bits = (bits << 1) | (m == 3u ? 1u : 0u);
        STAT(++level; st->depth = max(st->depth, level);)
        par = cur;
        sib = n->link[2 + (1 - k)];
        cur = n->link[2 + k];
        continue;
      }
    } else if (visit_leaf(leaves, tris, cur, r, &tmax, &best, any, st)) {
      return best;
    }
    while ((bits & 1u) == 0) {
      if (bits == 0) return best;
      cur = par;
      par = N[cur].link[0];
      sib = N[cur].link[1];
      bits >>= 1;
      STAT(++st->climbs; --level;)
    }
    bits ^= 1u;
    const int t = cur;
    cur = sib;
    sib = t;
  }
}

static Hit trace2_stack(global const Node2* N, global const Leaf* leaves, global const Tri* tris, const RayPre* r,
                        const bool any, Stats* st, volatile global uint* counters) {
  Hit best = miss_hit();
  float tmax = r->tmax;
  int stack[MBVH_STACK2_ENTRIES];
  uint sp = 0;
  int cur = 0;
  for (;;) {
    if (cur >= 0) {
      global const Node2* n = &N[cur];
      float d[2];
      const uint m = test2(n, r, tmax * MBVH_CULL_SLACK, d, any, st);
      if (m) {
        const int k = first_slot2(m, d, any);
        if (m == 3u) {
          if (sp + 1 > MBVH_STACK2_ENTRIES) {
            atomic_inc(&counters[MBVH_COUNTER_OVERFLOW]);
            return miss_hit();
          }
          stack[sp++] = n->link[2 + (1 - k)];
          STAT(st->depth = max(st->depth, sp);)
        }
        cur = n->link[2 + k];
        continue;
      }
    } else if (visit_leaf(leaves, tris, cur, r, &tmax, &best, any, st)) {
      return best;
    }
    if (sp == 0) return best;
    cur = stack[--sp];
  }
}

/* ---------------------------------------------------------------- kernels
 * One per (layout, traversal, query). Arguments: nodes, leaves, triangles, rays, n; outputs:
 * hits (closest) or occluded (any), per-ray StatsRecords (only with MBVH_STATS), counters. */

static void finish(uint gid, Hit h, const bool any, global Hit* hits, global uchar* occluded, const Stats* st,
                   global StatsRecord* stats) {
  if (any) occluded[gid] = h.prim != MBVH_MISS_PRIM ? 1 : 0;
  else hits[gid] = h;
#if MBVH_STATS
  global StatsRecord* s = stats + gid;
  s->nodes = st->nodes; s->box_tests = st->boxes; s->leaves = st->leaves; s->tris = st->tris;
  s->climbs = st->climbs; s->retests = st->retests; s->max_depth = st->depth; s->pad = 0;
#endif
}

/* The parameters in the order of MBVH_CL_ARG_NODES, _LEAVES, _TRIS, _RAYS, _COUNT, _HITS,
 * _OCCLUDED, _STATS and _COUNTERS (mbvh_layout.h), by which the host sets them. */
#define MBVH_KERNEL(NAME, NODE_T, CALL, ANY)                                                                       \
  kernel void NAME(global const NODE_T* nodes, global const Leaf* leaves, global const Tri* tris,                 \
                   global const Ray* rays, uint n, global Hit* hits, global uchar* occluded,                    \
                   global StatsRecord* stats, volatile global uint* counters) {                                   \
    const uint gid = (uint)get_global_id(0);                                                                      \
    if (gid >= n) return;                                                                                         \
    Stats st = {0, 0, 0, 0, 0, 0, 0};                                                                             \
    RayPre r;                                                                                                     \
    Hit h = miss_hit();                                                                                           \
    if (prepare_ray(rays[gid], &r)) h = CALL(nodes, leaves, tris, &r, ANY, &st MBVH_COUNTERS_##CALL);             \
    else atomic_inc(&counters[MBVH_COUNTER_INVALID]);                                                             \
    finish(gid, h, ANY, hits, occluded, &st, stats);                                                              \
  }

#define MBVH_COUNTERS_trace4_bitstack
#define MBVH_COUNTERS_trace2_bitstack
#define MBVH_COUNTERS_trace4_stack , counters
#define MBVH_COUNTERS_trace2_stack , counters

MBVH_KERNEL(mbvh4_bitstack_closest, float16, trace4_bitstack, false)
MBVH_KERNEL(mbvh4_bitstack_any, float16, trace4_bitstack, true)
MBVH_KERNEL(mbvh4_stack_closest, float16, trace4_stack, false)
MBVH_KERNEL(mbvh4_stack_any, float16, trace4_stack, true)
MBVH_KERNEL(mbvh2_bitstack_closest, Node2, trace2_bitstack, false)
MBVH_KERNEL(mbvh2_bitstack_any, Node2, trace2_bitstack, true)
MBVH_KERNEL(mbvh2_stack_closest, Node2, trace2_stack, false)
MBVH_KERNEL(mbvh2_stack_any, Node2, trace2_stack, true)

// SPDX-License-Identifier: MIT
// scene_gen.cpp — built-in generated scenes ("gen:NAME:PARAMS"), deterministic by their params:
// a closed UV sphere and a closed subdivided cube (watertightness), a random triangle soup,
// a hairball of thin tubes of any size (tens of millions of triangles), and exponentially
// spaced triangles (the worst case for the builder's depth cap).
#include <charconv>
#include <cmath>
#include <numbers>

#include "mbvh/error.h"
#include "host/core/gen/mandelbulb.h"
#include "host/core/random.h"
#include "host/core/resources.h"
#include "mbvh/scene.h"

namespace mbvh {
namespace {

std::vector<std::string> split(const std::string& s, char sep) {
  std::vector<std::string> out;
  std::size_t a = 0;
  for (;;) {
    std::size_t b = s.find(sep, a);
    out.push_back(s.substr(a, b == std::string::npos ? std::string::npos : b - a));
    if (b == std::string::npos) break;
    a = b + 1;
  }
  return out;
}

std::uint64_t param(const std::vector<std::string>& p, std::size_t i, std::uint64_t def, std::uint64_t lo,
                    std::uint64_t hi, const std::string& spec) {
  if (i >= p.size() || p[i].empty()) return def;
  std::uint64_t v = 0;
  auto r = std::from_chars(p[i].data(), p[i].data() + p[i].size(), v);
  if (r.ec != std::errc() || r.ptr != p[i].data() + p[i].size() || v < lo || v > hi)
    throw Error("gen:" + spec + ": parameter " + std::to_string(i) + " '" + p[i] + "' must be an integer in [" +
                std::to_string(lo) + ", " + std::to_string(hi) + "]");
  return v;
}

std::uint32_t add(Scene& s, float x, float y, float z) {
  s.vertices.push_back({x, y, z});
  return static_cast<std::uint32_t>(s.vertices.size() - 1);
}

// Two triangles per cell of an (n+1) x (n+1) vertex grid stored row by row from `base`.
void add_grid_triangles(Scene& s, std::uint32_t base, std::uint32_t n) {
  for (std::uint32_t i = 0; i < n; ++i)
    for (std::uint32_t j = 0; j < n; ++j) {
      const std::uint32_t a = base + i * (n + 1) + j, b = a + 1, c = a + (n + 1), d = c + 1;
      s.triangles.push_back({a, b, d});
      s.triangles.push_back({a, d, c});
    }
}

// Closed UV sphere of radius 1: `seg` segments around, seg/2 rings, poles shared.
Scene sphere(std::uint32_t seg) {
  Scene s;
  const std::uint32_t rings = std::max<std::uint32_t>(2, seg / 2);
  const double pi = std::numbers::pi;
  const std::uint32_t north = add(s, 0, 1, 0);
  for (std::uint32_t r = 1; r < rings; ++r) {
    const double th = pi * r / rings;
    for (std::uint32_t k = 0; k < seg; ++k) {
      const double ph = 2 * pi * k / seg;
      add(s, static_cast<float>(std::sin(th) * std::cos(ph)), static_cast<float>(std::cos(th)),
          static_cast<float>(std::sin(th) * std::sin(ph)));
    }
  }
  const std::uint32_t south = add(s, 0, -1, 0);
  auto ring = [&](std::uint32_t r, std::uint32_t k) { return 1 + (r - 1) * seg + (k % seg); };
  for (std::uint32_t k = 0; k < seg; ++k) s.triangles.push_back({north, ring(1, k + 1), ring(1, k)});
  for (std::uint32_t r = 1; r + 1 < rings; ++r)
    for (std::uint32_t k = 0; k < seg; ++k) {
      s.triangles.push_back({ring(r, k), ring(r, k + 1), ring(r + 1, k + 1)});
      s.triangles.push_back({ring(r, k), ring(r + 1, k + 1), ring(r + 1, k)});
    }
  for (std::uint32_t k = 0; k < seg; ++k) s.triangles.push_back({south, ring(rings - 1, k), ring(rings - 1, k + 1)});
  return s;
}

// Closed cube [-1,1]^3, n x n quads per face, two triangles each; grid coordinates are computed
// identically on every face, so shared edges are bit-identical.
Scene cube(std::uint32_t n) {
  Scene s;
  auto g = [n](std::uint32_t i) { return -1.0f + 2.0f * static_cast<float>(i) / static_cast<float>(n); };
  for (int axis = 0; axis < 3; ++axis)
    for (int side = 0; side < 2; ++side) {
      const std::uint32_t base = static_cast<std::uint32_t>(s.vertices.size());
      for (std::uint32_t i = 0; i <= n; ++i)
        for (std::uint32_t j = 0; j <= n; ++j) {
          Vec3f p;
          p[axis] = side ? 1.0f : -1.0f;
          p[(axis + 1) % 3] = g(i);
          p[(axis + 2) % 3] = g(j);
          s.vertices.push_back(p);
        }
      add_grid_triangles(s, base, n);
    }
  return s;
}

// Random triangle soup in the unit cube, edge lengths up to ~0.05.
Scene soup(std::uint64_t count, std::uint64_t seed) {
  Scene s;
  Rng rng(seed);
  s.vertices.reserve(count * 3);
  for (std::uint64_t i = 0; i < count; ++i) {
    const float cx = rng.uniform(), cy = rng.uniform(), cz = rng.uniform();
    const float r = 0.05f * rng.uniform() + 0.002f;
    std::array<std::uint32_t, 3> t{};
    for (int k = 0; k < 3; ++k)
      t[static_cast<std::size_t>(k)] = add(s, cx + r * (rng.uniform() - 0.5f), cy + r * (rng.uniform() - 0.5f),
                                           cz + r * (rng.uniform() - 0.5f));
    s.triangles.push_back(t);
  }
  return s;
}

// A hairball: random-walk tubes (6 sides, 16 segments, 192 triangles each) of radius 0.002
// inside the unit sphere, truncated to exactly `count` triangles.
Scene hairball(std::uint64_t count, std::uint64_t seed) {
  Scene s;
  Rng rng(seed);
  const int sides = 6, segs = 16;
  const double pi = std::numbers::pi;
  s.triangles.reserve(count);
  s.vertices.reserve(count / 2 + 64);
  while (s.triangles.size() < count) {
    // a walk start inside the sphere, smooth random direction changes
    double p[3], d[3];
    do {
      for (double& c : p) c = 2 * rng.uniform_d() - 1;
    } while (p[0] * p[0] + p[1] * p[1] + p[2] * p[2] > 0.8);
    double len = 0;
    do {
      for (double& c : d) c = 2 * rng.uniform_d() - 1;
      len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    } while (len < 0.1 || len > 1);
    for (double& c : d) c /= len;
    const double step = 0.02, radius = 0.002;
    const std::uint32_t base = static_cast<std::uint32_t>(s.vertices.size());
    for (int k = 0; k <= segs; ++k) {
      // frame perpendicular to d
      double a[3] = {std::fabs(d[0]) < 0.9 ? 1.0 : 0.0, std::fabs(d[0]) < 0.9 ? 0.0 : 1.0, 0.0};
      double u[3] = {d[1] * a[2] - d[2] * a[1], d[2] * a[0] - d[0] * a[2], d[0] * a[1] - d[1] * a[0]};
      double ul = std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]);
      for (double& c : u) c /= ul;
      double w[3] = {d[1] * u[2] - d[2] * u[1], d[2] * u[0] - d[0] * u[2], d[0] * u[1] - d[1] * u[0]};
      for (int j = 0; j < sides; ++j) {
        const double ang = 2 * pi * j / sides, cs = std::cos(ang) * radius, sn = std::sin(ang) * radius;
        add(s, static_cast<float>(p[0] + cs * u[0] + sn * w[0]), static_cast<float>(p[1] + cs * u[1] + sn * w[1]),
            static_cast<float>(p[2] + cs * u[2] + sn * w[2]));
      }
      for (int c = 0; c < 3; ++c) p[c] += step * d[c];
      for (double& c : d) c += 0.5 * (2 * rng.uniform_d() - 1);
      len = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
      for (double& c : d) c /= len;
    }
    for (int k = 0; k < segs && s.triangles.size() < count; ++k)
      for (int j = 0; j < sides && s.triangles.size() < count; ++j) {
        const std::uint32_t a = base + static_cast<std::uint32_t>(k * sides + j);
        const std::uint32_t b = base + static_cast<std::uint32_t>(k * sides + (j + 1) % sides);
        s.triangles.push_back({a, b, b + sides});
        if (s.triangles.size() < count) s.triangles.push_back({a, b + sides, a + sides});
      }
  }
  return s;
}

// n triangles at exponentially growing distances, x_i = 2^(40 i / n), each 0.1 x_i wide: SAH
// splits peel off a few at a time, making the deepest trees binning allows. The range stays
// within 2^40 so the watertight test's cubic products (~x^3) cannot overflow a float.
Scene exponential(std::uint32_t n) {
  Scene s;
  for (std::uint32_t i = 0; i < n; ++i) {
    const float x = std::exp2(40.0f * static_cast<float>(i) / static_cast<float>(n));
    const float w = 0.1f * x;
    const std::uint32_t a = add(s, x, 0, 0), b = add(s, x + w, 0, 0), c = add(s, x, w, w);
    s.triangles.push_back({a, b, c});
  }
  return s;
}

// Closed torus (major radius 1, minor 0.35): `seg` segments around, seg/2 around the tube.
Scene torus(std::uint32_t seg) {
  Scene s;
  const std::uint32_t tube = std::max<std::uint32_t>(3, seg / 2);
  const double pi = std::numbers::pi;
  for (std::uint32_t i = 0; i < seg; ++i)
    for (std::uint32_t j = 0; j < tube; ++j) {
      const double u = 2 * pi * i / seg, v = 2 * pi * j / tube, r = 1.0 + 0.35 * std::cos(v);
      add(s, static_cast<float>(r * std::cos(u)), static_cast<float>(0.35 * std::sin(v)), static_cast<float>(r * std::sin(u)));
    }
  auto at = [&](std::uint32_t i, std::uint32_t j) { return (i % seg) * tube + (j % tube); };
  for (std::uint32_t i = 0; i < seg; ++i)
    for (std::uint32_t j = 0; j < tube; ++j) {
      s.triangles.push_back({at(i, j), at(i + 1, j), at(i + 1, j + 1)});
      s.triangles.push_back({at(i, j), at(i + 1, j + 1), at(i, j + 1)});
    }
  return s;
}

// Closed box [0, n]^3 of unit quads with integer coordinates and shared (indexed) vertices.
Scene grid_box(std::uint32_t n) {
  Scene s;
  std::vector<std::int64_t> index(static_cast<std::size_t>(n + 1) * (n + 1) * (n + 1), -1);
  auto vid = [&](std::uint32_t x, std::uint32_t y, std::uint32_t z) {
    std::int64_t& v = index[(static_cast<std::size_t>(x) * (n + 1) + y) * (n + 1) + z];
    if (v < 0) v = add(s, static_cast<float>(x), static_cast<float>(y), static_cast<float>(z));
    return static_cast<std::uint32_t>(v);
  };
  for (int axis = 0; axis < 3; ++axis)
    for (std::uint32_t side : {0u, n})
      for (std::uint32_t i = 0; i < n; ++i)
        for (std::uint32_t j = 0; j < n; ++j) {
          std::uint32_t c[4][3];
          const std::uint32_t di[4] = {0, 1, 1, 0}, dj[4] = {0, 0, 1, 1};
          for (int k = 0; k < 4; ++k) {
            c[k][axis] = side;
            c[k][(axis + 1) % 3] = i + di[k];
            c[k][(axis + 2) % 3] = j + dj[k];
          }
          std::uint32_t q[4];
          for (int k = 0; k < 4; ++k) q[k] = vid(c[k][0], c[k][1], c[k][2]);
          s.triangles.push_back({q[0], q[1], q[2]});
          s.triangles.push_back({q[0], q[2], q[3]});
        }
  return s;
}

// A flat n x n grid in the plane z = 0 over [0, 1]^2: every box of its BVH has zero thickness.
Scene plane(std::uint32_t n) {
  Scene s;
  for (std::uint32_t i = 0; i <= n; ++i)
    for (std::uint32_t j = 0; j <= n; ++j)
      add(s, static_cast<float>(i) / static_cast<float>(n), static_cast<float>(j) / static_cast<float>(n), 0.0f);
  add_grid_triangles(s, 0, n);
  return s;
}

// Needles (one edge 1e-4 of the others), slivers (a vertex 1e-6 off the opposite edge) and
// exactly degenerate triangles (collinear or repeated vertices), mixed in the unit cube.
Scene needles(std::uint64_t count, std::uint64_t seed) {
  Scene s;
  Rng rng(seed);
  for (std::uint64_t i = 0; i < count; ++i) {
    const float cx = rng.uniform(), cy = rng.uniform(), cz = rng.uniform();
    const float ax = rng.uniform() - 0.5f, ay = rng.uniform() - 0.5f, az = rng.uniform() - 0.5f;
    const float l = 0.2f * rng.uniform() + 0.01f;
    const Vec3f a{cx, cy, cz}, b{cx + l * ax, cy + l * ay, cz + l * az};
    Vec3f c;
    switch (i % 4) {
      case 0: c = {a.x + 1e-4f * l, a.y - 1e-4f * l, a.z + 2e-4f * l}; break;            // needle
      case 1: c = {0.5f * (a.x + b.x), 0.5f * (a.y + b.y) + 1e-6f, 0.5f * (a.z + b.z)}; break;  // sliver
      case 2: c = {a.x + 2 * l * ax, a.y + 2 * l * ay, a.z + 2 * l * az}; break;          // collinear (maybe)
      default: c = b; break;                                                             // repeated vertex
    }
    const std::uint32_t ia = add(s, a.x, a.y, a.z), ib = add(s, b.x, b.y, b.z), ic = add(s, c.x, c.y, c.z);
    s.triangles.push_back({ia, ib, ic});
  }
  return s;
}

// "@scale=S" and "@offset=O" modifiers: every coordinate becomes v * S + O.
// An empty modifier (a trailing or doubled '@') is refused, as is any other unknown one.
void transform(Scene& s, const std::string& mods, const std::string& spec) {
  for (const std::string& m : split(mods, '@')) {
    const std::size_t eq = m.find('=');
    const std::string key = m.substr(0, eq);
    float value = 0;
    const char* vb = eq == std::string::npos ? nullptr : m.data() + eq + 1;
    const auto r = vb ? std::from_chars(vb, m.data() + m.size(), value) : std::from_chars_result{nullptr, std::errc::invalid_argument};
    if (!vb || r.ec != std::errc() || r.ptr != m.data() + m.size() || !std::isfinite(value) ||
        (key != "scale" && key != "offset") || (key == "scale" && !(value > 0)))
      throw Error("gen:" + spec + ": bad modifier '@" + m + "' (use @scale=S with S > 0 or @offset=O)");
    for (Vec3f& v : s.vertices)
      for (int k = 0; k < 3; ++k) {
        v[k] = key == "scale" ? v[k] * value : v[k] + value;
        if (!std::isfinite(v[k]))
          throw Error("gen:" + spec + ": '@" + m + "' takes a coordinate beyond the float range (" + std::to_string(v[k]) + ")");
      }
  }
}

}  // namespace

std::string generator_help() {
  return "gen:sphere:SEGMENTS          closed UV sphere, SEGMENTS around (default 64), SEGMENTS/2 rings\n"
         "gen:cube:N                   closed cube, N x N quads per face (default 16)\n"
         "gen:soup:COUNT[:SEED]        COUNT random triangles in the unit cube (default 100000)\n"
         "gen:hairball:COUNT[:SEED]    thin random tubes, exactly COUNT triangles (default 1000000)\n"
         "gen:exponential:N            N exponentially spaced triangles (default 200), depth-cap worst case\n"
         "gen:torus:SEGMENTS           closed torus, SEGMENTS around (default 64)\n"
         "gen:grid:N                   closed box [0,N]^3 of unit quads with integer coordinates (default 8)\n"
         "gen:plane:N                  flat N x N grid in z = 0 (default 32): zero-thickness boxes\n"
         "gen:needles:COUNT[:SEED]     needles, slivers and degenerate triangles (default 10000)\n"
         "gen:mandelbulb:RES[:K]       power-8 Mandelbulb (K iterations, default 8) on a RES^3 grid (default 64), closed;\n"
         "                             `mbvh gen` streams a large one to a .mtri file\n"
         "any of them + @scale=S@offset=O   every coordinate becomes v * S + O (in that order)\n";
}

namespace {
Scene generate_base(const std::string& spec);
MandelbulbOptions mandelbulb_options(const std::vector<std::string>& p, const std::string& spec);
void at_most(const std::vector<std::string>& p, std::size_t params, const std::string& spec, const char* usage);
}  // namespace

bool streamed_mandelbulb(const std::string& spec, MandelbulbOptions& out) {
  if (spec.find('@') != std::string::npos) return false;
  const std::vector<std::string> p = split(spec, ':');
  if (p[0] != "mandelbulb") return false;
  at_most(p, 2, spec, "gen:mandelbulb:RES:K");
  out = mandelbulb_options(p, spec);
  return true;
}

Scene generate_scene(const std::string& full_spec) {
  const std::size_t at = full_spec.find('@');
  const std::string spec = full_spec.substr(0, at);
  Scene s = generate_base(spec);
  if (at != std::string::npos) transform(s, full_spec.substr(at + 1), full_spec);
  return s;
}

namespace {

// Refuses, before generating, a scene of this size whose generation and build would not fit in
// memory (`extra`: the generator's own scratch memory).
void require_fit(const std::string& spec, std::uint64_t triangles, std::uint64_t vertices, std::uint64_t extra = 0) {
  // the scene itself (12 bytes a vertex and a triangle, as scene_memory_estimate) and the build's
  // share that this process will make (loading_build_estimate: all of it but in a data-parallel load)
  const std::uint64_t scene = scene_memory_estimate(triangles, vertices) - build_memory_estimate(triangles, vertices);
  const unsigned share = build_share();
  require_memory("gen:" + spec, scene + loading_build_estimate(triangles, vertices) + extra,
                 std::to_string(triangles) + " triangles, " + std::to_string(vertices) + " vertices, and " +
                     (share == 1 ? std::string("their build") : "1/" + std::to_string(share) + " of their build"));
}

// Refuses a spec with more parameters than its generator takes (`usage`: its form in
// generator_help), rather than ignoring the rest.
void at_most(const std::vector<std::string>& p, std::size_t params, const std::string& spec, const char* usage) {
  if (p.size() > params + 1)
    throw Error("gen:" + spec + ": " + std::to_string(p.size() - 1) + " parameters, but " + usage + " takes at most " +
                std::to_string(params) + " (parameter " + std::to_string(params + 1) + " is '" + p[params + 1] + "')");
}

MandelbulbOptions mandelbulb_options(const std::vector<std::string>& p, const std::string& spec) {
  MandelbulbOptions o;
  o.res = static_cast<std::uint32_t>(param(p, 1, 64, 2, 65536, spec));
  o.iterations = static_cast<std::uint32_t>(param(p, 2, 8, 1, 64, spec));
  return o;
}

Scene generate_base(const std::string& spec) {
  const std::vector<std::string> p = split(spec, ':');
  const std::string& n = p[0];
  static const struct { const char* name; std::size_t params; const char* usage; } forms[] = {
      {"sphere", 1, "gen:sphere:SEGMENTS"},          {"cube", 1, "gen:cube:N"},
      {"soup", 2, "gen:soup:COUNT:SEED"},            {"hairball", 2, "gen:hairball:COUNT:SEED"},
      {"exponential", 1, "gen:exponential:N"},       {"torus", 1, "gen:torus:SEGMENTS"},
      {"grid", 1, "gen:grid:N"},                     {"plane", 1, "gen:plane:N"},
      {"needles", 2, "gen:needles:COUNT:SEED"},      {"mandelbulb", 2, "gen:mandelbulb:RES:K"}};
  for (const auto& f : forms)
    if (n == f.name) at_most(p, f.params, spec, f.usage);
  if (n == "sphere") {
    const std::uint64_t seg = param(p, 1, 64, 3, 1u << 15, spec), rings = std::max<std::uint64_t>(2, seg / 2);
    require_fit(spec, 2 * seg * (rings - 1), 2 + (rings - 1) * seg);
    return sphere(static_cast<std::uint32_t>(seg));
  }
  if (n == "cube") {
    const std::uint64_t k = param(p, 1, 16, 1, 4096, spec);
    require_fit(spec, 12 * k * k, 6 * (k + 1) * (k + 1));
    return cube(static_cast<std::uint32_t>(k));
  }
  if (n == "soup") {
    const std::uint64_t count = param(p, 1, 100000, 1, 200'000'000, spec), seed = param(p, 2, 1, 0, UINT64_MAX, spec);
    require_fit(spec, count, 3 * count);
    return soup(count, seed);
  }
  if (n == "hairball") {
    const std::uint64_t count = param(p, 1, 1'000'000, 1, 400'000'000, spec), seed = param(p, 2, 1, 0, UINT64_MAX, spec);
    require_fit(spec, count, (count + 191) / 192 * 102);  // 102 vertices a tube of 192 triangles
    return hairball(count, seed);
  }
  if (n == "exponential") return exponential(static_cast<std::uint32_t>(param(p, 1, 200, 1, 200, spec)));
  if (n == "torus") {
    const std::uint64_t seg = param(p, 1, 64, 3, 1u << 14, spec), tube = std::max<std::uint64_t>(3, seg / 2);
    require_fit(spec, 2 * seg * tube, seg * tube);
    return torus(static_cast<std::uint32_t>(seg));
  }
  if (n == "grid") {
    const std::uint64_t k = param(p, 1, 8, 1, 1024, spec);
    require_fit(spec, 12 * k * k, 6 * (k + 1) * (k + 1), 8 * (k + 1) * (k + 1) * (k + 1));  // + the vertex index
    return grid_box(static_cast<std::uint32_t>(k));
  }
  if (n == "plane") {
    const std::uint64_t k = param(p, 1, 32, 1, 4096, spec);
    require_fit(spec, 2 * k * k, (k + 1) * (k + 1));
    return plane(static_cast<std::uint32_t>(k));
  }
  if (n == "needles") {
    const std::uint64_t count = param(p, 1, 10000, 1, 100'000'000, spec), seed = param(p, 2, 1, 0, UINT64_MAX, spec);
    require_fit(spec, count, 3 * count);
    return needles(count, seed);
  }
  if (n == "mandelbulb") {
    const MandelbulbOptions o = mandelbulb_options(p, spec);
    const std::uint64_t t = mandelbulb_triangle_estimate(o.res);
    require_fit(spec, t, 3 * t);
    Scene s;
    generate_mandelbulb(o, [&s](std::uint64_t, std::span<const SourceTri> tris) { append_triangles(s, tris); });
    return s;
  }
  throw Error("gen:" + spec + ": unknown generator '" + n + "'; known generators:\n" + generator_help());
}

}  // namespace

}  // namespace mbvh

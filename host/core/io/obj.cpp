// SPDX-License-Identifier: MIT
// obj.cpp — a fast Wavefront OBJ reader: v, f, usemtl and mtllib lines (vt/vn/groups ignored),
// all four face-index forms, negative indices, fan triangulation (0, k, k+1). `usemtl` gives the
// triangles after it a material (Scene::triangle_materials); `mtllib` names are kept for
// load_scene, which reads their colours (mtl.cpp).
// It never drops or shifts geometry silently: a UTF-8 byte-order mark at the start is skipped,
// LF and CRLF line ends are read, and these are errors naming the line: a carriage return inside
// a line (classic Mac line ends), a NUL byte (binary data, UTF-16), a statement that is not an
// OBJ keyword, a `v` without 3 coordinates or with 5 or more than 6 values (x y z, x y z w and
// x y z r g b are read: w and vertex colours are ignored), an `f` with fewer than 3 vertices.
// Written instead of tinyobjloader because it reports every error with file and line, and is
// faster (docs/cli.md).
#include "host/core/io/obj.h"

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstring>
#include <string_view>
#include <utility>

#include "mbvh/error.h"
#include "mbvh/scene.h"

namespace mbvh {
namespace {

bool is_space(char c) { return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f'; }

const char* skip_space(const char* p, const char* end) {
  while (p < end && is_space(*p)) ++p;
  return p;
}

const char* token_end(const char* p, const char* end) {
  while (p < end && !is_space(*p)) ++p;
  return p;
}

bool is(const char* b, const char* e, std::string_view keyword) { return std::string_view(b, static_cast<std::size_t>(e - b)) == keyword; }

// Every statement of the OBJ specification (Wavefront, appendix B1) besides v and f, the common first.
bool is_other_keyword(const char* b, const char* e) {
  static constexpr std::string_view keywords[] = {
      "vt", "vn", "g", "o", "s", "usemtl", "mtllib", "l", "p", "vp", "maplib", "usemap", "lod", "bevel", "c_interp",
      "d_interp", "trace_obj", "shadow_obj", "ctech", "stech", "cstype", "deg", "bmat", "step", "curv", "curv2",
      "surf", "parm", "trim", "hole", "scrv", "sp", "end", "con", "mg", "call", "csh", "res"};
  for (std::string_view k : keywords)
    if (is(b, e, k)) return true;
  return false;
}

// A statement name for a message: at most 24 bytes, anything unprintable shown as '?'.
std::string printable(const char* b, const char* e) {
  std::string out(b, std::min<std::size_t>(static_cast<std::size_t>(e - b), 24));
  for (char& c : out)
    if (static_cast<unsigned char>(c) < 0x20 || static_cast<unsigned char>(c) >= 0x7f) c = '?';
  return out + (e - b > 24 ? "..." : "");
}

}  // namespace

ObjParser::ObjParser(std::string name, MemoryBudget budget) : name_(std::move(name)), budget_(budget) { s_.name = name_; }

// A file with a NUL byte is binary (or UTF-16), not OBJ text: refused naming the line, as soon as
// the piece holding it arrives (a sparse 4 GB file of zeros is refused at its first MiB).
void ObjParser::refuse_binary(const char* data, std::size_t size) const {
  if (size == 0) return;  // no bytes (and data may be null, which memchr must not get)
  const char* nul = static_cast<const char*>(std::memchr(data, '\0', size));
  if (!nul) return;
  const bool utf16 = bytes_ >= 2 && ((first_[0] == '\xFF' && first_[1] == '\xFE') || (first_[0] == '\xFE' && first_[1] == '\xFF'));
  if (utf16) fail_at(name_, 1, "UTF-16 text (a UTF-16 byte-order mark): save the OBJ file as UTF-8 or ASCII");
  const std::size_t line = line_ + 1 + static_cast<std::size_t>(std::count(data, nul, '\n'));  // partial_ has no line end
  fail_at(name_, line, "a NUL byte: binary data, not an OBJ text file");
}

// What the parse holds (the scene so far, the partial line, the forward indices), then what the
// build of the scene so far will need: both refused before the file goes on.
void ObjParser::check_budget() const {
  const std::uint64_t held = 12 * std::uint64_t(s_.vertices.capacity()) + 12 * std::uint64_t(s_.triangles.capacity()) +
                             4 * std::uint64_t(s_.triangle_materials.capacity()) +
                             partial_.size() + sizeof(Pending) * std::uint64_t(forward_.capacity());
  require_memory(name_, held,
                 "to hold the " + std::to_string(s_.vertices.size()) + " vertices and " + std::to_string(s_.triangles.size()) +
                     " triangles read by line " + std::to_string(line_) + (partial_.empty() ? "" : " and a line of " + format_bytes(partial_.size())),
                 budget_);
  require_memory(name_, loading_build_estimate(s_.triangles.size(), s_.vertices.size()),
                 "to build its " + std::to_string(s_.triangles.size()) + " triangles read by line " + std::to_string(line_), budget_);
}

void ObjParser::feed(const char* data, std::size_t size) {
  if (size == 0) return;
  for (std::size_t i = 0; i < size && bytes_ + i < 2; ++i) first_[bytes_ + i] = data[i];
  bytes_ += size;
  refuse_binary(data, size);
  const char* p = data;
  const char* const end = data + size;
  if (!partial_.empty()) {  // the line begun in an earlier piece
    const char* nl = static_cast<const char*>(std::memchr(p, '\n', size));
    if (!nl) {
      partial_.append(p, size);
      check_budget();
      return;
    }
    partial_.append(p, nl);
    parse_line(partial_.data(), partial_.data() + partial_.size());
    partial_.clear();
    p = nl + 1;
  }
  while (p < end) {
    const char* nl = static_cast<const char*>(std::memchr(p, '\n', static_cast<std::size_t>(end - p)));
    if (!nl) break;
    parse_line(p, nl);
    p = nl + 1;
  }
  partial_.assign(p, end);
  check_budget();
}

Scene ObjParser::finish() {
  if (!partial_.empty()) parse_line(partial_.data(), partial_.data() + partial_.size());  // a last line without a line end
  partial_.clear();
  for (const Pending& f : forward_)
    if (f.index > static_cast<long long>(s_.vertices.size()))
      fail_at(name_, f.line, "vertex index " + std::to_string(f.index) + " is out of range (the file has " +
                                std::to_string(s_.vertices.size()) + " vertices)");
  return std::move(s_);
}

// One line without its line end: [p, next).
void ObjParser::parse_line(const char* p, const char* next) {
  const std::string& name = name_;
  Scene& s = s_;
  const std::size_t line = ++line_;
  if (line == 1 && next - p >= 3 && std::memcmp(p, "\xEF\xBB\xBF", 3) == 0) p += 3;  // UTF-8 byte-order mark
  const std::size_t length = static_cast<std::size_t>(next - p) - (next > p && next[-1] == '\r' ? 1 : 0);  // CRLF
  const char* eol = p + length;
  if (std::memchr(p, '\r', length))
    fail_at(name, line, "a carriage return inside the line (classic Mac line ends are not read; use LF or CRLF)");
  const char* q = skip_space(p, eol);
  if (q == eol || *q == '#') return;  // blank line or comment
  const char* ke = token_end(q, eol);
  if (is(q, ke, "v")) {
    // -- vertex: v x y z [w | r g b]
    float c[3];
    int values = 0;
    for (q = ke;; ++values) {
      q = skip_space(q, eol);
      if (q >= eol || *q == '#') break;
      const char* te = token_end(q, eol);
      float v = 0;
      const char* b = (*q == '+') ? q + 1 : q;
      auto r = std::from_chars(b, te, v);
      if (r.ec == std::errc::result_out_of_range) {
        fail_at(name, line, "coordinate '" + std::string(q, te) + "' is out of float range");
      }
      if (r.ec != std::errc() || r.ptr != te)
        fail_at(name, line, "bad number '" + std::string(q, te) + "' in vertex");
      if (values < 3) {
        if (!std::isfinite(v)) fail_at(name, line, "NaN or infinite coordinate '" + std::string(q, te) + "'");
        c[values] = v;
      }
      q = te;
    }
    if (values < 3) fail_at(name, line, "vertex has fewer than 3 coordinates");
    if (values == 5 || values > 6)
      fail_at(name, line, "vertex has " + std::to_string(values) + " values (x y z, x y z w or x y z r g b expected)");
    s.vertices.push_back({c[0], c[1], c[2]});
  } else if (is(q, ke, "f")) {
    // -- face: f i[/j[/k]] ... ; fan-triangulated
    face_.clear();
    q = ke;
    for (;;) {
      q = skip_space(q, eol);
      if (q >= eol || *q == '#') break;
      const char* te = token_end(q, eol);
      const char* slash = static_cast<const char*>(std::memchr(q, '/', static_cast<std::size_t>(te - q)));
      const char* ie = slash ? slash : te;
      long long idx = 0;
      auto r = std::from_chars(q, ie, idx);
      if (r.ec != std::errc() || r.ptr != ie)
        fail_at(name, line, "bad vertex index '" + std::string(q, te) + "' in face");
      for (const char* k = ie; k < te; ++k)
        if (!(*k == '/' || *k == '-' || (*k >= '0' && *k <= '9')))
          fail_at(name, line, "bad index token '" + std::string(q, te) + "' in face");
      const long long nv = static_cast<long long>(s.vertices.size());
      long long resolved;
      if (idx == 0) fail_at(name, line, "vertex index 0 is invalid (OBJ indices start at 1)");
      if (idx < 0) {
        resolved = nv + idx;
        if (resolved < 0)
          fail_at(name, line, "relative vertex index " + std::to_string(idx) + " is out of range (only " +
                                  std::to_string(nv) + " vertices so far)");
      } else {
        resolved = idx - 1;
        if (resolved > 0xFFFFFFF0ll) fail_at(name, line, "vertex index " + std::to_string(idx) + " is out of range");
        if (resolved >= nv) forward_.push_back({s.triangles.size(), line, idx});
      }
      face_.push_back(static_cast<std::uint32_t>(resolved));
      q = te;
    }
    if (face_.size() < 3)
      fail_at(name, line, "face has " + std::to_string(face_.size()) + " vertices (at least 3 needed)");
    for (std::size_t k = 1; k + 1 < face_.size(); ++k) s.triangles.push_back({face_[0], face_[k], face_[k + 1]});
    if (!s.materials.empty()) s.triangle_materials.resize(s.triangles.size(), material_);
  } else if (is(q, ke, "usemtl")) {
    // -- material of the faces that follow: the rest of the line, trimmed (names may hold spaces)
    const char* b = skip_space(ke, eol);
    const char* e = eol;
    while (e > b && is_space(e[-1])) --e;
    if (b == e) {
      material_ = kNoMaterial;
      return;
    }
    std::string m(b, e);
    auto [it, added] = material_index_.try_emplace(m, static_cast<std::uint32_t>(s.materials.size()));
    if (added) {
      if (s.materials.empty()) s.triangle_materials.assign(s.triangles.size(), kNoMaterial);  // the faces before
      s.materials.push_back(Material{std::move(m)});  // grey until read_materials finds its Kd
    }
    material_ = it->second;
  } else if (is(q, ke, "mtllib")) {
    // -- material libraries: one or more file names
    for (q = ke;;) {
      q = skip_space(q, eol);
      if (q >= eol) break;
      const char* te = token_end(q, eol);
      libraries_.push_back({std::string(q, te), line});
      q = te;
    }
  } else if (!is_other_keyword(q, ke)) {
    fail_at(name, line, "unknown statement '" + printable(q, ke) + "' (not an OBJ keyword)");
  }
  // the other keywords (vt, vn, g, o, s, l, p, curves and surfaces) are ignored
}

Scene parse_obj(const std::string& name, const char* data, std::size_t size) {
  ObjParser parser(name);
  parser.feed(data, size);
  return parser.finish();
}

}  // namespace mbvh

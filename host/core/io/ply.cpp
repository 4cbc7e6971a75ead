// SPDX-License-Identifier: MIT
// ply.cpp — a PLY reader: ascii, binary_little_endian and binary_big_endian; any extra vertex
// properties and elements; faces as a list property (vertex_indices / vertex_index),
// fan-triangulated (0, k, k+1). Counts are checked against the bytes left and the memory budget
// before anything is allocated, so a lying header cannot exhaust memory. Nothing is dropped silently: a UTF-8
// byte-order mark before "ply" is skipped and CRLF header lines are read, but a header line with
// more words than its keyword takes, an ascii element line with more values than its properties,
// and data after the last element are errors naming the line (or the byte count, in binary).
#include <algorithm>
#include <bit>
#include <charconv>
#include <cmath>
#include <cstring>
#include <sstream>

#include "host/core/resources.h"
#include "mbvh/error.h"
#include "mbvh/scene.h"

namespace mbvh {
namespace {

enum class Type { i8, u8, i16, u16, i32, u32, f32, f64 };

bool parse_type(const std::string& s, Type& t) {
  static const struct { const char* n; Type t; } table[] = {
      {"char", Type::i8},   {"int8", Type::i8},     {"uchar", Type::u8},   {"uint8", Type::u8},
      {"short", Type::i16}, {"int16", Type::i16},   {"ushort", Type::u16}, {"uint16", Type::u16},
      {"int", Type::i32},   {"int32", Type::i32},   {"uint", Type::u32},   {"uint32", Type::u32},
      {"float", Type::f32}, {"float32", Type::f32}, {"double", Type::f64}, {"float64", Type::f64}};
  for (const auto& e : table)
    if (s == e.n) { t = e.t; return true; }
  return false;
}

std::size_t type_size(Type t) {
  switch (t) {
    case Type::i8: case Type::u8: return 1;
    case Type::i16: case Type::u16: return 2;
    case Type::i32: case Type::u32: case Type::f32: return 4;
    case Type::f64: return 8;
  }
  return 0;
}

struct Property {
  std::string name;
  Type type = Type::f32;
  bool is_list = false;
  Type count_type = Type::u8;
};

struct Element {
  std::string name;
  std::uint64_t count = 0;
  std::size_t header_line = 0;
  std::vector<Property> props;
};

enum class Format { ascii, binary_le, binary_be };

// Reads values one at a time from the body, in either encoding.
class Reader {
public:
  Reader(const std::string& name, const char* p, const char* end, Format f, std::size_t line)
      : name_(name), p_(p), end_(end), format_(f), line_(line) {}

  double read(Type t, const char* what) {
    if (format_ == Format::ascii) return read_ascii(what);
    const std::size_t n = type_size(t);
    if (static_cast<std::size_t>(end_ - p_) < n) fail_at(name_, 0, std::string("truncated file: binary data ends inside ") + what);
    unsigned char b[8];
    std::memcpy(b, p_, n);
    p_ += n;
    if ((format_ == Format::binary_be) != (std::endian::native == std::endian::big))
      for (std::size_t i = 0; i < n / 2; ++i) std::swap(b[i], b[n - 1 - i]);
    switch (t) {
      case Type::i8: { std::int8_t v; std::memcpy(&v, b, 1); return v; }
      case Type::u8: return b[0];
      case Type::i16: { std::int16_t v; std::memcpy(&v, b, 2); return v; }
      case Type::u16: { std::uint16_t v; std::memcpy(&v, b, 2); return v; }
      case Type::i32: { std::int32_t v; std::memcpy(&v, b, 4); return v; }
      case Type::u32: { std::uint32_t v; std::memcpy(&v, b, 4); return v; }
      case Type::f32: { float v; std::memcpy(&v, b, 4); return v; }
      case Type::f64: { double v; std::memcpy(&v, b, 8); return v; }
    }
    return 0;
  }

  // A vertex coordinate, rounded once to float: in ascii the decimal is parsed straight to float
  // (as the OBJ reader does), so the same text gives the same float in both formats; a decimal
  // beyond the float range reads as infinite (refused by the caller, naming the vertex).
  float read_float(Type t, const char* what) {
    if (format_ != Format::ascii) return static_cast<float>(read(t, what));
    const char* b = token(what);
    const char* te = p_;
    float v = 0;
    const char* d = (*b == '+') ? b + 1 : b;
    auto r = std::from_chars(d, te, v);
    if (r.ec == std::errc::result_out_of_range && r.ptr == te) {
      double big = 0;  // out of float range: its sign and size decide infinity or zero
      std::from_chars(d, te, big);
      v = std::fabs(big) > 1 ? (big < 0 ? -INFINITY : INFINITY) : static_cast<float>(big);
    } else if (r.ec != std::errc() || r.ptr != te) {
      fail_at(name_, line_, "bad number '" + std::string(b, te) + "' for " + what);
    }
    return v;
  }

  // ascii: each element is one line; called at the start of an element's line
  void begin_element() {
    if (format_ != Format::ascii) return;
    // skip blank lines
    for (;;) {
      while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r')) ++p_;
      if (p_ < end_ && *p_ == '\n') { ++p_; ++line_; continue; }
      break;
    }
    ++line_;
    eol_ = static_cast<const char*>(std::memchr(p_, '\n', static_cast<std::size_t>(end_ - p_)));
    if (!eol_) eol_ = end_;
  }
  // ascii: the rest of the element's line must be blank; `what` names the element ("vertex 3")
  void end_element(const std::string& what) {
    if (format_ != Format::ascii) return;
    while (p_ < eol_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r')) ++p_;
    if (p_ < eol_) {
      const char* te = p_;
      while (te < eol_ && !(*te == ' ' || *te == '\t' || *te == '\r')) ++te;
      fail_at(name_, line_, what + ": extra value '" + std::string(p_, std::min<std::size_t>(static_cast<std::size_t>(te - p_), 24)) +
                                "' after the last property (the header declares fewer)");
    }
    p_ = eol_ < end_ ? eol_ + 1 : end_;
  }
  // after the last element only blank lines (ascii) or nothing (binary) may follow
  void end_data() {
    if (format_ != Format::ascii) {
      if (p_ < end_)
        fail_at(name_, 0, std::to_string(end_ - p_) + " bytes of data after the last element (the header's counts or "
                                                       "types do not match the data)");
      return;
    }
    while (p_ < end_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r' || *p_ == '\n')) {
      if (*p_ == '\n') ++line_;
      ++p_;
    }
    if (p_ < end_) fail_at(name_, line_ + 1, "data after the last element (the header's counts do not match the data)");
  }
  std::size_t line() const { return format_ == Format::ascii ? line_ : 0; }
  std::size_t bytes_left() const { return static_cast<std::size_t>(end_ - p_); }
  bool ascii() const { return format_ == Format::ascii; }

private:
  // ascii: skips to the next value of the element's line and past it; returns where it starts
  const char* token(const char* what) {
    while (p_ < eol_ && (*p_ == ' ' || *p_ == '\t' || *p_ == '\r')) ++p_;
    if (p_ >= eol_) {
      if (p_ >= end_) fail_at(name_, line_, std::string("truncated file: data ends before ") + what);
      fail_at(name_, line_, std::string("line ends before ") + what);
    }
    const char* b = p_;
    while (p_ < eol_ && !(*p_ == ' ' || *p_ == '\t' || *p_ == '\r')) ++p_;
    return b;
  }
  double read_ascii(const char* what) {
    const char* b = token(what);
    const char* te = p_;
    double v = 0;
    const char* d = (*b == '+') ? b + 1 : b;
    auto r = std::from_chars(d, te, v);
    if (r.ec != std::errc() || r.ptr != te)
      fail_at(name_, line_, "bad number '" + std::string(b, te) + "' for " + what);
    return v;
  }

  const std::string& name_;
  const char* p_;
  const char* end_;
  const char* eol_ = nullptr;
  Format format_;
  std::size_t line_;
};

// Reads the header from `p` (past a byte-order mark) to its end_header line: the format and the
// elements with their properties, in file order. `p` moves past the header, `line` counts its lines.
struct PlyHeader {
  Format format = Format::ascii;
  std::vector<Element> elements;
};

PlyHeader read_header(const std::string& name, const char*& p, const char* end, std::size_t& line) {
  PlyHeader h;
  auto next_line = [&](std::string& out) -> bool {
    if (p >= end) return false;
    const char* eol = static_cast<const char*>(std::memchr(p, '\n', static_cast<std::size_t>(end - p)));
    if (!eol) eol = end;
    out.assign(p, eol);
    if (!out.empty() && out.back() == '\r') out.pop_back();
    p = eol < end ? eol + 1 : end;
    ++line;
    return true;
  };
  std::string l;
  if (!next_line(l) || l != "ply") fail_at(name, 1, "not a PLY file (first line must be 'ply')");
  bool have_format = false;
  for (;;) {
    if (!next_line(l)) fail_at(name, line, "truncated header (no end_header)");
    std::istringstream ls(l);
    std::string kw;
    ls >> kw;
    if (kw.empty() || kw == "comment" || kw == "obj_info") continue;
    // a line with more words than its keyword takes is refused: a guess could shift every value
    auto no_more_words = [&] {
      std::string extra;
      if (ls >> extra) fail_at(name, line, "unexpected '" + extra + "' at the end of the header line '" + l + "'");
    };
    if (kw == "end_header") {
      no_more_words();
      break;
    }
    if (kw == "format") {
      std::string f, v;
      ls >> f >> v;
      if (f == "ascii") h.format = Format::ascii;
      else if (f == "binary_little_endian") h.format = Format::binary_le;
      else if (f == "binary_big_endian") h.format = Format::binary_be;
      else fail_at(name, line, "unknown PLY format '" + f + "'");
      if (v != "1.0") fail_at(name, line, "unsupported PLY version '" + v + "'");
      no_more_words();
      have_format = true;
    } else if (kw == "element") {
      Element e;
      std::string count;
      ls >> e.name >> count;
      auto r = std::from_chars(count.data(), count.data() + count.size(), e.count);
      if (e.name.empty() || r.ec != std::errc() || r.ptr != count.data() + count.size())
        fail_at(name, line, "bad element line '" + l + "'");
      no_more_words();
      for (const Element& o : h.elements)
        if (o.name == e.name)
          fail_at(name, line, "element '" + e.name + "' declared a second time (first on line " + std::to_string(o.header_line) +
                                  "); a PLY file declares each element once");
      e.header_line = line;
      h.elements.push_back(e);
    } else if (kw == "property") {
      if (h.elements.empty()) fail_at(name, line, "property before any element");
      Property pr;
      std::string t;
      ls >> t;
      if (t == "list") {
        std::string ct, it;
        ls >> ct >> it >> pr.name;
        pr.is_list = true;
        if (!parse_type(ct, pr.count_type) || !parse_type(it, pr.type))
          fail_at(name, line, "unknown property type in '" + l + "'");
      } else {
        ls >> pr.name;
        if (!parse_type(t, pr.type)) fail_at(name, line, "unknown property type '" + t + "'");
      }
      if (pr.name.empty()) fail_at(name, line, "property without a name");
      no_more_words();
      Element& e = h.elements.back();
      auto is_index_list = [](const Property& q) { return q.is_list && (q.name == "vertex_indices" || q.name == "vertex_index"); };
      for (std::size_t k = 0; k < e.props.size(); ++k) {
        if (e.props[k].name == pr.name)
          fail_at(name, line, "property '" + pr.name + "' of element '" + e.name + "' declared a second time (which to read is ambiguous)");
        if (e.name == "face" && is_index_list(pr) && is_index_list(e.props[k]))
          fail_at(name, line, "a second vertex index list '" + pr.name + "' in element 'face' (it has '" + e.props[k].name +
                                  "'; which to read is ambiguous)");
      }
      e.props.push_back(pr);
    } else if (!std::isalpha(static_cast<unsigned char>(kw[0])) ||
               std::any_of(l.begin(), l.end(), [](char c) { return static_cast<unsigned char>(c) < 0x20 && c != '\t'; })) {
      // numbers or binary bytes where a keyword should be: the data, with no end_header before it
      fail_at(name, line, "no end_header before the data: this line holds '" +
                              std::string(l, 0, std::min<std::size_t>(l.size(), 24)) + "', not a header keyword; the header "
                              "must end with an end_header line");
    } else {
      fail_at(name, line, "unknown header keyword '" + kw + "'");
    }
  }
  if (!have_format) fail_at(name, line, "header has no format line");
  return h;
}

}  // namespace

Scene parse_ply(const std::string& name, const char* data, std::size_t size) {
  Scene s;
  s.name = name;
  const char* p = data;
  const char* end = data + size;
  if (size >= 3 && std::memcmp(p, "\xEF\xBB\xBF", 3) == 0) p += 3;  // UTF-8 byte-order mark
  std::size_t line = 0;
  const PlyHeader h = read_header(name, p, end, line);
  const Format format = h.format;
  const std::vector<Element>& elements = h.elements;

  // -- body
  Reader rd(name, p, end, format, line);
  const MemoryBudget budget = memory_budget();
  // faces may come before the vertices (the order of elements is free): their indices are then
  // checked once the vertices are read, against the largest index and the face that holds it
  bool vertices_read = false;
  struct { std::uint32_t index = 0; std::uint64_t face = 0; std::size_t line = 0; bool any = false; } largest;
  for (const Element& e : elements) {
    const bool is_vertex = e.name == "vertex";
    const bool is_face = e.name == "face";
    int ix = -1, iy = -1, iz = -1, ilist = -1;
    std::size_t min_bytes = 0;  // lower bound on bytes per element, for the count check
    for (std::size_t k = 0; k < e.props.size(); ++k) {
      const Property& pr = e.props[k];
      min_bytes += pr.is_list ? type_size(pr.count_type) : type_size(pr.type);
      if (is_vertex && !pr.is_list) {
        if (pr.name == "x") ix = static_cast<int>(k);
        if (pr.name == "y") iy = static_cast<int>(k);
        if (pr.name == "z") iz = static_cast<int>(k);
      }
      if (is_face && pr.is_list && (pr.name == "vertex_indices" || pr.name == "vertex_index")) ilist = static_cast<int>(k);
    }
    if (is_vertex && (ix < 0 || iy < 0 || iz < 0)) fail_at(name, e.header_line, "vertex element lacks x, y or z");
    if (is_face && ilist < 0) fail_at(name, e.header_line, "face element lacks a vertex_indices list");
    // every element needs at least 2 bytes in ascii ("0\n") or its fixed bytes in binary
    const std::size_t per = rd.ascii() ? 2 * std::max<std::size_t>(e.props.size(), 1) : std::max<std::size_t>(min_bytes, 1);
    if (e.count > rd.bytes_left() / per + (rd.ascii() ? 1 : 0))
      fail_at(name, e.header_line, "truncated file: element '" + e.name + "' claims " + std::to_string(e.count) +
                                       " entries but the file has only " + std::to_string(rd.bytes_left()) + " bytes left");
    // the counts the bytes allow may still exceed the memory budget: refused before allocating
    if (is_vertex || is_face)
      require_memory(name, size + 12 * (e.count + (is_vertex ? s.triangles.size() : s.vertices.size())),
                     "to hold the " + std::to_string(e.count) + (is_vertex ? " vertices" : " faces, a triangle or more each,") +
                         " its header declares (line " + std::to_string(e.header_line) + ") beside the file's " + format_bytes(size),
                     budget);
    if (is_vertex) s.vertices.reserve(static_cast<std::size_t>(e.count));
    std::vector<std::uint32_t> face;
    for (std::uint64_t i = 0; i < e.count; ++i) {
      rd.begin_element();
      const std::size_t at_line = rd.line();
      auto where = [&](const std::string& msg) {
        fail_at(name, at_line, e.name + " " + std::to_string(i) + ": " + msg);
      };
      float c[3] = {0, 0, 0};
      face.clear();
      for (std::size_t k = 0; k < e.props.size(); ++k) {
        const Property& pr = e.props[k];
        if (pr.is_list) {
          const double n = rd.read(pr.count_type, "a list count");
          if (!(n >= 0) || n != std::floor(n) || n > 1e6) where("bad list count " + std::to_string(n));
          const bool keep = static_cast<int>(k) == ilist;
          for (std::uint64_t j = 0; j < static_cast<std::uint64_t>(n); ++j) {
            const double v = rd.read(pr.type, "a list entry");
            if (keep) {
              if (!(v >= 0) || v != std::floor(v) || v >= 4294967295.0)
                where("bad vertex index " + std::to_string(v));
              face.push_back(static_cast<std::uint32_t>(v));
            }
          }
        } else {
          const int axis = static_cast<int>(k) == ix ? 0 : static_cast<int>(k) == iy ? 1 : static_cast<int>(k) == iz ? 2 : -1;
          if (axis >= 0) c[axis] = rd.read_float(pr.type, pr.name.c_str());
          else rd.read(pr.type, pr.name.c_str());
        }
      }
      rd.end_element(e.name + " " + std::to_string(i));
      if (is_vertex) {
        const Vec3f v{c[0], c[1], c[2]};
        if (!std::isfinite(v.x) || !std::isfinite(v.y) || !std::isfinite(v.z))
          where("NaN or infinite coordinate (or beyond float range)");
        s.vertices.push_back(v);
      } else if (is_face) {
        if (face.size() < 3) where("face has " + std::to_string(face.size()) + " vertices (at least 3 needed)");
        for (std::uint32_t v : face) {
          if (vertices_read && v >= s.vertices.size())
            where("vertex index " + std::to_string(v) + " is out of range (" + std::to_string(s.vertices.size()) +
                  " vertices)");
          if (!vertices_read && (!largest.any || v > largest.index)) largest = {v, i, at_line, true};
        }
        for (std::size_t k = 1; k + 1 < face.size(); ++k) s.triangles.push_back({face[0], face[k], face[k + 1]});
      }
    }
    vertices_read |= is_vertex;
  }
  if (largest.any && largest.index >= s.vertices.size())
    fail_at(name, largest.line, "face " + std::to_string(largest.face) + ": vertex index " + std::to_string(largest.index) +
                                    " is out of range (" + std::to_string(s.vertices.size()) + " vertices)");
  rd.end_data();
  return s;
}

}  // namespace mbvh

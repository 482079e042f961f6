#pragma once
// The INRIA 3D Gaussian Splatting PLY format (the file 3DGS, gsplat, OpenSplat and
// most viewers exchange).
//
// One `vertex` element with one row per Gaussian:
//   x y z            mean
//   nx ny nz         unused normals (written as 0, ignored when read)
//   f_dc_0..2        SH DC coefficient, RGB
//   f_rest_0..M-1    higher SH coefficients, CHANNEL-major: f_rest[c * (K-1) + (k-1)]
//                    holds coefficient k (1..K-1) of channel c; M = 3 (K-1) is 0, 9, 24
//                    or 45 for degree 0..3 (K = (degree+1)^2)
//   opacity          opacity logit (opacity = sigmoid(value))
//   scale_0..2       log of the per-axis standard deviation
//   rot_0..3         quaternion, w first, not necessarily normalised
// GaussianScene keeps sh as [N][K][3] (coefficient-major, then RGB), so the reader
// and writer transpose the f_rest block.
//
// Reading accepts any property order, property types char/uchar/short/ushort/int/
// uint/float/double (and the int8.. float64 aliases), the formats
// binary_little_endian, binary_big_endian and ascii, comment/obj_info lines, extra
// vertex properties (ignored) and other elements before or after `vertex` (skipped,
// list properties included). The degree is inferred from the number of f_rest
// properties. Values are taken as stored: NaN or infinite parameters are NOT
// rejected here (the renderer culls and counts such Gaussians), so a caller that
// needs finite data should check.
//
// Writing produces the standard layout above in binary_little_endian float32, so a
// GaussianScene<float> round-trips bit-exactly; GaussianScene<double> is rounded to
// float. The file is written under a temporary name and renamed.
//
// Errors (orbitforge::Error) name the file, the header line or the vertex index /
// byte offset, and the problem. A vertex count larger than the data could hold is
// rejected before anything is allocated. A count smaller than the data holds (data
// after the last vertex when `vertex` is the last element) reads the declared
// vertices and warns how many bytes were ignored: into the caller's `warnings`
// list when given, else on stderr.
#include <algorithm>
#include <array>
#include <cctype>
#include <charconv>
#include <cstdint>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>
#include <system_error>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/endian.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

enum class PlyFormat { ascii, binary_little_endian, binary_big_endian };
enum class PlyType { int8, uint8, int16, uint16, int32, uint32, float32, float64 };

inline int ply_type_size(PlyType t) {
  switch (t) {
    case PlyType::int8:
    case PlyType::uint8: return 1;
    case PlyType::int16:
    case PlyType::uint16: return 2;
    case PlyType::int32:
    case PlyType::uint32:
    case PlyType::float32: return 4;
    case PlyType::float64: return 8;
  }
  return 0;
}

struct PlyProperty {
  std::string name;
  PlyType type = PlyType::float32;  // value type (the item type for lists)
  bool is_list = false;
  PlyType count_type = PlyType::uint8;  // lists only
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> properties;
  int header_line = 0;  // 1-based line of the `element` line, for messages

  bool fixed_size() const {
    return std::none_of(properties.begin(), properties.end(), [](const PlyProperty& p) { return p.is_list; });
  }
  // Bytes per row in a binary file when fixed_size(); the count bytes of lists otherwise.
  std::uint64_t min_row_bytes() const {
    std::uint64_t n = 0;
    for (const auto& p : properties) n += std::uint64_t(ply_type_size(p.is_list ? p.count_type : p.type));
    return n;
  }
  int find(const std::string& property) const {
    for (std::size_t i = 0; i < properties.size(); ++i)
      if (properties[i].name == property) return int(i);
    return -1;
  }
};

struct PlyHeader {
  PlyFormat format = PlyFormat::binary_little_endian;
  std::vector<PlyElement> elements;
  std::size_t data_offset = 0;  // first byte after the end_header line
};

namespace ply_detail {

inline bool parse_type(const std::string& s, PlyType& t) {
  static const std::pair<const char*, PlyType> table[] = {
      {"char", PlyType::int8},      {"int8", PlyType::int8},       {"uchar", PlyType::uint8},
      {"uint8", PlyType::uint8},    {"short", PlyType::int16},     {"int16", PlyType::int16},
      {"ushort", PlyType::uint16},  {"uint16", PlyType::uint16},   {"int", PlyType::int32},
      {"int32", PlyType::int32},    {"uint", PlyType::uint32},     {"uint32", PlyType::uint32},
      {"float", PlyType::float32},  {"float32", PlyType::float32}, {"double", PlyType::float64},
      {"float64", PlyType::float64}};
  for (const auto& e : table)
    if (s == e.first) {
      t = e.second;
      return true;
    }
  return false;
}

inline std::vector<std::string> split_words(const std::string& line) {
  std::vector<std::string> words;
  std::size_t i = 0;
  while (i < line.size()) {
    while (i < line.size() && (line[i] == ' ' || line[i] == '\t')) ++i;
    std::size_t j = i;
    while (j < line.size() && line[j] != ' ' && line[j] != '\t') ++j;
    if (j > i) words.push_back(line.substr(i, j - i));
    i = j;
  }
  return words;
}

inline bool parse_u64(const std::string& s, std::uint64_t& v) {
  if (s.empty() || s[0] == '-' || s[0] == '+') return false;
  const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
  return r.ec == std::errc() && r.ptr == s.data() + s.size();
}

// Reads one binary value of type t at p (bounds checked by the caller).
inline double load_binary(const unsigned char* p, PlyType t, bool swap) {
  unsigned char b[8];
  const int n = ply_type_size(t);
  if (swap)
    for (int i = 0; i < n; ++i) b[i] = p[n - 1 - i];
  else
    std::memcpy(b, p, std::size_t(n));
  switch (t) {
    case PlyType::int8: { std::int8_t v; std::memcpy(&v, b, 1); return v; }
    case PlyType::uint8: return b[0];
    case PlyType::int16: { std::int16_t v; std::memcpy(&v, b, 2); return v; }
    case PlyType::uint16: { std::uint16_t v; std::memcpy(&v, b, 2); return v; }
    case PlyType::int32: { std::int32_t v; std::memcpy(&v, b, 4); return v; }
    case PlyType::uint32: { std::uint32_t v; std::memcpy(&v, b, 4); return v; }
    case PlyType::float32: { float v; std::memcpy(&v, b, 4); return double(v); }
    case PlyType::float64: { double v; std::memcpy(&v, b, 8); return v; }
  }
  return 0;
}

inline void store_float_le(float v, unsigned char* out, bool swap) {
  std::memcpy(out, &v, 4);
  if (swap) {
    std::swap(out[0], out[3]);
    std::swap(out[1], out[2]);
  }
}

// Where each vertex property goes in the scene: array id and index inside the row.
enum Target : int { skip = 0, mean, rot, scale, opacity, dc, rest };

// Whitespace-separated tokens of an ascii body.
struct AsciiCursor {
  const std::string& bytes;
  std::size_t pos;
  bool next(std::size_t& begin, std::size_t& end) {
    while (pos < bytes.size() && std::isspace(static_cast<unsigned char>(bytes[pos]))) ++pos;
    if (pos >= bytes.size()) return false;
    begin = pos;
    while (pos < bytes.size() && !std::isspace(static_cast<unsigned char>(bytes[pos]))) ++pos;
    end = pos;
    return true;
  }
};

inline bool parse_ascii_number(const std::string& bytes, std::size_t b, std::size_t e, double& v) {
  if (b < e && bytes[b] == '+') ++b;
  const auto r = std::from_chars(bytes.data() + b, bytes.data() + e, v);
  return r.ec == std::errc() && r.ptr == bytes.data() + e;
}

}  // namespace ply_detail

// Parses the header of a PLY held in memory. `name` is used in messages.
inline PlyHeader parse_ply_header(const std::string& bytes, const std::string& name) {
  using namespace ply_detail;
  PlyHeader h;
  std::size_t pos = 0;
  int line_no = 0;
  bool have_format = false;
  auto next_line = [&](std::string& line) {
    if (pos >= bytes.size()) return false;
    std::size_t nl = bytes.find('\n', pos);
    const bool found = nl != std::string::npos;
    if (!found) nl = bytes.size();
    line.assign(bytes, pos, nl - pos);
    if (!line.empty() && line.back() == '\r') line.pop_back();
    pos = found ? nl + 1 : nl;
    ++line_no;
    return true;
  };
  std::string line;
  ensure(next_line(line) && line == "ply", name, ": not a PLY file (first line must be 'ply')");
  for (;;) {
    ensure(next_line(line), name, ": PLY header ends at line ", line_no, " without 'end_header'");
    const auto w = split_words(line);
    if (w.empty()) continue;
    const std::string& key = w[0];
    if (key == "end_header") {
      ensure(w.size() == 1, name, ": PLY header line ", line_no, ": unexpected text after end_header");
      break;
    }
    if (key == "comment" || key == "obj_info") continue;
    if (key == "format") {
      ensure(w.size() == 3, name, ": PLY header line ", line_no, ": expected 'format <type> 1.0'");
      ensure(!have_format, name, ": PLY header line ", line_no, ": second format line");
      if (w[1] == "binary_little_endian") h.format = PlyFormat::binary_little_endian;
      else if (w[1] == "binary_big_endian") h.format = PlyFormat::binary_big_endian;
      else if (w[1] == "ascii") h.format = PlyFormat::ascii;
      else fail(name, ": PLY header line ", line_no, ": unsupported format '", w[1], "'");
      ensure(w[2] == "1.0" || w[2] == "1", name, ": PLY header line ", line_no, ": unsupported version '", w[2],
             "'");
      have_format = true;
      continue;
    }
    if (key == "element") {
      ensure(w.size() == 3, name, ": PLY header line ", line_no, ": expected 'element <name> <count>'");
      PlyElement e;
      e.name = w[1];
      e.header_line = line_no;
      ensure(parse_u64(w[2], e.count), name, ": PLY header line ", line_no, ": bad element count '", w[2], "'");
      for (const auto& other : h.elements)
        ensure(other.name != e.name, name, ": PLY header line ", line_no, ": element '", e.name,
               "' declared twice");
      h.elements.push_back(std::move(e));
      continue;
    }
    if (key == "property") {
      ensure(!h.elements.empty(), name, ": PLY header line ", line_no, ": property before any element");
      PlyProperty p;
      if (w.size() >= 2 && w[1] == "list") {
        ensure(w.size() == 5, name, ": PLY header line ", line_no,
               ": expected 'property list <count type> <item type> <name>'");
        ensure(parse_type(w[2], p.count_type) && parse_type(w[3], p.type), name, ": PLY header line ", line_no,
               ": unknown property type in '", line, "'");
        ensure(p.count_type != PlyType::float32 && p.count_type != PlyType::float64, name, ": PLY header line ",
               line_no, ": list count type must be an integer type");
        p.is_list = true;
        p.name = w[4];
      } else {
        ensure(w.size() == 3, name, ": PLY header line ", line_no, ": expected 'property <type> <name>'");
        ensure(parse_type(w[1], p.type), name, ": PLY header line ", line_no, ": unknown property type '", w[1],
               "'");
        p.name = w[2];
      }
      auto& e = h.elements.back();
      ensure(e.find(p.name) < 0, name, ": PLY header line ", line_no, ": property '", p.name,
             "' declared twice in element '", e.name, "'");
      e.properties.push_back(std::move(p));
      continue;
    }
    fail(name, ": PLY header line ", line_no, ": unknown keyword '", key, "'");
  }
  ensure(have_format, name, ": PLY header has no format line");
  h.data_offset = pos;
  return h;
}

// Reads a Gaussian scene from PLY bytes held in memory; `name` is used in messages.
// Warnings (data ignored) go to `warnings` when given, else to stderr.
template <class Scalar>
GaussianScene<Scalar> read_ply_from_memory(const std::string& bytes, const std::string& name,
                                           std::vector<std::string>* warnings = nullptr) {
  using namespace ply_detail;
  const PlyHeader h = parse_ply_header(bytes, name);

  int vi = -1;
  for (std::size_t i = 0; i < h.elements.size(); ++i)
    if (h.elements[i].name == "vertex") vi = int(i);
  ensure(vi >= 0, name, ": PLY has no 'vertex' element");
  const PlyElement& ve = h.elements[std::size_t(vi)];

  // Map vertex properties onto scene arrays.
  std::vector<std::pair<Target, int>> map(ve.properties.size(), {skip, 0});
  auto require = [&](const std::string& prop, Target t, int index) {
    const int p = ve.find(prop);
    ensure(p >= 0, name, ": PLY vertex element (header line ", ve.header_line, ") has no property '", prop, "'");
    ensure(!ve.properties[std::size_t(p)].is_list, name, ": PLY vertex property '", prop, "' is a list");
    map[std::size_t(p)] = {t, index};
  };
  const char* xyz[3] = {"x", "y", "z"};
  for (int i = 0; i < 3; ++i) require(xyz[i], mean, i);
  for (int i = 0; i < 3; ++i) require("f_dc_" + std::to_string(i), dc, i);
  require("opacity", opacity, 0);
  for (int i = 0; i < 3; ++i) require("scale_" + std::to_string(i), scale, i);
  for (int i = 0; i < 4; ++i) require("rot_" + std::to_string(i), rot, i);
  int rest_count = 0;
  for (const auto& p : ve.properties)
    if (p.name.compare(0, 7, "f_rest_") == 0) ++rest_count;
  int degree = -1;
  for (int d = 0; d <= 3; ++d)
    if (rest_count == 3 * (sh_coefficient_count(d) - 1)) degree = d;
  ensure(degree >= 0, name, ": PLY vertex element has ", rest_count,
         " f_rest_* properties; expected 0, 9, 24 or 45 (SH degree 0..3)");
  for (int i = 0; i < rest_count; ++i) require("f_rest_" + std::to_string(i), rest, i);

  const bool binary = h.format != PlyFormat::ascii;
  const bool swap = binary && ((h.format == PlyFormat::binary_little_endian) != host_is_little_endian());
  const std::size_t size = bytes.size();
  std::size_t pos = h.data_offset;
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());

  // Skip the elements before `vertex`.
  AsciiCursor cursor{bytes, pos};
  for (int ei = 0; ei < vi; ++ei) {
    const PlyElement& e = h.elements[std::size_t(ei)];
    if (binary && e.fixed_size()) {
      const std::uint64_t row = e.min_row_bytes();
      ensure(row == 0 || e.count <= (size - pos) / row, name, ": PLY element '", e.name, "' (header line ",
             e.header_line, ") declares ", e.count, " rows of ", row, " bytes but only ", size - pos,
             " bytes remain at byte offset ", pos);
      pos += std::size_t(e.count * row);
      continue;
    }
    if (e.properties.empty()) continue;  // rows of nothing, in any format
    // Rows of variable size: walk them. Each row consumes at least one byte or token,
    // so this loop is bounded by the file size.
    for (std::uint64_t r = 0; r < e.count; ++r) {
      for (const auto& p : e.properties) {
        std::uint64_t items = 1;
        if (binary) {
          if (p.is_list) {
            const int cs = ply_type_size(p.count_type);
            ensure(std::size_t(cs) <= size - pos, name, ": PLY truncated in element '", e.name, "' row ", r,
                   " at byte offset ", pos);
            const double c = load_binary(data + pos, p.count_type, swap);
            ensure(c >= 0, name, ": PLY negative list length in element '", e.name, "' row ", r,
                   " at byte offset ", pos);
            pos += std::size_t(cs);
            items = std::uint64_t(c);
          }
          const std::uint64_t isz = std::uint64_t(ply_type_size(p.type));
          ensure(items <= (size - pos) / isz, name, ": PLY truncated in element '", e.name, "' row ", r,
                 " at byte offset ", pos);
          pos += std::size_t(items * isz);
        } else {
          std::size_t b, en;
          if (p.is_list) {
            ensure(cursor.next(b, en) && parse_u64(bytes.substr(b, en - b), items), name,
                   ": PLY ascii data: bad or missing list length in element '", e.name, "' row ", r);
          }
          for (std::uint64_t k = 0; k < items; ++k)
            ensure(cursor.next(b, en), name, ": PLY ascii data ends inside element '", e.name, "' row ", r);
        }
      }
    }
  }

  // Bound the vertex count by what the remaining data could hold before allocating.
  const std::size_t remaining = binary ? size - pos : size - std::min(size, cursor.pos);
  if (binary) {
    const std::uint64_t row = ve.min_row_bytes();  // > 0: x/y/z are required
    ensure(ve.count <= remaining / row, name, ": PLY vertex count ", ve.count, " (header line ", ve.header_line,
           ") needs at least ", row, " bytes per vertex but only ", remaining, " bytes remain at byte offset ",
           pos, " (truncated file or bad count)");
  } else {
    // Every value takes at least one character and one separator (the last excepted).
    const std::uint64_t tokens = ve.properties.size();
    ensure(ve.count <= (std::uint64_t(remaining) + 1) / (2 * tokens), name, ": PLY vertex count ", ve.count,
           " (header line ", ve.header_line, ") is larger than the ", remaining,
           " bytes of ascii data could hold (truncated file or bad count)");
  }

  GaussianScene<Scalar> scene;
  const std::size_t n = std::size_t(ve.count);
  scene.resize(n, degree);
  const int K = sh_coefficient_count(degree);
  Scalar* arrays[7] = {nullptr, scene.means.data(), scene.rotations.data(), scene.log_scales.data(),
                       scene.opacity_logits.data(), scene.sh.data(), scene.sh.data()};
  const int stride[7] = {0, 3, 4, 3, 1, 3 * K, 3 * K};
  // Offset of each target inside a Gaussian's block of its array.
  std::vector<int> offset(ve.properties.size(), 0);
  for (std::size_t p = 0; p < map.size(); ++p) {
    const auto [t, i] = map[p];
    if (t == rest) offset[p] = 3 * (1 + i % (K - 1)) + i / (K - 1);  // f_rest is channel-major
    else offset[p] = i;
  }
  auto put = [&](std::size_t p, std::size_t g, double v) {
    const Target t = map[p].first;
    if (t != skip) arrays[t][g * std::size_t(stride[t]) + std::size_t(offset[p])] = Scalar(v);
  };

  if (binary && ve.fixed_size()) {
    std::vector<int> at(ve.properties.size(), 0);
    int row = 0;
    for (std::size_t p = 0; p < ve.properties.size(); ++p) {
      at[p] = row;
      row += ply_type_size(ve.properties[p].type);
    }
    for (std::size_t g = 0; g < n; ++g, pos += std::size_t(row))
      for (std::size_t p = 0; p < ve.properties.size(); ++p)
        put(p, g, load_binary(data + pos + std::size_t(at[p]), ve.properties[p].type, swap));
  } else {
    for (std::size_t g = 0; g < n; ++g) {
      for (std::size_t p = 0; p < ve.properties.size(); ++p) {
        const PlyProperty& pr = ve.properties[p];
        if (binary) {
          std::uint64_t items = 1;
          if (pr.is_list) {
            const int cs = ply_type_size(pr.count_type);
            ensure(std::size_t(cs) <= size - pos, name, ": PLY truncated at vertex ", g, " (byte offset ", pos, ")");
            const double c = load_binary(data + pos, pr.count_type, swap);
            ensure(c >= 0, name, ": PLY negative list length at vertex ", g, " (byte offset ", pos, ")");
            pos += std::size_t(cs);
            items = std::uint64_t(c);
          }
          const std::uint64_t isz = std::uint64_t(ply_type_size(pr.type));
          ensure(items <= (size - pos) / isz, name, ": PLY truncated at vertex ", g, " property '", pr.name,
                 "' (byte offset ", pos, ")");
          if (!pr.is_list) put(p, g, load_binary(data + pos, pr.type, swap));
          pos += std::size_t(items * isz);
        } else {
          std::size_t b, e;
          std::uint64_t items = 1;
          if (pr.is_list)
            ensure(cursor.next(b, e) && parse_u64(bytes.substr(b, e - b), items), name,
                   ": PLY ascii data: bad or missing list length at vertex ", g, " property '", pr.name, "'");
          for (std::uint64_t k = 0; k < items; ++k) {
            ensure(cursor.next(b, e), name, ": PLY ascii data ends at vertex ", g, " property '", pr.name,
                   "' (truncated)");
            if (pr.is_list) continue;
            double v = 0;
            ensure(parse_ascii_number(bytes, b, e, v), name, ": PLY ascii data: bad number '",
                   bytes.substr(b, std::min<std::size_t>(e - b, 32)), "' at vertex ", g, " property '", pr.name,
                   "'");
            put(p, g, v);
          }
        }
      }
    }
  }

  // Data after the declared vertices, when nothing else was declared after them:
  // most likely a header whose vertex count is too small, so say what was dropped.
  if (std::size_t(vi) + 1 == h.elements.size()) {
    std::size_t extra = 0;
    if (binary) {
      extra = size - pos;
    } else {
      std::size_t begin = cursor.pos, end = size;
      while (begin < end && std::isspace(static_cast<unsigned char>(bytes[begin]))) ++begin;
      while (end > begin && std::isspace(static_cast<unsigned char>(bytes[end - 1]))) --end;
      extra = end - begin;
    }
    if (extra > 0) {
      std::ostringstream w;
      w << name << ": " << extra << (binary ? " bytes" : " bytes of ascii data") << " beyond the " << n
        << " vertices the header declares (line " << ve.header_line << ") were ignored";
      const std::uint64_t row = ve.min_row_bytes();
      if (binary && ve.fixed_size())
        w << " (" << extra / row << " more vertices of " << row << " bytes"
          << (extra % row ? " and " + std::to_string(extra % row) + " bytes" : std::string()) << ")";
      w << "; is the header's vertex count too small?";
      if (warnings) warnings->push_back(w.str());
      else std::cerr << "orbitforge: warning: " << w.str() << "\n";
    }
  }
  return scene;
}

template <class Scalar>
GaussianScene<Scalar> read_ply(const std::string& path, std::vector<std::string>* warnings = nullptr) {
  return read_ply_from_memory<Scalar>(read_file_bytes(path), path, warnings);
}

// How a scene is written. Positions in float64 are for a scene far from its
// model's origin, where float32 cannot hold its detail (1e5 units out, float32
// steps by 0.008); readers that take only float32 positions will refuse them.
struct PlyWriteOptions {
  bool double_positions = false;
};

// The bytes of the standard INRIA layout (binary little endian float32; x, y, z
// float64 with options.double_positions).
template <class Scalar>
std::string ply_bytes(const GaussianScene<Scalar>& scene, const PlyWriteOptions& options = {}) {
  scene.check_consistent();
  const int degree = scene.sh_degree;
  const int K = sh_coefficient_count(degree);
  const int rest = 3 * (K - 1);
  std::string header = "ply\nformat binary_little_endian 1.0\ncomment written by orbitforge\nelement vertex " +
                       std::to_string(scene.size()) + "\n";
  const char* fixed_names[] = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  for (int i = 0; i < 9; ++i)
    header += std::string(i < 3 && options.double_positions ? "property double " : "property float ") +
              fixed_names[i] + "\n";
  for (int i = 0; i < rest; ++i) header += "property float f_rest_" + std::to_string(i) + "\n";
  header += "property float opacity\n";
  for (int i = 0; i < 3; ++i) header += "property float scale_" + std::to_string(i) + "\n";
  for (int i = 0; i < 4; ++i) header += "property float rot_" + std::to_string(i) + "\n";
  header += "end_header\n";

  const std::size_t floats = std::size_t(9 + rest + 1 + 3 + 4);
  const std::size_t n = scene.size();
  const std::size_t row = floats * 4 + (options.double_positions ? 12 : 0);
  std::string out = header;
  out.resize(header.size() + n * row);
  auto* w = reinterpret_cast<unsigned char*>(&out[header.size()]);
  const bool swap = !host_is_little_endian();
  auto emit = [&](Scalar v) {
    ply_detail::store_float_le(float(v), w, swap);
    w += 4;
  };
  auto emit_double = [&](double v) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, 8);
    for (int b = 0; b < 8; ++b) *w++ = static_cast<unsigned char>(bits >> (8 * b));
  };
  for (std::size_t g = 0; g < n; ++g) {
    for (int i = 0; i < 3; ++i) {
      if (options.double_positions)
        emit_double(double(scene.means[3 * g + std::size_t(i)]));
      else
        emit(scene.means[3 * g + std::size_t(i)]);
    }
    for (int i = 0; i < 3; ++i) emit(Scalar(0));
    const Scalar* sh = scene.sh.data() + g * std::size_t(3 * K);
    for (int c = 0; c < 3; ++c) emit(sh[c]);
    for (int c = 0; c < 3; ++c)
      for (int k = 1; k < K; ++k) emit(sh[3 * k + c]);
    emit(scene.opacity_logits[g]);
    for (int i = 0; i < 3; ++i) emit(scene.log_scales[3 * g + std::size_t(i)]);
    for (int i = 0; i < 4; ++i) emit(scene.rotations[4 * g + std::size_t(i)]);
  }
  return out;
}

template <class Scalar>
void write_ply(const std::string& path, const GaussianScene<Scalar>& scene, const PlyWriteOptions& options = {}) {
  write_file_atomic(path, ply_bytes(scene, options));
}

}  // namespace orbitforge

#pragma once
// NumPy .npy arrays (format versions 1, 2 and 3; little-endian float32 '<f4'
// or float64 '<f8'; C order), and camera-estimator outputs stored as .npy the
// way VGGT's are saved: extrinsics N x 3 x 4 camera-from-world [R | t] with
// OpenCV axes (N x 4 x 4 accepted, top 3 rows used) and intrinsics N x 3 x 3 K;
// a leading batch axis of size 1 (1 x N x ...) is accepted on both.
//
// Frames whose extrinsics or intrinsics contain non-finite values are kept
// with valid = false (identity pose), so frame numbering is preserved. Finite
// rows must be well-formed: a rotation (orthonormal to 1e-3, det > 0), K with
// positive focal lengths and last row 0 0 1; anything else is an error naming
// the file and the frame index.
//
// parse_npy reads from memory (for fuzzing); `file_name` is only used in messages.
#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <iomanip>
#include <limits>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/byte_reader.hpp"

namespace orbitforge {

struct NpyArray {
  std::vector<std::size_t> shape;
  std::vector<double> data;  // C order, converted to double
};

inline std::string npy_shape_string(const std::vector<std::size_t>& shape) {
  std::ostringstream os;
  if (shape.empty()) return "() (a scalar)";
  for (std::size_t i = 0; i < shape.size(); ++i) os << (i ? " x " : "") << shape[i];
  return os.str();
}

namespace detail {

// The header is a Python dict literal, e.g.
//   {'descr': '<f8', 'fortran_order': False, 'shape': (3, 4), }
// This parses exactly that subset: string keys; string, True/False and
// integer-tuple values.
class NpyHeaderParser {
 public:
  NpyHeaderParser(std::string_view text, const std::string& file) : s_(text), file_(file) {}

  void parse(std::string& descr, bool& fortran_order, std::vector<std::size_t>& shape) {
    bool have_descr = false, have_order = false, have_shape = false;
    skip_ws();
    expect('{');
    for (;;) {
      skip_ws();
      if (peek() == '}') {
        ++i_;
        break;
      }
      const std::string key = string_literal();
      skip_ws();
      expect(':');
      skip_ws();
      if (key == "descr") {
        descr = string_literal();
        have_descr = true;
      } else if (key == "fortran_order") {
        fortran_order = boolean();
        have_order = true;
      } else if (key == "shape") {
        shape = tuple();
        have_shape = true;
      } else {
        error("unexpected key '" + key + "'");
      }
      skip_ws();
      if (peek() == ',') {
        ++i_;
        continue;
      }
      expect('}');
      break;
    }
    skip_ws();
    if (i_ != s_.size()) error("unexpected text after the closing '}'");
    if (!have_descr || !have_order || !have_shape) error("needs the keys 'descr', 'fortran_order' and 'shape'");
  }

 private:
  [[noreturn]] void error(const std::string& what) const {
    fail(file_, ": bad .npy header at header character ", i_, ": ", what);
  }
  char peek() const { return i_ < s_.size() ? s_[i_] : '\0'; }
  void skip_ws() {
    while (i_ < s_.size() && (s_[i_] == ' ' || s_[i_] == '\t' || s_[i_] == '\n' || s_[i_] == '\r')) ++i_;
  }
  void expect(char c) {
    if (peek() != c || i_ >= s_.size()) error(std::string("expected '") + c + "'");
    ++i_;
  }
  std::string string_literal() {
    const char q = peek();
    if (q != '\'' && q != '"' ) error("expected a quoted string");
    ++i_;
    const std::size_t end = s_.find(q, i_);
    if (end == std::string_view::npos) error("unterminated string");
    std::string out(s_.substr(i_, end - i_));
    i_ = end + 1;
    return out;
  }
  bool boolean() {
    if (s_.substr(i_, 4) == "True") {
      i_ += 4;
      return true;
    }
    if (s_.substr(i_, 5) == "False") {
      i_ += 5;
      return false;
    }
    error("expected True or False");
  }
  std::vector<std::size_t> tuple() {
    std::vector<std::size_t> dims;
    expect('(');
    for (;;) {
      skip_ws();
      if (peek() == ')') {
        ++i_;
        break;
      }
      if (peek() < '0' || peek() > '9') error("expected a non-negative integer in the shape");
      std::size_t v = 0;
      while (peek() >= '0' && peek() <= '9') {
        const std::size_t d = static_cast<std::size_t>(peek() - '0');
        if (v > (std::numeric_limits<std::size_t>::max() - d) / 10) error("shape dimension too large");
        v = v * 10 + d;
        ++i_;
      }
      if (peek() == 'L') ++i_;  // Python 2 long suffix, as old numpy wrote it
      dims.push_back(v);
      if (dims.size() > 32) error("more than 32 dimensions");
      skip_ws();
      if (peek() == ',') {
        ++i_;
        continue;
      }
      expect(')');
      break;
    }
    return dims;
  }

  std::string_view s_;
  const std::string& file_;
  std::size_t i_ = 0;
};

}  // namespace detail

inline NpyArray parse_npy(std::string_view bytes, const std::string& file_name) {
  ByteReader in(bytes, file_name);
  const std::string_view magic = in.take(6, ".npy magic");
  ensure(magic == std::string_view("\x93NUMPY", 6), file_name, ": not a .npy file (bad magic bytes)");
  const auto major = in.read<std::uint8_t>(".npy version");
  in.read<std::uint8_t>(".npy minor version");
  ensure(major >= 1 && major <= 3, file_name, ": unsupported .npy format version ", int(major));
  const std::size_t header_len =
      major == 1 ? std::size_t(in.read<std::uint16_t>("header length")) : std::size_t(in.read<std::uint32_t>("header length"));
  const std::string_view header = in.take(header_len, ".npy header");

  std::string descr;
  bool fortran_order = false;
  NpyArray a;
  detail::NpyHeaderParser(header, file_name).parse(descr, fortran_order, a.shape);
  ensure(!fortran_order, file_name, ": Fortran-order arrays are not supported (save with C order)");
  std::size_t item = 0;
  if (descr == "<f8") {
    item = 8;
  } else if (descr == "<f4") {
    item = 4;
  } else if (descr == ">f8" || descr == ">f4") {
    fail(file_name, ": big-endian dtype '", descr, "' is not supported (expected <f4 or <f8)");
  } else {
    fail(file_name, ": unsupported dtype '", descr, "' (expected <f4 or <f8)");
  }
  std::size_t count = 1;
  for (const std::size_t d : a.shape) {
    ensure(d == 0 || count <= std::numeric_limits<std::size_t>::max() / d, file_name, ": shape ",
           npy_shape_string(a.shape), " has too many elements");
    count *= d;
  }
  ensure(count <= in.remaining() / item && count * item == in.remaining(), file_name, ": data size mismatch: shape ",
         npy_shape_string(a.shape), " of '", descr, "' needs ",
         count <= std::numeric_limits<std::size_t>::max() / item ? std::to_string(count * item) : std::string("too many"),
         " bytes, the file has ", in.remaining(), " bytes after the header (byte offset ", in.offset(), ")");
  a.data.resize(count);
  if (item == 8) {
    for (auto& v : a.data) v = in.read<double>("array data");
  } else {
    for (auto& v : a.data) v = double(in.read<float>("array data"));
  }
  return a;
}

inline NpyArray read_npy(const std::string& path) { return parse_npy(read_file_bytes(path), path); }

// The bytes of a version-1 .npy file of '<f8' values (version 2 when the
// header needs more than 65535 bytes).
inline std::string npy_bytes(const std::vector<std::size_t>& shape, const std::vector<double>& data,
                             const std::string& file_name) {
  std::size_t count = 1;
  for (const std::size_t d : shape) count *= d;
  ensure(count == data.size(), file_name, ": cannot write .npy: shape ", npy_shape_string(shape), " holds ", count,
         " values, got ", data.size());
  std::string dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (";
  for (std::size_t i = 0; i < shape.size(); ++i) dict += (i ? ", " : "") + std::to_string(shape[i]);
  dict += shape.size() == 1 ? ",), }" : "), }";
  // Pad with spaces and a final newline so that the data starts on a 64-byte boundary.
  const std::size_t prefix_v1 = 10, prefix_v2 = 12;
  const bool v2 = dict.size() + 1 + 64 > 65535;
  const std::size_t prefix = v2 ? prefix_v2 : prefix_v1;
  const std::size_t total = ((prefix + dict.size() + 1 + 63) / 64) * 64;
  dict.append(total - prefix - dict.size() - 1, ' ');
  dict += '\n';
  std::string out("\x93NUMPY", 6);
  out += char(v2 ? 2 : 1);
  out += char(0);
  const std::size_t hl = dict.size();
  const int len_bytes = v2 ? 4 : 2;
  for (int i = 0; i < len_bytes; ++i) out += char((hl >> (8 * i)) & 0xff);
  out += dict;
  out.reserve(out.size() + 8 * data.size());
  for (const double v : data) {
    std::uint64_t bits;
    std::memcpy(&bits, &v, 8);
    for (int i = 0; i < 8; ++i) out += char((bits >> (8 * i)) & 0xff);
  }
  return out;
}

inline void write_npy(const std::string& path, const std::vector<std::size_t>& shape, const std::vector<double>& data) {
  write_file_atomic(path, npy_bytes(shape, data, path));
}

namespace detail {
// Number of frames N for an array of per-frame rows x cols matrices, accepting
// N x rows x cols and 1 x N x rows x cols; 0 when the shape does not fit.
inline bool npy_frames_of(const std::vector<std::size_t>& s, std::size_t rows, std::size_t cols, std::size_t& n) {
  if (s.size() == 3 && s[1] == rows && s[2] == cols) {
    n = s[0];
    return true;
  }
  if (s.size() == 4 && s[0] == 1 && s[2] == rows && s[3] == cols) {
    n = s[1];
    return true;
  }
  return false;
}
}  // namespace detail

// Builds cameras from two arrays already in memory; the paths are only used in messages.
template <class S>
std::vector<FrameCamera<S>> npy_cameras(const NpyArray& extrinsics, const std::string& extrinsics_path,
                                        const NpyArray& intrinsics, const std::string& intrinsics_path, int width,
                                        int height) {
  ensure(width > 0 && height > 0, extrinsics_path, ": image size ", width, "x", height, " must be positive");
  std::size_t n_ext = 0, n_int = 0, ext_rows = 3;
  if (!detail::npy_frames_of(extrinsics.shape, 3, 4, n_ext)) {
    ensure(detail::npy_frames_of(extrinsics.shape, 4, 4, n_ext), extrinsics_path, ": extrinsics have shape ",
           npy_shape_string(extrinsics.shape), ", expected N x 3 x 4 or N x 4 x 4 (camera-from-world [R | t])");
    ext_rows = 4;
  }
  ensure(detail::npy_frames_of(intrinsics.shape, 3, 3, n_int), intrinsics_path, ": intrinsics have shape ",
         npy_shape_string(intrinsics.shape), ", expected N x 3 x 3");
  ensure(n_ext == n_int, extrinsics_path, " has ", n_ext, " frames but ", intrinsics_path, " has ", n_int);
  ensure(n_ext > 0, extrinsics_path, ": contains no frames");

  std::vector<FrameCamera<S>> out(n_ext);
  for (std::size_t i = 0; i < n_ext; ++i) {
    const double* e = extrinsics.data.data() + i * ext_rows * 4;
    const double* k = intrinsics.data.data() + i * 9;
    FrameCamera<S>& f = out[i];
    std::ostringstream name;
    name << "frame_" << std::setw(5) << std::setfill('0') << (i + 1);
    f.name = name.str();
    f.camera.intrinsics.width = width;
    f.camera.intrinsics.height = height;
    Eigen::Matrix<double, 3, 4> E;
    Eigen::Matrix3d K;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 4; ++c) E(r, c) = e[r * 4 + c];
      for (int c = 0; c < 3; ++c) K(r, c) = k[r * 3 + c];
    }
    if (!E.allFinite() || !K.allFinite()) {
      f.valid = false;
      continue;
    }
    const Eigen::Matrix3d R = E.leftCols<3>();
    const double orth_err = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
    ensure(orth_err < 1e-3 && R.determinant() > 0, extrinsics_path, ": frame ", i,
           ": rotation part is not a rotation (|R^T R - I| = ", orth_err, ", det = ", R.determinant(), ")");
    const double bottom_err = (K.row(2) - Eigen::RowVector3d(0, 0, 1)).cwiseAbs().maxCoeff();
    ensure(bottom_err < 1e-6, intrinsics_path, ": frame ", i, ": last row of K must be 0 0 1");
    ensure(K(0, 0) > 0 && K(1, 1) > 0, intrinsics_path, ": frame ", i, ": focal lengths must be positive (fx ",
           K(0, 0), ", fy ", K(1, 1), ")");
    f.camera.R = R.cast<S>();
    f.camera.t = E.col(3).cast<S>();
    f.camera.intrinsics.fx = S(K(0, 0));
    f.camera.intrinsics.fy = S(K(1, 1));
    f.camera.intrinsics.cx = S(K(0, 2));
    f.camera.intrinsics.cy = S(K(1, 2));
    ensure(f.camera.is_finite(), extrinsics_path, ": frame ", i, ": values do not fit the precision");
  }
  return out;
}

template <class S>
std::vector<FrameCamera<S>> read_npy_cameras(const std::string& extrinsics_path, const std::string& intrinsics_path,
                                             int width, int height) {
  return npy_cameras<S>(read_npy(extrinsics_path), extrinsics_path, read_npy(intrinsics_path), intrinsics_path, width,
                        height);
}

}  // namespace orbitforge

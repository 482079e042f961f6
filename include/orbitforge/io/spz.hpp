#pragma once
// Niantic's SPZ format (".spz"): a quantised Gaussian scene, about a tenth of the
// PLY's size. The only orbitforge header that needs zlib (link ZLIB::ZLIB, which
// orbitforge::io does).
//
// The file is one gzip stream holding a 16-byte little-endian header
//   uint32 magic 0x5053474e ("NGSP")   uint32 version   uint32 numPoints
//   uint8 shDegree   uint8 fractionalBits   uint8 flags (0x1 antialiased, 0x2 extensions)   uint8 0
// then each attribute for every Gaussian in turn:
//   positions  3 x int24 fixed point, value = int / 2^fractionalBits
//   alphas     1 byte,  round(sigmoid(logit) * 255)
//   colours    3 bytes, round(f_dc * 0.15 * 255 + 127.5) (0.15, not C0: leaves room for
//              DC colours outside [0, 1] that higher bands bring back)
//   scales     3 bytes, round((log_scale + 10) * 16): log scales -10 .. 5.94 in 1/16 steps
//   rotations  v2: 3 bytes x y z of the unit quaternion with w >= 0, round(q * 127.5 + 127.5),
//              w rebuilt as sqrt(1 - |xyz|^2);
//              v3: 32 bits "smallest three": bits 30-31 the index (x y z w = 0..3) of the
//              largest component, made positive; the other three in index order, first in
//              the highest bits, each as a sign bit over 9 bits of |q| / sqrt(1/2) * 511
//   sh         (degree+1)^2 - 1 coefficients, each R G B, byte = 128 + 128 x, decoded
//              (byte - 128) / 128; the writer rounds bytes to multiples of a power of two
//              (SpzOptions), which only makes the stream compress better
// Positions, rotations and SH are stored in the format's own axes, RUB (x right, y up, z
// back); orbitforge's scenes (and PLY) use x right, y down, z forward, so y and z flip on
// both ways: means (x, -y, -z), quaternions (w, x, -y, -z), and each SH coefficient times
// its basis function's parity under (y, z) -> (-y, -z).
//
// Writing: version 3, SH as the scene has it, fractionalBits 12 (1/4096 steps, +-2048)
// unless the scene's extent needs fewer. Non-finite means are refused; other values are
// clamped into the bytes (NaN -> 0); a zero quaternion is written as the identity.
// Reading: versions 2 and 3 (gzip); version 4 (zstd) and anything else are refused with
// an Error naming the file and the problem. Degree-4 SH (newer writers) is read to
// degree 3; the antialiased flag is ignored; files with extensions (flag 0x2) are refused
// (an extension may change how SH decodes). Alpha bytes 0 and 255 read as finite logits
// (a / 255 kept inside [0.25/255, 1 - 0.25/255], as for .splat) that write back the same.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <string>

#include <zlib.h>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

inline constexpr std::uint32_t spz_magic = 0x5053474e;
inline constexpr std::uint32_t spz_write_version = 3;
inline constexpr std::size_t spz_header_bytes = 16;
inline constexpr double spz_color_scale = 0.15;
inline constexpr int spz_default_fractional_bits = 12;

// How many of each SH byte's 8 bits the writer keeps (1..8; readers need not know):
// fewer bits compress better. The reference writer keeps 5 and 4; one more each
// (steps of 4/128 and 8/128) cut the PSNR cost on two of our scenes from ~0.4 dB to
// ~0.07 dB for a file still under 1/8 of the PLY (docs/formats.md).
struct SpzOptions {
  int sh1_bits = 6;      // degree 1
  int sh_rest_bits = 5;  // degrees 2 and 3
};

namespace spz_detail {

// Sign of SH coefficient k (1..15, 3DGS order) when y and z flip: the parity of its
// basis polynomial in (y, z). Degree 1: y z x; degree 2: xy yz (3z^2-1) xz (x^2-y^2);
// degree 3: y(3x^2-y^2) xyz y(5z^2-1) z(5z^2-3) x(5z^2-1) z(x^2-y^2) x(x^2-3y^2).
inline constexpr std::array<int, 16> sh_flip = {1, -1, -1, 1, -1, 1, 1, -1, 1, -1, 1, -1, -1, 1, -1, 1};
inline constexpr std::array<int, 3> axis_flip = {1, -1, -1};

inline int sh_coefficients_for_degree(int degree) { return (degree + 1) * (degree + 1); }

inline void put_u32(std::string& out, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) out.push_back(char((v >> (8 * i)) & 0xff));
}
inline std::uint32_t get_u32(const unsigned char* p) {
  return std::uint32_t(p[0]) | std::uint32_t(p[1]) << 8 | std::uint32_t(p[2]) << 16 | std::uint32_t(p[3]) << 24;
}

// Nearest byte of v in [0, 255] (NaN -> 0).
inline unsigned char to_byte(double v) {
  if (!(v > 0)) return 0;
  if (v >= 255) return 255;
  return static_cast<unsigned char>(std::lround(v));
}

// SH value x to a byte on multiples of `bucket` around 128, clamped (NaN -> 128).
inline unsigned char sh_byte(double x, int bucket) {
  if (std::isnan(x)) return 128;
  const double steps = std::round(std::clamp(x * 128.0, -256.0, 256.0) / bucket);
  return static_cast<unsigned char>(std::clamp(128.0 + steps * bucket, 0.0, 255.0));
}

// Smallest-three packing of a unit quaternion given as x y z w.
inline std::uint32_t pack_quaternion_v3(const double q[4]) {
  int largest = 0;
  for (int i = 1; i < 4; ++i)
    if (std::abs(q[i]) > std::abs(q[largest])) largest = i;
  const bool negate = q[largest] < 0;
  std::uint32_t bits = std::uint32_t(largest);
  for (int i = 0; i < 4; ++i) {
    if (i == largest) continue;
    const std::uint32_t sign = (q[i] < 0) != negate ? 1u : 0u;
    const long mag = std::min(511L, std::lround(std::abs(q[i]) / std::sqrt(0.5) * 511.0));
    bits = (bits << 10) | (sign << 9) | std::uint32_t(mag);
  }
  return bits;
}

// Inverse of pack_quaternion_v3, to x y z w.
inline void unpack_quaternion_v3(std::uint32_t bits, double q[4]) {
  const int largest = int(bits >> 30);
  double sum = 0;
  for (int i = 3; i >= 0; --i) {
    if (i == largest) continue;
    const double mag = double(bits & 511u) / 511.0 * std::sqrt(0.5);
    q[i] = (bits >> 9) & 1u ? -mag : mag;
    bits >>= 10;
    sum += q[i] * q[i];
  }
  q[largest] = std::sqrt(std::max(0.0, 1.0 - sum));
}

// Gzip (not zlib or raw deflate) in one stream: what SPZ readers inflate.
inline std::string gzip_compress(const std::string& data, int level = Z_DEFAULT_COMPRESSION) {
  z_stream z{};
  ensure(deflateInit2(&z, level, Z_DEFLATED, 16 + MAX_WBITS, 8, Z_DEFAULT_STRATEGY) == Z_OK,
         "gzip: deflateInit2 failed");
  std::string out(deflateBound(&z, uLong(data.size())) + 64, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
  z.avail_in = uInt(data.size());
  ensure(data.size() == z.avail_in, "gzip: ", data.size(), " bytes is more than one zlib call takes");
  z.next_out = reinterpret_cast<Bytef*>(&out[0]);
  z.avail_out = uInt(out.size());
  const int rc = deflate(&z, Z_FINISH);
  const std::size_t produced = out.size() - z.avail_out;
  deflateEnd(&z);
  ensure(rc == Z_STREAM_END, "gzip: deflate failed (zlib code ", rc, ")");
  out.resize(produced);
  return out;
}

// Inflates a gzip stream on demand, so that a header can be read before the size of
// the rest is trusted (a tiny file cannot make the reader allocate gigabytes).
class GunzipStream {
 public:
  GunzipStream(const std::string& in, const std::string& name) : in_(in), name_(name) {
    ensure(inflateInit2(&z_, 16 + MAX_WBITS) == Z_OK, name, ": zlib inflateInit2 failed");
    z_.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
    z_.avail_in = uInt(std::min<std::size_t>(in.size(), chunk));
    fed_ = z_.avail_in;
  }
  ~GunzipStream() { inflateEnd(&z_); }
  GunzipStream(const GunzipStream&) = delete;
  GunzipStream& operator=(const GunzipStream&) = delete;

  // Appends up to n more decompressed bytes to out; fewer only at the stream's end
  // (ended()) or where the compressed data runs out (truncated()).
  void read(std::size_t n, std::string& out) {
    const std::size_t start = out.size();
    out.resize(start + n);
    std::size_t got = 0;
    while (got < n && !ended_ && !truncated_) {
      if (z_.avail_in == 0 && fed_ < in_.size()) {
        z_.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in_.data() + fed_));
        z_.avail_in = uInt(std::min<std::size_t>(in_.size() - fed_, chunk));
        fed_ += z_.avail_in;
      }
      const std::size_t want = std::min<std::size_t>(n - got, chunk);
      z_.next_out = reinterpret_cast<Bytef*>(&out[start + got]);
      z_.avail_out = uInt(want);
      const uInt in_before = z_.avail_in;
      const int rc = inflate(&z_, Z_NO_FLUSH);
      got += want - z_.avail_out;
      const bool progress = z_.avail_out != want || z_.avail_in != in_before;
      if (rc == Z_STREAM_END) {
        ended_ = true;
      } else if (rc == Z_OK || rc == Z_BUF_ERROR) {
        // No progress with every input byte consumed: the stream was cut short.
        if (!progress && z_.avail_in == 0 && fed_ == in_.size()) truncated_ = true;
      } else {
        fail(name_, ": not a valid gzip stream (zlib: ", z_.msg ? z_.msg : "error " + std::to_string(rc),
             " after ", z_.total_in, " compressed bytes)");
      }
    }
    out.resize(start + got);
  }
  // Inflates what is left, discarding it, so that the stream's checksum is verified.
  void finish() {
    std::string rest;
    while (!ended_ && !truncated_) {
      rest.clear();
      read(std::size_t(1) << 20, rest);
    }
    ensure(ended_, name_, ": SPZ data truncated: the gzip stream is cut short before its end (",
           in_.size(), " compressed bytes)");
  }
  bool ended() const { return ended_; }
  bool truncated() const { return truncated_; }
  std::size_t compressed_bytes_read() const { return std::size_t(z_.total_in); }

 private:
  static constexpr std::size_t chunk = std::size_t(1) << 30;
  const std::string& in_;
  std::string name_;
  z_stream z_{};
  std::size_t fed_ = 0;
  bool ended_ = false;
  bool truncated_ = false;
};

inline bool starts_with_gzip(const std::string& b) {
  return b.size() >= 2 && static_cast<unsigned char>(b[0]) == 0x1f && static_cast<unsigned char>(b[1]) == 0x8b;
}

// The most fractional bits (at most 12) whose 24-bit range holds every coordinate.
template <class Scalar>
int fractional_bits_for(const GaussianScene<Scalar>& scene) {
  double extent = 0;
  for (std::size_t i = 0; i < scene.means.size(); ++i) {
    const double v = double(scene.means[i]);
    ensure(std::isfinite(v), "SPZ: Gaussian ", i / 3, " has a non-finite mean (", v, "); SPZ cannot store it");
    extent = std::max(extent, std::abs(v));
  }
  const double limit = double((1 << 23) - 1);
  for (int bits = spz_default_fractional_bits; bits >= 0; --bits)
    if (std::round(extent * double(1 << bits)) <= limit) return bits;
  fail("SPZ: a mean coordinate of ", extent, " is beyond the format's 24-bit range (+-", limit, ")");
}

}  // namespace spz_detail

// The uncompressed version-3 stream (header and attributes) of a scene.
template <class Scalar>
std::string spz_payload(const GaussianScene<Scalar>& scene, const SpzOptions& options = {}) {
  using namespace spz_detail;
  scene.check_consistent();
  ensure(options.sh1_bits >= 1 && options.sh1_bits <= 8 && options.sh_rest_bits >= 1 && options.sh_rest_bits <= 8,
         "SPZ: SH bits must be 1..8, got ", options.sh1_bits, " and ", options.sh_rest_bits);
  const int sh1_bucket = 1 << (8 - options.sh1_bits), sh_rest_bucket = 1 << (8 - options.sh_rest_bits);
  const std::size_t n = scene.size();
  ensure(n <= 0xffffffffu, "SPZ: ", n, " Gaussians is more than the format's 32-bit count holds");
  const int K = scene.sh_coefficients();
  const int bits = fractional_bits_for(scene);
  std::string out;
  out.reserve(spz_header_bytes + n * (9 + 1 + 3 + 3 + 4 + 3 * std::size_t(K - 1)));
  put_u32(out, spz_magic);
  put_u32(out, spz_write_version);
  put_u32(out, std::uint32_t(n));
  out.push_back(char(scene.sh_degree));
  out.push_back(char(bits));
  out.push_back(0);  // flags: not antialiased, no extensions
  out.push_back(0);
  const double step = double(1 << bits);
  for (std::size_t i = 0; i < 3 * n; ++i) {
    const auto v = std::int32_t(std::lround(axis_flip[i % 3] * double(scene.means[i]) * step));
    for (int b = 0; b < 3; ++b) out.push_back(char((std::uint32_t(v) >> (8 * b)) & 0xff));
  }
  for (std::size_t g = 0; g < n; ++g) out.push_back(char(to_byte(sigmoid(double(scene.opacity_logits[g])) * 255.0)));
  for (std::size_t g = 0; g < n; ++g)
    for (int c = 0; c < 3; ++c)
      out.push_back(char(to_byte(double(scene.sh[g * std::size_t(3 * K) + c]) * spz_color_scale * 255.0 + 127.5)));
  for (std::size_t i = 0; i < 3 * n; ++i) out.push_back(char(to_byte((double(scene.log_scales[i]) + 10.0) * 16.0)));
  for (std::size_t g = 0; g < n; ++g) {
    const Scalar* r = &scene.rotations[4 * g];
    double q[4] = {double(r[1]), -double(r[2]), -double(r[3]), double(r[0])};  // x y z w, flipped
    const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    if (!(norm > 0) || !std::isfinite(norm)) {
      q[0] = q[1] = q[2] = 0;
      q[3] = 1;
    } else {
      for (double& v : q) v /= norm;
    }
    put_u32(out, pack_quaternion_v3(q));
  }
  for (std::size_t g = 0; g < n; ++g)
    for (int k = 1; k < K; ++k)
      for (int c = 0; c < 3; ++c)
        out.push_back(char(sh_byte(sh_flip[std::size_t(k)] * double(scene.sh[(g * std::size_t(K) + std::size_t(k)) * 3 + c]),
                                   k < 4 ? sh1_bucket : sh_rest_bucket)));
  return out;
}

// The .spz file bytes (gzip-compressed version-3 stream) of a scene.
template <class Scalar>
std::string spz_bytes(const GaussianScene<Scalar>& scene, const SpzOptions& options = {}) {
  return spz_detail::gzip_compress(spz_payload(scene, options));
}

template <class Scalar>
void write_spz(const std::string& path, const GaussianScene<Scalar>& scene, const SpzOptions& options = {}) {
  write_file_atomic(path, spz_bytes(scene, options));
}

template <class Scalar>
GaussianScene<Scalar> read_spz_from_memory(const std::string& bytes, const std::string& name) {
  using namespace spz_detail;
  const auto* raw = reinterpret_cast<const unsigned char*>(bytes.data());
  if (!starts_with_gzip(bytes)) {
    if (bytes.size() >= 8 && get_u32(raw) == spz_magic) {
      const std::uint32_t version = get_u32(raw + 4);
      ensure(version < 4, name, ": SPZ version ", version,
             " is not gzip-compressed (version 4 and later use zstd); only gzip versions 2 and 3 are read: "
             "convert it to version 3");
      fail(name, ": SPZ version ", version, " header found uncompressed; an SPZ file is a gzip stream");
    }
    fail(name, ": not an SPZ file: ", bytes.size() < 2 ? "too short for" : "does not start with",
         " the gzip magic 1f 8b (", bytes.size(), " bytes)");
  }
  GunzipStream z(bytes, name);
  std::string data;
  z.read(spz_header_bytes, data);
  ensure(data.size() == spz_header_bytes, name, ": SPZ data truncated: the stream holds ", data.size(),
         " bytes, less than the 16-byte header", z.truncated() ? " (the gzip stream is cut short)" : "");
  const auto* h = reinterpret_cast<const unsigned char*>(data.data());
  const std::uint32_t magic = get_u32(h);
  ensure(magic == spz_magic, name, ": wrong magic 0x", [&] {
    char buf[16];
    std::snprintf(buf, sizeof buf, "%08x", unsigned(magic));
    return std::string(buf);
  }(), " (expected 0x5053474e, \"NGSP\"): not an SPZ stream");
  const std::uint32_t version = get_u32(h + 4);
  ensure(version == 2 || version == 3, name, ": unsupported SPZ version ", version,
         " (versions 2 and 3 are read", version >= 4 ? "; version 4 and later use zstd, not gzip" : "", ")");
  const std::uint32_t n = get_u32(h + 8);
  const int degree = h[12];
  const int bits = h[13];
  const int flags = h[14];
  ensure(degree <= 4, name, ": SPZ SH degree ", degree, " is not 0..4");
  ensure(bits <= 23, name, ": SPZ fractional bits ", bits, " leave no room in a 24-bit coordinate");
  ensure(!(flags & 0x2), name, ": SPZ file has extensions (flag 0x2), which this reader does not support");
  const std::size_t rest = std::size_t(sh_coefficients_for_degree(degree) - 1);
  const std::size_t rot_bytes = version == 2 ? 3 : 4;
  const std::size_t per_gaussian = 9 + 1 + 3 + 3 + rot_bytes + 3 * rest;
  const std::size_t need = std::size_t(n) * per_gaussian;
  // Inflate in slices so that a false count stops at the data's end, not at an allocation.
  while (data.size() < spz_header_bytes + need && !z.ended() && !z.truncated())
    z.read(std::min<std::size_t>(spz_header_bytes + need - data.size(), std::size_t(64) << 20), data);
  ensure(data.size() >= spz_header_bytes + need, name, ": SPZ data truncated: ", n, " Gaussians of version ", version,
         " degree ", degree, " need ", spz_header_bytes + need, " bytes, the ",
         z.truncated() ? "gzip stream is cut short after " : "stream ends after ", data.size(), " bytes");
  z.finish();

  const int out_degree = std::min(degree, 3);
  GaussianScene<Scalar> scene;
  scene.resize(n, out_degree);
  const int K = scene.sh_coefficients();
  const auto* d = reinterpret_cast<const unsigned char*>(data.data()) + spz_header_bytes;
  const unsigned char* pos = d;
  const unsigned char* alpha = pos + 9 * std::size_t(n);
  const unsigned char* color = alpha + n;
  const unsigned char* scale = color + 3 * std::size_t(n);
  const unsigned char* rot = scale + 3 * std::size_t(n);
  const unsigned char* sh = rot + rot_bytes * n;
  const double step = 1.0 / double(1 << bits);
  const double eps = 0.25 / 255.0;
  for (std::size_t i = 0; i < 3 * std::size_t(n); ++i) {
    std::uint32_t u = std::uint32_t(pos[3 * i]) | std::uint32_t(pos[3 * i + 1]) << 8 | std::uint32_t(pos[3 * i + 2]) << 16;
    const std::int32_t v = std::int32_t(u & 0x800000u ? u | 0xff000000u : u);
    scene.means[i] = Scalar(axis_flip[i % 3] * double(v) * step);
    scene.log_scales[i] = Scalar(double(scale[i]) / 16.0 - 10.0);
  }
  for (std::size_t g = 0; g < n; ++g) {
    const double a = std::clamp(alpha[g] / 255.0, eps, 1.0 - eps);
    scene.opacity_logits[g] = Scalar(std::log(a / (1.0 - a)));
    for (int c = 0; c < 3; ++c)
      scene.sh[g * std::size_t(3 * K) + c] = Scalar((color[3 * g + c] / 255.0 - 0.5) / spz_color_scale);
    double q[4];  // x y z w
    if (version == 2) {
      double s = 0;
      for (int i = 0; i < 3; ++i) {
        q[i] = rot[3 * g + i] / 127.5 - 1.0;
        s += q[i] * q[i];
      }
      q[3] = std::sqrt(std::max(0.0, 1.0 - s));
    } else {
      unpack_quaternion_v3(get_u32(rot + 4 * g), q);
    }
    Scalar* r = &scene.rotations[4 * g];
    r[0] = Scalar(q[3]);
    r[1] = Scalar(q[0]);
    r[2] = Scalar(-q[1]);
    r[3] = Scalar(-q[2]);
    const unsigned char* s = sh + 3 * rest * g;
    for (int k = 1; k < K; ++k)
      for (int c = 0; c < 3; ++c)
        scene.sh[(g * std::size_t(K) + std::size_t(k)) * 3 + c] =
            Scalar(sh_flip[std::size_t(k)] * (double(s[3 * (k - 1) + c]) - 128.0) / 128.0);
  }
  return scene;
}

template <class Scalar>
GaussianScene<Scalar> read_spz(const std::string& path) {
  return read_spz_from_memory<Scalar>(read_file_bytes(path), path);
}

}  // namespace orbitforge

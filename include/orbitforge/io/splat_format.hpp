#pragma once
// The antimatter15 ".splat" format used by many web viewers: no header, 32 bytes
// per Gaussian, little endian:
//   bytes  0..11  float32 x y z          mean
//   bytes 12..23  float32 sx sy sz       ACTIVATED (linear) scales, exp(log_scale)
//   bytes 24..27  uint8 r g b a          colour = clamp(0.5 + C0 * f_dc, 0, 1) * 255,
//                                        alpha  = sigmoid(opacity logit) * 255
//   bytes 28..31  uint8 w x y z          normalised quaternion stored as q * 128 + 128
//
// The format is lossy: it has no view-dependent SH (reading gives degree-0 scenes,
// writing drops the higher coefficients), colours and opacity are 8-bit, colours are
// clamped to [0, 1], and rotations are 8-bit per component. Bytes are rounded to
// the nearest value when written. When read back:
//   f_dc = (byte / 255 - 0.5) / C0
//   opacity logit = logit(a / 255) with a / 255 kept inside [0.25/255, 1 - 0.25/255]
//     (so 0 and 255 give finite logits that write back as 0 and 255)
//   log_scale = log(s): a stored scale <= 0 reads as -inf / NaN, taken as stored
//   q = (byte - 128) / 128, not renormalised (the renderer normalises).
// Writing what was read reproduces the colour and opacity bytes exactly; positions
// are exact, scales within a float rounding, rotations within a byte (renormalising
// an 8-bit quaternion moves it slightly).
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/endian.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

inline constexpr std::size_t splat_record_bytes = 32;

namespace splat_detail {

inline float load_f32_le(const unsigned char* p) {
  unsigned char b[4] = {p[0], p[1], p[2], p[3]};
  if (!host_is_little_endian()) {
    std::swap(b[0], b[3]);
    std::swap(b[1], b[2]);
  }
  float v;
  std::memcpy(&v, b, 4);
  return v;
}

inline void store_f32_le(float v, unsigned char* p) {
  std::memcpy(p, &v, 4);
  if (!host_is_little_endian()) {
    std::swap(p[0], p[3]);
    std::swap(p[1], p[2]);
  }
}

// Nearest byte of v in [0, 255] (NaN -> 0).
template <class Scalar>
unsigned char to_byte(Scalar v) {
  if (!(v > Scalar(0))) return 0;
  if (v >= Scalar(255)) return 255;
  return static_cast<unsigned char>(std::lround(double(v)));
}

}  // namespace splat_detail

template <class Scalar>
GaussianScene<Scalar> read_splat_from_memory(const std::string& bytes, const std::string& name) {
  ensure(bytes.size() % splat_record_bytes == 0, name, ": .splat size ", bytes.size(),
         " bytes is not a multiple of 32 (truncated or not a .splat file; last record starts at byte offset ",
         bytes.size() / splat_record_bytes * splat_record_bytes, ")");
  const std::size_t n = bytes.size() / splat_record_bytes;
  GaussianScene<Scalar> scene;
  scene.resize(n, 0);
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data());
  const double c0 = sh_c0<double>();
  const double eps = 0.25 / 255.0;
  for (std::size_t g = 0; g < n; ++g) {
    const unsigned char* r = data + g * splat_record_bytes;
    for (int i = 0; i < 3; ++i) scene.means[3 * g + i] = Scalar(splat_detail::load_f32_le(r + 4 * i));
    for (int i = 0; i < 3; ++i)
      scene.log_scales[3 * g + i] = Scalar(std::log(double(splat_detail::load_f32_le(r + 12 + 4 * i))));
    for (int c = 0; c < 3; ++c) scene.sh[3 * g + c] = Scalar((r[24 + c] / 255.0 - 0.5) / c0);
    const double a = std::clamp(r[27] / 255.0, eps, 1.0 - eps);
    scene.opacity_logits[g] = Scalar(std::log(a / (1.0 - a)));
    for (int i = 0; i < 4; ++i) scene.rotations[4 * g + i] = Scalar((double(r[28 + i]) - 128.0) / 128.0);
  }
  return scene;
}

template <class Scalar>
GaussianScene<Scalar> read_splat(const std::string& path) {
  return read_splat_from_memory<Scalar>(read_file_bytes(path), path);
}

// The .splat bytes of a scene (higher SH dropped). A zero quaternion is written as
// the identity rotation, since the format cannot hold it.
template <class Scalar>
std::string splat_bytes(const GaussianScene<Scalar>& scene) {
  scene.check_consistent();
  const std::size_t n = scene.size();
  const int K = scene.sh_coefficients();
  std::string out(n * splat_record_bytes, '\0');
  auto* data = reinterpret_cast<unsigned char*>(&out[0]);
  const double c0 = sh_c0<double>();
  for (std::size_t g = 0; g < n; ++g) {
    unsigned char* r = data + g * splat_record_bytes;
    for (int i = 0; i < 3; ++i) splat_detail::store_f32_le(float(scene.means[3 * g + i]), r + 4 * i);
    for (int i = 0; i < 3; ++i)
      splat_detail::store_f32_le(float(std::exp(double(scene.log_scales[3 * g + i]))), r + 12 + 4 * i);
    for (int c = 0; c < 3; ++c) {
      const double rgb = std::clamp(0.5 + c0 * double(scene.sh[g * std::size_t(3 * K) + c]), 0.0, 1.0);
      r[24 + c] = splat_detail::to_byte(rgb * 255.0);
    }
    r[27] = splat_detail::to_byte(255.0 / (1.0 + std::exp(-double(scene.opacity_logits[g]))));
    double q[4], norm2 = 0;
    for (int i = 0; i < 4; ++i) {
      q[i] = double(scene.rotations[4 * g + i]);
      norm2 += q[i] * q[i];
    }
    const double norm = std::sqrt(norm2);
    if (!(norm > 0) || !std::isfinite(norm)) {
      q[0] = 1;
      q[1] = q[2] = q[3] = 0;
    } else {
      for (double& v : q) v /= norm;
    }
    for (int i = 0; i < 4; ++i) r[28 + i] = splat_detail::to_byte(q[i] * 128.0 + 128.0);
  }
  return out;
}

template <class Scalar>
void write_splat(const std::string& path, const GaussianScene<Scalar>& scene) {
  write_file_atomic(path, splat_bytes(scene));
}

}  // namespace orbitforge

#pragma once
// Real spherical-harmonic colour of degree 0..3 in a viewing direction, with the
// constants, basis order and sign pattern of the original 3DGS, and its VJP.
//
//   colour_c = max(0, sum_k basis_k(d) * sh[k][c] + 0.5),   d = dir / |dir|
//
// sh is coefficient-major then RGB: sh[3 * k + c], k < (degree + 1)^2. Work stops
// at the degree asked for; coefficients above it are never read or written.
// The clamp passes no gradient where it clamps (raw + 0.5 < 0), as in 3DGS.
//
// `dir` is the un-normalised viewing direction (Gaussian mean - camera centre);
// sh_to_color_vjp returns the gradient w.r.t. it, through the normalisation, so
// that mean gradients are complete. Degree 0 does not depend on the direction
// (dir is not read and v_dir is zero).
#include <cmath>
#include <type_traits>

#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

namespace detail {
// The scalar of a value type: itself, or a SIMD batch's value_type (sh_basis and
// sh_basis_vjp also run on batches of directions, in splat/project_lanes.hpp).
template <class T, class = void>
struct lane_scalar { using type = T; };
template <class T>
struct lane_scalar<T, std::void_t<typename T::value_type>> { using type = typename T::value_type; };
}  // namespace detail

template <class Scalar>
struct ShConstants {
  static constexpr Scalar C0 = Scalar(0.28209479177387814);
  static constexpr Scalar C1 = Scalar(0.4886025119029199);
  static constexpr Scalar C2[5] = {Scalar(1.0925484305920792), Scalar(-1.0925484305920792),
                                   Scalar(0.31539156525252005), Scalar(-1.0925484305920792),
                                   Scalar(0.5462742152960396)};
  static constexpr Scalar C3[7] = {Scalar(-0.5900435899266435), Scalar(2.890611442640554),
                                   Scalar(-0.4570457994644658), Scalar(0.3731763325901154),
                                   Scalar(-0.4570457994644658), Scalar(1.445305721320277),
                                   Scalar(-0.5900435899266435)};
};

// Basis values b[k], k < (degree + 1)^2, at the unit direction (x, y, z).
template <class Scalar>
inline void sh_basis(int degree, Scalar x, Scalar y, Scalar z, Scalar* b) {
  using C = ShConstants<typename detail::lane_scalar<Scalar>::type>;
  b[0] = C::C0;
  if (degree < 1) return;
  b[1] = -C::C1 * y;
  b[2] = C::C1 * z;
  b[3] = -C::C1 * x;
  if (degree < 2) return;
  const Scalar xx = x * x, yy = y * y, zz = z * z, xy = x * y, yz = y * z, xz = x * z;
  b[4] = C::C2[0] * xy;
  b[5] = C::C2[1] * yz;
  b[6] = C::C2[2] * (Scalar(2) * zz - xx - yy);
  b[7] = C::C2[3] * xz;
  b[8] = C::C2[4] * (xx - yy);
  if (degree < 3) return;
  b[9] = C::C3[0] * y * (Scalar(3) * xx - yy);
  b[10] = C::C3[1] * xy * z;
  b[11] = C::C3[2] * y * (Scalar(4) * zz - xx - yy);
  b[12] = C::C3[3] * z * (Scalar(2) * zz - Scalar(3) * xx - Scalar(3) * yy);
  b[13] = C::C3[4] * x * (Scalar(4) * zz - xx - yy);
  b[14] = C::C3[5] * z * (xx - yy);
  b[15] = C::C3[6] * x * (xx - Scalar(3) * yy);
}

// Gradient of sum_k v_b[k] * b_k(x, y, z) w.r.t. the (unit) direction components,
// treating x, y, z as independent (the normalisation is handled by the caller).
template <class Scalar>
inline void sh_basis_vjp(int degree, Scalar x, Scalar y, Scalar z,  // inputs
                         const Scalar* v_b,                          // grad outputs [K]
                         Scalar v_xyz[3]) {                          // grad inputs [3]
  using C = ShConstants<typename detail::lane_scalar<Scalar>::type>;
  Scalar gx(0), gy(0), gz(0);
  if (degree >= 1) {
    gy -= C::C1 * v_b[1];
    gz += C::C1 * v_b[2];
    gx -= C::C1 * v_b[3];
  }
  if (degree >= 2) {
    const Scalar c0 = C::C2[0] * v_b[4], c1 = C::C2[1] * v_b[5], c2 = C::C2[2] * v_b[6], c3 = C::C2[3] * v_b[7],
                 c4 = C::C2[4] * v_b[8];
    gx += c0 * y - Scalar(2) * x * c2 + c3 * z + Scalar(2) * x * c4;
    gy += c0 * x + c1 * z - Scalar(2) * y * c2 - Scalar(2) * y * c4;
    gz += c1 * y + Scalar(4) * z * c2 + c3 * x;
  }
  if (degree >= 3) {
    const Scalar xx = x * x, yy = y * y, zz = z * z;
    const Scalar c0 = C::C3[0] * v_b[9], c1 = C::C3[1] * v_b[10], c2 = C::C3[2] * v_b[11],
                 c3 = C::C3[3] * v_b[12], c4 = C::C3[4] * v_b[13], c5 = C::C3[5] * v_b[14],
                 c6 = C::C3[6] * v_b[15];
    gx += c0 * Scalar(6) * x * y + c1 * y * z - c2 * Scalar(2) * x * y - c3 * Scalar(6) * x * z +
          c4 * (Scalar(4) * zz - Scalar(3) * xx - yy) + c5 * Scalar(2) * x * z + c6 * Scalar(3) * (xx - yy);
    gy += c0 * Scalar(3) * (xx - yy) + c1 * x * z + c2 * (Scalar(4) * zz - xx - Scalar(3) * yy) -
          c3 * Scalar(6) * y * z - c4 * Scalar(2) * x * y - c5 * Scalar(2) * y * z - c6 * Scalar(6) * x * y;
    gz += c1 * x * y + c2 * Scalar(8) * y * z + c3 * (Scalar(6) * zz - Scalar(3) * xx - Scalar(3) * yy) +
          c4 * Scalar(8) * x * z + c5 * (xx - yy);
  }
  v_xyz[0] = gx;
  v_xyz[1] = gy;
  v_xyz[2] = gz;
}

namespace detail {
// Keeps an argument out of template deduction (so nullptr can be passed).
template <class T>
struct same { using type = T; };
template <class T>
using same_t = typename same<T>::type;
// Unit direction and 1/|dir|.
template <class Scalar>
inline Scalar normalize_dir(const Scalar dir[3], Scalar unit[3]) {
  const Scalar inv = Scalar(1) / std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
  unit[0] = dir[0] * inv;
  unit[1] = dir[1] * inv;
  unit[2] = dir[2] * inv;
  return inv;
}
// Unclamped sum_k b_k sh[k][c] + 0.5 for c = 0..2.
template <class Scalar>
inline void sh_raw_color(int k_count, const Scalar* b, const Scalar* sh, Scalar raw[3]) {
  Scalar r = 0, g = 0, bl = 0;
  for (int k = 0; k < k_count; ++k) {
    r += b[k] * sh[3 * k + 0];
    g += b[k] * sh[3 * k + 1];
    bl += b[k] * sh[3 * k + 2];
  }
  raw[0] = r + Scalar(0.5);
  raw[1] = g + Scalar(0.5);
  raw[2] = bl + Scalar(0.5);
}
}  // namespace detail

template <class Scalar>
inline void sh_to_color(int degree,           // 0..3
                        const Scalar* sh,     // [K][3]
                        const Scalar dir[3],  // un-normalised viewing direction
                        Scalar rgb[3]) {      // output colour, >= 0
  Scalar b[16];
  if (degree > 0) {
    Scalar d[3];
    detail::normalize_dir(dir, d);
    sh_basis(degree, d[0], d[1], d[2], b);
  } else {
    b[0] = ShConstants<Scalar>::C0;
  }
  Scalar raw[3];
  detail::sh_raw_color(sh_coefficient_count(degree), b, sh, raw);
  for (int c = 0; c < 3; ++c) rgb[c] = raw[c] < Scalar(0) ? Scalar(0) : raw[c];
}

// v_sh (may be null) is overwritten for k < K; v_dir (may be null) is overwritten.
template <class Scalar>
inline void sh_to_color_vjp(int degree, const Scalar* sh, const Scalar dir[3],  // inputs
                            const Scalar v_rgb[3],                               // grad outputs
                            detail::same_t<Scalar>* v_sh,                        // grad inputs
                            detail::same_t<Scalar>* v_dir) {
  const int k_count = sh_coefficient_count(degree);
  Scalar b[16], d[3] = {0, 0, 0}, inv_norm = 0;
  if (degree > 0) {
    inv_norm = detail::normalize_dir(dir, d);
    sh_basis(degree, d[0], d[1], d[2], b);
  } else {
    b[0] = ShConstants<Scalar>::C0;
  }
  Scalar raw[3];
  detail::sh_raw_color(k_count, b, sh, raw);
  Scalar g[3];
  for (int c = 0; c < 3; ++c) g[c] = raw[c] < Scalar(0) ? Scalar(0) : v_rgb[c];
  if (v_sh) {
    for (int k = 0; k < k_count; ++k) {
      v_sh[3 * k + 0] = b[k] * g[0];
      v_sh[3 * k + 1] = b[k] * g[1];
      v_sh[3 * k + 2] = b[k] * g[2];
    }
  }
  if (!v_dir) return;
  if (degree == 0) {
    v_dir[0] = v_dir[1] = v_dir[2] = Scalar(0);
    return;
  }
  Scalar v_b[16];
  for (int k = 0; k < k_count; ++k) v_b[k] = sh[3 * k] * g[0] + sh[3 * k + 1] * g[1] + sh[3 * k + 2] * g[2];
  Scalar v_d[3];
  sh_basis_vjp(degree, d[0], d[1], d[2], v_b, v_d);
  // d = dir / |dir|:  v_dir = (v_d - d (d . v_d)) / |dir|
  const Scalar dot = d[0] * v_d[0] + d[1] * v_d[1] + d[2] * v_d[2];
  for (int a = 0; a < 3; ++a) v_dir[a] = (v_d[a] - d[a] * dot) * inv_norm;
}

}  // namespace orbitforge

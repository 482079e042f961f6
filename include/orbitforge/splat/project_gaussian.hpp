#pragma once
// Projecting one Gaussian: EWA projection, culling, opacity and SH colour
// (project_gaussian) and its VJP (project_gaussian_vjp), with the differentiable
// maths they are made of. The per-Gaussian reference that project_scene's batch
// path (splat/project_lanes.hpp) matches and that project_scene_vjp recomputes.
//
// Conventions (docs/conventions.md):
//   camera space t = R x + t_cam (OpenCV axes); culled when t_z <= near (0.01).
//   u = fx t_x / t_z + cx, v = fy t_y / t_z + cy; pixel i has its centre at i + 0.5.
//   Sigma = R_q diag(s^2) R_q^T, cov2d = J W Sigma W^T J^T + 0.3 I, where the EWA
//   Jacobian uses t_x' = clamp(t_x / t_z, -lim_x, lim_x) t_z, lim_x = 1.3 * 0.5 W / fx
//   (same for y). The VJP differentiates the clamp exactly: where it clamps,
//   t_x' = +-lim_x t_z, so d t_x' / d t_x = 0 (as in 3DGS) and d t_x' / d t_z = +-lim_x
//   (a term 3DGS drops; keeping it makes the gradient match finite differences).
//   conic = cov2d^-1; radius = ceil(3 sqrt(lambda_max(cov2d))) (exact eigenvalue).
//   The rectangle is the set of pixels whose centres lie in the 3-sigma square
//   |px - u| <= r, |py - v| <= r, clipped to the image; with tight_extents it is
//   intersected with the box of the ellipse where alpha = o exp(power) >= 1/255:
//   d^T conic d <= 2 ln(255 o), half-extents sqrt(2 ln(255 o) cov2d_xx), ... (with a
//   small slack on ln(255 o) so that rounding in the rasterizer never loses a pixel).
//   Colour = SH in the direction mean - camera centre, + 0.5, clamped at 0.
//
// Culling (counted in ProjectionStats; culled Gaussians get radius 0 and zero
// gradients): non-finite parameters (any NaN/inf input, a zero quaternion, an
// overflowing or non-positive-definite 2D covariance) -> culled_nonfinite;
// t_z <= near -> culled_near; opacity < 1/255 or an empty tight rectangle ->
// culled_faint; an empty 3-sigma rectangle -> culled_outside.
//
// project_gaussian is the per-Gaussian reference (and what the VJP recomputes);
// project_scene runs a SIMD batch path (detail::project_lanes) that makes the
// same decisions and gives the same values within float rounding.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/splat/sh.hpp"

namespace orbitforge {

struct ProjectionParams {
  double near_plane = 0.01;     // cull when camera-space z <= near_plane
  double eps2d = 0.3;           // dilation added to the 2D covariance diagonal
  double clip_factor = 1.3;     // x/z, y/z clamp in J, as a multiple of tan(half fov)
  double alpha_min = 1.0 / 255.0;  // the rasterizer's skip threshold
  bool tight_extents = true;    // opacity-aware rectangles (never change the image)
  std::size_t chunk = 1024;     // Gaussians per parallel work item
};

struct ProjectionStats {
  std::size_t visible = 0, culled_near = 0, culled_outside = 0, culled_faint = 0, culled_nonfinite = 0;
  std::size_t total() const { return visible + culled_near + culled_outside + culled_faint + culled_nonfinite; }
};

enum class CullReason : int { none = 0, near = 1, outside = 2, faint = 3, nonfinite = 4 };

// ---------------------------------------------------------------------------
// Per-camera constants shared by every Gaussian.
template <class Scalar>
struct ProjectionCamera {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  Mat3 R;        // camera_R_world
  Vec3 t;        // camera_t_world
  Vec3 center;   // camera centre in world coordinates
  Scalar fx, fy, cx, cy;
  Scalar lim_x, lim_y;  // clamp of x/z, y/z in the EWA Jacobian
  Scalar near_plane, eps2d, alpha_min;
  int width, height;
  bool tight_extents;

  static ProjectionCamera make(const Camera<Scalar>& cam, const ProjectionParams& p) {
    const auto& k = cam.intrinsics;
    ensure(cam.is_finite(), "project: camera has non-finite intrinsics or pose");
    ensure(k.width > 0 && k.height > 0, "project: image size must be positive, got ", k.width, "x", k.height);
    ensure(k.fx > 0 && k.fy > 0, "project: focal lengths must be positive, got fx=", k.fx, " fy=", k.fy);
    ensure(p.near_plane > 0 && p.eps2d >= 0 && p.clip_factor > 0 && p.alpha_min > 0 && p.alpha_min < 1,
           "project: invalid ProjectionParams (near_plane > 0, eps2d >= 0, clip_factor > 0, 0 < alpha_min < 1)");
    ProjectionCamera c;
    c.R = cam.R;
    c.t = cam.t;
    c.center = cam.center();
    c.fx = k.fx; c.fy = k.fy; c.cx = k.cx; c.cy = k.cy;
    c.lim_x = Scalar(p.clip_factor) * Scalar(0.5) * Scalar(k.width) / k.fx;
    c.lim_y = Scalar(p.clip_factor) * Scalar(0.5) * Scalar(k.height) / k.fy;
    c.near_plane = Scalar(p.near_plane);
    c.eps2d = Scalar(p.eps2d);
    c.alpha_min = Scalar(p.alpha_min);
    c.width = k.width;
    c.height = k.height;
    c.tight_extents = p.tight_extents;
    return c;
  }
};

// One Gaussian as the projection consumes it (scale activated, any sign).
template <class Scalar>
struct GaussianParams {
  Scalar mean[3];
  Scalar quat[4];   // (w, x, y, z), not necessarily normalised
  Scalar scale[3];  // activated standard deviations
  Scalar opacity_logit;
  int sh_degree;
  const Scalar* sh;  // [K][3]
};

// One projected Gaussian (the per-Gaussian row of ProjectedSplats).
template <class Scalar>
struct Splat {
  Scalar mean_x, mean_y, conic_a, conic_b, conic_c, opacity, color[3], depth;
  std::int32_t radius, rect_x0, rect_y0, rect_x1, rect_y1;
};

template <class Scalar>
struct SplatGrad {
  Scalar v_mean_x, v_mean_y, v_conic_a, v_conic_b, v_conic_c, v_opacity, v_color[3], v_depth;
};

// ---------------------------------------------------------------------------
// Quaternion (w, x, y, z), any non-zero norm -> rotation matrix of q / |q|.
template <class Scalar>
inline void quat_to_rotmat(const Scalar q[4],                      // input
                           Eigen::Matrix<Scalar, 3, 3>& R) {       // output
  const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const Scalar w = q[0] * inv, x = q[1] * inv, y = q[2] * inv, z = q[3] * inv;
  R(0, 0) = Scalar(1) - Scalar(2) * (y * y + z * z);
  R(0, 1) = Scalar(2) * (x * y - w * z);
  R(0, 2) = Scalar(2) * (x * z + w * y);
  R(1, 0) = Scalar(2) * (x * y + w * z);
  R(1, 1) = Scalar(1) - Scalar(2) * (x * x + z * z);
  R(1, 2) = Scalar(2) * (y * z - w * x);
  R(2, 0) = Scalar(2) * (x * z - w * y);
  R(2, 1) = Scalar(2) * (y * z + w * x);
  R(2, 2) = Scalar(1) - Scalar(2) * (x * x + y * y);
}

// Gradient w.r.t. the stored (un-normalised) quaternion, through the normalisation.
template <class Scalar>
inline void quat_to_rotmat_vjp(const Scalar q[4],                           // input
                               const Eigen::Matrix<Scalar, 3, 3>& v_R,      // grad output
                               Scalar v_q[4]) {                             // grad input
  const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const Scalar w = q[0] * inv, x = q[1] * inv, y = q[2] * inv, z = q[3] * inv;
  const Scalar gw = Scalar(2) * (-z * v_R(0, 1) + y * v_R(0, 2) + z * v_R(1, 0) - x * v_R(1, 2) -
                                 y * v_R(2, 0) + x * v_R(2, 1));
  const Scalar gx = Scalar(2) * (y * v_R(0, 1) + z * v_R(0, 2) + y * v_R(1, 0) - Scalar(2) * x * v_R(1, 1) -
                                 w * v_R(1, 2) + z * v_R(2, 0) + w * v_R(2, 1) - Scalar(2) * x * v_R(2, 2));
  const Scalar gy = Scalar(2) * (-Scalar(2) * y * v_R(0, 0) + x * v_R(0, 1) + w * v_R(0, 2) + x * v_R(1, 0) +
                                 z * v_R(1, 2) - w * v_R(2, 0) + z * v_R(2, 1) - Scalar(2) * y * v_R(2, 2));
  const Scalar gz = Scalar(2) * (-Scalar(2) * z * v_R(0, 0) - w * v_R(0, 1) + x * v_R(0, 2) + w * v_R(1, 0) -
                                 Scalar(2) * z * v_R(1, 1) + y * v_R(1, 2) + x * v_R(2, 0) + y * v_R(2, 1));
  // n = q / |q|:  v_q = (v_n - n (n . v_n)) / |q|
  const Scalar dot = w * gw + x * gx + y * gy + z * gz;
  v_q[0] = (gw - w * dot) * inv;
  v_q[1] = (gx - x * dot) * inv;
  v_q[2] = (gy - y * dot) * inv;
  v_q[3] = (gz - z * dot) * inv;
}

// Sigma = R diag(s)^2 R^T (s of any sign).
template <class Scalar>
inline void covariance3d(const Eigen::Matrix<Scalar, 3, 3>& R, const Scalar s[3],  // inputs
                         Eigen::Matrix<Scalar, 3, 3>& Sigma) {                      // output
  Eigen::Matrix<Scalar, 3, 3> M = R;
  M.col(0) *= s[0];
  M.col(1) *= s[1];
  M.col(2) *= s[2];
  Sigma.noalias() = M * M.transpose();
}

// v_Sigma is the gradient w.r.t. the entries of the (symmetric) matrix, each
// entry counted once (so a scalar loss reading Sigma(0,1) and Sigma(1,0) through
// one value must split its gradient between them).
template <class Scalar>
inline void covariance3d_vjp(const Eigen::Matrix<Scalar, 3, 3>& R, const Scalar s[3],  // inputs
                             const Eigen::Matrix<Scalar, 3, 3>& v_Sigma,               // grad output
                             Eigen::Matrix<Scalar, 3, 3>& v_R, Scalar v_s[3]) {         // grad inputs
  Eigen::Matrix<Scalar, 3, 3> M = R;
  M.col(0) *= s[0];
  M.col(1) *= s[1];
  M.col(2) *= s[2];
  // Sigma = M M^T: v_M = (v_Sigma + v_Sigma^T) M
  const Eigen::Matrix<Scalar, 3, 3> v_M = (v_Sigma + v_Sigma.transpose()) * M;
  for (int j = 0; j < 3; ++j) {
    v_R.col(j) = v_M.col(j) * s[j];
    v_s[j] = v_M.col(j).dot(R.col(j));
  }
}

// The EWA Jacobian of the perspective map at camera-space t, with the x/z, y/z clamp.
template <class Scalar>
struct EwaJacobian {
  Scalar j00, j02, j11, j12;  // J = [[j00, 0, j02], [0, j11, j12]]
  Scalar tx, ty;              // clamped t_x', t_y'
  Scalar dtx_dx, dtx_dz, dty_dy, dty_dz;

  EwaJacobian(const Scalar t[3], Scalar fx, Scalar fy, Scalar lim_x, Scalar lim_y) {
    const Scalar z = t[2], iz = Scalar(1) / z, iz2 = iz * iz;
    const Scalar ux = t[0] * iz, uy = t[1] * iz;
    const Scalar cx = std::min(lim_x, std::max(-lim_x, ux)), cy = std::min(lim_y, std::max(-lim_y, uy));
    const bool in_x = ux > -lim_x && ux < lim_x, in_y = uy > -lim_y && uy < lim_y;
    tx = cx * z;
    ty = cy * z;
    dtx_dx = in_x ? Scalar(1) : Scalar(0);
    dtx_dz = in_x ? Scalar(0) : cx;
    dty_dy = in_y ? Scalar(1) : Scalar(0);
    dty_dz = in_y ? Scalar(0) : cy;
    j00 = fx * iz;
    j02 = -fx * tx * iz2;
    j11 = fy * iz;
    j12 = -fy * ty * iz2;
  }
  // T = J W (2x3)
  Eigen::Matrix<Scalar, 2, 3> times(const Eigen::Matrix<Scalar, 3, 3>& W) const {
    Eigen::Matrix<Scalar, 2, 3> T;
    T.row(0) = j00 * W.row(0) + j02 * W.row(2);
    T.row(1) = j11 * W.row(1) + j12 * W.row(2);
    return T;
  }
  // Accumulates into v_t the gradient of the J entries' dependence on t.
  void vjp(const Scalar t[3], Scalar fx, Scalar fy, Scalar v_j00, Scalar v_j02, Scalar v_j11, Scalar v_j12,
           Scalar v_t[3]) const {
    const Scalar iz = Scalar(1) / t[2], iz2 = iz * iz, iz3 = iz2 * iz;
    // j02 = -fx tx / z^2, tx = tx(t_x, t_z)
    const Scalar d02_dtx = -fx * iz2, d12_dty = -fy * iz2;
    v_t[0] += v_j02 * d02_dtx * dtx_dx;
    v_t[1] += v_j12 * d12_dty * dty_dy;
    v_t[2] += -fx * iz2 * v_j00 - fy * iz2 * v_j11 +
              v_j02 * (d02_dtx * dtx_dz + Scalar(2) * fx * tx * iz3) +
              v_j12 * (d12_dty * dty_dz + Scalar(2) * fy * ty * iz3);
  }
};

// cov2d = J W Sigma W^T J^T + eps2d I, as (xx, xy, yy).
template <class Scalar>
inline void project_covariance(const Scalar t[3], const Eigen::Matrix<Scalar, 3, 3>& Sigma,   // inputs
                               const Eigen::Matrix<Scalar, 3, 3>& W, Scalar fx, Scalar fy,    // camera
                               Scalar lim_x, Scalar lim_y, Scalar eps2d,                       //
                               Scalar cov[3]) {                                                // output
  const EwaJacobian<Scalar> J(t, fx, fy, lim_x, lim_y);
  const Eigen::Matrix<Scalar, 2, 3> T = J.times(W);
  const Eigen::Matrix<Scalar, 2, 3> TS = T * Sigma;
  cov[0] = TS.row(0).dot(T.row(0)) + eps2d;
  cov[1] = TS.row(0).dot(T.row(1));
  cov[2] = TS.row(1).dot(T.row(1)) + eps2d;
}

// v_cov = (v_xx, v_xy, v_yy): gradient w.r.t. the three scalars (xy counted once).
// v_t (3) is accumulated into; v_Sigma (may be null) is overwritten with a
// symmetric matrix: a symmetric change dSigma changes the loss by
// sum_ij v_Sigma(i, j) dSigma(i, j), as covariance3d_vjp expects.
template <class Scalar>
inline void project_covariance_vjp(const Scalar t[3], const Eigen::Matrix<Scalar, 3, 3>& Sigma,   // inputs
                                   const Eigen::Matrix<Scalar, 3, 3>& W, Scalar fx, Scalar fy,    // camera
                                   Scalar lim_x, Scalar lim_y,                                     //
                                   const Scalar v_cov[3],                                          // grad output
                                   detail::same_t<Scalar>* v_t,                                    // grad inputs
                                   detail::same_t<Eigen::Matrix<Scalar, 3, 3>>* v_Sigma) {
  const EwaJacobian<Scalar> J(t, fx, fy, lim_x, lim_y);
  const Eigen::Matrix<Scalar, 2, 3> T = J.times(W);
  Eigen::Matrix<Scalar, 2, 2> V;
  V << v_cov[0], Scalar(0.5) * v_cov[1], Scalar(0.5) * v_cov[1], v_cov[2];
  if (v_Sigma) v_Sigma->noalias() = T.transpose() * V * T;
  if (v_t) {
    // cov = T Sigma T^T, V symmetric: v_T = 2 V T Sigma; T = J W: v_J = v_T W^T
    const Eigen::Matrix<Scalar, 2, 3> v_T = Scalar(2) * (V * (T * Sigma));
    const Scalar v_j00 = v_T.row(0).dot(W.row(0)), v_j02 = v_T.row(0).dot(W.row(2));
    const Scalar v_j11 = v_T.row(1).dot(W.row(1)), v_j12 = v_T.row(1).dot(W.row(2));
    J.vjp(t, fx, fy, v_j00, v_j02, v_j11, v_j12, v_t);
  }
}

// conic = cov^-1, both as (xx, xy, yy). Returns det(cov).
template <class Scalar>
inline Scalar inverse2x2(const Scalar cov[3], Scalar conic[3]) {
  const Scalar det = cov[0] * cov[2] - cov[1] * cov[1];
  const Scalar inv = Scalar(1) / det;
  conic[0] = cov[2] * inv;
  conic[1] = -cov[1] * inv;
  conic[2] = cov[0] * inv;
  return det;
}

// Gradients in the three-scalar convention (xy counted once) on both sides.
template <class Scalar>
inline void inverse2x2_vjp(const Scalar conic[3],  // forward output
                           const Scalar v_conic[3],  // grad output
                           Scalar v_cov[3]) {        // grad input
  // v_Cov = -Q V Q with V = [[va, vb/2], [vb/2, vc]]; v_xy = 2 v_Cov(0, 1).
  const Scalar a = conic[0], b = conic[1], c = conic[2];
  const Scalar va = v_conic[0], vb = Scalar(0.5) * v_conic[1], vc = v_conic[2];
  // Q V = [[a va + b vb, a vb + b vc], [b va + c vb, b vb + c vc]]
  const Scalar qv00 = a * va + b * vb, qv01 = a * vb + b * vc, qv10 = b * va + c * vb, qv11 = b * vb + c * vc;
  v_cov[0] = -(qv00 * a + qv01 * b);
  v_cov[1] = -Scalar(2) * (qv00 * b + qv01 * c);
  v_cov[2] = -(qv10 * b + qv11 * c);
}

namespace detail {
template <class Scalar>
inline Scalar sum_times_zero(const Scalar* v, int n) {
  Scalar acc = 0;
  for (int i = 0; i < n; ++i) acc += v[i] * Scalar(0);
  return acc;
}
}  // namespace detail

// ---------------------------------------------------------------------------
// Projects one Gaussian. On a cull, `out` is partly written and only
// out.radius (= 0) is meaningful.
template <class Scalar>
inline CullReason project_gaussian(const ProjectionCamera<Scalar>& cam, const GaussianParams<Scalar>& g,  // inputs
                                   Splat<Scalar>& out) {                                                  // output
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  out.radius = 0;
  const int k_count = sh_coefficient_count(g.sh_degree);
  // NaN or inf anywhere: x * 0 is NaN only for those.
  const Scalar poison = detail::sum_times_zero(g.mean, 3) + detail::sum_times_zero(g.quat, 4) +
                        detail::sum_times_zero(g.scale, 3) + g.opacity_logit * Scalar(0) +
                        detail::sum_times_zero(g.sh, 3 * k_count);
  if (!(poison == Scalar(0))) return CullReason::nonfinite;

  const Vec3 x(g.mean[0], g.mean[1], g.mean[2]);
  const Vec3 tv = cam.R * x + cam.t;
  const Scalar t[3] = {tv[0], tv[1], tv[2]};
  if (!(t[2] > cam.near_plane)) return CullReason::near;

  Mat3 Rq, Sigma;
  quat_to_rotmat(g.quat, Rq);
  covariance3d(Rq, g.scale, Sigma);
  Scalar cov[3];
  project_covariance(t, Sigma, cam.R, cam.fx, cam.fy, cam.lim_x, cam.lim_y, cam.eps2d, cov);
  Scalar conic[3];
  const Scalar det = inverse2x2(cov, conic);
  if (!(det > Scalar(0) && det <= std::numeric_limits<Scalar>::max())) return CullReason::nonfinite;
  if (!(std::isfinite(conic[0]) && std::isfinite(conic[1]) && std::isfinite(conic[2])))
    return CullReason::nonfinite;

  const Scalar opacity = sigmoid(g.opacity_logit);
  if (opacity < cam.alpha_min) return CullReason::faint;

  const Scalar iz = Scalar(1) / t[2];
  const Scalar u = cam.fx * t[0] * iz + cam.cx, v = cam.fy * t[1] * iz + cam.cy;
  // The larger eigenvalue, its square root's argument mid^2 - det written as a
  // sum of squares: never negative, and its rounding stays relative to itself
  // (mid^2 - det cancels for a round splat, and its rounding, magnified by the
  // root, would decide the radius).
  const Scalar mid = Scalar(0.5) * (cov[0] + cov[2]), half_diff = Scalar(0.5) * (cov[0] - cov[2]);
  const Scalar lambda = mid + std::sqrt(half_diff * half_diff + cov[1] * cov[1]);
  // Rectangle arithmetic in double: exact integer bounds for any precision.
  const double r = std::min(std::ceil(3.0 * std::sqrt(double(lambda))), double(1 << 30));
  const double W1 = cam.width - 1, H1 = cam.height - 1;
  const double ud = double(u), vd = double(v);
  if (!(std::isfinite(ud) && std::isfinite(vd))) return CullReason::nonfinite;
  // Pixel i is inside when |i + 0.5 - u| <= r.
  double x0 = std::max(0.0, std::ceil(ud - r - 0.5)), x1 = std::min(W1, std::floor(ud + r - 0.5));
  double y0 = std::max(0.0, std::ceil(vd - r - 0.5)), y1 = std::min(H1, std::floor(vd + r - 0.5));
  if (x0 > x1 || y0 > y1) return CullReason::outside;
  if (cam.tight_extents) {
    // alpha >= alpha_min only where d^T conic d <= 2 ln(o / alpha_min). The slack
    // (1e-3 in power, relative and absolute) covers rounding in the rasterizer.
    const double tt = std::log(double(opacity) / double(cam.alpha_min)) * (1 + 1e-3) + 1e-3;
    const double ex = std::sqrt(2 * tt * double(cov[0])), ey = std::sqrt(2 * tt * double(cov[2]));
    x0 = std::max(x0, std::ceil(ud - ex - 0.5));
    x1 = std::min(x1, std::floor(ud + ex - 0.5));
    y0 = std::max(y0, std::ceil(vd - ey - 0.5));
    y1 = std::min(y1, std::floor(vd + ey - 0.5));
    if (x0 > x1 || y0 > y1) return CullReason::faint;
  }

  const Scalar dir[3] = {g.mean[0] - cam.center[0], g.mean[1] - cam.center[1], g.mean[2] - cam.center[2]};
  sh_to_color(g.sh_degree, g.sh, dir, out.color);

  out.mean_x = u;
  out.mean_y = v;
  out.conic_a = conic[0];
  out.conic_b = conic[1];
  out.conic_c = conic[2];
  out.opacity = opacity;
  out.depth = t[2];
  out.rect_x0 = std::int32_t(x0);
  out.rect_x1 = std::int32_t(x1);
  out.rect_y0 = std::int32_t(y0);
  out.rect_y1 = std::int32_t(y1);
  out.radius = std::int32_t(std::max(1.0, r));
  return CullReason::none;
}

// VJP of project_gaussian for a Gaussian it kept (radius > 0). Gradients of
// frozen groups are not computed: their outputs are left as they were. v_sh is
// written for k < K (k = 0 skipped when freeze.sh_dc, k >= 1 when freeze.sh_rest).
template <class Scalar>
inline void project_gaussian_vjp(const ProjectionCamera<Scalar>& cam, const GaussianParams<Scalar>& g,  // inputs
                                 const SplatGrad<Scalar>& v_out,                                     // grad outputs
                                 const Freeze& freeze,                                               //
                                 Scalar v_mean[3], Scalar v_quat[4], Scalar v_scale[3],              // grad inputs
                                 Scalar* v_opacity_logit, Scalar* v_sh) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  const bool want_mean = !freeze.means, want_cov3 = !(freeze.rotations && freeze.scales);
  const bool want_sh = !(freeze.sh_dc && freeze.sh_rest);

  if (!freeze.opacities) {
    const Scalar o = sigmoid(g.opacity_logit);
    *v_opacity_logit = v_out.v_opacity * o * (Scalar(1) - o);
  }

  Scalar v_dir[3] = {0, 0, 0};
  if (want_sh || want_mean) {
    const Scalar dir[3] = {g.mean[0] - cam.center[0], g.mean[1] - cam.center[1], g.mean[2] - cam.center[2]};
    const bool direct = !freeze.sh_dc && !freeze.sh_rest;
    Scalar buf[48];
    Scalar* vs = want_sh ? (direct ? v_sh : buf) : nullptr;
    sh_to_color_vjp(g.sh_degree, g.sh, dir, v_out.v_color, vs, want_mean ? v_dir : nullptr);
    if (want_sh && !direct) {
      const int k_count = sh_coefficient_count(g.sh_degree);
      if (!freeze.sh_dc)
        for (int c = 0; c < 3; ++c) v_sh[c] = buf[c];
      if (!freeze.sh_rest)
        for (int j = 3; j < 3 * k_count; ++j) v_sh[j] = buf[j];
    }
  }
  if (!want_mean && !want_cov3) return;

  const Vec3 x(g.mean[0], g.mean[1], g.mean[2]);
  const Vec3 tv = cam.R * x + cam.t;
  const Scalar t[3] = {tv[0], tv[1], tv[2]};
  Mat3 Rq, Sigma;
  quat_to_rotmat(g.quat, Rq);
  covariance3d(Rq, g.scale, Sigma);
  Scalar cov[3], conic[3];
  project_covariance(t, Sigma, cam.R, cam.fx, cam.fy, cam.lim_x, cam.lim_y, cam.eps2d, cov);
  inverse2x2(cov, conic);
  const Scalar v_conic[3] = {v_out.v_conic_a, v_out.v_conic_b, v_out.v_conic_c};
  Scalar v_cov[3];
  inverse2x2_vjp(conic, v_conic, v_cov);

  Scalar v_t[3] = {0, 0, 0};
  Mat3 v_Sigma;
  project_covariance_vjp(t, Sigma, cam.R, cam.fx, cam.fy, cam.lim_x, cam.lim_y, v_cov, want_mean ? v_t : nullptr,
                         want_cov3 ? &v_Sigma : nullptr);
  if (want_mean) {
    // u = fx t_x / t_z + cx, v = fy t_y / t_z + cy, depth = t_z
    const Scalar iz = Scalar(1) / t[2];
    v_t[0] += cam.fx * iz * v_out.v_mean_x;
    v_t[1] += cam.fy * iz * v_out.v_mean_y;
    v_t[2] += -(cam.fx * t[0] * v_out.v_mean_x + cam.fy * t[1] * v_out.v_mean_y) * iz * iz + v_out.v_depth;
    const Vec3 vx = cam.R.transpose() * Vec3(v_t[0], v_t[1], v_t[2]);
    for (int a = 0; a < 3; ++a) v_mean[a] = vx[a] + v_dir[a];
  }
  if (want_cov3) {
    Mat3 v_Rq;
    Scalar v_s[3];
    covariance3d_vjp(Rq, g.scale, v_Sigma, v_Rq, v_s);
    if (!freeze.scales)
      for (int a = 0; a < 3; ++a) v_scale[a] = v_s[a];
    if (!freeze.rotations) quat_to_rotmat_vjp(g.quat, v_Rq, v_quat);
  }
}

namespace detail {
// Reads Gaussian i from an adaptor; scale activated (exp for log-mode adaptors).
template <class Scene, class Scalar>
inline void gather_gaussian(const Scene& scene, std::size_t i, int degree, GaussianParams<Scalar>& g,
                            Scalar* sh_buf) {
  scene.mean(i, g.mean);
  scene.rotation(i, g.quat);
  scene.scale(i, g.scale);
  if (Scene::scale_mode == ScaleMode::log)
    for (int a = 0; a < 3; ++a) g.scale[a] = std::exp(g.scale[a]);
  g.opacity_logit = scene.opacity_logit(i);
  g.sh_degree = degree;
  const int k_count = sh_coefficient_count(degree);
  for (int k = 0; k < k_count; ++k)
    for (int c = 0; c < 3; ++c) sh_buf[3 * k + c] = scene.sh(i, k, c);
  g.sh = sh_buf;
}
}  // namespace detail

}  // namespace orbitforge

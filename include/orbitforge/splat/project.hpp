#pragma once
// Per-Gaussian stages of the renderer: EWA projection, culling, opacity and SH
// colour (forward: project_scene -> ProjectedSplats), and their VJP
// (project_scene_vjp: ProjectedSplatsGrad -> GaussianSceneGrad).
//
// ---------------------------------------------------------------------------
// Scenes are read through an adaptor (the contract, with its compile-time
// check: splat/scene_adaptor.hpp).
// SceneView<S> adapts a GaussianScene<S>; DeformedSceneView<S> renders the
// deformable state x + dx, normalize(q) + dq, exp(log s) + ds of a base scene
// without copying it. A host renderer writes its own adaptor over its storage.
// Gradients (project_scene_vjp) go into a GaussianSceneGrad, w.r.t. exactly what
// the adaptor returns, or into the caller's own arrays through a SceneGradView
// (splat/scene_grad_view.hpp), in the parametrisation the view asks for.
// ---------------------------------------------------------------------------
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
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/splat/scene_grad_view.hpp"
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
  const Scalar mid = Scalar(0.5) * (cov[0] + cov[2]);
  const Scalar lambda = mid + std::sqrt(std::max(Scalar(0), mid * mid - det));
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

// ---------------------------------------------------------------------------
// Adaptors.

namespace detail {
// Prefetches the cache lines of [p, p + bytes) (a hint). GCC's pure-const
// analysis sees no side effect in __builtin_prefetch, marks a function holding
// only prefetches const and deletes its calls; the volatile asm keeps them.
inline void prefetch_bytes(const void* p, std::size_t bytes) {
  const char* c = static_cast<const char*>(p);
  for (std::size_t o = 0; o < bytes; o += 64) {
#if (defined(__GNUC__) || defined(__clang__)) && (defined(__x86_64__) || defined(__i386__))
    asm volatile("prefetcht0 %0" : : "m"(c[o]));
#elif defined(__GNUC__) || defined(__clang__)
    __builtin_prefetch(c + o);
    asm volatile("" : : : "memory");
#else
    (void)c;
#endif
  }
}
}  // namespace detail

// A GaussianScene held by const reference (log-scales).
template <class Scalar>
class SceneView {
 public:
  using scalar_type = Scalar;
  static constexpr ScaleMode scale_mode = ScaleMode::log;

  explicit SceneView(const GaussianScene<Scalar>& s) : s_(s) { s.check_consistent(); }

  std::size_t size() const { return s_.size(); }
  int sh_degree() const { return s_.sh_degree; }
  void mean(std::size_t i, Scalar out[3]) const { copy_n(&s_.means[3 * i], 3, out); }
  void rotation(std::size_t i, Scalar out[4]) const { copy_n(&s_.rotations[4 * i], 4, out); }
  void scale(std::size_t i, Scalar out[3]) const { copy_n(&s_.log_scales[3 * i], 3, out); }
  Scalar opacity_logit(std::size_t i) const { return s_.opacity_logits[i]; }
  Scalar sh(std::size_t i, int k, int c) const { return s_.sh[(i * std::size_t(k_) + std::size_t(k)) * 3 + c]; }
  void prefetch(std::size_t first, std::size_t count) const {
    const std::size_t s1 = sizeof(Scalar);
    detail::prefetch_bytes(&s_.means[3 * first], 3 * count * s1);
    detail::prefetch_bytes(&s_.rotations[4 * first], 4 * count * s1);
    detail::prefetch_bytes(&s_.log_scales[3 * first], 3 * count * s1);
    detail::prefetch_bytes(&s_.opacity_logits[first], count * s1);
    detail::prefetch_bytes(&s_.sh[first * k_ * 3], 3 * k_ * count * s1);
  }

 private:
  static void copy_n(const Scalar* a, int n, Scalar* b) {
    for (int j = 0; j < n; ++j) b[j] = a[j];
  }
  const GaussianScene<Scalar>& s_;
  std::size_t k_ = std::size_t(s_.sh_coefficients());
};

// The deformed state of a base scene, as Deformable 3D Gaussians renders it:
//   mean = x + dx,  rotation = normalize(q) + dq  (normalised again by the projection),
//   scale = exp(log s) + ds  (ScaleOffset::additive: activated, any sign) or
//           exp(log s + ds)  (ScaleOffset::log),  opacity and SH of the base.
// dx [N][3], dq [N][4], ds [N][3] are caller-owned arrays; a null pointer means zero.
// The VJP w.r.t. this adaptor gives v_dx = grad.means, v_dq = grad.rotations and
// the activated-scale gradient in grad.log_scales (scale_offset_gradients() turns
// it into v_ds); base_gradients() chains to the base parameters.
template <class Scalar>
class DeformedSceneView {
 public:
  using scalar_type = Scalar;
  static constexpr ScaleMode scale_mode = ScaleMode::activated;

  DeformedSceneView(const GaussianScene<Scalar>& base, const Scalar* dx, const Scalar* dq, const Scalar* ds,
                    ScaleOffset scale_offset = ScaleOffset::additive)
      : b_(base), dx_(dx), dq_(dq), ds_(ds), mode_(scale_offset) {
    base.check_consistent();
  }

  std::size_t size() const { return b_.size(); }
  int sh_degree() const { return b_.sh_degree; }
  ScaleOffset scale_offset() const { return mode_; }
  void mean(std::size_t i, Scalar out[3]) const {
    for (int a = 0; a < 3; ++a) out[a] = b_.means[3 * i + a] + (dx_ ? dx_[3 * i + a] : Scalar(0));
  }
  void rotation(std::size_t i, Scalar out[4]) const {
    const Scalar* q = &b_.rotations[4 * i];
    const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int a = 0; a < 4; ++a) out[a] = q[a] * inv + (dq_ ? dq_[4 * i + a] : Scalar(0));
  }
  void scale(std::size_t i, Scalar out[3]) const {
    for (int a = 0; a < 3; ++a) {
      const Scalar l = b_.log_scales[3 * i + a], d = ds_ ? ds_[3 * i + a] : Scalar(0);
      out[a] = mode_ == ScaleOffset::log ? std::exp(l + d) : std::exp(l) + d;
    }
  }
  Scalar opacity_logit(std::size_t i) const { return b_.opacity_logits[i]; }
  Scalar sh(std::size_t i, int k, int c) const { return b_.sh[(i * std::size_t(k_) + std::size_t(k)) * 3 + c]; }

  // Gradients w.r.t. this view (from project_scene_vjp) -> gradients w.r.t. the base
  // scene (means, rotations through normalize(q), log-scales through exp; opacity and
  // SH unchanged). `base_grad` may be the same object as `view_grad`. Empty arrays
  // (frozen groups never sized) are skipped.
  void base_gradients(const GaussianSceneGrad<Scalar>& view_grad, GaussianSceneGrad<Scalar>& base_grad) const {
    const std::size_t n = size();
    if (&base_grad != &view_grad) base_grad = view_grad;
    if (base_grad.rotations.size() == 4 * n) {
      for (std::size_t i = 0; i < n; ++i) {
        const Scalar* q = &b_.rotations[4 * i];
        Scalar* v = &base_grad.rotations[4 * i];
        const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        Scalar dot = 0;
        for (int a = 0; a < 4; ++a) dot += q[a] * inv * v[a];
        for (int a = 0; a < 4; ++a) v[a] = (v[a] - q[a] * inv * dot) * inv;
      }
    }
    if (base_grad.log_scales.size() == 3 * n)
      for (std::size_t j = 0; j < 3 * n; ++j) {
        // d s' / d log s = exp(log s), times exp(ds) for relative offsets (= s').
        const Scalar d = (mode_ == ScaleOffset::log && ds_) ? ds_[j] : Scalar(0);
        base_grad.log_scales[j] *= std::exp(b_.log_scales[j] + d);
      }
  }

  // Gradient w.r.t. the scale offsets from the gradient w.r.t. this view's
  // (activated) scales: v_ds = v_s' (additive) or v_s' s' (log). [3 x N].
  void scale_offset_gradients(const GaussianSceneGrad<Scalar>& view_grad, Scalar* v_ds) const {
    const std::size_t n = size();
    ensure(view_grad.log_scales.size() == 3 * n, "DeformedSceneView: scale gradients for ",
           view_grad.log_scales.size() / 3, " Gaussians, the view has ", n);
    for (std::size_t j = 0; j < 3 * n; ++j)
      v_ds[j] = mode_ == ScaleOffset::log
                    ? view_grad.log_scales[j] * std::exp(b_.log_scales[j] + (ds_ ? ds_[j] : Scalar(0)))
                    : view_grad.log_scales[j];
  }

 private:
  const GaussianScene<Scalar>& b_;
  const Scalar *dx_, *dq_, *ds_;
  ScaleOffset mode_;
  std::size_t k_ = std::size_t(b_.sh_coefficients());
};

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

// ---------------------------------------------------------------------------
// The batch path of project_scene: simd::native_batch<Scalar>::size Gaussians at
// a time. Each lane's parameters are read through the adaptor into small
// structure-of-arrays buffers (any adaptor works), the projection runs in SIMD,
// and the results go to ProjectedSplats. project_gaussian stays the reference:
// the batch path gives the same culling reasons, radii and rectangles, and values
// within float rounding of it. Where a decision of the reference (near plane,
// opacity threshold, a ceil/floor of a rectangle bound or of the radius) lies
// within a bound on the rounding difference between the two (operations in
// another order, xsimd's exp and log for std's), project_gaussian makes that
// decision for the lane; where the 2D covariance is degenerate or overflows, or
// the scales overflow once activated, it gives the lane's values too. That is
// rare (about 2 in 100 Gaussians of the benchmark scene) and keeps the decisions
// identical.
namespace detail {

// Each lane's parameters as one row (mean 3, quaternion 4, scale 3 as the
// adaptor returns it, opacity logit, padding, SH [3 k + c]), then transposed
// block by block into one row per parameter and a column per lane.
template <class Scalar, int W>
struct GaussianLanes {
  static constexpr int kMean = 0, kQuat = 3, kScale = 7, kLogit = 10, kSh = 16, kRow = 64;
  alignas(64) Scalar aos[W][kRow];
  alignas(64) Scalar soa[kRow][W];
  const Scalar* operator[](int row) const { return soa[row]; }
};

// Lanes j < count <- Gaussians i0 + j; the other lanes get harmless values.
template <class B, class Scene, class Scalar, int W>
inline void gather_lanes(const Scene& scene, std::size_t i0, int count, int k_count,
                         GaussianLanes<Scalar, W>& L) {
  using G = GaussianLanes<Scalar, W>;
  for (int j = 0; j < count; ++j) {
    const std::size_t i = i0 + std::size_t(j);
    Scalar* row = L.aos[j];
    scene.mean(i, row + G::kMean);
    scene.rotation(i, row + G::kQuat);
    scene.scale(i, row + G::kScale);
    row[G::kLogit] = scene.opacity_logit(i);
    Scalar* sh = row + G::kSh;
    for (int k = 0; k < k_count; ++k)
      for (int c = 0; c < 3; ++c) sh[3 * k + c] = scene.sh(i, k, c);
  }
  for (int j = count; j < W; ++j)
    for (int r = 0; r < G::kRow; ++r) L.aos[j][r] = Scalar(r == G::kQuat);
  // Rows used: the parameters, then the SH rows.
  const int rows = G::kSh + 3 * k_count;
  for (int r0 = 0; r0 < rows; r0 += W) simd::transpose_block<B>(&L.aos[0][r0], G::kRow, &L.soa[r0][0], W);
}

// Distance from x to the nearest integer.
template <class B>
inline B dist_to_int(const B& x) { return simd::abs(x - simd::round_nearest(x)); }

// Outcome codes of a lane: CullReason values; kLaneScalar: project_gaussian
// gives everything (the batch values are unusable: overflow, degenerate 2D
// covariance); kLaneDecision: project_gaussian gives the decision (reason,
// radius, rectangle), the values are the batch's (so that they never depend on
// a decision, e.g. an image on tight_extents).
constexpr int kLaneScalar = 5, kLaneDecision = 6;

// GCC 12 reports -Wuninitialized inside avx512fintrin.h for xsimd's AVX-512
// kernels once inlined here (the unmasked intrinsics pass _mm512_undefined_*():
// a false positive).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif
// Projects Gaussians i0 .. i0 + count - 1 (count <= B::size) into `out`,
// counting reasons into local[5].
template <class B, class Scene>
inline void project_lanes(const Scene& scene, const ProjectionCamera<typename B::value_type>& cam, int degree,
                          std::size_t i0, int count, GaussianLanes<typename B::value_type, int(B::size)>& L,
                          ProjectedSplats<typename B::value_type>& out, std::size_t local[5]) {
  using Scalar = typename B::value_type;
  using M = simd::mask_t<B>;
  constexpr int W = int(B::size);
  const int k_count = sh_coefficient_count(degree);
  gather_lanes<B>(scene, i0, count, k_count, L);
  using G = GaussianLanes<Scalar, W>;

  const B zero(Scalar(0)), one(Scalar(1)), half(Scalar(0.5));
  // The rounding difference of a short chain of operations evaluated in another
  // order, relative to the sum of the magnitudes of its terms (4 units in the
  // last place; the bounds below are sums of such terms, so generous: in 10^6
  // random Gaussians even 1/64 of this let no decision differ).
  const B tol(Scalar(4) * std::numeric_limits<Scalar>::epsilon());
  auto ld = [](const Scalar* p) { return B::load_unaligned(p); };

  // Non-finite inputs (x * 0 is NaN only for NaN and inf): certain, as in
  // project_gaussian, which checks the activated scales (exp(-inf) = 0 is fine).
  B p0 = zero, p1 = zero, p2 = zero, p3 = zero;
  for (int a = 0; a < 3; ++a) p0 = p0 + ld(L[G::kMean + a]) * zero;
  for (int a = 0; a < 4; ++a) p1 = p1 + ld(L[G::kQuat + a]) * zero;
  p3 = p3 + ld(L[G::kLogit]) * zero;
  for (int r = 0; r < 3 * k_count; r += 4) {
    p0 = p0 + ld(L[G::kSh + r]) * zero;
    if (r + 1 < 3 * k_count) p1 = p1 + ld(L[G::kSh + r + 1]) * zero;
    if (r + 2 < 3 * k_count) p2 = p2 + ld(L[G::kSh + r + 2]) * zero;
    if (r + 3 < 3 * k_count) p3 = p3 + ld(L[G::kSh + r + 3]) * zero;
  }
  B s[3], raw_poison = zero, act_poison = zero;
  for (int a = 0; a < 3; ++a) {
    const B raw = ld(L[G::kScale + a]);
    s[a] = Scene::scale_mode == ScaleMode::log ? simd::exp(raw) : raw;
    raw_poison = raw_poison + raw * zero;
    act_poison = act_poison + s[a] * zero;
  }
  const M bad_act = ~(act_poison <= zero);
  const M bad_in = ~((p0 + p1) + (p2 + p3) <= zero) | (bad_act & ~(raw_poison <= zero));
  M decided = bad_in;
  // Finite log-scales whose exp overflows (at the threshold xsimd's exp and
  // std::exp may disagree): the reference decides.
  M scalar = ~bad_in & bad_act;
  decided = decided | scalar;
  // Lanes where m holds and nothing is decided yet go to the reference.
  auto defer = [&](const M& m) {
    const M d = ~decided & m;
    scalar = scalar | d;
    decided = decided | d;
  };

  // Camera space, and bounds on its rounding difference (et: absolute).
  const B x = ld(L[G::kMean]), y = ld(L[G::kMean + 1]), z = ld(L[G::kMean + 2]);
  B t[3], et[3];
  for (int k = 0; k < 3; ++k) {
    t[k] = B(cam.R(k, 0)) * x + B(cam.R(k, 1)) * y + B(cam.R(k, 2)) * z + B(cam.t[k]);
    et[k] = tol * (B(std::abs(cam.R(k, 0))) * simd::abs(x) + B(std::abs(cam.R(k, 1))) * simd::abs(y) +
                   B(std::abs(cam.R(k, 2))) * simd::abs(z) + B(std::abs(cam.t[k])));
  }
  const B near(cam.near_plane);
  defer(simd::abs(t[2] - near) <= et[2]);
  const M cull_near = ~decided & (t[2] <= near);
  decided = decided | cull_near;

  // Rotation of q / |q| and Sigma = (R diag(s)) (R diag(s))^T.
  B qw = ld(L[G::kQuat]), qx = ld(L[G::kQuat + 1]), qy = ld(L[G::kQuat + 2]), qz = ld(L[G::kQuat + 3]);
  const B qinv = one / simd::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  qw = qw * qinv; qx = qx * qinv; qy = qy * qinv; qz = qz * qinv;
  const B two(Scalar(2));
  B Mq[3][3];
  Mq[0][0] = (one - two * (qy * qy + qz * qz)) * s[0];
  Mq[0][1] = (two * (qx * qy - qw * qz)) * s[1];
  Mq[0][2] = (two * (qx * qz + qw * qy)) * s[2];
  Mq[1][0] = (two * (qx * qy + qw * qz)) * s[0];
  Mq[1][1] = (one - two * (qx * qx + qz * qz)) * s[1];
  Mq[1][2] = (two * (qy * qz - qw * qx)) * s[2];
  Mq[2][0] = (two * (qx * qz - qw * qy)) * s[0];
  Mq[2][1] = (two * (qy * qz + qw * qx)) * s[1];
  Mq[2][2] = (one - two * (qx * qx + qy * qy)) * s[2];
  B S[3][3];
  for (int r = 0; r < 3; ++r)
    for (int c = r; c < 3; ++c) S[r][c] = S[c][r] = Mq[r][0] * Mq[c][0] + Mq[r][1] * Mq[c][1] + Mq[r][2] * Mq[c][2];

  // EWA Jacobian with the x/z, y/z clamp; T = J W; cov2d = T Sigma T^T + eps2d I.
  const B iz = one / t[2], iz2 = iz * iz;
  const B lx(cam.lim_x), ly(cam.lim_y), fx(cam.fx), fy(cam.fy);
  const B clx = simd::min(lx, simd::max(-lx, t[0] * iz)), cly = simd::min(ly, simd::max(-ly, t[1] * iz));
  const B j00 = fx * iz, j02 = -fx * (clx * t[2]) * iz2, j11 = fy * iz, j12 = -fy * (cly * t[2]) * iz2;
  B T0[3], T1[3];
  for (int c = 0; c < 3; ++c) {
    T0[c] = j00 * B(cam.R(0, c)) + j02 * B(cam.R(2, c));
    T1[c] = j11 * B(cam.R(1, c)) + j12 * B(cam.R(2, c));
  }
  B TS0[3], TS1[3];
  for (int c = 0; c < 3; ++c) {
    TS0[c] = T0[0] * S[0][c] + T0[1] * S[1][c] + T0[2] * S[2][c];
    TS1[c] = T1[0] * S[0][c] + T1[1] * S[1][c] + T1[2] * S[2][c];
  }
  const B eps2d(cam.eps2d);
  const B cov0 = TS0[0] * T0[0] + TS0[1] * T0[1] + TS0[2] * T0[2] + eps2d;
  const B cov1 = TS0[0] * T1[0] + TS0[1] * T1[1] + TS0[2] * T1[2];
  const B cov2 = TS1[0] * T1[0] + TS1[1] * T1[1] + TS1[2] * T1[2] + eps2d;
  const B det = cov0 * cov2 - cov1 * cov1;
  const B idet = one / det;
  const B conic0 = cov2 * idet, conic1 = -cov1 * idet, conic2 = cov0 * idet;

  // Bounds on the rounding differences: rz relative in t_z; rJ relative in J
  // (w.r.t. its norm); ecov, edet absolute.
  const B rz = et[2] * iz;
  const B rJ = rz * (one + B(Scalar(3)) * simd::max(lx, ly)) + (et[0] + et[1]) * iz + tol;
  const B smax2 = simd::max(s[0] * s[0], simd::max(s[1] * s[1], s[2] * s[2]));
  const B ecov = smax2 * (j00 * j00 + j02 * j02 + j11 * j11 + j12 * j12) * (B(Scalar(4)) * rJ + B(Scalar(4)) * tol) +
                 tol * eps2d;
  const B acov1 = simd::abs(cov1);
  const B edet = ecov * (cov0 + cov2 + two * acov1) + tol * (cov0 * cov2 + cov1 * cov1);
  // Degenerate, non-finite or overflowing 2D covariances: the reference decides.
  const B big(std::numeric_limits<Scalar>::max() / Scalar(16));
  const M det_bad = ~((det > edet) & (det < big) & ((conic0 * zero + conic1 * zero + conic2 * zero) <= zero));
  defer(det_bad);

  const B o = one / (one + simd::exp(-ld(L[G::kLogit])));
  const B amin(cam.alpha_min);
  const B eo = tol * o;
  defer(simd::abs(o - amin) <= eo);
  const M cull_faint_o = ~decided & (o < amin);
  decided = decided | cull_faint_o;

  const B u = fx * t[0] * iz + B(cam.cx), v = fy * t[1] * iz + B(cam.cy);
  const B eu = two * fx * iz * (et[0] + simd::abs(t[0]) * rz) + tol * (simd::abs(u) + B(std::abs(cam.cx)));
  const B ev = two * fy * iz * (et[1] + simd::abs(t[1]) * rz) + tol * (simd::abs(v) + B(std::abs(cam.cy)));
  const B lim_int(Scalar(1 << 22));  // beyond: rectangle arithmetic left to the reference
  defer(~((simd::abs(u) < lim_int) & (simd::abs(v) < lim_int)));

  const B mid = half * (cov0 + cov2);
  const B disc = mid * mid - det;
  const B lambda = mid + simd::sqrt(simd::max(zero, disc));
  const B edisc = ecov * (cov0 + cov2) + edet + tol * (mid * mid + simd::abs(det));
  // |sqrt(a) - sqrt(b)| <= min(sqrt(|a - b|), |a - b| / sqrt(a)).
  const B elam = ecov + simd::min(simd::sqrt(edisc), edisc / simd::sqrt(simd::max(disc, zero))) + tol * lambda;
  const B sr = B(Scalar(3)) * simd::sqrt(lambda);
  const B esr = B(Scalar(3)) * elam / simd::sqrt(lambda) + tol * sr;
  defer(~(sr < lim_int) | (dist_to_int(sr) <= esr));
  const B r = simd::ceil(sr);

  // Pixel i is inside when |i + 0.5 - u| <= r.
  const B W1(Scalar(cam.width - 1)), H1(Scalar(cam.height - 1));
  const B X0 = u - r - half, X1 = u + r - half, Y0 = v - r - half, Y1 = v + r - half;
  const B ex = eu + tol * (simd::abs(u) + r), ey = ev + tol * (simd::abs(v) + r);
  defer(((dist_to_int(X0) <= ex) & (X0 > -one - ex)) | ((dist_to_int(X1) <= ex) & (X1 < W1 + one + ex)) |
        ((dist_to_int(Y0) <= ey) & (Y0 > -one - ey)) | ((dist_to_int(Y1) <= ey) & (Y1 < H1 + one + ey)));
  B x0 = simd::max(zero, simd::ceil(X0)), x1 = simd::min(W1, simd::floor(X1));
  B y0 = simd::max(zero, simd::ceil(Y0)), y1 = simd::min(H1, simd::floor(Y1));
  const M cull_outside = ~decided & ((x0 > x1) | (y0 > y1));
  decided = decided | cull_outside;

  M cull_faint = cull_faint_o;
  if (cam.tight_extents) {
    // alpha >= alpha_min only where d^T conic d <= 2 ln(o / alpha_min), with the
    // reference's slack.
    const B lo = simd::log(o / amin);
    const B tt = lo * B(Scalar(1 + 1e-3)) + B(Scalar(1e-3));
    const B ett = tol * (simd::abs(lo) + two);
    const B hx = simd::sqrt(two * tt * cov0), hy = simd::sqrt(two * tt * cov2);
    const B eh = half * (ett / tt + ecov / simd::min(cov0, cov2)) + tol;
    const B Xt0 = u - hx - half, Xt1 = u + hx - half, Yt0 = v - hy - half, Yt1 = v + hy - half;
    const B ext = eu + hx * eh + tol * (simd::abs(u) + hx), eyt = ev + hy * eh + tol * (simd::abs(v) + hy);
    defer(((dist_to_int(Xt0) <= ext) & (Xt0 > x0 - one - ext)) |
          ((dist_to_int(Xt1) <= ext) & (Xt1 < x1 + one + ext)) |
          ((dist_to_int(Yt0) <= eyt) & (Yt0 > y0 - one - eyt)) |
          ((dist_to_int(Yt1) <= eyt) & (Yt1 < y1 + one + eyt)));
    x0 = simd::max(x0, simd::ceil(Xt0));
    x1 = simd::min(x1, simd::floor(Xt1));
    y0 = simd::max(y0, simd::ceil(Yt0));
    y1 = simd::min(y1, simd::floor(Yt1));
    const M empty = ~decided & ((x0 > x1) | (y0 > y1));
    cull_faint = cull_faint | empty;
    decided = decided | empty;
  }

  // SH colour in the direction mean - camera centre, + 0.5, clamped at 0.
  using C = ShConstants<Scalar>;
  B cr = zero, cg = zero, cb = zero;
  auto acc = [&](int k, const B& basis) {
    cr = cr + basis * ld(L[G::kSh + 3 * k + 0]);
    cg = cg + basis * ld(L[G::kSh + 3 * k + 1]);
    cb = cb + basis * ld(L[G::kSh + 3 * k + 2]);
  };
  acc(0, B(C::C0));
  if (degree > 0) {
    const B dx = x - B(cam.center[0]), dy = y - B(cam.center[1]), dz = z - B(cam.center[2]);
    const B dinv = one / simd::sqrt(dx * dx + dy * dy + dz * dz);
    const B ux = dx * dinv, uy = dy * dinv, uz = dz * dinv;
    acc(1, -B(C::C1) * uy);
    acc(2, B(C::C1) * uz);
    acc(3, -B(C::C1) * ux);
    if (degree > 1) {
      const B xx = ux * ux, yy = uy * uy, zz = uz * uz, xy = ux * uy, yz = uy * uz, xz = ux * uz;
      acc(4, B(C::C2[0]) * xy);
      acc(5, B(C::C2[1]) * yz);
      acc(6, B(C::C2[2]) * (two * zz - xx - yy));
      acc(7, B(C::C2[3]) * xz);
      acc(8, B(C::C2[4]) * (xx - yy));
      if (degree > 2) {
        const B three(Scalar(3)), four(Scalar(4));
        acc(9, B(C::C3[0]) * uy * (three * xx - yy));
        acc(10, B(C::C3[1]) * xy * uz);
        acc(11, B(C::C3[2]) * uy * (four * zz - xx - yy));
        acc(12, B(C::C3[3]) * uz * (two * zz - three * xx - three * yy));
        acc(13, B(C::C3[4]) * ux * (four * zz - xx - yy));
        acc(14, B(C::C3[5]) * uz * (xx - yy));
        acc(15, B(C::C3[6]) * ux * (xx - three * yy));
      }
    }
  }
  cr = cr + half;
  cg = cg + half;
  cb = cb + half;
  cr = simd::select(cr < zero, zero, cr);
  cg = simd::select(cg < zero, zero, cg);
  cb = simd::select(cb < zero, zero, cb);

  // Outcome per lane.
  B code = simd::select(bad_in, B(Scalar(int(CullReason::nonfinite))), zero);
  code = simd::select(scalar, B(Scalar(kLaneDecision)), code);
  code = simd::select(scalar & (bad_act | det_bad), B(Scalar(kLaneScalar)), code);
  code = simd::select(cull_near, B(Scalar(int(CullReason::near))), code);
  code = simd::select(cull_faint, B(Scalar(int(CullReason::faint))), code);
  code = simd::select(cull_outside, B(Scalar(int(CullReason::outside))), code);
  const B radius = simd::max(one, r);

  // Values (unspecified for culled lanes): straight into `out` for whole batches.
  const B* vals[10] = {&u, &v, &conic0, &conic1, &conic2, &o, &cr, &cg, &cb, &t[2]};
  Scalar* dst[10] = {out.mean_x.data(), out.mean_y.data(), out.conic_a.data(), out.conic_b.data(),
                     out.conic_c.data(), out.opacity.data(), out.color_r.data(), out.color_g.data(),
                     out.color_b.data(), out.depth.data()};
  if (count == W) {
    for (int f = 0; f < 10; ++f) vals[f]->store_unaligned(dst[f] + i0);
  } else {
    alignas(64) Scalar buf[W];
    for (int f = 0; f < 10; ++f) {
      vals[f]->store_unaligned(buf);
      for (int j = 0; j < count; ++j) dst[f][i0 + std::size_t(j)] = buf[j];
    }
  }
  alignas(64) Scalar codes[W], rad[W], rx0[W], ry0[W], rx1[W], ry1[W];
  code.store_unaligned(codes);
  radius.store_unaligned(rad);
  x0.store_unaligned(rx0);
  y0.store_unaligned(ry0);
  x1.store_unaligned(rx1);
  y1.store_unaligned(ry1);
  for (int j = 0; j < count; ++j) {
    const std::size_t i = i0 + std::size_t(j);
    const int why = int(codes[j]);
    if (why >= kLaneScalar) {
      Scalar sh_buf[48];
      GaussianParams<Scalar> g;
      Splat<Scalar> sp;
      gather_gaussian(scene, i, degree, g, sh_buf);
      const CullReason w = project_gaussian(cam, g, sp);
      ++local[int(w)];
      out.radius[i] = sp.radius;
      if (w != CullReason::none) continue;
      out.rect_x0[i] = sp.rect_x0;
      out.rect_y0[i] = sp.rect_y0;
      out.rect_x1[i] = sp.rect_x1;
      out.rect_y1[i] = sp.rect_y1;
      if (why == kLaneDecision) continue;
      out.mean_x[i] = sp.mean_x;
      out.mean_y[i] = sp.mean_y;
      out.conic_a[i] = sp.conic_a;
      out.conic_b[i] = sp.conic_b;
      out.conic_c[i] = sp.conic_c;
      out.opacity[i] = sp.opacity;
      out.color_r[i] = sp.color[0];
      out.color_g[i] = sp.color[1];
      out.color_b[i] = sp.color[2];
      out.depth[i] = sp.depth;
      continue;
    }
    ++local[why];
    out.radius[i] = why == 0 ? std::int32_t(rad[j]) : 0;
    if (why != 0) continue;
    out.rect_x0[i] = std::int32_t(rx0[j]);
    out.rect_y0[i] = std::int32_t(ry0[j]);
    out.rect_x1[i] = std::int32_t(rx1[j]);
    out.rect_y1[i] = std::int32_t(ry1[j]);
  }
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
}  // namespace detail

// ---------------------------------------------------------------------------
// Projects every Gaussian of `scene` into `out` (resized to scene.size(); no
// reallocation when its capacity suffices). threads = 0: the default count.
template <class Scene>
void project_scene(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                   const ProjectionParams& params, ProjectedSplats<typename Scene::scalar_type>& out,
                   ProjectionStats* stats = nullptr, int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene: Scene is not a scene adaptor");
  using Scalar = typename Scene::scalar_type;
  const auto cam = ProjectionCamera<Scalar>::make(camera, params);
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();
  out.resize(n);
  const std::size_t chunk = std::max<std::size_t>(1, params.chunk);
  const std::size_t chunks = (n + chunk - 1) / chunk;
  std::atomic<std::size_t> counts[5] = {};
  parallel_for(chunks, threads, [&](std::size_t ci, int) {
    using B = simd::native_batch<Scalar>;
    constexpr std::size_t W = B::size;
    std::size_t local[5] = {0, 0, 0, 0, 0};
    detail::GaussianLanes<Scalar, int(W)> lanes{};
    const std::size_t end = std::min(n, (ci + 1) * chunk);
    constexpr std::size_t ahead = 4 * W;  // prefetch distance (adaptors that offer it)
    for (std::size_t i = ci * chunk; i < end; i += W) {
      if constexpr (adaptor_detail::has_prefetch<Scene>::value)
        if (i + ahead < n) scene.prefetch(i + ahead, std::min(W, n - (i + ahead)));
      detail::project_lanes<B>(scene, cam, degree, i, int(std::min(W, end - i)), lanes, out, local);
    }
    for (int r = 0; r < 5; ++r)
      if (local[r]) counts[r].fetch_add(local[r], std::memory_order_relaxed);
  });
  if (stats) {
    stats->visible = counts[0].load();
    stats->culled_near = counts[1].load();
    stats->culled_outside = counts[2].load();
    stats->culled_faint = counts[3].load();
    stats->culled_nonfinite = counts[4].load();
  }
}

namespace detail {
inline void check_vjp_inputs(std::size_t n, std::size_t fwd_size) {
  ensure(fwd_size == n, "project_scene_vjp: forward result has ", fwd_size, " Gaussians, scene has ", n);
}

// The VJP of project_scene into a gradient view. `freeze` says which groups are
// computed (derived from the view's null fields, plus the SH dc/rest split of
// GaussianSceneGrad's Freeze).
template <class Scene>
void project_scene_vjp_into(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                            const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                            const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                            const SceneGradView<typename Scene::scalar_type>& out, const Freeze& freeze,
                            int threads) {
  using Scalar = typename Scene::scalar_type;
  const auto cam = ProjectionCamera<Scalar>::make(camera, params);
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene_vjp: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();
  const int k_count = sh_coefficient_count(degree);
  check_vjp_inputs(n, fwd.size());
  ensure(out.size == n, "project_scene_vjp: the gradient view is for ", out.size, " Gaussians, the scene has ", n);
  for (const auto* v : {&v_in.v_mean_x, &v_in.v_mean_y, &v_in.v_conic_a, &v_in.v_conic_b, &v_in.v_conic_c,
                        &v_in.v_opacity, &v_in.v_color_r, &v_in.v_color_g, &v_in.v_color_b, &v_in.v_depth})
    ensure(v->size() == n, "project_scene_vjp: a ProjectedSplatsGrad array has ", v->size(), " entries, expected ",
           n);
  const Scalar half_w = Scalar(0.5) * Scalar(cam.width), half_h = Scalar(0.5) * Scalar(cam.height);
  const int sh_first = freeze.sh_dc ? 1 : 0, sh_end = freeze.sh_rest ? 1 : k_count;
  const bool xyzw = out.rotation_order == QuatOrder::xyzw;

  const std::size_t chunk = std::max<std::size_t>(1, params.chunk);
  const std::size_t chunks = (n + chunk - 1) / chunk;
  parallel_for(chunks, threads, [&](std::size_t ci, int) {
    Scalar sh_buf[48], v_sh[48];
    Scalar v_mean[3] = {0, 0, 0}, v_quat[4] = {0, 0, 0, 0}, v_scale[3] = {0, 0, 0}, v_logit = 0;
    GaussianParams<Scalar> g;
    SplatGrad<Scalar> vg;
    const std::size_t end = std::min(n, (ci + 1) * chunk);
    for (std::size_t i = ci * chunk; i < end; ++i) {
      const bool kept = fwd.radius[i] > 0;
      Scalar scale[3] = {0, 0, 0}, opacity = 0, screen = 0, screen_ndc = 0;
      if (kept) {
        gather_gaussian(scene, i, degree, g, sh_buf);
        vg.v_mean_x = v_in.v_mean_x[i];
        vg.v_mean_y = v_in.v_mean_y[i];
        vg.v_conic_a = v_in.v_conic_a[i];
        vg.v_conic_b = v_in.v_conic_b[i];
        vg.v_conic_c = v_in.v_conic_c[i];
        vg.v_opacity = v_in.v_opacity[i];
        vg.v_color[0] = v_in.v_color_r[i];
        vg.v_color[1] = v_in.v_color_g[i];
        vg.v_color[2] = v_in.v_color_b[i];
        vg.v_depth = v_in.v_depth[i];
        project_gaussian_vjp(cam, g, vg, freeze, v_mean, v_quat, v_scale, &v_logit, v_sh);
        for (int a = 0; a < 3; ++a) scale[a] = g.scale[a];
        opacity = vg.v_opacity;
        screen = std::sqrt(vg.v_mean_x * vg.v_mean_x + vg.v_mean_y * vg.v_mean_y);
        const Scalar nx = vg.v_mean_x * half_w, ny = vg.v_mean_y * half_h;
        screen_ndc = std::sqrt(nx * nx + ny * ny);
      }
      const Scalar z = Scalar(0);
      if (out.means)
        for (int a = 0; a < 3; ++a) out.means.at(i)[a] = kept ? v_mean[a] : z;
      if (out.rotations) {
        Scalar* q = out.rotations.at(i);
        for (int a = 0; a < 4; ++a) q[xyzw ? (a + 3) % 4 : a] = kept ? v_quat[a] : z;  // w goes last for xyzw
      }
      for (int a = 0; a < 3; ++a) {
        if (out.scales) out.scales.at(i)[a] = kept ? v_scale[a] : z;
        if (out.log_scales) out.log_scales.at(i)[a] = kept ? v_scale[a] * scale[a] : z;  // ds / dlog s = s
      }
      if (out.opacity_logits) *out.opacity_logits.at(i) = kept ? v_logit : z;
      if (out.opacities) *out.opacities.at(i) = kept ? opacity : z;
      if (out.sh) {
        char* base = reinterpret_cast<char*>(out.sh.at(i));
        for (int k = sh_first; k < sh_end; ++k) {
          Scalar* dst = reinterpret_cast<Scalar*>(base + std::ptrdiff_t(k) * out.sh_coefficient_stride_bytes);
          for (int c = 0; c < 3; ++c) dst[c] = kept ? v_sh[3 * k + c] : z;
        }
      }
      if (out.screen_grad_norm) *out.screen_grad_norm.at(i) = screen;
      if (out.screen_grad_ndc_norm) *out.screen_grad_ndc_norm.at(i) = screen_ndc;
    }
  });
}
}  // namespace detail

// Gradients into the caller's storage (splat/scene_grad_view.hpp), in the
// parametrisation the view asks for, given the forward result `fwd` (same scene,
// camera and params) and the rasterizer's gradients `v_in`.
template <class Scene>
void project_scene_vjp(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                       const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                       const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                       const SceneGradView<typename Scene::scalar_type>& out, int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene_vjp: Scene is not a scene adaptor");
  Freeze freeze;
  freeze.means = !out.means;
  freeze.rotations = !out.rotations;
  freeze.scales = !out.scales && !out.log_scales;
  freeze.opacities = !out.opacity_logits;  // d/d opacity needs no work
  freeze.sh_dc = freeze.sh_rest = !out.sh;
  detail::project_scene_vjp_into(scene, camera, params, fwd, v_in, out, freeze, threads);
}

// Gradients w.r.t. the scene parameters as the adaptor exposes them, into a
// GaussianSceneGrad (log_scales holds d/d log s for ScaleMode::log adaptors and
// d/d s for activated ones). Non-frozen groups of `out` are overwritten (zero for
// culled Gaussians); frozen groups are never written (see Freeze), only sized.
// screen_grad_norm and screen_grad_ndc_norm are always written.
template <class Scene>
void project_scene_vjp(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                       const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                       const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                       GaussianSceneGrad<typename Scene::scalar_type>& out, const Freeze& freeze = {},
                       int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene_vjp: Scene is not a scene adaptor");
  using Scalar = typename Scene::scalar_type;
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene_vjp: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();
  detail::check_vjp_inputs(n, fwd.size());
  const std::size_t sh_size = 3 * std::size_t(sh_coefficient_count(degree)) * n;
  auto prepare = [](std::vector<Scalar>& v, std::size_t size, bool frozen) {
    if (!frozen)
      v.resize(size);
    else if (v.size() != size)
      v.assign(size, Scalar(0));
  };
  out.sh_degree = degree;
  prepare(out.means, 3 * n, freeze.means);
  prepare(out.rotations, 4 * n, freeze.rotations);
  prepare(out.log_scales, 3 * n, freeze.scales);
  prepare(out.opacity_logits, n, freeze.opacities);
  prepare(out.sh, sh_size, freeze.sh_dc && freeze.sh_rest);
  if (out.sh.size() != sh_size) out.sh.assign(sh_size, Scalar(0));
  out.screen_grad_norm.resize(n);
  out.screen_grad_ndc_norm.resize(n);

  const std::ptrdiff_t s1 = sizeof(Scalar);
  SceneGradView<Scalar> view;
  view.size = n;
  if (!freeze.means) view.means = strided(out.means.data(), 3 * s1);
  if (!freeze.rotations) view.rotations = strided(out.rotations.data(), 4 * s1);
  if (!freeze.scales)
    (Scene::scale_mode == ScaleMode::log ? view.log_scales : view.scales) = strided(out.log_scales.data(), 3 * s1);
  if (!freeze.opacities) view.opacity_logits = strided(out.opacity_logits.data(), s1);
  if (!(freeze.sh_dc && freeze.sh_rest))
    view.sh = strided(out.sh.data(), std::ptrdiff_t(sh_size / std::max<std::size_t>(1, n)) * s1);
  view.screen_grad_norm = strided(out.screen_grad_norm.data(), s1);
  view.screen_grad_ndc_norm = strided(out.screen_grad_ndc_norm.data(), s1);
  detail::project_scene_vjp_into(scene, camera, params, fwd, v_in, view, freeze, threads);
}

}  // namespace orbitforge

#pragma once
// Bundle adjustment of source cameras with soft orbit priors.
//
// Why: on a short arc (~125 degrees) of a generated, not quite rigid video,
// COLMAP's cameras can under-rotate after some frame (registration drift), and
// a frame matched by few points can sit off the arc. The canonical orbit
// extrapolates the source arc to 360 degrees, so both errors grow there. This
// refines the cameras against their own 2D observations and, softly, against
// the orbit the method assumes anyway (orbit.hpp).
//
// Design:
//  - The orbit (centre c, normal n, radius r, look-at L) comes from fit_orbit on
//    the input cameras and is held fixed, with the target height h0 = mean
//    height of the input centres above c and the target roll = mean of
//    right . n. Held fixed, not refined: fit_orbit's centre, normal, radius
//    and look-at are robust to drift along the arc (a drifted arc keeps its
//    centres on the circle and its axes through L), and a fixed orbit keeps the
//    problem small and its gauge simple.
//  - Residuals (each whitened by its sigma):
//      reprojection, pixels, Huber loss (scale huber_px), solved by IRLS;
//      radius: (in-plane |C - c| - r) / r;  height: ((C - c) . n - h0) / r;
//      look-at: L in the camera's normalised image plane (x/z, y/z), i.e. the
//        tangent of the angle between the optical axis and L;
//      roll: right . n - target (no roll change about the optical axis, the
//        one pose direction the other priors leave free);
//      acceleration: second difference of consecutive azimuths about c
//        (radians): a smooth angular speed, without fixing its value.
//    All priors are scale-free (divided by r, or angles).
//  - Per-frame weight: the priors of frame i are scaled by
//    alpha_i = 1 / (1 + n_i / prior_reference_observations), n_i = its
//    observation count; an acceleration term takes the largest alpha of its
//    three frames. A frame seen by hundreds of points keeps its own pose, a
//    frame seen by a handful follows the orbit.
//  - Gauge: camera hold_camera (default the first) is held fixed; with the
//    priors, which fix scale and position through r and c, the only exact
//    invariance left is a rotation about the orbit axis, and holding a camera
//    removes it. With hold_camera = -1 nothing is held and the LM damping
//    alone keeps the step finite.
//  - Solver: Levenberg-Marquardt in double whatever Scalar is: the points are
//    eliminated per point (3x3 blocks, Schur complement) and the reduced
//    camera system (6 per free camera, dense; ~200 unknowns for 33 frames) is
//    solved by LDLT. Perturbations: R <- Exp(w) R (w in camera axes), C <- C + dC,
//    X <- X + dX, with x_cam = R (X - C).
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/orbit.hpp"

namespace orbitforge {

// One 2D observation: point `point` seen by camera `camera` at pixel `xy`
// (orbitforge's pixel convention, = COLMAP's).
template <class Scalar>
struct BundleObservation {
  int camera = 0;
  int point = 0;
  Eigen::Matrix<Scalar, 2, 1> xy = Eigen::Matrix<Scalar, 2, 1>::Zero();
};

struct OrbitBundleParams {
  double huber_px = 2.0;  // reprojection error above which the loss grows linearly
  // Prior sigmas; 0 turns a prior off. Set from the recorded videos' COLMAP
  // cameras (circle RMSE and height std ~0.001-0.005 r, look-at error ~0.05
  // degrees, angular steps within ~+-0.3 degrees of the median).
  double sigma_radius = 0.003;      // of r
  double sigma_height = 0.003;      // of r
  double sigma_lookat_deg = 0.1;
  double sigma_roll_deg = 0.5;
  double sigma_accel_deg = 0.3;     // second difference of azimuths
  double prior_reference_observations = 30;  // n_i at which a frame's priors weigh half
  int hold_camera = 0;                       // -1: hold none
  int max_iterations = 100;
  double relative_tolerance = 1e-10;  // stop when a step lowers the cost by less than this fraction
  OrbitParams orbit;                  // for fit_orbit on the input cameras
};

template <class Scalar>
struct OrbitBundleResult {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  std::vector<Camera<Scalar>> cameras;
  std::vector<Vec3> points;
  std::vector<double> rotation_change_deg;  // per camera: angle of R_out R_in^T
  std::vector<double> center_shift;         // per camera: |C_out - C_in| / r
  std::vector<int> observations;            // per camera: observations used
  std::vector<double> prior_weight;         // per camera: alpha_i
  OrbitGeometry<double> orbit;              // the orbit the priors used
  double height = 0;                        // h0 (scene units)
  double initial_cost = 0, final_cost = 0;  // 0.5 sum of whitened, robustified squares
  double initial_rms_px = 0, final_rms_px = 0;  // reprojection RMS over the observations used
  int iterations = 0;                       // accepted LM steps
  int dropped_observations = 0;             // behind their camera at the start
  bool converged = false;
};

namespace detail {

template <class T>
Eigen::Matrix<T, 3, 3> ba_skew(const Eigen::Matrix<T, 3, 1>& v) {
  Eigen::Matrix<T, 3, 3> m;
  m << T(0), -v.z(), v.y(), v.z(), T(0), -v.x(), -v.y(), v.x(), T(0);
  return m;
}

// Residual blocks with their Jacobians at zero perturbation (see the header
// comment for the perturbation convention). Templated so the tests can check
// them in float and double against finite differences.
template <class T>
struct BaProjection {
  Eigen::Matrix<T, 2, 1> e = Eigen::Matrix<T, 2, 1>::Zero();  // predicted - observed
  Eigen::Matrix<T, 2, 6> J_cam = Eigen::Matrix<T, 2, 6>::Zero();  // d e / d (w, C)
  Eigen::Matrix<T, 2, 3> J_point = Eigen::Matrix<T, 2, 3>::Zero();
  bool in_front = false;
};

// e = (fx x/z + cx, fy y/z + cy) - xy with (x, y, z) = R (X - C). With fx = fy
// = 1, cx = cy = 0 and xy = 0 it is the look-at residual of X = L.
template <class T>
BaProjection<T> ba_projection(const Eigen::Matrix<T, 3, 3>& R, const Eigen::Matrix<T, 3, 1>& C,
                              const Eigen::Matrix<T, 3, 1>& X, T fx, T fy, T cx, T cy,
                              const Eigen::Matrix<T, 2, 1>& xy) {
  BaProjection<T> b;
  const Eigen::Matrix<T, 3, 1> y = R * (X - C);
  b.in_front = y.z() > T(1e-6) * (X - C).norm();
  if (!b.in_front) return b;
  const T iz = T(1) / y.z();
  b.e = Eigen::Matrix<T, 2, 1>(fx * y.x() * iz + cx, fy * y.y() * iz + cy) - xy;
  Eigen::Matrix<T, 2, 3> dp;
  dp << fx * iz, T(0), -fx * y.x() * iz * iz, T(0), fy * iz, -fy * y.y() * iz * iz;
  b.J_cam.template leftCols<3>() = -dp * ba_skew(y);
  b.J_cam.template rightCols<3>() = -dp * R;
  b.J_point = dp * R;
  return b;
}

template <class T>
struct BaScalarResidual {
  T value = 0;
  Eigen::Matrix<T, 1, 3> J = Eigen::Matrix<T, 1, 3>::Zero();
};

// In-plane distance of C from the centre minus r (scene units) and its
// gradient in C.
template <class T>
BaScalarResidual<T> ba_radius(const Eigen::Matrix<T, 3, 1>& C, const Eigen::Matrix<T, 3, 1>& center,
                              const Eigen::Matrix<T, 3, 1>& normal, T radius) {
  const Eigen::Matrix<T, 3, 1> d = C - center;
  const Eigen::Matrix<T, 3, 1> p = d - normal * normal.dot(d);
  const T rho = p.norm();
  BaScalarResidual<T> r;
  r.value = rho - radius;
  if (rho > T(0)) r.J = (p / rho).transpose();
  return r;
}

template <class T>
BaScalarResidual<T> ba_height(const Eigen::Matrix<T, 3, 1>& C, const Eigen::Matrix<T, 3, 1>& center,
                              const Eigen::Matrix<T, 3, 1>& normal, T height) {
  BaScalarResidual<T> r;
  r.value = (C - center).dot(normal) - height;
  r.J = normal.transpose();
  return r;
}

// right . n - target, gradient in w (the rotation perturbation).
template <class T>
BaScalarResidual<T> ba_roll(const Eigen::Matrix<T, 3, 3>& R, const Eigen::Matrix<T, 3, 1>& normal, T target) {
  BaScalarResidual<T> r;
  r.value = R.row(0).dot(normal.transpose()) - target;
  // Exp(w) R ~ (I + [w]x) R: row 0 gains -w_z R.row(1) + w_y R.row(2).
  r.J << T(0), R.row(2).dot(normal.transpose()), -R.row(1).dot(normal.transpose());
  return r;
}

// Azimuth (radians) of C about the centre in the (e1, e2) frame, gradient in C.
template <class T>
BaScalarResidual<T> ba_azimuth(const Eigen::Matrix<T, 3, 1>& C, const Eigen::Matrix<T, 3, 1>& center,
                               const Eigen::Matrix<T, 3, 1>& e1, const Eigen::Matrix<T, 3, 1>& e2) {
  const Eigen::Matrix<T, 3, 1> d = C - center;
  const T a = d.dot(e1), b = d.dot(e2);
  BaScalarResidual<T> r;
  r.value = std::atan2(b, a);
  const T q = a * a + b * b;
  if (q > T(0)) r.J = ((a * e2 - b * e1) / q).transpose();
  return r;
}

template <class T>
T ba_wrap_pi(T x) {
  const T two_pi = T(2) * Constants<T>::pi();
  x = std::fmod(x + Constants<T>::pi(), two_pi);
  if (x < T(0)) x += two_pi;
  return x - Constants<T>::pi();
}

// Second difference of the azimuths of three consecutive centres (radians),
// each step wrapped to (-pi, pi]; gradients in C0, C1, C2.
template <class T>
struct BaAccel {
  T value = 0;
  Eigen::Matrix<T, 1, 3> J[3];
};

template <class T>
BaAccel<T> ba_accel(const Eigen::Matrix<T, 3, 1>& C0, const Eigen::Matrix<T, 3, 1>& C1,
                    const Eigen::Matrix<T, 3, 1>& C2, const Eigen::Matrix<T, 3, 1>& center,
                    const Eigen::Matrix<T, 3, 1>& e1, const Eigen::Matrix<T, 3, 1>& e2) {
  const auto a0 = ba_azimuth(C0, center, e1, e2), a1 = ba_azimuth(C1, center, e1, e2),
             a2 = ba_azimuth(C2, center, e1, e2);
  BaAccel<T> r;
  r.value = ba_wrap_pi(a2.value - a1.value) - ba_wrap_pi(a1.value - a0.value);
  r.J[0] = a0.J;
  r.J[1] = -T(2) * a1.J;
  r.J[2] = a2.J;
  return r;
}

// Huber: cost 0.5 rho(|e|^2) and the IRLS weight at |e|.
inline double ba_huber_cost(double sq, double delta) {
  if (delta <= 0 || sq <= delta * delta) return 0.5 * sq;
  return delta * std::sqrt(sq) - 0.5 * delta * delta;
}
inline double ba_huber_weight(double sq, double delta) {
  if (delta <= 0 || sq <= delta * delta) return 1.0;
  return delta / std::sqrt(sq);
}

// The whole problem in double.
struct OrbitBaProblem {
  using Vec2 = Eigen::Vector2d;
  using Vec3 = Eigen::Vector3d;
  using Mat3 = Eigen::Matrix3d;
  std::vector<Mat3> R;
  std::vector<Vec3> C;
  std::vector<Intrinsics<double>> K;
  std::vector<Vec3> X;
  std::vector<BundleObservation<double>> obs;  // only those in front at the start
  std::vector<double> alpha;                   // per camera
  OrbitGeometry<double> orbit;
  double height = 0, roll = 0;
  OrbitBundleParams p;

  double w_radius() const { return p.sigma_radius > 0 ? 1.0 / (p.sigma_radius * orbit.radius) : 0.0; }
  double w_height() const { return p.sigma_height > 0 ? 1.0 / (p.sigma_height * orbit.radius) : 0.0; }
  double w_lookat() const { return p.sigma_lookat_deg > 0 ? 1.0 / Constants<double>::deg2rad(p.sigma_lookat_deg) : 0.0; }
  double w_roll() const { return p.sigma_roll_deg > 0 ? 1.0 / Constants<double>::deg2rad(p.sigma_roll_deg) : 0.0; }
  double w_accel() const { return p.sigma_accel_deg > 0 ? 1.0 / Constants<double>::deg2rad(p.sigma_accel_deg) : 0.0; }
  double accel_alpha(std::size_t i) const { return std::max({alpha[i - 1], alpha[i], alpha[i + 1]}); }

  BaProjection<double> project(std::size_t k, const std::vector<Mat3>& Rs, const std::vector<Vec3>& Cs,
                               const std::vector<Vec3>& Xs) const {
    const auto& o = obs[k];
    const auto& k_ = K[std::size_t(o.camera)];
    return ba_projection<double>(Rs[std::size_t(o.camera)], Cs[std::size_t(o.camera)], Xs[std::size_t(o.point)],
                                 k_.fx, k_.fy, k_.cx, k_.cy, o.xy);
  }

  // Total cost; +infinity when a point falls behind a camera. sq_px: sum of
  // squared reprojection errors.
  double cost(const std::vector<Mat3>& Rs, const std::vector<Vec3>& Cs, const std::vector<Vec3>& Xs,
              double* sq_px = nullptr) const {
    double c = 0, sq = 0;
    for (std::size_t k = 0; k < obs.size(); ++k) {
      const auto b = project(k, Rs, Cs, Xs);
      if (!b.in_front) return std::numeric_limits<double>::infinity();
      const double s = b.e.squaredNorm();
      sq += s;
      c += ba_huber_cost(s, p.huber_px);
    }
    if (sq_px) *sq_px = sq;
    const Vec2 zero = Vec2::Zero();
    for (std::size_t i = 0; i < Rs.size(); ++i) {
      const double a = alpha[i];
      const double rr = w_radius() * ba_radius<double>(Cs[i], orbit.center, orbit.normal, orbit.radius).value;
      const double hh = w_height() * ba_height<double>(Cs[i], orbit.center, orbit.normal, height).value;
      const auto la = ba_projection<double>(Rs[i], Cs[i], orbit.look_at, 1, 1, 0, 0, zero);
      const double ll = la.in_front ? w_lookat() * w_lookat() * la.e.squaredNorm() : 0.0;
      const double ro = w_roll() * ba_roll<double>(Rs[i], orbit.normal, roll).value;
      c += 0.5 * a * (rr * rr + hh * hh + ll + ro * ro);
    }
    for (std::size_t i = 1; i + 1 < Rs.size(); ++i) {
      const double v = w_accel() * ba_accel<double>(Cs[i - 1], Cs[i], Cs[i + 1], orbit.center, orbit.e1, orbit.e2).value;
      c += 0.5 * accel_alpha(i) * v * v;
    }
    return c;
  }
};

}  // namespace detail

// Refines `cameras` and `points` from `observations` with the orbit priors
// (see the header comment). Cameras are in source-frame order (the
// acceleration prior relates consecutive ones).
template <class Scalar>
OrbitBundleResult<Scalar> orbit_bundle_adjust(const std::vector<Camera<Scalar>>& cameras,
                                              const std::vector<Eigen::Matrix<Scalar, 3, 1>>& points,
                                              const std::vector<BundleObservation<Scalar>>& observations,
                                              const OrbitBundleParams& params = {}) {
  using Vec3 = Eigen::Vector3d;
  using Mat3 = Eigen::Matrix3d;
  using Vec6 = Eigen::Matrix<double, 6, 1>;
  const std::size_t n_cam = cameras.size(), n_pt = points.size();
  ensure(n_cam >= 3, "orbit_bundle_adjust: need at least 3 cameras, got ", n_cam);
  ensure(params.hold_camera >= -1 && params.hold_camera < int(n_cam), "orbit_bundle_adjust: hold_camera ",
         params.hold_camera, " outside -1..", n_cam - 1);
  ensure(params.huber_px >= 0 && params.prior_reference_observations > 0 && params.max_iterations >= 0,
         "orbit_bundle_adjust: huber_px, prior_reference_observations and max_iterations must be >= 0 (> 0)");
  detail::OrbitBaProblem pb;
  pb.p = params;
  std::vector<FrameCamera<double>> frames;
  for (std::size_t i = 0; i < n_cam; ++i) {
    const Camera<double> c = cameras[i].template cast<double>();
    ensure(c.is_finite() && c.intrinsics.fx > 0 && c.intrinsics.fy > 0, "orbit_bundle_adjust: camera ", i,
           " is not finite or has no positive focal length");
    pb.R.push_back(c.R);
    pb.C.push_back(c.center());
    pb.K.push_back(c.intrinsics);
    frames.push_back({std::to_string(i), c, true});
  }
  for (std::size_t j = 0; j < n_pt; ++j) {
    pb.X.push_back(points[j].template cast<double>());
    ensure(pb.X.back().allFinite(), "orbit_bundle_adjust: point ", j, " is not finite");
  }

  OrbitParams op = params.orbit;
  const OrbitFit<double> fit = fit_orbit(frames, op);
  ensure(fit.diagnostics.cameras_used == int(n_cam), "orbit_bundle_adjust: fit_orbit skipped ",
         n_cam - std::size_t(fit.diagnostics.cameras_used), " of the cameras (not proper rotations?)");
  pb.orbit = fit.orbit;
  pb.orbit.elevation_offset_deg = 0;
  for (std::size_t i = 0; i < n_cam; ++i) {
    pb.height += (pb.C[i] - pb.orbit.center).dot(pb.orbit.normal) / double(n_cam);
    pb.roll += pb.R[i].row(0).dot(pb.orbit.normal.transpose()) / double(n_cam);
  }

  OrbitBundleResult<Scalar> res;
  res.observations.assign(n_cam, 0);
  for (std::size_t k = 0; k < observations.size(); ++k) {
    const auto& o = observations[k];
    ensure(o.camera >= 0 && std::size_t(o.camera) < n_cam && o.point >= 0 && std::size_t(o.point) < n_pt,
           "orbit_bundle_adjust: observation ", k, " refers to camera ", o.camera, " / point ", o.point, " (have ",
           n_cam, " / ", n_pt, ")");
    BundleObservation<double> d{o.camera, o.point, o.xy.template cast<double>()};
    ensure(d.xy.allFinite(), "orbit_bundle_adjust: observation ", k, " has a non-finite pixel position");
    pb.obs.push_back(d);
    if (!pb.project(pb.obs.size() - 1, pb.R, pb.C, pb.X).in_front) {
      pb.obs.pop_back();
      ++res.dropped_observations;
      continue;
    }
    ++res.observations[std::size_t(o.camera)];
  }
  for (std::size_t i = 0; i < n_cam; ++i)
    pb.alpha.push_back(1.0 / (1.0 + res.observations[i] / params.prior_reference_observations));

  // Free cameras -> slots of the reduced system; observations grouped by point.
  std::vector<int> slot(n_cam, -1);
  int n_free = 0;
  for (std::size_t i = 0; i < n_cam; ++i)
    if (int(i) != params.hold_camera) slot[i] = n_free++;
  const int dim = 6 * n_free;
  std::vector<std::vector<int>> by_point(n_pt);
  for (std::size_t k = 0; k < pb.obs.size(); ++k) by_point[std::size_t(pb.obs[k].point)].push_back(int(k));

  double sq = 0;
  double cost = pb.cost(pb.R, pb.C, pb.X, &sq);
  ensure(std::isfinite(cost), "orbit_bundle_adjust: the initial cost is not finite");
  res.initial_cost = cost;
  res.initial_rms_px = pb.obs.empty() ? 0.0 : std::sqrt(sq / double(pb.obs.size()));
  double lambda = 1e-4;

  Eigen::MatrixXd Hcc(dim, dim);
  Eigen::VectorXd bc(dim);
  std::vector<Mat3> Hpp(n_pt);
  std::vector<Vec3> bp(n_pt);
  std::vector<Eigen::Matrix<double, 6, 3>> Hcp(pb.obs.size());
  const Eigen::Vector2d zero2 = Eigen::Vector2d::Zero();

  for (int it = 0; it < params.max_iterations; ++it) {
    // Linearise (IRLS weights at the current residuals).
    Hcc.setZero();
    bc.setZero();
    for (auto& h : Hpp) h.setZero();
    for (auto& b : bp) b.setZero();
    for (std::size_t k = 0; k < pb.obs.size(); ++k) {
      const auto& o = pb.obs[k];
      const auto b = pb.project(k, pb.R, pb.C, pb.X);
      const double w = detail::ba_huber_weight(b.e.squaredNorm(), params.huber_px);
      const std::size_t j = std::size_t(o.point);
      Hpp[j] += w * b.J_point.transpose() * b.J_point;
      bp[j] += w * b.J_point.transpose() * b.e;
      const int s = slot[std::size_t(o.camera)];
      if (s < 0) {
        Hcp[k].setZero();
        continue;
      }
      Hcc.block<6, 6>(6 * s, 6 * s) += w * b.J_cam.transpose() * b.J_cam;
      bc.segment<6>(6 * s) += w * b.J_cam.transpose() * b.e;
      Hcp[k] = w * b.J_cam.transpose() * b.J_point;
    }
    // Priors on single cameras: rows are (value, 1x6 Jacobian in (w, C)).
    auto add_row = [&](int s, double weight, double value, const Eigen::Matrix<double, 1, 6>& J) {
      Hcc.block<6, 6>(6 * s, 6 * s) += weight * J.transpose() * J;
      bc.segment<6>(6 * s) += weight * J.transpose() * value;
    };
    for (std::size_t i = 0; i < n_cam; ++i) {
      const int s = slot[i];
      if (s < 0) continue;
      const double a = pb.alpha[i];
      Eigen::Matrix<double, 1, 6> J;
      const auto rr = detail::ba_radius<double>(pb.C[i], pb.orbit.center, pb.orbit.normal, pb.orbit.radius);
      J << 0, 0, 0, rr.J;
      add_row(s, a * pb.w_radius() * pb.w_radius(), rr.value, J);
      const auto hh = detail::ba_height<double>(pb.C[i], pb.orbit.center, pb.orbit.normal, pb.height);
      J << 0, 0, 0, hh.J;
      add_row(s, a * pb.w_height() * pb.w_height(), hh.value, J);
      const auto ro = detail::ba_roll<double>(pb.R[i], pb.orbit.normal, pb.roll);
      J << ro.J, 0, 0, 0;
      add_row(s, a * pb.w_roll() * pb.w_roll(), ro.value, J);
      const auto la = detail::ba_projection<double>(pb.R[i], pb.C[i], pb.orbit.look_at, 1, 1, 0, 0, zero2);
      if (la.in_front)
        for (int r = 0; r < 2; ++r) add_row(s, a * pb.w_lookat() * pb.w_lookat(), la.e[r], la.J_cam.row(r));
    }
    for (std::size_t i = 1; i + 1 < n_cam; ++i) {
      const auto ac = detail::ba_accel<double>(pb.C[i - 1], pb.C[i], pb.C[i + 1], pb.orbit.center, pb.orbit.e1,
                                               pb.orbit.e2);
      const double wgt = pb.accel_alpha(i) * pb.w_accel() * pb.w_accel();
      for (int u = 0; u < 3; ++u) {
        const int su = slot[i - 1 + std::size_t(u)];
        if (su < 0) continue;
        bc.segment<3>(6 * su + 3) += wgt * ac.J[u].transpose() * ac.value;
        for (int v = 0; v < 3; ++v) {
          const int sv = slot[i - 1 + std::size_t(v)];
          if (sv < 0) continue;
          Hcc.block<3, 3>(6 * su + 3, 6 * sv + 3) += wgt * ac.J[u].transpose() * ac.J[v];
        }
      }
    }

    // Damped steps until one lowers the cost.
    bool accepted = false, stop = false;
    for (int attempt = 0; attempt < 12 && !accepted; ++attempt) {
      Eigen::MatrixXd S = Hcc;
      for (int r = 0; r < dim; ++r) S(r, r) += lambda * (Hcc(r, r) + 1e-9);
      Eigen::VectorXd g = bc;
      std::vector<Mat3> Hinv(n_pt);
      for (std::size_t j = 0; j < n_pt; ++j) {
        if (by_point[j].empty()) continue;
        Mat3 H = Hpp[j];
        for (int r = 0; r < 3; ++r) H(r, r) += lambda * (Hpp[j](r, r) + 1e-9);
        Hinv[j] = H.inverse();
        const auto& ks = by_point[j];
        for (int ka : ks) {
          const int sa = slot[std::size_t(pb.obs[std::size_t(ka)].camera)];
          if (sa < 0) continue;
          const Eigen::Matrix<double, 6, 3> A = Hcp[std::size_t(ka)] * Hinv[j];
          g.segment<6>(6 * sa) -= A * bp[j];
          for (int kb : ks) {
            const int sb = slot[std::size_t(pb.obs[std::size_t(kb)].camera)];
            if (sb < 0) continue;
            S.block<6, 6>(6 * sa, 6 * sb) -= A * Hcp[std::size_t(kb)].transpose();
          }
        }
      }
      const Eigen::VectorXd dc = S.ldlt().solve(-g);
      if (!dc.allFinite()) {
        lambda *= 10;
        continue;
      }
      std::vector<Mat3> R2 = pb.R;
      std::vector<Vec3> C2 = pb.C, X2 = pb.X;
      for (std::size_t i = 0; i < n_cam; ++i) {
        const int s = slot[i];
        if (s < 0) continue;
        const Vec6 d = dc.segment<6>(6 * s);
        const Vec3 w = d.head<3>();
        const double angle = w.norm();
        if (angle > 0) R2[i] = Eigen::AngleAxisd(angle, w / angle).toRotationMatrix() * pb.R[i];
        C2[i] += d.tail<3>();
      }
      for (std::size_t j = 0; j < n_pt; ++j) {
        if (by_point[j].empty()) continue;
        Vec3 rhs = bp[j];
        for (int ka : by_point[j]) {
          const int sa = slot[std::size_t(pb.obs[std::size_t(ka)].camera)];
          if (sa >= 0) rhs += Hcp[std::size_t(ka)].transpose() * dc.segment<6>(6 * sa);
        }
        X2[j] -= Hinv[j] * rhs;
      }
      double sq2 = 0;
      const double c2 = pb.cost(R2, C2, X2, &sq2);
      if (std::isfinite(c2) && c2 < cost) {
        const double gain = (cost - c2) / std::max(cost, 1e-300);
        pb.R = std::move(R2);
        pb.C = std::move(C2);
        pb.X = std::move(X2);
        cost = c2;
        sq = sq2;
        lambda = std::max(lambda / 3, 1e-12);
        accepted = true;
        ++res.iterations;
        if (gain < params.relative_tolerance) stop = true;
      } else {
        lambda *= 4;
      }
    }
    if (!accepted || stop) {
      res.converged = true;  // no step lowers the cost any further (a local minimum)
      break;
    }
  }

  res.final_cost = cost;
  res.final_rms_px = pb.obs.empty() ? 0.0 : std::sqrt(sq / double(pb.obs.size()));
  res.orbit = pb.orbit;
  res.height = pb.height;
  res.prior_weight = pb.alpha;
  for (std::size_t i = 0; i < n_cam; ++i) {
    Camera<Scalar> c = cameras[i];
    if (slot[i] < 0) {  // the held camera, bit for bit
      res.cameras.push_back(c);
      res.rotation_change_deg.push_back(0);
      res.center_shift.push_back(0);
      continue;
    }
    // Re-orthonormalise the accumulated rotation before casting.
    const Mat3 R = Eigen::Quaterniond(pb.R[i]).normalized().toRotationMatrix();
    c.R = R.template cast<Scalar>();
    c.t = (-R * pb.C[i]).template cast<Scalar>();
    res.cameras.push_back(c);
    const Mat3 dR = R * cameras[i].R.template cast<double>().transpose();
    res.rotation_change_deg.push_back(Constants<double>::rad2deg(Eigen::AngleAxisd(dR).angle()));
    res.center_shift.push_back((pb.C[i] - cameras[i].center().template cast<double>()).norm() / pb.orbit.radius);
  }
  for (const auto& x : pb.X) res.points.push_back(x.template cast<Scalar>());
  return res;
}

}  // namespace orbitforge

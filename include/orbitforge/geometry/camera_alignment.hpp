#pragma once
// Similarity alignment of two estimates of the same cameras (Umeyama's least
// squares on the camera centres), checked on their rotations.
//
// Two camera estimators (COLMAP on the source frames alone, COLMAP on every
// frame) agree at best up to a similarity: each picks its own origin, axes and
// scale. `align_camera_centres(from, to)` finds x_to = s R x_from + t minimising
// the squared centre distances, then says how far the pair still disagrees:
//   centre residual   RMS distance after alignment, also relative to the RMS
//                     spread of the `to` centres about their mean (scale-free);
//   rotation residual angle between each `to` camera orientation and the aligned
//                     `from` one. The centres alone do not fix rotations, so a
//                     large value says the two estimates disagree in a way no
//                     similarity removes (a mirrored or rolled model).
// The fit runs in double whatever Scalar is: centres far from the origin (a
// georeferenced model) lose the residual's digits in float.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <Eigen/Eigenvalues>
#include <Eigen/SVD>  // Eigen::umeyama
#include <algorithm>
#include <cmath>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

// x' = scale * R * x + t.
struct Similarity3 {
  double scale = 1;
  Eigen::Matrix3d R = Eigen::Matrix3d::Identity();
  Eigen::Vector3d t = Eigen::Vector3d::Zero();

  Eigen::Vector3d apply(const Eigen::Vector3d& x) const { return scale * (R * x) + t; }

  // The same physical camera in the target frame: its centre moves with the
  // similarity, its axes turn with R, its intrinsics stay.
  template <class Scalar>
  Camera<Scalar> apply(const Camera<Scalar>& c) const {
    const Camera<double> d = c.template cast<double>();
    const Eigen::Matrix3d world_R_camera = R * d.R.transpose();
    return Camera<double>::from_world_T_camera(world_R_camera, apply(d.center()), d.intrinsics)
        .template cast<Scalar>();
  }
};

struct CameraAlignment {
  Similarity3 transform;           // from -> to
  int cameras = 0;                 // pairs used
  double centre_rms = 0;           // in the `to` frame's units
  double centre_rms_relative = 0;  // centre_rms / RMS spread of the `to` centres
  double rotation_mean_deg = 0, rotation_max_deg = 0;
  std::vector<double> rotation_deg;  // per pair, in input order
};

// Rotation angle of R_a^T R_b, in degrees: how far two orientations differ.
// atan2 of the sine (from the skew part) and the cosine (from the trace) keeps
// full precision near 0, where acos of the trace alone loses half the digits.
inline double rotation_angle_deg(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  const Eigen::Matrix3d d = a.transpose() * b;
  const Eigen::Vector3d skew(d(2, 1) - d(1, 2), d(0, 2) - d(2, 0), d(1, 0) - d(0, 1));
  return std::atan2(skew.norm() / 2, (d.trace() - 1) / 2) * 180.0 / Constants<double>::pi();
}

// Aligns `from` onto `to` (parallel lists of the same frames' cameras). Needs at
// least three pairs whose `to` centres are not all on one line.
template <class Scalar>
CameraAlignment align_camera_centres(const std::vector<Camera<Scalar>>& from, const std::vector<Camera<Scalar>>& to) {
  ensure(from.size() == to.size(), "align_camera_centres: ", from.size(), " cameras against ", to.size());
  const int n = int(from.size());
  ensure(n >= 3, "align_camera_centres: need at least 3 camera pairs, got ", n);
  Eigen::Matrix3Xd src(3, n), dst(3, n);
  for (int i = 0; i < n; ++i) {
    ensure(from[std::size_t(i)].is_finite() && to[std::size_t(i)].is_finite(), "align_camera_centres: camera pair ",
           i, " is not finite");
    src.col(i) = from[std::size_t(i)].template cast<double>().center();
    dst.col(i) = to[std::size_t(i)].template cast<double>().center();
  }
  const Eigen::Vector3d mean_dst = dst.rowwise().mean();
  const double spread = std::sqrt((dst.colwise() - mean_dst).squaredNorm() / n);
  const Eigen::Vector3d mean_src = src.rowwise().mean();
  const double spread_src = std::sqrt((src.colwise() - mean_src).squaredNorm() / n);
  ensure(spread > 0 && spread_src > 0, "align_camera_centres: the camera centres of one side coincide");
  // Two singular values of the centred centres must be non-zero (they span at
  // least a plane). They are the square roots of the scatter's eigenvalues, which
  // resolve ratios down to about 1e-8 in double, hence the 1e-6 threshold.
  const Eigen::Matrix3Xd centred = dst.colwise() - mean_dst;
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> scatter(centred * centred.transpose(),
                                                                Eigen::EigenvaluesOnly);
  const Eigen::Vector3d lambda = scatter.eigenvalues().cwiseMax(0.0);  // ascending
  ensure(std::sqrt(lambda(1)) > 1e-6 * std::sqrt(lambda(2)),
         "align_camera_centres: the target camera centres lie on one line; the rotation about it is not fixed");

  const Eigen::Matrix4d T = Eigen::umeyama(src, dst, true);
  CameraAlignment a;
  a.cameras = n;
  a.transform.R = T.topLeftCorner<3, 3>();
  a.transform.scale = std::cbrt(a.transform.R.determinant());
  a.transform.R /= a.transform.scale;
  a.transform.t = T.topRightCorner<3, 1>();
  double sq = 0;
  for (int i = 0; i < n; ++i) {
    sq += (a.transform.apply(Eigen::Vector3d(src.col(i))) - dst.col(i)).squaredNorm();
    const Camera<Scalar> moved = a.transform.apply(from[std::size_t(i)]);
    const double deg = rotation_angle_deg(moved.R.template cast<double>(), to[std::size_t(i)].R.template cast<double>());
    a.rotation_deg.push_back(deg);
    a.rotation_mean_deg += deg / n;
    a.rotation_max_deg = std::max(a.rotation_max_deg, deg);
  }
  a.centre_rms = std::sqrt(sq / n);
  a.centre_rms_relative = a.centre_rms / spread;
  return a;
}

}  // namespace orbitforge

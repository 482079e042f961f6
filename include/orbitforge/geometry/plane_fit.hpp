#pragma once
// Orbit plane by SVD of the centred camera centres (paper, "Orbit Plane and
// Circle Fitting"): the two dominant right-singular vectors span the plane, the
// smallest is the normal n.
//
// Normal sign (the paper: agree with the average camera up):
//   "camera_up"  when |n . mean_up| >= up_threshold (0.2), n . mean_up > 0, where
//                mean_up is the plain mean of the cameras' unit up vectors (so
//                rolls that cancel out shrink it, and the rule hands over);
//   "look_down"  otherwise (cameras rolled ~90 degrees, as in dinoSparseRing):
//                n points to the side the cameras look down from, i.e. the
//                cameras' mean forward has a negative component along n
//                (cameras above the object, looking down along -n);
//   "ambiguous"  when also |n . mean_forward| < 1e-3 (rolled cameras exactly in
//                the plane of their target): the sign is then fixed only by a
//                deterministic rule (largest |component| of n positive).
// The basis is completed right-handed: e2 = n x e1.
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <cmath>
#include <string>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

struct PlaneFitParams {
  double up_threshold = 0.2;        // |n . mean_up| at which the camera-up rule decides
  double forward_threshold = 1e-3;  // |n . mean_forward| below which look_down is ambiguous
  // Singular-value ratios s2/s1 below which the centres are collinear, and the
  // absolute spread (relative to the centroid's magnitude) below which they coincide.
  double collinear_ratio = 1e-6;
};

template <class Scalar>
struct PlaneFit {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  Vec3 centroid = Vec3::Zero();  // o-bar
  Vec3 e1 = Vec3::UnitX(), e2 = Vec3::UnitY(), normal = Vec3::UnitZ();
  Eigen::Matrix<Scalar, 3, 1> singular_values = Eigen::Matrix<Scalar, 3, 1>::Zero();
  Scalar height_std = 0;       // std of signed heights (o - o-bar) . n
  std::string normal_rule;     // "camera_up", "look_down" or "ambiguous"
  // In-plane coordinates (u, v) and height of a point.
  Eigen::Matrix<Scalar, 2, 1> to_plane(const Vec3& p) const {
    const Vec3 d = p - centroid;
    return {d.dot(e1), d.dot(e2)};
  }
  Scalar height(const Vec3& p) const { return (p - centroid).dot(normal); }
};

template <class Scalar>
PlaneFit<Scalar> fit_plane(const std::vector<Eigen::Matrix<Scalar, 3, 1>>& points,
                           const Eigen::Matrix<Scalar, 3, 1>& mean_up,
                           const Eigen::Matrix<Scalar, 3, 1>& mean_forward,
                           const PlaneFitParams& params = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  const auto T = points.size();
  ensure(T >= 3, "fit_plane: need at least 3 camera centres, got ", T);
  PlaneFit<Scalar> pf;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  for (const auto& p : points) {
    ensure(p.allFinite(), "fit_plane: non-finite camera centre");
    centroid += p.template cast<double>();
  }
  centroid /= double(T);
  pf.centroid = centroid.cast<Scalar>();
  // The singular values of the centred T x 3 matrix X are the square roots of the
  // eigenvalues of X^T X (3x3, in double): the same plane as an SVD of X, through
  // a fixed-size solver that compiles in a fraction of the time.
  Eigen::Matrix3d XtX = Eigen::Matrix3d::Zero();
  for (const auto& p : points) {
    const Eigen::Vector3d d = p.template cast<double>() - centroid;
    XtX += d * d.transpose();
  }
  const Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(XtX);  // eigenvalues ascending
  const Eigen::Vector3d lambda = es.eigenvalues().cwiseMax(0.0);
  const Vec3 s(Scalar(std::sqrt(lambda(2))), Scalar(std::sqrt(lambda(1))), Scalar(std::sqrt(lambda(0))));
  pf.singular_values = s;
  const Scalar scale = std::max(Scalar(1), pf.centroid.cwiseAbs().maxCoeff());
  ensure(s(0) > Scalar(100) * Constants<Scalar>::epsilon() * scale * std::sqrt(Scalar(T)),
         "fit_plane: all ", T, " camera centres coincide; no orbit plane");
  const Scalar floor = std::max(Scalar(params.collinear_ratio), Scalar(100) * Constants<Scalar>::epsilon());
  ensure(s(1) >= floor * s(0), "fit_plane: the ", T, " camera centres are collinear (singular values ", s(0),
         ", ", s(1), "); no orbit plane");
  pf.e1 = es.eigenvectors().col(2).cast<Scalar>().normalized();
  Vec3 n = es.eigenvectors().col(0).cast<Scalar>().normalized();

  const Scalar up_dot = n.dot(mean_up);
  if (std::abs(up_dot) >= Scalar(params.up_threshold)) {
    pf.normal_rule = "camera_up";
    if (up_dot < 0) n = -n;
  } else if (std::abs(n.dot(mean_forward)) >= Scalar(params.forward_threshold)) {
    pf.normal_rule = "look_down";
    if (n.dot(mean_forward) > 0) n = -n;
  } else {
    pf.normal_rule = "ambiguous";
    int k = 0;
    n.cwiseAbs().maxCoeff(&k);
    if (n(k) < 0) n = -n;
  }
  pf.normal = n;
  pf.e2 = n.cross(pf.e1).normalized();
  pf.e1 = pf.e2.cross(n).normalized();  // exact orthonormality after rounding
  Scalar h2 = 0, hm = 0;
  for (const auto& p : points) hm += pf.height(p);
  hm /= Scalar(T);
  for (const auto& p : points) h2 += (pf.height(p) - hm) * (pf.height(p) - hm);
  pf.height_std = std::sqrt(h2 / Scalar(T));
  return pf;
}

}  // namespace orbitforge

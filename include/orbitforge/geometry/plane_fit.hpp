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
#include <Eigen/SVD>
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
  using MatX3 = Eigen::Matrix<Scalar, Eigen::Dynamic, 3>;
  const auto T = points.size();
  ensure(T >= 3, "fit_plane: need at least 3 camera centres, got ", T);
  PlaneFit<Scalar> pf;
  for (const auto& p : points) {
    ensure(p.allFinite(), "fit_plane: non-finite camera centre");
    pf.centroid += p;
  }
  pf.centroid /= Scalar(T);
  MatX3 X(T, 3);
  for (std::size_t i = 0; i < T; ++i) X.row(i) = (points[i] - pf.centroid).transpose();
  Eigen::JacobiSVD<MatX3> svd(X, Eigen::ComputeFullV);  // V is 3x3: "thin" is only for dynamic columns
  pf.singular_values = svd.singularValues();
  const Vec3 s = svd.singularValues();
  const Scalar scale = std::max(Scalar(1), pf.centroid.cwiseAbs().maxCoeff());
  ensure(s(0) > Scalar(100) * Constants<Scalar>::epsilon() * scale * std::sqrt(Scalar(T)),
         "fit_plane: all ", T, " camera centres coincide; no orbit plane");
  const Scalar floor = std::max(Scalar(params.collinear_ratio), Scalar(100) * Constants<Scalar>::epsilon());
  ensure(s(1) >= floor * s(0), "fit_plane: the ", T, " camera centres are collinear (singular values ", s(0),
         ", ", s(1), "); no orbit plane");
  pf.e1 = svd.matrixV().col(0).normalized();
  Vec3 n = svd.matrixV().col(2).normalized();

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

#pragma once
// Least-squares ray intersection (the paper's Eq. lookat-fit):
//
//   x_look = argmin_x  sum_t || (I - d_t d_t^T) (x - o_t) ||^2
//          => [sum_t (I - d_t d_t^T)] x = sum_t (I - d_t d_t^T) o_t .
//
// The 3x3 matrix is singular when every ray is parallel (the point then slides
// along the common direction). We refuse to solve when its smallest eigenvalue
// is below `min_eigen_ratio` times its largest: for T rays spread over an angle
// alpha the smallest eigenvalue is about T alpha^2 / 4 and the largest about T,
// so the default ratio 1e-6 rejects bundles whose directions all lie within
// ~0.1 degree of each other (the point would be pinned down only to ~1000x the
// camera spacing). Float raises the floor to 100 machine epsilons.
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <algorithm>
#include <cmath>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

struct LookAtParams {
  double min_eigen_ratio = 1e-6;  // see the header comment
};

template <class Scalar>
struct LookAtFit {
  Eigen::Matrix<Scalar, 3, 1> point = Eigen::Matrix<Scalar, 3, 1>::Zero();
  Scalar eigen_ratio = 0;      // smallest / largest eigenvalue of sum (I - d d^T)
  Scalar mean_angle_deg = 0;   // mean angle between each ray and the direction to `point`
};

// Mean angle (degrees) between each ray d_t and the direction from o_t to `point`.
// A ray that points away from the point scores near 180 degrees, so the sign of
// the forward axis matters here although it does not in the least-squares fit.
template <class Scalar>
Scalar mean_ray_angle_deg(const std::vector<Eigen::Matrix<Scalar, 3, 1>>& origins,
                          const std::vector<Eigen::Matrix<Scalar, 3, 1>>& directions,
                          const Eigen::Matrix<Scalar, 3, 1>& point) {
  ensure(origins.size() == directions.size() && !origins.empty(),
         "mean_ray_angle_deg: need as many directions as origins (got ", origins.size(), " and ",
         directions.size(), ")");
  Scalar sum = 0;
  for (std::size_t i = 0; i < origins.size(); ++i) {
    const Eigen::Matrix<Scalar, 3, 1> to = point - origins[i];
    const Scalar n = to.norm(), dn = directions[i].norm();
    if (!(n > 0) || !(dn > 0)) continue;  // a camera sitting on the point sees it at angle 0
    // atan2 of |cross| and dot is accurate at small and large angles alike.
    const Scalar c = to.dot(directions[i]) / (n * dn);
    const Scalar s = to.cross(directions[i]).norm() / (n * dn);
    sum += Constants<Scalar>::rad2deg(std::atan2(s, c));
  }
  return sum / Scalar(origins.size());
}

// Solves Eq. lookat-fit. Directions need not be unit length (they are normalised).
// Throws Error for fewer than two rays, non-finite input, or near-parallel rays.
template <class Scalar>
LookAtFit<Scalar> fit_lookat_point(const std::vector<Eigen::Matrix<Scalar, 3, 1>>& origins,
                                   const std::vector<Eigen::Matrix<Scalar, 3, 1>>& directions,
                                   const LookAtParams& params = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  ensure(origins.size() == directions.size(), "fit_lookat_point: ", origins.size(), " origins but ",
         directions.size(), " directions");
  ensure(origins.size() >= 2, "fit_lookat_point: need at least 2 rays, got ", origins.size());
  // Centre the origins so that large world offsets (1e6) do not swamp the system.
  Vec3 mean = Vec3::Zero();
  for (const auto& o : origins) {
    ensure(o.allFinite(), "fit_lookat_point: non-finite ray origin");
    mean += o;
  }
  mean /= Scalar(origins.size());
  Mat3 A = Mat3::Zero();
  Vec3 b = Vec3::Zero();
  for (std::size_t i = 0; i < origins.size(); ++i) {
    ensure(directions[i].allFinite(), "fit_lookat_point: non-finite ray direction ", i);
    const Scalar dn = directions[i].norm();
    ensure(dn > Constants<Scalar>::small(), "fit_lookat_point: ray ", i, " has zero direction");
    const Vec3 d = directions[i] / dn;
    const Mat3 P = Mat3::Identity() - d * d.transpose();
    A += P;
    b += P * (origins[i] - mean);
  }
  Eigen::SelfAdjointEigenSolver<Mat3> es(A);
  const Vec3 ev = es.eigenvalues();  // ascending
  const Scalar ratio = ev(0) / ev(2);
  const Scalar floor = std::max(Scalar(params.min_eigen_ratio), Scalar(100) * Constants<Scalar>::epsilon());
  ensure(std::isfinite(ratio) && ratio >= floor,
         "fit_lookat_point: the ", origins.size(),
         " rays are nearly parallel (eigenvalue ratio ", ratio, " < ", floor,
         "); the look-at point is undefined");
  LookAtFit<Scalar> fit;
  // Solve in the eigenbasis (A is symmetric positive definite here).
  const Vec3 y = es.eigenvectors().transpose() * b;
  fit.point = mean + es.eigenvectors() * y.cwiseQuotient(ev);
  fit.eigen_ratio = ratio;
  fit.mean_angle_deg = mean_ray_angle_deg(origins, directions, fit.point);
  return fit;
}

}  // namespace orbitforge

#pragma once
// Circle fits in the orbit plane.
//
//  kasa:      the paper's linear least squares (Eq. circle-fit)
//               2 a u + 2 b v + gamma ~= u^2 + v^2,  r = sqrt(a^2 + b^2 + gamma).
//             Minimises algebraic, not geometric, distance: biased towards small
//             radii on short noisy arcs.
//  geometric: orthogonal-distance fit, min sum (|p - c| - r)^2, by
//             Levenberg-Marquardt started from the Kasa solution.
// Both work on coordinates centred on the mean and scaled to unit RMS spread,
// so offsets and units do not matter. bench/bench_circle_fit.cpp sweeps arc
// length and noise: the geometric fit is the more accurate one and the default.
#include <Eigen/Core>
#include <Eigen/Cholesky>
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

enum class CircleFitMethod { kasa, geometric };

inline const char* circle_fit_method_name(CircleFitMethod m) {
  return m == CircleFitMethod::kasa ? "kasa" : "geometric";
}

struct CircleFitParams {
  CircleFitMethod method = CircleFitMethod::geometric;
  int max_iterations = 100;         // Levenberg-Marquardt
  double relative_tolerance = 1e-12;  // stop when the step is this small (relative to the spread)
  // Smallest / largest eigenvalue of the points' 2x2 scatter below which they are
  // collinear (a circle through them is undefined).
  double collinear_ratio = 1e-10;
};

template <class Scalar>
struct Circle2 {
  Eigen::Matrix<Scalar, 2, 1> center = Eigen::Matrix<Scalar, 2, 1>::Zero();
  Scalar radius = 0;
  Scalar rmse = 0;        // sqrt(mean (|p - c| - r)^2)
  Scalar radius_std = 0;  // std of |p - c|
  int iterations = 0;     // LM iterations (0 for Kasa)
};

namespace detail {

template <class Scalar>
struct NormalisedPoints {
  Eigen::Matrix<Scalar, 2, 1> mean;
  Scalar scale = 1;  // RMS distance to the mean
  std::vector<Eigen::Matrix<Scalar, 2, 1>> q;
};

template <class Scalar>
NormalisedPoints<Scalar> normalise_points(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& p,
                                          const CircleFitParams& params, const char* who) {
  using Vec2 = Eigen::Matrix<Scalar, 2, 1>;
  ensure(p.size() >= 3, who, ": need at least 3 points for a circle, got ", p.size());
  NormalisedPoints<Scalar> n;
  n.mean.setZero();
  for (const auto& x : p) {
    ensure(x.allFinite(), who, ": non-finite point");
    n.mean += x;
  }
  n.mean /= Scalar(p.size());
  Eigen::Matrix<Scalar, 2, 2> S = Eigen::Matrix<Scalar, 2, 2>::Zero();
  for (const auto& x : p) {
    const Vec2 d = x - n.mean;
    S += d * d.transpose();
  }
  S /= Scalar(p.size());
  const Scalar tr = S.trace();
  const Scalar mscale = std::max(Scalar(1), n.mean.cwiseAbs().maxCoeff());
  ensure(std::sqrt(tr) > Scalar(100) * Constants<Scalar>::epsilon() * mscale,
         who, ": all ", p.size(), " points coincide; no circle");
  // Eigenvalues of the symmetric 2x2 scatter.
  const Scalar det = S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0);
  const Scalar disc = std::sqrt(std::max(Scalar(0), tr * tr / 4 - det));
  const Scalar lmax = tr / 2 + disc, lmin = std::max(Scalar(0), tr / 2 - disc);
  const Scalar floor = std::max(Scalar(params.collinear_ratio), Scalar(1000) * Constants<Scalar>::epsilon());
  ensure(lmin >= floor * lmax, who, ": the ", p.size(), " points are collinear (scatter eigenvalues ", lmax,
         ", ", lmin, "); no circle");
  n.scale = std::sqrt(tr);
  n.q.reserve(p.size());
  for (const auto& x : p) n.q.push_back((x - n.mean) / n.scale);
  return n;
}

template <class Scalar>
void circle_residual_stats(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& p, Circle2<Scalar>& c) {
  Scalar se = 0, sd = 0, sd2 = 0;
  for (const auto& x : p) {
    const Scalar d = (x - c.center).norm();
    se += (d - c.radius) * (d - c.radius);
    sd += d;
  }
  const Scalar md = sd / Scalar(p.size());
  for (const auto& x : p) {
    const Scalar d = (x - c.center).norm();
    sd2 += (d - md) * (d - md);
  }
  c.rmse = std::sqrt(se / Scalar(p.size()));
  c.radius_std = std::sqrt(sd2 / Scalar(p.size()));
}

// Kasa on normalised points; returns (a, b, r) in normalised units. The
// least-squares system [2x 2y 1] (a b c)^T = x^2 + y^2 is solved through its 3x3
// normal equations in double, with two steps of refinement on the residual
// (corrected semi-normal equations): as accurate as a QR of the T x 3 matrix on
// normalised points, and a fixed-size solve compiles in a fraction of the time.
template <class Scalar>
Eigen::Matrix<Scalar, 3, 1> kasa_normalised(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& q, const char* who) {
  Eigen::Matrix3d M = Eigen::Matrix3d::Zero();
  for (const auto& p : q) {
    const Eigen::Vector3d a(2 * double(p.x()), 2 * double(p.y()), 1.0);
    M += a * a.transpose();
  }
  const Eigen::LDLT<Eigen::Matrix3d> ldlt(M);
  Eigen::Vector3d x = Eigen::Vector3d::Zero();
  for (int pass = 0; pass < 3; ++pass) {
    Eigen::Vector3d g = Eigen::Vector3d::Zero();  // A^T (b - A x)
    for (const auto& p : q) {
      const Eigen::Vector3d a(2 * double(p.x()), 2 * double(p.y()), 1.0);
      g += a * (double(p.x()) * double(p.x()) + double(p.y()) * double(p.y()) - a.dot(x));
    }
    x += ldlt.solve(g);
  }
  const double r2 = x(0) * x(0) + x(1) * x(1) + x(2);
  ensure(x.allFinite() && r2 > 0, who, ": the linear circle fit has no real radius (points nearly collinear)");
  return {Scalar(x(0)), Scalar(x(1)), Scalar(std::sqrt(r2))};
}

}  // namespace detail

// The paper's linear least-squares circle (Kasa).
template <class Scalar>
Circle2<Scalar> fit_circle_kasa(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& points,
                                const CircleFitParams& params = {}) {
  const auto n = detail::normalise_points(points, params, "fit_circle_kasa");
  const auto x = detail::kasa_normalised(n.q, "fit_circle_kasa");
  Circle2<Scalar> c;
  c.center = n.mean + n.scale * x.template head<2>();
  c.radius = n.scale * x(2);
  detail::circle_residual_stats(points, c);
  return c;
}

// Orthogonal-distance circle by Levenberg-Marquardt from the Kasa start.
template <class Scalar>
Circle2<Scalar> fit_circle_geometric(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& points,
                                     const CircleFitParams& params = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  const auto n = detail::normalise_points(points, params, "fit_circle_geometric");
  Vec3 x = detail::kasa_normalised(n.q, "fit_circle_geometric");
  auto cost_of = [&](const Vec3& y) {
    Scalar s = 0;
    for (const auto& q : n.q) {
      const Scalar r = (q - y.template head<2>()).norm() - y(2);
      s += r * r;
    }
    return s;
  };
  Scalar cost = cost_of(x);
  Scalar lambda = Scalar(1e-3);
  int it = 0;
  for (; it < params.max_iterations; ++it) {
    Mat3 JtJ = Mat3::Zero();
    Vec3 Jtr = Vec3::Zero();
    for (const auto& q : n.q) {
      const Eigen::Matrix<Scalar, 2, 1> d = q - x.template head<2>();
      const Scalar dist = d.norm();
      if (!(dist > Constants<Scalar>::small())) continue;  // a point at the centre has no gradient
      Vec3 J;
      J << -d.x() / dist, -d.y() / dist, Scalar(-1);
      const Scalar r = dist - x(2);
      JtJ += J * J.transpose();
      Jtr += J * r;
    }
    bool accepted = false;
    Vec3 step = Vec3::Zero();
    for (int tries = 0; tries < 20 && !accepted; ++tries) {
      Mat3 H = JtJ;
      H.diagonal() += lambda * JtJ.diagonal().cwiseMax(Scalar(1e-12));
      step = H.ldlt().solve(-Jtr);
      if (!step.allFinite()) break;
      const Vec3 trial = x + step;
      const Scalar c2 = cost_of(trial);
      if (c2 <= cost && trial(2) > 0) {
        x = trial;
        cost = c2;
        lambda = std::max(lambda / 10, Scalar(1e-12));
        accepted = true;
      } else {
        lambda *= 10;
      }
    }
    if (!accepted || step.norm() < Scalar(params.relative_tolerance) ||
        step.norm() < Scalar(10) * Constants<Scalar>::epsilon())
      break;
  }
  Circle2<Scalar> c;
  c.center = n.mean + n.scale * x.template head<2>();
  c.radius = n.scale * x(2);
  c.iterations = it;
  ensure(c.center.allFinite() && std::isfinite(c.radius), "fit_circle_geometric: fit diverged");
  detail::circle_residual_stats(points, c);
  return c;
}

template <class Scalar>
Circle2<Scalar> fit_circle(const std::vector<Eigen::Matrix<Scalar, 2, 1>>& points, const CircleFitParams& params = {}) {
  return params.method == CircleFitMethod::kasa ? fit_circle_kasa(points, params)
                                                : fit_circle_geometric(points, params);
}

}  // namespace orbitforge

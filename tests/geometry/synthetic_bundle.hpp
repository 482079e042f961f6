#pragma once
// A rigid scene with 2D observations seen from a synthetic source arc, for the
// bundle-adjustment and camera-refinement tests.
#include <Eigen/Cholesky>
#include <Eigen/Core>
#include <cmath>
#include <random>
#include <vector>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/orbit_bundle_adjust.hpp"

namespace orbitforge_test {
using orbitforge::BundleObservation;
using orbitforge::Camera;
using orbitforge::FrameCamera;

// A rigid scene seen from the source arc of a generated orbit video: 33
// cameras over 125 degrees at constant radius and height, looking at the
// centre of a ball of random points. Each point is matched over a window of
// consecutive frames, as a sequential matcher gives.
template <class S>
struct RigidScene {
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  SyntheticOrbit<S> orbit;
  std::vector<Camera<S>> cameras;
  std::vector<Vec3> points;
  std::vector<BundleObservation<S>> observations;
};

template <class S>
RigidScene<S> rigid_scene(int n_points, double noise_px, unsigned seed, int window = 12) {
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  RigidScene<S> sc;
  sc.orbit.count = 33;
  sc.orbit.step_deg = 125.0 / 32;
  sc.orbit.radius = 3.7;
  sc.orbit.focal = 450;
  for (const auto& f : sc.orbit.cameras()) sc.cameras.push_back(f.camera);
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::uniform_int_distribution<int> first(0, sc.orbit.count - window);
  while (int(sc.points.size()) < n_points) {
    Vec3 d(S(g(rng)), S(g(rng)), S(g(rng)));
    const double u = std::uniform_real_distribution<double>(0, 1)(rng);
    const Vec3 X = sc.orbit.look_at() + d.normalized() * S(std::cbrt(u));
    const int f0 = first(rng);
    std::vector<BundleObservation<S>> seen;
    for (int i = f0; i < f0 + window; ++i) {
      const auto& c = sc.cameras[std::size_t(i)];
      const Eigen::Matrix<S, 2, 1> px = c.project(X);
      if (c.to_camera(X).z() <= 0 || px.x() < 0 || px.y() < 0 || px.x() > 512 || px.y() > 512) continue;
      seen.push_back({i, int(sc.points.size()), px + Eigen::Matrix<S, 2, 1>(S(g(rng)), S(g(rng))) * S(noise_px)});
    }
    if (seen.size() < 2) continue;
    sc.points.push_back(X);
    sc.observations.insert(sc.observations.end(), seen.begin(), seen.end());
  }
  return sc;
}

// Least-squares intersection of each point's rays (the midpoint method).
template <class S>
std::vector<Eigen::Matrix<S, 3, 1>> triangulate(const std::vector<Camera<S>>& cams, std::size_t n_points,
                                                const std::vector<BundleObservation<S>>& obs) {
  std::vector<Eigen::Matrix3d> A(n_points, Eigen::Matrix3d::Zero());
  std::vector<Eigen::Vector3d> b(n_points, Eigen::Vector3d::Zero());
  for (const auto& o : obs) {
    const Camera<double> c = cams[std::size_t(o.camera)].template cast<double>();
    const Eigen::Vector3d ray(((double(o.xy.x()) - c.intrinsics.cx) / c.intrinsics.fx),
                              ((double(o.xy.y()) - c.intrinsics.cy) / c.intrinsics.fy), 1.0);
    const Eigen::Vector3d d = (c.R.transpose() * ray).normalized();
    const Eigen::Matrix3d P = Eigen::Matrix3d::Identity() - d * d.transpose();
    A[std::size_t(o.point)] += P;
    b[std::size_t(o.point)] += P * c.center();
  }
  std::vector<Eigen::Matrix<S, 3, 1>> X;
  for (std::size_t j = 0; j < n_points; ++j) X.push_back(A[j].ldlt().solve(b[j]).template cast<S>());
  return X;
}

template <class S>
std::vector<Camera<S>> under_rotated(const RigidScene<S>& sc, int k, double factor) {
  std::vector<FrameCamera<S>> f;
  for (const auto& c : sc.cameras) f.push_back({"", c, true});
  under_rotate(f, k, factor, sc.orbit.center, sc.orbit.n());
  std::vector<Camera<S>> out;
  for (const auto& x : f) out.push_back(x.camera);
  return out;
}

}  // namespace orbitforge_test

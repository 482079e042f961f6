#pragma once
// Synthetic source cameras on a known orbit, for the geometry tests and benches.
#include <Eigen/Geometry>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"

namespace orbitforge_test {

template <class S>
struct SyntheticOrbit {
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  int count = 33;
  double start_deg = 20;     // azimuth of the first camera in (e1, e2)
  double step_deg = 3;       // signed azimuth step per frame (negative: clockwise)
  double radius = 2.5;
  double elevation_deg = 12;  // cameras above the plane of the look-at point, looking down
  double roll_deg = 0;        // camera roll about its forward axis
  double noise = 0;           // std of centre noise (scene units)
  double angle_noise_deg = 0; // std of forward-axis jitter
  Vec3 center = Vec3(S(0.3), S(-0.2), S(0.5));
  Eigen::Matrix<S, 3, 3> world_R_orbit = Eigen::Matrix<S, 3, 3>::Identity();  // columns e1, e2, n
  int width = 512, height = 512;
  double focal = 600;
  unsigned seed = 7;

  Vec3 e1() const { return world_R_orbit.col(0); }
  Vec3 e2() const { return world_R_orbit.col(1); }
  Vec3 n() const { return world_R_orbit.col(2); }
  // All cameras aim at the point below the circle's centre that makes them look
  // down by elevation_deg; their centres lie exactly on the circle.
  Vec3 look_at() const {
    return center - S(radius * std::tan(elevation_deg * M_PI / 180)) * n();
  }
  Vec3 position(double az_deg) const {
    const double a = az_deg * M_PI / 180;
    return center + S(radius * std::cos(a)) * e1() + S(radius * std::sin(a)) * e2();
  }
  std::vector<orbitforge::FrameCamera<S>> cameras() const {
    std::mt19937 rng(seed);
    std::normal_distribution<double> g(0, 1);
    std::vector<orbitforge::FrameCamera<S>> out;
    orbitforge::Intrinsics<S> k{S(focal), S(focal), S(width / 2.0), S(height / 2.0), width, height};
    for (int i = 0; i < count; ++i) {
      Vec3 o = position(start_deg + step_deg * i);
      if (noise > 0) o += Vec3(S(g(rng)), S(g(rng)), S(g(rng))) * S(noise);
      Vec3 target = look_at();
      if (angle_noise_deg > 0) {
        const S d = (target - o).norm() * S(std::tan(angle_noise_deg * M_PI / 180));
        target += Vec3(S(g(rng)), S(g(rng)), S(g(rng))) * d;
      }
      auto cam = orbitforge::Camera<S>::look_at(o, target, n(), k);
      if (roll_deg != 0) {
        // Roll about the camera's own z axis: R' = Rz(roll) R.
        const Eigen::Matrix<S, 3, 3> Rz =
            Eigen::AngleAxis<S>(S(roll_deg * M_PI / 180), Vec3::UnitZ()).toRotationMatrix();
        const Vec3 c = cam.center();
        cam.R = Rz * cam.R;
        cam.t = -cam.R * c;
      }
      char name[32];
      std::snprintf(name, sizeof name, "%03d.jpg", i + 1);
      out.push_back({name, cam, true});
    }
    return out;
  }
};

// Registration drift as COLMAP shows it on a short arc: from camera k on, the
// rotation about the orbit axis (through `center` along `axis`) is compressed
// by `factor` about camera k, centre and orientation together: camera i > k is
// rotated about the axis by (factor - 1) times its azimuth from camera k, so
// every centre stays on the circle and keeps aiming at the axis.
template <class S>
void under_rotate(std::vector<orbitforge::FrameCamera<S>>& cams, int k, double factor,
                  const Eigen::Matrix<S, 3, 1>& center, const Eigen::Matrix<S, 3, 1>& axis) {
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  const Vec3 n = axis.normalized();
  auto azimuth = [&](const Vec3& p) {
    const Vec3 d = p - center - n * n.dot(p - center);
    const Vec3 e1 = (cams[k].camera.center() - center - n * n.dot(cams[k].camera.center() - center)).normalized();
    return std::atan2(double(n.cross(e1).dot(d)), double(e1.dot(d)));
  };
  for (std::size_t i = std::size_t(k) + 1; i < cams.size(); ++i) {
    auto& c = cams[i].camera;
    const Vec3 o = c.center();
    const Eigen::Matrix<S, 3, 3> Q = Eigen::AngleAxis<S>(S((factor - 1) * azimuth(o)), n).toRotationMatrix();
    const Vec3 o_new = Q * (o - center) + center;
    c.R = c.R * Q.transpose();
    c.t = -c.R * o_new;
  }
}

template <class S>
Eigen::Matrix<S, 3, 3> random_rotation(std::mt19937& rng) {
  std::normal_distribution<double> g(0, 1);
  Eigen::Quaternion<double> q(g(rng), g(rng), g(rng), g(rng));
  q.normalize();
  return q.toRotationMatrix().cast<S>();
}

}  // namespace orbitforge_test

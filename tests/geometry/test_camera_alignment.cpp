#include <catch2/catch.hpp>

#include <cmath>
#include <random>

#include "orbitforge/geometry/camera_alignment.hpp"

using namespace orbitforge;

namespace camera_alignment_test {

template <class S>
std::vector<Camera<S>> ring_cameras(int n, double arc_deg, double radius) {
  std::vector<Camera<S>> cams;
  const Intrinsics<S> k{S(400), S(400), S(256), S(256), 512, 512};
  for (int i = 0; i < n; ++i) {
    const double a = arc_deg * i / (n - 1) * 3.14159265358979 / 180;
    const Eigen::Matrix<S, 3, 1> eye(S(radius * std::cos(a)), S(radius * std::sin(a)), S(0.3 * radius));
    cams.push_back(Camera<S>::look_at(eye, {0, 0, 0}, {0, 0, 1}, k));
  }
  return cams;
}

}  // namespace camera_alignment_test

using camera_alignment_test::ring_cameras;

TEMPLATE_TEST_CASE("align_camera_centres recovers a similarity and reports no residual", "[geometry][alignment]",
                   float, double) {
  using S = TestType;
  const auto to = ring_cameras<S>(33, 125, 4.0);
  Similarity3 truth;
  truth.scale = 0.37;
  truth.R = Eigen::AngleAxisd(1.1, Eigen::Vector3d(0.3, -0.5, 0.8).normalized()).toRotationMatrix();
  truth.t = Eigen::Vector3d(120, -40, 7);
  // from = truth^-1 (to): so that aligning from onto to must find `truth`.
  Similarity3 inverse;
  inverse.scale = 1 / truth.scale;
  inverse.R = truth.R.transpose();
  inverse.t = -inverse.scale * (inverse.R * truth.t);
  std::vector<Camera<S>> from;
  for (const auto& c : to) from.push_back(inverse.apply(c));

  const CameraAlignment a = align_camera_centres(from, to);
  const double tol = std::is_same<S, float>::value ? 1e-4 : 1e-9;
  REQUIRE(a.cameras == 33);
  REQUIRE(std::abs(a.transform.scale - truth.scale) < tol * 10);
  REQUIRE((a.transform.R - truth.R).norm() < tol * 10);
  REQUIRE(a.centre_rms_relative < tol * 10);
  REQUIRE(a.rotation_max_deg < (std::is_same<S, float>::value ? 0.05 : 1e-6));
  // The aligned cameras project a point where the originals do.
  const Eigen::Vector3d x(0.2, -0.1, 0.4);
  const Eigen::Vector3d x_from = inverse.apply(x);
  for (std::size_t i = 0; i < to.size(); i += 8) {
    const Camera<S> moved = a.transform.apply(from[i]);
    const auto p0 = to[i].project(x.cast<S>());
    const auto p1 = moved.project(a.transform.apply(x_from).cast<S>());
    REQUIRE((p0 - p1).norm() < (std::is_same<S, float>::value ? 2e-2 : 1e-6));
  }
}

TEST_CASE("align_camera_centres: residuals measure what no similarity removes", "[geometry][alignment]") {
  auto to = ring_cameras<double>(33, 125, 4.0);
  auto from = to;
  // Under-rotated second half: a similarity cannot absorb it.
  for (std::size_t i = 17; i < from.size(); ++i) {
    const double a = -0.2 * (double(i) - 16) / 16;
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(a, Eigen::Vector3d::UnitZ()).toRotationMatrix();
    from[i] = Camera<double>::from_world_T_camera(turn * from[i].R.transpose(), turn * from[i].center(),
                                                  from[i].intrinsics);
  }
  const CameraAlignment bad = align_camera_centres(from, to);
  REQUIRE(bad.centre_rms_relative > 0.02);
  REQUIRE(bad.rotation_max_deg > 2);

  // A rolled copy: centres agree exactly, every orientation is off by the roll.
  std::vector<Camera<double>> rolled;
  const Eigen::Matrix3d roll = Eigen::AngleAxisd(0.2, Eigen::Vector3d::UnitZ()).toRotationMatrix();
  for (const auto& c : to) rolled.push_back(Camera<double>::from_world_T_camera(c.R.transpose() * roll, c.center(), c.intrinsics));
  const CameraAlignment r = align_camera_centres(rolled, to);
  REQUIRE(r.centre_rms_relative < 1e-9);
  REQUIRE(std::abs(r.rotation_mean_deg - 0.2 * 180 / 3.14159265358979) < 1e-6);
}

TEST_CASE("align_camera_centres refuses what cannot be aligned", "[geometry][alignment]") {
  const auto to = ring_cameras<double>(5, 90, 2.0);
  REQUIRE_THROWS_WITH(align_camera_centres(std::vector<Camera<double>>(to.begin(), to.begin() + 2),
                                           std::vector<Camera<double>>(to.begin(), to.begin() + 2)),
                      Catch::Contains("at least 3"));
  REQUIRE_THROWS_WITH(align_camera_centres(to, std::vector<Camera<double>>(to.begin(), to.begin() + 4)),
                      Catch::Contains("5 cameras against 4"));
  std::vector<Camera<double>> line;
  const Intrinsics<double> k{100, 100, 50, 50, 100, 100};
  for (int i = 0; i < 4; ++i)
    line.push_back(Camera<double>::look_at({double(i), 0, 0}, {double(i), 5, 0}, {0, 0, 1}, k));
  REQUIRE_THROWS_WITH(align_camera_centres(line, line), Catch::Contains("one line"));
}

#include <catch2/catch.hpp>
#include <cmath>

#include "orbitforge/metrics/view_rotation.hpp"

using namespace orbitforge;

namespace {

// A view of a world seen only by direction (a textured sky): every pixel is a
// function of its ray, so a camera turned about its centre sees exactly a
// homography of the unturned camera's image, as view_rotation.hpp assumes.
template <class S>
Image<S> sky_view(const Camera<S>& cam) {
  const auto& k = cam.intrinsics;
  Image<S> img(k.width, k.height, 3);
  const Eigen::Matrix3d Rt = cam.R.template cast<double>().transpose();
  for (int y = 0; y < k.height; ++y)
    for (int x = 0; x < k.width; ++x) {
      const Eigen::Vector3d d =
          (Rt * Eigen::Vector3d((x + 0.5 - k.cx) / k.fx, (y + 0.5 - k.cy) / k.fy, 1.0)).normalized();
      const double v[3] = {0.5 + 0.3 * std::sin(9 * d.x() + 4 * d.y()) * std::cos(7 * d.y() - 2 * d.z()),
                           0.5 + 0.25 * std::sin(11 * d.y() + 3 * d.z() + 1),
                           0.5 + 0.2 * std::cos(8 * d.x() - 5 * d.z())};
      for (int c = 0; c < 3; ++c) img(x, y, c) = S(v[c]);
    }
  return img;
}

template <class S>
Camera<S> base_camera() {
  Camera<S> c;
  c.intrinsics = {S(150), S(150), S(80), S(60), 160, 120};
  c.R = Eigen::AngleAxis<S>(S(0.3), Eigen::Matrix<S, 3, 1>(S(0.2), S(1), S(0.1)).normalized()).toRotationMatrix();
  c.t = Eigen::Matrix<S, 3, 1>(S(0.1), S(-0.2), S(3));
  return c;
}

Eigen::Matrix3d turn(double deg, const Eigen::Vector3d& axis) {
  return Eigen::AngleAxisd(deg * 3.14159265358979323846 / 180.0, axis.normalized()).toRotationMatrix();
}

}  // namespace

TEMPLATE_TEST_CASE("view rotation: a turned camera's image gives back the turn", "[metrics][view_rotation]", float,
                   double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const Eigen::Matrix3d truth = turn(2.0, Eigen::Vector3d(0.3, 1.0, -0.4));
  const Camera<S> turned = turned_camera(cam, truth);
  CHECK((turned.center() - cam.center()).norm() < 1e-5);
  const Image<S> render = sky_view(cam), target = sky_view(turned);
  const ViewRotationFit fit = fit_view_rotation(render, target, cam.intrinsics);
  REQUIRE(fit.refined);
  const double err_deg = Eigen::AngleAxisd(fit.camera_R_camera * truth.transpose()).angle() * 180.0 / 3.14159265358979323846;
  CHECK(err_deg < 0.02);
  CHECK(fit.angle_deg == Approx(2.0).margin(0.02));
  CHECK(fit.rms_after < 0.1 * fit.rms_before);
}

TEMPLATE_TEST_CASE("view rotation: nothing to fit leaves the camera", "[metrics][view_rotation]", float, double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const Image<S> render = sky_view(cam);
  const ViewRotationFit fit = fit_view_rotation(render, render, cam.intrinsics);
  CHECK(fit.angle_deg < 1e-3);
  CHECK(fit.rms_before == Approx(0.0).margin(1e-6));
}

TEMPLATE_TEST_CASE("view rotation: a turn past the limit is refused", "[metrics][view_rotation]", float, double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const Image<S> render = sky_view(cam), target = sky_view(turned_camera(cam, turn(3.0, Eigen::Vector3d(1, 0.2, 0))));
  ViewRotationParams p;
  p.max_angle_deg = 5.0;
  CHECK(fit_view_rotation(render, target, cam.intrinsics, p).refined);
  p.max_angle_deg = 1.0;
  const ViewRotationFit refused = fit_view_rotation(render, target, cam.intrinsics, p);
  CHECK_FALSE(refused.refined);
  CHECK(refused.camera_R_camera.isIdentity());
  CHECK(refused.rms_after == refused.rms_before);
}

TEST_CASE("view rotation: images of two shapes are refused", "[metrics][view_rotation]") {
  const Camera<float> cam = base_camera<float>();
  const Image<float> a(160, 120, 3, 0.5f), b(160, 100, 3, 0.5f);
  CHECK_THROWS_WITH(fit_view_rotation(a, b, cam.intrinsics), Catch::Contains("one shape"));
}

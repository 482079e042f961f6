#include <catch2/catch.hpp>
#include <cmath>

#include "orbitforge/metrics/view_alignment.hpp"

using namespace orbitforge;

namespace {

// A view of a world seen only by direction (a textured sky): every pixel is a
// function of its ray, so a camera turned about its centre, or zoomed, sees
// exactly a homography of the given camera's image, as view_alignment.hpp assumes.
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

ViewAlignment alignment(double deg, const Eigen::Vector3d& axis, double zoom) {
  ViewAlignment a;
  a.camera_R_camera = turn(deg, axis);
  a.zoom = zoom;
  return a;
}

TEMPLATE_TEST_CASE("view alignment: a turned and zoomed camera's image gives back the turn and the zoom",
                   "[metrics][view_alignment]", float, double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const ViewAlignment truth = alignment(2.0, Eigen::Vector3d(0.3, 1.0, -0.4), 1.04);
  const Camera<S> moved = aligned_camera(cam, truth);
  CHECK((moved.center() - cam.center()).norm() < 1e-5);
  CHECK(double(moved.intrinsics.fx) == Approx(150 * 1.04).epsilon(1e-6));
  const Image<S> render = sky_view(cam), target = sky_view(moved);
  const ViewAlignment fit = fit_view_alignment(render, target, cam.intrinsics);
  REQUIRE(fit.refined);
  const double err_deg =
      Eigen::AngleAxisd(fit.camera_R_camera * truth.camera_R_camera.transpose()).angle() * 180.0 / 3.14159265358979323846;
  CHECK(err_deg < 0.02);
  CHECK(fit.angle_deg == Approx(2.0).margin(0.02));
  CHECK(fit.zoom == Approx(1.04).margin(2e-4));
  CHECK(fit.rms_after < 0.1 * fit.rms_before);

  // The turn alone, where the views differ by a turn only.
  ViewAlignmentParams turn_only;
  turn_only.fit_zoom = false;
  const ViewAlignment t = fit_view_alignment(render, sky_view(aligned_camera(cam, alignment(1.5, {1, 0, 0.2}, 1.0))),
                                             cam.intrinsics, turn_only);
  REQUIRE(t.refined);
  CHECK(t.zoom == 1.0);
  CHECK(t.angle_deg == Approx(1.5).margin(0.02));
}

TEMPLATE_TEST_CASE("view alignment: nothing to fit leaves the camera", "[metrics][view_alignment]", float, double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const Image<S> render = sky_view(cam);
  const ViewAlignment fit = fit_view_alignment(render, render, cam.intrinsics);
  CHECK(fit.angle_deg < 1e-3);
  CHECK(fit.zoom == Approx(1.0).margin(1e-5));
  CHECK(fit.rms_before == Approx(0.0).margin(1e-6));
}

TEMPLATE_TEST_CASE("view alignment: a turn or zoom past its limit is refused", "[metrics][view_alignment]", float,
                   double) {
  using S = TestType;
  const Camera<S> cam = base_camera<S>();
  const Image<S> render = sky_view(cam);
  const Image<S> turned = sky_view(aligned_camera(cam, alignment(3.0, {1, 0.2, 0}, 1.0)));
  const Image<S> zoomed = sky_view(aligned_camera(cam, alignment(0.0, {1, 0, 0}, 1.06)));
  ViewAlignmentParams p;
  CHECK(fit_view_alignment(render, turned, cam.intrinsics, p).refined);
  CHECK(fit_view_alignment(render, zoomed, cam.intrinsics, p).refined);
  p.max_angle_deg = 1.0;
  p.max_zoom = 0.03;
  for (const Image<S>* target : {&turned, &zoomed}) {
    const ViewAlignment refused = fit_view_alignment(render, *target, cam.intrinsics, p);
    CHECK_FALSE(refused.refined);
    CHECK(refused.camera_R_camera.isIdentity());
    CHECK(refused.zoom == 1.0);
    CHECK(refused.rms_after == refused.rms_before);
  }
}

TEST_CASE("view alignment: images of two shapes are refused", "[metrics][view_alignment]") {
  const Camera<float> cam = base_camera<float>();
  const Image<float> a(160, 120, 3, 0.5f), b(160, 100, 3, 0.5f);
  CHECK_THROWS_WITH(fit_view_alignment(a, b, cam.intrinsics), Catch::Contains("one shape"));
}

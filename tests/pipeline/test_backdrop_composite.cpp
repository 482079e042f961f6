// The backdrop composite (pipeline/inputs/backdrop_composite.hpp): the object's
// pixels stay the photograph's, the black around it becomes a wall that covers
// every pixel, differs along the borders, and is one surface that two cameras
// see alike.
#include <catch2/catch.hpp>

#include <cmath>

#include "orbitforge/pipeline/inputs/backdrop_composite.hpp"

using namespace orbitforge;

namespace backdrop_composite_test {

// A ring of 12 cameras looking at the origin; every frame black with a grey
// square in the middle (the "object").
template <class S>
PipelineInput<S> black_ring(int w, int h) {
  PipelineInput<S> in;
  in.width = w;
  in.height = h;
  const Intrinsics<S> k{S(60), S(60), S(w) / 2, S(h) / 2, w, h};
  for (int i = 0; i < 12; ++i) {
    const double az = 2 * 3.14159265358979 * i / 12;
    const Eigen::Matrix<S, 3, 1> eye(S(4 * std::cos(az)), S(4 * std::sin(az)), S(1));
    FrameCamera<S> fc;
    fc.name = std::to_string(i) + ".png";
    fc.camera = Camera<S>::look_at(eye, Eigen::Matrix<S, 3, 1>::Zero(), Eigen::Matrix<S, 3, 1>::UnitZ(), k);
    in.cameras.push_back(fc);
    Image<S> img(w, h, 3, S(0));
    for (int y = h / 3; y < 2 * h / 3; ++y)
      for (int x = w / 3; x < 2 * w / 3; ++x)
        for (int c = 0; c < 3; ++c) img(x, y, c) = S(0.8);
    in.images.push_back(img);
  }
  select_source(in, "1-12");
  return in;
}

TEMPLATE_TEST_CASE("backdrop composite: the object stays, the black becomes one textured wall",
                   "[pipeline][input][background]", float, double) {
  using S = TestType;
  const int w = 64, h = 48;
  PipelineInput<S> in = black_ring<S>(w, h);
  const PipelineInput<S> before = in;
  BackdropCompositeParams p;
  p.wall_gaussians = 6000;
  p.threads = 1;
  composite_on_backdrop(in, p);

  for (std::size_t f = 0; f < in.images.size(); ++f) {
    const Image<S>& img = in.images[f];
    // The object's pixels are the photograph's.
    CHECK(img(w / 2, h / 2, 0) == Approx(0.8));
    CHECK(img(w / 3, h / 3, 2) == Approx(0.8));
    // No pixel is left black, and none shows the renderer's background through a hole.
    int black = 0, hole = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) {
        S m = 0;
        for (int c = 0; c < 3; ++c) m = std::max(m, img(x, y, c));
        black += m < S(0.02);
        hole += std::abs(img(x, y, 0) - S(0.5)) < S(1e-6) && std::abs(img(x, y, 1) - S(0.5)) < S(1e-6);
      }
    CHECK(black == 0);
    CHECK(hole < w * h / 100);
    CHECK(img.data != before.images[f].data);
  }
  // The borders disagree: the library's background choice must not pick one colour.
  const BackgroundEstimate bg = choose_background(in);
  CHECK(bg.random);

  // One surface: a point of the wall two neighbouring cameras both see has one colour in both.
  const GaussianScene<S> wall = backdrop_wall(in, p);
  REQUIRE(wall.size() == std::size_t(p.wall_gaussians));
  const Camera<S>& a = in.cameras[0].camera;
  const Camera<S>& b = in.cameras[1].camera;
  int compared = 0;
  double diff = 0;
  for (int y = 2; y < h - 2; y += 4)
    for (int x = 2; x < w - 2; x += 4) {
      if (x >= w / 3 - 2 && x < 2 * w / 3 + 2 && y >= h / 3 - 2 && y < 2 * h / 3 + 2) continue;
      // The wall point behind pixel (x, y) of camera a: intersect its ray with the cylinder.
      const Eigen::Matrix<S, 3, 1> d =
          (a.R.transpose() * Eigen::Matrix<S, 3, 1>((S(x) + S(0.5) - a.intrinsics.cx) / a.intrinsics.fx,
                                                    (S(y) + S(0.5) - a.intrinsics.cy) / a.intrinsics.fy, S(1)))
              .normalized();
      const Eigen::Matrix<S, 3, 1> o = a.center();
      // |(o + t d)_xy| = 2 x (ring radius 4) = 8, the far root.
      const double qa = double(d.x() * d.x() + d.y() * d.y()), qb = 2 * double(o.x() * d.x() + o.y() * d.y()),
                   qc = double(o.x() * o.x() + o.y() * o.y()) - 64;
      const double t = (-qb + std::sqrt(qb * qb - 4 * qa * qc)) / (2 * qa);
      const Eigen::Matrix<S, 3, 1> X = o + S(t) * d;
      const auto uv = b.project(X);
      if (b.to_camera(X).z() <= 0 || uv.x() < 2 || uv.y() < 2 || uv.x() > w - 3 || uv.y() > h - 3) continue;
      const int bx = int(uv.x()), by = int(uv.y());
      if (bx >= w / 3 - 2 && bx < 2 * w / 3 + 2 && by >= h / 3 - 2 && by < 2 * h / 3 + 2) continue;
      for (int c = 0; c < 3; ++c) diff += std::abs(double(in.images[0](x, y, c) - in.images[1](bx, by, c)));
      ++compared;
    }
  REQUIRE(compared > 20);
  // Against the photographs' black the wall is bright; the same point in two views differs far less.
  CHECK(diff / (3 * compared) < 0.12);
}

TEST_CASE("backdrop composite: too few cameras are named", "[pipeline][input][background]") {
  PipelineInput<float> in = black_ring<float>(32, 24);
  for (std::size_t i = 2; i < in.cameras.size(); ++i) in.cameras[i].valid = false;
  CHECK_THROWS_WITH(backdrop_wall(in, BackdropCompositeParams{}), Catch::Contains("at least 3 cameras"));
}

}  // namespace backdrop_composite_test

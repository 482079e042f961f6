#include <catch2/catch.hpp>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/axis_convention.hpp"

using namespace orbitforge;
using orbitforge_test::SyntheticOrbit;

// Re-expresses a correct OpenCV world-to-camera camera in another convention,
// keeping c = -R^T t (the centre every candidate uses).
template <class S>
static Camera<S> recast(const Camera<S>& cam, ForwardConvention c) {
  const Eigen::Matrix<S, 3, 3> flip = Eigen::Matrix<S, 3, 1>(1, -1, -1).asDiagonal();
  Camera<S> out = cam;
  switch (c) {
    case ForwardConvention::row2: break;
    case ForwardConvention::neg_row2: out.R = flip * cam.R; break;                    // OpenGL world-to-camera
    case ForwardConvention::col2: out.R = cam.R.transpose(); break;                   // camera-to-world, OpenCV
    case ForwardConvention::neg_col2: out.R = (flip * cam.R).transpose(); break;      // camera-to-world, OpenGL
  }
  out.t = -out.R * cam.center();
  return out;
}

TEMPLATE_TEST_CASE("select_forward_convention finds the convention the rotations are stored in",
                   "[geometry][convention]", float, double) {
  using S = TestType;
  SyntheticOrbit<S> orbit;
  orbit.count = 25;
  orbit.step_deg = 5;
  std::mt19937 rng(3);
  orbit.world_R_orbit = orbitforge_test::random_rotation<S>(rng);
  const auto frames = orbit.cameras();
  for (auto conv : {ForwardConvention::row2, ForwardConvention::neg_row2, ForwardConvention::col2,
                    ForwardConvention::neg_col2}) {
    INFO("stored as " << convention_name(conv));
    std::vector<Camera<S>> cams;
    for (const auto& f : frames) cams.push_back(recast(f.camera, conv));
    const auto choice = select_forward_convention(cams);
    REQUIRE(choice.convention == conv);
    REQUIRE(choice.error_deg < 0.01);
    REQUIRE((choice.look_at - orbit.look_at()).norm() < 1e-3);
    REQUIRE(choice.candidates.size() == 4);
    for (const auto& c : choice.candidates)
      if (c.convention != conv) REQUIRE((!c.solvable || c.error_deg > 1.0));
    // The forward and up axes of the chosen convention are the true ones.
    for (std::size_t i = 0; i < cams.size(); ++i) {
      REQUIRE((forward_axis<S>(cams[i].R, conv) - frames[i].camera.forward()).norm() < 1e-5);
      REQUIRE((up_axis<S>(cams[i].R, conv) - frames[i].camera.up()).norm() < 1e-5);
    }
  }
}

TEMPLATE_TEST_CASE("select_forward_convention: names and failure", "[geometry][convention]", float, double) {
  using S = TestType;
  REQUIRE(convention_from_name("neg_col2") == ForwardConvention::neg_col2);
  REQUIRE_THROWS_AS(convention_from_name("col3"), Error);
  // Identity rotations everywhere: every convention's rays are parallel.
  std::vector<Camera<S>> cams(4);
  for (int i = 0; i < 4; ++i) cams[i].t = Eigen::Matrix<S, 3, 1>(S(i), S(i * i), 0);
  REQUIRE_THROWS_WITH(select_forward_convention(cams), Catch::Contains("no forward-axis convention"));
}

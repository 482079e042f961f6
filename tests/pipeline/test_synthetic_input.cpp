#include <catch2/catch.hpp>

#include "orbitforge/pipeline/inputs/synthetic_input.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("synthetic input is deterministic and well-formed", "[pipeline][synthetic]", float, double) {
  using S = TestType;
  SyntheticInputParams p;
  const auto a = make_synthetic_input<S>(p);
  const auto b = make_synthetic_input<S>(p);
  a.scene.check_consistent();
  REQUIRE(a.scene.size() == std::size_t(p.object_gaussians + p.ground_gaussians));
  REQUIRE(a.scene.means == b.scene.means);
  REQUIRE(a.recorded.size() == std::size_t(p.frames));
  REQUIRE(a.true_cameras.size() == std::size_t(p.frames));
  for (int f = 0; f < p.frames; ++f) {
    const auto& t = a.true_cameras[f];
    const auto& r = a.recorded[f].camera;
    REQUIRE(r.R == b.recorded[f].camera.R);
    // True cameras look at the target from the prescribed radius.
    REQUIRE((t.center() - a.target).norm() == Approx(p.radius).epsilon(1e-5));
    REQUIRE(t.project(a.target).x() == Approx(p.width / 2.0).margin(1e-2));
    // Recorded cameras are close to the true ones, but not equal.
    const S dist = (r.center() - t.center()).norm();
    REQUIRE(dist < S(0.15 * p.radius));
    REQUIRE(r.forward().dot(t.forward()) > S(0.99));
    REQUIRE(r.R.allFinite());
  }
  REQUIRE(a.recorded[0].name == "001.png");
  // Every scene value is finite.
  for (S v : a.scene.means) REQUIRE(std::isfinite(v));
  for (S v : a.scene.log_scales) REQUIRE(std::isfinite(v));
  for (S v : a.scene.opacity_logits) REQUIRE(std::isfinite(v));
}

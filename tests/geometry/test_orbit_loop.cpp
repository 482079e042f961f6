// orbit_loop: how cameras go round an orbit in frame order, and whether the
// last one comes back to the first in one even step.
#include <catch2/catch.hpp>

#include <vector>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/orbit_loop.hpp"

using namespace orbitforge;

namespace orbit_loop_test {

std::vector<int> frames_of(int n) {
  std::vector<int> f;
  for (int i = 0; i < n; ++i) f.push_back(i);
  return f;
}

TEMPLATE_TEST_CASE("orbit_loop: 90 cameras all the way round close in one step; 4 % short a step leave 18 degrees",
                   "[geometry][orbit_loop]", float, double) {
  using S = TestType;
  for (double direction : {1.0, -1.0}) {
    INFO("direction " << direction);
    orbitforge_test::SyntheticOrbit<S> o;
    o.count = 90;
    o.noise = 0.002;
    o.step_deg = direction * 4.0;
    const OrbitLoop closed = orbit_loop(o.cameras(), frames_of(90));
    CHECK(closed.cameras == 90);
    CHECK(closed.mean_step_deg == Approx(4.0).margin(0.01));
    CHECK(closed.last_to_first_deg == Approx(4.0).margin(0.2));
    CHECK(closed.largest_step_deg < 4.2);
    CHECK(closed.smallest_step_deg > 3.8);

    o.step_deg = direction * 3.84;
    const OrbitLoop short_of = orbit_loop(o.cameras(), frames_of(90));
    CHECK(short_of.mean_step_deg == Approx(3.84).margin(0.01));
    CHECK(short_of.last_to_first_deg == Approx(360 - 89 * 3.84).margin(0.2));
  }
}

TEST_CASE("orbit_loop: missing frames count in the steps; bad input is named", "[geometry][orbit_loop]") {
  orbitforge_test::SyntheticOrbit<double> o;
  o.count = 90;
  o.step_deg = 4.0;
  std::vector<FrameCamera<double>> cams = o.cameras();
  std::vector<int> frame = frames_of(90);
  // Frames 10-14 not registered: the step over the hole is 6 frames of 4 degrees.
  cams.erase(cams.begin() + 10, cams.begin() + 15);
  frame.erase(frame.begin() + 10, frame.begin() + 15);
  const OrbitLoop l = orbit_loop(cams, frame);
  CHECK(l.cameras == 85);
  CHECK(l.mean_step_deg == Approx(4.0).margin(0.01));
  CHECK(l.largest_step_deg == Approx(4.0).margin(0.01));
  CHECK(l.smallest_step_deg == Approx(4.0).margin(0.01));
  CHECK(l.last_to_first_deg == Approx(4.0).margin(0.01));

  CHECK_THROWS_WITH(orbit_loop(std::vector<FrameCamera<double>>(cams.begin(), cams.begin() + 3), {0, 1, 2}),
                    Catch::Contains("at least 4"));
  std::vector<int> backwards = frame;
  std::swap(backwards[3], backwards[4]);
  CHECK_THROWS_WITH(orbit_loop(cams, backwards), Catch::Contains("must increase"));
}

}  // namespace orbit_loop_test

#include <catch2/catch.hpp>

#include "orbitforge/geometry/binning.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("bin_sources: counter-clockwise and clockwise arcs", "[geometry][binning]", float, double) {
  using S = TestType;
  for (int d : {1, -1}) {
    INFO("direction " << d);
    // 33 frames, 4 degrees apart, starting at azimuth 170 (wraps past 180).
    std::vector<S> az;
    for (int t = 0; t < 33; ++t) az.push_back(S(wrap_deg_180(170.0 + d * 4.0 * t)));
    const auto s = bin_sources(az, az[0], d, 361);
    REQUIRE(s.source_bins.size() == 33);
    for (int t = 0; t < 33; ++t) REQUIRE(s.source_bins[t] == 4 * t);
    REQUIRE(s.observed.size() == 33);
    REQUIRE(s.arc_end == 128);
    REQUIRE(s.unwrapped_max == 128);
    REQUIRE(s.arc.size() == 129);
    REQUIRE(s.arc.front() == 0);
    REQUIRE(s.arc.back() == 128);
    REQUIRE(s.gap.size() == 361 - 129);
    REQUIRE(s.gap.front() == 129);
    REQUIRE(s.gap.back() == 360);
    // With the opposite direction the same frames run backwards from bin 0.
    const auto wrong = bin_sources(az, az[0], -d, 361);
    REQUIRE(wrong.source_bins[1] == 356);
    REQUIRE(wrong.arc_end == 0);
  }
}

TEMPLATE_TEST_CASE("bin_sources: jitter behind the start does not open the arc", "[geometry][binning]", float, double) {
  using S = TestType;
  // Frames 2-3 lie slightly behind theta0 (0.4 and 0.2 degrees), then progress.
  std::vector<S> az{S(10), S(9.6), S(9.8), S(11), S(13), S(40)};
  const auto s = bin_sources(az, S(10), 1, 361);
  REQUIRE(s.source_bins[1] == 360);  // the paper's formula: 359.6 -> bin 360 (= view 0)
  REQUIRE(s.source_bins[2] == 360);
  REQUIRE(s.arc_end == 30);           // not 360
  REQUIRE(s.gap.size() == 330);
  REQUIRE(s.observed == std::vector<int>{0, 1, 3, 30, 360});
}

TEMPLATE_TEST_CASE("bin_sources: overshoot past 360 closes the orbit", "[geometry][binning]", float, double) {
  using S = TestType;
  std::vector<S> az;
  for (int t = 0; t <= 75; ++t) az.push_back(S(wrap_deg_180(-30.0 - 5.0 * t)));  // 375 degrees clockwise
  const auto s = bin_sources(az, az[0], -1, 361);
  REQUIRE(s.unwrapped_max == 375);
  REQUIRE(s.arc_end == 360);
  REQUIRE(s.gap.empty());
  REQUIRE(s.arc.size() == 361);
  // Exactly one turn minus a step: bin 360 stays in the gap.
  std::vector<S> az2;
  for (int t = 0; t < 72; ++t) az2.push_back(S(wrap_deg_180(5.0 * t)));
  const auto s2 = bin_sources(az2, S(0), 1, 361);
  REQUIRE(s2.arc_end == 355);
  REQUIRE(s2.gap.front() == 356);
}

TEMPLATE_TEST_CASE("bin_sources: other view counts and bad input", "[geometry][binning]", float, double) {
  using S = TestType;
  std::vector<S> az{S(0), S(45), S(90)};
  const auto s = bin_sources(az, S(0), 1, 9);  // 45 degrees per bin
  REQUIRE(s.source_bins == std::vector<int>{0, 1, 2});
  REQUIRE(s.arc_end == 2);
  REQUIRE(azimuth_to_bin(S(359.9), 361) == 360);
  REQUIRE(azimuth_to_bin(S(0.49), 361) == 0);
  REQUIRE_THROWS_AS(bin_sources(az, S(0), 0, 361), Error);
  REQUIRE_THROWS_AS(bin_sources(std::vector<S>{}, S(0), 1, 361), Error);
  REQUIRE_THROWS_AS(bin_sources(az, std::numeric_limits<S>::quiet_NaN(), 1, 361), Error);
  REQUIRE_THROWS_AS(bin_sources(std::vector<S>{S(0), std::numeric_limits<S>::infinity()}, S(0), 1, 361), Error);
}

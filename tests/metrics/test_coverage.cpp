#include <catch2/catch.hpp>

#include "orbitforge/metrics/coverage.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("span and monotone progress", "[metrics][coverage]", float, double) {
  using S = TestType;
  SECTION("361-view canonical orbit: A = 359, M = 1, closed") {
    std::vector<S> az;
    for (int i = 0; i < 361; ++i) az.push_back(S(17 + i));
    const auto c = orbit_coverage(az);
    REQUIRE(c.span_deg == Approx(359));
    REQUIRE(c.monotone == Approx(1));
    REQUIRE(c.closed);
  }
  SECTION("120 views of 3 degrees clockwise: A = 357") {
    std::vector<S> az;
    for (int i = 0; i < 120; ++i) az.push_back(S(-3.0 * i));
    const auto c = orbit_coverage(az);
    REQUIRE(c.span_deg == Approx(357));
    REQUIRE(c.monotone == Approx(1));
    REQUIRE(c.closed);
  }
  SECTION("a local arc: A small, not closed") {
    std::vector<S> az;
    for (int i = 0; i < 25; ++i) az.push_back(S(170 + 0.8 * i));  // crosses 180
    const auto c = orbit_coverage(az);
    REQUIRE(c.span_deg == Approx(19.2).epsilon(1e-4));
    REQUIRE(!c.closed);
  }
  SECTION("back-and-forth motion lowers M; stalls count for neither direction") {
    std::vector<S> az{S(0), S(10), S(20), S(15), S(25), S(25), S(35)};
    REQUIRE(monotone_progress(az) == Approx(4.0 / 6));
    REQUIRE(azimuth_span_deg(az) == Approx(35));
  }
  SECTION("full coverage but non-monotone fails the gate") {
    std::vector<S> az;
    for (int i = 0; i < 360; i += 2) az.push_back(S(i % 4 == 0 ? i : -i));
    const auto c = orbit_coverage(az);
    REQUIRE(c.span_deg > 330);
    REQUIRE(!c.closed);
  }
  SECTION("edge cases") {
    REQUIRE(azimuth_span_deg(std::vector<S>{S(42)}) == 0);
    REQUIRE(monotone_progress(std::vector<S>{S(42)}) == 0);
    REQUIRE_THROWS_AS(azimuth_span_deg(std::vector<S>{}), Error);
    REQUIRE_THROWS_AS(azimuth_span_deg(std::vector<S>{S(1), std::numeric_limits<S>::quiet_NaN()}), Error);
  }
}

TEST_CASE("temporal trace diagnostics", "[metrics][coverage]") {
  TraceParams p;
  p.period = 361;
  SECTION("one clean turn") {
    std::vector<double> x;
    for (int j = 0; j <= 360; ++j) x.push_back(j);
    const auto t = temporal_trace(x, p);
    REQUIRE(t.steps == 360);
    REQUIRE(t.absolute_turns == Approx(360.0 / 361));
    REQUIRE(t.net_turns == Approx(360.0 / 361));
    REQUIRE(t.stall_fraction == 0);
    REQUIRE(t.reversals == 0);
  }
  SECTION("wrap-around steps are short steps") {
    std::vector<double> x{355, 358, 0, 3};
    p.period = 360;
    const auto t = temporal_trace(x, p);
    REQUIRE(t.net_turns == Approx(8.0 / 360));
  }
  SECTION("stalls and reversals") {
    // forward 3, stall, stall, back 2, back 2, stall(0.5), forward 4
    std::vector<double> x{0, 3, 3, 3.5, 1.5, -0.5, 0, 4};
    p.period = 100;
    const auto t = temporal_trace(x, p);
    REQUIRE(t.steps == 7);
    REQUIRE(t.stall_fraction == Approx(3.0 / 7));
    REQUIRE(t.reversals == 2);
    REQUIRE(t.absolute_turns == Approx((3 + 0 + 0.5 + 2 + 2 + 0.5 + 4) / 100.0));
    REQUIRE(t.net_turns == Approx(4 / 100.0));
  }
  SECTION("bad input") {
    p.period = 0;
    REQUIRE_THROWS_AS(temporal_trace({0, 1}, p), Error);
    REQUIRE_THROWS_AS(temporal_trace({0, std::nan("")}), Error);
  }
}

#include <catch2/catch.hpp>

#include <random>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/lookat.hpp"

using namespace orbitforge;

template <class S>
static S lookat_tol() { return std::is_same<S, float>::value ? S(2e-4) : S(1e-10); }

TEMPLATE_TEST_CASE("fit_lookat_point recovers the common point of exact rays", "[geometry][lookat]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> u(-3, 3);
  const Vec3 x(S(0.4), S(-1.2), S(0.7));
  std::vector<Vec3> o, d;
  for (int i = 0; i < 20; ++i) {
    const Vec3 oi(S(u(rng)), S(u(rng)), S(u(rng) + 8));
    o.push_back(oi);
    d.push_back((x - oi) * S(1.7));  // not unit: the fit normalises
  }
  const auto fit = fit_lookat_point(o, d);
  REQUIRE((fit.point - x).norm() < lookat_tol<S>() * 10);
  REQUIRE(fit.mean_angle_deg < (std::is_same<S, float>::value ? 0.05 : 1e-6));
  REQUIRE(fit.eigen_ratio > 0.001);

  SECTION("rays pointing away score near 180 degrees") {
    std::vector<Vec3> back;
    for (auto& v : d) back.push_back(-v);
    const auto f2 = fit_lookat_point(o, back);
    REQUIRE((f2.point - x).norm() < lookat_tol<S>() * 10);  // lines, not rays
    REQUIRE(f2.mean_angle_deg > 179);
  }
}

TEMPLATE_TEST_CASE("fit_lookat_point: least squares with noise and two rays", "[geometry][lookat]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  // Two skew lines: x-axis at z = 0 and y-axis at z = 2 -> midpoint (0, 0, 1).
  std::vector<Vec3> o{Vec3(-5, 0, 0), Vec3(0, -5, 2)}, d{Vec3(1, 0, 0), Vec3(0, 1, 0)};
  const auto fit = fit_lookat_point(o, d);
  REQUIRE((fit.point - Vec3(0, 0, 1)).norm() < lookat_tol<S>() * 10);
  // The angle to the midpoint from each origin: atan(1/5).
  REQUIRE(fit.mean_angle_deg == Approx(std::atan(0.2) * 180 / M_PI).epsilon(1e-4));
}

TEMPLATE_TEST_CASE("fit_lookat_point rejects degenerate input", "[geometry][lookat]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  std::vector<Vec3> o{Vec3(0, 0, 0), Vec3(1, 0, 0), Vec3(0, 1, 0)};
  SECTION("parallel rays") {
    std::vector<Vec3> d(3, Vec3(0, 0, 1));
    REQUIRE_THROWS_WITH(fit_lookat_point(o, d), Catch::Contains("nearly parallel"));
  }
  SECTION("rays within 0.01 degree of each other") {
    std::vector<Vec3> d{Vec3(0, 0, 1), Vec3(S(1e-4), 0, 1), Vec3(0, S(1e-4), 1)};
    REQUIRE_THROWS_AS(fit_lookat_point(o, d), Error);
  }
  SECTION("one ray") {
    REQUIRE_THROWS_WITH(fit_lookat_point(std::vector<Vec3>{o[0]}, std::vector<Vec3>{Vec3(0, 0, 1)}),
                        Catch::Contains("at least 2"));
  }
  SECTION("NaN and inf") {
    std::vector<Vec3> d{Vec3(0, 0, 1), Vec3(1, 0, 1), Vec3(0, 1, 1)};
    auto o2 = o;
    o2[1].x() = std::numeric_limits<S>::quiet_NaN();
    REQUIRE_THROWS_WITH(fit_lookat_point(o2, d), Catch::Contains("non-finite"));
    auto d2 = d;
    d2[2].z() = std::numeric_limits<S>::infinity();
    REQUIRE_THROWS_WITH(fit_lookat_point(o, d2), Catch::Contains("non-finite"));
  }
  SECTION("zero direction") {
    std::vector<Vec3> d{Vec3(0, 0, 1), Vec3(0, 0, 0), Vec3(0, 1, 1)};
    REQUIRE_THROWS_WITH(fit_lookat_point(o, d), Catch::Contains("zero direction"));
  }
}

TEST_CASE("fit_lookat_point is exact with coordinates offset by 1e6 (double)", "[geometry][lookat]") {
  using Vec3 = Eigen::Vector3d;
  const Vec3 off(1e6, -1e6, 1e6), x = off + Vec3(0.1, 0.2, 0.3);
  std::vector<Vec3> o, d;
  for (int i = 0; i < 12; ++i) {
    const double a = i * 0.5;
    const Vec3 oi = off + Vec3(2 * std::cos(a), 2 * std::sin(a), 0.5);
    o.push_back(oi);
    d.push_back(x - oi);
  }
  const auto fit = fit_lookat_point(o, d);
  REQUIRE((fit.point - x).norm() < 1e-8);
}

#include <catch2/catch.hpp>

#include <random>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/plane_fit.hpp"

using namespace orbitforge;

template <class S>
using V3 = Eigen::Matrix<S, 3, 1>;

template <class S>
static std::vector<V3<S>> ring(const Eigen::Matrix<S, 3, 3>& Rw, const V3<S>& c, double arc_deg, int n,
                               double height_noise = 0, unsigned seed = 1) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0, 1);
  std::vector<V3<S>> p;
  for (int i = 0; i < n; ++i) {
    const double a = arc_deg * M_PI / 180 * i / (n - 1);
    p.push_back(c + Rw * V3<S>(S(2 * std::cos(a)), S(2 * std::sin(a)), S(height_noise * g(rng))));
  }
  return p;
}

TEMPLATE_TEST_CASE("fit_plane recovers a randomly oriented plane and orients its normal", "[geometry][plane]", float,
                   double) {
  using S = TestType;
  std::mt19937 rng(5);
  for (int trial = 0; trial < 5; ++trial) {
    const auto Rw = orbitforge_test::random_rotation<S>(rng);
    const V3<S> n_true = Rw.col(2), c(S(1), S(-2), S(3));
    const auto pts = ring<S>(Rw, c, 120, 30);
    {  // every trial runs every case (SECTIONs inside a loop would run once)
      INFO("trial " << trial << ": camera up decides");
      // Up mostly along n (and a little sideways); forward pointing along +n would
      // contradict look-down, but the up rule has priority.
      const V3<S> up = (S(0.8) * n_true + S(0.3) * Rw.col(0));
      const auto pf = fit_plane(pts, up, V3<S>(n_true));
      REQUIRE(pf.normal_rule == "camera_up");
      REQUIRE((pf.normal - n_true).norm() < 1e-4);
      REQUIRE(std::abs(pf.e1.dot(pf.normal)) < 1e-5);
      REQUIRE((pf.e2 - pf.normal.cross(pf.e1)).norm() < 1e-5);  // right-handed
      REQUIRE(pf.height_std < 1e-4);
      // Flipping the up flips the normal.
      const auto pf2 = fit_plane(pts, V3<S>(-up), V3<S>(n_true));
      REQUIRE((pf2.normal + n_true).norm() < 1e-4);
    }
    {  // every trial runs every case (SECTIONs inside a loop would run once)
      INFO("trial " << trial << ": rolled cameras: the look-down side decides");
      const V3<S> up = Rw.col(0) * S(0.1);      // |n . up| < 0.2
      const V3<S> fwd = -S(0.27) * n_true;      // cameras look down along -n
      const auto pf = fit_plane(pts, up, fwd);
      REQUIRE(pf.normal_rule == "look_down");
      REQUIRE((pf.normal - n_true).norm() < 1e-4);
      const auto pf2 = fit_plane(pts, up, V3<S>(-fwd));
      REQUIRE((pf2.normal + n_true).norm() < 1e-4);
    }
    {  // every trial runs every case (SECTIONs inside a loop would run once)
      INFO("trial " << trial << ": neither rule: ambiguous, deterministic");
      const auto pf = fit_plane(pts, V3<S>(V3<S>::Zero()), V3<S>(V3<S>::Zero()));
      REQUIRE(pf.normal_rule == "ambiguous");
      REQUIRE(std::abs(std::abs(pf.normal.dot(n_true)) - 1) < 1e-4);
      int k = 0;
      pf.normal.cwiseAbs().maxCoeff(&k);
      REQUIRE(pf.normal(k) > 0);
    }
  }
}

TEMPLATE_TEST_CASE("fit_plane: height spread and degenerate centres", "[geometry][plane]", float, double) {
  using S = TestType;
  const Eigen::Matrix<S, 3, 3> I = Eigen::Matrix<S, 3, 3>::Identity();
  const V3<S> up(0, 0, 1), fwd(0, 0, -1);
  SECTION("height std matches the injected noise") {
    const auto pts = ring<S>(I, V3<S>::Zero(), 300, 2000, 0.01, 9);
    const auto pf = fit_plane(pts, up, fwd);
    REQUIRE(pf.height_std == Approx(0.01).epsilon(0.1));
  }
  SECTION("two centres") {
    std::vector<V3<S>> p{V3<S>(0, 0, 0), V3<S>(1, 0, 0)};
    REQUIRE_THROWS_WITH(fit_plane(p, up, fwd), Catch::Contains("at least 3"));
  }
  SECTION("identical centres") {
    std::vector<V3<S>> p(5, V3<S>(1, 2, 3));
    REQUIRE_THROWS_WITH(fit_plane(p, up, fwd), Catch::Contains("coincide"));
  }
  SECTION("collinear centres") {
    std::vector<V3<S>> p;
    for (int i = 0; i < 6; ++i) p.push_back(V3<S>(S(i), S(2 * i), S(-i)));
    REQUIRE_THROWS_WITH(fit_plane(p, up, fwd), Catch::Contains("collinear"));
  }
  SECTION("NaN centre") {
    auto p = ring<S>(I, V3<S>::Zero(), 90, 5);
    p[2].y() = std::numeric_limits<S>::quiet_NaN();
    REQUIRE_THROWS_WITH(fit_plane(p, up, fwd), Catch::Contains("non-finite"));
  }
}

TEST_CASE("fit_plane with coordinates offset by 1e6 (double)", "[geometry][plane]") {
  const auto pts = ring<double>(Eigen::Matrix3d::Identity(), V3<double>(1e6, 1e6, -1e6), 90, 20);
  const auto pf = fit_plane(pts, V3<double>(0, 0, 1), V3<double>(0, 0, -1));
  REQUIRE((pf.normal - V3<double>(0, 0, 1)).norm() < 1e-8);
  REQUIRE(pf.height_std < 1e-8);
}

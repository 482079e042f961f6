#include <catch2/catch.hpp>

#include <random>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/metrics/coverage.hpp"

using namespace orbitforge;
using orbitforge_test::SyntheticOrbit;

template <class S>
static double orbit_tol() { return std::is_same<S, float>::value ? 2e-3 : 1e-8; }

template <class S>
static void require_finite(const OrbitFit<S>& f) {
  REQUIRE(f.orbit.center.allFinite());
  REQUIRE(f.orbit.normal.allFinite());
  REQUIRE(std::isfinite(f.orbit.radius));
  REQUIRE(f.orbit.look_at.allFinite());
  for (const auto& c : f.cameras) REQUIRE(c.is_finite());
}

TEMPLATE_TEST_CASE("fit_orbit recovers a known orbit exactly (random planes, both directions)", "[geometry][orbit]",
                   float, double) {
  using S = TestType;
  std::mt19937 rng(21);
  for (int trial = 0; trial < 6; ++trial) {
    SyntheticOrbit<S> o;
    o.world_R_orbit = orbitforge_test::random_rotation<S>(rng);
    o.center = Eigen::Matrix<S, 3, 1>(S(trial - 2.5), S(0.5 * trial), S(-1));
    o.radius = 0.5 + trial;
    o.count = 20 + 5 * trial;
    o.step_deg = (trial % 2 ? -1.0 : 1.0) * (2 + trial % 3);  // 2..4 degrees, cw and ccw
    o.start_deg = 50.0 * trial - 120;
    INFO("trial " << trial << " step " << o.step_deg);
    OrbitParams p;
    p.elevation_offset_deg = 0;
    const auto fit = fit_orbit(o.cameras(), p);
    require_finite(fit);
    const double r = o.radius;
    REQUIRE(fit.diagnostics.convention == "row2");
    REQUIRE(fit.diagnostics.normal_rule == "camera_up");
    REQUIRE(fit.diagnostics.center_rule == "look_at");
    REQUIRE(fit.diagnostics.center_offset < orbit_tol<S>() * 10);  // look-at and circle centres agree
    REQUIRE((fit.orbit.normal - o.n()).norm() < orbit_tol<S>());
    REQUIRE((fit.orbit.center - o.center).norm() < orbit_tol<S>() * r * 10);
    REQUIRE(fit.orbit.radius == Approx(r).epsilon(orbit_tol<S>()));
    REQUIRE((fit.orbit.look_at - o.look_at()).norm() < orbit_tol<S>() * r * 10);
    REQUIRE(fit.orbit.direction == (o.step_deg > 0 ? 1 : -1));
    REQUIRE(fit.diagnostics.cameras_used == o.count);
    REQUIRE(fit.diagnostics.cameras_skipped.empty());
    REQUIRE(fit.diagnostics.circle_rmse < orbit_tol<S>() * r * 10);
    REQUIRE(fit.diagnostics.height_std < orbit_tol<S>() * r * 10);
    REQUIRE(fit.diagnostics.lookat_error_deg < (std::is_same<S, float>::value ? 0.05 : 1e-5));
    const double span = std::abs(o.step_deg) * (o.count - 1);
    REQUIRE(fit.diagnostics.source_span_deg == Approx(span).margin(1e-2));
    // Canonical view i sits at the source's azimuth start + d i degrees (in the
    // synthetic orbit's own frame), i.e. theta0 and d are right.
    REQUIRE(fit.cameras.size() == 361);
    for (int i : {0, 1, 90, 200, 360}) {
      const auto expect = o.position(o.start_deg + (o.step_deg > 0 ? 1 : -1) * i);
      REQUIRE((fit.cameras[i].center() - expect).norm() < orbit_tol<S>() * r * 10);
    }
    // Source camera t lands in bin |step| t; the arc ends at the last one.
    const int step = int(std::abs(o.step_deg));
    for (int t = 0; t < o.count; ++t) REQUIRE(fit.source[t].bin == step * t);
    REQUIRE(fit.support.arc_end == step * (o.count - 1));
    REQUIRE(fit.diagnostics.observed_bins == o.count);
    REQUIRE(fit.diagnostics.gap_bins == 361 - (step * (o.count - 1) + 1));
  }
}

TEMPLATE_TEST_CASE("canonical views at observed bins coincide with the source cameras (offset 0)",
                   "[geometry][orbit]", float, double) {
  using S = TestType;
  SyntheticOrbit<S> o;
  std::mt19937 rng(4);
  o.world_R_orbit = orbitforge_test::random_rotation<S>(rng);
  o.step_deg = -4;
  o.roll_deg = 7;  // rolled sources: same position and viewing direction, different roll
  OrbitParams p;
  p.elevation_offset_deg = 0;
  const auto src = o.cameras();
  const auto fit = fit_orbit(src, p);
  for (std::size_t t = 0; t < src.size(); ++t) {
    const auto& c = fit.cameras[fit.source[t].bin];
    REQUIRE((c.center() - src[t].camera.center()).norm() < orbit_tol<S>() * 10);
    REQUIRE((c.forward() - src[t].camera.forward()).norm() < orbit_tol<S>() * 10);
    // No roll: the canonical camera's x axis is parallel to the orbit plane.
    REQUIRE(std::abs(c.right().dot(fit.orbit.normal)) < orbit_tol<S>());
    REQUIRE(c.up().dot(fit.orbit.normal) > 0);
  }
}

TEMPLATE_TEST_CASE("elevation offset, intrinsics and coverage of the canonical orbit", "[geometry][orbit]", float,
                   double) {
  using S = TestType;
  SyntheticOrbit<S> o;
  o.height = 1024;
  o.width = 1024;
  o.focal = 800;
  auto src = o.cameras();
  src[3].camera.intrinsics.fx = S(820);  // the median is robust to one odd focal
  src[3].camera.intrinsics.fy = S(830);
  OrbitParams p;  // offset 10, 896x512
  const auto fit = fit_orbit(src, p);
  REQUIRE(fit.intrinsics.fy == Approx(400));
  REQUIRE(fit.intrinsics.fx == Approx(400));
  REQUIRE(fit.intrinsics.cx == Approx(448));
  REQUIRE(fit.intrinsics.cy == Approx(256));
  REQUIRE(fit.intrinsics.width == 896);
  REQUIRE(fit.intrinsics.height == 512);
  const double lift = o.radius * std::tan(10 * M_PI / 180);
  std::vector<S> az;
  for (int i = 0; i < 361; ++i) {
    const auto& c = fit.cameras[i];
    const Eigen::Matrix<S, 3, 1> d = c.center() - fit.orbit.center;
    REQUIRE(d.dot(fit.orbit.normal) == Approx(lift).epsilon(1e-4));
    REQUIRE((d - d.dot(fit.orbit.normal) * fit.orbit.normal).norm() == Approx(o.radius).epsilon(1e-4));
    // Still aimed at the look-at point.
    REQUIRE((c.forward() - (fit.orbit.look_at - c.center()).normalized()).norm() < 1e-4);
    az.push_back(orbit_azimuth_deg<S>(c.center(), fit.orbit.center, fit.orbit.e1, fit.orbit.e2));
  }
  REQUIRE((fit.cameras[0].center() - fit.cameras[360].center()).norm() < 1e-4);
  const auto cov = orbit_coverage(az);
  REQUIRE(cov.span_deg == Approx(359).margin(1e-2));
  REQUIRE(cov.monotone == Approx(1));
  REQUIRE(cov.closed);
}

TEMPLATE_TEST_CASE("cameras rolled by 90 degrees: the look-down rule orients the normal", "[geometry][orbit]", float,
                   double) {
  using S = TestType;
  for (double roll : {90.0, -90.0}) {
    SyntheticOrbit<S> o;
    o.roll_deg = roll;
    o.elevation_deg = 15.8;
    o.count = 16;
    o.step_deg = 22.5;
    const auto fit = fit_orbit(o.cameras());
    REQUIRE(fit.diagnostics.normal_rule == "look_down");
    REQUIRE((fit.orbit.normal - o.n()).norm() < orbit_tol<S>());
    REQUIRE(fit.orbit.direction == 1);
    REQUIRE(fit.diagnostics.source_span_deg == Approx(337.5).margin(1e-2));
  }
}

TEMPLATE_TEST_CASE("unusable frames are left out and listed", "[geometry][orbit]", float, double) {
  using S = TestType;
  SyntheticOrbit<S> o;
  auto src = o.cameras();
  const auto clean = fit_orbit(src);
  src[2].valid = false;
  src[5].camera.t.x() = std::numeric_limits<S>::quiet_NaN();
  src[7].camera.R(0, 0) = std::numeric_limits<S>::infinity();
  src[9].camera.R *= S(2);  // not a rotation
  src[11].camera.intrinsics.fx = S(0);
  src[0].valid = false;     // the first frame too: theta0 moves to the next usable one
  const auto fit = fit_orbit(src);
  REQUIRE(fit.diagnostics.cameras_used == o.count - 6);
  REQUIRE(fit.diagnostics.cameras_skipped ==
          std::vector<std::string>{"001.jpg", "003.jpg", "006.jpg", "008.jpg", "010.jpg", "012.jpg"});
  REQUIRE(fit.diagnostics.skipped_reasons[0] == "not registered");
  REQUIRE(fit.diagnostics.skipped_reasons[2] == "non-finite pose or intrinsics");
  REQUIRE(fit.diagnostics.skipped_reasons[4] == "rotation is not a proper rotation");
  REQUIRE(fit.diagnostics.skipped_reasons[5] == "non-positive focal length");
  REQUIRE(fit.source.front().name == "002.jpg");
  REQUIRE(fit.source.front().input_index == 1);
  REQUIRE(fit.source.front().bin == 0);
  REQUIRE((fit.orbit.center - clean.orbit.center).norm() < orbit_tol<S>() * 10);
  REQUIRE(fit.orbit.radius == Approx(clean.orbit.radius).epsilon(orbit_tol<S>()));
  REQUIRE((fit.cameras[0].center() - src[1].camera.center()).norm() > 0.01);  // offset 10: raised
}

TEMPLATE_TEST_CASE("fit_orbit: degenerate inputs give clear errors", "[geometry][orbit]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  SyntheticOrbit<S> o;
  const auto src = o.cameras();
  SECTION("cameras without an image size: the error says so, with a count and an example") {
    auto no_size = src;
    for (auto& f : no_size) f.camera.intrinsics.width = f.camera.intrinsics.height = 0;
    no_size[3].valid = false;
    REQUIRE_THROWS_WITH(fit_orbit(no_size), Catch::Contains("got 0 of " + std::to_string(src.size())) &&
                                                Catch::Contains(std::to_string(src.size() - 1) +
                                                                " skipped: unknown image size (e.g. '001.jpg')") &&
                                                Catch::Contains("1 skipped: not registered (e.g. '004.jpg')"));
  }
  SECTION("one or two cameras") {
    REQUIRE_THROWS_WITH(fit_orbit(std::vector<FrameCamera<S>>(src.begin(), src.begin() + 1)),
                        Catch::Contains("at least 3 usable"));
    REQUIRE_THROWS_WITH(fit_orbit(std::vector<FrameCamera<S>>(src.begin(), src.begin() + 2)),
                        Catch::Contains("at least 3 usable"));
    REQUIRE_THROWS_WITH(fit_orbit(std::vector<FrameCamera<S>>{}), Catch::Contains("at least 3 usable"));
  }
  SECTION("all frames NaN") {
    auto bad = src;
    for (auto& f : bad) f.camera.t.setConstant(std::numeric_limits<S>::quiet_NaN());
    REQUIRE_THROWS_WITH(fit_orbit(bad), Catch::Contains("at least 3 usable"));
  }
  SECTION("identical centres (a camera turning in place)") {
    std::vector<FrameCamera<S>> same;
    for (int i = 0; i < 10; ++i) {
      const S a = S(i * 0.3);
      same.push_back({"x", Camera<S>::look_at(Vec3(1, 2, 3), Vec3(1 + std::cos(a), 2 + std::sin(a), 3), Vec3(0, 0, 1)),
                      true});
      same.back().camera.intrinsics = src[0].camera.intrinsics;
    }
    REQUIRE_THROWS_WITH(fit_orbit(same), Catch::Contains("coincide"));
  }
  SECTION("collinear centres (a dolly past the object)") {
    std::vector<FrameCamera<S>> line;
    for (int i = 0; i < 10; ++i) {
      line.push_back({"x", Camera<S>::look_at(Vec3(S(i) - 5, 3, 0), Vec3(0, 0, 0), Vec3(0, 0, 1)), true});
      line.back().camera.intrinsics = src[0].camera.intrinsics;
    }
    REQUIRE_THROWS_WITH(fit_orbit(line), Catch::Contains("collinear"));
  }
  SECTION("parallel optical axes") {
    std::vector<FrameCamera<S>> par;
    for (int i = 0; i < 10; ++i) {
      const Vec3 c(S(std::cos(i * 0.5)), S(std::sin(i * 0.5)), 0);
      par.push_back({"x", Camera<S>::look_at(c, Vec3(c + Vec3(0, 10, 1)), Vec3(0, 0, 1)), true});
      par.back().camera.intrinsics = src[0].camera.intrinsics;
    }
    REQUIRE_THROWS_WITH(fit_orbit(par), Catch::Contains("no forward-axis convention"));
  }
  SECTION("bad parameters") {
    OrbitParams p;
    p.views = 2;
    REQUIRE_THROWS_AS(fit_orbit(src, p), Error);
    p = {};
    p.width = 0;
    REQUIRE_THROWS_AS(fit_orbit(src, p), Error);
    p = {};
    p.elevation_offset_deg = 90;
    REQUIRE_THROWS_AS(fit_orbit(src, p), Error);
  }
}

TEMPLATE_TEST_CASE("fit_orbit: noise, short arcs, transposed rotations", "[geometry][orbit]", float, double) {
  using S = TestType;
  SECTION("noisy centres and axes: radius within 2%, centre within 3% of r") {
    for (unsigned seed : {1u, 2u, 3u}) {
      SyntheticOrbit<S> o;
      o.count = 121;
      o.step_deg = 1.07;  // ~128 degrees, like the paper's median source
      o.noise = 0.01;
      o.angle_noise_deg = 0.5;
      o.seed = seed;
      const auto fit = fit_orbit(o.cameras());
      require_finite(fit);
      REQUIRE(std::abs(fit.orbit.radius / o.radius - 1) < 0.02);
      REQUIRE((fit.orbit.center - o.center).norm() < 0.03 * o.radius);
      REQUIRE(fit.diagnostics.circle_rmse == Approx(0.01).epsilon(0.3));  // radial part of the noise
      REQUIRE(fit.diagnostics.lookat_error_deg < 1.5);
    }
  }
  SECTION("cameras aimed off the orbit axis: the circle centre option, and center_offset shows it") {
    SyntheticOrbit<S> o;
    o.count = 60;
    o.step_deg = 3;
    auto src = o.cameras();
    const Eigen::Matrix<S, 3, 1> shift = S(0.3) * o.e1();
    for (auto& f : src)  // re-aim at a point 0.3 off the axis
      f.camera = Camera<S>::look_at(f.camera.center(), Eigen::Matrix<S, 3, 1>(o.look_at() + shift), o.n(),
                                    f.camera.intrinsics);
    OrbitParams p;
    p.center = OrbitCenter::circle;
    const auto fit = fit_orbit(src, p);
    REQUIRE((fit.orbit.center - o.center).norm() < 1e-3);
    REQUIRE(fit.diagnostics.center_offset == Approx(0.3 / o.radius).epsilon(1e-3));
    const auto fl = fit_orbit(src);  // default: centre under the look-at point
    REQUIRE((fl.orbit.center - (o.center + shift)).norm() < 1e-3);
  }
  SECTION("a 20-degree exact arc is still recovered") {
    SyntheticOrbit<S> o;
    o.count = 21;
    o.step_deg = 1;
    const auto fit = fit_orbit(o.cameras());
    REQUIRE(fit.orbit.radius == Approx(o.radius).epsilon(std::is_same<S, float>::value ? 2e-2 : 1e-6));
    REQUIRE(fit.support.arc_end == 20);
  }
  SECTION("rotations stored transposed: col2 is selected and the orbit is the same") {
    SyntheticOrbit<S> o;
    std::mt19937 rng(8);  // a tilted orbit: under row2 the transposed rows are not all parallel
    o.world_R_orbit = orbitforge_test::random_rotation<S>(rng);
    auto src = o.cameras();
    const auto ref = fit_orbit(src);
    for (auto& f : src) {
      const auto c = f.camera.center();
      f.camera.R.transposeInPlace();
      f.camera.t = -f.camera.R * c;
    }
    const auto fit = fit_orbit(src);
    REQUIRE(fit.diagnostics.convention == "col2");
    REQUIRE((fit.orbit.normal - ref.orbit.normal).norm() < orbit_tol<S>() * 10);
    REQUIRE((fit.orbit.look_at - ref.orbit.look_at).norm() < orbit_tol<S>() * 10);
    OrbitParams p;
    p.convention = ForwardConvention::row2;  // forcing the wrong one is allowed and reported
    const auto forced = fit_orbit(src, p);
    REQUIRE(forced.diagnostics.convention == "row2");
    REQUIRE(forced.diagnostics.lookat_error_deg > 1);
  }
}

TEST_CASE("fit_orbit with coordinates offset by 1e6", "[geometry][orbit]") {
  SECTION("double: exact") {
    SyntheticOrbit<double> o;
    o.center = Eigen::Vector3d(1e6, -1e6, 1e6);
    const auto fit = fit_orbit(o.cameras());
    REQUIRE((fit.orbit.center - o.center).norm() < 1e-6);
    REQUIRE(fit.orbit.radius == Approx(o.radius).epsilon(1e-9));
    REQUIRE((fit.orbit.normal - o.n()).norm() < 1e-8);
  }
  SECTION("float: a radius-2.5 orbit at 1e6 is below float resolution; result is finite or an Error") {
    SyntheticOrbit<float> o;
    o.center = Eigen::Vector3f(1e6f, -1e6f, 1e6f);
    try {
      const auto fit = fit_orbit(o.cameras());
      require_finite(fit);
    } catch (const Error& e) {
      SUCCEED(std::string("Error: ") + e.what());
    }
  }
}

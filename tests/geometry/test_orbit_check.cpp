#include <catch2/catch.hpp>

#include <cstdio>
#include <string>
#include <vector>

#include "geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/orbit_check.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "support/data.hpp"

using namespace orbitforge;

namespace {

// 33 cameras over 125 degrees, as the source arc of a generated orbit video.
template <class S>
orbitforge_test::SyntheticOrbit<S> source_arc() {
  orbitforge_test::SyntheticOrbit<S> o;
  o.count = 33;
  o.step_deg = 125.0 / 32;
  o.radius = 3.7;
  return o;
}

bool mentions(const std::vector<std::string>& warnings, const std::string& word) {
  for (const auto& w : warnings)
    if (w.find(word) != std::string::npos) return true;
  return false;
}

}  // namespace

TEMPLATE_TEST_CASE("check_orbit: a clean arc passes, an under-rotated one is flagged", "[geometry][orbit_check]", float,
                   double) {
  using S = TestType;
  auto orbit = source_arc<S>();
  orbit.noise = 0.003;  // centre jitter of the size the recorded videos show (RMSE ~0.001 r)
  orbit.angle_noise_deg = 0.05;
  const auto clean = orbit.cameras();
  const auto fit = fit_orbit(clean);
  const OrbitCheck ok = check_orbit(clean, fit);
  INFO((ok.warnings.empty() ? std::string() : ok.warnings.front()));
  CHECK(ok.ok);
  CHECK(ok.warnings.empty());
  CHECK(ok.flagged_frames.empty());
  CHECK(ok.median_step_deg == Approx(125.0 / 32).epsilon(0.02));
  CHECK(ok.steps_deg.size() == 32);
  CHECK(ok.trend_halves == Approx(1).margin(0.03));

  // Registration drift: the rotation after the middle frame compressed by 0.8.
  for (double factor : {0.8, 0.64}) {
    INFO("compression " << factor);
    auto drifted = clean;
    orbitforge_test::under_rotate(drifted, 16, factor, orbit.center, orbit.n());
    const auto dfit = fit_orbit(drifted);
    const OrbitCheck bad = check_orbit(drifted, dfit);
    std::printf("check_orbit %s, compression %.2f: halves %.3f, split %.3f at %s, circle rmse/r %.4f\n",
                sizeof(S) == 4 ? "float" : "double", factor, bad.trend_halves, bad.trend_split,
                dfit.source[std::size_t(bad.trend_split_frame)].name.c_str(), bad.circle_rmse);
    CHECK_FALSE(bad.ok);
    CHECK(mentions(bad.warnings, "second half"));
    CHECK(bad.trend_halves == Approx(factor).margin(0.03));
    // The split that best separates the speeds is at the compressed frame (+-1).
    CHECK(std::abs(bad.trend_split_frame - 17) <= 1);
    // Centres stay on the circle, so only the speed shows the drift.
    CHECK(bad.circle_rmse < 0.01);
  }

  // Drift that sets in late is caught by the split, not the halves.
  {
    auto late = clean;
    orbitforge_test::under_rotate(late, 23, 0.6, orbit.center, orbit.n());
    const OrbitCheck bad = check_orbit(late, fit_orbit(late));
    CHECK_FALSE(bad.ok);
    CHECK(bad.trend_split < 0.87);
    CHECK(std::abs(bad.trend_split_frame - 24) <= 1);
  }

  // One frame registered in the wrong place: its step and the next are flagged by name.
  {
    auto jump = clean;
    auto& c = jump[10].camera;
    const Eigen::Matrix<S, 3, 1> o = c.center();
    const Eigen::Matrix<S, 3, 3> Q =
        Eigen::AngleAxis<S>(S(3.0 * M_PI / 180), orbit.n()).toRotationMatrix();  // +3 deg on a 3.9 deg step
    c.R = c.R * Q.transpose();
    c.t = -c.R * (Q * (o - orbit.center) + orbit.center);
    const OrbitCheck bad = check_orbit(jump, fit_orbit(jump));
    CHECK_FALSE(bad.ok);
    CHECK(bad.flagged_frames == std::vector<std::string>{"011.jpg", "012.jpg"});
  }

  // A camera off the circle and off the look-at point.
  {
    auto off = clean;
    auto& c = off[20].camera;
    const Eigen::Matrix<S, 3, 1> o = c.center() + S(0.4) * orbit.n();
    c.t = -c.R * o;
    const OrbitCheck bad = check_orbit(off, fit_orbit(off));
    CHECK_FALSE(bad.ok);
    CHECK(mentions(bad.warnings, "heights"));
  }
}

TEST_CASE("check_orbit: unregistered frames are gaps, not speed changes", "[geometry][orbit_check]") {
  auto orbit = source_arc<double>();
  auto cams = orbit.cameras();
  for (int i : {5, 6, 20}) cams[i].valid = false;
  const auto fit = fit_orbit(cams);
  const OrbitCheck c = check_orbit(cams, fit);
  CHECK(c.ok);
  CHECK(c.steps_deg.size() == 29);
  for (double s : c.steps_deg) CHECK(s == Approx(125.0 / 32).epsilon(1e-6));
}

TEMPLATE_TEST_CASE("check_orbit: silent on the recorded videos' cameras", "[geometry][orbit_check][data]", float,
                   double) {
  using S = TestType;
  if (!orbitforge_test::have_shared_data("v3d")) return;
  for (const char* video : {"cool_teddy", "doll", "robot", "sunflower", "corgi_bread"}) {
    const auto all = colmap_frame_cameras<S>(read_colmap_model(orbitforge_test::shared_path(std::string("v3d/") + video)));
    for (const FrameRange range : {FrameRange{1, 33}, FrameRange{1, -1}}) {
      const auto cams = select_frames(all, range);
      const OrbitCheck c = check_orbit(cams, fit_orbit(cams));
      std::printf("check_orbit %-11s %-6s frames %2zu: median step %.3f, halves %.3f, split %.3f, rmse/r %.4f, "
                  "height/r %.4f, look-at %.3f deg\n",
                  video, sizeof(S) == 4 ? "float" : "double", cams.size(), c.median_step_deg, c.trend_halves,
                  c.trend_split, c.circle_rmse, c.height_std, c.lookat_error_deg);
      INFO(video << " frames " << cams.size() << ": " << (c.warnings.empty() ? std::string() : c.warnings.front()));
      CHECK(c.ok);
      CHECK(c.flagged_frames.empty());
    }
  }
  std::fflush(stdout);
}

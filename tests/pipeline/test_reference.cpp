// Scoring on the user's path (pipeline/report/reference.hpp): a reference model of every
// frame, in its own gauge, is aligned to cameras estimated from the source frames
// alone; gap frames and withheld frames are scored at its cameras, and nothing
// the method reads changes.
#include <catch2/catch.hpp>

#include <cmath>

#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"
#include "orbitforge/pipeline/report/reference.hpp"

using namespace orbitforge;

namespace reference_test {

SyntheticInputParams small_input() {
  SyntheticInputParams sp;
  sp.width = sp.height = 32;
  sp.focal = 40;
  sp.object_gaussians = 200;
  sp.ground_gaussians = 100;
  return sp;
}

// The user's view of `all`: the same frames, cameras in another gauge (scale,
// turn, shift), only the source frames estimated, their images kept.
PipelineInput<double> user_view(const PipelineInput<double>& all, const Similarity3& gauge) {
  PipelineInput<double> u = all;
  std::vector<char> src(u.cameras.size(), 0);
  for (int f : u.source) src[std::size_t(f)] = 1;
  for (std::size_t i = 0; i < u.cameras.size(); ++i) {
    u.cameras[i].camera = gauge.apply(u.cameras[i].camera);
    if (!src[i]) {
      u.cameras[i].valid = false;
      u.images[i] = Image<double>();
    }
  }
  return u;
}

Similarity3 some_gauge() {
  Similarity3 g;
  g.scale = 2.5;
  g.R = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, -1).normalized()).toRotationMatrix();
  g.t = Eigen::Vector3d(-3, 11, 4);
  return g;
}

TEST_CASE("attach_reference: gap and withheld frames get the aligned reference's cameras", "[pipeline][reference]") {
  const PipelineInput<double> all = synthetic_pipeline_input<double>(small_input(), 1);
  const Similarity3 gauge = some_gauge();
  PipelineInput<double> user = user_view(all, gauge);
  withhold_every(user, 8);
  REQUIRE(!user.withheld.empty());
  const auto before = user;

  const CameraAlignment a = attach_reference(user, all, "all frames");
  CHECK(a.cameras == int(user.source.size()));
  CHECK(std::abs(a.transform.scale - gauge.scale) < 1e-9);
  CHECK(a.centre_rms_relative < 1e-9);
  CHECK(a.rotation_max_deg < 1e-6);
  REQUIRE(user.reference);

  std::vector<char> src(user.cameras.size(), 0);
  for (int f : user.source) src[std::size_t(f)] = 1;
  for (std::size_t i = 0; i < user.cameras.size(); ++i) {
    const Camera<double> expect = gauge.apply(all.cameras[i].camera);
    if (src[i]) {  // the method's frames are untouched
      CHECK((user.cameras[i].camera.R - before.cameras[i].camera.R).norm() == 0);
      CHECK((user.cameras[i].camera.t - before.cameras[i].camera.t).norm() == 0);
      CHECK(user.images[i].data == before.images[i].data);
      CHECK(user.scoring_cameras.count(int(i)) == (user.is_withheld(int(i)) ? 1u : 0u));
    } else {
      REQUIRE(user.cameras[i].valid);
      CHECK((user.cameras[i].camera.center() - expect.center()).norm() < 1e-9);
      CHECK(user.images[i].data == all.images[i].data);
    }
    CHECK((user.scoring_camera(int(i)).center() - expect.center()).norm() < 1e-9);
  }
  CHECK(user.points == before.points);
  CHECK(input_hash(user) != input_hash(before));
}

TEST_CASE("reference_report: an under-rotated estimate shows as gap azimuth error", "[pipeline][reference]") {
  const PipelineInput<double> all = synthetic_pipeline_input<double>(small_input(), 1);
  OrbitParams op;
  op.views = 121;
  op.width = op.height = 32;
  auto report_of = [&](double compression) {
    PipelineInput<double> user = user_view(all, some_gauge());
    // Compress the estimated arc after its middle frame about the orbit's axis.
    std::vector<FrameCamera<double>> src;
    for (int f : user.source) src.push_back(user.cameras[std::size_t(f)]);
    const OrbitFit<double> truth = fit_orbit(src, op);
    const int mid = user.source[user.source.size() / 2];
    const double az_mid = orbit_azimuth_deg<double>(user.cameras[std::size_t(mid)].camera.center(), truth.orbit.center,
                                                    truth.orbit.e1, truth.orbit.e2);
    for (int f : user.source) {
      if (f <= mid) continue;
      auto& c = user.cameras[std::size_t(f)].camera;
      const double az = orbit_azimuth_deg<double>(c.center(), truth.orbit.center, truth.orbit.e1, truth.orbit.e2);
      const double turn = (compression - 1) * wrap_deg_180(az - az_mid) * 3.14159265358979 / 180;
      const Eigen::Matrix3d R = Eigen::AngleAxisd(turn, truth.orbit.normal).toRotationMatrix();
      const Eigen::Vector3d centre = truth.orbit.center + R * (c.center() - truth.orbit.center);
      c = Camera<double>::from_world_T_camera(R * c.R.transpose(), centre, c.intrinsics);
    }
    attach_reference(user, all, "all frames");
    src.clear();
    for (int f : user.source) src.push_back(user.cameras[std::size_t(f)]);
    return reference_report(user, fit_orbit(src, op));
  };
  const nlohmann::json clean = report_of(1.0), bent = report_of(0.8);
  const double clean_err = clean["gap_azimuth_error_deg"]["mean_abs"];
  const double bent_err = bent["gap_azimuth_error_deg"]["mean_abs"];
  INFO("gap azimuth error, clean " << clean_err << " deg, under-rotated " << bent_err << " deg");
  CHECK(clean["gap_azimuth_error_deg"]["frames"].get<int>() == int(all.cameras.size()) - 33);
  CHECK(clean_err < 3);
  CHECK(bent_err > clean_err + 10);
  CHECK(bent["alignment"]["rotation_max_deg"].get<double>() > clean["alignment"]["rotation_max_deg"].get<double>());
  const double arc_user = bent["source_arc_deg"]["user"], arc_ref = bent["source_arc_deg"]["reference"];
  CHECK(arc_user < arc_ref - 5);
}

TEST_CASE("attach_reference refuses a reference of another video or size", "[pipeline][reference]") {
  const PipelineInput<double> all = synthetic_pipeline_input<double>(small_input(), 1);
  PipelineInput<double> user = user_view(all, some_gauge());
  PipelineInput<double> shorter = all;
  shorter.cameras.pop_back();
  shorter.images.pop_back();
  CHECK_THROWS_WITH(attach_reference(user, shorter, "short"), Catch::Contains("89 frames, the input has 90"));
  PipelineInput<double> bigger = all;
  bigger.width = 64;
  CHECK_THROWS_WITH(attach_reference(user, bigger, "big"), Catch::Contains("loaded at 64x32"));
}

}  // namespace reference_test

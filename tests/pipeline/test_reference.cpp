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

TEST_CASE("reference_report: a reference that stops short of its first frame shows a wide last step",
          "[pipeline][reference]") {
  // 90 frames all the way round: frame 90 is one 4-degree step before frame 1.
  SyntheticInputParams sp = small_input();
  sp.arc_deg = 360.0;
  const PipelineInput<double> all = synthetic_pipeline_input<double>(sp, 1);
  OrbitParams op;
  op.views = 121;
  op.width = op.height = 32;
  std::vector<FrameCamera<double>> every(all.cameras.begin(), all.cameras.end());
  const OrbitFit<double> truth = fit_orbit(every, op);
  auto loop_of = [&](double turn_per_frame_scale) {
    // The reference turns by `scale` of each true step about the orbit's axis
    // from frame 1 on, as a model that under-rotates from frame to frame does.
    PipelineInput<double> ref = all;
    const double az0 = orbit_azimuth_deg<double>(all.cameras[0].camera.center(), truth.orbit.center,
                                                 truth.orbit.e1, truth.orbit.e2);
    for (auto& fc : ref.cameras) {
      auto& c = fc.camera;
      const double az = orbit_azimuth_deg<double>(c.center(), truth.orbit.center, truth.orbit.e1, truth.orbit.e2);
      const double travelled = wrap_deg_360(double(truth.orbit.direction) * (az - az0));
      const double turn = -double(truth.orbit.direction) * (1 - turn_per_frame_scale) * travelled * 3.14159265358979 / 180;
      const Eigen::Matrix3d R = Eigen::AngleAxisd(turn, truth.orbit.normal).toRotationMatrix();
      const Eigen::Vector3d centre = truth.orbit.center + R * (c.center() - truth.orbit.center);
      c = Camera<double>::from_world_T_camera(R * c.R.transpose(), centre, c.intrinsics);
    }
    PipelineInput<double> user = user_view(all, some_gauge());
    attach_reference(user, ref, "all frames");
    std::vector<FrameCamera<double>> src;
    for (int f : user.source) src.push_back(user.cameras[std::size_t(f)]);
    return reference_report(user, fit_orbit(src, op))["loop"];
  };
  const nlohmann::json closed = loop_of(1.0), short_of = loop_of(0.96);
  INFO("closed: " << closed.dump() << "; under-rotated: " << short_of.dump());
  REQUIRE(closed.is_object());
  CHECK(closed["frames"].get<int>() == 90);
  CHECK(closed["mean_step_deg"].get<double>() == Approx(4.0).margin(0.1));
  CHECK(closed["last_to_first_deg"].get<double>() == Approx(4.0).margin(1.5));
  // 4 % short a step: 89 steps of 3.84 degrees, and 18 degrees back to frame 1.
  CHECK(short_of["mean_step_deg"].get<double>() == Approx(3.84).margin(0.1));
  CHECK(short_of["last_to_first_deg"].get<double>() > 3 * short_of["mean_step_deg"].get<double>());
  // No step between neighbours is that wide (the cameras' noise moves each by about 1 degree).
  CHECK(short_of["largest_step_deg"].get<double>() < 2 * short_of["mean_step_deg"].get<double>());
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


TEST_CASE("carry_camera: a held-out view is placed in another estimate as its neighbours are",
          "[pipeline][reference]") {
  // `to`: 40 cameras on a circle around the origin, looking at it. `from`: the same
  // cameras in another gauge, each turned by a disagreement that changes slowly
  // along the orbit (up to 1.5 degrees), as two estimates of one orbit differ.
  const int views = 40;
  const Similarity3 gauge = some_gauge();  // from -> to
  Similarity3 inverse;
  inverse.scale = 1 / gauge.scale;
  inverse.R = gauge.R.transpose();
  inverse.t = -inverse.scale * (inverse.R * gauge.t);
  Intrinsics<double> k;
  k.fx = k.fy = 50, k.cx = 16, k.cy = 16, k.width = k.height = 32;
  auto truth = [&](int i) {
    const double a = 2 * Constants<double>::pi() * i / views;
    const Eigen::Matrix3d wrc = Eigen::AngleAxisd(a + Constants<double>::pi(), Eigen::Vector3d::UnitY()).toRotationMatrix();
    return Camera<double>::from_world_T_camera(wrc, Eigen::Vector3d(3 * std::sin(a), 0.5, 3 * std::cos(a)), k);
  };
  auto other_estimate = [&](int i) {
    const Camera<double> c = truth(i);
    const double deg = 1.5 * std::sin(2 * Constants<double>::pi() * i / views);
    const Eigen::Matrix3d turn = Eigen::AngleAxisd(deg * Constants<double>::pi() / 180, Eigen::Vector3d(1, 0.3, 0).normalized()).toRotationMatrix();
    return inverse.apply(Camera<double>::from_world_T_camera(turn * c.R.transpose(), c.center(), k));
  };
  std::vector<double> position;
  std::vector<Camera<double>> from, to;
  for (int i = 0; i < views; ++i) {
    if (i % 2 == 1) continue;  // the odd views are held out
    position.push_back(i);
    from.push_back(other_estimate(i));
    to.push_back(truth(i));
  }
  const EstimatePairs<double> e = estimate_pairs(position, from, to, views + 1);
  CHECK(std::abs(e.global.transform.scale - gauge.scale) < 0.05 * gauge.scale);
  double global_error = 0, carried_error = 0;
  for (int i = 1; i < views; i += 2) {
    const Camera<double> want = truth(i);
    const Camera<double> global = e.global.transform.apply(other_estimate(i));
    const Camera<double> carried = carry_camera(other_estimate(i), double(i), e, 4);
    global_error += rotation_angle_deg(global.R, want.R) / (views / 2);
    carried_error += rotation_angle_deg(carried.R, want.R) / (views / 2);
    CHECK((carried.center() - want.center()).norm() < 0.05);
    CHECK(carried.intrinsics.fx == k.fx);
  }
  CHECK(global_error > 0.5);                 // a similarity leaves the disagreement ...
  CHECK(carried_error < 0.2 * global_error); // ... the neighbours take most of it away
  // Without neighbours the camera is only moved by the similarity.
  const Camera<double> plain = carry_camera(other_estimate(3), 3.0, e, 0);
  CHECK((plain.center() - e.global.transform.apply(other_estimate(3)).center()).norm() < 1e-12);
}

}  // namespace reference_test

// The cameras stage's orbit refinement on COLMAP models built from a synthetic
// rigid scene: an under-rotated arc is caught by the check and brought back by
// the default mode, a clean one is left as it is, and the refined model goes
// through the text writer and reader unchanged.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "geometry/synthetic_bundle.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/pipeline/inputs/orbit_refinement.hpp"
#include "orbitforge/pipeline/report/report_markdown.hpp"

using namespace orbitforge;

namespace orbit_refinement_test {

// The scene's cameras (`cameras`, the points triangulated from them) and its
// observations as a COLMAP model: one SIMPLE_PINHOLE camera, images 00001.png ...
ColmapModel scene_model(const orbitforge_test::RigidScene<double>& sc, const std::vector<Camera<double>>& cameras) {
  const auto points = orbitforge_test::triangulate(cameras, sc.points.size(), sc.observations);
  ColmapModel m;
  const auto& k = cameras.front().intrinsics;
  m.cameras[1] = ColmapCamera{1, "SIMPLE_PINHOLE", k.width, k.height, {k.fx, k.cx, k.cy}};
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    ColmapImage im;
    im.id = int(i) + 1;
    im.camera_id = 1;
    char name[32];
    std::snprintf(name, sizeof name, "%05zu.png", i + 1);
    im.name = name;
    set_colmap_pose(im, cameras[i].R, cameras[i].t);
    m.images[im.id] = im;
  }
  for (std::size_t j = 0; j < points.size(); ++j) {
    ColmapPoint p;
    p.id = std::int64_t(j) + 100;  // ids are not indices
    p.xyz = points[j];
    m.points.push_back(p);
  }
  for (const auto& o : sc.observations) {
    ColmapImage& im = m.images.at(o.camera + 1);
    ColmapPoint& p = m.points[std::size_t(o.point)];
    p.track_images.push_back(im.id);
    p.track_point2D.push_back(int(im.points2D.size()));
    im.points2D.push_back({o.xy, p.id});
  }
  return m;
}

// Azimuth of each camera from the first, about the true orbit axis.
std::vector<double> relative_azimuths(const ColmapModel& m, const orbitforge_test::SyntheticOrbit<double>& o) {
  std::vector<double> az;
  for (const auto& f : colmap_frame_cameras<double>(m))
    az.push_back(orbit_azimuth_deg<double>(f.camera.center(), o.center, o.e1(), o.e2()));
  for (std::size_t i = az.size(); i-- > 0;) az[i] = wrap_deg_360(az[i] - az[0]);
  return az;
}

double max_rotation_between_deg(const ColmapModel& a, const ColmapModel& b) {
  const auto ca = colmap_frame_cameras<double>(a), cb = colmap_frame_cameras<double>(b);
  REQUIRE(ca.size() == cb.size());
  double worst = 0;
  for (std::size_t i = 0; i < ca.size(); ++i)
    worst = std::max(worst, Eigen::AngleAxisd(ca[i].camera.R * cb[i].camera.R.transpose()).angle() * 180 / M_PI);
  return worst;
}

TEST_CASE("orbit refinement: an under-rotated arc is caught and brought back by default", "[pipeline][orbit_refine]") {
  const auto sc = orbitforge_test::rigid_scene<double>(2000, 0.5, 21);
  const double truth = relative_azimuths(scene_model(sc, sc.cameras), sc.orbit).back();  // 125 degrees
  // Registration drift after the middle frame: the later arc compressed by 0.8.
  const ColmapModel drifted = scene_model(sc, orbitforge_test::under_rotated(sc, 16, 0.8));
  const double drifted_arc = relative_azimuths(drifted, sc.orbit).back();
  REQUIRE(std::abs(drifted_arc - truth) > 10);  // the corruption is real

  const OrbitRefinement r = refine_model_on_orbit(drifted, OrbitRefine::flagged);
  INFO(r.summary);
  CHECK_FALSE(r.before.ok);  // the check warns before the refinement ...
  REQUIRE(r.applied);        // ... so the default mode refines
  CHECK(r.json["applied"] == true);
  CHECK(r.json["check_before"]["ok"] == false);
  CHECK(r.after.ok);
  const double refined_arc = relative_azimuths(r.model, sc.orbit).back();
  CHECK(std::abs(refined_arc - truth) < 2);
  CHECK(std::abs(r.arc_after_deg - truth) < 2);
  CHECK(r.rms_after_px < r.rms_before_px);
  // Images, keypoints and tracks are kept; only poses and positions change.
  REQUIRE(r.model.images.size() == drifted.images.size());
  for (const auto& [id, im] : drifted.images) {
    CHECK(r.model.images.at(id).name == im.name);
    CHECK(r.model.images.at(id).points2D.size() == im.points2D.size());
  }
  REQUIRE(r.model.points.size() == drifted.points.size());
  CHECK(r.model.points[7].track_images == drifted.points[7].track_images);

  // What the cameras stage writes is what the pipeline reads back.
  const auto dir = std::filesystem::temp_directory_path() / ("orbitforge_refine_" + std::to_string(std::random_device{}()));
  write_colmap_model_text(dir.string(), r.model);
  const ColmapModel back = read_colmap_model(dir.string());
  std::filesystem::remove_all(dir);
  CHECK(max_rotation_between_deg(back, r.model) < 1e-9);
  CHECK(std::abs(relative_azimuths(back, sc.orbit).back() - refined_arc) < 1e-9);

  // The report says what was done.
  nlohmann::json report = {{"cameras", {{"path", "estimated"}, {"estimate", {{"focal_px", 450.0}, {"chosen_by", "mapper"}}}}}};
  report["cameras"]["estimate"]["orbit_refinement"] = r.json;
  const std::string md = report_markdown(report);
  CHECK_THAT(md, Catch::Contains("Orbit refinement (flagged): applied, the orbit check warned: angular speed drifts"));

  // Off leaves the model alone even when the check warns.
  const OrbitRefinement off = refine_model_on_orbit(drifted, OrbitRefine::off);
  CHECK_FALSE(off.applied);
  CHECK_FALSE(off.before.ok);
  CHECK(max_rotation_between_deg(off.model, drifted) < 1e-6);
}

TEST_CASE("orbit refinement: a clean arc passes the check and is left alone", "[pipeline][orbit_refine]") {
  const auto sc = orbitforge_test::rigid_scene<double>(2000, 0.5, 5);
  const ColmapModel clean = scene_model(sc, sc.cameras);
  const OrbitRefinement r = refine_model_on_orbit(clean, OrbitRefine::flagged);
  INFO(r.summary);
  CHECK(r.before.ok);
  CHECK_FALSE(r.applied);
  CHECK(r.why == "the cameras pass the orbit check");
  CHECK(max_rotation_between_deg(r.model, clean) < 1e-6);
  CHECK(r.model.points[3].xyz == clean.points[3].xyz);

  // Asked for anyway, it moves a clean arc very little.
  const OrbitRefinement always = refine_model_on_orbit(clean, OrbitRefine::always);
  REQUIRE(always.applied);
  CHECK(always.after.ok);
  CHECK(always.max_rotation_change_deg < 0.3);
}

TEST_CASE("orbit refinement: a model without an orbit is left alone with the reason", "[pipeline][orbit_refine]") {
  const auto sc = orbitforge_test::rigid_scene<double>(200, 0.5, 9);
  ColmapModel two = scene_model(sc, sc.cameras);
  while (two.images.size() > 2) two.images.erase(std::prev(two.images.end()));
  const OrbitRefinement r = refine_model_on_orbit(two, OrbitRefine::always);
  CHECK_FALSE(r.applied);
  CHECK_THAT(r.why, Catch::StartsWith("no orbit to check against"));
  CHECK_THROWS_WITH(parse_orbit_refine("sometimes"), Catch::Contains("not one of off, flagged, always"));
  CHECK(parse_orbit_refine("flagged") == OrbitRefine::flagged);
}

}  // namespace orbit_refinement_test

#pragma once
// orbit.json: the canonical orbit, its support bins, the completion layout and the
// fitting diagnostics, as fit_orbit writes it and render_orbit / the pipeline read
// it. Everything is in the input model's world frame (the pipeline's fit, made in
// its normalised frame, is moved back on writing); camera poses use the
// library's convention x_cam = R x_world + t (OpenCV axes), R written as three rows.
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/geometry/orbit_check.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/metrics/coverage.hpp"
#include "orbitforge/splat/scene_frame.hpp"

namespace orbitforge {

namespace orbit_file_detail {

template <class Derived>
nlohmann::json vec_json(const Eigen::MatrixBase<Derived>& v) {
  nlohmann::json a = nlohmann::json::array();
  for (int i = 0; i < v.size(); ++i) a.push_back(double(v[i]));
  return a;
}

template <class Scalar>
nlohmann::json camera_json(int index, Scalar azimuth_deg, const Camera<Scalar>& c) {
  nlohmann::json R = nlohmann::json::array();
  for (int r = 0; r < 3; ++r) R.push_back(vec_json(c.R.row(r).transpose()));
  const auto& k = c.intrinsics;
  return {{"index", index},          {"azimuth_deg", double(azimuth_deg)},
          {"width", k.width},        {"height", k.height},
          {"fx", double(k.fx)},      {"fy", double(k.fy)},
          {"cx", double(k.cx)},      {"cy", double(k.cy)},
          {"R", R},                  {"t", vec_json(c.t)}};
}

}  // namespace orbit_file_detail

// Azimuths (degrees) of the canonical views, for coverage of the canonical orbit.
template <class Scalar>
std::vector<Scalar> canonical_azimuths(const OrbitFit<Scalar>& fit) {
  std::vector<Scalar> az;
  for (int i = 0; i < fit.views; ++i) az.push_back(fit.orbit.azimuth_deg(i, fit.views));
  return az;
}

// `frame`: the fit is in that frame's normalised coordinates and orbit.json is
// written in the model's own (positions and lengths moved back in double;
// directions and angles are the same in both).
template <class Scalar>
nlohmann::json orbit_json(const OrbitFit<Scalar>& fit, const CompletionLayout& layout, const SceneFrame& frame = {}) {
  using orbit_file_detail::vec_json;
  const auto& g = fit.orbit;
  const auto& k = fit.intrinsics;
  const double length = 1 / frame.scale;
  auto point = [&](const Eigen::Matrix<Scalar, 3, 1>& x) { return vec_json(frame.to_user(x.template cast<double>())); };
  nlohmann::json j;
  j["orbit"] = {{"center", point(g.center)},
                {"normal", vec_json(g.normal)},
                {"e1", vec_json(g.e1)},
                {"e2", vec_json(g.e2)},
                {"radius", double(g.radius) * length},
                {"theta0_deg", double(g.theta0_deg)},
                {"direction", g.direction},
                {"look_at", point(g.look_at)},
                {"elevation_offset_deg", double(g.elevation_offset_deg)},
                {"views", fit.views},
                {"width", k.width},
                {"height", k.height},
                {"fx", double(k.fx)},
                {"fy", double(k.fy)},
                {"cx", double(k.cx)},
                {"cy", double(k.cy)}};
  const auto& d = fit.diagnostics;
  nlohmann::json skipped = nlohmann::json::array();
  for (std::size_t i = 0; i < d.cameras_skipped.size(); ++i)
    skipped.push_back(d.cameras_skipped[i]);
  nlohmann::json reasons = nlohmann::json::object();
  for (std::size_t i = 0; i < d.cameras_skipped.size() && i < d.skipped_reasons.size(); ++i)
    reasons[d.cameras_skipped[i]] = d.skipped_reasons[i];
  j["diagnostics"] = {{"cameras_used", d.cameras_used},
                      {"cameras_skipped", skipped},
                      {"skipped_reasons", reasons},
                      {"source_span_deg", double(d.source_span_deg)},
                      {"circle_rmse", double(d.circle_rmse) * length},
                      {"radius_std", double(d.radius_std) * length},
                      {"height_std", double(d.height_std) * length},
                      {"lookat_error_deg", double(d.lookat_error_deg)},
                      {"convention", d.convention},
                      {"normal_rule", d.normal_rule},
                      {"observed_bins", d.observed_bins},
                      {"gap_bins", d.gap_bins}};
  j["support"] = {{"observed", fit.support.observed}, {"arc", fit.support.arc}, {"gap", fit.support.gap}};
  nlohmann::json source = nlohmann::json::array();
  for (const auto& s : fit.source)
    source.push_back({{"name", s.name}, {"bin", s.bin}, {"azimuth_deg", double(s.azimuth_deg)}});
  j["source"] = source;
  nlohmann::json anchors = nlohmann::json::array();
  for (const auto& a : layout.anchors)
    anchors.push_back({{"synthetic", a.synthetic}, {"canonical", a.canonical}, {"name", a.name}});
  j["layout"] = {{"frames", layout.frames},
                 {"start", layout.start},
                 {"synthetic_to_canonical", layout.synthetic_to_canonical},
                 {"anchors", anchors},
                 {"anchor_index_error", {{"mean", layout.anchor_error_mean}, {"max", layout.anchor_error_max}}}};
  const auto az = canonical_azimuths(fit);
  const auto cov = orbit_coverage(az);
  j["coverage"] = {{"A", double(cov.span_deg)}, {"M", double(cov.monotone)}, {"closed", cov.closed}};
  nlohmann::json cams = nlohmann::json::array();
  for (int i = 0; i < fit.views; ++i)
    cams.push_back(orbit_file_detail::camera_json(i, double(az[i]), frame.to_user_for_file(fit.cameras[i])));
  j["cameras"] = cams;
  return j;
}

template <class Scalar>
void write_orbit_json(const std::string& path, const OrbitFit<Scalar>& fit, const CompletionLayout& layout) {
  write_file_atomic(path, orbit_json(fit, layout).dump(1) + "\n");
}

// The canonical cameras of an orbit.json (or of any {"cameras": [...]} file),
// checked: each needs width, height, fx, fy, cx, cy, R (3x3) and t (3), finite.
template <class Scalar>
std::vector<Camera<Scalar>> cameras_from_json(const nlohmann::json& j, const std::string& file_name) {
  const nlohmann::json* list = &j;
  if (j.is_object() && j.contains("cameras")) list = &j["cameras"];
  nlohmann::json single;  // one bare camera object is a list of one
  if (list->is_object()) {
    single = nlohmann::json::array({*list});
    list = &single;
  }
  ensure(list->is_array(), file_name, ": expected a camera object, a list of cameras or {\"cameras\": [...]}");
  std::vector<Camera<Scalar>> out;
  for (std::size_t i = 0; i < list->size(); ++i) {
    const auto& c = (*list)[i];
    const std::string where = file_name + ": camera " + std::to_string(i);
    auto num = [&](const char* key) {
      ensure(c.contains(key) && c[key].is_number(), where, ": missing or non-numeric \"", key, "\"");
      const double v = c[key].get<double>();
      ensure(std::isfinite(v), where, ": \"", key, "\" is not finite");
      return v;
    };
    Camera<Scalar> cam;
    // Checked before the conversion: int(3e9) is undefined.
    auto size = [&](const char* key) {
      const double v = num(key);
      ensure(v >= 1 && v <= 2147483647.0 && v == std::floor(v), where, ": \"", key,
             "\" must be an integer in [1, 2147483647], got ", v);
      return int(v);
    };
    cam.intrinsics.width = size("width");
    cam.intrinsics.height = size("height");
    cam.intrinsics.fx = Scalar(num("fx"));
    cam.intrinsics.fy = Scalar(num("fy"));
    cam.intrinsics.cx = Scalar(num("cx"));
    cam.intrinsics.cy = Scalar(num("cy"));
    ensure(cam.intrinsics.fx > 0 && cam.intrinsics.fy > 0, where, ": focal lengths must be positive");
    ensure(c.contains("R") && c["R"].is_array() && c["R"].size() == 3, where, ": \"R\" must be 3 rows");
    ensure(c.contains("t") && c["t"].is_array() && c["t"].size() == 3, where, ": \"t\" must have 3 values");
    for (int r = 0; r < 3; ++r) {
      const auto& row = c["R"][r];
      ensure(row.is_array() && row.size() == 3, where, ": \"R\" row ", r, " must have 3 values");
      for (int k = 0; k < 3; ++k) {
        ensure(row[k].is_number(), where, ": \"R\"[", r, "][", k, "] is not a number");
        cam.R(r, k) = Scalar(row[k].get<double>());
      }
      ensure(c["t"][r].is_number(), where, ": \"t\"[", r, "] is not a number");
      cam.t[r] = Scalar(c["t"][r].get<double>());
    }
    ensure(cam.R.allFinite() && cam.t.allFinite(), where, ": non-finite pose");
    const Scalar dev = (cam.R * cam.R.transpose() - Eigen::Matrix<Scalar, 3, 3>::Identity()).cwiseAbs().maxCoeff();
    ensure(dev < Scalar(1e-3) && cam.R.determinant() > 0, where, ": \"R\" is not a rotation");
    out.push_back(cam);
  }
  return out;
}

// One training frame's camera as a file entry ({"index", width, ..., R, t}, in
// the model's frame) and back: the files that record the cameras G1 trains on.
template <class Scalar>
nlohmann::json frame_camera_json(const SceneFrame& frame, int index, const Camera<Scalar>& cam) {
  nlohmann::json e = orbit_file_detail::camera_json(index, 0.0, frame.to_user_for_file(cam));
  e.erase("azimuth_deg");
  return e;
}
template <class Scalar>
Camera<Scalar> frame_camera_from_json(const SceneFrame& frame, const nlohmann::json& e, const std::string& file) {
  return frame.to_normalised(cameras_from_json<double>(e, file).front()).template cast<Scalar>();
}

template <class Scalar>
std::vector<Camera<Scalar>> read_cameras_json(const std::string& path) {
  const std::string text = read_file_bytes(path);
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(text);
  } catch (const nlohmann::json::exception& e) {
    fail(path, ": not valid JSON: ", e.what());
  }
  return cameras_from_json<Scalar>(j, path);
}

// The orbit check's verdict and figures (orbit.json's "check", the cameras
// stage's refinement record).
inline nlohmann::json orbit_check_json(const OrbitCheck& c) {
  return {{"ok", c.ok},
          {"warnings", c.warnings},
          {"flagged_frames", c.flagged_frames},
          {"median_step_deg", c.median_step_deg},
          {"trend_halves", c.trend_halves},
          {"trend_split", c.trend_split},
          {"circle_rmse", c.circle_rmse},
          {"height_std", c.height_std},
          {"lookat_error_deg", c.lookat_error_deg}};
}

}  // namespace orbitforge

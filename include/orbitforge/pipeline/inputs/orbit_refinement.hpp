#pragma once
// The source cameras a COLMAP model gives, refined with the orbit as a prior
// when they do not look like an orbit.
//
// The cameras stage maps the source frames alone; on a short arc of a generated
// video the later frames can under-rotate (registration drift) or one frame can
// land off the arc. The orbit check (geometry/orbit_check.hpp) sees both; the
// orbit-prior bundle adjustment (geometry/orbit_bundle_adjust.hpp) moves weakly
// matched frames onto the orbit and keeps well-matched ones where their points
// put them. Here the two meet a COLMAP model:
//
//   off      the model as the mapper wrote it
//   flagged  (default) refined only when the check warns. On the five recorded
//            videos the check is silent, and the adjustment, run anyway, moved
//            no camera more than 0.66 degrees (docs/cameras.md): a model that
//            passes the check is left alone.
//   always   refined whatever the check says
//
// The refined model keeps every image, keypoint and track; the poses and the
// refined points' positions change. The record says what the check found before
// and after, and how far the cameras moved.
#include <Eigen/Core>
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdint>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <unordered_map>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/geometry/orbit_bundle_adjust.hpp"
#include "orbitforge/geometry/orbit_check.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/colmap_observations.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"

namespace orbitforge {

enum class OrbitRefine { off, flagged, always };

inline const char* orbit_refine_name(OrbitRefine m) {
  switch (m) {
    case OrbitRefine::off: return "off";
    case OrbitRefine::flagged: return "flagged";
    case OrbitRefine::always: return "always";
  }
  return "?";
}

inline OrbitRefine parse_orbit_refine(const std::string& s) {
  for (OrbitRefine m : {OrbitRefine::off, OrbitRefine::flagged, OrbitRefine::always})
    if (s == orbit_refine_name(m)) return m;
  fail("orbit refinement '", s, "' is not one of off, flagged, always");
}

struct OrbitRefinement {
  bool applied = false;
  std::string why;      // one sentence: why it ran or did not
  ColmapModel model;    // refined when applied, otherwise the input
  OrbitCheck before, after;  // `after` only when applied
  double arc_before_deg = 0, arc_after_deg = 0;
  double max_rotation_change_deg = 0, max_center_shift = 0;  // shift relative to the orbit radius
  double rms_before_px = 0, rms_after_px = 0;                // reprojection RMS over the observations used
  int points = 0, observations = 0, iterations = 0;
  double seconds = 0;
  nlohmann::json json;  // all of the above, for the stage's record
  std::string summary;  // one line for the log
};

namespace orbit_refinement_detail {

// The model's registered cameras in frame (name) order, with their orbit fit.
inline std::vector<FrameCamera<double>> model_cameras(const ColmapModel& model) {
  std::vector<FrameCamera<double>> cams;
  for (auto& f : colmap_frame_cameras<double>(model))
    if (f.valid) cams.push_back(std::move(f));
  return cams;
}

}  // namespace orbit_refinement_detail

// Checks the model's cameras against the orbit and refines them as `mode` says.
// A model whose orbit cannot be fitted (fewer than three cameras, ...) is left
// alone, with the reason: the orbit stage reports that itself.
inline OrbitRefinement refine_model_on_orbit(const ColmapModel& model, OrbitRefine mode,
                                             const OrbitBundleParams& params = {}) {
  using namespace orbit_refinement_detail;
  const auto t0 = std::chrono::steady_clock::now();
  OrbitRefinement r;
  r.model = model;
  r.json = {{"mode", orbit_refine_name(mode)}, {"applied", false}};
  auto finish = [&](const std::string& why) {
    r.why = why;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    r.json["why"] = why;
    r.json["seconds"] = r.seconds;
    char b[240] = "";
    if (r.applied)
      std::snprintf(b, sizeof(b),
                    "; source arc %.1f -> %.1f deg, cameras moved up to %.2f deg, reprojection RMS %.2f -> %.2f px; "
                    "the check %s after it",
                    r.arc_before_deg, r.arc_after_deg, r.max_rotation_change_deg, r.rms_before_px, r.rms_after_px,
                    r.after.ok ? "passes" : "still warns");
    r.summary = r.applied ? "orbit refinement: " + why + b : "orbit refinement: not applied (" + why + ")";
    return r;
  };

  const std::vector<FrameCamera<double>> cams = model_cameras(model);
  OrbitFit<double> fit;
  try {
    fit = fit_orbit_shape(cams);
  } catch (const Error& e) {
    return finish(std::string("no orbit to check against: ") + e.what());
  }
  r.before = check_orbit(cams, fit);
  r.arc_before_deg = double(fit.diagnostics.source_span_deg);
  r.json["check_before"] = orbit_check_json(r.before);
  r.json["arc_deg"] = {{"before", r.arc_before_deg}};
  if (mode == OrbitRefine::off) return finish("off");
  if (mode == OrbitRefine::flagged && r.before.ok) return finish("the cameras pass the orbit check");

  const ColmapBundleInput<double> in = colmap_bundle_input<double>(model, cams);
  std::vector<Camera<double>> start;
  for (const auto& f : cams) start.push_back(f.camera);
  OrbitBundleResult<double> ba;
  try {
    ba = orbit_bundle_adjust(start, in.points, in.observations, params);
  } catch (const Error& e) {
    return finish(std::string("the bundle adjustment could not run: ") + e.what());
  }

  std::map<std::string, int> image_of;
  for (const auto& [id, im] : model.images) image_of[im.name] = id;
  for (std::size_t i = 0; i < cams.size(); ++i)
    set_colmap_pose(r.model.images.at(image_of.at(cams[i].name)), ba.cameras[i].R, ba.cameras[i].t);
  std::unordered_map<std::int64_t, std::size_t> point_of;
  for (std::size_t j = 0; j < r.model.points.size(); ++j) point_of[r.model.points[j].id] = j;
  for (std::size_t j = 0; j < in.point_ids.size(); ++j) r.model.points[point_of.at(in.point_ids[j])].xyz = ba.points[j];

  const std::vector<FrameCamera<double>> refined = model_cameras(r.model);
  const OrbitFit<double> fit_after = fit_orbit_shape(refined);
  r.after = check_orbit(refined, fit_after);
  r.applied = true;
  r.arc_after_deg = double(fit_after.diagnostics.source_span_deg);
  for (std::size_t i = 0; i < cams.size(); ++i) {
    r.max_rotation_change_deg = std::max(r.max_rotation_change_deg, ba.rotation_change_deg[i]);
    r.max_center_shift = std::max(r.max_center_shift, ba.center_shift[i]);
  }
  r.rms_before_px = ba.initial_rms_px;
  r.rms_after_px = ba.final_rms_px;
  r.points = int(in.points.size());
  r.observations = int(in.observations.size()) - ba.dropped_observations;
  r.iterations = ba.iterations;
  r.json["applied"] = true;
  r.json["check_after"] = orbit_check_json(r.after);
  r.json["arc_deg"]["after"] = r.arc_after_deg;
  r.json["max_rotation_change_deg"] = r.max_rotation_change_deg;
  r.json["max_center_shift_of_radius"] = r.max_center_shift;
  r.json["reprojection_rms_px"] = {{"before", r.rms_before_px}, {"after", r.rms_after_px}};
  r.json["points"] = r.points;
  r.json["observations"] = r.observations;
  r.json["iterations"] = r.iterations;
  r.json["converged"] = ba.converged;
  return finish(mode == OrbitRefine::always ? "asked for (--orbit-refine always)"
                                            : "the orbit check warned: " + r.before.warnings.front());
}

}  // namespace orbitforge

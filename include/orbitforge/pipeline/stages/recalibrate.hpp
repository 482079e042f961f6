#pragma once
// Stage 3b, recalibrate: G1's cameras estimated again from every frame G1
// trains on (pipeline/inputs/recalibration.hpp) -> recalibrate/cameras.json
// (+ the frames, COLMAP database and model it came from).
//
// It runs only where the method estimated the cameras from the source frames
// (PipelineInput::estimated_cameras), a completion exists, and
// PipelineParams::recalibrate is enabled. It reads the source frames with a
// camera (the user has them all; the cameras stage saw them too) and the
// completion's frames: never a held-out frame. When the new cameras pass the
// checks, G1 trains every frame at its new camera with one lens for all
// (PipelineRun::g1_cameras); completion frames COLMAP did not register keep
// the provider's pose with the new lens. G0, R0 and the orbit keep the first
// cameras, and the report scores each reconstruction at its own.
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/pipeline/inputs/recalibration.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/pipeline/report/reference.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/stages/completion.hpp"

namespace orbitforge {

namespace recalibrate_detail {

// Reads cameras.json into run.g1_cameras (when it says the cameras were used).
template <class Scalar>
void apply_recalibration(PipelineRun<Scalar>& run, const std::string& path) {
  const nlohmann::json j = nlohmann::json::parse(read_file_bytes(path));
  if (!j.value("applied", false)) return;
  G1Cameras<Scalar> g;
  for (const auto& e : j.at("frames")) {
    const auto cam = frame_camera_from_json<Scalar>(run.input->frame, e, path);
    if (e.at("kind") == "source")
      g.source[e.at("input_index").get<int>()] = cam;
    else
      g.completion[e.at("vhat_index").get<int>()] = cam;
  }
  ensure(!g.source.empty(), path, ": no source cameras");
  g.lens = g.source.begin()->second.intrinsics;
  run.g1_cameras = std::move(g);
}

}  // namespace recalibrate_detail

template <class Scalar>
void stage_recalibrate(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const auto& in = *run.input;
  const fs::path dir = fs::path(run.out) / "recalibrate";
  run.g1_cameras.reset();
  bool reuse = false;
  std::vector<VhatFrame<Scalar>> vhat;
  std::vector<int> completion;  // indices into vhat
  if (p.recalibrate.enabled && in.estimated_cameras) {
    // Cameras first: the frames' images are decoded only when COLMAP runs.
    vhat = read_vhat<Scalar>(run.out, "vhat.json", in.frame, &reuse, VhatImages::skip);
    completion = completion_indices(vhat);
  }
  if (reuse || completion.empty()) {  // also when the stage is off or the cameras were given
    run.keys["recalibrate"] = run.keys.at("completion");  // G1's key as without the stage
    return;
  }
  const RecalibrateParams& rp = p.recalibrate;
  const nlohmann::json settings = {{"camera_model", rp.camera_model},
                                   {"hold_focal", rp.hold_focal},
                                   {"matcher", "neighbours along the orbit"},
                                   // COLMAP sees square pixels (recalibrate_cameras); keyed, so
                                   // that cameras estimated on the working grid's pixels are redone
                                   {"pixels", "square"},
                                   {"neighbours", rp.neighbours},
                                   {"init_min_tri_angle_deg", rp.init_min_tri_angle_deg},
                                   {"max_centre_residual", rp.max_centre_residual},
                                   {"max_rotation_residual_deg", rp.max_rotation_residual_deg},
                                   {"max_focal_change", rp.max_focal_change},
                                   {"min_completion_registered", rp.min_completion_registered}};
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("completion"))));
  run.keys["recalibrate"] = key;
  const std::vector<std::string> outputs = {"recalibrate/cameras.json"};
  if (run.stage_current("recalibrate", key, outputs)) {
    recalibrate_detail::apply_recalibration(run, (dir / "cameras.json").string());
    return;
  }

  vhat = read_vhat<Scalar>(run.out, "vhat.json", in.frame, nullptr, VhatImages::load);
  // The frames in their order along the orbit (the neighbours COLMAP matches).
  std::vector<std::pair<double, RecalibrationFrame<Scalar>>> along;
  std::map<std::string, std::pair<const char*, int>> what;  // name -> (kind, index)
  for (int f : in.source) {
    const std::string name = "source_" + numbered_png(f, 5);
    along.push_back({orbit_position(run.fit, in.cameras[std::size_t(f)].camera),
                     {name, &in.images[std::size_t(f)], true, &in.cameras[std::size_t(f)].camera}});
    what[name] = {"source", f};
  }
  for (int i : completion) {
    const std::string name = "completion_" + numbered_png(i, 4);
    along.push_back({vhat[std::size_t(i)].position, {name, &vhat[std::size_t(i)].image, false, nullptr}});
    what[name] = {"completion", i};
  }
  std::stable_sort(along.begin(), along.end(), [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<RecalibrationFrame<Scalar>> frames;
  for (const auto& a : along) frames.push_back(a.second);
  run.log("   recalibrate: COLMAP on " + std::to_string(in.source.size()) + " source and " +
          std::to_string(completion.size()) + " completion frames");
  const Recalibration<Scalar> r = recalibrate_cameras((dir / "colmap").string(), frames, rp, p.threads, run.log);

  nlohmann::json j = {{"applied", r.applied},
                      {"registered",
                       {{"source", r.source_registered},
                        {"source_frames", r.source_frames},
                        {"completion", r.completion_registered},
                        {"completion_frames", r.completion_frames}}},
                      {"focal_px", {{"first", r.focal_first_px}, {"recalibrated", r.focal_px}}}};
  if (r.alignment.cameras > 0)
    j["alignment"] = camera_alignment_json(r.alignment);
  if (r.applied) {
    nlohmann::json list = nlohmann::json::array();
    for (const auto& [name, cam] : r.cameras) {
      const auto& [kind, index] = what.at(name);
      nlohmann::json e = frame_camera_json(in.frame, index, cam);
      e["kind"] = kind;
      e[std::string(kind) == "source" ? "input_index" : "vhat_index"] = index;
      list.push_back(e);
    }
    j["frames"] = list;
    char b[200];
    std::snprintf(b, sizeof(b), "   recalibrate: focal length %.1f -> %.1f px; %d of %d completion frames registered",
                  r.focal_first_px, r.focal_px, r.completion_registered, r.completion_frames);
    run.log(b);
  } else {
    j["why_not"] = r.why_not;
    run.log("   recalibrate: G1 keeps the first cameras: " + r.why_not);
  }
  write_file_atomic((dir / "cameras.json").string(), j.dump(1) + "\n");
  recalibrate_detail::apply_recalibration(run, (dir / "cameras.json").string());
  finish_stage(run, "recalibrate", key, t0, settings, outputs);
}

}  // namespace orbitforge

#pragma once
// Stage 4, g1: the second reconstruction, its bake and R1 -> g1/checkpoint.bin,
// g1/frames.json, final.ply (and final.spz, the same scene in the web viewers'
// compressed format, about a tenth of the size), R1/NNNN.png. And two comparisons an audit may ask
// for (PipelineParams::compare_g1_paper, oracle_bound), trained the same way:
//
//   g1_paper  the paper's G1: deformable, on the paper's V_hat (R0's arc renders
//             + completion) -> g1_paper/checkpoint.bin, g1_paper/frames.json,
//             g1_paper/final.ply
//   bound     the oracle bound: G1's recipe on everything the oracle provider
//             knows (the training source frames and the even recorded gap frames,
//             each at its recorded camera) -> bound/checkpoint.bin,
//             bound/frames.json, bound/bound.ply. How close G1 gets to it says how
//             much of the gap to a perfect result is the method's own.
//
// Every training frame has the time code of its place on the canonical orbit
// (position / (views - 1)), so the source and the completion share one clock.
// frames.json lists each training frame's name and origin, so a test can check
// that no held-out frame was trained on.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/io/spz.hpp"
#include "orbitforge/pipeline/completion/camera_fit.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"
#include "orbitforge/pipeline/reconstruction.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/stages/completion.hpp"

namespace orbitforge {

namespace g1_detail {

template <class Scalar>
TrainFrame<Scalar> orbit_frame(const PipelineRun<Scalar>& run, Image<Scalar> image, const Camera<Scalar>& cam,
                               double position, const std::string& name, int repeats) {
  const double period = double(run.fit.views - 1);
  TrainFrame<Scalar> f;
  f.image = std::move(image);
  f.camera = cam;
  f.time = Scalar(std::min(1.0, std::max(0.0, position / period)));
  f.name = name;
  f.repeats = repeats;
  return f;
}

// The training source frames (G0's), at G1's cameras (the recalibrated ones,
// or the estimated ones G0 had).
template <class Scalar>
void add_source_frames(const PipelineRun<Scalar>& run, std::vector<TrainFrame<Scalar>>& frames, int repeats) {
  const auto& in = *run.input;
  for (int t = 0; t < int(run.fit.source.size()); ++t) {
    const int idx = run.input_index_of_source(t);
    if (in.is_withheld(idx)) continue;
    const auto& cam = run.source_camera(idx, true);
    frames.push_back(orbit_frame(run, in.images[std::size_t(idx)], cam, orbit_position(run.fit, cam),
                                 "source " + in.cameras[std::size_t(idx)].name, repeats));
  }
}

// Trains a second reconstruction on `frames` (initialised as G1 is) into `dir`
// and returns its bake.
template <class Scalar>
GaussianScene<Scalar> train_second(PipelineRun<Scalar>& run, const std::vector<TrainFrame<Scalar>>& frames,
                                   bool deformable, const std::string& dir, const std::string& key,
                                   const std::string& label,
                                   const std::function<void(Trainer<Scalar>&)>& after_step = {}) {
  namespace fs = std::filesystem;
  const auto& p = run.params;
  GaussianScene<Scalar> init = p.g1_from_gmed0 ? run.read_scene((fs::path(run.out) / "gmed0.ply").string())
                                               : initial_scene(run, frames);
  TrainParams tp = run.g1_train_params(p.iters_g1, deformable);
  tp.max_sh_degree = std::max(tp.max_sh_degree, init.sh_degree);
  return reconstruct_and_bake(run, frames, std::move(init), tp, dir, key, label, after_step);
}

// What a training run sees, names aside: every frame's pixels, camera, time code
// and weight, in order. Two runs with equal signatures and settings train the
// same reconstruction.
template <class Scalar>
std::uint64_t training_set_signature(const std::vector<TrainFrame<Scalar>>& frames) {
  std::uint64_t h = kFnv1aSeed;
  for (const auto& f : frames) {
    h = fnv1a(f.image.data.data(), f.image.data.size() * sizeof(Scalar), h);
    const auto& k = f.camera.intrinsics;
    const Scalar numbers[] = {k.fx, k.fy, k.cx, k.cy, Scalar(k.width), Scalar(k.height), f.time, Scalar(f.repeats)};
    h = fnv1a(numbers, sizeof(numbers), h);
    h = fnv1a(f.camera.R.data(), 9 * sizeof(Scalar), h);
    h = fnv1a(f.camera.t.data(), 3 * sizeof(Scalar), h);
  }
  return h;
}

template <class Scalar>
nlohmann::json second_settings(const PipelineRun<Scalar>& run, const std::string& data, bool deformable) {
  const auto& p = run.params;
  return {{"train", pipeline_detail::train_settings<Scalar>(run.g1_train_params(p.iters_g1, deformable), p)},
          {"from_gmed0", p.g1_from_gmed0},
          {"data", data},
          {"source_repeats", p.g1_source_repeats},
          {"completion_repeats", p.g1_completion_repeats},
          {"completion_lens", p.g1_source_lens ? "source" : "provider"},
          {"refine_completion_at", p.g1_refine_completion_at},
          {"threads", p.threads}};
}

// G1's cameras once the completion's have been fitted (PipelineRun::g1_cameras):
// the source cameras as they were, and `completion` by index into V_hat.
template <class Scalar>
G1Cameras<Scalar> with_completion_cameras(const PipelineRun<Scalar>& run,
                                          std::map<int, Camera<Scalar>> completion) {
  G1Cameras<Scalar> g;
  g.lens = run.g1_cameras ? run.g1_cameras->lens : run.fit.cameras.front().intrinsics;
  for (int t = 0; t < int(run.fit.source.size()); ++t) {
    const int idx = run.input_index_of_source(t);
    g.source[idx] = run.source_camera(idx, true);
  }
  g.completion = std::move(completion);
  return g;
}

// g1/completion_cameras.json: the fit's figures and every completion frame's
// camera after it, under G1's stage key, so that a resumed G1 trains on the
// same cameras and the report scores in them.
template <class Scalar>
void write_completion_cameras(const PipelineRun<Scalar>& run, const std::string& path, const std::string& key,
                              int iteration, const FrameCameraFit& fit, const std::map<int, Camera<Scalar>>& cams) {
  nlohmann::json list = nlohmann::json::array();
  for (const auto& [i, cam] : cams) {
    nlohmann::json e = frame_camera_json(run.input->frame, i, cam);
    e["vhat_index"] = i;
    list.push_back(e);
  }
  const nlohmann::json j = {{"key", key}, {"iteration", iteration}, {"fit", fit.json()}, {"frames", list}};
  write_file_atomic(path, j.dump(1) + "\n");
}

// The cameras of a completion_cameras.json written under `key`, one for each
// V_hat index in `expected`; false (the fit runs again) when there is none, it
// is another run's, or it does not parse or name exactly those frames.
template <class Scalar>
bool read_completion_cameras(const PipelineRun<Scalar>& run, const std::string& path, const std::string& key,
                             const std::vector<int>& expected, std::map<int, Camera<Scalar>>& cams) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec)) return false;
  std::map<int, Camera<Scalar>> read;
  try {
    const nlohmann::json j = nlohmann::json::parse(read_file_bytes(path));
    if (j.value("key", std::string()) != key) return false;
    for (const auto& e : j.at("frames"))
      read[e.at("vhat_index").get<int>()] = frame_camera_from_json<Scalar>(run.input->frame, e, path);
  } catch (const std::exception& e) {
    run.log(std::string("G1: ") + path + " not usable (" + e.what() + "); fitting again");
    return false;
  }
  std::vector<int> named;
  for (const auto& kv : read) named.push_back(kv.first);
  if (named != expected) {
    run.log("G1: " + path + " names other completion frames than this run's; fitting again");
    return false;
  }
  cams = std::move(read);
  return true;
}

}  // namespace g1_detail

// The frames G1 trains on, from V_hat (vhat.json) and the input, per `data`.
template <class Scalar>
std::vector<TrainFrame<Scalar>> g1_frames(const PipelineRun<Scalar>& run, std::vector<VhatFrame<Scalar>> vhat,
                                          G1Data data, std::vector<int>* vhat_index = nullptr) {
  const auto& p = run.params;
  std::vector<TrainFrame<Scalar>> frames;
  if (data == G1Data::source) g1_detail::add_source_frames(run, frames, p.g1_source_repeats);
  if (vhat_index) vhat_index->assign(frames.size(), -1);
  for (std::size_t i = 0; i < vhat.size(); ++i) {
    auto& v = vhat[i];
    if (v.from_r0 && data == G1Data::source && !p.g1_arc_renders) continue;
    const int repeats = v.from_r0 ? 1 : p.g1_completion_repeats;
    Camera<Scalar> cam = v.from_r0 ? v.camera : run.completion_camera(v.camera, v.image.width, v.image.height);
    if (!v.from_r0 && run.g1_cameras) {
      const auto it = run.g1_cameras->completion.find(int(i));
      if (it != run.g1_cameras->completion.end()) cam = it->second;
    }
    frames.push_back(g1_detail::orbit_frame(run, std::move(v.image), cam, v.position, v.origin, repeats));
    if (vhat_index) vhat_index->push_back(v.from_r0 ? -1 : int(i));
  }
  ensure(!frames.empty(), "pipeline: G1 has no training frames");
  return frames;
}

template <class Scalar>
void stage_g1(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  using namespace pipeline_detail;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  bool reuse = false;
  std::vector<VhatFrame<Scalar>> vhat = read_vhat<Scalar>(run.out, "vhat.json", run.input->frame, &reuse);
  nlohmann::json settings = g1_detail::second_settings(run, g1_data_name(p.g1_data), p.g1_deformable);
  settings["arc_renders"] = p.g1_arc_renders;
  settings["reuse_r0"] = reuse;
  settings["render_stride"] = p.render_stride;
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("recalibrate"))));
  run.keys["g1"] = key;
  std::vector<std::string> outputs = {"final.ply", "final.spz"};
  if (!reuse) outputs.insert(outputs.end(), {"g1/checkpoint.bin", "g1/training.json", "g1/frames.json"});
  for (const auto& f : orbit_view_files(run, "R1")) outputs.push_back(f);
  // The completion's cameras fitted part way (PipelineParams::g1_refine_completion_at;
  // a deformable G1 is not fitted).
  const int fit_at = reuse || p.g1_deformable ? 0 : int(p.g1_refine_completion_at * p.iters_g1 + 0.5);
  const std::string fit_file = (out / "g1" / "completion_cameras.json").string();
  if (fit_at > 0) outputs.push_back("g1/completion_cameras.json");
  const std::vector<int> completion = completion_indices(vhat);
  if (run.stage_current("g1", key, outputs)) {
    std::map<int, Camera<Scalar>> cams;
    if (fit_at > 0 && g1_detail::read_completion_cameras(run, fit_file, key, completion, cams))
      run.g1_cameras = g1_detail::with_completion_cameras(run, std::move(cams));
    return;
  }
  GaussianScene<Scalar> final_scene;
  if (reuse) {
    final_scene = run.read_scene((out / "gmed0.ply").string());
  } else {
    std::vector<int> vhat_index;
    std::vector<TrainFrame<Scalar>> frames = g1_frames(run, std::move(vhat), p.g1_data, &vhat_index);
    fs::create_directories(out / "g1");
    write_frame_list((out / "g1" / "frames.json").string(), frames);
    bool fitted = false;
    const std::function<void(Trainer<Scalar>&)> fit_completion = [&](Trainer<Scalar>& trainer) {
      if (!fit_at || fitted || trainer.iteration() < fit_at) return;
      fitted = true;
      std::map<int, Camera<Scalar>> cams;
      if (g1_detail::read_completion_cameras(run, fit_file, key, completion, cams)) {
        for (std::size_t k = 0; k < frames.size(); ++k)
          if (vhat_index[k] >= 0) frames[k].camera = cams.at(vhat_index[k]);
        run.log("G1: completion cameras as fitted at iteration " + std::to_string(fit_at));
      } else {
        std::vector<bool> movable(frames.size());
        for (std::size_t k = 0; k < frames.size(); ++k) movable[k] = vhat_index[k] >= 0;
        Renderer<Scalar> r = run.renderer();
        const auto fit_t0 = std::chrono::steady_clock::now();
        const FrameCameraFit fit = fit_frame_cameras(r, trainer.scene(), frames, movable);
        const double fit_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - fit_t0).count();
        for (std::size_t k = 0; k < frames.size(); ++k)
          if (vhat_index[k] >= 0) cams[vhat_index[k]] = frames[k].camera;
        g1_detail::write_completion_cameras(run, fit_file, key, trainer.iteration(), fit, cams);
        char line[200];
        std::snprintf(line, sizeof(line),
                      "G1: %d of %d completion cameras fitted to their images, turned %.2f deg on average (at "
                      "most %.2f), zoomed %.2f %%, in %.1f s",
                      fit.moved, fit.frames, fit.turn_mean_deg, fit.turn_max_deg, 100 * fit.zoom_change_mean,
                      fit_seconds);
        run.log(line);
      }
      run.g1_cameras = g1_detail::with_completion_cameras(run, std::move(cams));
      trainer.cameras_changed();
    };
    final_scene = g1_detail::train_second(run, frames, p.g1_deformable, (out / "g1").string(), key, "G1",
                                          fit_completion);
  }
  run.write_scene((out / "final.ply").string(), final_scene);
  write_spz((out / "final.spz").string(), run.input->frame.to_user(final_scene.template cast<double>()));
  if (run.input->frame.far_from_origin())
    run.log("g1: warning: the model's origin is far from the scene, so final.spz (24-bit fixed-point positions) "
            "holds it coarsely; final.ply keeps float64 positions");
  render_orbit_views(run, final_scene, "R1", "R1");
  finish_stage(run, "g1", key, t0, settings, outputs);
}

// G1 trained on the paper's V_hat, for comparison (no renders along the orbit).
template <class Scalar>
void stage_g1_paper(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  if (!p.compare_g1_paper) return;
  bool reuse = false;
  std::vector<VhatFrame<Scalar>> vhat = read_vhat<Scalar>(run.out, "vhat.json", run.input->frame, &reuse);
  if (reuse) return;  // no completion: G1 is Gmed0 whatever its data
  const nlohmann::json settings = g1_detail::second_settings(run, "paper", true);
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("recalibrate"))));
  run.keys["g1_paper"] = key;
  const std::vector<std::string> outputs = {"g1_paper/checkpoint.bin", "g1_paper/training.json", "g1_paper/frames.json",
                                            "g1_paper/final.ply"};
  if (run.stage_current("g1_paper", key, outputs)) return;
  const std::vector<TrainFrame<Scalar>> frames = g1_frames(run, std::move(vhat), G1Data::paper);
  fs::create_directories(out / "g1_paper");
  write_frame_list((out / "g1_paper" / "frames.json").string(), frames);
  const GaussianScene<Scalar> scene =
      g1_detail::train_second(run, frames, true, (out / "g1_paper").string(), key, "G1 paper");
  run.write_scene((out / "g1_paper" / "final.ply").string(), scene);
  finish_stage(run, "g1_paper", key, t0, settings, outputs);
}

// The oracle bound (recorded inputs with gap frames only).
template <class Scalar>
void stage_bound(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  if (!p.oracle_bound) return;
  const auto& in = *run.input;
  const GapFrames gap = gap_frames(in, run.fit);
  if (gap.completion.empty()) {
    run.log("bound: no recorded frame in the gap; no oracle bound");
    return;
  }
  std::vector<TrainFrame<Scalar>> frames;
  g1_detail::add_source_frames(run, frames, 1);
  for (int i : gap.completion) {
    const auto& img = in.images[std::size_t(i)];
    const auto cam = run.completion_camera(in.cameras[std::size_t(i)].camera, img.width, img.height);
    frames.push_back(g1_detail::orbit_frame(run, img, cam, orbit_position(run.fit, cam),
                                            "recorded " + in.cameras[std::size_t(i)].name, 1));
  }
  // With a perfect completion (the oracle) and G1 on source + completion, G1 has
  // already trained on exactly this set with these settings: the bound is G1.
  bool same_as_g1 = false;
  if (!p.g1_arc_renders && p.g1_data == G1Data::source) {
    bool reuse = false;
    std::vector<VhatFrame<Scalar>> vhat = read_vhat<Scalar>(run.out, "vhat.json", run.input->frame, &reuse);
    same_as_g1 = !reuse && g1_detail::training_set_signature(g1_frames(run, std::move(vhat), p.g1_data)) ==
                               g1_detail::training_set_signature(frames);
  }
  nlohmann::json settings = g1_detail::second_settings(run, "oracle bound", p.g1_deformable);
  settings["same_as_g1"] = same_as_g1;
  const std::string& after = same_as_g1        ? run.keys.at("g1")
                            : run.g1_cameras ? run.keys.at("recalibrate")
                                             : run.keys.at("g0");
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(after)));
  run.keys["bound"] = key;
  std::vector<std::string> outputs = {"bound/frames.json", "bound/bound.ply"};
  if (!same_as_g1) outputs.insert(outputs.begin(), {"bound/checkpoint.bin", "bound/training.json"});
  if (run.stage_current("bound", key, outputs)) return;
  fs::create_directories(out / "bound");
  write_frame_list((out / "bound" / "frames.json").string(), frames);
  if (same_as_g1) run.log("bound: G1 trained on these frames with these settings; the bound is G1's final.ply");
  const GaussianScene<Scalar> scene =
      same_as_g1 ? run.read_scene((out / "final.ply").string())
                 : g1_detail::train_second(run, frames, p.g1_deformable, (out / "bound").string(), key, "bound");
  run.write_scene((out / "bound" / "bound.ply").string(), scene);
  finish_stage(run, "bound", key, t0, settings, outputs);
}

}  // namespace orbitforge

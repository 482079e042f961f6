#pragma once
// What the pipeline's stages share while they run: the input, the settings, the
// fitted orbit and layout, each finished stage's key, and small helpers every
// stage uses (file names of the orbit views, records, the renderer).
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/pipeline/completion/prompt.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/stage_record.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/still_check.hpp"
#include "orbitforge/train/trainer.hpp"

namespace orbitforge {

namespace pipeline_detail {

namespace fs = std::filesystem;

inline std::string view_file(int v) { return numbered_png(v, 4); }

inline std::vector<int> rendered_views(int views, int stride) {
  std::vector<int> v;
  for (int i = 0; i < views; i += stride) v.push_back(i);
  return v;
}

// Everything in `t` (the TrainParams a stage trains with, as train_params()
// makes them) that can change the result, for the stage's key and record: every
// learning rate, schedule and network setting, and the settings of the optional
// features only when the feature is on, so that a disabled feature's parameter
// does not invalidate a finished reconstruction. Threads are keyed by the stages.
template <class Scalar>
nlohmann::json train_settings(const TrainParams& t, const PipelineParams& p) {
  const auto& d = t.densify_params;
  const auto& s = t.densify_schedule;
  nlohmann::json j = {
      {"iterations", t.iterations},
      {"reference_budget", t.reference_budget},
      {"seed", t.seed},
      {"background", t.background},
      {"lr", {{"position", {t.position_lr_init, t.position_lr_final, t.position_lr_steps}},
              {"feature", t.feature_lr},
              {"sh_rest_divisor", t.sh_rest_divisor},
              {"opacity", t.opacity_lr},
              {"scaling", t.scaling_lr},
              {"rotation", t.rotation_lr},
              {"adam", {t.adam.beta1, t.adam.beta2, t.adam.eps}}}},
      {"max_sh_degree", t.max_sh_degree},
      {"sh_degree_interval", t.sh_degree_interval},
      {"lambda_dssim", t.lambda_dssim},
      {"near_plane_fraction", t.near_plane_fraction},
      {"deformable", t.deformable},
      {"densify", t.densify},
      {"median_samples", p.median_samples},
      {"init_points", p.init_points},
      {"scalar_bytes", sizeof(Scalar)},
      // A checkpoint of an older format cannot be resumed, or read by the stages that load a finished one.
      {"checkpoint_format", std::string(checkpoint_detail::kTag)}};
  if (t.random_background) j["random_background"] = true;
  if (t.learned_background) j["learned_background_lr"] = t.background_lr;
  if (t.exposure_compensation) j["exposure_lr"] = t.exposure_lr;
  if (t.densify)
    j["densification"] = {{"grad_threshold", d.grad_threshold},
                          {"percent_dense", d.percent_dense},
                          {"min_opacity", d.min_opacity},
                          {"split", {d.split_count, d.split_scale_divisor}},
                          {"max_world_scale", d.max_world_scale},
                          {"max_screen_radius", d.max_screen_radius},
                          {"reset_opacity", d.reset_opacity},
                          {"max_gaussians", d.max_gaussians},
                          {"min_gaussians", d.min_gaussians},
                          {"schedule", {s.densify_from, s.densify_until, s.densify_interval, s.opacity_reset_interval}},
                          {"min_interval", t.min_densify_interval},
                          {"floors_in_passes", {t.densify_interval_passes, t.opacity_reset_passes}}};
  if (t.densify && t.random_background) j["densification"]["max_screen_fraction"] = d.max_screen_fraction;
  if (t.deformable) {
    const auto& f = t.field;
    j["deformation"] = {{"field", {{"depth", f.depth},
                                   {"width", f.width},
                                   {"skip_layer", f.skip_layer},
                                   {"frequencies", {f.x_frequencies, f.t_frequencies}},
                                   {"head_init_scale", f.head_init_scale},
                                   {"scale_offset", scale_offset_name(f.scale_offset)},
                                   {"seed", f.seed}}},
                        {"normalize_field", t.normalize_field},
                        {"warmup", {t.warmup_iterations, t.deform_reference_budget}},
                        {"lr", {t.deform_lr_init, t.deform_lr_final, t.deform_lr_steps}}};
    if (t.time_noise != 0) j["deformation"]["time_noise"] = {t.time_noise, t.time_noise_steps};
    if (t.still_check_iterations > 0)
      j["still_check"] = {{"iterations", t.still_check_iterations},
                          {"holdout_every", t.still_holdout_every},
                          {"gain_db", t.still_gain_db},
                          {"region_gain_db", t.still_region_gain_db},
                          {"region_floor", kStillRegionFloor},
                          {"bake_samples", t.still_bake_samples}};
  }
  if (t.coarse_levels > 0) j["coarse"] = {{"levels", t.coarse_levels}, {"fraction", t.coarse_fraction}};
  if (t.plateau_window > 0) j["plateau"] = {{"window", t.plateau_window}, {"tolerance", t.plateau_tolerance}};
  return j;
}

}  // namespace pipeline_detail

// G1's cameras where the recalibrate stage replaced the first ones
// (stages/recalibrate.hpp): one lens, in the run's frame.
template <class Scalar>
struct G1Cameras {
  std::map<int, Camera<Scalar>> source;      // by input index
  std::map<int, Camera<Scalar>> completion;  // by index into V_hat (vhat.json's frames)
  Intrinsics<Scalar> lens;                   // at the working size
};

template <class Scalar>
struct PipelineRun {
  std::string out;
  PipelineParams params;
  const PipelineInput<Scalar>* input = nullptr;
  std::vector<FrameCamera<Scalar>> source_cameras;  // in.cameras at in.source
  OrbitFit<Scalar> fit;
  CompletionLayout layout;
  PromptResult prompt;
  std::optional<G1Cameras<Scalar>> g1_cameras;  // set by the recalibrate stage when it replaced them
  std::map<std::string, std::string> keys;  // stage -> key
  std::vector<std::string> ran, skipped;    // stage names
  std::function<void(const std::string&)> log = [](const std::string& s) { std::fprintf(stderr, "%s\n", s.c_str()); };

  int input_index_of_source(int t) const { return input->source[std::size_t(fit.source[std::size_t(t)].input_index)]; }

  // A source frame's camera (input index) for G1 (`for_g1`) or G0.
  const Camera<Scalar>& source_camera(int frame, bool for_g1) const {
    if (for_g1 && g1_cameras) {
      const auto it = g1_cameras->source.find(frame);
      if (it != g1_cameras->source.end()) return it->second;
    }
    return input->cameras[std::size_t(frame)].camera;
  }

  // params.train with the fields the pipeline owns set from their owners
  // (refused when params.train contradicts them: check_train_owners).
  TrainParams train_params(int iters, bool deformable) const {
    check_train_owners(params, input->background, input->random_background);
    TrainParams t = params.train;
    t.iterations = iters;
    t.coarse_levels = resolved_coarse_levels(t);  // by this budget: the stage's key names what it trains
    t.deformable = deformable;
    t.seed = params.seed;
    t.threads = params.threads;
    t.background = input->background;
    t.random_background = input->random_background;
    t.min_densify_interval = params.min_densify_interval;
    return t;
  }
  // train_params for G1 and the reconstructions trained as it is (the bound,
  // G1 on V_hat): without the plateau stop unless params.plateau_g1.
  TrainParams g1_train_params(int iters, bool deformable) const {
    TrainParams t = train_params(iters, deformable);
    if (!params.plateau_g1) t.plateau_window = 0;
    return t;
  }

  // The camera G1 (`for_g1`; else G0) gives a completion frame the provider
  // placed at `cam`, its image width x height: with params.g1_source_lens the
  // source cameras' focal length (their median, the canonical cameras'; G1's
  // own after the recalibrate stage), scaled to that size, as a video model
  // continuing the source would film it, and the provider's pose and principal
  // point; else `cam` as given. Gap views are scored at the same camera, so that
  // the score measures the scene, not two estimates' focal lengths.
  Camera<Scalar> completion_camera(Camera<Scalar> cam, int width, int height, bool for_g1 = true) const {
    if (!params.g1_source_lens) return cam;
    const Intrinsics<Scalar>& lens = for_g1 && g1_cameras ? g1_cameras->lens : fit.cameras.front().intrinsics;
    const Intrinsics<Scalar> k = lens.resized(width, height);
    cam.intrinsics.fx = k.fx;
    cam.intrinsics.fy = k.fy;
    return cam;
  }

  // Scene files (gmed0.ply, final.ply, ...) are in the input model's own frame,
  // while the run works in the input's (PipelineInput::frame, identity unless the
  // input was loaded normalised). The move is made in double; far from the
  // model's origin the positions are written in float64.
  void write_scene(const std::string& path, const GaussianScene<Scalar>& scene) const {
    PlyWriteOptions o;
    o.double_positions = input->frame.far_from_origin();
    write_ply(path, input->frame.to_user(scene.template cast<double>()), o);
  }
  GaussianScene<Scalar> read_scene(const std::string& path) const {
    return input->frame.to_normalised(read_ply<double>(path)).template cast<Scalar>();
  }

  Renderer<Scalar> renderer() const {
    RenderParams<Scalar> rp;
    for (int c = 0; c < 3; ++c) rp.background[std::size_t(c)] = Scalar(input->background[std::size_t(c)]);
    rp.threads = params.threads;
    return Renderer<Scalar>(rp);
  }

  // Progress of a long step, to params.on_progress (or stderr lines) when enabled.
  void progress(const std::string& label, int done, int total, const std::string& detail = "") const {
    if (!params.progress) return;
    if (!sink_) sink_ = params.on_progress ? params.on_progress : progress_lines_to_stderr();
    sink_({label, done, total, detail});
  }

  // Whether `stage` may be skipped (see stage_record.hpp); says why not when a
  // record existed but does not prove its outputs.
  bool stage_current(const std::string& stage, const std::string& key, const std::vector<std::string>& outputs) {
    const StageCheck c = check_stage(out, stage, key, outputs);
    if (c.current) {
      skipped.push_back(stage);
      return true;
    }
    if (c.why != "no record") log("   " + stage + ": running again: " + c.why);
    return false;
  }

 private:
  mutable ProgressSink sink_;
};

// Records a finished stage (its key, wall time since t0, settings and outputs) and lists it as run.
template <class Run>
void finish_stage(Run& run, const std::string& stage, const std::string& key,
                  std::chrono::steady_clock::time_point t0, const nlohmann::json& settings,
                  const std::vector<std::string>& outputs) {
  record_stage(run.out, stage, key, std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(),
               settings, outputs);
  run.ran.push_back(stage);
}

}  // namespace orbitforge

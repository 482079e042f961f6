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
#include <string>
#include <vector>

#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/pipeline/input.hpp"
#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/prompt.hpp"
#include "orbitforge/pipeline/stage_record.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/splat/renderer.hpp"
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

template <class Scalar>
nlohmann::json train_settings(const TrainParams& t, int iters, bool deformable, const PipelineParams& p) {
  return {{"iterations", iters},
          {"deformable", deformable},
          {"scale_offset", scale_offset_name(t.field.scale_offset)},
          {"normalize_field", t.normalize_field},
          {"seed", p.seed},
          {"median_samples", p.median_samples},
          {"max_sh_degree", t.max_sh_degree},
          {"densify", t.densify},
          {"min_densify_interval", p.min_densify_interval},
          {"lambda_dssim", t.lambda_dssim},
          {"field_depth", t.field.depth},
          {"field_width", t.field.width},
          {"init_points", p.init_points},
          {"max_gaussians", t.densify_params.max_gaussians},
          {"coarse_levels", t.coarse_levels},
          {"coarse_fraction", t.coarse_fraction},
          {"still_check_iterations", t.still_check_iterations},
          {"still_gain_db", t.still_gain_db},
          {"plateau_window", t.plateau_window},
          {"plateau_tolerance", t.plateau_tolerance},
          {"scalar_bytes", sizeof(Scalar)}};
}

}  // namespace pipeline_detail

template <class Scalar>
struct PipelineRun {
  std::string out;
  PipelineParams params;
  const PipelineInput<Scalar>* input = nullptr;
  std::vector<FrameCamera<Scalar>> source_cameras;  // in.cameras at in.source
  OrbitFit<Scalar> fit;
  CompletionLayout layout;
  PromptResult prompt;
  std::map<std::string, std::string> keys;  // stage -> key
  std::vector<std::string> ran, skipped;    // stage names
  std::function<void(const std::string&)> log = [](const std::string& s) { std::fprintf(stderr, "%s\n", s.c_str()); };

  int input_index_of_source(int t) const { return input->source[std::size_t(fit.source[std::size_t(t)].input_index)]; }

  TrainParams train_params(int iters, bool deformable) const {
    TrainParams t = params.train;
    t.iterations = iters;
    t.deformable = deformable;
    t.seed = params.seed;
    t.threads = params.threads;
    t.background = input->background;
    t.min_densify_interval = params.min_densify_interval;
    return t;
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

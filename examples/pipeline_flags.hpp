#pragma once
// The flags full_pipeline and audit share, and the one way both load a recorded
// input (a COLMAP folder): frames, working size, withheld frames, background.
//
// --protocol paper|measured is read first, wherever it stands: it sets every
// value the paper fixes (pipeline/protocol.hpp), and the other flags given then
// override single values of it.
#include <array>
#include <cstdio>
#include <optional>
#include <string>

#include "cli.hpp"
#include "orbitforge/pipeline/completion/providers.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/protocol.hpp"
#include "orbitforge/pipeline/report/reference.hpp"
#include "orbitforge/pipeline/stages/cameras.hpp"

namespace orbitforge::cli {

inline const char* kPipelineFlagsUsage =
    "  --protocol measured|paper   the library's measured defaults (default) or the method as published\n"
    "  --frames A-B                source video frames (1-based, default 1-33)\n"
    "  --width W --height H        working size of the frames (default 512 on the longer side,\n"
    "                              aspect kept; paper: the frames' own)\n"
    "  --holdout-every K           withhold every K-th source frame from every reconstruction (0 = none)\n"
    "  --completion oracle|perturbed|perturbed-geometric|external|none\n"
    "  --iters N --iters-g1 N      iterations of G0 and G1\n"
    "  --views N --render-stride K --median-samples N --static --threads N --seed S --background r,g,b|random\n"
    "  --g1-data source|paper --g1-arc-renders --g1-deformable --g1-static --g1-random-init\n"
    "  --g1-source-repeats N --g1-completion-repeats N\n"
    "  --compare-g1-paper --oracle-bound --no-comparisons --quiet\n"
    "  --static-diagnostics        also render the static-proxy comparison (not part of the method; off by default)\n"
    "  --checkpoint-every N        partial training checkpoints every N iterations (default 500, 0 = none)\n"
    "Work a scene does not need (off by default; each reconstruction):\n"
    "  --still-check N [--still-gain DB]   N iterations after the warm-up, bake the field in and train static\n"
    "                              when it fits the frames less than DB better than its bake (default 1.0)\n"
    "  --plateau-window N [--plateau-tolerance X]   stop when the mean loss over N iterations (whole passes)\n"
    "                              improves by less than X (relative; default 0.002) after densification\n"
    "  --max-gaussians N           Gaussian budget of densification\n"
    "  --coarse-levels L [--coarse-fraction F]   the first F of training (default 0.5) on frames\n"
    "                              downsampled by up to 2^L\n"
    "Cameras estimated from the source frames (--video, --images; audit --cameras estimated):\n"
    "  --focal PX | --fov DEG      the video model's lens (pixels of the frames' own size, or the\n"
    "                              horizontal field of view), held fixed while mapping\n"
    "  --focal-search              also map at 0.8, 0.9, 1.1 and 1.25 times the mapper's own focal\n"
    "                              estimate and keep the cameras that fit an orbit best (default: keep it)\n";

struct PipelineFlags {
  Protocol protocol = Protocol::measured;
  PipelineParams params;
  std::string frames = "1-33";
  int width = 0, height = 0;  // 0 = the protocol's choice
  int holdout_every = 0;
  bool iters_g1_set = false;
  std::optional<std::array<double, 3>> background;
  bool random_background = false;  // --background random
  // Cameras estimated from the source frames (COLMAP): the lens when known, and
  // whether to search the focal length otherwise.
  double focal_px = 0, fov_deg = 0;
  bool focal_search = false;
};

// The --protocol value anywhere on the command line (measured when absent).
inline Protocol scan_protocol(const std::string& program, int argc, char** argv) {
  Protocol p = Protocol::measured;
  for (int i = 1; i < argc; ++i) {
    if (std::string(argv[i]) != "--protocol") continue;
    if (i + 1 >= argc) throw UsageError(program + ": --protocol needs a value (paper or measured)");
    try {
      p = parse_protocol(argv[i + 1]);
    } catch (const Error& e) {
      throw UsageError(program + ": --protocol: " + e.what());
    }
  }
  return p;
}

// Starts `f` from the protocol named on the command line.
inline void begin_pipeline_flags(const std::string& program, int argc, char** argv, PipelineFlags& f) {
  f.protocol = scan_protocol(program, argc, argv);
  apply_protocol(f.params, f.protocol);
}

// Consumes the walker's current flag when it is a shared one; false otherwise.
inline bool parse_pipeline_flag(const std::string& program, ArgWalker& a, PipelineFlags& f) {
  PipelineParams& p = f.params;
  const std::string flag = a.flag();
  auto integer = [&](long lo) { return int(parse_int(program, flag, a.value(), lo)); };
  if (flag == "--protocol") a.value();  // read by begin_pipeline_flags
  else if (flag == "--frames") {
    f.frames = a.value();
    try {
      parse_frame_range(f.frames);
    } catch (const Error& e) {
      throw UsageError(program + ": --frames: " + e.what());
    }
  } else if (flag == "--width") f.width = integer(8);
  else if (flag == "--height") f.height = integer(8);
  else if (flag == "--holdout-every") f.holdout_every = integer(0);
  else if (flag == "--completion") {
    p.completion = a.value();
    if (p.completion != "external" && p.completion != "oracle" && p.completion != "none" &&
        p.completion != "perturbed" && p.completion != "perturbed-geometric")
      throw UsageError(program + ": --completion must be " + completion_provider_names() + ", got '" +
                       p.completion + "'");
  } else if (flag == "--iters") p.iters_g0 = integer(1);
  else if (flag == "--iters-g1") {
    p.iters_g1 = integer(1);
    f.iters_g1_set = true;
  } else if (flag == "--views") p.orbit.views = int(parse_int(program, flag, a.value(), 9, kMaxOrbitViews));
  else if (flag == "--render-stride") p.render_stride = integer(1);
  else if (flag == "--median-samples") p.median_samples = integer(2);
  else if (flag == "--threads") p.threads = parse_threads(program, flag, a.value());
  else if (flag == "--seed") p.seed = unsigned(integer(0));
  else if (flag == "--static") p.deformable = false;
  else if (flag == "--background") {
    const std::string v = a.value();
    f.random_background = v == "random";
    if (!f.random_background) f.background = parse_rgb(program, flag, v);
  }
  else if (flag == "--g1-data") {
    try {
      p.g1_data = parse_g1_data(a.value());
    } catch (const Error& e) {
      throw UsageError(program + ": --g1-data: " + e.what());
    }
  } else if (flag == "--g1-arc-renders") p.g1_arc_renders = true;
  else if (flag == "--g1-deformable") p.g1_deformable = true;
  else if (flag == "--g1-static") p.g1_deformable = false;
  else if (flag == "--g1-random-init") p.g1_from_gmed0 = false;
  else if (flag == "--g1-source-repeats") p.g1_source_repeats = integer(1);
  else if (flag == "--g1-completion-repeats") p.g1_completion_repeats = integer(1);
  else if (flag == "--compare-g1-paper") p.compare_g1_paper = true;
  else if (flag == "--oracle-bound") p.oracle_bound = true;
  else if (flag == "--no-comparisons") p.compare_g1_paper = p.oracle_bound = false;
  else if (flag == "--quiet") p.progress = false;
  else if (flag == "--static-diagnostics") p.static_proxy_diagnostics = true;
  else if (flag == "--no-static-diagnostics") p.static_proxy_diagnostics = false;  // the default; kept for old commands
  else if (flag == "--checkpoint-every") p.checkpoint_every = integer(0);
  else if (flag == "--still-check") p.train.still_check_iterations = integer(0);
  else if (flag == "--still-gain") p.train.still_gain_db = parse_double(program, flag, a.value());
  else if (flag == "--plateau-window") p.train.plateau_window = integer(0);
  else if (flag == "--plateau-tolerance") p.train.plateau_tolerance = parse_double(program, flag, a.value());
  else if (flag == "--max-gaussians") p.train.densify_params.max_gaussians = std::size_t(integer(0));
  else if (flag == "--coarse-levels") p.train.coarse_levels = integer(0);
  else if (flag == "--coarse-fraction") p.train.coarse_fraction = parse_double(program, flag, a.value());
  else if (flag == "--focal") {
    f.focal_px = parse_double(program, flag, a.value());
    if (!(f.focal_px > 0)) throw UsageError(program + ": --focal must be a positive number of pixels");
  } else if (flag == "--fov") {
    f.fov_deg = parse_double(program, flag, a.value());
    if (!(f.fov_deg > 0 && f.fov_deg < 180)) throw UsageError(program + ": --fov must lie in (0, 180) degrees");
  } else if (flag == "--focal-search") f.focal_search = true;
  else return false;
  return true;
}

// After parsing: values that follow from others.
inline void end_pipeline_flags(PipelineFlags& f) {
  if (!f.iters_g1_set) f.params.iters_g1 = f.params.iters_g0;
  if (f.focal_px > 0 && f.fov_deg > 0) throw UsageError("give --focal or --fov, not both");
}

// The working size a recorded input is loaded at: the flags' (one of --width /
// --height alone: square), else the frames' own under the paper's protocol, else
// 512 pixels on the frames' longer side with their aspect kept.
inline WorkingSize working_size(const PipelineFlags& f) {
  if (f.width > 0 || f.height > 0)
    return WorkingSize::exact(f.width > 0 ? f.width : f.height, f.height > 0 ? f.height : f.width);
  if (protocol_loads_native_size(f.protocol)) return WorkingSize::native();
  return WorkingSize::longer_side(512);
}

// Withheld frames and background of a loaded recorded input, as every pipeline
// program sets them.
template <class Scalar>
void finish_recorded_input(const std::string& program, PipelineInput<Scalar>& input, const PipelineFlags& f) {
  withhold_every(input, f.holdout_every);
  BackgroundEstimate bg = choose_background(input, f.background ? &*f.background : nullptr);
  if (f.random_background) force_random_background(input, bg);
  if (f.params.progress)
    std::fprintf(stderr, "%s: %s, %dx%d, background %.3f,%.3f,%.3f: %s\n", program.c_str(),
                 input.description.c_str(), input.width, input.height, bg.color[0], bg.color[1], bg.color[2],
                 bg.reason.c_str());
}

// A COLMAP folder as every pipeline program loads it.
template <class Scalar>
PipelineInput<Scalar> load_recorded_input(const std::string& program, const std::string& dir,
                                          const PipelineFlags& f) {
  const auto size = working_size(f);
  PipelineInput<Scalar> input = load_colmap_input<Scalar>(dir, f.frames, size);
  finish_recorded_input(program, input, f);
  return input;
}

// The cameras stage's settings from the flags (the input itself is the caller's).
inline CameraStageParams camera_stage_params(const PipelineFlags& f) {
  CameraStageParams cp;
  cp.frames = f.frames;
  cp.threads = f.params.threads;
  cp.focal_px = f.focal_px;
  cp.fov_deg = f.fov_deg;
  if (f.focal_search) cp.focal_factors = {0.8, 0.9, 1.1, 1.25};
  return cp;
}

// A video or a folder of frames whose cameras COLMAP estimates from the source
// frames alone (stages/cameras.hpp), as a user gets them. With `reference` (a
// COLMAP folder of the same video estimated from every frame) the run is scored
// against it (pipeline/report/reference.hpp); the method never reads it.
template <class Scalar>
PipelineInput<Scalar> load_estimated_input(const std::string& program, const std::string& out,
                                           const CameraStageParams& cp, const PipelineFlags& f,
                                           const std::string& reference, std::string* cameras_key) {
  if (f.params.progress) std::fprintf(stderr, "== stage cameras\n");
  CameraStageParams p = cp;
  const bool progress = f.params.progress;
  p.log = [progress](const std::string& line) {
    if (progress) std::fprintf(stderr, "%s\n", line.c_str());
  };
  const CameraStageResult cr = stage_cameras(out, p);
  if (cr.skipped && progress) std::fprintf(stderr, "   cameras: outputs verified, skipped\n");
  if (cameras_key) *cameras_key = cr.key;
  PipelineInput<Scalar> input = load_colmap_input<Scalar>(cr.dataset, f.frames, working_size(f));
  input.description = (p.video.empty() ? "images " + p.images : "video " + p.video) + " frames " + f.frames +
                      " (cameras: COLMAP registered " + std::to_string(cr.registered_names.size()) + " of " +
                      std::to_string(cr.source_names.size()) + " source frames)";
  input.camera_path = "estimated from the source frames only";
  finish_recorded_input(program, input, f);
  if (!reference.empty()) {
    const PipelineInput<Scalar> ref = load_colmap_input<Scalar>(reference, f.frames, input.width, input.height);
    const CameraAlignment a = attach_reference(input, ref, reference);
    input.camera_path += "; scored against a reference model of every frame";
    if (progress)
      std::fprintf(stderr,
                   "%s: reference %s aligned on %d source frames: centre residual %.4f of the spread, rotation "
                   "residual mean %.2f max %.2f deg\n",
                   program.c_str(), reference.c_str(), a.cameras, a.centre_rms_relative, a.rotation_mean_deg,
                   a.rotation_max_deg);
  }
  return input;
}

}  // namespace orbitforge::cli

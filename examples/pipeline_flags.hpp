#pragma once
// The flags full_pipeline, audit and reconstruct share, defined once
// (add_reconstruction_flags, add_pipeline_flags), and the one way the pipeline
// programs load a recorded input (a COLMAP folder): frames, working size,
// withheld frames, background.
//
// --protocol paper|measured sets every value the paper fixes
// (pipeline/protocol.hpp); the other flags, on the command line or in a --config
// file, override single values of it wherever they stand (parse_with_protocol).
#include <array>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>
#include <string>

#include "cli.hpp"
#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/pipeline/completion/providers.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/protocol.hpp"
#include "orbitforge/pipeline/report/reference.hpp"
#include "orbitforge/pipeline/stages/cameras.hpp"
#include "orbitforge/pipeline/stages/points.hpp"
#include "orbitforge/train/init.hpp"

namespace orbitforge::cli {

struct PipelineFlags {
  Protocol protocol = Protocol::measured;
  PipelineParams params;
  std::string frames = "1-33";
  int width = 0, height = 0;  // 0 = the protocol's choice
  int holdout_every = 0;
  ImageOrder image_order = ImageOrder::name;  // how a COLMAP folder's images are numbered
  std::string background_text;  // --background as given; empty: estimated from the frames
  // Resolved by end_pipeline_flags from background_text.
  std::optional<std::array<double, 3>> background;
  bool random_background = false;  // --background random
  // Cameras estimated from the source frames (COLMAP): the lens when known, and
  // whether to search the focal length otherwise.
  double focal_px = 0, fov_deg = 0;
  bool focal_search = false;
  bool recalibrate_hold_focal = true;
  std::string orbit_refine = "flagged";
  double sift_peak_threshold = 0;  // 0: COLMAP's, again at 0.004 when features are few
  // A COLMAP model without 3D points: COLMAP triangulates the training frames at
  // their cameras (stages/points.hpp), else training starts from a random cloud.
  bool triangulate = true;
};

inline const char* kInputGroup = "Input";
inline const char* kTrainingGroup = "Training";
inline const char* kSkipGroup = "Work a scene does not need (each reconstruction; full_pipeline and audit check for a still scene by default, the rest is off)";

// The flags of one reconstruction, which reconstruct and the pipeline share. Each
// option's default is the value `f` holds when it is added (a program sets its
// own first, e.g. reconstruct's 30000 iterations).
inline void add_reconstruction_flags(CLI::App& app, PipelineFlags& f) {
  PipelineParams& p = f.params;
  app.add_option_function<std::string>(
         "--protocol", [&f](const std::string& s) { f.protocol = parse_protocol(s); },
         "measured: the library's measured defaults; paper: the method as published (its values first, "
         "then the other flags given)")
      ->default_function([&f] { return std::string(protocol_name(f.protocol)); })
      ->capture_default_str()
      ->check(checked_by([](const std::string& s) { parse_protocol(s); }, "measured|paper"))
      ->group(kTrainingGroup);
  app.add_option("--frames", f.frames, "source video frames A-B (1-based, in name order; \"A-\": to the last)")
      ->check(frame_range())
      ->group(kInputGroup);
  unset_when_zero(app.add_option("--width", f.width,
                                 "working size of the frames (one of --width/--height alone: square; default 512 on "
                                 "the longer side, aspect kept; paper: the frames' own)"),
                  f.width)
      ->transform(at_least(8))
      ->group(kInputGroup);
  unset_when_zero(app.add_option("--height", f.height, "see --width"), f.height)
      ->transform(at_least(8))
      ->group(kInputGroup);
  app.add_option_function<std::string>(
         "--image-order", [&f](const std::string& s) { f.image_order = parse_image_order(s); },
         "how a COLMAP folder's images are numbered: name, or ring (around their cameras' ring, from one end of "
         "its largest gap: photographs named in another order)")
      ->default_function([&f] { return std::string(image_order_name(f.image_order)); })
      ->capture_default_str()
      ->check(checked_by([](const std::string& s) { parse_image_order(s); }, "name|ring"))
      ->group(kInputGroup);
  app.add_option("--holdout-every", f.holdout_every,
                 "withhold every K-th source frame from every reconstruction (0 = none)")
      ->transform(at_least(0))
      ->group(kInputGroup);
  app.add_option("--background", f.background_text,
                 "r,g,b in [0,1] or random (default: estimated from the frames' borders)")
      ->check(rgb(true))
      ->group(kInputGroup);
  app.add_option("--iters", p.iters_g0, "training iterations (full_pipeline, audit: of G0, and of G1 unless --iters-g1)")
      ->transform(at_least(1))
      ->group(kTrainingGroup);
  app.add_option("--median-samples", p.median_samples, "samples of the MedianGS bake (T_m)")
      ->transform(at_least(2))
      ->group(kTrainingGroup);
  app.add_option("--threads", p.threads, "worker threads (0 = all hardware threads)")
      ->transform(thread_count())
      ->group(kTrainingGroup);
  app.add_option("--seed", p.seed, "random seed")->transform(at_least(0))->group(kTrainingGroup);
  app.add_flag("--exposure", p.train.exposure_compensation,
               "learn an exposure and white-balance transform per training frame, kept out of the scene "
               "(photographs whose exposure or colour balance changed between shots)")
      ->group(kTrainingGroup);
  app.add_option("--exposure-lr", p.train.exposure_lr, "see --exposure")->check(positive())->group(kTrainingGroup);
  app.add_option("--still-check", p.train.still_check_iterations,
                 "N iterations after the warm-up, bake the field in and train static when it fits the frames held "
                 "back for the check (--still-holdout-every) less than --still-gain dB better than its bake, and no "
                 "image region more than --still-region-gain dB (0 = off)")
      ->transform(at_least(0))
      ->group(kSkipGroup);
  app.add_option("--still-gain", p.train.still_gain_db, "see --still-check (dB)")->check(finite())->group(kSkipGroup);
  app.add_option("--still-region-gain", p.train.still_region_gain_db, "see --still-check (dB)")
      ->check(finite())
      ->group(kSkipGroup);
  app.add_option("--still-holdout-every", p.train.still_holdout_every,
                 "see --still-check: training frames i with i % K == K/2 are not trained on until the check, which "
                 "compares on them (0 = compare on training frames)")
      ->check(number_where([](double x) { return x == 0 || (x >= 2 && x == std::floor(x)); },
                           "must be 0 or a whole number >= 2", "K"))
      ->group(kSkipGroup);
  app.add_option("--plateau-window", p.train.plateau_window,
                 "stop when the mean loss over N iterations (whole passes) improves by less than "
                 "--plateau-tolerance after densification (0 = off)")
      ->transform(at_least(0))
      ->group(kSkipGroup);
  app.add_option("--plateau-tolerance", p.train.plateau_tolerance, "see --plateau-window (relative)")
      ->check(finite())
      ->group(kSkipGroup);
  app.add_option("--max-gaussians", p.train.densify_params.max_gaussians,
                 "Gaussian budget of densification (0 = none)")
      ->transform(at_least(0))
      ->group(kSkipGroup);
  app.add_option("--coarse-levels", p.train.coarse_levels,
                 "the first --coarse-fraction of training on frames downsampled by up to 2^L (0 = off; -1 = one "
                 "level where a reconstruction's budget is at least 10,000 iterations, else off: full_pipeline's "
                 "and audit's default)")
      ->check(number_where([](double x) { return x == std::floor(x) && x >= -1 && x <= 6; },
                           "must be a whole number from -1 to 6", "L"))
      ->group(kSkipGroup);
  app.add_option("--coarse-fraction", p.train.coarse_fraction, "see --coarse-levels")
      ->check(finite())
      ->group(kSkipGroup);
}

// The pipeline's flags (full_pipeline and audit): one reconstruction's, and the
// method's own.
inline void add_pipeline_flags(CLI::App& app, PipelineFlags& f) {
  add_reconstruction_flags(app, f);
  PipelineParams& p = f.params;
  const char* method = "Pipeline";
  app.add_option("--completion", p.completion, std::string("the completion provider: ") + completion_provider_names())
      ->check(CLI::IsMember({"external", "oracle", "perturbed", "perturbed-geometric", "none"}))
      ->group(method);
  app.add_option("--iters-g1", p.iters_g1, "iterations of G1 (default: --iters)")
      ->transform(at_least(1))
      ->group(method);
  app.add_option("--views", p.orbit.views, "views of the canonical orbit")
      ->transform(at_least(9))
      ->check(CLI::Range(9, kMaxOrbitViews))
      ->group(method);
  app.add_flag_function("--no-triangulate", [&f](std::int64_t) { f.triangulate = false; },
               "a COLMAP model without 3D points starts from --init-points random points instead of points COLMAP "
               "triangulates from the training frames at their cameras")
      ->group(method);
  app.add_option("--init-points", p.init_points,
                 "random initial points when the input has none (the embedded synthetic input, --no-triangulate)")
      ->transform(at_least(1))
      ->check(CLI::Range(std::size_t(1), kMaxRandomPoints))
      ->group(method);
  app.add_option("--render-stride", p.render_stride, "render R0 / R1 at every K-th canonical view")
      ->transform(at_least(1))
      ->group(method);
  add_setting_flag(app, "--static", p.deformable, false, "G0 static (default: deformable)")->group(method);
  app.add_option_function<std::string>(
         "--g1-data", [&p](const std::string& s) { p.g1_data = parse_g1_data(s); },
         "what G1 trains on: source (the source frames and the completion) or paper (V_hat as published)")
      ->default_function([&p] { return std::string(g1_data_name(p.g1_data)); })
      ->capture_default_str()
      ->check(checked_by([](const std::string& s) { parse_g1_data(s); }, "source|paper"))
      ->group(method);
  add_setting_flag(app, "--g1-arc-renders", p.g1_arc_renders, true, "with --g1-data source: add R0's arc renders")
      ->group(method);
  add_setting_flag(app, "--g1-deformable", p.g1_deformable, true, "G1 (and the bound) deformable")->group(method);
  add_setting_flag(app, "--g1-static", p.g1_deformable, false, "G1 (and the bound) static (the default)")
      ->group(method);
  add_setting_flag(app, "--g1-random-init", p.g1_from_gmed0, false, "G1 from points / random, not from Gmed0")
      ->group(method);
  add_setting_flag(app, "--g1-source-lens", p.g1_source_lens, true,
                   "G1 gives the completion frames the source cameras' lens (the default)")
      ->group(method);
  add_setting_flag(app, "--g1-provider-lens", p.g1_source_lens, false,
                   "G1 gives the completion frames the lens their provider gave them")
      ->group(method);
  app.add_option("--g1-refine-completion", p.g1_refine_completion_at,
                 "fit each completion frame's camera to its image after this fraction of G1's iterations (0: off)")
      ->check(CLI::Range(0.0, 1.0))
      ->group(method);
  app.add_option("--g1-source-repeats", p.g1_source_repeats, "sampling weight of G1's source frames")
      ->transform(at_least(1))
      ->group(method);
  app.add_option("--g1-completion-repeats", p.g1_completion_repeats, "sampling weight of G1's completion frames")
      ->transform(at_least(1))
      ->group(method);
  add_setting_flag(app, "--plateau-g0-only", p.plateau_g1, false,
                   "with --plateau-window: the plateau stop on G0 only, G1 (and the comparisons) train their whole "
                   "budget")
      ->group(method);
  // Defined before the two it clears, so that either one given with it still runs.
  app.add_flag_callback("--no-comparisons", [&p] { p.compare_g1_paper = p.oracle_bound = false; },
                        "neither comparison (--compare-g1-paper or --oracle-bound given too still adds that one)")
      ->default_function([] { return std::string("false"); })
      ->group(method);
  add_setting_flag(app, "--compare-g1-paper", p.compare_g1_paper, true,
                   "also train G1 on the paper's V_hat (a comparison, not the method)")
      ->group(method);
  add_setting_flag(app, "--oracle-bound", p.oracle_bound, true,
                   "also train the oracle bound (a comparison; recorded inputs only)")
      ->group(method);
  add_setting_flag(app, "--quiet", p.progress, false, "no progress lines")->group(method);
  add_old_default_flag(app, "--no-static-diagnostics", p.static_proxy_diagnostics, false)->group(method);
  add_setting_flag(app, "--static-diagnostics", p.static_proxy_diagnostics, true,
                   "also render the static-proxy comparison (not part of the method)")
      ->group(method);
  add_setting_flag(app, "--score-view-fitted", p.score_view_fitted, true,
                   "also score withheld and gap views with each camera's turn and zoom fitted to its image")
      ->group(method);
  app.add_option("--checkpoint-every", p.checkpoint_every, "partial training checkpoints every N iterations (0 = none)")
      ->transform(at_least(0))
      ->group(method);
  const char* cameras = "Cameras estimated from the source frames (--video, --images; audit --cameras estimated)";
  unset_when_zero(app.add_option("--focal", f.focal_px,
                                 "the video model's lens in pixels of the frames' own size, held fixed while mapping"),
                  f.focal_px)
      ->check(positive())
      ->group(cameras);
  unset_when_zero(app.add_option("--fov", f.fov_deg,
                                 "the lens as the horizontal field of view in degrees (0, 180), instead of --focal"),
                  f.fov_deg)
      ->check(positive() & CLI::Range(0.0, 179.999999))
      ->group(cameras);
  add_setting_flag(app, "--focal-search", f.focal_search, true,
                   "also map at 0.8, 0.9, 1.1 and 1.25 times the mapper's own focal estimate and keep the cameras "
                   "that fit an orbit best (default: keep it)")
      ->group(cameras);
  app.add_option("--orbit-refine", f.orbit_refine,
                 "refine the cameras with the orbit as a prior (bundle adjustment): flagged = when the orbit check "
                 "warns, always, off")
      ->check(CLI::IsMember({"flagged", "always", "off"}))
      ->capture_default_str()
      ->group(cameras);
  unset_when_zero(app.add_option("--sift-peak-threshold", f.sift_peak_threshold,
                                 "SIFT's threshold, held (default: COLMAP's 0.0067, and 0.004 when that gives "
                                 "under 300 features per frame)"),
                  f.sift_peak_threshold)
      ->check(positive())
      ->group(cameras);
  add_old_default_flag(app, "--recalibrate", p.recalibrate.enabled, true)->group(cameras);
  add_old_default_flag(app, "--recalibrate-hold-focal", f.recalibrate_hold_focal, true)->group(cameras);
  add_setting_flag(app, "--no-recalibrate", p.recalibrate.enabled, false,
                   "G1 at the source cameras as estimated (default: once the completion is back, COLMAP again on "
                   "the source frames and the completion together, and G1 at those cameras where they pass the "
                   "stage's checks)")
      ->group(cameras);
  add_setting_flag(app, "--recalibrate-refit-focal", f.recalibrate_hold_focal, false,
                   "the recalibrate stage estimates the focal length again with the completion's frames (default: "
                   "it keeps the source cameras'; always so with --focal / --fov)")
      ->group(cameras);
}

// Parses argv with the options `define(f)` returns an App for. The protocol sets
// defaults that the other flags override wherever they stand (the command line, a
// --config file): a first parse finds it, `begin(f, protocol)` starts `f` from its
// defaults, and a second parse reads every flag over them. Returns the App of the
// second parse (bound to `f`; it writes the settings file).
template <class Flags, class Define, class Protocol_of, class Begin>
std::unique_ptr<CLI::App> parse_with_protocol(Flags& f, int argc, char** argv, Define define, Protocol_of protocol_of,
                                              Begin begin) {
  {
    Flags first = f;
    const std::unique_ptr<CLI::App> app = define(first);
    parse(*app, argc, argv);
    begin(f, protocol_of(first));
  }
  std::unique_ptr<CLI::App> app = define(f);
  parse(*app, argc, argv);
  return app;
}

// The pipeline's protocol, as parse_with_protocol's `begin`.
inline void begin_pipeline_flags(PipelineFlags& f, Protocol protocol) {
  f.protocol = protocol;
  apply_protocol(f.params, protocol);
}

// After parsing: values that follow from others.
inline void end_pipeline_flags(const CLI::App& app, PipelineFlags& f) {
  recheck(app.get_name(), "--frames", f.frames, frame_range());
  const CLI::Option* iters_g1 = app.get_option_no_throw("--iters-g1");  // reconstruct has none
  if (!iters_g1 || iters_g1->count() == 0) f.params.iters_g1 = f.params.iters_g0;
  f.random_background = f.background_text == "random";
  f.background.reset();
  if (!f.background_text.empty() && !f.random_background) f.background = parse_rgb(f.background_text);
  if (f.focal_px > 0 && f.fov_deg > 0) throw UsageError(app.get_name() + ": give --focal or --fov, not both");
  f.params.recalibrate.hold_focal = f.recalibrate_hold_focal || f.focal_px > 0 || f.fov_deg > 0;  // a known lens stays known
}

// Writes OUT/settings.toml, the run's resolved settings (settings_text), which
// `--config OUT/settings.toml` replays, and returns the record report.json keeps
// of the run: the command line and those settings.
inline RunInvocation record_invocation(CLI::App& app, int argc, char** argv, const std::string& out) {
  RunInvocation inv;
  inv.command = shell_command(argc, argv);
  inv.settings = settings_text(app);
  inv.memory_pages = huge_page_state();
  std::filesystem::create_directories(out);
  write_file_atomic((std::filesystem::path(out) / "settings.toml").string(), inv.settings);
  return inv;
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

// A COLMAP folder as every pipeline program loads it; a model without points
// the training frames saw gets them from the points stage (into out/points),
// when colmap is installed. points_key gets the stage's key when it recorded
// points (the report counts its time).
template <class Scalar>
PipelineInput<Scalar> load_recorded_input(const std::string& program, const std::string& dir, const std::string& out,
                                          const PipelineFlags& f, std::string* points_key = nullptr) {
  const auto size = working_size(f);
  PipelineInput<Scalar> input = load_colmap_input<Scalar>(dir, f.frames, size, /*normalise=*/true, f.image_order);
  finish_recorded_input(program, input, f);
  if (f.triangulate && needs_triangulated_points(input) && training_source(input).size() >= 2) {
    const bool progress = f.params.progress;
    if (find_program("colmap").empty()) {
      if (progress)
        std::fprintf(stderr, "%s: the model has no 3D points and colmap is not installed (Debian package colmap): "
                     "training starts from a random cloud\n", program.c_str());
    } else {
      if (progress) std::fprintf(stderr, "== stage points\n");
      PointStageParams pp;
      pp.threads = f.params.threads;
      pp.log = [progress](const std::string& line) {
        if (progress) std::fprintf(stderr, "%s\n", line.c_str());
      };
      const PointStageResult r = stage_points(out, input, pp);
      if (r.points > 0) {
        input.description += " (" + std::to_string(r.points) + " points triangulated from the training frames)";
        if (points_key) *points_key = r.key;
      }
    }
  }
  return input;
}

// The cameras stage's settings from the flags (the input itself is the caller's).
inline CameraStageParams camera_stage_params(const PipelineFlags& f) {
  CameraStageParams cp;
  cp.frames = f.frames;
  cp.threads = f.params.threads;
  cp.focal_px = f.focal_px;
  cp.fov_deg = f.fov_deg;
  if (f.focal_search) cp.focal_factors = kFocalSearchFactors;
  cp.orbit_refine = parse_orbit_refine(f.orbit_refine);
  cp.sift_peak_threshold = f.sift_peak_threshold;
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
  PipelineInput<Scalar> input = load_colmap_input<Scalar>(cr.dataset, f.frames, working_size(f), /*normalise=*/true);
  input.description = (p.video.empty() ? "images " + p.images : "video " + p.video) + " frames " + f.frames +
                      " (cameras: COLMAP registered " + std::to_string(cr.registered_names.size()) + " of " +
                      std::to_string(cr.source_names.size()) + " source frames)";
  input.camera_path = "estimated from the source frames only";
  input.estimated_cameras = true;
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

// reconstruct: fit a (static or deformable) Gaussian scene to a video with COLMAP cameras.
//
//   reconstruct --colmap DIR [--frames A-B] [--holdout-every K] [--width W --height H] [--iters N]
//               [--deformable] [--median-samples 128] [--background r,g,b|random] [--threads N]
//               [--minutes M] [--eval-every N] [--seed S] [--field fast|original|DEPTHxWIDTH]
//               [--config FILE] --out DIR          (--help lists every flag)
//
// DIR (input) holds images/ and sparse/0/ (as shared/data/v3d/*). Frames are the COLMAP
// images in name order; --frames and --holdout-every count in that order (1-based);
// held-out frames (index a multiple of K) are never trained on. Images are resized to
// the working size (default 512 on the longer side, aspect kept) with the intrinsics
// rescaled. Time code of frame i of the n selected frames: (i - 1) / (n - 1). The
// flags it shares with full_pipeline and audit (frames, size, hold-out, iterations,
// threads, seed, background, protocol, the levers that skip work) are defined once,
// in pipeline_flags.hpp, with reconstruct's own defaults (30000 iterations, every frame).
//
// Writes to --out: checkpoint.bin (trainer state, incl. the deformation network),
// scene.ply (static: the trained scene; deformable: the MedianGS bake), metrics.json
// {iterations, seconds, gaussians, train_psnr, holdout_psnr, holdout_ssim,
// holdout_psnr_baked (deformable), curve (with --eval-every), exposure (with --exposure),
// frame, invocation} and
// settings.toml (the resolved settings; --config settings.toml replays the run). Training runs in a
// frame normalised to the cameras (splat/scene_frame.hpp; metrics.json "frame" gives
// origin and scale, and checkpoint.bin is in it); scene.ply is in the model's own frame. --minutes stops
// training early after that much training wall time. --field picks the deformation
// network (default fast = 4 x 64; original = the published 8 x 256). Errors: a message, exit
// status 2 (arguments) or 1 (inputs), and no output files.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <memory>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/training_record.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "cli.hpp"
#include "pipeline_flags.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"

using namespace orbitforge;
using S = float;

namespace {

const char* kDescription =
    "reconstruct: fit a (static or deformable) Gaussian scene to a video with COLMAP cameras.\n"
    "  reconstruct --colmap DIR [flags] --out DIR\n"
    "Frames are the COLMAP images in name order; --frames and --holdout-every count in that order (1-based), and\n"
    "held-out frames are never trained on. Writes OUT/checkpoint.bin, OUT/scene.ply, OUT/metrics.json and\n"
    "OUT/settings.toml (the run's settings, which --config replays).\n"
    "--protocol paper: the DeformableGS backend's schedule, learning rates and 8 x 256 network, unscaled, 10,000\n"
    "iterations, deformable, frames at their own size (flags given override).";

using cli::UsageError;

// Everything the command line sets: the flags shared with the pipeline
// (pipeline_flags.hpp) and training's own.
struct Args {
  std::string colmap, out;
  cli::PipelineFlags shared;  // frames, size, hold-out, iterations, threads, seed, background, protocol, levers
  int eval_every = 0;
  // Floor of the budget-scaled densification interval, as the pipeline's: scaled to a
  // few thousand iterations the published schedule densifies every 5-10 iterations,
  // too soon for cloned Gaussians to settle, and few training views then clone a
  // scene up to about a Gaussian per pixel (six 320x240 photographs: 375k).
  int min_densify_interval = 50;
  // Single settings, for measuring a departure from the paper one at a time
  // (unset: the protocol's value).
  std::optional<double> scaling_lr, deform_lr_final, time_noise, max_screen_fraction, densify_passes, reset_passes;
  double minutes = 0;
  bool deformable = false;
  bool learn_background = false;
  std::string field;  // empty: the protocol's network (fast; paper: the backend's 8 x 256)
  std::string scale_offset = "log";

  Args() {
    shared.frames = "1-";            // every frame
    shared.params.iters_g0 = 30000;  // reconstruct's own default (the pipeline's is 3000)
    // One reconstruction trains as asked, as TrainParams does; the method's
    // still check and coarse-to-fine by budget (PipelineParams) are a flag away.
    shared.params.train.still_check_iterations = TrainParams{}.still_check_iterations;
    shared.params.train.coarse_levels = TrainParams{}.coarse_levels;
  }
};

// --field: "fast" (4 x 64), "original" (8 x 256 with its skip) or DEPTHxWIDTH.
DeformationFieldParams parse_field(const std::string& v) {
  if (v == "fast") return DeformationFieldParams::fast();
  if (v == "original") return DeformationFieldParams::original();
  const auto x = v.find('x');
  DeformationFieldParams f = DeformationFieldParams::fast();
  const bool ok = x != std::string::npos && CLI::detail::lexical_cast(v.substr(0, x), f.depth) &&
                  CLI::detail::lexical_cast(v.substr(x + 1), f.width) && f.depth >= 1 && f.width >= 1;
  ensure(ok, "must be fast, original or DEPTHxWIDTH, got '", v, "'");
  return f;
}

std::unique_ptr<CLI::App> define(Args& a) {
  auto app = std::make_unique<CLI::App>(kDescription, "reconstruct");
  cli::setup(*app, /*with_config=*/true);
  app->add_option("--colmap", a.colmap, "input folder: images/ and sparse/0/ (as shared/data/v3d/*)")
      ->required()
      ->group(cli::kInputGroup);
  cli::add_reconstruction_flags(*app, a.shared);
  const char* training = cli::kTrainingGroup;
  cli::add_setting_flag(*app, "--deformable", a.deformable, true, "train a deformation field (default: static)")
      ->group(training);
  app->add_option("--field", a.field,
                  "the deformation network: fast (4 x 64, the default), original (the published 8 x 256) or "
                  "DEPTHxWIDTH (paper: the backend's 8 x 256)")
      ->check(cli::checked_by([](const std::string& v) { parse_field(v); }, "fast|original|DxW"))
      ->group(training);
  app->add_option("--scale-offset", a.scale_offset, "how the field offsets scales: log or additive (paper: additive)")
      ->check(CLI::IsMember({"log", "additive"}))
      ->group(training);
  app->add_flag("--learn-background", a.learn_background,
               "learn one background colour with the scene, from the chosen one (from the borders' median colour "
               "where they disagree); not with --background random")
      ->group(training);
  app->add_option("--min-densify-interval", a.min_densify_interval,
                  "floor of the budget-scaled densification interval (paper: 1)")
      ->transform(cli::at_least(1))
      ->group(training);
  cli::unset_when_zero(app->add_option("--minutes", a.minutes, "stop training after M minutes of training wall time"),
                       a.minutes)
      ->check(cli::positive())
      ->group(training);
  cli::unset_when_zero(app->add_option("--eval-every", a.eval_every,
                                       "score the held-out frames every N iterations (metrics.json \"curve\")"),
                       a.eval_every)
      ->transform(cli::at_least(1))
      ->group(training);
  const char* single = "Single departures from the paper (default: the protocol's value)";
  cli::add_optional(*app, "--scaling-lr", a.scaling_lr, "the scaling learning rate")
      ->check(cli::non_negative())
      ->group(single);
  cli::add_optional(*app, "--deform-lr-final", a.deform_lr_final, "the deformation network's final learning rate")
      ->check(cli::non_negative())
      ->group(single);
  cli::add_optional(*app, "--time-noise", a.time_noise,
                    "annealed noise on the time code (the backend's 0.1 for real scenes; 0 = off)")
      ->check(cli::non_negative())
      ->group(single);
  cli::add_optional(*app, "--max-screen-fraction", a.max_screen_fraction,
                    "with a random background, prune Gaussians wider on screen than this fraction of the frames' "
                    "longer side, never below 20 pixels (default 0.15; 0: 3DGS's 20 pixels)")
      ->check(cli::non_negative())
      ->group(single);
  cli::add_optional(*app, "--densify-passes", a.densify_passes,
                    "densify at most once per this many passes over the training frames (default 0.5; 0: the "
                    "budget's interval alone)")
      ->check(cli::non_negative())
      ->group(single);
  cli::add_optional(*app, "--reset-passes", a.reset_passes,
                    "reset the opacities at most once per this many passes over the training frames (default 3; "
                    "0: the budget's period alone)")
      ->check(cli::non_negative())
      ->group(single);
  app->add_option("--out", a.out, "output folder")->required();
  return app;
}

// The paper's protocol: its values first, the flags given over them.
void begin_protocol(Args& a, Protocol protocol) {
  a.shared.protocol = protocol;
  if (protocol != Protocol::paper) return;
  a.shared.params.iters_g0 = 10000;
  a.deformable = true;
  a.scale_offset = paper_train_params().field.scale_offset == ScaleOffset::additive ? "additive" : "log";
  a.min_densify_interval = 1;
}

struct Dataset {
  std::vector<TrainFrame<S>> train, holdout;
  std::vector<S> points, colors;
  std::size_t points_total = 0;
  BackgroundEstimate background;
  std::vector<SkippedFrame> skipped;
  SceneFrame frame;  // the model's frame -> the normalised one training works in
};

// The frames of --frames (video frame numbers: the images of images/ in name
// order), those without a COLMAP camera skipped; every K-th frame of the range
// held out. Points: those at least two training frames observed.
Dataset load(const Args& a) {
  const cli::PipelineFlags& f = a.shared;
  PipelineInput<S> in = load_colmap_input<S>(a.colmap, f.frames, cli::working_size(f), /*normalise=*/true, f.image_order);
  withhold_every(in, f.holdout_every);
  Dataset d;
  d.frame = in.frame;
  d.background = choose_background(in, f.background ? &*f.background : nullptr);
  if (f.random_background) force_random_background(in, d.background);
  d.skipped = in.source_skipped;
  for (int f : in.source) {
    TrainFrame<S> t;
    t.name = in.cameras[std::size_t(f)].name;
    t.time = S(in.time_code(f));
    t.image = in.images[std::size_t(f)];
    t.camera = in.cameras[std::size_t(f)].camera;
    (in.is_withheld(f) ? d.holdout : d.train).push_back(std::move(t));
  }
  ensure(!d.train.empty(), a.colmap, ": every selected frame is held out or has no camera");
  const SourcePoints<S> sp = source_points(in);
  d.points = sp.points;
  d.colors = sp.colors;
  d.points_total = sp.total;
  return d;
}

struct Eval {
  double psnr = 0, ssim = 0;
};

Eval evaluate(Trainer<S>& t, const std::vector<TrainFrame<S>>& frames, int threads, bool with_ssim) {
  Eval e;
  if (frames.empty()) return e;
  for (const auto& f : frames) {
    const Image<S> img = clamp01(t.render(f.camera, f.time));
    e.psnr += psnr(img, f.image) / double(frames.size());
    if (with_ssim) e.ssim += ssim_metric(img, f.image, threads) / double(frames.size());
  }
  return e;
}

Eval evaluate_static(const GaussianScene<S>& scene, const std::vector<TrainFrame<S>>& frames,
                     const std::array<double, 3>& bg, int threads) {
  Eval e;
  RenderParams<S> rp;
  for (int c = 0; c < 3; ++c) rp.background[std::size_t(c)] = S(bg[std::size_t(c)]);
  rp.threads = threads;
  Renderer<S> r(rp);
  for (const auto& f : frames) {
    const Image<S> img = clamp01(r.render(SceneView<S>(scene), f.camera).color);
    e.psnr += psnr(img, f.image) / double(frames.size());
    e.ssim += ssim_metric(img, f.image, threads) / double(frames.size());
  }
  return e;
}

int run(const Args& a, const RunInvocation& invocation) {
  namespace fs = std::filesystem;
  // Before any work: an output folder that cannot be created fails now, not after training.
  fs::create_directories(a.out);
  const Dataset d = load(a);
  std::fprintf(stderr, "reconstruct: %zu training frames, %zu held out, %zu skipped, %zu of %zu COLMAP points, %dx%d%s\n",
               d.train.size(), d.holdout.size(), d.skipped.size(), d.points.size() / 3, d.points_total,
               d.train.front().camera.intrinsics.width, d.train.front().camera.intrinsics.height, a.deformable ? ", deformable" : "");
  for (const auto& s : d.skipped) std::fprintf(stderr, "reconstruct: skipped %s: %s\n", s.name.c_str(), s.reason.c_str());
  std::fprintf(stderr, "reconstruct: background %.3f,%.3f,%.3f: %s\n", d.background.color[0], d.background.color[1],
               d.background.color[2], d.background.reason.c_str());
  const PipelineParams& shared = a.shared.params;
  const bool paper = a.shared.protocol == Protocol::paper;
  const int iters = shared.iters_g0, threads = shared.threads;
  TrainParams p = paper ? paper_train_params(iters) : TrainParams{};
  p.iterations = iters;
  p.seed = shared.seed;
  p.threads = threads;
  p.background = d.background.color;
  p.random_background = d.background.random;
  if (a.learn_background) {
    // Borders that disagree would choose a random colour; a learned one starts at their median instead.
    if (d.background.random) p.background = d.background.border_median;
    p.random_background = false;
    p.learned_background = true;
    std::fprintf(stderr, "reconstruct: learning the background colour, from %.3f,%.3f,%.3f\n", p.background[0],
                 p.background[1], p.background[2]);
  }
  p.deformable = a.deformable;
  const DeformationFieldParams field =
      !a.field.empty() ? parse_field(a.field) : paper ? paper_train_params().field : DeformationFieldParams::fast();
  p.field = field;
  p.field.scale_offset = a.scale_offset == "additive" ? ScaleOffset::additive : ScaleOffset::log;
  p.min_densify_interval = a.min_densify_interval;
  const TrainParams& levers = shared.train;  // the flags that skip work, and --exposure, as the pipeline's
  p.coarse_levels = levers.coarse_levels;
  p.coarse_fraction = levers.coarse_fraction;
  p.still_check_iterations = levers.still_check_iterations;
  p.still_gain_db = levers.still_gain_db;
  p.still_region_gain_db = levers.still_region_gain_db;
  p.still_holdout_every = levers.still_holdout_every;
  p.plateau_window = levers.plateau_window;
  p.plateau_tolerance = levers.plateau_tolerance;
  p.densify_params.max_gaussians = levers.densify_params.max_gaussians;
  p.exposure_compensation = levers.exposure_compensation;
  p.exposure_lr = levers.exposure_lr;
  p.scaling_lr = a.scaling_lr.value_or(p.scaling_lr);
  p.deform_lr_final = a.deform_lr_final.value_or(p.deform_lr_final);
  p.time_noise = a.time_noise.value_or(p.time_noise);
  p.densify_params.max_screen_fraction = a.max_screen_fraction.value_or(p.densify_params.max_screen_fraction);
  p.densify_interval_passes = a.densify_passes.value_or(p.densify_interval_passes);
  p.opacity_reset_passes = a.reset_passes.value_or(p.opacity_reset_passes);
  InitParams ip;
  ip.seed = shared.seed;
  GaussianScene<S> init;
  if (!d.points.empty()) {
    init = init_from_points(d.points, d.colors, ip);
  } else {
    init = init_random(frame_cameras(d.train), ip);
  }
  Trainer<S> trainer(d.train, std::move(init), p);

  const bool tty = isatty(fileno(stderr)) != 0;
  const int line_every = std::max(1, iters / 100);
  nlohmann::json curve = nlohmann::json::array();
  double train_seconds = 0;
  nlohmann::json shortcuts = nlohmann::json::object();
  while (!trainer.finished()) {
    const TrainProgress& pr = trainer.step();
    if (!pr.warning.empty()) std::fprintf(stderr, "reconstruct: warning: %s\n", pr.warning.c_str());
    train_seconds = pr.elapsed_seconds;
    const ShortcutState& sc = pr.shortcuts;
    if (sc.still_checked && !shortcuts.contains("still_check")) {
      shortcuts["still_check"] = still_check_json(sc, p, pr.iteration);
      std::fprintf(stderr, "reconstruct: %s\n", still_verdict_text(sc).c_str());
    }
    if (sc.plateau_last > 0 && (shortcuts["plateau"].empty() || shortcuts["plateau"].back()[1] != sc.plateau_last))
      shortcuts["plateau"].push_back({pr.iteration, sc.plateau_last});
    if (sc.stopped) {
      shortcuts["stopped_at"] = pr.iteration;
      std::fprintf(stderr, "reconstruct: loss plateaued, stopped at iteration %d\n", pr.iteration);
    }
    if (tty) {
      const int width = 30, filled = int(double(width) * pr.iteration / pr.iterations);
      std::fprintf(stderr, "\r[%s%s] %d/%d loss %.4f psnr %.2f gaussians %zu %.0f ms/it  ",
                   std::string(std::size_t(filled), '#').c_str(), std::string(std::size_t(width - filled), '.').c_str(),
                   pr.iteration, pr.iterations, pr.loss, pr.psnr, pr.gaussians, 1e3 * pr.seconds_per_iteration);
    } else if (pr.iteration % line_every == 0 || pr.iteration == 1) {
      std::fprintf(stderr,
                   "iteration %d/%d loss %.5f psnr %.3f gaussians %zu (cloned %zu split %zu pruned %zu, %zu of them "
                   "for size) sec/it %.4f elapsed %.1f s\n",
                   pr.iteration, pr.iterations, pr.loss, pr.psnr, pr.gaussians, pr.cloned, pr.split, pr.pruned,
                   pr.pruned_by_size, pr.seconds_per_iteration, pr.elapsed_seconds);
    }
    const bool stop = a.minutes > 0 && train_seconds >= 60.0 * a.minutes;
    if (a.eval_every > 0 && !d.holdout.empty() && (pr.iteration % a.eval_every == 0 || stop)) {
      const Eval e = evaluate(trainer, d.holdout, threads, false);
      curve.push_back({{"iteration", pr.iteration}, {"seconds", train_seconds}, {"holdout_psnr", e.psnr},
                       {"gaussians", pr.gaussians}});
      if (!tty) std::fprintf(stderr, "  holdout PSNR %.3f dB at %.1f s\n", e.psnr, train_seconds);
    }
    if (stop) break;
  }
  if (tty) std::fprintf(stderr, "\n");

  nlohmann::json m;
  m["iterations"] = trainer.iteration();
  m["seconds"] = train_seconds;
  m["gaussians"] = trainer.scene().size();
  const DensifySchedule& ds = trainer.schedule().densify;
  m["densification"] = {{"from", ds.densify_from}, {"until", ds.densify_until}, {"interval", ds.densify_interval},
                        {"opacity_reset_interval", ds.opacity_reset_interval}};
  m["background"] = {{"color", d.background.color}, {"random", p.random_background}, {"reason", d.background.reason}};
  if (p.learned_background) {
    const std::array<S, 3> learned = trainer.background();
    m["background"]["learned"] = {{"from", p.background}, {"color", {learned[0], learned[1], learned[2]}}};
  }
  m["points"] = {{"kept", d.points.size() / 3}, {"total", d.points_total}};
  if (a.deformable) m["field"] = std::to_string(field.depth) + "x" + std::to_string(field.width);
  m["train_psnr"] = evaluate(trainer, d.train, threads, false).psnr;
  if (!d.holdout.empty()) {
    const Eval e = evaluate(trainer, d.holdout, threads, true);
    m["holdout_psnr"] = e.psnr;
    m["holdout_ssim"] = e.ssim;
  }
  if (!curve.empty()) m["curve"] = curve;
  if (trainer.exposure().enabled()) {  // per training frame: A (row-major 3x3) and b of c' = A c + b
    nlohmann::json ex = nlohmann::json::array();
    for (std::size_t f = 0; f < trainer.exposure().frames(); ++f) {
      const S* t = trainer.exposure().transform(f);
      ex.push_back({{"A", std::vector<double>(t, t + 9)}, {"b", std::vector<double>(t + 9, t + 12)}});
    }
    m["exposure"] = ex;
  }
  m["frame"] = {{"origin", {d.frame.origin[0], d.frame.origin[1], d.frame.origin[2]}}, {"scale", d.frame.scale}};
  if (!shortcuts.empty()) m["levers"] = shortcuts;
  // How the run was asked for: its command line and the settings OUT/settings.toml replays.
  m["invocation"] = {{"command", invocation.command}, {"settings", invocation.settings},
                     {"memory_pages", invocation.memory_pages}};
  GaussianScene<S> out_scene;
  const std::array<S, 3> rc = trainer.background();
  const std::array<double, 3> resting_color{{double(rc[0]), double(rc[1]), double(rc[2])}};
  if (a.deformable && trainer.field()) {
    MedianBakeParams bp;
    bp.samples = shared.median_samples;
    bp.threads = threads;
    out_scene = bake_median(trainer.scene(), FieldDeformation<S>(*trainer.field(), threads), bp);
    if (!d.holdout.empty())
      m["holdout_psnr_baked"] = evaluate_static(out_scene, d.holdout, resting_color, threads).psnr;
  } else {
    out_scene = trainer.scene();
  }
  fs::create_directories(a.out);
  trainer.save_checkpoint((fs::path(a.out) / "checkpoint.bin").string());
  write_ply((fs::path(a.out) / "scene.ply").string(), d.frame.to_user(out_scene));
  write_file_atomic((fs::path(a.out) / "metrics.json").string(), m.dump(2) + "\n");
  write_file_atomic((fs::path(a.out) / "settings.toml").string(), invocation.settings);
  std::fprintf(stderr, "reconstruct: %s\n", m.dump().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  relaunch_with_huge_pages(argv);  // first: glibc reads its tunables only at start
  return cli::run([&] {
    Args a;
    const std::unique_ptr<CLI::App> app = cli::parse_with_protocol(
        a, argc, argv, define, [](const Args& x) { return x.shared.protocol; }, begin_protocol);
    cli::end_pipeline_flags(*app, a.shared);
    if (a.shared.holdout_every == 1)
      throw UsageError("reconstruct: --holdout-every must be 0 (none) or at least 2 (1 would hold out every frame)");
    if (a.learn_background && a.shared.random_background)
      throw UsageError("reconstruct: --learn-background and --background random exclude each other");
    RunInvocation invocation{cli::shell_command(argc, argv), cli::settings_text(*app), huge_page_state()};
    try {
      return run(a, invocation);
    } catch (const std::exception& e) {
      throw std::runtime_error("reconstruct: " + cli::describe(e));
    }
  });
}

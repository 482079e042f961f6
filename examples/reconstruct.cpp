// reconstruct: fit a (static or deformable) Gaussian scene to a video with COLMAP cameras.
//
//   reconstruct --colmap DIR [--frames A-B] [--holdout-every K] [--width W --height H] [--iters N]
//               [--deformable] [--median-samples 128] [--background r,g,b|random] [--threads N]
//               [--minutes M] [--eval-every N] [--seed S] [--field fast|original|DEPTHxWIDTH] --out DIR
//
// DIR (input) holds images/ and sparse/0/ (as shared/data/v3d/*). Frames are the COLMAP
// images in name order; --frames and --holdout-every count in that order (1-based);
// held-out frames (index a multiple of K) are never trained on. Images are resized to
// W x H (default 512 x 512) with the intrinsics rescaled. Time code of frame i of the n
// selected frames: (i - 1) / (n - 1).
//
// Writes to --out: checkpoint.bin (trainer state, incl. the deformation network),
// scene.ply (static: the trained scene; deformable: the MedianGS bake) and metrics.json
// {iterations, seconds, gaussians, train_psnr, holdout_psnr, holdout_ssim,
// holdout_psnr_baked (deformable), curve (with --eval-every), frame}. Training runs in a
// frame normalised to the cameras (splat/scene_frame.hpp; metrics.json "frame" gives
// origin and scale, and checkpoint.bin is in it); scene.ply is in the model's own frame. --minutes stops
// training early after that much training wall time. --field picks the deformation
// network (default fast = 4 x 64; original = the published 8 x 256). Errors: a message, exit
// status 2 (arguments) or 1 (inputs), and no output files.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>

#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "cli.hpp"
#include "pipeline_flags.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"

using namespace orbitforge;
using S = float;

namespace {

const char* kUsage =
    "usage: reconstruct --colmap DIR [--frames A-B] [--holdout-every K] [--width W --height H] [--iters N]\n"
    "                   [--deformable] [--median-samples 128] [--background r,g,b|random] [--threads N]\n"
    "                   [--minutes M] [--eval-every N] [--seed S] [--field fast|original|DEPTHxWIDTH]\n"
    "                   [--min-densify-interval N] [--scale-offset log|additive] [--protocol measured|paper]\n"
    "                   [--coarse-levels L [--coarse-fraction F]] [--max-gaussians N]\n"
    "                   [--still-check N [--still-gain DB]] [--plateau-window N [--plateau-tolerance X]]\n"
    "                   [--scaling-lr X] [--deform-lr-final X] [--time-noise S] [--max-screen-fraction F] --out DIR\n"
    "  --protocol paper: the DeformableGS backend's schedule, learning rates and 8 x 256 network, unscaled,\n"
    "                    10,000 iterations, deformable, frames at their own size (flags given override)\n"
    "  --scaling-lr, --deform-lr-final, --time-noise: one learning rate or the annealed noise on the\n"
    "                    time code (the backend's 0.1 for real scenes; 0 = off), to measure one departure\n"
    "                    from the paper at a time\n"
    "  --max-screen-fraction F: prune Gaussians wider on screen than F of the frames' longer side\n"
    "                    (0: 3DGS's 20 pixels)\n";

using cli::UsageError;

struct Args {
  std::string colmap, frames, out;
  Protocol protocol = Protocol::measured;
  int holdout_every = 0, width = 0, height = 0, iters = 30000, median_samples = 128, threads = 0;  // size 0: see load()
  int eval_every = 0;
  // Floor of the budget-scaled densification interval, as the pipeline's: scaled to a
  // few thousand iterations the published schedule densifies every 5-10 iterations,
  // too soon for cloned Gaussians to settle, and few training views then clone a
  // scene up to about a Gaussian per pixel (six 320x240 photographs: 375k).
  int min_densify_interval = 50;
  unsigned seed = 0;
  int coarse_levels = 0;
  double coarse_fraction = 0.5;
  // Levers that skip work (TrainParams; 0 = off).
  int still_check = 0, plateau_window = 0;
  double still_gain_db = TrainParams{}.still_gain_db, plateau_tolerance = 0.002;
  long max_gaussians = 0;
  // Single settings, for measuring a departure from the paper one at a time
  // (unset: the protocol's value).
  std::optional<double> scaling_lr, deform_lr_final, time_noise, max_screen_fraction;
  double minutes = 0;
  bool deformable = false;
  std::array<double, 3> background{{0, 0, 0}};
  bool background_set = false;  // else estimated from the frames' borders
  bool background_random = false;  // --background random
  ScaleOffset scale_offset = ScaleOffset::log;
  DeformationFieldParams field = DeformationFieldParams::fast();
};

// --field: "fast" (4 x 64, the default), "original" (8 x 256 with its skip) or DEPTHxWIDTH.
DeformationFieldParams parse_field(const std::string& v) {
  if (v == "fast") return DeformationFieldParams::fast();
  if (v == "original") return DeformationFieldParams::original();
  const auto x = v.find('x');
  if (x == std::string::npos) throw UsageError("reconstruct: --field must be fast, original or DEPTHxWIDTH, got '" + v + "'");
  DeformationFieldParams f = DeformationFieldParams::fast();
  f.depth = int(cli::parse_int("reconstruct", "--field", v.substr(0, x), 1));
  f.width = int(cli::parse_int("reconstruct", "--field", v.substr(x + 1), 1));
  return f;
}

long to_long(const std::string& flag, const std::string& v, long lo) {
  return cli::parse_int("reconstruct", flag, v, lo);
}

double to_double(const std::string& flag, const std::string& v) { return cli::parse_double("reconstruct", flag, v); }

double to_nonnegative(const std::string& flag, const std::string& v) {
  const double x = to_double(flag, v);
  if (x < 0) throw UsageError("reconstruct: " + flag + " must not be negative, got '" + v + "'");
  return x;
}

Args parse(int argc, char** argv) {
  Args a;
  a.protocol = cli::scan_protocol("reconstruct", argc, argv);
  if (a.protocol == Protocol::paper) {
    a.iters = 10000;
    a.deformable = true;
    a.field = paper_train_params().field;
    a.scale_offset = a.field.scale_offset;
    a.min_densify_interval = 1;
  }
  for (int i = 1; i < argc; ++i) {
    const std::string f = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError("reconstruct: " + f + " needs a value");
      return argv[++i];
    };
    if (f == "--colmap") a.colmap = value();
    else if (f == "--protocol") value();  // read by scan_protocol
    else if (f == "--frames") a.frames = value();
    else if (f == "--holdout-every") a.holdout_every = int(to_long(f, value(), 2));
    else if (f == "--width") a.width = int(to_long(f, value(), 8));
    else if (f == "--height") a.height = int(to_long(f, value(), 8));
    else if (f == "--iters") a.iters = int(to_long(f, value(), 1));
    else if (f == "--median-samples") a.median_samples = int(to_long(f, value(), 2));
    else if (f == "--threads") a.threads = cli::parse_threads("reconstruct", f, value());
    else if (f == "--eval-every") a.eval_every = int(to_long(f, value(), 1));
    else if (f == "--seed") a.seed = unsigned(to_long(f, value(), 0));
    else if (f == "--min-densify-interval") a.min_densify_interval = int(to_long(f, value(), 1));
    else if (f == "--coarse-levels") a.coarse_levels = int(to_long(f, value(), 0));
    else if (f == "--coarse-fraction") a.coarse_fraction = to_double(f, value());
    else if (f == "--still-check") a.still_check = int(to_long(f, value(), 0));
    else if (f == "--still-gain") a.still_gain_db = to_double(f, value());
    else if (f == "--plateau-window") a.plateau_window = int(to_long(f, value(), 0));
    else if (f == "--plateau-tolerance") a.plateau_tolerance = to_double(f, value());
    else if (f == "--max-gaussians") a.max_gaussians = to_long(f, value(), 0);
    else if (f == "--scaling-lr") a.scaling_lr = to_nonnegative(f, value());
    else if (f == "--deform-lr-final") a.deform_lr_final = to_nonnegative(f, value());
    else if (f == "--time-noise") a.time_noise = to_nonnegative(f, value());
    else if (f == "--max-screen-fraction") a.max_screen_fraction = to_nonnegative(f, value());
    else if (f == "--minutes") {
      a.minutes = to_double(f, value());
      if (a.minutes <= 0) throw UsageError("reconstruct: --minutes must be positive");
    } else if (f == "--deformable") a.deformable = true;
    else if (f == "--field") a.field = parse_field(value());
    else if (f == "--scale-offset") {
      const std::string v = value();
      if (v != "log" && v != "additive") throw UsageError("reconstruct: --scale-offset must be log or additive, got '" + v + "'");
      a.scale_offset = v == "log" ? ScaleOffset::log : ScaleOffset::additive;
    }
    else if (f == "--background") {
      const std::string v = value();
      a.background_random = v == "random";
      if (!a.background_random) {
        a.background = cli::parse_rgb("reconstruct", f, v);
        a.background_set = true;
      }
    } else if (f == "--out") a.out = value();
    else if (f == "-h" || f == "--help") {
      std::cout << kUsage;
      std::exit(0);
    } else throw UsageError("reconstruct: unknown argument '" + f + "'");
  }
  if (a.colmap.empty()) throw UsageError("reconstruct: --colmap DIR is required");
  if (a.out.empty()) throw UsageError("reconstruct: --out DIR is required");
  if (a.width == 0) a.width = a.height;
  if (a.height == 0) a.height = a.width;
  return a;
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
  // No size given: 512 pixels on the longer side, aspect kept (the paper's protocol: the frames' own).
  const WorkingSize size = a.width > 0                              ? WorkingSize::exact(a.width, a.height)
                           : protocol_loads_native_size(a.protocol) ? WorkingSize::native()
                                                                    : WorkingSize::longer_side(512);
  PipelineInput<S> in =
      load_colmap_input<S>(a.colmap, a.frames.empty() ? std::string("1-") : a.frames, size, /*normalise=*/true);
  withhold_every(in, a.holdout_every);
  Dataset d;
  d.frame = in.frame;
  d.background = choose_background(in, a.background_set ? &a.background : nullptr);
  if (a.background_random) force_random_background(in, d.background);
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

int run(const Args& a) {
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
  TrainParams p = a.protocol == Protocol::paper ? paper_train_params(a.iters) : TrainParams{};
  p.iterations = a.iters;
  p.seed = a.seed;
  p.threads = a.threads;
  p.background = d.background.color;
  p.random_background = d.background.random;
  p.deformable = a.deformable;
  p.field = a.field;
  p.field.scale_offset = a.scale_offset;
  p.min_densify_interval = a.min_densify_interval;
  p.coarse_levels = a.coarse_levels;
  p.coarse_fraction = a.coarse_fraction;
  p.still_check_iterations = a.still_check;
  p.still_gain_db = a.still_gain_db;
  p.plateau_window = a.plateau_window;
  p.plateau_tolerance = a.plateau_tolerance;
  p.densify_params.max_gaussians = std::size_t(a.max_gaussians);
  p.scaling_lr = a.scaling_lr.value_or(p.scaling_lr);
  p.deform_lr_final = a.deform_lr_final.value_or(p.deform_lr_final);
  p.time_noise = a.time_noise.value_or(p.time_noise);
  p.densify_params.max_screen_fraction = a.max_screen_fraction.value_or(p.densify_params.max_screen_fraction);
  InitParams ip;
  ip.seed = a.seed;
  GaussianScene<S> init;
  if (!d.points.empty()) {
    init = init_from_points(d.points, d.colors, ip);
  } else {
    std::vector<Camera<S>> cams;
    for (const auto& f : d.train) cams.push_back(f.camera);
    const S extent = cams.size() > 1 ? camera_extent(cams) : S(1);
    init = init_random(cams, extent > S(0) ? extent : S(1), ip);
  }
  Trainer<S> trainer(d.train, std::move(init), p);

  const bool tty = isatty(fileno(stderr)) != 0;
  const int line_every = std::max(1, a.iters / 100);
  nlohmann::json curve = nlohmann::json::array();
  double train_seconds = 0;
  nlohmann::json levers = nlohmann::json::object();
  while (!trainer.finished()) {
    const TrainProgress& pr = trainer.step();
    if (!pr.warning.empty()) std::fprintf(stderr, "reconstruct: warning: %s\n", pr.warning.c_str());
    train_seconds = pr.elapsed_seconds;
    const ShortcutState& sc = pr.shortcuts;
    if (sc.still_checked && !levers.contains("field_gain_db")) {
      levers["field_gain_db"] = sc.field_gain_db;
      levers["field_baked"] = sc.field_baked;
      levers["still_check_at"] = pr.iteration;
      std::fprintf(stderr, "reconstruct: the field fits the frames %.3f dB better than its bake: %s\n",
                   sc.field_gain_db, sc.field_baked ? "baked in, training static" : "training deformable");
    }
    if (sc.plateau_last > 0 && (levers["plateau"].empty() || levers["plateau"].back()[1] != sc.plateau_last))
      levers["plateau"].push_back({pr.iteration, sc.plateau_last});
    if (sc.stopped) {
      levers["stopped_at"] = pr.iteration;
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
      const Eval e = evaluate(trainer, d.holdout, a.threads, false);
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
  m["background"] = {{"color", d.background.color}, {"random", d.background.random}, {"reason", d.background.reason}};
  m["points"] = {{"kept", d.points.size() / 3}, {"total", d.points_total}};
  if (a.deformable) m["field"] = std::to_string(a.field.depth) + "x" + std::to_string(a.field.width);
  m["train_psnr"] = evaluate(trainer, d.train, a.threads, false).psnr;
  if (!d.holdout.empty()) {
    const Eval e = evaluate(trainer, d.holdout, a.threads, true);
    m["holdout_psnr"] = e.psnr;
    m["holdout_ssim"] = e.ssim;
  }
  if (!curve.empty()) m["curve"] = curve;
  m["frame"] = {{"origin", {d.frame.origin[0], d.frame.origin[1], d.frame.origin[2]}}, {"scale", d.frame.scale}};
  if (!levers.empty()) m["levers"] = levers;
  GaussianScene<S> out_scene;
  if (a.deformable && trainer.field()) {
    MedianBakeParams bp;
    bp.samples = a.median_samples;
    bp.threads = a.threads;
    out_scene = bake_median(trainer.scene(), FieldDeformation<S>(*trainer.field(), a.threads), bp);
    if (!d.holdout.empty())
      m["holdout_psnr_baked"] = evaluate_static(out_scene, d.holdout, d.background.color, a.threads).psnr;
  } else {
    out_scene = trainer.scene();
  }
  fs::create_directories(a.out);
  trainer.save_checkpoint((fs::path(a.out) / "checkpoint.bin").string());
  write_ply((fs::path(a.out) / "scene.ply").string(), d.frame.to_user(out_scene));
  write_file_atomic((fs::path(a.out) / "metrics.json").string(), m.dump(2) + "\n");
  std::fprintf(stderr, "reconstruct: %s\n", m.dump().c_str());
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    return run(parse(argc, argv));
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n" << kUsage;
    return 2;
  } catch (const std::exception& e) {
    std::cerr << "reconstruct: " << cli::describe(e) << "\n";
    return 1;
  }
}

// reconstruct: fit a (static or deformable) Gaussian scene to a video with COLMAP cameras.
//
//   reconstruct --colmap DIR [--frames A-B] [--holdout-every K] [--width W --height H] [--iters N]
//               [--deformable] [--median-samples 128] [--background r,g,b] [--threads N]
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
// holdout_psnr_baked (deformable), curve (with --eval-every)}. --minutes stops
// training early after that much training wall time. --field picks the deformation
// network (default fast = 4 x 64; original = the published 8 x 256). Errors: a message, exit
// status 2 (arguments) or 1 (inputs), and no output files.
#include <unistd.h>

#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "cli.hpp"

using namespace orbitforge;
using S = float;

namespace {

const char* kUsage =
    "usage: reconstruct --colmap DIR [--frames A-B] [--holdout-every K] [--width W --height H] [--iters N]\n"
    "                   [--deformable] [--median-samples 128] [--background r,g,b] [--threads N]\n"
    "                   [--minutes M] [--eval-every N] [--seed S] [--field fast|original|DEPTHxWIDTH]\n"
    "                   [--min-densify-interval N] --out DIR\n";

using cli::UsageError;

struct Args {
  std::string colmap, frames, out;
  int holdout_every = 0, width = 512, height = 512, iters = 30000, median_samples = 128, threads = 0;
  int eval_every = 0;
  int min_densify_interval = 1;  // floor of the budget-scaled densification interval (TrainParams)
  unsigned seed = 0;
  double minutes = 0;
  bool deformable = false;
  std::array<double, 3> background{{0, 0, 0}};
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

Args parse(int argc, char** argv) {
  Args a;
  for (int i = 1; i < argc; ++i) {
    const std::string f = argv[i];
    auto value = [&]() -> std::string {
      if (i + 1 >= argc) throw UsageError("reconstruct: " + f + " needs a value");
      return argv[++i];
    };
    if (f == "--colmap") a.colmap = value();
    else if (f == "--frames") a.frames = value();
    else if (f == "--holdout-every") a.holdout_every = int(to_long(f, value(), 2));
    else if (f == "--width") a.width = int(to_long(f, value(), 8));
    else if (f == "--height") a.height = int(to_long(f, value(), 8));
    else if (f == "--iters") a.iters = int(to_long(f, value(), 1));
    else if (f == "--median-samples") a.median_samples = int(to_long(f, value(), 2));
    else if (f == "--threads") a.threads = int(to_long(f, value(), 0));
    else if (f == "--eval-every") a.eval_every = int(to_long(f, value(), 1));
    else if (f == "--seed") a.seed = unsigned(to_long(f, value(), 0));
    else if (f == "--min-densify-interval") a.min_densify_interval = int(to_long(f, value(), 1));
    else if (f == "--minutes") {
      a.minutes = to_double(f, value());
      if (a.minutes <= 0) throw UsageError("reconstruct: --minutes must be positive");
    } else if (f == "--deformable") a.deformable = true;
    else if (f == "--field") a.field = parse_field(value());
    else if (f == "--background") {
      a.background = cli::parse_rgb("reconstruct", f, value());
    } else if (f == "--out") a.out = value();
    else if (f == "-h" || f == "--help") {
      std::cout << kUsage;
      std::exit(0);
    } else throw UsageError("reconstruct: unknown argument '" + f + "'");
  }
  if (a.colmap.empty()) throw UsageError("reconstruct: --colmap DIR is required");
  if (a.out.empty()) throw UsageError("reconstruct: --out DIR is required");
  return a;
}

struct Dataset {
  std::vector<TrainFrame<S>> train, holdout;
  std::vector<S> points, colors;
};

Dataset load(const Args& a) {
  namespace fs = std::filesystem;
  const std::string model_dir = find_colmap_model_dir(a.colmap);
  const ColmapModel model = read_colmap_model(model_dir);
  auto cams = colmap_frame_cameras<S>(model);
  if (!a.frames.empty()) cams = select_frames(cams, parse_frame_range(a.frames));
  const int n = int(cams.size());
  ensure(n >= 1, a.colmap, ": no frames selected");
  const fs::path images = fs::path(a.colmap) / "images";
  ensure(fs::is_directory(images), a.colmap, ": no images/ folder next to the COLMAP model");
  Dataset d;
  for (int i = 1; i <= n; ++i) {
    const auto& fc = cams[std::size_t(i - 1)];
    ensure(fc.valid, a.colmap, ": image ", fc.name, " has no valid pose");
    TrainFrame<S> f;
    f.name = fc.name;
    f.time = n > 1 ? S(i - 1) / S(n - 1) : S(0);
    const Image<S> img = read_image<S>((images / fc.name).string());
    const auto& k = fc.camera.intrinsics;
    ensure(img.width == k.width && img.height == k.height, (images / fc.name).string(), ": image is ", img.width,
           "x", img.height, ", its COLMAP camera is ", k.width, "x", k.height);
    f.image = (img.width == a.width && img.height == a.height) ? img
                                                                : resize_image(img, a.width, a.height,
                                                                               ResizeFilter::area);
    f.camera = fc.camera;
    f.camera.intrinsics = k.resized(a.width, a.height);
    const bool held = a.holdout_every > 0 && i % a.holdout_every == 0;
    (held ? d.holdout : d.train).push_back(std::move(f));
  }
  ensure(!d.train.empty(), a.colmap, ": every selected frame is held out");
  for (const auto& p : model.points) {
    for (int c = 0; c < 3; ++c) {
      d.points.push_back(S(p.xyz[c]));
      d.colors.push_back(S(p.rgb[std::size_t(c)]) / S(255));
    }
  }
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
  const Dataset d = load(a);
  std::fprintf(stderr, "reconstruct: %zu training frames, %zu held out, %zu COLMAP points, %dx%d%s\n",
               d.train.size(), d.holdout.size(), d.points.size() / 3, a.width, a.height,
               a.deformable ? ", deformable" : "");
  TrainParams p;
  p.iterations = a.iters;
  p.seed = a.seed;
  p.threads = a.threads;
  p.background = a.background;
  p.deformable = a.deformable;
  p.field = a.field;
  p.min_densify_interval = a.min_densify_interval;
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
  while (trainer.iteration() < a.iters) {
    const TrainProgress& pr = trainer.step();
    train_seconds = pr.elapsed_seconds;
    if (tty) {
      const int width = 30, filled = int(double(width) * pr.iteration / pr.iterations);
      std::fprintf(stderr, "\r[%s%s] %d/%d loss %.4f psnr %.2f gaussians %zu %.0f ms/it  ",
                   std::string(std::size_t(filled), '#').c_str(), std::string(std::size_t(width - filled), '.').c_str(),
                   pr.iteration, pr.iterations, pr.loss, pr.psnr, pr.gaussians, 1e3 * pr.seconds_per_iteration);
    } else if (pr.iteration % line_every == 0 || pr.iteration == 1) {
      std::fprintf(stderr, "iteration %d/%d loss %.5f psnr %.3f gaussians %zu sec/it %.4f elapsed %.1f s\n",
                   pr.iteration, pr.iterations, pr.loss, pr.psnr, pr.gaussians, pr.seconds_per_iteration,
                   pr.elapsed_seconds);
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
  if (a.deformable) m["field"] = std::to_string(a.field.depth) + "x" + std::to_string(a.field.width);
  m["train_psnr"] = evaluate(trainer, d.train, a.threads, false).psnr;
  if (!d.holdout.empty()) {
    const Eval e = evaluate(trainer, d.holdout, a.threads, true);
    m["holdout_psnr"] = e.psnr;
    m["holdout_ssim"] = e.ssim;
  }
  if (!curve.empty()) m["curve"] = curve;
  GaussianScene<S> out_scene;
  if (a.deformable) {
    MedianBakeParams bp;
    bp.samples = a.median_samples;
    bp.threads = a.threads;
    out_scene = bake_median(trainer.scene(), FieldDeformation<S>(*trainer.field(), a.threads), bp);
    if (!d.holdout.empty()) m["holdout_psnr_baked"] = evaluate_static(out_scene, d.holdout, a.background, a.threads).psnr;
  } else {
    out_scene = trainer.scene();
  }
  fs::create_directories(a.out);
  trainer.save_checkpoint((fs::path(a.out) / "checkpoint.bin").string());
  write_ply((fs::path(a.out) / "scene.ply").string(), out_scene);
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
    std::cerr << "reconstruct: " << e.what() << "\n";
    return 1;
  }
}

// full_pipeline: the whole method, from a source video to a closed-orbit
// Gaussian Splatting scene (final.ply, and final.spz for web viewers) with a report.
//
//   full_pipeline --video FILE | --images DIR | --colmap DIR | --transforms FILE [--images DIR]
//                 | --images DIR --npy-extrinsics F --npy-intrinsics F
//                 [--protocol measured|paper] [--frames A-B] [--completion ...]
//                 [--holdout-every K] [--prompt TEXT] [...] --out DIR   (--help lists every flag)
//   full_pipeline            (no arguments: the embedded synthetic input, oracle completion,
//                             small size, writes ./out/pipeline)
//
// --video and --images alone estimate the cameras of the source frames with
// COLMAP (stage "cameras", pipeline/stages/cameras.hpp; needs the ffmpeg and
// colmap programs); the other frames get no camera, so the completion defaults
// to external and the oracle providers cannot be used.
//
// A second run with the same arguments skips every finished stage. With
// --completion external the run stops after writing the completion request
// (exit status 3); run it again once the completed frames are in place.
// Errors: a message and exit status 2 (arguments) or 1 (inputs).
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

#include "cli.hpp"
#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/pipeline/completion/providers.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/frame_inputs.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "orbitforge/pipeline/stages/cameras.hpp"
#include "pipeline_flags.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"

using namespace orbitforge;
using S = float;

namespace {

const char* kDescription =
    "full_pipeline: the whole method, from a recorded video to a closed-orbit Gaussian Splatting scene\n"
    "(final.ply, final.spz) with a report.\n"
    "  full_pipeline INPUT [flags] --out DIR\n"
    "  full_pipeline   (no arguments: the embedded synthetic input, oracle completion, small size -> ./out/pipeline)\n"
    "INPUT is one of --video, --images, --colmap, --transforms [--images] or --images with --npy-extrinsics and\n"
    "--npy-intrinsics; frames in name order, --frames picks the source. With --video or --images alone only the\n"
    "source frames get cameras (COLMAP), and a recorded input runs with --completion external unless one is named\n"
    "(oracle and perturbed read the gap frames). A second run with the same settings skips every finished stage;\n"
    "--completion external stops after writing the completion request (exit status 3) until the completed frames\n"
    "are in place. Every run writes OUT/settings.toml, which --config replays.";

struct Inputs {
  std::string colmap, video, images, transforms, npy_ext, npy_int, npy_size, camera_model = "SIMPLE_PINHOLE";
  std::string reference;  // a COLMAP folder of every frame, for scoring only
  double fps = 0;
  bool camera_model_set = false;
  bool npy() const { return !npy_ext.empty() || !npy_int.empty(); }
  // COLMAP estimates the cameras: a video, or an image folder without cameras of its own.
  bool estimate_cameras() const { return !video.empty() || (!images.empty() && transforms.empty() && !npy()); }
  bool recorded() const { return !colmap.empty() || !video.empty() || !images.empty() || !transforms.empty() || npy(); }
};

void check_inputs(const Inputs& in, const cli::PipelineFlags& flags, bool frames_set, bool completion_set) {
  auto usage = [](bool ok, const std::string& m) {
    if (!ok) throw cli::UsageError("full_pipeline: " + m);
  };
  const bool npy = in.npy();
  usage(in.colmap.empty() || (in.video.empty() && in.images.empty() && in.transforms.empty() && !npy),
        "--colmap is an input on its own (not with --video, --images, --transforms or --npy-*)");
  usage(in.video.empty() || (in.images.empty() && in.transforms.empty() && !npy),
        "--video is an input on its own (its frames are extracted; not with --images, --transforms or --npy-*)");
  usage(in.transforms.empty() || !npy, "give --transforms or --npy-extrinsics/--npy-intrinsics, not both");
  usage(!npy || (!in.npy_ext.empty() && !in.npy_int.empty()), "--npy-extrinsics and --npy-intrinsics go together");
  usage(!npy || !in.images.empty(), "--npy-extrinsics/--npy-intrinsics need --images DIR (camera i is the i-th image)");
  usage(in.npy_size.empty() || npy, "--npy-size goes with --npy-extrinsics/--npy-intrinsics");
  usage(in.fps == 0 || !in.video.empty(), "--fps goes with --video");
  usage(!in.camera_model_set || in.estimate_cameras(), "--camera-model goes with --video or --images alone (COLMAP)");
  usage(in.reference.empty() || in.estimate_cameras(),
        "--reference goes with --video or --images alone (cameras estimated from the source frames)");
  usage((flags.focal_px == 0 && flags.fov_deg == 0 && !flags.focal_search && flags.orbit_refine == "flagged" &&
         flags.sift_peak_threshold == 0) ||
            in.estimate_cameras(),
        "--focal, --fov, --focal-search, --orbit-refine and --sift-peak-threshold go with --video or --images alone "
        "(COLMAP)");
  usage(in.camera_model == "SIMPLE_PINHOLE" || in.camera_model == "PINHOLE",
        "--camera-model must be SIMPLE_PINHOLE or PINHOLE, got '" + in.camera_model + "'");
  usage(flags.image_order == ImageOrder::name || !in.colmap.empty(),
        "--image-order ring goes with --colmap (a video's or a folder's source frames are chosen by name before "
        "COLMAP gives them cameras)");
  usage(!frames_set || in.recorded(), "--frames needs a recorded input (--video, --images, --colmap, ...)");
  const std::string& c = flags.params.completion;
  usage(!completion_set || !in.estimate_cameras() || !in.reference.empty() ||
            (c != "oracle" && c != "perturbed" && c != "perturbed-geometric"),
        "--completion " + c + " needs recorded cameras for the gap frames, and with " +
            (in.video.empty() ? "--images" : "--video") +
            " only the source frames get cameras (COLMAP sees nothing else); use --completion external (the "
            "default for this input) or none, or give --reference DIR (a model of every frame, for scoring)");
}

// Everything the command line sets.
struct Args {
  Inputs in;
  cli::PipelineFlags flags;
  std::string out;
};

std::unique_ptr<CLI::App> define(Args& a) {
  auto app = std::make_unique<CLI::App>(kDescription, "full_pipeline");
  cli::setup(*app, /*with_config=*/true);
  Inputs& in = a.in;
  const char* input = cli::kInputGroup;
  app->add_option("--video", in.video,
                  "a video ffmpeg reads; frames -> OUT/cameras/images, cameras of the source frames only by COLMAP "
                  "(needs the ffmpeg and colmap programs)")
      ->group(input);
  app->add_option("--images", in.images,
                  "a folder of frames; alone: cameras of the source frames by COLMAP; with --transforms or "
                  "--npy-*: the frames those cameras belong to")
      ->group(input);
  app->add_option("--colmap", in.colmap, "a COLMAP dataset (images/ + sparse/0) with cameras already estimated")
      ->group(input);
  app->add_option("--transforms", in.transforms, "cameras from transforms.json (frames: its file_paths, or --images)")
      ->group(input);
  app->add_option("--npy-extrinsics", in.npy_ext, "VGGT-style arrays: camera i for the i-th image of --images")
      ->group(input);
  app->add_option("--npy-intrinsics", in.npy_int, "see --npy-extrinsics")->group(input);
  app->add_option("--npy-size", in.npy_size, "WxH, the size the estimator saw (default: the frames')")
      ->check(CLI::Validator(
          [](std::string& s) -> std::string {
            int w = 0, h = 0;
            char end = 0;
            if (std::sscanf(s.c_str(), "%dx%d%c", &w, &h, &end) != 2 || w <= 0 || h <= 0)
              return "expects WxH, got '" + s + "'";
            return {};
          },
          "WxH"))
      ->group(input);
  cli::unset_when_zero(app->add_option("--fps", in.fps, "--video: resample to R frames per second (default: every frame)"),
                       in.fps)
      ->check(cli::positive())
      ->group(input);
  app->add_option("--camera-model", in.camera_model,
                  "COLMAP's one camera with --video or --images alone (default SIMPLE_PINHOLE)")
      ->check(CLI::IsMember({"SIMPLE_PINHOLE", "PINHOLE"}))
      ->group(input);
  app->add_option("--reference", in.reference,
                  "with --video / --images: a COLMAP folder of the same video estimated from every frame, used only "
                  "to score the run (and by the oracle)")
      ->group(input);
  cli::add_pipeline_flags(*app, a.flags);
  app->add_option("--prompt", a.flags.params.prompt, "the scene's description for the completion request")
      ->group("Pipeline");
  app->add_option("--out", a.out, "output folder (required with a recorded input; default out/pipeline)");
  return app;
}

}  // namespace

int main(int argc, char** argv) {
  relaunch_with_huge_pages(argv);  // first: glibc reads its tunables only at start
  Args args;
  Inputs& in = args.in;
  cli::PipelineFlags& flags = args.flags;
  std::string& out = args.out;
  std::unique_ptr<CLI::App> app;
  try {
    app = cli::parse_with_protocol(
        args, argc, argv, define, [](const Args& a) { return a.flags.protocol; },
        [](Args& a, Protocol p) { cli::begin_pipeline_flags(a.flags, p); });
    cli::end_pipeline_flags(*app, flags);
    const bool frames_set = app->count("--frames") > 0, completion_set = app->count("--completion") > 0;
    in.camera_model_set = app->count("--camera-model") > 0;
    check_inputs(in, flags, frames_set, completion_set);
    // A recorded input is a real run unless a completion is named: the oracle
    // and the perturbed provider read frames the method would not have.
    if (in.recorded() && !completion_set) flags.params.completion = "external";
    if (in.recorded() && out.empty()) throw cli::UsageError("full_pipeline: --out DIR is required with a recorded input");
  } catch (const cli::HelpShown&) {
    return 0;
  } catch (const cli::UsageError& e) {
    std::cerr << e.what() << "\n";
    return 2;
  } catch (const Error& e) {
    std::cerr << "full_pipeline: " << e.what() << "\n";
    return 2;
  }

  PipelineParams& p = flags.params;
  CameraStageParams cp = cli::camera_stage_params(flags);
  if (in.estimate_cameras()) {
    cp.video = in.video;
    cp.images = in.images;
    cp.fps = in.fps;
    cp.camera_model = in.camera_model;
    // Before any work: the programs the cameras stage runs.
    for (const auto& [program, package] : camera_stage_programs(cp))
      if (find_program(program).empty()) {
        std::cerr << missing_program_message("full_pipeline", in.video.empty() ? "--images" : "--video", program,
                                             package)
                  << "\n";
        return 1;
      }
  }
  if (!in.recorded()) {
    // The embedded synthetic input, with the defaults of a run without arguments:
    // small enough to finish in a few minutes on 2 cores.
    if (out.empty()) out = "out/pipeline";
    if (argc == 1) {
      p.iters_g0 = p.iters_g1 = 1000;
      p.orbit.views = 121;
      p.init_points = 5000;
      p.median_samples = 64;
    }
    if (p.prompt.empty()) p.prompt = "a striped capsule on a checkered floor";
    cli::leave_out(*app, "--frames");  // it reads no video frames
  }
  if (!in.estimate_cameras()) cli::leave_out(*app, "--camera-model");  // COLMAP does not run
  try {
    // Before any work: the settings as this run resolved them, and its command line.
    p.invocation = cli::record_invocation(*app, argc, argv, out);
    PipelineInput<S> input;
    PipelineRun<S> run;
    const auto size = cli::working_size(flags);
    if (!in.recorded()) {
      SyntheticInputParams sp;
      sp.width = flags.width > 0 ? flags.width : 96;
      sp.height = flags.height > 0 ? flags.height : 96;
      sp.focal = 160.0 * sp.height / 128.0;
      input = synthetic_pipeline_input<S>(sp, p.threads);
      withhold_every(input, flags.holdout_every);
      BackgroundEstimate bg = choose_background(input, flags.background ? &*flags.background : nullptr);
      if (flags.random_background) force_random_background(input, bg);
      std::fprintf(stderr, "full_pipeline: background %.3f,%.3f,%.3f: %s\n", bg.color[0], bg.color[1], bg.color[2],
                   bg.reason.c_str());
    } else if (in.estimate_cameras()) {
      std::string key;
      input = cli::load_estimated_input<S>("full_pipeline", out, cp, flags, in.reference, &key);
      run.keys["cameras"] = key;  // the report counts its time
    } else if (!in.colmap.empty()) {
      std::string key;
      input = cli::load_recorded_input<S>("full_pipeline", in.colmap, out, flags, &key);
      if (!key.empty()) run.keys["points"] = key;  // the report counts its time
    } else {
      if (!in.transforms.empty()) {
        input = load_transforms_input<S>(in.transforms, in.images, flags.frames, size);
      } else {
        int nw = 0, nh = 0;
        if (!in.npy_size.empty()) std::sscanf(in.npy_size.c_str(), "%dx%d", &nw, &nh);  // checked by --npy-size
        input = load_npy_input<S>(in.npy_ext, in.npy_int, in.images, nw, nh, flags.frames, size);
      }
      cli::finish_recorded_input("full_pipeline", input, flags);
    }
    std::fprintf(stderr, "full_pipeline: %s -> %s (protocol %s, completion %s)\n", input.description.c_str(),
                 out.c_str(), protocol_name(flags.protocol), p.completion.c_str());
    const nlohmann::json r = run_pipeline(input, p, out, nullptr, &run);
    std::cout << report_markdown(r);
    std::fprintf(stderr, "full_pipeline: done; report in %s/report.md, scene in %s/final.ply (and final.spz)\n",
                 out.c_str(), out.c_str());
    return 0;
  } catch (const PipelineStopped& e) {
    std::cerr << "full_pipeline: stopped: " << e.what() << "\n";
    return 3;
  } catch (const std::exception& e) {
    std::cerr << "full_pipeline: error: " << cli::describe(e) << "\n";
    return 1;
  }
}

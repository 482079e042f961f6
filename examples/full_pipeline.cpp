// full_pipeline: the whole method, from a recorded source video with estimated
// cameras to a closed-orbit Gaussian Splatting scene (final.ply) with a report.
//
//   full_pipeline --colmap DIR [--frames A-B] [--completion external|oracle|none] [--prompt TEXT]
//                 [--width W --height H] [--iters N] [--iters-g1 N] [--views 361] [--render-stride K]
//                 [--static] [--g1-random-init] [--median-samples 128] [--background r,g,b]
//                 [--threads N] [--seed S] [--quiet] --out DIR
//   full_pipeline            (no arguments: the embedded synthetic input, oracle completion,
//                             small size, writes ./out/pipeline)
//
// A second run with the same arguments skips every finished stage. With
// --completion external the run stops after writing the completion request
// (exit status 3); run it again once the completed frames are in place.
// Errors: a message and exit status 2 (arguments) or 1 (inputs).
#include <cstdio>
#include <iostream>
#include <string>

#include "orbitforge/pipeline/pipeline.hpp"

using namespace orbitforge;
using S = float;

namespace {

const char* kUsage =
    "usage: full_pipeline --colmap DIR [--frames A-B] [--completion external|oracle|none] [--prompt TEXT]\n"
    "                     [--width W --height H] [--iters N] [--iters-g1 N] [--views 361] [--render-stride K]\n"
    "                     [--static] [--g1-random-init] [--median-samples 128] [--background r,g,b]\n"
    "                     [--threads N] [--seed S] [--quiet] --out DIR\n"
    "       full_pipeline   (no arguments: embedded synthetic input -> ./out/pipeline)\n";

struct UsageError : std::runtime_error {
  using std::runtime_error::runtime_error;
};

long to_long(const std::string& flag, const std::string& v, long lo) {
  std::size_t used = 0;
  long x = 0;
  try {
    x = std::stol(v, &used);
  } catch (...) {
    used = 0;
  }
  if (v.empty() || used != v.size() || x < lo)
    throw UsageError("full_pipeline: " + flag + " expects an integer >= " + std::to_string(lo) + ", got '" + v + "'");
  return x;
}

}  // namespace

int main(int argc, char** argv) {
  std::string colmap, frames, out;
  PipelineParams p;
  int width = 0, height = 0;
  bool iters_g1_set = false;
  int holdout_every = 0;
  std::array<double, 3> background{{-1, -1, -1}};
  try {
    for (int i = 1; i < argc; ++i) {
      const std::string f = argv[i];
      auto value = [&]() -> std::string {
        if (i + 1 >= argc) throw UsageError("full_pipeline: " + f + " needs a value");
        return argv[++i];
      };
      if (f == "--colmap") colmap = value();
      else if (f == "--frames") frames = value();
      else if (f == "--completion") {
        p.completion = value();
        if (p.completion != "external" && p.completion != "oracle" && p.completion != "none" &&
            p.completion != "perturbed")
          throw UsageError("full_pipeline: --completion must be external, oracle, perturbed or none, got '" +
                           p.completion + "'");
      } else if (f == "--prompt") p.prompt = value();
      else if (f == "--width") width = int(to_long(f, value(), 8));
      else if (f == "--height") height = int(to_long(f, value(), 8));
      else if (f == "--iters") p.iters_g0 = int(to_long(f, value(), 1));
      else if (f == "--iters-g1") {
        p.iters_g1 = int(to_long(f, value(), 1));
        iters_g1_set = true;
      } else if (f == "--views") p.orbit.views = int(to_long(f, value(), 9));
      else if (f == "--render-stride") p.render_stride = int(to_long(f, value(), 1));
      else if (f == "--median-samples") p.median_samples = int(to_long(f, value(), 2));
      else if (f == "--threads") p.threads = int(to_long(f, value(), 0));
      else if (f == "--seed") p.seed = unsigned(to_long(f, value(), 0));
      else if (f == "--static") p.deformable = false;
      else if (f == "--holdout-every") holdout_every = int(to_long(f, value(), 0));
      else if (f == "--g1-data") p.g1_data = parse_g1_data(value());
      else if (f == "--g1-arc-renders") p.g1_arc_renders = true;
      else if (f == "--g1-deformable") p.g1_deformable = true;
      else if (f == "--g1-static") p.g1_deformable = false;
      else if (f == "--compare-g1-paper") p.compare_g1_paper = true;
      else if (f == "--oracle-bound") p.oracle_bound = true;
      else if (f == "--g1-random-init") p.g1_from_gmed0 = false;
      else if (f == "--quiet") p.progress = false;
      else if (f == "--background") {
        const std::string v = value();
        if (std::sscanf(v.c_str(), "%lf,%lf,%lf", &background[0], &background[1], &background[2]) != 3)
          throw UsageError("full_pipeline: --background expects r,g,b in [0, 1], got '" + v + "'");
        for (double c : background)
          if (!(c >= 0 && c <= 1)) throw UsageError("full_pipeline: --background components must be in [0, 1]");
      } else if (f == "--out") out = value();
      else if (f == "-h" || f == "--help") {
        std::cout << kUsage;
        return 0;
      } else
        throw UsageError("full_pipeline: unknown argument '" + f + "'");
    }
    if (!iters_g1_set) p.iters_g1 = p.iters_g0;
    if (colmap.empty() && !frames.empty()) throw UsageError("full_pipeline: --frames needs --colmap");
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n" << kUsage;
    return 2;
  }

  try {
    PipelineInput<S> input;
    if (colmap.empty()) {
      // The embedded default: small enough to finish in a few minutes on 2 cores.
      SyntheticInputParams sp;
      sp.width = width > 0 ? width : 96;
      sp.height = height > 0 ? height : 96;
      sp.focal = 160.0 * sp.height / 128.0;
      if (out.empty()) out = "out/pipeline";
      if (argc == 1) {
        p.iters_g0 = p.iters_g1 = 1000;
        p.orbit.views = 121;
        p.init_points = 5000;
        p.median_samples = 64;
      }
      input = synthetic_pipeline_input<S>(sp, p.threads);
      if (p.prompt.empty()) p.prompt = "a striped capsule on a checkered floor";
    } else {
      if (out.empty()) throw UsageError("full_pipeline: --out DIR is required with --colmap");
      input = load_colmap_input<S>(colmap, frames.empty() ? std::string("1-33") : frames, width > 0 ? width : 512,
                                   height > 0 ? height : 512);
    }
    withhold_every(input, holdout_every);
    const BackgroundEstimate bg = choose_background(input, background[0] >= 0 ? &background : nullptr);
    std::fprintf(stderr, "full_pipeline: background %.3f,%.3f,%.3f: %s\n", bg.color[0], bg.color[1], bg.color[2],
                 bg.reason.c_str());
    std::fprintf(stderr, "full_pipeline: %s -> %s (completion: %s)\n", input.description.c_str(), out.c_str(),
                 p.completion.c_str());
    const nlohmann::json r = run_pipeline(input, p, out);
    std::cout << report_markdown(r);
    std::fprintf(stderr, "full_pipeline: done; report in %s/report.md, scene in %s/final.ply\n", out.c_str(),
                 out.c_str());
    return 0;
  } catch (const UsageError& e) {
    std::cerr << e.what() << "\n" << kUsage;
    return 2;
  } catch (const PipelineStopped& e) {
    std::cerr << "full_pipeline: stopped: " << e.what() << "\n";
    return 3;
  } catch (const std::exception& e) {
    std::cerr << "full_pipeline: error: " << e.what() << "\n";
    return 1;
  }
}

// full_pipeline: the whole method, from a recorded source video with estimated
// cameras to a closed-orbit Gaussian Splatting scene (final.ply) with a report.
//
//   full_pipeline --colmap DIR [--protocol measured|paper] [--frames A-B] [--completion ...]
//                 [--holdout-every K] [--prompt TEXT] [...] --out DIR   (--help lists every flag)
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

#include "cli.hpp"
#include "orbitforge/pipeline/completion_providers.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "pipeline_flags.hpp"

using namespace orbitforge;
using S = float;

namespace {

const std::string kUsage = std::string(
    "usage: full_pipeline --colmap DIR [flags] --out DIR\n"
    "       full_pipeline   (no arguments: embedded synthetic input -> ./out/pipeline)\n"
    "  --prompt TEXT               the scene's description for the completion request\n") +
                           cli::kPipelineFlagsUsage;

}  // namespace

int main(int argc, char** argv) {
  std::string colmap, out;
  cli::PipelineFlags flags;
  bool frames_set = false;
  try {
    cli::begin_pipeline_flags("full_pipeline", argc, argv, flags);
    cli::ArgWalker a("full_pipeline", argc, argv);
    while (a.next()) {
      const std::string f = a.flag();
      if (f == "--frames") frames_set = true;
      if (cli::parse_pipeline_flag("full_pipeline", a, flags)) continue;
      if (f == "--colmap") colmap = a.value();
      else if (f == "--prompt") flags.params.prompt = a.value();
      else if (f == "--out") out = a.value();
      else if (f == "-h" || f == "--help") {
        std::cout << kUsage;
        return 0;
      } else
        a.unknown();
    }
    cli::end_pipeline_flags(flags);
    if (colmap.empty() && frames_set) throw cli::UsageError("full_pipeline: --frames needs --colmap");
  } catch (const cli::UsageError& e) {
    std::cerr << e.what() << "\n" << kUsage;
    return 2;
  } catch (const Error& e) {
    std::cerr << "full_pipeline: " << e.what() << "\n" << kUsage;
    return 2;
  }

  PipelineParams& p = flags.params;
  try {
    PipelineInput<S> input;
    if (colmap.empty()) {
      // The embedded default: small enough to finish in a few minutes on 2 cores.
      SyntheticInputParams sp;
      sp.width = flags.width > 0 ? flags.width : 96;
      sp.height = flags.height > 0 ? flags.height : 96;
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
      withhold_every(input, flags.holdout_every);
      const BackgroundEstimate bg = choose_background(input, flags.background ? &*flags.background : nullptr);
      std::fprintf(stderr, "full_pipeline: background %.3f,%.3f,%.3f: %s\n", bg.color[0], bg.color[1], bg.color[2],
                   bg.reason.c_str());
    } else {
      if (out.empty()) throw cli::UsageError("full_pipeline: --out DIR is required with --colmap");
      input = cli::load_recorded_input<S>("full_pipeline", colmap, flags);
    }
    std::fprintf(stderr, "full_pipeline: %s -> %s (protocol %s, completion %s)\n", input.description.c_str(),
                 out.c_str(), protocol_name(flags.protocol), p.completion.c_str());
    const nlohmann::json r = run_pipeline(input, p, out);
    std::cout << report_markdown(r);
    std::fprintf(stderr, "full_pipeline: done; report in %s/report.md, scene in %s/final.ply\n", out.c_str(),
                 out.c_str());
    return 0;
  } catch (const cli::UsageError& e) {
    std::cerr << e.what() << "\n" << kUsage;
    return 2;
  } catch (const PipelineStopped& e) {
    std::cerr << "full_pipeline: stopped: " << e.what() << "\n";
    return 3;
  } catch (const std::exception& e) {
    std::cerr << "full_pipeline: error: " << cli::describe(e) << "\n";
    return 1;
  }
}

#pragma once
// Stage 2, g0: the deformable reconstruction of the source frames at their
// estimated cameras, its MedianGS bake and R0, the bake rendered along the
// canonical orbit -> g0/frames.json (its training set), g0/checkpoint.bin,
// gmed0.ply, R0/NNNN.png.
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/io/ply.hpp"
#include "orbitforge/pipeline/reconstruction.hpp"
#include "orbitforge/pipeline/run_state.hpp"

namespace orbitforge {

// The source frames G0 trains on (those the orbit fit used, minus the withheld),
// in frame order, each with its own time code (PipelineInput::time_code).
template <class Scalar>
std::vector<TrainFrame<Scalar>> g0_frames(const PipelineRun<Scalar>& run) {
  const auto& in = *run.input;
  std::vector<TrainFrame<Scalar>> frames;
  for (int t = 0; t < int(run.fit.source.size()); ++t) {
    const int idx = run.input_index_of_source(t);
    if (in.is_withheld(idx)) continue;
    TrainFrame<Scalar> f;
    f.image = in.images[std::size_t(idx)];
    f.camera = in.cameras[std::size_t(idx)].camera;
    f.time = Scalar(in.time_code(idx));
    f.name = in.cameras[std::size_t(idx)].name;
    frames.push_back(std::move(f));
  }
  ensure(!frames.empty(), "pipeline: every source frame is withheld; nothing to train G0 on");
  return frames;
}

template <class Scalar>
void stage_g0(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  using namespace pipeline_detail;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const nlohmann::json settings = {{"train", train_settings<Scalar>(run.train_params(p.iters_g0, p.deformable), p)},
                                   {"render_stride", p.render_stride},
                                   {"threads", p.threads}};
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("orbit"))));
  run.keys["g0"] = key;
  std::vector<std::string> outputs = {"g0/frames.json", "g0/checkpoint.bin", "g0/training.json", "gmed0.ply"};
  for (const auto& f : orbit_view_files(run, "R0")) outputs.push_back(f);
  if (run.stage_current("g0", key, outputs)) return;
  const std::vector<TrainFrame<Scalar>> frames = g0_frames(run);
  fs::create_directories(fs::path(run.out) / "g0");
  write_frame_list((fs::path(run.out) / "g0" / "frames.json").string(), frames);
  const GaussianScene<Scalar> gmed0 = reconstruct_and_bake(run, frames, initial_scene(run, frames),
                                                           run.train_params(p.iters_g0, p.deformable),
                                                           (fs::path(run.out) / "g0").string(), key, "G0");
  run.write_scene((fs::path(run.out) / "gmed0.ply").string(), gmed0);
  render_orbit_views(run, gmed0, "R0", "R0");
  finish_stage(run, "g0", key, t0, settings, outputs);
}

}  // namespace orbitforge

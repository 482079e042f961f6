#pragma once
// The whole method over an output folder, as resumable stages (each in
// pipeline/stages/):
//
//   orbit         fit the canonical orbit, bins, layout          -> orbit.json
//   g0            deformable reconstruction of the source frames,
//                 MedianGS bake, R0 on the canonical orbit       -> g0/checkpoint.bin, gmed0.ply, R0/NNNN.png
//   static_proxy  (diagnostic) G0 rendered frame-varying, fixed
//                 slice and MedianGS along the orbit, stability  -> static_proxy.json
//   completion    provider (completion.hpp) + assembly of V_hat  -> vhat.json, vhat/NNNN.png (+ the provider's folder)
//   recalibrate   (user's path) G1's cameras from COLMAP on the
//                 source frames and the completion together      -> recalibrate/cameras.json
//   g1            reconstruction of V_hat with its cameras (from
//                 Gmed0 by default), bake, R1                    -> g1/checkpoint.bin, final.ply, R1/NNNN.png
//   g1_paper      (comparison, on request) G1 on the paper's V_hat   -> g1_paper/
//   bound         (comparison, on request) the oracle bound          -> bound/
//   report        coverage, quality, completion metrics          -> report.json, report.md, contact_sheet.png,
//                                                                   support_mask.png, top_view.png
//
// Resuming: each stage's key hashes its inputs (the previous stage's key, or the
// input data) and its settings; stages/<name>.json records the key, the wall
// time and the size and content hash of every output once all are written (each
// atomically; stage_record.hpp). A stage is skipped only when its record matches
// and every output is unchanged; otherwise it runs again and the log says why.
// Later stages read earlier outputs from disk (R0 PNGs, gmed0.ply, V_hat PNGs),
// so a resumed run computes what an uninterrupted one does. Training checkpoints
// its state every checkpoint_every iterations and when it ends
// (reconstruction.hpp), so an interrupted stage continues where it stopped.
//
// The external provider stops the run (PipelineStopped) until its completed
// frames exist; the stages before it stay done.
#include <cstdio>
#include <filesystem>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <type_traits>

#include "orbitforge/core/error.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"
#include "orbitforge/pipeline/completion/providers.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"
#include "orbitforge/pipeline/params.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/stages/completion.hpp"
#include "orbitforge/pipeline/stages/g0.hpp"
#include "orbitforge/pipeline/stages/g1.hpp"
#include "orbitforge/pipeline/stages/orbit.hpp"
#include "orbitforge/pipeline/stages/recalibrate.hpp"
#include "orbitforge/pipeline/stages/report.hpp"
#include "orbitforge/pipeline/stages/static_proxy.hpp"

namespace orbitforge {


// Runs (or resumes) every stage; returns report.json's content. `provider`
// overrides params.completion (for a user's own provider). Throws PipelineStopped
// when the completion is not ready, Error on bad input; earlier outputs stay.
template <class Scalar>
nlohmann::json run_pipeline(const PipelineInput<Scalar>& input, const PipelineParams& params, const std::string& out,
                            CompletionProvider<std::common_type_t<Scalar>>* provider = nullptr,
                            PipelineRun<std::common_type_t<Scalar>>* state = nullptr) {
  ensure(!out.empty(), "pipeline: no output folder");
  ensure(params.render_stride >= 1, "pipeline: render_stride must be >= 1, got ", params.render_stride);
  ensure(params.iters_g0 >= 1 && params.iters_g1 >= 1, "pipeline: iteration counts must be positive");
  check_train_owners(params, input.background, input.random_background);
  std::filesystem::create_directories(out);
  PipelineRun<Scalar> local;
  PipelineRun<Scalar>& run = state ? *state : local;
  run.out = out;
  run.params = params;
  run.input = &input;
  std::unique_ptr<CompletionProvider<Scalar>> owned;
  if (!provider) {
    owned = make_completion_provider<Scalar>(params.completion, params.perturb);
    provider = owned.get();
  }
  auto timed = [&](const char* name, auto&& f) {
    const std::size_t skipped = run.skipped.size();
    if (params.progress) run.log(std::string("== stage ") + name);
    f();
    if (params.progress && run.skipped.size() > skipped) run.log(std::string("   ") + name + ": outputs verified, skipped");
  };
  nlohmann::json report;
  timed("orbit", [&] { stage_orbit(run); });
  timed("g0", [&] { stage_g0(run); });
  timed("static_proxy", [&] { stage_static_proxy(run); });
  timed("completion", [&] { stage_completion(run, *provider); });
  timed("recalibrate", [&] { stage_recalibrate(run); });
  timed("g1", [&] { stage_g1(run); });
  if (params.compare_g1_paper) timed("g1_paper", [&] { stage_g1_paper(run); });
  if (params.oracle_bound) timed("bound", [&] { stage_bound(run); });
  timed("report", [&] { report = stage_report(run); });
  return report;
}

}  // namespace orbitforge

#pragma once
// G0's static-proxy diagnostics (a diagnostic stage after g0) -> static_proxy.json.
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/stages/g0.hpp"

namespace orbitforge {

// The paper's static-proxy comparison (its Table "Static-proxy diagnostics"):
// G0's deformable checkpoint rendered along the canonical orbit as
//   frame_varying  the deformation at t = v / (views - 1) for view v,
//   fixed_slice    the deformation at t = 0.5,
//   median         MedianGS (gmed0.ply),
// each scored by SequenceStability over the rendered views 0 .. views - 2 (the
// last view repeats view 0): adjacent-frame L1 (0-255), its P95, and the loop L1
// across the orbit's start. Frames are rendered in memory (not quantised to 8
// bits) and not kept. Writes static_proxy.json; a diagnostic only, no later stage
// reads it except the report.
template <class Scalar>
void stage_static_proxy(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  using namespace pipeline_detail;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  const nlohmann::json settings = {{"render_stride", p.render_stride}, {"fixed_slice_t", 0.5}, {"version", 1}};
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("g0"))));
  run.keys["static_proxy"] = key;
  if (!p.deformable || !p.static_proxy_diagnostics) return;
  const std::vector<std::string> outputs = {"static_proxy.json"};
  if (run.stage_current("static_proxy", key, outputs)) return;
  const GaussianScene<Scalar> gmed0 = run.read_scene((out / "gmed0.ply").string());
  const std::vector<TrainFrame<Scalar>> frames = g0_frames(run);
  Trainer<Scalar> trainer(frames, gmed0, run.train_params(p.iters_g0, p.deformable));
  trainer.load_checkpoint((out / "g0" / "checkpoint.bin").string());
  nlohmann::json j = {{"views_scored", 0}, {"variants", nlohmann::json::object()}};
  if (!trainer.field() || !trainer.deforming_at(trainer.iteration())) {
    j["note"] = trainer.field_baked()
                    ? "G0's field moved the scene too little and was baked in: the three variants coincide"
                    : "G0 never deformed (training ended within the warm-up): the three variants coincide";
  } else {
    std::vector<int> views = rendered_views(run.fit.views, p.render_stride);
    if (views.size() > 2 && views.back() == run.fit.views - 1) views.pop_back();
    FieldDeformation<Scalar> d(*trainer.field(), p.threads);
    MedianBakeParams mp;
    mp.threads = p.threads;
    const GaussianScene<Scalar> fixed = bake_fixed_slice(trainer.scene(), d, mp);
    Renderer<Scalar> r = run.renderer();
    SequenceStabilityMeter<Scalar> m_vary, m_fixed, m_median;
    for (std::size_t i = 0; i < views.size(); ++i) {
      const int v = views[i];
      const auto& cam = run.fit.cameras[std::size_t(v)];
      const Scalar t = Scalar(double(v) / double(run.fit.views - 1));
      m_vary.add(r.render(SceneView<Scalar>(bake_time_slice(trainer.scene(), d, t, mp)), cam).color);
      m_fixed.add(r.render(SceneView<Scalar>(fixed), cam).color);
      m_median.add(r.render(SceneView<Scalar>(gmed0), cam).color);
      run.progress("static", int(i + 1), int(views.size()));
    }
    auto row = [](const SequenceStability& s) {
      return nlohmann::json{{"adjacent_l1", s.adjacent_l1}, {"adjacent_l1_p95", s.adjacent_l1_p95},
                            {"loop_l1", s.loop_l1}};
    };
    j["views_scored"] = views.size();
    j["variants"] = {{"frame_varying", row(m_vary.result())},
                     {"fixed_slice", row(m_fixed.result())},
                     {"median", row(m_median.result())}};
  }
  write_file_atomic((out / "static_proxy.json").string(), j.dump(1) + "\n");
  finish_stage(run, "static_proxy", key, t0, settings, outputs);
}

}  // namespace orbitforge

#pragma once
// Stage 1, orbit: the canonical orbit fitted to the source cameras, its support
// bins and the completion layout -> orbit.json. The cameras are checked against
// the orbit the method assumes (geometry/orbit_check.hpp): a warning names the
// frames and goes to the log and to orbit.json's "check", from where the
// report takes it. Everything after the fit leans on it.
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/geometry/orbit_check.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/pipeline/completion/prompt.hpp"
#include "orbitforge/pipeline/inputs/input_json.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/pipeline/run_state.hpp"

namespace orbitforge {

template <class Scalar>
void stage_orbit(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& in = *run.input;
  const auto& p = run.params;
  ensure(in.cameras.size() == in.images.size(), "pipeline: ", in.cameras.size(), " cameras but ", in.images.size(),
         " images");
  ensure(in.source.size() >= 3, "pipeline: need at least 3 source frames, got ", in.source.size());
  run.source_cameras.clear();
  for (int s : in.source) {
    ensure(s >= 0 && s < int(in.cameras.size()), "pipeline: source frame index ", s, " outside the input");
    run.source_cameras.push_back(in.cameras[std::size_t(s)]);
  }
  OrbitParams op = p.orbit;
  op.width = p.canonical_width > 0 ? p.canonical_width : in.width;
  op.height = p.canonical_height > 0 ? p.canonical_height : in.height;
  run.fit = fit_orbit(run.source_cameras, op);
  ensure(double(run.fit.diagnostics.source_span_deg) >= p.min_source_arc_deg, "pipeline: the source cameras span ",
         run.fit.diagnostics.source_span_deg, " degrees of arc, under the minimum of ", p.min_source_arc_deg,
         " (the orbit cannot be fitted reliably)");
  for (std::size_t t = 0; t < run.fit.source.size(); ++t) {
    const int idx = run.input_index_of_source(int(t));
    ensure(!in.images[std::size_t(idx)].empty(), "pipeline: source frame ", in.cameras[std::size_t(idx)].name,
           " has no image");
  }
  const OrbitCheck check = check_orbit(run.source_cameras, run.fit);
  for (const auto& w : check.warnings) run.log("orbit: warning: the cameras are not an orbit: " + w);
  std::vector<std::string> names;
  for (const auto& s : run.fit.source) names.push_back(s.name);
  run.layout = endpoint_window_layout(run.fit.support, names, p.layout);
  run.prompt = make_prompt(p.prompt.empty() ? std::string("an object on a table") : p.prompt);

  const nlohmann::json settings = {{"views", op.views},
                                   {"width", op.width},
                                   {"height", op.height},
                                   {"elevation_offset_deg", op.elevation_offset_deg},
                                   {"circle_fit", int(op.circle_fit)},
                                   {"center", orbit_center_name(op.center)},
                                   {"anchor_stride", p.layout.anchor_stride},
                                   {"placement", anchor_placement_name(p.layout.placement)},
                                   {"orbit_check", 1}};
  const std::string key = hex64(fnv1a(settings.dump(), input_hash(in)));
  run.keys["orbit"] = key;
  const std::vector<std::string> outputs = {"orbit.json"};
  if (run.stage_current("orbit", key, outputs)) return;
  nlohmann::json oj = orbit_json(run.fit, run.layout, in.frame);
  oj["source_frames"] = source_frames_json(in);
  oj["check"] = orbit_check_json(check);
  write_file_atomic((fs::path(run.out) / "orbit.json").string(), oj.dump(1) + "\n");
  finish_stage(run, "orbit", key, t0, settings, outputs);
}

}  // namespace orbitforge

#pragma once
// What a reconstruction's levers decided (the still-scene check and the plateau
// stop, TrainParams) and where its time went, as JSON: reconstruction.hpp writes it to
// <stage>/training.json, report.json lists it under "training", and reconstruct
// puts the still check in its metrics.
#include <algorithm>

#include <nlohmann/json.hpp>

#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/train/still_check.hpp"
#include "orbitforge/train/train_params.hpp"
#include "orbitforge/train/train_progress.hpp"

namespace orbitforge {

// The still check's figures, its thresholds and its decision ("baked": the field
// was baked in and training went on static; "kept"); holdout_every: the rule of
// the frames it compared on (TrainParams::still_holdout_every).
inline nlohmann::json still_check_json(const ShortcutState& sc, const TrainParams& p, int iteration) {
  return {{"iteration", iteration},
          {"holdout_every", p.still_holdout_every},
          {"gain_db", sc.field_gain_db},
          {"region_gain_db", sc.field_region_gain_db},
          {"region", {sc.field_region / kStillRegions, sc.field_region % kStillRegions}},
          {"regions", {kStillRegions, kStillRegions}},
          {"region_rank", kStillRegionRank},
          {"region_floor", kStillRegionFloor},
          {"thresholds_db", {{"gain", p.still_gain_db}, {"region_gain", p.still_region_gain_db}}},
          {"decision", sc.field_baked ? "baked" : "kept"}};
}

// Where the training iterations' wall time went, summed over the iterations
// trained in this sitting (a resumed run counts only its own).
struct TrainingTimes {
  int iterations = 0;
  double wall_ms = 0, field_ms = 0, loss_ms = 0, adam_ms = 0, densify_ms = 0;
  double project_ms = 0, sort_bin_ms = 0, raster_ms = 0, raster_backward_ms = 0, project_backward_ms = 0;
  double render_ms = 0, backward_ms = 0;  // the renderer's whole passes, which the stages above are part of
  double gaussians = 0, tile_entries = 0, pairs_evaluated = 0, contributions = 0;  // summed over the iterations

  void add(const TrainProgress& pr) {
    ++iterations;
    wall_ms += 1e3 * pr.seconds_per_iteration;
    field_ms += pr.field_ms, loss_ms += pr.loss_ms, adam_ms += pr.adam_ms, densify_ms += pr.densify_ms;
    render_ms += pr.render_ms, backward_ms += pr.backward_ms;
    project_ms += pr.render.project_ms, sort_bin_ms += pr.render.sort_ms + pr.render.bin_ms;
    raster_ms += pr.render.raster_ms;
    raster_backward_ms += pr.render.backward_raster_ms, project_backward_ms += pr.render.backward_project_ms;
    gaussians += double(pr.gaussians), tile_entries += double(pr.render.tile_entries);
    pairs_evaluated += double(pr.render.pairs_evaluated), contributions += double(pr.render.contributions);
  }

  // Seconds per phase; "other" is what no phase timed (the frame's preparation,
  // the schedules, the still check's bake).
  nlohmann::json to_json() const {
    const double timed = render_ms + loss_ms + backward_ms + field_ms + adam_ms + densify_ms;
    return {{"iterations", iterations},
            {"wall", 1e-3 * wall_ms},
            {"projection", 1e-3 * project_ms},
            {"sort_and_binning", 1e-3 * sort_bin_ms},
            {"rasterization", 1e-3 * raster_ms},
            {"loss", 1e-3 * loss_ms},
            {"rasterization_backward", 1e-3 * raster_backward_ms},
            {"projection_backward", 1e-3 * project_backward_ms},
            {"deformation_field", 1e-3 * field_ms},
            {"adam", 1e-3 * adam_ms},
            {"densification", 1e-3 * densify_ms},
            {"other", 1e-3 * std::max(0.0, wall_ms - timed)},
            // Per iteration on average, so that the times above read per unit of work.
            {"mean_gaussians", gaussians / iterations},
            {"mean_tile_entries", tile_entries / iterations},
            {"mean_pairs_evaluated", pairs_evaluated / iterations},
            {"mean_contributions", contributions / iterations}};
  }
};

// A finished run: iterations done of the budget, the still check (null when it
// was off or training ended before it), whether the plateau stop ended it, and
// where this sitting's training time went ("timing", null when it trained nothing).
inline nlohmann::json training_json(const ShortcutState& sc, const TrainParams& p, int check_iteration,
                                    int iterations_done, const TrainingTimes& times = {}) {
  return {{"iterations", iterations_done},
          {"budget", p.iterations},
          {"still_check", sc.still_checked ? still_check_json(sc, p, check_iteration) : nlohmann::json()},
          {"plateau_stopped", sc.stopped},
          {"timing", times.iterations > 0 ? times.to_json() : nlohmann::json()}};
}

}  // namespace orbitforge

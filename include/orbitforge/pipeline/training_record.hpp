#pragma once
// What a reconstruction's levers decided (the still-scene check and the plateau
// stop, TrainParams), as JSON: reconstruction.hpp writes it to
// <stage>/training.json, report.json lists it under "training", and reconstruct
// puts the still check in its metrics.
#include <nlohmann/json.hpp>

#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/train/still_check.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// The still check's figures, its thresholds and its decision ("baked": the field
// was baked in and training went on static; "kept").
inline nlohmann::json still_check_json(const ShortcutState& sc, const TrainParams& p, int iteration) {
  return {{"iteration", iteration},
          {"gain_db", sc.field_gain_db},
          {"region_gain_db", sc.field_region_gain_db},
          {"region", {sc.field_region / kStillRegions, sc.field_region % kStillRegions}},
          {"regions", {kStillRegions, kStillRegions}},
          {"region_rank", kStillRegionRank},
          {"thresholds_db", {{"gain", p.still_gain_db}, {"region_gain", p.still_region_gain_db}}},
          {"decision", sc.field_baked ? "baked" : "kept"}};
}

// A finished run: iterations done of the budget, the still check (null when it
// was off or training ended before it) and whether the plateau stop ended it.
inline nlohmann::json training_json(const ShortcutState& sc, const TrainParams& p, int check_iteration,
                                    int iterations_done) {
  return {{"iterations", iterations_done},
          {"budget", p.iterations},
          {"still_check", sc.still_checked ? still_check_json(sc, p, check_iteration) : nlohmann::json()},
          {"plateau_stopped", sc.stopped}};
}

}  // namespace orbitforge

#pragma once
// The plateau stop (TrainParams::plateau_window, plateau_tolerance): the mean loss
// over windows of whole passes over the frames (at least plateau_window
// iterations, so every frame weighs the same in each window) against the previous
// window's; training ends when it improved by less than the tolerance (relative).
// A window counts once nothing but the optimizer changed the model during it.
#include <algorithm>
#include <cmath>
#include <cstddef>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/train/coarse_to_fine.hpp"
#include "orbitforge/train/schedules.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

inline void check_plateau_params(const TrainParams& p) {
  ensure(p.plateau_window >= 0 && std::isfinite(p.plateau_tolerance),
         "Trainer: plateau_window must be >= 0 and plateau_tolerance finite");
}

// The first iteration after the last change to the model's structure:
// densification and opacity resets, the deformation warm-up and the still-scene
// check at `still_check_iteration` (0: none), the coarse-to-fine span.
inline int plateau_quiet_from(const TrainParams& p, const TrainSchedule& s, int still_check_iteration) {
  int quiet_from = 0;
  if (p.densify) quiet_from = std::max(quiet_from, s.densify.densify_until);
  if (p.deformable) quiet_from = std::max(quiet_from, std::max(s.warmup, still_check_iteration) + 1);
  if (p.coarse_levels > 0) quiet_from = std::max(quiet_from, coarse_span_end(p));
  return quiet_from;
}

struct PlateauStop {
  int window = 0;      // iterations per window, whole passes; 0 = off
  int quiet_from = 0;  // windows starting before this iteration do not count
  double tolerance = 0;
  int budget = 0;      // stopping at the budget's last iteration is no stop

  // `pass_length`: draws per pass over the frames (FrameOrder).
  static PlateauStop make(const TrainParams& p, std::size_t pass_length, int quiet_from) {
    PlateauStop s;
    if (p.plateau_window <= 0) return s;
    const int pass = int(pass_length);
    s.window = std::max(1, (p.plateau_window + pass - 1) / pass) * pass;
    s.quiet_from = quiet_from;
    s.tolerance = p.plateau_tolerance;
    s.budget = p.iterations;
    return s;
  }

  // Adds iteration `it`'s loss; at a window's end, records its mean in `s` and
  // sets s.stopped when it improved on the previous window's by less than the
  // tolerance (a negative tolerance only records the means).
  void track(int it, double loss, ShortcutState& s) const {
    if (window <= 0) return;
    s.plateau_sum += loss;
    if (it % window != 0) return;
    const double mean = s.plateau_sum / window;
    s.plateau_sum = 0;
    if (it - window + 1 < quiet_from) {
      s.plateau_previous = s.plateau_last = 0;
      return;
    }
    s.plateau_previous = s.plateau_last;
    s.plateau_last = mean;
    if (s.plateau_previous > 0 && s.plateau_previous - mean < tolerance * s.plateau_previous)
      s.stopped = it < budget;
  }
};

}  // namespace orbitforge

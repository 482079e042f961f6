#pragma once
// What changes with the iteration number alone: the schedules of a budget
// (SH degree interval, deformation warm-up, densification; TrainSchedule), the
// learning-rate decays, the SH degree raise and the time-code noise's annealing.
// Iterations are 1-based, as in 3DGS train.py.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <random>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// Schedules resolved for a budget: the published ones (given for
// reference_budget / deform_reference_budget iterations) scaled to p.iterations.
struct TrainSchedule {
  int sh_interval = 1000;
  int warmup = 3000;
  DensifySchedule densify;

  // `pass_length`: draws per pass over the training frames (0: unknown, no
  // floors in passes).
  static TrainSchedule make(const TrainParams& p, std::size_t pass_length = 0) {
    ensure(p.iterations > 0, "TrainParams: iterations must be positive, got ", p.iterations);
    ensure(p.reference_budget > 0 && p.deform_reference_budget > 0, "TrainParams: reference budgets must be positive");
    ensure(p.max_sh_degree >= 0 && p.max_sh_degree <= 3, "Trainer: max_sh_degree must be 0..3, got ", p.max_sh_degree);
    ensure(p.sh_rest_divisor > 0, "Trainer: sh_rest_divisor must be positive");
    ensure(p.near_plane_fraction > 0, "Trainer: near_plane_fraction must be positive, got ", p.near_plane_fraction);
    TrainSchedule s;
    const double f = double(p.iterations) / double(p.reference_budget);
    s.sh_interval = std::max(1, int(std::lround(p.sh_degree_interval * f)));
    s.warmup = int(std::lround(double(p.warmup_iterations) * double(p.iterations) / double(p.deform_reference_budget)));
    s.densify = schedule_floors_for_frames(
        scale_schedule(p.iterations, p.densify_schedule, p.reference_budget, p.min_densify_interval), pass_length,
        p.densify_interval_passes, p.opacity_reset_passes);
    return s;
  }

  // The SH degree goes up by one at multiples of sh_interval (up to max_sh_degree).
  bool raises_sh_degree_at(int it) const { return it % sh_interval == 0; }
};

// The positions' learning rate: exponential decay from position_lr_init to
// position_lr_final over position_lr_steps (0 = the budget), both times the
// scene extent (3DGS spatial_lr_scale).
inline ExponentialLr position_lr(const TrainParams& p, double extent) {
  ExponentialLr lr;
  lr.lr_init = p.position_lr_init * extent;
  lr.lr_final = p.position_lr_final * extent;
  lr.max_steps = p.position_lr_steps > 0 ? p.position_lr_steps : p.iterations;
  return lr;
}

// The deformation network's learning rate: deform_lr_init to deform_lr_final over
// deform_lr_steps (0 = the budget), not scaled by the extent.
inline ExponentialLr deformation_lr(const TrainParams& p) {
  ExponentialLr lr;
  lr.lr_init = p.deform_lr_init;
  lr.lr_final = p.deform_lr_final;
  lr.max_steps = p.deform_lr_steps > 0 ? p.deform_lr_steps : p.iterations;
  return lr;
}

// Adds the next band of SH coefficients (zero-initialised), as 3DGS's oneupSHdegree
// (3DGS keeps all coefficients from the start; inactive ones get zero gradient and
// stay zero, so this is the same).
template <class Scalar>
void raise_sh_degree(GaussianScene<Scalar>& scene) {
  const std::size_t n = scene.size();
  const int k_old = scene.sh_coefficients();
  const int k_new = sh_coefficient_count(scene.sh_degree + 1);
  std::vector<Scalar> sh(n * std::size_t(k_new) * 3, Scalar(0));
  for (std::size_t i = 0; i < n; ++i)
    std::copy_n(&scene.sh[i * std::size_t(k_old) * 3], k_old * 3, &sh[i * std::size_t(k_new) * 3]);
  scene.sh.swap(sh);
  scene.sh_degree += 1;
}

// The noise on the time code of deforming iteration `it` (TrainParams::time_noise):
// n * time_noise * max(0, 1 - it / time_noise_steps) / remaining, n ~ N(0, 1) drawn
// from `rng`, `remaining` = draws left in the current pass over the frames, this
// one included. Draws nothing when time_noise is off.
template <class Scalar, class Rng>
Scalar time_noise_at(const TrainParams& p, int it, std::size_t remaining, Rng& rng) {
  if (!(p.time_noise > 0)) return Scalar(0);
  const double anneal = std::max(0.0, 1.0 - double(it) / double(std::max(1, p.time_noise_steps)));
  std::normal_distribution<double> n(0.0, 1.0);
  return Scalar(n(rng) * p.time_noise * anneal / double(remaining));
}

}  // namespace orbitforge

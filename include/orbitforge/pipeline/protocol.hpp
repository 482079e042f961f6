#pragma once
// Named settings of the whole method. `measured` is the library's default: each
// departure from the paper there was chosen by a measurement (docs/audit.md,
// README "The paper's protocol"). `paper` runs the method as published:
//
//   orbit centre          the linear least-squares (Kasa) circle in the SVD plane
//                         (not the look-at point, nor the geometric circle fit)
//   G0 frames             at the source frames' own resolution (the loader's job:
//                         see protocol_loads_native_size)
//   canonical views       896 x 512, focal = median source focal scaled by
//                         512 / source height (a square source gives a wider view)
//   reconstructions       the DeformableGS backend's defaults unscaled, 10,000
//                         iterations each: warm-up 3,000; densify from 500 until
//                         15,000 every 100 (gradient 2e-4, percent dense 0.01);
//                         opacity reset every 3,000; SH degree + 1 every 1,000;
//                         learning rates position 1.6e-4 -> 1.6e-6 (x extent) over
//                         30,000 steps, features 2.5e-3, opacity 0.05, scaling 1e-3,
//                         rotation 1e-3, network 8e-4 -> 1.6e-6 over 40,000 steps;
//                         0.8 L1 + 0.2 D-SSIM
//   deformation network   8 x 256, input skip after layer 4, 10 frequencies for x and
//                         t, PyTorch's default head init, additive scale offsets,
//                         world units; annealed time noise 0.1 / frames over 20,000
//   G1                    deformable, on V_hat (R0 on the supported arc, the
//                         completion on the gap), initialised like G0, at the
//                         cameras the source frames gave (no recalibrate stage)
//   MedianGS              T_m = 128
//   completion request    sparse stride-24 source anchors only, with the paper's
//                         negative prompt
#include <string>

#include "orbitforge/core/error.hpp"
#include "orbitforge/pipeline/params.hpp"

namespace orbitforge {

enum class Protocol { measured, paper };

inline const char* protocol_name(Protocol p) { return p == Protocol::paper ? "paper" : "measured"; }

inline Protocol parse_protocol(const std::string& s) {
  if (s == "measured" || s == "default") return Protocol::measured;
  if (s == "paper") return Protocol::paper;
  fail("protocol '", s, "': expected paper or measured");
}

// The completion negative prompt the paper describes (its implementation details).
inline const char* paper_negative_prompt() {
  return "blur, flicker, warping, geometry distortion, unstable camera, texture repainting, deformation, "
         "inconsistent perspective";
}

// The DeformableGS backend's training settings, unscaled, for `iterations`.
inline TrainParams paper_train_params(int iterations = 10000) {
  TrainParams t;
  t.iterations = iterations;
  t.reference_budget = iterations;         // the schedule is not scaled to the budget
  t.deform_reference_budget = iterations;  // warm-up 3,000 as published
  t.min_densify_interval = 1;
  t.densify_interval_passes = t.opacity_reset_passes = 0;
  t.position_lr_init = 1.6e-4;
  t.position_lr_final = 1.6e-6;
  t.position_lr_steps = 30000;
  t.feature_lr = 2.5e-3;
  t.opacity_lr = 0.05;
  t.scaling_lr = 1e-3;
  t.rotation_lr = 1e-3;
  t.max_sh_degree = 3;
  t.sh_degree_interval = 1000;
  t.lambda_dssim = 0.2;
  t.densify_schedule = DensifySchedule{};  // from 500 until 15,000 every 100, reset every 3,000
  t.densify_params = DensifyParams{};      // gradient 2e-4, percent dense 0.01, no Gaussian budget
  t.densify_params.max_screen_fraction = 0;  // 3DGS's 20-pixel screen-size limit, whatever the background
  t.warmup_iterations = 3000;
  t.deform_lr_init = 8e-4;
  t.deform_lr_final = 1.6e-6;
  t.deform_lr_steps = 40000;
  t.field = DeformationFieldParams::original();
  t.field.t_frequencies = 10;  // the backend's setting for real (non-Blender) scenes
  t.field.head_init_scale = 1.0;
  t.normalize_field = false;
  t.time_noise = 0.1;
  t.time_noise_steps = 20000;
  return t;
}

// Whether G0's frames are used at their own resolution under `p` (else the
// caller's working size).
inline bool protocol_loads_native_size(Protocol p) { return p == Protocol::paper; }

// Sets every pipeline setting `protocol` fixes; the others keep their values.
inline void apply_protocol(PipelineParams& p, Protocol protocol) {
  if (protocol == Protocol::measured) return;
  p.orbit.center = OrbitCenter::circle;
  p.orbit.circle_fit = CircleFitMethod::kasa;  // the paper's linear least squares
  p.orbit.views = 361;
  p.orbit.elevation_offset_deg = 10.0;
  p.canonical_width = 896;
  p.canonical_height = 512;
  p.iters_g0 = p.iters_g1 = 10000;
  p.deformable = true;
  p.g1_deformable = true;
  p.g1_data = G1Data::paper;
  p.g1_from_gmed0 = false;
  p.recalibrate.enabled = false;  // G1 at the cameras the source frames gave
  p.median_samples = 128;
  p.min_densify_interval = 1;
  p.layout.anchor_stride = 24;
  p.request_conditioning = false;
  p.negative_prompt = paper_negative_prompt();
  const int threads = p.train.threads;
  p.train = paper_train_params(10000);
  p.train.threads = threads;
  // The budgets and the interval floor are the fields above's (iters_g0 / iters_g1,
  // min_densify_interval; check_train_owners): the training settings leave them unset.
  p.train.iterations = TrainParams{}.iterations;
  p.train.min_densify_interval = TrainParams{}.min_densify_interval;
}

}  // namespace orbitforge

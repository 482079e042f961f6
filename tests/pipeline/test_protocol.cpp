// The `paper` protocol preset against the published values, each cited:
//   [paper X]   the OrbitForge paper, section or appendix X;
//   [backend F] the DeformableGS backend (Deformable 3D Gaussians' public code), file F.
// The values are written here independently of pipeline/protocol.hpp, so a
// changed preset fails this test.
#include <catch2/catch.hpp>

#include <string>

#include "orbitforge/pipeline/protocol.hpp"

using namespace orbitforge;

TEST_CASE("protocol paper: every setting as published", "[pipeline][protocol]") {
  PipelineParams p;
  apply_protocol(p, Protocol::paper);
  const TrainParams& t = p.train;

  // [paper App. "Orbit Plane and Circle Fitting"]: c_orb = o_bar + a e1 + b e2 from the
  // linear least-squares circle 2au + 2bv + gamma = u^2 + v^2 (Eq. circle-fit).
  CHECK(p.orbit.center == OrbitCenter::circle);
  CHECK(p.orbit.circle_fit == CircleFitMethod::kasa);
  // [paper App. "Camera Estimation and Canonical-Orbit Constants"]: N = 361, 896 x 512, 10 degrees.
  CHECK(p.orbit.views == 361);
  CHECK(p.canonical_width == 896);
  CHECK(p.canonical_height == 512);
  CHECK(p.orbit.elevation_offset_deg == 10.0);
  // [paper App. "Gaussian Splatting Reconstruction Settings"]: the same DeformableGS backend,
  // 10,000 iterations for each reconstruction.
  CHECK(p.iters_g0 == 10000);
  CHECK(p.iters_g1 == 10000);
  CHECK(p.deformable);
  CHECK(p.g1_deformable);
  // [paper Sec. "Second Reconstruction and Output"]: G1 = recon(V_hat, canonical orbit).
  CHECK(p.g1_data == G1Data::paper);
  // [paper App. "MedianGS Staticization Settings"]: T_m = 128.
  CHECK(p.median_samples == 128);
  // [paper App. "Coverage-Completion Settings"]: sparse source anchors at stride 24.
  CHECK(p.layout.anchor_stride == 24);
  CHECK_FALSE(p.request_conditioning);
  // [paper App. "Generative Backbones and Sampling"]: a negative prompt against blur, flicker,
  // warping, geometry distortion, unstable cameras, texture repainting, deformation, perspective.
  for (const char* w : {"blur", "flicker", "warping", "geometry distortion", "unstable camera", "texture repainting",
                        "deformation", "inconsistent perspective"})
    CHECK_THAT(p.negative_prompt, Catch::Contains(w));

  // [backend arguments/__init__.py OptimizationParams]
  // (The budget is iters_g0 / iters_g1's, checked above; params.train leaves it unset.)
  CHECK(t.iterations == TrainParams{}.iterations);
  CHECK(t.warmup_iterations == 3000);
  CHECK(t.position_lr_init == 0.00016);
  CHECK(t.position_lr_final == 0.0000016);
  CHECK(t.position_lr_steps == 30000);
  CHECK(t.feature_lr == 0.0025);
  CHECK(t.opacity_lr == 0.05);
  CHECK(t.scaling_lr == 0.001);
  CHECK(t.rotation_lr == 0.001);
  CHECK(t.lambda_dssim == 0.2);
  CHECK(t.densify_params.percent_dense == 0.01);
  CHECK(t.densify_params.grad_threshold == 0.0002);
  CHECK(t.densify_params.max_gaussians == 0);
  // [backend scene/deform_model.py]: network lr = position_lr_init x 5 -> position_lr_final over 40,000 steps.
  CHECK(t.deform_lr_init == Approx(0.00016 * 5));
  CHECK(t.deform_lr_final == 0.0000016);
  CHECK(t.deform_lr_steps == 40000);
  // [backend arguments/__init__.py ModelParams]: sh_degree 3; [backend train.py]: one degree per 1,000 iterations.
  CHECK(t.max_sh_degree == 3);
  // The schedule as it runs at 10,000 iterations: not scaled to the budget.
  TrainParams g0 = t;
  g0.iterations = p.iters_g0;
  const TrainSchedule s = TrainSchedule::make(g0);
  CHECK(s.warmup == 3000);
  CHECK(s.sh_interval == 1000);
  CHECK(s.densify.densify_from == 500);
  CHECK(s.densify.densify_until == 15000);
  CHECK(s.densify.densify_interval == 100);
  CHECK(s.densify.opacity_reset_interval == 3000);
  // [backend utils/time_utils.py DeformNetwork]: D = 8, W = 256, skip at D // 2, 10 x frequencies,
  // 10 t frequencies for real scenes, PyTorch's default layer init, d_scaling added to the scale.
  CHECK(t.field.depth == 8);
  CHECK(t.field.width == 256);
  CHECK(t.field.skip_layer == 4);
  CHECK(t.field.x_frequencies == 10);
  CHECK(t.field.t_frequencies == 10);
  CHECK(t.field.head_init_scale == 1.0);
  CHECK(t.field.scale_offset == ScaleOffset::additive);
  CHECK_FALSE(t.normalize_field);
  // [backend train.py]: ast_noise = N(0, 1) x time_interval x smooth_term(iteration),
  // smooth_term linear from 0.1 to ~0 over 20,000 steps.
  CHECK(t.time_noise == 0.1);
  CHECK(t.time_noise_steps == 20000);
  // [paper App. "Gaussian Splatting Reconstruction Settings"]: every reconstruction
  // deformable for its whole budget: no still-scene check.
  CHECK(t.still_check_iterations == 0);
  // [paper Sec. "Second Reconstruction and Output"]: the completed orbit is
  // reconstructed at the canonical cameras; re-estimating cameras from the
  // completed video is argued against there.
  CHECK_FALSE(p.recalibrate.enabled);
  CHECK(p.train.coarse_levels == 0);  // the published training runs at full size throughout
  CHECK(protocol_loads_native_size(Protocol::paper));
}

TEST_CASE("protocol measured: the defaults, untouched", "[pipeline][protocol]") {
  PipelineParams a, b;
  b.iters_g0 = 123;
  apply_protocol(b, Protocol::measured);
  CHECK(b.iters_g0 == 123);
  CHECK(b.orbit.center == a.orbit.center);
  CHECK(b.train.field.depth == a.train.field.depth);
  // The method's defaults check for a still scene (docs/benchmarks.md); a bare
  // TrainParams, the library's single reconstruction, does not.
  CHECK(a.train.still_check_iterations == 500);
  CHECK(b.train.still_check_iterations == 500);
  CHECK(TrainParams{}.still_check_iterations == 0);
  // Coarse-to-fine by the budget: on at the paper's 10,000 iterations, off at 3,000.
  CHECK(b.train.coarse_levels == kCoarseLevelsByBudget);
  CHECK(TrainParams{}.coarse_levels == 0);
  // On the user's path G1's cameras are estimated again with the completion,
  // the lens held (docs/cameras.md).
  CHECK(b.recalibrate.enabled);
  CHECK(b.recalibrate.hold_focal);
  CHECK_FALSE(protocol_loads_native_size(Protocol::measured));
  CHECK(parse_protocol("paper") == Protocol::paper);
  CHECK_THROWS_WITH(parse_protocol("papers"), Catch::Contains("expected paper or measured"));
}

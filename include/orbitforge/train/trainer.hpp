#pragma once
// Gaussian Splatting training on the CPU, static (3DGS, Kerbl et al. 2023) and
// deformable (Deformable 3D Gaussians, Yang et al. 2023): frames with per-frame
// cameras and a time code t in [0, 1] -> a trained GaussianScene (+ a
// DeformationField).
//
//   std::vector<TrainFrame<float>> frames = ...;      // image [H][W][3] in [0, 1]
//   Trainer<float> trainer(frames, init_from_points(xyz, rgb), params);
//   trainer.train(params.iterations, [](const TrainProgress& p) { ... });
//   trainer.save_checkpoint("ckpt.bin");
//
// One iteration (1-based `it`), as 3DGS train.py does it:
//   learning rates for `it`; SH degree + 1 at multiples of sh_degree_interval;
//   next frame of a seeded shuffled order (reshuffled when used up);
//   render (deformable and it > warmup: DeformedSceneView with the field's offsets at
//   the frame's t); loss 0.8 L1 + 0.2 (1 - SSIM); backward (into the field through its
//   vjp, into the canonical Gaussians through base_gradients); Adam steps;
//   densification statistics, densify/prune (optimizer moments remapped; new
//   Gaussians start with zero moments) and opacity resets per DensifySchedule;
//   optionally the still-scene check (bakes a field that fits the frames no better
//   than its bake, then trains static) and the plateau stop (finished() before
//   the budget).
// Differences from 3DGS: the optimizer step comes before densification in the same
// iteration (3DGS densifies first and skips the step for the new tensors).
//
// Determinism: the same frames, initial scene, params and thread count give the same
// result bit for bit (renderer, loss and network are deterministic per thread count).
//
// Checkpoints (save_checkpoint / load_checkpoint) hold the iteration, scene, optimizer
// moments and steps, RNG and frame-order state, densification statistics and the
// field with its optimizer; resuming with the same frames, params and thread count
// continues exactly as an uninterrupted run. Written atomically (temp + rename);
// the file format is io/checkpoint.hpp's (checkpoint() / restore() give the
// record itself); a damaged or truncated file is refused whole.
#include <Eigen/Core>
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <functional>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/project.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/losses.hpp"

namespace orbitforge {

template <class Scalar>
struct TrainFrame {
  Image<Scalar> image;     // [H][W][3], values in [0, 1], H x W = the camera's image size
  Camera<Scalar> camera;
  Scalar time = 0;         // time code in [0, 1] (deformable training)
  std::string name;
  int repeats = 1;         // times the frame is drawn per pass over the frames (sampling weight, >= 1)
};

// Settings with the published defaults (3DGS arguments/__init__.py; Deformable 3D
// Gaussians for the deformable ones). Schedules given for `reference_budget`
// iterations are scaled to `iterations`.
struct TrainParams {
  int iterations = 30000;
  int reference_budget = 30000;     // the budget the published schedules are for
  unsigned seed = 0;
  int threads = 0;                  // 0 = all hardware threads
  std::array<double, 3> background{{0, 0, 0}};  // white {1,1,1} for the v3d videos

  // Learning rates. Positions: exponential decay from init to final over the
  // budget, both times the scene extent (3DGS spatial_lr_scale).
  double position_lr_init = 1.6e-4;
  double position_lr_final = 1.6e-6;
  int position_lr_steps = 0;        // the exponential decay reaches lr_final here (0 = the budget)
  double feature_lr = 2.5e-3;       // SH DC; higher SH coefficients use feature_lr / sh_rest_divisor
  double sh_rest_divisor = 20;
  double opacity_lr = 0.05;         // the 3DGS paper value (later 3DGS versions use 0.025)
  double scaling_lr = 5e-3;
  double rotation_lr = 1e-3;
  AdamParams adam;                  // eps 1e-15 as 3DGS

  int max_sh_degree = 3;
  int sh_degree_interval = 1000;    // per reference_budget; scaled (>= 1)
  double lambda_dssim = 0.2;

  bool densify = true;
  DensifyParams densify_params;
  DensifySchedule densify_schedule;  // published; scaled to the budget
  // Floor of the scaled densification and opacity-reset intervals. 1 keeps the
  // published schedule exactly; short budgets may want more (the pipeline uses 50:
  // scaled to 1000 iterations the schedule densifies every 3 iterations on a
  // handful of views, and the Gaussian count explodes).
  int min_densify_interval = 1;

  // Deformable training.
  bool deformable = false;
  DeformationFieldParams field = DeformationFieldParams::fast();
  // The field works in a frame normalised to the cameras' extent (see
  // deform/deformation_field.hpp); false uses world units as published.
  bool normalize_field = true;
  int warmup_iterations = 3000;      // per deform_reference_budget: no deformation before
  int deform_reference_budget = 40000;
  double deform_lr_init = 8e-4;      // position_lr_init * 5 (Deformable 3DGS), not scaled by the extent
  double deform_lr_final = 8e-6;     // decays over deform_lr_steps
  int deform_lr_steps = 0;           // 0 = the budget
  // Annealed noise on the time code (Deformable 3D Gaussians, real scenes): each
  // deforming step uses t + n * time_noise * max(0, 1 - it / time_noise_steps) / r,
  // n ~ N(0, 1), r = frames left in the current pass over the frames, this one
  // included (the backend divides by the size of its shrinking camera stack).
  // 0 = off.
  double time_noise = 0;
  int time_noise_steps = 20000;

  // Coarse-to-fine: the first coarse_fraction of the budget trains on frames
  // downsampled by 2^level (2x2 box filter per level, focal length and principal
  // point scaled by the same 2^-level), level falling linearly from
  // coarse_levels to 0 over that span; the rest at full size. 0 = off. With the
  // still-scene check on, the iterations up to the check train at full size.
  int coarse_levels = 0;
  double coarse_fraction = 0.5;

  // Work a scene does not need (off by default; docs/benchmarks.md measures each).
  // Still scene: still_check_iterations after the deformation warm-up, the field
  // is baked (MedianGS over still_bake_samples time codes) and the bake's PSNR on
  // up to 8 training frames is compared with the deformed model's; when the field
  // gains less than still_gain_db the bake replaces the scene and training goes on
  // static, a step then costing what a static one does. 0 = never checked.
  // still_gain_db: on the recorded (static) videos at the paper's budget the
  // field gained 0.00 to 0.55 dB by the check (five videos, three seeds each);
  // with the frames shifted along a 4-pixel circle, 1.6 to 3.3 dB
  // (scripts/still_check_spread.sh, docs/benchmarks.md).
  int still_check_iterations = 0;
  double still_gain_db = 1.0;
  int still_bake_samples = 32;
  // Plateau stop: once densification and the deformation warm-up are over, the mean
  // loss over windows of whole passes over the frames (at least plateau_window
  // iterations, so every frame weighs the same in each window) is compared with the
  // previous window's; training ends when it improved by less than
  // plateau_tolerance (relative; a negative tolerance only records the windows'
  // means in TrainProgress). plateau_window 0 = train the whole budget.
  int plateau_window = 0;
  double plateau_tolerance = 0.002;
};

// The image level of iteration `it` (1-based) under the coarse-to-fine schedule.
inline int coarse_level_at(const TrainParams& p, int it) {
  if (p.coarse_levels <= 0 || !(p.coarse_fraction > 0)) return 0;
  const double span = p.coarse_fraction * double(p.iterations);
  const double left = 1.0 - double(it - 1) / span;  // 1 at the start, 0 at the end of the span
  return left <= 0 ? 0 : std::min(p.coarse_levels, int(std::ceil(left * p.coarse_levels)));
}

struct TrainProgress {
  int iteration = 0, iterations = 0;
  double loss = 0, l1 = 0, ssim = 0;
  double psnr = 0;                   // of this iteration's render against its frame
  std::size_t gaussians = 0;
  int sh_degree = 0;
  bool deforming = false;            // the deformation field was applied
  int image_level = 0;               // coarse-to-fine: the frame was downsampled by 2^image_level
  double seconds_per_iteration = 0;  // wall time of this iteration
  double elapsed_seconds = 0;        // wall time of all iterations trained by this object
  std::size_t frame = 0;
  // Where this iteration's wall time went (ms). render: project + sort/bin +
  // rasterize; backward: rasterizer and projection backward; field: the
  // deformation network forward, backward and its Adam step (0 when not deforming).
  double render_ms = 0, loss_ms = 0, backward_ms = 0, field_ms = 0, adam_ms = 0, densify_ms = 0;
  RenderStats render;  // the renderer's own breakdown of this iteration's render and backward
  // The last densification step (cumulative counts since the trainer started).
  std::size_t cloned = 0, split = 0, pruned = 0;
  // The still-scene check's and the plateau stop's state after this iteration.
  ShortcutState shortcuts;
};

// Schedules resolved for a budget.
struct TrainSchedule {
  int sh_interval = 1000;
  int warmup = 3000;
  DensifySchedule densify;

  static TrainSchedule make(const TrainParams& p) {
    ensure(p.iterations > 0, "TrainParams: iterations must be positive, got ", p.iterations);
    ensure(p.reference_budget > 0 && p.deform_reference_budget > 0, "TrainParams: reference budgets must be positive");
    TrainSchedule s;
    const double f = double(p.iterations) / double(p.reference_budget);
    s.sh_interval = std::max(1, int(std::lround(p.sh_degree_interval * f)));
    s.warmup = int(std::lround(double(p.warmup_iterations) * double(p.iterations) / double(p.deform_reference_budget)));
    s.densify = scale_schedule(p.iterations, p.densify_schedule, p.reference_budget, p.min_densify_interval);
    return s;
  }
};

template <class Scalar>
class Trainer {
 public:
  using Progress = std::function<void(const TrainProgress&)>;

  // `frames` must outlive the trainer. `initial` is the starting scene (see
  // train/init.hpp); its SH degree is the starting active degree.
  Trainer(const std::vector<TrainFrame<Scalar>>& frames, GaussianScene<Scalar> initial, const TrainParams& params)
      : frames_(frames), params_(params), schedule_(TrainSchedule::make(params)), scene_(std::move(initial)),
        adam_(params.adam), field_adam_(params.adam), rng_(params.seed) {
    ensure(!frames_.empty(), "Trainer: no frames");
    resolve_threads(params.threads, "TrainParams::threads");  // over the limit: refused before anything is built
    ensure(params.max_sh_degree >= 0 && params.max_sh_degree <= 3, "Trainer: max_sh_degree must be 0..3, got ",
           params.max_sh_degree);
    ensure(params.sh_rest_divisor > 0, "Trainer: sh_rest_divisor must be positive");
    ensure(params.still_check_iterations >= 0 && std::isfinite(params.still_gain_db) && params.still_bake_samples >= 2,
           "Trainer: still_check_iterations must be >= 0, still_gain_db finite and still_bake_samples >= 2");
    ensure(params.plateau_window >= 0 && std::isfinite(params.plateau_tolerance),
           "Trainer: plateau_window must be >= 0 and plateau_tolerance finite");
    ensure(params.coarse_levels >= 0 && params.coarse_levels <= 6 && params.coarse_fraction >= 0 &&
               params.coarse_fraction <= 1,
           "Trainer: coarse_levels must be 0..6 and coarse_fraction 0..1, got ", params.coarse_levels, " and ",
           params.coarse_fraction);
    scene_.check_consistent();
    ensure(!scene_.empty(), "Trainer: the initial scene has no Gaussians");
    ensure(scene_.sh_degree <= params.max_sh_degree, "Trainer: initial scene has SH degree ", scene_.sh_degree,
           ", above max_sh_degree ", params.max_sh_degree);
    std::vector<Camera<Scalar>> cams;
    std::size_t draws = 0;
    for (std::size_t i = 0; i < frames_.size(); ++i) {
      const auto& f = frames_[i];
      ensure(f.image.channels == 3 && f.image.width == f.camera.intrinsics.width &&
                 f.image.height == f.camera.intrinsics.height && !f.image.empty(),
             "Trainer: frame ", i, " (", f.name, ") has a ", f.image.width, "x", f.image.height, "x",
             f.image.channels, " image for a ", f.camera.intrinsics.width, "x", f.camera.intrinsics.height,
             " camera (need RGB of the camera's size)");
      ensure(f.camera.is_finite(), "Trainer: frame ", i, " (", f.name, ") has a non-finite camera");
      ensure(std::isfinite(double(f.time)), "Trainer: frame ", i, " (", f.name, ") has a non-finite time code");
      ensure(f.repeats >= 1 && f.repeats <= 1000, "Trainer: frame ", i, " (", f.name, ") has repeats ", f.repeats,
             " (need 1..1000)");
      draws += std::size_t(f.repeats);
      cams.push_back(f.camera);
    }
    extent_ = frames_.size() > 1 ? camera_extent(cams) : Scalar(0);
    if (!(extent_ > Scalar(1e-6))) extent_ = Scalar(1);  // one camera (or all at one place): unit scale
    RenderParams<Scalar> rp;
    for (int c = 0; c < 3; ++c) rp.background[std::size_t(c)] = Scalar(params.background[std::size_t(c)]);
    rp.threads = params.threads;
    renderer_ = Renderer<Scalar>(rp);
    const std::size_t n = scene_.size();
    g_means_ = adam_.add_group("means", n, 3, Scalar(0));
    g_rot_ = adam_.add_group("rotations", n, 4, Scalar(params.rotation_lr));
    g_scale_ = adam_.add_group("log_scales", n, 3, Scalar(params.scaling_lr));
    g_opacity_ = adam_.add_group("opacity_logits", n, 1, Scalar(params.opacity_lr));
    g_dc_ = adam_.add_group("sh_dc", n, 3, Scalar(params.feature_lr));
    g_rest_ = adam_.add_group("sh_rest", n, rest_width(), Scalar(params.feature_lr / params.sh_rest_divisor));
    stats_.reset(n);
    if (params.deformable) {
      field_ = std::make_unique<DeformationField<Scalar>>(params.field);
      if (params.normalize_field) {
        typename Camera<Scalar>::Vec3 mean = Camera<Scalar>::Vec3::Zero();
        for (const auto& c : cams) mean += c.center();
        field_->set_frame(mean / Scalar(cams.size()), extent_ / Scalar(kFieldReferenceExtent));
      }
      g_field_ = field_adam_.add_group("deformation", field_->parameter_count(), 1, Scalar(0));
    }
    order_.resize(draws);
    cursor_ = order_.size();  // shuffle on first use
  }

  const TrainParams& params() const { return params_; }
  const TrainSchedule& schedule() const { return schedule_; }
  const GaussianScene<Scalar>& scene() const { return scene_; }
  const DeformationField<Scalar>* field() const { return field_.get(); }
  const Adam<Scalar>& optimizer() const { return adam_; }
  const DensifyStats<Scalar>& densify_stats() const { return stats_; }
  int iteration() const { return iteration_; }
  Scalar extent() const { return extent_; }
  const TrainProgress& last_progress() const { return last_; }
  // The deformation is applied at iterations > warmup (until a still-scene check
  // bakes the field in).
  bool deforming_at(int it) const { return field_ && it > schedule_.warmup; }
  // The budget is used up, or the plateau stop ended training.
  bool finished() const { return shortcuts_.stopped || iteration_ >= params_.iterations; }
  // The still-scene check baked the field into the scene; training went on static.
  bool field_baked() const { return shortcuts_.field_baked; }
  // The iteration at whose end the still-scene check runs (0: it does not).
  int still_check_iteration() const {
    return params_.deformable && params_.still_check_iterations > 0 ? schedule_.warmup + params_.still_check_iterations
                                                                    : 0;
  }
  // The image level iteration `it` trains at: coarse_level_at, except that
  // iterations up to the still-scene check train at full size. A field fitted to
  // half-size frames learns faster than one fitted to full-size frames (cool_teddy:
  // 0.40 dB over its bake after 500 deforming iterations at half size, 0.01 dB at
  // full size), so checking inside the coarse span would let coarse-to-fine
  // decide whether a scene moves.
  int image_level_at(int it) const { return it <= still_check_iteration() ? 0 : coarse_level_at(params_, it); }

  // Trains until iteration `until` (at most params.iterations; earlier when the
  // plateau stop ends training), calling `progress` after every iteration.
  void train(int until, const Progress& progress = {}) {
    until = std::min(until, params_.iterations);
    while (iteration_ < until && !shortcuts_.stopped) {
      step();
      if (progress) progress(last_);
    }
  }

  // One iteration; returns its report. A std::bad_alloc inside becomes OutOfMemory
  // naming the iteration and the model's size (the trainer is then unusable).
  const TrainProgress& step() {
    const std::size_t n = scene_.size();
    const std::uint64_t per_gaussian = std::uint64_t(11 + 3 * sh_coefficient_count(params_.max_sh_degree));
    return with_memory_context([this]() -> const TrainProgress& { return step_unchecked(); },
                               // parameters, gradients and two optimizer moments
                               std::uint64_t(n) * per_gaussian * sizeof(Scalar) * 4, "training iteration ",
                               iteration_ + 1, " of ", params_.iterations, " (", n,
                               " Gaussians; their parameters, gradients and optimizer moments)");
  }

 private:
  const TrainProgress& step_unchecked() {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    ensure(iteration_ < params_.iterations, "Trainer::step: the budget of ", params_.iterations,
           " iterations is used up");
    ensure(!shortcuts_.stopped, "Trainer::step: training stopped on a plateau at iteration ", iteration_);
    const int it = ++iteration_;
    const int threads = params_.threads;
    update_learning_rates(it);
    if (it % schedule_.sh_interval == 0 && scene_.sh_degree < params_.max_sh_degree) raise_sh_degree();

    const std::size_t fi = next_frame();
    const int level = image_level_at(it);
    const TrainFrame<Scalar>& frame = level == 0 ? frames_[fi] : coarse_frame(fi, level);
    const bool deforming = deforming_at(it);
    const GaussianSceneGrad<Scalar>* grad = nullptr;
    const RenderOutput<Scalar>* out = nullptr;
    LossTerms<Scalar> loss;
    auto lap = [last = clock::now()]() mutable {
      const auto now = clock::now();
      const double m = std::chrono::duration<double, std::milli>(now - last).count();
      last = now;
      return m;
    };
    double field_ms = 0;
    if (!deforming) {
      const SceneView<Scalar> view(scene_);
      lap();
      out = &renderer_.render(view, frame.camera);
      last_.render_ms = lap();
      loss = combined_loss(out->color, frame.image, v_color_, ssim_ws_, params_.lambda_dssim, threads);
      last_.loss_ms = lap();
      grad = &renderer_.backward(view, frame.camera, v_color_);
      last_.backward_ms = lap();
    } else {
      double ms[4];
      loss = deformed_forward_backward(frame, frame.time + time_noise(it), ms);
      out = &renderer_.output();
      field_ms = ms[0];
      last_.render_ms = ms[1];
      last_.loss_ms = ms[2];
      last_.backward_ms = ms[3];
      grad = &base_grad_;
      lap();
      Adam<Scalar>::update(field_adam_.group(g_field_), field_adam_.params(), field_->parameters().data(), v_field_.data(),
                  v_field_.size(), threads);
      field_ms += lap();
    }
    last_.field_ms = field_ms;
    last_.render = out->frame;
    last_.psnr = loss.mse > 0 ? -10.0 * std::log10(loss.mse) : 100.0;

    // Adam on the Gaussians.
    step_group(g_means_, scene_.means, grad->means);
    step_group(g_rot_, scene_.rotations, grad->rotations);
    step_group(g_scale_, scene_.log_scales, grad->scales);
    step_group(g_opacity_, scene_.opacity_logits, grad->opacity_logits);
    step_sh(grad->sh);
    last_.adam_ms = lap();

    // Adaptive density control.
    const DensifySchedule& ds = schedule_.densify;
    if (params_.densify) {
      if (ds.collects_stats(it)) {
        if (level == 0) {
          stats_.add_view(grad->screen_grad_ndc_norm, renderer_.projected().radius);
        } else {  // radii in full-size pixels (the screen-size prune compares them with a pixel count)
          const auto& r = renderer_.projected().radius;
          full_radius_.resize(r.size());
          for (std::size_t i = 0; i < r.size(); ++i) full_radius_[i] = r[i] << level;
          stats_.add_view(grad->screen_grad_ndc_norm, full_radius_);
        }
      }
      if (ds.densifies_at(it)) densify_now(ds.size_prune_at(it));
      if (ds.resets_opacity_at(it, white_background())) reset_opacities();
    }
    last_.densify_ms = lap();

    if (field_ && it == still_check_iteration()) check_still();
    track_plateau(it, double(loss.total));

    const double secs = std::chrono::duration<double>(clock::now() - t0).count();
    elapsed_ += secs;
    last_.iteration = it;
    last_.iterations = params_.iterations;
    last_.loss = double(loss.total);
    last_.l1 = double(loss.l1);
    last_.ssim = double(loss.ssim);
    last_.gaussians = scene_.size();
    last_.sh_degree = scene_.sh_degree;
    last_.deforming = deforming;
    last_.image_level = level;
    last_.seconds_per_iteration = secs;
    last_.elapsed_seconds = elapsed_;
    last_.frame = fi;
    last_.shortcuts = shortcuts_;
    return last_;
  }

  // Forward and backward of a deforming step on `frame` at time code t: the
  // field's offsets, render, loss (v_color_), then d loss / d field parameters
  // into v_field_ and the canonical Gaussians' gradients into base_grad_.
  // ms: field (forward and vjp), render, loss and backward times.
  LossTerms<Scalar> deformed_forward_backward(const TrainFrame<Scalar>& frame, Scalar t, double ms[4]) {
    using clock = std::chrono::steady_clock;
    auto lap = [last = clock::now()]() mutable {
      const auto now = clock::now();
      const double m = std::chrono::duration<double, std::milli>(now - last).count();
      last = now;
      return m;
    };
    const int threads = params_.threads;
    const std::size_t n = scene_.size();
    const Eigen::Map<const Matrix3X<Scalar>> means(scene_.means.data(), 3, Eigen::Index(n));
    field_->evaluate(means, t, field_ws_, offsets_, threads);
    ms[0] = lap();
    const DeformedSceneView<Scalar> view(scene_, offsets_.dx.data(), offsets_.dq.data(), offsets_.ds.data(),
                                         offsets_.scale_offset);
    const RenderOutput<Scalar>& out = renderer_.render(view, frame.camera);
    ms[1] = lap();
    const LossTerms<Scalar> loss = combined_loss(out.color, frame.image, v_color_, ssim_ws_, params_.lambda_dssim,
                                                 threads);
    ms[2] = lap();
    const GaussianSceneGrad<Scalar>& vg = renderer_.backward(view, frame.camera, v_color_);
    ms[3] = lap();
    // d loss / d offsets = the gradients w.r.t. the deformed view's parameters.
    v_offsets_.resize(Eigen::Index(n));
    v_offsets_.dx = Eigen::Map<const Matrix3X<Scalar>>(vg.means.data(), 3, Eigen::Index(n));
    v_offsets_.dq = Eigen::Map<const Matrix4X<Scalar>>(vg.rotations.data(), 4, Eigen::Index(n));
    view.scale_offset_gradients(vg, v_offsets_.ds.data());
    v_field_.assign(field_->parameter_count(), Scalar(0));
    field_->evaluate_vjp(field_ws_, v_offsets_, v_field_.data(), nullptr, threads);
    view.base_gradients(vg, base_grad_);
    ms[0] += lap();
    return loss;
  }

 public:
  // The loss of a deforming step on frame `frame` at time code t (no time noise)
  // and, in v_field, its gradient w.r.t. the field's parameters: the step's own
  // forward and backward, without optimiser steps or statistics. Lets a test
  // check the chain image loss -> renderer -> offsets -> network.
  Scalar deformed_loss_gradient(std::size_t frame, Scalar t, std::vector<Scalar>& v_field) {
    ensure(field_ != nullptr, "Trainer::deformed_loss_gradient: the trainer is not deformable");
    ensure(frame < frames_.size(), "Trainer::deformed_loss_gradient: frame ", frame, " of ", frames_.size());
    double ms[4];
    const LossTerms<Scalar> loss = deformed_forward_backward(frames_[frame], t, ms);
    v_field = v_field_;
    return loss.total;
  }
  // The field, writable (a test perturbing its weights); null when not deformable.
  DeformationField<Scalar>* field() { return field_.get(); }

  // Renders the current model for a camera at time code t (deformed when the
  // deformation is active at the current iteration). The image is the renderer's
  // buffer: valid until the next render or training step.
  const Image<Scalar>& render(const Camera<Scalar>& camera, Scalar time) {
    if (deforming_at(iteration_)) {
      const std::size_t n = scene_.size();
      const Eigen::Map<const Matrix3X<Scalar>> means(scene_.means.data(), 3, Eigen::Index(n));
      field_->evaluate(means, time, field_ws_, offsets_, params_.threads);
      const DeformedSceneView<Scalar> view(scene_, offsets_.dx.data(), offsets_.dq.data(), offsets_.ds.data(),
                                           offsets_.scale_offset);
      return renderer_.render(view, camera).color;
    }
    return renderer_.render(SceneView<Scalar>(scene_), camera).color;
  }

  // ------------------------------------------------------------------ checkpoints
  // The whole training state as a record of io/checkpoint.hpp's format.
  TrainingCheckpoint<Scalar> checkpoint() const {
    TrainingCheckpoint<Scalar> c;
    c.iteration = iteration_;
    c.budget = params_.iterations;
    c.frame_count = frames_.size();
    c.seed = params_.seed;
    c.deformable = params_.deformable;
    c.extent = extent_;
    c.elapsed_s = elapsed_;
    c.scene = scene_;
    c.adam = adam_;
    std::ostringstream rs;
    rs << rng_;
    c.rng_state = rs.str();
    c.order = order_;
    c.cursor = cursor_;
    c.densify_grad_sum = stats_.grad_sum;
    c.densify_count = stats_.count;
    c.densify_max_radius = stats_.max_radius;
    c.shortcuts = shortcuts_;
    if (field_) {
      c.field = std::make_unique<DeformationField<Scalar>>(*field_);
      c.field_adam = field_adam_;
    }
    return c;
  }
  void save_checkpoint(std::ostream& os) const { write_checkpoint(os, checkpoint()); }
  void save_checkpoint(const std::string& path) const { write_checkpoint_file(path, checkpoint()); }

  // Replaces the training state with the record's. The trainer must have been
  // built with the same frames and params (checked: budget, frame count, seed,
  // mode, SH degree, optimizer layout); nothing changes when a check fails.
  void restore(TrainingCheckpoint<Scalar> c) {
    ensure(c.budget == params_.iterations, "checkpoint: trained for a budget of ", c.budget,
           " iterations, this trainer has ", params_.iterations, " (schedules would differ)");
    ensure(c.frame_count == frames_.size(), "checkpoint: made with ", c.frame_count, " frames, this trainer has ",
           frames_.size());
    ensure(c.seed == params_.seed, "checkpoint: seed ", c.seed, " differs from this trainer's ", params_.seed);
    ensure(c.deformable == params_.deformable, "checkpoint: ", c.deformable ? "deformable" : "static",
           " model, this trainer is ", params_.deformable ? "deformable" : "static");
    ensure(c.scene.sh_degree >= 0 && c.scene.sh_degree <= params_.max_sh_degree, "checkpoint: SH degree ",
           c.scene.sh_degree, " outside 0..", params_.max_sh_degree);
    // A group whose rows are narrower than its parameters' would let a step write
    // past the end of its moments.
    for (int g = 0; g < 6; ++g)
      ensure(c.adam.group(g).row_width == adam_.group(g).row_width, "checkpoint: optimizer group '",
             c.adam.group(g).name, "' has rows of ", c.adam.group(g).row_width, " values, its parameters ",
             adam_.group(g).row_width);
    ensure(c.order.size() == order_.size(), "checkpoint: a frame order of ", c.order.size(),
           " draws, this trainer's has ", order_.size());
    std::mt19937 rng;
    std::istringstream rs(c.rng_state);
    rs >> rng;
    ensure(!rs.fail(), "checkpoint: unreadable random generator state");
    // Everything checked: commit.
    iteration_ = c.iteration;
    extent_ = c.extent;
    elapsed_ = c.elapsed_s;
    scene_ = std::move(c.scene);
    adam_ = std::move(c.adam);
    rng_ = rng;
    order_ = std::move(c.order);
    cursor_ = std::size_t(c.cursor);
    stats_.grad_sum = std::move(c.densify_grad_sum);
    stats_.count = std::move(c.densify_count);
    stats_.max_radius = std::move(c.densify_max_radius);
    if (c.deformable) {
      field_ = std::move(c.field);  // null when the still-scene check baked it in
      field_adam_ = std::move(c.field_adam);
    }
    shortcuts_ = c.shortcuts;
  }
  void load_checkpoint(std::istream& is) { restore(read_checkpoint<Scalar>(is, params_.adam)); }
  // Refuses a file whose checksum does not match before reading any of it.
  void load_checkpoint(const std::string& path) {
    try {
      restore(read_checkpoint_file<Scalar>(path, params_.adam));
    } catch (const Error& e) {
      const std::string what = e.what();
      if (what.compare(0, path.size(), path) == 0) throw;
      fail(path, ": ", what);
    }
  }

 private:

  int rest_width() const { return std::max(1, 3 * (sh_coefficient_count(params_.max_sh_degree) - 1)); }
  bool white_background() const {
    return params_.background[0] >= 1 && params_.background[1] >= 1 && params_.background[2] >= 1;
  }

  void update_learning_rates(int it) {
    ExponentialLr pos;
    pos.lr_init = params_.position_lr_init * double(extent_);
    pos.lr_final = params_.position_lr_final * double(extent_);
    pos.max_steps = params_.position_lr_steps > 0 ? params_.position_lr_steps : params_.iterations;
    adam_.set_lr(g_means_, Scalar(pos(it)));
    if (field_) {
      ExponentialLr f;
      f.lr_init = params_.deform_lr_init;
      f.lr_final = params_.deform_lr_final;
      f.max_steps = params_.deform_lr_steps > 0 ? params_.deform_lr_steps : params_.iterations;
      field_adam_.set_lr(g_field_, Scalar(f(it)));
    }
  }

  Scalar time_noise(int it) {
    if (!(params_.time_noise > 0)) return Scalar(0);
    const double anneal = std::max(0.0, 1.0 - double(it) / double(std::max(1, params_.time_noise_steps)));
    const double remaining = double(order_.size() - cursor_ + 1);
    std::normal_distribution<double> n(0.0, 1.0);
    return Scalar(n(rng_) * params_.time_noise * anneal / remaining);
  }

  // Frame fi at image level `level` (>= 1), built on first use: each level halves
  // the one above (2x2 box filter; an odd last row or column is dropped) and the
  // camera keeps its pose with fx, fy, cx, cy scaled by 2^-level.
  const TrainFrame<Scalar>& coarse_frame(std::size_t fi, int level) {
    if (coarse_.size() != frames_.size()) coarse_.assign(frames_.size(), {});
    auto& levels = coarse_[fi];
    while (int(levels.size()) < level) {
      const TrainFrame<Scalar>& above = levels.empty() ? frames_[fi] : levels.back();
      TrainFrame<Scalar> f = above;
      const int w = std::max(1, above.image.width / 2), h = std::max(1, above.image.height / 2);
      f.image = Image<Scalar>(w, h, 3);
      for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
          for (int c = 0; c < 3; ++c) {
            const int x1 = std::min(2 * x + 1, above.image.width - 1), y1 = std::min(2 * y + 1, above.image.height - 1);
            f.image(x, y, c) = Scalar(0.25) * (above.image(2 * x, 2 * y, c) + above.image(x1, 2 * y, c) +
                                               above.image(2 * x, y1, c) + above.image(x1, y1, c));
          }
      Intrinsics<Scalar>& k = f.camera.intrinsics;
      k.fx *= Scalar(0.5), k.fy *= Scalar(0.5), k.cx *= Scalar(0.5), k.cy *= Scalar(0.5);
      k.width = w, k.height = h;
      levels.push_back(std::move(f));
    }
    return levels[std::size_t(level - 1)];
  }

  std::size_t next_frame() {
    if (cursor_ >= order_.size()) {
      std::size_t k = 0;
      for (std::size_t i = 0; i < frames_.size(); ++i)
        for (int r = 0; r < frames_[i].repeats; ++r) order_[k++] = i;
      std::shuffle(order_.begin(), order_.end(), rng_);
      cursor_ = 0;
    }
    return order_[cursor_++];
  }

  // Adds the next band of SH coefficients (zero-initialised), as 3DGS's oneupSHdegree
  // (3DGS keeps all coefficients from the start; inactive ones get zero gradient and
  // stay zero, so this is the same).
  void raise_sh_degree() {
    const std::size_t n = scene_.size();
    const int k_old = scene_.sh_coefficients();
    const int k_new = sh_coefficient_count(scene_.sh_degree + 1);
    std::vector<Scalar> sh(n * std::size_t(k_new) * 3, Scalar(0));
    for (std::size_t i = 0; i < n; ++i)
      std::copy_n(&scene_.sh[i * std::size_t(k_old) * 3], k_old * 3, &sh[i * std::size_t(k_new) * 3]);
    scene_.sh.swap(sh);
    scene_.sh_degree += 1;
  }

  void step_group(int id, std::vector<Scalar>& params, const std::vector<Scalar>& grad) {
    auto& g = adam_.group(id);
    ensure(params.size() == g.size() && grad.size() == g.size(), "Trainer: optimizer group '", g.name, "' has ",
           g.size(), " values, parameters ", params.size(), ", gradients ", grad.size());
    Adam<Scalar>::update(g, adam_.params(), params.data(), grad.data(), params.size(), params_.threads);
  }

  // Adam on SH with two learning rates: DC (group sh_dc) and the rest (group
  // sh_rest, moments stored at the maximum degree's width). Same update as
  // Adam::step, on the interleaved [N][K][3] layout.
  void step_sh(const std::vector<Scalar>& grad) {
    auto& dc = adam_.group(g_dc_);
    auto& rest = adam_.group(g_rest_);
    const std::size_t n = scene_.size();
    const int k3 = 3 * scene_.sh_coefficients();
    ensure(grad.size() == n * std::size_t(k3), "Trainer: SH gradient has ", grad.size(), " values, expected ",
           n * std::size_t(k3));
    const std::size_t rw = std::size_t(rest.row_width);
    ++dc.step;
    ++rest.step;
    const AdamStep<Scalar> cd = AdamStep<Scalar>::of(adam_.params(), double(dc.lr), dc.step);
    const AdamStep<Scalar> cr = AdamStep<Scalar>::of(adam_.params(), double(rest.lr), rest.step);
    Scalar* sh = scene_.sh.data();
    const std::size_t per_block = std::max<std::size_t>(1, kAdamBlock / std::size_t(k3));
    parallel_for((n + per_block - 1) / per_block, params_.threads, [&](std::size_t b, int) {
      for (std::size_t i = b * per_block, end = std::min(n, i + per_block); i < end; ++i) {
        Scalar* p = sh + i * std::size_t(k3);
        const Scalar* g = grad.data() + i * std::size_t(k3);
        adam_apply(cd, p, g, dc.m.data() + 3 * i, dc.v.data() + 3 * i, 3);
        if (k3 > 3) adam_apply(cr, p + 3, g + 3, rest.m.data() + i * rw, rest.v.data() + i * rw, std::size_t(k3 - 3));
      }
    });
  }

  void densify_now(bool size_prune) {
    const DensifyPlan plan =
        densify_and_prune(scene_, stats_, params_.densify_params, extent_, size_prune, rng_);
    last_.cloned += plan.cloned;
    last_.split += plan.split;
    last_.pruned += plan.pruned;
    // Nothing left to train: say so rather than carry on rendering the background.
    ensure(scene_.size() > 0, "Trainer: densification at iteration ", iteration_,
           " pruned every Gaussian (schedule densifying every ", schedule_.densify.densify_interval,
           " iterations, opacity reset every ", schedule_.densify.opacity_reset_interval,
           "; check the background colour against the frames, or raise TrainParams::min_densify_interval)");
    // New row order: kept old rows, then appended rows (zero moments, as 3DGS).
    std::vector<std::int64_t> source;
    source.reserve(plan.new_size());
    for (std::size_t i = 0; i < plan.keep.size(); ++i)
      if (plan.keep[i]) source.push_back(std::int64_t(i));
    source.resize(plan.new_size(), -1);
    for (int g = 0; g < adam_.group_count(); ++g) adam_.gather(g, source);
    stats_.reset(scene_.size());
  }

  // Still scene: bake the field and compare the bake's fit of up to 8 training
  // frames with the deformed model's; when the field gains too little, keep the
  // bake and go on static. The scene keeps its size and row order, so the
  // optimizer's moments still belong to their Gaussians.
  void check_still() {
    MedianBakeParams mp;
    mp.samples = params_.still_bake_samples;
    mp.threads = params_.threads;
    GaussianScene<Scalar> baked = bake_median(scene_, FieldDeformation<Scalar>(*field_, params_.threads), mp);
    const std::size_t k = std::min<std::size_t>(8, frames_.size());
    double gain = 0;
    for (std::size_t j = 0; j < k; ++j) {
      const TrainFrame<Scalar>& f = frames_[j * frames_.size() / k];
      const double deformed = fit_psnr(render(f.camera, f.time), f.image);
      gain += (deformed - fit_psnr(renderer_.render(SceneView<Scalar>(baked), f.camera).color, f.image)) / double(k);
    }
    shortcuts_.still_checked = true;
    shortcuts_.field_gain_db = gain;
    if (!(gain < params_.still_gain_db)) return;
    scene_ = std::move(baked);
    field_.reset();
    shortcuts_.field_baked = true;
  }

  // PSNR of a render (clamped to [0, 1]) against a frame.
  static double fit_psnr(const Image<Scalar>& render, const Image<Scalar>& frame) {
    double se = 0;
    for (std::size_t i = 0; i < render.data.size(); ++i) {
      const double d = std::min(1.0, std::max(0.0, double(render.data[i]))) - double(frame.data[i]);
      se += d * d;
    }
    const double mse = se / double(std::max<std::size_t>(1, render.data.size()));
    return mse > 0 ? -10.0 * std::log10(mse) : 100.0;
  }

  // Plateau stop: windows of whole passes over the frames, ending at multiples of
  // their length; a window counts once nothing but the optimiser changed the
  // model during it (densification, opacity resets, warm-up, coarse levels, the
  // still-scene bake all lie before its start).
  void track_plateau(int it, double loss) {
    if (params_.plateau_window <= 0) return;
    const int pass = int(order_.size());
    const int window = std::max(1, (params_.plateau_window + pass - 1) / pass) * pass;
    ShortcutState& s = shortcuts_;
    s.plateau_sum += loss;
    if (it % window != 0) return;
    int quiet_from = 0;  // the first iteration after the last change to the model's structure
    if (params_.densify) quiet_from = std::max(quiet_from, schedule_.densify.densify_until);
    if (params_.deformable) quiet_from = std::max(quiet_from, std::max(schedule_.warmup, still_check_iteration()) + 1);
    if (params_.coarse_levels > 0)
      quiet_from = std::max(quiet_from, int(std::ceil(params_.coarse_fraction * params_.iterations)) + 1);
    const double mean = s.plateau_sum / window;
    s.plateau_sum = 0;
    if (it - window + 1 < quiet_from) {
      s.plateau_previous = s.plateau_last = 0;
      return;
    }
    s.plateau_previous = s.plateau_last;
    s.plateau_last = mean;
    if (s.plateau_previous > 0 && s.plateau_previous - mean < params_.plateau_tolerance * s.plateau_previous)
      s.stopped = it < params_.iterations;
  }

  // 3DGS's reset_opacity also replaces the optimizer state of the opacities by zeros.
  void reset_opacities() {
    reset_opacity(scene_, params_.densify_params);
    auto& g = adam_.group(g_opacity_);
    std::fill(g.m.begin(), g.m.end(), Scalar(0));
    std::fill(g.v.begin(), g.v.end(), Scalar(0));
  }

  const std::vector<TrainFrame<Scalar>>& frames_;
  TrainParams params_;
  TrainSchedule schedule_;
  GaussianScene<Scalar> scene_;
  Adam<Scalar> adam_, field_adam_;
  std::vector<std::vector<TrainFrame<Scalar>>> coarse_;  // [frame][level - 1], coarse-to-fine
  std::vector<std::int32_t> full_radius_;
  int g_means_ = -1, g_rot_ = -1, g_scale_ = -1, g_opacity_ = -1, g_dc_ = -1, g_rest_ = -1, g_field_ = -1;
  std::mt19937 rng_;
  std::vector<std::size_t> order_;
  std::size_t cursor_ = 0;
  DensifyStats<Scalar> stats_;
  Scalar extent_ = 1;
  int iteration_ = 0;
  double elapsed_ = 0;
  TrainProgress last_;
  // Still-scene check and plateau stop (see TrainParams).
  ShortcutState shortcuts_;

  // Workspaces reused across iterations.
  Renderer<Scalar> renderer_;
  Image<Scalar> v_color_;
  SsimWorkspace<Scalar> ssim_ws_;
  std::unique_ptr<DeformationField<Scalar>> field_;
  typename DeformationField<Scalar>::Workspace field_ws_;
  DeformationOffsets<Scalar> offsets_, v_offsets_;
  std::vector<Scalar> v_field_;
  GaussianSceneGrad<Scalar> base_grad_;
};

}  // namespace orbitforge

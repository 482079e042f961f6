#pragma once
// Gaussian Splatting training on the CPU, static (3DGS, Kerbl et al. 2023) and
// deformable (Deformable 3D Gaussians, Yang et al. 2023): frames with per-frame
// cameras and a time code t in [0, 1] -> a GaussianScene (+ a DeformationField).
//
//   std::vector<TrainFrame<float>> frames = ...;      // image [H][W][3] in [0, 1]
//   Trainer<float> trainer(frames, init_from_points(xyz, rgb), params);
//   trainer.train(params.iterations, [](const TrainProgress& p) { ... });
//   trainer.save_checkpoint("ckpt.bin");
//
// One iteration (1-based `it`), as 3DGS train.py: learning rates; SH degree raise;
// the next frame of a seeded shuffled order; render (deformed after the warm-up);
// loss 0.8 L1 + 0.2 (1 - SSIM), through the frame's exposure transform when on;
// backward; Adam steps (the learned background's too, when on); density control
// and opacity resets; the still-scene check and the plateau stop when enabled.
// Unlike 3DGS, the optimizer step comes before densification.
//
// This class is the loop; each concept it drives has a header of its own:
// train_frame / train_params / train_progress (data), schedules, frame_order,
// frame_exposure, coarse_to_fine, deformed_pass, gaussian_adam, densify_driver,
// still_check, plateau_stop, background, learned_background, trainer_checkpoint.
//
// Determinism: the same frames, initial scene, params and thread count give the
// same result bit for bit, and a run resumed from a checkpoint (written atomically;
// a damaged file is refused whole) continues exactly as an uninterrupted one.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <functional>
#include <memory>
#include <ostream>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/background.hpp"
#include "orbitforge/train/coarse_to_fine.hpp"
#include "orbitforge/train/deformed_pass.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/densify_driver.hpp"
#include "orbitforge/train/frame_exposure.hpp"
#include "orbitforge/train/frame_order.hpp"
#include "orbitforge/train/gaussian_adam.hpp"
#include "orbitforge/train/learned_background.hpp"
#include "orbitforge/train/losses.hpp"
#include "orbitforge/train/plateau_stop.hpp"
#include "orbitforge/train/schedules.hpp"
#include "orbitforge/train/still_check.hpp"
#include "orbitforge/train/train_frame.hpp"
#include "orbitforge/train/train_params.hpp"
#include "orbitforge/train/train_progress.hpp"
#include "orbitforge/train/trainer_checkpoint.hpp"

namespace orbitforge {

template <class Scalar>
class Trainer {
 public:
  using Progress = std::function<void(const TrainProgress&)>;

  // `frames` must outlive the trainer. `initial` is the starting scene (see
  // train/init.hpp); its SH degree is the starting active degree.
  Trainer(const std::vector<TrainFrame<Scalar>>& frames, GaussianScene<Scalar> initial, const TrainParams& params)
      : frames_(frames), params_(resolved(params)), schedule_(TrainSchedule::make(params_, draws_per_pass(frames))) {
    check_train_frames(frames_);
    resolve_threads(params.threads, "TrainParams::threads");  // over the limit: refused before anything is built
    check_still_params(params);
    check_plateau_params(params);  // coarse_levels and coarse_fraction: checked by resolved()
    GaussianScene<Scalar>& scene = s_.scene = std::move(initial);
    scene.check_consistent();
    ensure(!scene.empty(), "Trainer: the initial scene has no Gaussians");
    ensure(scene.sh_degree <= params.max_sh_degree, "Trainer: initial scene has SH degree ", scene.sh_degree,
           ", above max_sh_degree ", params.max_sh_degree);
    std::vector<Camera<Scalar>> cams;
    std::vector<int> repeats;
    for (const auto& f : frames_) cams.push_back(f.camera), repeats.push_back(f.repeats);
    s_.extent = camera_extent_or_one(cams);
    RenderParams<Scalar> rp;
    rp.threads = params.threads;
    rp.near_plane = params.near_plane_fraction * double(s_.extent);
    renderer_ = Renderer<Scalar>(rp);
    s_.background = learned_background_for<Scalar>(params);
    renderer_.params().background = background();
    // Only a learned background steps on its gradient.
    renderer_.params().background_gradient = s_.background.enabled();
    s_.adam = make_gaussian_adam<Scalar>(params, scene.size());
    s_.stats.reset(scene.size());
    s_.field_adam = Adam<Scalar>(params.adam);
    if (params.exposure_compensation)
      s_.exposure = FrameExposure<Scalar>(frames_.size(), params.adam, params.exposure_lr);
    if (params.deformable) {
      s_.field = std::make_unique<DeformationField<Scalar>>(params.field);
      if (params.normalize_field)
        s_.field->set_frame(mean_camera_center(cams), s_.extent / Scalar(kFieldReferenceExtent));
      s_.field_adam.add_group("deformation", s_.field->parameter_count(), 1, Scalar(0));
    }
    s_.rng.seed(params.seed);
    s_.order = FrameOrder(std::move(repeats));
    densify_ = DensifyDriver<Scalar>(params, schedule_.densify, longer_side(frames_));
    plateau_ = PlateauStop::make(params_, s_.order.pass_length(),
                                 plateau_quiet_from(params_, schedule_, still_check_iteration()));
  }

  const TrainParams& params() const { return params_; }
  const TrainSchedule& schedule() const { return schedule_; }
  const GaussianScene<Scalar>& scene() const { return s_.scene; }
  const DeformationField<Scalar>* field() const { return s_.field.get(); }
  DeformationField<Scalar>* field() { return s_.field.get(); }  // writable (a test perturbs it); null when static
  const Adam<Scalar>& optimizer() const { return s_.adam; }
  const DensifyStats<Scalar>& densify_stats() const { return s_.stats; }
  const FrameExposure<Scalar>& exposure() const { return s_.exposure; }  // per-frame colour transforms (or off)
  // The background of every render but a training render with a random one (learned, when on).
  std::array<Scalar, 3> background() const { return resting_background(s_.background, params_); }
  int iteration() const { return s_.iteration; }
  Scalar extent() const { return s_.extent; }
  const TrainProgress& last_progress() const { return last_; }
  // The deformation is applied at iterations > warmup (until a still-scene check bakes it in).
  bool deforming_at(int it) const { return s_.field && it > schedule_.warmup; }
  // The budget is used up, or the plateau stop ended training.
  bool finished() const { return s_.shortcuts.stopped || s_.iteration >= params_.iterations; }
  // What the still-scene check and the plateau stop decided (kept in checkpoints).
  const ShortcutState& shortcuts() const { return s_.shortcuts; }
  bool field_baked() const { return s_.shortcuts.field_baked; }  // the field was baked in; training went on static
  // The iteration at whose end the still-scene check runs (0: it does not).
  int still_check_iteration() const { return orbitforge::still_check_iteration(params_, schedule_.warmup); }
  // The image level iteration `it` trains at (coarse_to_fine.hpp; full size up to the still-scene check).
  int image_level_at(int it) const { return orbitforge::image_level_at(params_, it, still_check_iteration()); }

  // The caller moved cameras of the frames it gave (their images and count
  // unchanged): the downsampled copies are made again from them.
  void cameras_changed() { coarse_.clear(); }

  // Trains until iteration `until` (at most params.iterations; earlier when the
  // plateau stop ends training), calling `progress` after every iteration.
  void train(int until, const Progress& progress = {}) {
    until = std::min(until, params_.iterations);
    while (s_.iteration < until && !s_.shortcuts.stopped) {
      step();
      if (progress) progress(last_);
    }
  }

  // One iteration; a std::bad_alloc inside becomes OutOfMemory naming it (the trainer is then unusable).
  const TrainProgress& step() {
    const std::size_t n = s_.scene.size();
    const std::uint64_t per_gaussian = std::uint64_t(11 + 3 * sh_coefficient_count(params_.max_sh_degree));
    return with_memory_context([this]() -> const TrainProgress& { return step_unchecked(); },
                               // parameters, gradients and two optimizer moments
                               std::uint64_t(n) * per_gaussian * sizeof(Scalar) * 4, "training iteration ",
                               s_.iteration + 1, " of ", params_.iterations, " (", n,
                               " Gaussians; their parameters, gradients and optimizer moments)");
  }

  // A deforming step's loss on `frame` at time t (no noise) and, in v_field, its gradient w.r.t. the
  // field's parameters, without optimiser steps or statistics (a test checks the chain with it).
  Scalar deformed_loss_gradient(std::size_t frame, Scalar t, std::vector<Scalar>& v_field) {
    ensure(s_.field != nullptr, "Trainer::deformed_loss_gradient: the trainer is not deformable");
    ensure(frame < frames_.size(), "Trainer::deformed_loss_gradient: frame ", frame, " of ", frames_.size());
    double ms[4];
    const auto loss_fn = [&](const Image<Scalar>& r, Image<Scalar>& v) {
      return combined_loss(r, frames_[frame].image, v, ssim_ws_, params_.lambda_dssim, params_.threads);
    };
    const LossTerms<Scalar> loss = deformed_.forward_backward(s_.scene, *s_.field, renderer_, frames_[frame].camera,
                                                              t, loss_fn, v_color_, params_.threads, ms);
    v_field = deformed_.v_field();
    return loss.total;
  }

  // The current model at a camera and time t (deformed when the deformation is active), in the
  // renderer's buffer: valid until the next render or training step.
  const Image<Scalar>& render(const Camera<Scalar>& camera, Scalar time) {
    renderer_.params().background = background();  // a restored learned colour too
    if (!deforming_at(s_.iteration)) return renderer_.render(SceneView<Scalar>(s_.scene), camera).color;
    return renderer_.render(deformed_.view(s_.scene, *s_.field, time, params_.threads), camera).color;
  }

  // Checkpoints (trainer_checkpoint.hpp): the whole training state as a record of
  // io/checkpoint.hpp's format, and back. restore() needs a trainer built with the
  // same frames and params (checked); nothing changes when a check fails.
  TrainingCheckpoint<Scalar> checkpoint() const { return make_checkpoint(s_, params_, frames_.size()); }
  void save_checkpoint(std::ostream& os) const { write_checkpoint(os, checkpoint()); }
  void save_checkpoint(const std::string& path) const { write_checkpoint_file(path, checkpoint()); }
  void restore(TrainingCheckpoint<Scalar> c) { restore_checkpoint(s_, std::move(c), params_, frames_.size()); }
  void load_checkpoint(std::istream& is) { restore(read_checkpoint<Scalar>(is, params_.adam)); }
  // Refuses a file whose checksum does not match before reading any of it.
  void load_checkpoint(const std::string& path) { restore_checkpoint_file(s_, path, params_, frames_.size()); }

 private:
  const TrainProgress& step_unchecked() {
    using clock = std::chrono::steady_clock;
    const auto t0 = clock::now();
    ensure(s_.iteration < params_.iterations, "Trainer::step: the budget of ", params_.iterations,
           " iterations is used up");
    ensure(!s_.shortcuts.stopped, "Trainer::step: training stopped on a plateau at iteration ", s_.iteration);
    const int it = ++s_.iteration;
    const int threads = params_.threads;
    s_.adam.set_lr(kMeansGroup, Scalar(position_lr(params_, double(s_.extent))(it)));
    if (s_.field) s_.field_adam.set_lr(0, Scalar(deformation_lr(params_)(it)));
    if (schedule_.raises_sh_degree_at(it) && s_.scene.sh_degree < params_.max_sh_degree) raise_sh_degree(s_.scene);

    std::size_t fi = s_.order.next(s_.rng);
    // Until the still check, the frames it compares on are not trained on.
    if (s_.field && it <= still_check_iteration())
      while (held_for_still_check(params_, fi)) fi = s_.order.next(s_.rng);
    const int level = image_level_at(it);
    const TrainFrame<Scalar>& frame = level == 0 ? frames_[fi] : coarse_.at(frames_, fi, level);
    const bool deforming = deforming_at(it);
    renderer_.params().background =
        params_.random_background ? background_color<Scalar>(random_background_at(params_.seed, it)) : background();
    const GaussianSceneGrad<Scalar>* grad = nullptr;
    const auto loss_fn = [&](const Image<Scalar>& render, Image<Scalar>& v) {
      return s_.exposure.loss_and_step(fi, render, frame.image, v, ssim_ws_, params_.lambda_dssim, threads);
    };
    LossTerms<Scalar> loss;
    LapTimer lap;
    double field_ms = 0;
    if (!deforming) {
      const SceneView<Scalar> view(s_.scene);
      lap();
      renderer_.render(view, frame.camera);
      last_.render_ms = lap();
      loss = loss_fn(renderer_.output().color, v_color_);
      last_.loss_ms = lap();
      grad = &renderer_.backward(view, frame.camera, v_color_);
      last_.backward_ms = lap();
    } else {
      const Scalar t = frame.time + time_noise_at<Scalar>(params_, it, s_.order.remaining_with_last(), s_.rng);
      double ms[4];
      loss = deformed_.forward_backward(s_.scene, *s_.field, renderer_, frame.camera, t, loss_fn, v_color_, threads,
                                        ms);
      field_ms = ms[0], last_.render_ms = ms[1], last_.loss_ms = ms[2], last_.backward_ms = ms[3];
      grad = &deformed_.base_grad();
      lap();
      const std::vector<Scalar>& v_field = deformed_.v_field();
      Adam<Scalar>::update(s_.field_adam.group(0), s_.field_adam.params(), s_.field->parameters().data(),
                           v_field.data(), v_field.size(), threads);
      field_ms += lap();
    }
    last_.field_ms = field_ms;
    last_.render = renderer_.output().frame;
    last_.warning.clear();
    if (!near_warned_) {  // once: the same cameras would repeat it every iteration
      last_.warning = near_cull_warning(last_.render, renderer_.params().near_plane);
      near_warned_ = !last_.warning.empty();
    }

    if (s_.background.enabled()) s_.background.step(renderer_.background_gradient());
    renderer_.params().background = background();  // after a random one, or a learned one's step
    step_gaussians(s_.adam, s_.scene, *grad, threads);
    last_.adam_ms = lap();

    const DensifyCounts dc = densify_.step(it, level, grad->screen_grad_ndc_norm, renderer_.projected().radius,
                                           s_.scene, s_.stats, s_.adam, s_.extent, s_.rng);
    last_.cloned += dc.cloned, last_.split += dc.split, last_.pruned += dc.pruned, last_.spared += dc.spared;
    last_.pruned_by_size += dc.pruned_by_size;
    last_.densify_ms = lap();

    if (s_.field && it == still_check_iteration()) check_still();
    plateau_.track(it, double(loss.total), s_.shortcuts);

    const double secs = std::chrono::duration<double>(clock::now() - t0).count();
    s_.elapsed += secs;
    last_.set_loss(loss);
    last_.iteration = it, last_.iterations = params_.iterations;
    last_.gaussians = s_.scene.size(), last_.sh_degree = s_.scene.sh_degree;
    last_.deforming = deforming, last_.image_level = level, last_.frame = fi;
    last_.seconds_per_iteration = secs, last_.elapsed_seconds = s_.elapsed;
    last_.shortcuts = s_.shortcuts;
    return last_;
  }

  // The still-scene check (still_check.hpp); a bake keeps the scene's size and row
  // order, so the optimizer's moments still belong to their Gaussians.
  void check_still() {
    StillVerdict<Scalar> v = check_still_scene(
        s_.scene, *s_.field, frames_, still_check_frames(params_, frames_.size()), renderer_, params_,
        [this](const Camera<Scalar>& camera, Scalar time) -> const Image<Scalar>& { return render(camera, time); });
    record_still_verdict(v, s_.shortcuts);
    if (!v.bake) return;
    s_.scene = std::move(v.baked);
    s_.field.reset();
    s_.shortcuts.field_baked = true;
  }

  const std::vector<TrainFrame<Scalar>>& frames_;
  // The caller's params with the budget's choices made (coarse_levels).
  static TrainParams resolved(TrainParams p) {
    check_coarse_params(p);
    p.coarse_levels = resolved_coarse_levels(p);
    return p;
  }

  TrainParams params_;
  TrainSchedule schedule_;
  TrainState<Scalar> s_;
  CoarseFrames<Scalar> coarse_;
  DensifyDriver<Scalar> densify_;
  PlateauStop plateau_;
  TrainProgress last_;
  bool near_warned_ = false;

  // Workspaces reused across iterations.
  Renderer<Scalar> renderer_;
  Image<Scalar> v_color_;
  SsimWorkspace<Scalar> ssim_ws_;
  DeformedPass<Scalar> deformed_;
};

}  // namespace orbitforge

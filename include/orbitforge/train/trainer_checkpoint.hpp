#pragma once
// The training state a Trainer carries from one iteration to the next
// (TrainState), and its conversion to and from a checkpoint record
// (io/checkpoint.hpp's format): what is saved, and the checks that a record fits
// the trainer it is loaded into.
#include <cstddef>
#include <memory>
#include <random>
#include <sstream>
#include <string>
#include <utility>

#include "orbitforge/core/error.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/frame_exposure.hpp"
#include "orbitforge/train/learned_background.hpp"
#include "orbitforge/train/frame_order.hpp"
#include "orbitforge/train/gaussian_adam.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// Everything a resumed run needs to continue exactly as an uninterrupted one.
template <class Scalar>
struct TrainState {
  int iteration = 0;  // iterations done
  Scalar extent = 1;  // scene extent (camera_extent; 1 for a single camera)
  double elapsed = 0; // wall seconds of the iterations done
  GaussianScene<Scalar> scene;
  Adam<Scalar> adam;  // the Gaussians' (gaussian_adam.hpp)
  std::mt19937 rng;   // frame order, time noise, densification
  FrameOrder order;
  DensifyStats<Scalar> stats;
  ShortcutState shortcuts;  // still-scene check and plateau stop
  std::unique_ptr<DeformationField<Scalar>> field;  // null: static, or baked by the still-scene check
  Adam<Scalar> field_adam;
  FrameExposure<Scalar> exposure;  // off unless TrainParams::exposure_compensation
  LearnedBackground<Scalar> background;  // off unless TrainParams::learned_background
};

// The state as a record, with what it must be resumed with: budget, frame count,
// seed and mode.
template <class Scalar>
TrainingCheckpoint<Scalar> make_checkpoint(const TrainState<Scalar>& s, const TrainParams& p,
                                           std::size_t frame_count) {
  TrainingCheckpoint<Scalar> c;
  c.iteration = s.iteration;
  c.budget = p.iterations;
  c.frame_count = frame_count;
  c.seed = p.seed;
  c.deformable = p.deformable;
  c.extent = s.extent;
  c.elapsed_s = s.elapsed;
  c.scene = s.scene;
  c.adam = s.adam;
  std::ostringstream rs;
  rs << s.rng;
  c.rng_state = rs.str();
  c.order = s.order.order();
  c.cursor = s.order.cursor();
  c.densify_grad_sum = s.stats.grad_sum;
  c.densify_count = s.stats.count;
  c.densify_max_radius = s.stats.max_radius;
  c.shortcuts = s.shortcuts;
  if (s.field) {
    c.field = std::make_unique<DeformationField<Scalar>>(*s.field);
    c.field_adam = s.field_adam;
  }
  c.exposure = s.exposure.transforms();
  c.exposure_adam = s.exposure.optimizer();
  c.background = s.background.logits();
  c.background_adam = s.background.optimizer();
  return c;
}

// Replaces `s` by the record's state. The record must have been made with the
// same frames and params (checked: budget, frame count, seed, mode, SH degree,
// optimizer layout, frame order length, exposure compensation, learned background); nothing changes
// when a check fails.
template <class Scalar>
void restore_checkpoint(TrainState<Scalar>& s, TrainingCheckpoint<Scalar> c, const TrainParams& p,
                        std::size_t frame_count) {
  ensure(c.budget == p.iterations, "checkpoint: trained for a budget of ", c.budget, " iterations, this trainer has ",
         p.iterations, " (schedules would differ)");
  ensure(c.frame_count == frame_count, "checkpoint: made with ", c.frame_count, " frames, this trainer has ",
         frame_count);
  ensure(c.seed == p.seed, "checkpoint: seed ", c.seed, " differs from this trainer's ", p.seed);
  ensure(c.deformable == p.deformable, "checkpoint: ", c.deformable ? "deformable" : "static",
         " model, this trainer is ", p.deformable ? "deformable" : "static");
  ensure(c.scene.sh_degree >= 0 && c.scene.sh_degree <= p.max_sh_degree, "checkpoint: SH degree ",
         c.scene.sh_degree, " outside 0..", p.max_sh_degree);
  // A group whose rows are narrower than its parameters' would let a step write
  // past the end of its moments.
  for (int g = 0; g < kGaussianGroupCount; ++g)
    ensure(c.adam.group(g).row_width == s.adam.group(g).row_width, "checkpoint: optimizer group '",
           c.adam.group(g).name, "' has rows of ", c.adam.group(g).row_width, " values, its parameters ",
           s.adam.group(g).row_width);
  ensure(c.order.size() == s.order.pass_length(), "checkpoint: a frame order of ", c.order.size(),
         " draws, this trainer's has ", s.order.pass_length());
  std::mt19937 rng;
  std::istringstream rs(c.rng_state);
  rs >> rng;
  ensure(!rs.fail(), "checkpoint: unreadable random generator state");
  ensure(c.exposure.empty() != p.exposure_compensation, "checkpoint: made ",
         c.exposure.empty() ? "without" : "with", " exposure compensation, this trainer is ",
         p.exposure_compensation ? "with" : "without");
  FrameExposure<Scalar> exposure;
  if (!c.exposure.empty()) exposure = FrameExposure<Scalar>(std::move(c.exposure), std::move(c.exposure_adam));
  ensure(c.background.empty() != p.learned_background, "checkpoint: made ", c.background.empty() ? "without" : "with",
         " a learned background, this trainer is ", p.learned_background ? "with" : "without");
  LearnedBackground<Scalar> background;
  if (!c.background.empty()) background = LearnedBackground<Scalar>(std::move(c.background), std::move(c.background_adam));
  // Everything checked: commit.
  s.iteration = c.iteration;
  s.extent = c.extent;
  s.elapsed = c.elapsed_s;
  s.scene = std::move(c.scene);
  s.adam = std::move(c.adam);
  s.rng = rng;
  s.order.restore(std::move(c.order), std::size_t(c.cursor));
  s.stats.grad_sum = std::move(c.densify_grad_sum);
  s.stats.count = std::move(c.densify_count);
  s.stats.max_radius = std::move(c.densify_max_radius);
  if (c.deformable) {
    s.field = std::move(c.field);  // null when the still-scene check baked it in
    s.field_adam = std::move(c.field_adam);
  }
  s.shortcuts = c.shortcuts;
  s.exposure = std::move(exposure);
  s.background = std::move(background);
}

// Reads the file and restores `s` from it (restore_checkpoint), every error
// naming the file. A file whose checksum does not match is refused before any of
// it is read.
template <class Scalar>
void restore_checkpoint_file(TrainState<Scalar>& s, const std::string& path, const TrainParams& p,
                             std::size_t frame_count) {
  try {
    restore_checkpoint(s, read_checkpoint_file<Scalar>(path, p.adam), p, frame_count);
  } catch (const Error& e) {
    const std::string what = e.what();
    if (what.compare(0, path.size(), path) == 0) throw;
    fail(path, ": ", what);
  }
}

}  // namespace orbitforge

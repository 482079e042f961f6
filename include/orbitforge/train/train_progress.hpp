#pragma once
// What one training iteration reports (Trainer::step, the train() callback).
#include <chrono>
#include <cmath>
#include <cstddef>
#include <string>

#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/losses.hpp"

namespace orbitforge {

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
  std::size_t pruned_by_size = 0;  // of the pruned, those removed for their size only
  // Gaussians the pruning floor kept (DensifyParams::min_gaussians), cumulative:
  // above 0, the schedule would have pruned the model below its floor.
  std::size_t spared = 0;
  // The still-scene check's and the plateau stop's state after this iteration.
  ShortcutState shortcuts;
  // A problem to tell the user, set on the first iteration that shows it only
  // (near_cull_warning); empty otherwise.
  std::string warning;

  // The iteration's loss terms, and the PSNR of its mean squared error.
  template <class Scalar>
  void set_loss(const LossTerms<Scalar>& l) {
    loss = double(l.total), l1 = double(l.l1), ssim = double(l.ssim);
    psnr = l.mse > 0 ? -10.0 * std::log10(l.mse) : 100.0;
  }
};

// Milliseconds since the previous lap (or since construction): the breakdown of
// an iteration's wall time in TrainProgress.
class LapTimer {
 public:
  double operator()() {
    const auto now = clock::now();
    const double ms = std::chrono::duration<double, std::milli>(now - last_).count();
    last_ = now;
    return ms;
  }

 private:
  using clock = std::chrono::steady_clock;
  clock::time_point last_ = clock::now();
};

}  // namespace orbitforge

#pragma once
// Adaptive density control driven through training (densify.hpp has the
// operations): per iteration, the statistics, densify/prune with the optimizer's
// moments following their Gaussians, and opacity resets, when the schedule says.
#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <random>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/gaussian_adam.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// What one iteration's density control did (zero when it did not densify).
struct DensifyCounts {
  std::size_t cloned = 0, split = 0, pruned = 0, spared = 0;  // spared: kept by DensifyParams::min_gaussians
  std::size_t pruned_by_size = 0;  // of the pruned, those removed for their size only
};

// White background: 3DGS then also resets opacities once at densify_from.
inline bool white_background(const TrainParams& p) {
  return p.background[0] >= 1 && p.background[1] >= 1 && p.background[2] >= 1;
}

template <class Scalar>
class DensifyDriver {
 public:
  DensifyDriver() = default;
  // `schedule`: the densification schedule scaled to the budget (TrainSchedule);
  // `image_long_side`: the training frames' longer side in pixels (for
  // DensifyParams::max_screen_fraction, with a random background).
  DensifyDriver(const TrainParams& p, const DensifySchedule& schedule, int image_long_side)
      : enabled_(p.densify), params_(p.densify_params), schedule_(schedule), white_(white_background(p)) {
    if (p.random_background && params_.max_screen_fraction > 0 && image_long_side > 0)
      params_.max_screen_radius =
          std::max(params_.max_screen_radius, params_.max_screen_fraction * double(image_long_side));
  }

  // Iteration `it`, after the optimizer step: `ndc_grad_norm` and `radius` are
  // the iteration's render's, at image level `level` (radii are counted in
  // full-size pixels, since the screen-size prune compares them with a pixel
  // count). `adam` is the Gaussians' (gaussian_adam.hpp): densification gathers
  // every group's rows (new Gaussians start with zero moments, as 3DGS), an
  // opacity reset zeroes the opacities' moments (as 3DGS's reset_opacity).
  DensifyCounts step(int it, int level, const std::vector<Scalar>& ndc_grad_norm,
                     const std::vector<std::int32_t>& radius, GaussianScene<Scalar>& scene,
                     DensifyStats<Scalar>& stats, Adam<Scalar>& adam, Scalar extent, std::mt19937& rng) {
    DensifyCounts counts;
    if (!enabled_) return counts;
    const DensifySchedule& ds = schedule_;
    if (ds.collects_stats(it)) {
      if (level == 0) {
        stats.add_view(ndc_grad_norm, radius);
      } else {
        full_radius_.resize(radius.size());
        for (std::size_t i = 0; i < radius.size(); ++i) full_radius_[i] = radius[i] << level;
        stats.add_view(ndc_grad_norm, full_radius_);
      }
    }
    if (ds.densifies_at(it)) counts = densify(it, ds.size_prune_at(it), scene, stats, adam, extent, rng);
    if (ds.resets_opacity_at(it, white_)) {
      reset_opacity(scene, params_);
      auto& g = adam.group(kOpacityGroup);
      std::fill(g.m.begin(), g.m.end(), Scalar(0));
      std::fill(g.v.begin(), g.v.end(), Scalar(0));
    }
    return counts;
  }

 private:
  DensifyCounts densify(int it, bool size_prune, GaussianScene<Scalar>& scene, DensifyStats<Scalar>& stats,
                        Adam<Scalar>& adam, Scalar extent, std::mt19937& rng) const {
    const DensifyPlan plan = densify_and_prune(scene, stats, params_, extent, size_prune, rng);
    // Nothing left to train: say so rather than carry on rendering the background.
    ensure(scene.size() > 0, "Trainer: densification at iteration ", it,
           " pruned every Gaussian (schedule densifying every ", schedule_.densify_interval,
           " iterations, opacity reset every ", schedule_.opacity_reset_interval,
           "; DensifyParams::min_gaussians is 0, so nothing stopped it)");
    // New row order: kept old rows, then appended rows (zero moments).
    std::vector<std::int64_t> source;
    source.reserve(plan.new_size());
    for (std::size_t i = 0; i < plan.keep.size(); ++i)
      if (plan.keep[i]) source.push_back(std::int64_t(i));
    source.resize(plan.new_size(), -1);
    for (int g = 0; g < adam.group_count(); ++g) adam.gather(g, source);
    stats.reset(scene.size());
    return {plan.cloned, plan.split, plan.pruned, plan.spared, plan.pruned_by_size};
  }

  bool enabled_ = false;
  DensifyParams params_;
  DensifySchedule schedule_;
  bool white_ = false;
  std::vector<std::int32_t> full_radius_;  // workspace: radii in full-size pixels
};

}  // namespace orbitforge

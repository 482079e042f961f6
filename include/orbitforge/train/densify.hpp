#pragma once
// Adaptive density control of 3D Gaussian Splatting (Kerbl et al. 2023, section 5):
// screen-space gradient statistics, clone, split, prune and opacity reset, with the
// published defaults and schedule.
//
// Gradient units. 3DGS compares the mean, over the views in which a Gaussian was
// visible, of |dL/d mean2D| where mean2D is the projected mean in NDC, with the
// threshold 0.0002. Our renderer works in pixels: pixel = ((ndc + 1) * W - 1) / 2
// (and the same with H for y), so d pixel / d ndc = W / 2 and
//   dL/d ndc_x = dL/d pixel_x * W / 2,   dL/d ndc_y = dL/d pixel_y * H / 2
// (ndc_gradient_norm below). project_scene_vjp reports this norm per Gaussian as
// GaussianSceneGrad::screen_grad_ndc_norm, and DensifyStats accumulates exactly that
// quantity, so DensifyParams::grad_threshold is in the published NDC units.
//
// Usage per training iteration `it` (1-based, as in 3DGS):
//   if (schedule.collects_stats(it)) stats.add_view(grad.screen_grad_ndc_norm, fwd.radius);
//   if (schedule.densifies_at(it)) {
//     plan = densify_and_prune(scene, stats, params, extent, schedule.size_prune_at(it), rng);
//     remap_per_gaussian(adam_m, stride, plan, AppendFill::zero);   // every per-Gaussian array
//     stats.reset(scene.size());
//   }
//   if (schedule.resets_opacity_at(it, white_background)) reset_opacity(scene, params);
//
// After densify_and_prune the scene holds the kept Gaussians in their old order,
// followed by the appended ones in plan order (clones, then split children).
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <random>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/train/camera_extent.hpp"

namespace orbitforge {

// |dL/d ndc| from the pixel-space gradient of the projected mean, for an image of
// width x height pixels (see the header comment: factor W/2 on x, H/2 on y).
template <class Scalar>
Scalar ndc_gradient_norm(Scalar v_pixel_x, Scalar v_pixel_y, int width, int height) {
  const Scalar gx = v_pixel_x * Scalar(0.5) * Scalar(width);
  const Scalar gy = v_pixel_y * Scalar(0.5) * Scalar(height);
  return std::sqrt(gx * gx + gy * gy);
}

// Thresholds, published 3DGS defaults.
struct DensifyParams {
  double grad_threshold = 0.0002;   // mean |dL/d ndc| over visible views (NDC units)
  double percent_dense = 0.01;      // clone if max scale <= percent_dense * extent, else split
  double min_opacity = 0.005;       // prune below
  int split_count = 2;              // children per split Gaussian
  double split_scale_divisor = 1.6; // children scales = parent / (0.8 * split_count)
  double max_world_scale = 0.1;     // size prune: max scale > max_world_scale * extent
  double max_screen_radius = 20;    // size prune: largest 2D radius seen > this (pixels)
  // With a random background (the frames' borders disagree, so the model must
  // draw the backdrop too) and > 0: the screen-size limit is this fraction of
  // the frames' longer side when that is larger (DensifyDriver sets
  // max_screen_radius from it; small frames keep the pixel limit). 3DGS's 20 pixels, set for frames about 1,000 pixels wide with a normal
  // lens, prune the Gaussians that cover a backdrop faster than densification
  // makes them: with a long lens (Middlebury's 11 degrees at 320 pixels) they cap
  // a Gaussian at 0.4 % of the object, and deformable models fell to 1-5k
  // Gaussians. 0 keeps the pixel limit everywhere.
  double max_screen_fraction = 0.15;
  double reset_opacity = 0.01;      // opacity reset: opacity = min(opacity, this)
  // A Gaussian budget (0 = none, as 3DGS): a densification step adds at most as
  // many Gaussians as keep the count within it, taking the candidates with the
  // largest mean gradient first. Few training views can otherwise clone a scene
  // up to about one Gaussian per pixel (375k for six 320x240 photographs).
  std::size_t max_gaussians = 0;
  // A floor: pruning never leaves fewer Gaussians than this; the most opaque of
  // those it would remove stay. A schedule tuned on clean renders can otherwise
  // prune a real capture's model to nothing (opacities all driven under
  // min_opacity by a background the frames do not share), and training could
  // not recover from an empty scene.
  std::size_t min_gaussians = 256;
};

// When things happen, in 1-based iterations (3DGS train.py).
struct DensifySchedule {
  int densify_from = 500;            // densify at iterations > densify_from ...
  int densify_until = 15000;         // ... and < densify_until (stats collected before it)
  int densify_interval = 100;        // ... that are multiples of densify_interval
  int opacity_reset_interval = 3000; // reset at multiples of this, while < densify_until

  bool collects_stats(int it) const { return it < densify_until; }
  bool densifies_at(int it) const {
    return it < densify_until && it > densify_from && densify_interval > 0 && it % densify_interval == 0;
  }
  // 3DGS also resets once at densify_from when the background is white.
  bool resets_opacity_at(int it, bool white_background = false) const {
    if (it >= densify_until) return false;
    return (opacity_reset_interval > 0 && it % opacity_reset_interval == 0) ||
           (white_background && it == densify_from);
  }
  // World- and screen-size pruning is only active after the first opacity reset.
  bool size_prune_at(int it) const { return it > opacity_reset_interval; }
};

// The published schedule (for `reference_budget` = 30000 iterations) scaled to a
// budget of `iterations`: every field multiplied by iterations / reference_budget and
// rounded, intervals at least `min_interval` iterations. The number of densification
// steps and of opacity resets stays that of the published schedule.
inline DensifySchedule scale_schedule(int iterations, const DensifySchedule& published = {},
                                      int reference_budget = 30000, int min_interval = 1) {
  ensure(iterations > 0, "scale_schedule: iteration budget must be positive, got ", iterations);
  ensure(reference_budget > 0, "scale_schedule: reference budget must be positive, got ", reference_budget);
  const double f = double(iterations) / double(reference_budget);
  auto scaled = [&](int v) { return int(std::lround(double(v) * f)); };
  DensifySchedule s;
  s.densify_from = scaled(published.densify_from);
  s.densify_until = scaled(published.densify_until);
  s.densify_interval = std::max(std::max(1, min_interval), scaled(published.densify_interval));
  s.opacity_reset_interval = std::max(std::max(1, min_interval), scaled(published.opacity_reset_interval));
  return s;
}

// Floors that follow the data rather than the budget, for `pass_length` draws
// per pass over the training frames (FrameOrder; 0: unknown, no floor). A
// densification decides on the gradients gathered since the last one, so it
// waits for at least `interval_passes` of a pass (3DGS densifies every 100
// iterations on 100-300 images: a third of a pass to a whole one); an opacity
// reset waits for at least `reset_passes` passes, so that every frame is seen
// a few times while the opacities grow back before the next reset.
inline DensifySchedule schedule_floors_for_frames(DensifySchedule s, std::size_t pass_length, double interval_passes,
                                                  double reset_passes) {
  ensure(interval_passes >= 0 && reset_passes >= 0 && std::isfinite(interval_passes) && std::isfinite(reset_passes),
         "schedule: the passes per densification and per opacity reset must be finite and >= 0, got ",
         interval_passes, " and ", reset_passes);
  auto draws = [&](double passes) { return int(std::min(1e9, std::ceil(passes * double(pass_length)))); };
  s.densify_interval = std::max(s.densify_interval, draws(interval_passes));
  s.opacity_reset_interval = std::max(s.opacity_reset_interval, draws(reset_passes));
  return s;
}

// Per-Gaussian statistics gathered between densification steps.
template <class Scalar>
struct DensifyStats {
  std::vector<double> grad_sum;      // [N] sum of |dL/d ndc| over visible views
  std::vector<std::uint32_t> count;  // [N] views in which the Gaussian was visible
  std::vector<Scalar> max_radius;    // [N] largest 2D radius (pixels) seen

  std::size_t size() const { return count.size(); }
  void reset(std::size_t n) {
    grad_sum.assign(n, 0.0);
    count.assign(n, 0);
    max_radius.assign(n, Scalar(0));
  }

  // One rendered view: ndc_grad_norm[i] (see ndc_gradient_norm) and the projected
  // radius[i] (0 = not visible, its gradient is ignored).
  template <class RadiusT>
  void add_view(const std::vector<Scalar>& ndc_grad_norm, const std::vector<RadiusT>& radius) {
    ensure(ndc_grad_norm.size() == size() && radius.size() == size(), "DensifyStats::add_view: got ",
           ndc_grad_norm.size(), " gradients and ", radius.size(), " radii for ", size(),
           " Gaussians (call reset(n) after the scene changes size)");
    for (std::size_t i = 0; i < size(); ++i) {
      if (!(radius[i] > 0)) continue;
      const double g = double(ndc_grad_norm[i]);
      if (std::isfinite(g)) grad_sum[i] += g;
      count[i] += 1;
      max_radius[i] = std::max(max_radius[i], Scalar(radius[i]));
    }
  }

  // Mean gradient over visible views; 0 for a Gaussian never seen.
  double mean_grad(std::size_t i) const { return count[i] ? grad_sum[i] / double(count[i]) : 0.0; }
};

// What densify_and_prune did, so that every other per-Gaussian array (optimizer
// moments, per-Gaussian learning state, ...) can follow: the new scene is
//   [old[i] for i in 0..N_old-1 if keep[i]] + [appended_from[j] for j ...]
// where appended_from[j] is the old index each appended Gaussian derives from.
struct DensifyPlan {
  std::vector<std::uint8_t> keep;          // [N_old] 1 = kept
  std::vector<std::size_t> appended_from;  // [N_appended] source index in the old scene
  // Gaussians cloned, split (parents, removed), and pruned among the others (old
  // ones); spared: old ones the pruning rules removed but the floor kept;
  // pruned_by_size: of the pruned, those opaque enough to stay but too large
  // (on screen or in the world).
  std::size_t cloned = 0, split = 0, pruned = 0, spared = 0, pruned_by_size = 0;

  std::size_t new_size() const {
    std::size_t k = 0;
    for (auto v : keep) k += v ? 1 : 0;
    return k + appended_from.size();
  }
};

enum class AppendFill { zero, copy_source };

// Applies a plan to an array holding `stride` values per Gaussian. New entries are
// zero (what 3DGS does for Adam moments) or a copy of their source.
template <class T>
void remap_per_gaussian(std::vector<T>& values, std::size_t stride, const DensifyPlan& plan,
                        AppendFill fill = AppendFill::zero) {
  const std::size_t n_old = plan.keep.size();
  ensure(values.size() == n_old * stride, "remap_per_gaussian: array has ", values.size(), " values, expected ",
         n_old * stride, " (", n_old, " Gaussians x ", stride, ")");
  std::vector<T> out;
  out.reserve(plan.new_size() * stride);
  for (std::size_t i = 0; i < n_old; ++i)
    if (plan.keep[i]) out.insert(out.end(), values.begin() + i * stride, values.begin() + (i + 1) * stride);
  for (std::size_t src : plan.appended_from) {
    if (fill == AppendFill::copy_source)
      out.insert(out.end(), values.begin() + src * stride, values.begin() + (src + 1) * stride);
    else
      out.insert(out.end(), stride, T(0));
  }
  values.swap(out);
}

namespace densify_detail {
// v rotated by the normalised quaternion q = (w, x, y, z).
template <class Scalar>
void rotate(const Scalar* q, const Scalar v[3], Scalar out[3]) {
  const Scalar n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  const Scalar w = q[0] / n, x = q[1] / n, y = q[2] / n, z = q[3] / n;
  const Scalar R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                          {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                          {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
  for (int r = 0; r < 3; ++r) out[r] = R[r][0] * v[0] + R[r][1] * v[1] + R[r][2] * v[2];
}

template <class Scalar>
Scalar max_scale(const GaussianScene<Scalar>& s, std::size_t i) {
  return std::exp(std::max({s.log_scales[3 * i], s.log_scales[3 * i + 1], s.log_scales[3 * i + 2]}));
}
}  // namespace densify_detail

// One densification step of 3DGS (densify_and_prune):
//   mean gradient g_i = stats.mean_grad(i) (0 if never visible);
//   clone  g_i >= grad_threshold and max scale <= percent_dense * extent: an exact copy;
//   split  g_i >= grad_threshold and max scale >  percent_dense * extent: split_count
//          children at mean + R(q) * (s * n), n ~ N(0, I), scales s / split_scale_divisor,
//          rotation, opacity and SH copied; the parent is removed;
//   prune  (old Gaussians and the new ones) opacity < min_opacity, and when size_prune:
//          largest 2D radius > max_screen_radius or max scale > max_world_scale * extent
//          (new Gaussians have no 2D radius yet).
// The scene is rewritten in place; returns the plan. Reset `stats` afterwards.
template <class Scalar>
DensifyPlan densify_and_prune(GaussianScene<Scalar>& scene, const DensifyStats<Scalar>& stats,
                              const DensifyParams& params, Scalar extent, bool size_prune, std::mt19937& rng) {
  using densify_detail::max_scale;
  scene.check_consistent();
  const std::size_t n = scene.size();
  ensure(stats.size() == n, "densify_and_prune: statistics cover ", stats.size(), " Gaussians, scene has ", n);
  ensure(extent > 0 && std::isfinite(double(extent)), "densify_and_prune: scene extent must be positive, got ",
         extent);
  ensure(params.split_count >= 1 && params.split_scale_divisor > 0,
         "densify_and_prune: split_count must be >= 1 and split_scale_divisor > 0");
  const int k3 = 3 * scene.sh_coefficients();
  const Scalar dense_limit = Scalar(params.percent_dense) * extent;
  const Scalar world_limit = Scalar(params.max_world_scale) * extent;
  const Scalar logit_min = logit(Scalar(params.min_opacity));
  const Scalar log_div = std::log(Scalar(params.split_scale_divisor));

  // opacity < min_opacity  <=>  logit < logit(min_opacity) (sigmoid is increasing).
  auto pruned_by_opacity = [&](std::size_t i) { return !(scene.opacity_logits[i] >= logit_min); };

  DensifyPlan plan;
  plan.keep.assign(n, 1);
  std::vector<std::size_t> clones, splits;
  std::vector<std::size_t> candidates;
  for (std::size_t i = 0; i < n; ++i)
    if (stats.mean_grad(i) >= params.grad_threshold) candidates.push_back(i);
  if (params.max_gaussians > 0) {
    // Largest gradients first (ties by index, so the choice is deterministic),
    // while the net growth stays within the budget.
    std::stable_sort(candidates.begin(), candidates.end(),
                     [&](std::size_t a, std::size_t b) { return stats.mean_grad(a) > stats.mean_grad(b); });
    std::size_t room = params.max_gaussians > n ? params.max_gaussians - n : 0, taken = 0;
    for (std::size_t i : candidates) {
      const std::size_t grows = max_scale(scene, i) <= dense_limit ? 1 : std::size_t(params.split_count - 1);
      if (grows > room) break;
      room -= grows;
      ++taken;
    }
    candidates.resize(taken);
    std::sort(candidates.begin(), candidates.end());
  }
  for (std::size_t i : candidates) (max_scale(scene, i) <= dense_limit ? clones : splits).push_back(i);
  plan.cloned = clones.size();
  plan.split = splits.size();

  // New Gaussians, built in a side scene: clones, then split children.
  GaussianScene<Scalar> add;
  add.resize(clones.size() + splits.size() * std::size_t(params.split_count), scene.sh_degree);
  std::vector<std::size_t> add_from;
  add_from.reserve(add.size());
  auto copy_into = [&](std::size_t dst, std::size_t src) {
    std::copy_n(&scene.means[3 * src], 3, &add.means[3 * dst]);
    std::copy_n(&scene.rotations[4 * src], 4, &add.rotations[4 * dst]);
    std::copy_n(&scene.log_scales[3 * src], 3, &add.log_scales[3 * dst]);
    add.opacity_logits[dst] = scene.opacity_logits[src];
    std::copy_n(&scene.sh[std::size_t(k3) * src], k3, &add.sh[std::size_t(k3) * dst]);
    add_from.push_back(src);
  };
  for (std::size_t i : clones) copy_into(add_from.size(), i);
  std::normal_distribution<double> normal(0.0, 1.0);
  for (std::size_t i : splits) {
    plan.keep[i] = 0;
    for (int c = 0; c < params.split_count; ++c) {
      const std::size_t d = add_from.size();
      copy_into(d, i);
      Scalar local[3], world[3];
      for (int a = 0; a < 3; ++a) local[a] = std::exp(scene.log_scales[3 * i + a]) * Scalar(normal(rng));
      densify_detail::rotate(&scene.rotations[4 * i], local, world);
      for (int a = 0; a < 3; ++a) {
        add.means[3 * d + a] += world[a];
        add.log_scales[3 * d + a] -= log_div;
      }
    }
  }

  // Prune old and new.
  std::vector<std::size_t> pruned_old;
  std::vector<std::uint8_t> too_large(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    if (!plan.keep[i]) continue;
    bool prune = pruned_by_opacity(i);
    if (size_prune && !prune) {
      prune = double(stats.max_radius[i]) > params.max_screen_radius || max_scale(scene, i) > world_limit;
      too_large[i] = prune ? 1 : 0;
    }
    if (prune) {
      plan.keep[i] = 0;
      pruned_old.push_back(i);
    }
  }
  std::vector<std::uint8_t> add_keep(add.size(), 1);
  std::size_t kept = 0;
  for (std::size_t j = 0; j < add.size(); ++j) {
    bool prune = !(add.opacity_logits[j] >= logit_min);
    if (size_prune) prune = prune || max_scale(add, j) > world_limit;
    add_keep[j] = prune ? 0 : 1;
    if (!prune) plan.appended_from.push_back(add_from[j]);
    kept += add_keep[j];
  }
  for (auto k : plan.keep) kept += k;
  // The floor: spare the most opaque of the pruned (ties by index, so the choice
  // is deterministic) until the scene holds min_gaussians again.
  if (kept < params.min_gaussians && !pruned_old.empty()) {
    std::stable_sort(pruned_old.begin(), pruned_old.end(), [&](std::size_t a, std::size_t b) {
      return scene.opacity_logits[a] > scene.opacity_logits[b];
    });
    for (std::size_t i : pruned_old) {
      if (kept >= params.min_gaussians) break;
      plan.keep[i] = 1;
      ++plan.spared;
      ++kept;
    }
  }
  plan.pruned = pruned_old.size() - plan.spared;
  for (std::size_t i : pruned_old) plan.pruned_by_size += plan.keep[i] ? 0 : too_large[i];

  // Rewrite the scene: kept old ones in order, then the kept new ones.
  auto rebuild = [&](std::vector<Scalar>& dst, const std::vector<Scalar>& extra, std::size_t stride) {
    std::size_t w = 0;
    for (std::size_t i = 0; i < n; ++i)
      if (plan.keep[i]) {
        if (w != i) std::copy_n(&dst[i * stride], stride, &dst[w * stride]);
        ++w;
      }
    dst.resize(w * stride);
    for (std::size_t j = 0; j < add_keep.size(); ++j)
      if (add_keep[j]) dst.insert(dst.end(), extra.begin() + j * stride, extra.begin() + (j + 1) * stride);
  };
  rebuild(scene.means, add.means, 3);
  rebuild(scene.rotations, add.rotations, 4);
  rebuild(scene.log_scales, add.log_scales, 3);
  rebuild(scene.opacity_logits, add.opacity_logits, 1);
  rebuild(scene.sh, add.sh, std::size_t(k3));
  scene.check_consistent();
  return plan;
}

// 3DGS opacity reset: opacity = min(opacity, params.reset_opacity), applied through the
// logit. (3DGS also zeroes the optimizer moments of the opacity logits at this point.)
template <class Scalar>
void reset_opacity(GaussianScene<Scalar>& scene, const DensifyParams& params = {}) {
  ensure(params.reset_opacity > 0 && params.reset_opacity < 1, "reset_opacity: value must be in (0, 1), got ",
         params.reset_opacity);
  const Scalar cap = logit(Scalar(params.reset_opacity));
  for (auto& l : scene.opacity_logits) l = std::min(l, cap);
}

}  // namespace orbitforge

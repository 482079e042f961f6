#pragma once
// The still-scene check (TrainParams::still_check_iterations): some time after
// the deformation warm-up, bake the field (MedianGS) and compare how well the
// bake and the deformed model fit training frames. A field that gains too little
// over its bake is not worth its cost: the bake replaces the scene and training
// goes on static.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/train_frame.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

inline void check_still_params(const TrainParams& p) {
  ensure(p.still_check_iterations >= 0 && std::isfinite(p.still_gain_db) && p.still_bake_samples >= 2,
         "Trainer: still_check_iterations must be >= 0, still_gain_db finite and still_bake_samples >= 2");
}

// The iteration at whose end the check runs (0: it does not), given the
// deformation warm-up (TrainSchedule::warmup).
inline int still_check_iteration(const TrainParams& p, int warmup) {
  return p.deformable && p.still_check_iterations > 0 ? warmup + p.still_check_iterations : 0;
}

// PSNR of a render (clamped to [0, 1]) against a frame.
template <class Scalar>
double fit_psnr(const Image<Scalar>& render, const Image<Scalar>& frame) {
  double se = 0;
  for (std::size_t i = 0; i < render.data.size(); ++i) {
    const double d = std::min(1.0, std::max(0.0, double(render.data[i]))) - double(frame.data[i]);
    se += d * d;
  }
  const double mse = se / double(std::max<std::size_t>(1, render.data.size()));
  return mse > 0 ? -10.0 * std::log10(mse) : 100.0;
}

template <class Scalar>
struct StillVerdict {
  GaussianScene<Scalar> baked;  // the field baked into the scene (same size and row order)
  double gain_db = 0;           // the deformed model's mean PSNR over the bake's
  bool bake = false;            // gain_db < still_gain_db: keep the bake, train static
};

// The check on up to 8 training frames spread over `frames`. render_deformed(camera,
// time) renders the deformed model (an image valid until `renderer` renders again).
template <class Scalar, class RenderDeformed>
StillVerdict<Scalar> check_still_scene(const GaussianScene<Scalar>& scene, const DeformationField<Scalar>& field,
                                       const std::vector<TrainFrame<Scalar>>& frames, Renderer<Scalar>& renderer,
                                       const TrainParams& p, RenderDeformed&& render_deformed) {
  MedianBakeParams mp;
  mp.samples = p.still_bake_samples;
  mp.threads = p.threads;
  StillVerdict<Scalar> v;
  v.baked = bake_median(scene, FieldDeformation<Scalar>(field, p.threads), mp);
  const std::size_t k = std::min<std::size_t>(8, frames.size());
  for (std::size_t j = 0; j < k; ++j) {
    const TrainFrame<Scalar>& f = frames[j * frames.size() / k];
    const double deformed = fit_psnr(render_deformed(f.camera, f.time), f.image);
    const double baked = fit_psnr(renderer.render(SceneView<Scalar>(v.baked), f.camera).color, f.image);
    v.gain_db += (deformed - baked) / double(k);
  }
  v.bake = v.gain_db < p.still_gain_db;
  return v;
}

}  // namespace orbitforge

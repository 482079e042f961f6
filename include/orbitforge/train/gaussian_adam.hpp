#pragma once
// The Gaussians' optimizer: one Adam group per parameter array, in a fixed order
// (the checkpoint's), and the step over all of them. SH has two learning rates,
// DC (feature_lr) and the higher bands (feature_lr / sh_rest_divisor), on the
// interleaved [N][K][3] layout, with the rest's moments stored at the maximum
// degree's width so raising the degree needs no remap.
#include <algorithm>
#include <cstddef>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// Group ids in the Gaussians' Adam (the order make_gaussian_adam adds them).
enum GaussianAdamGroup : int {
  kMeansGroup = 0,
  kRotationsGroup,
  kScalesGroup,
  kOpacityGroup,
  kShDcGroup,
  kShRestGroup,
  kGaussianGroupCount
};

// The SH rest group's row width: every coefficient above DC at max_sh_degree (>= 1).
inline int sh_rest_width(int max_sh_degree) { return std::max(1, 3 * (sh_coefficient_count(max_sh_degree) - 1)); }

// The optimizer of `n` Gaussians with p's learning rates (the positions' is set
// per iteration, schedules.hpp's position_lr).
template <class Scalar>
Adam<Scalar> make_gaussian_adam(const TrainParams& p, std::size_t n) {
  Adam<Scalar> adam(p.adam);
  adam.add_group("means", n, 3, Scalar(0));
  adam.add_group("rotations", n, 4, Scalar(p.rotation_lr));
  adam.add_group("log_scales", n, 3, Scalar(p.scaling_lr));
  adam.add_group("opacity_logits", n, 1, Scalar(p.opacity_lr));
  adam.add_group("sh_dc", n, 3, Scalar(p.feature_lr));
  adam.add_group("sh_rest", n, sh_rest_width(p.max_sh_degree), Scalar(p.feature_lr / p.sh_rest_divisor));
  return adam;
}

namespace gaussian_adam_detail {

template <class Scalar>
void step_group(Adam<Scalar>& adam, int id, std::vector<Scalar>& params, const std::vector<Scalar>& grad,
                int threads) {
  auto& g = adam.group(id);
  ensure(params.size() == g.size() && grad.size() == g.size(), "Trainer: optimizer group '", g.name, "' has ",
         g.size(), " values, parameters ", params.size(), ", gradients ", grad.size());
  Adam<Scalar>::update(g, adam.params(), params.data(), grad.data(), params.size(), threads);
}

// Same update as Adam::update, DC and rest at their own rates.
template <class Scalar>
void step_sh(Adam<Scalar>& adam, GaussianScene<Scalar>& scene, const std::vector<Scalar>& grad, int threads) {
  auto& dc = adam.group(kShDcGroup);
  auto& rest = adam.group(kShRestGroup);
  const std::size_t n = scene.size();
  const int k3 = 3 * scene.sh_coefficients();
  ensure(grad.size() == n * std::size_t(k3), "Trainer: SH gradient has ", grad.size(), " values, expected ",
         n * std::size_t(k3));
  const std::size_t rw = std::size_t(rest.row_width);
  ++dc.step;
  ++rest.step;
  const AdamStep<Scalar> cd = AdamStep<Scalar>::of(adam.params(), double(dc.lr), dc.step);
  const AdamStep<Scalar> cr = AdamStep<Scalar>::of(adam.params(), double(rest.lr), rest.step);
  Scalar* sh = scene.sh.data();
  const std::size_t per_block = std::max<std::size_t>(1, kAdamBlock / std::size_t(k3));
  parallel_for((n + per_block - 1) / per_block, threads, [&](std::size_t b, int) {
    for (std::size_t i = b * per_block, end = std::min(n, i + per_block); i < end; ++i) {
      Scalar* p = sh + i * std::size_t(k3);
      const Scalar* g = grad.data() + i * std::size_t(k3);
      adam_apply(cd, p, g, dc.m.data() + 3 * i, dc.v.data() + 3 * i, 3);
      if (k3 > 3) adam_apply(cr, p + 3, g + 3, rest.m.data() + i * rw, rest.v.data() + i * rw, std::size_t(k3 - 3));
    }
  });
}

}  // namespace gaussian_adam_detail

// One Adam step of every Gaussian parameter array on its gradient.
template <class Scalar>
void step_gaussians(Adam<Scalar>& adam, GaussianScene<Scalar>& scene, const GaussianSceneGrad<Scalar>& grad,
                    int threads) {
  using namespace gaussian_adam_detail;
  step_group(adam, kMeansGroup, scene.means, grad.means, threads);
  step_group(adam, kRotationsGroup, scene.rotations, grad.rotations, threads);
  step_group(adam, kScalesGroup, scene.log_scales, grad.scales, threads);
  step_group(adam, kOpacityGroup, scene.opacity_logits, grad.opacity_logits, threads);
  step_sh(adam, scene, grad.sh, threads);
}

}  // namespace orbitforge

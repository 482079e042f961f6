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

// adam_apply over `rows` rows of `width` values (at most 1024) whose rows lie
// the given strides apart. Strided operands are gathered into contiguous
// scratch, a few rows at a time, so that the update runs on whole vectors:
// SH's DC and rest rows are 3 and 45 values, and updating each row on its own
// sent every row's ragged end through adam_apply's zero-padded copy
// (docs/benchmarks.md, "The Gaussians' Adam step"). Each value gets the same
// arithmetic wherever it sits, so the results do not change.
template <class Scalar>
void adam_apply_rows(const AdamStep<Scalar>& c, std::size_t rows, std::size_t width, Scalar* p, std::size_t p_stride,
                     const Scalar* g, std::size_t g_stride, Scalar* m, Scalar* v, std::size_t mv_stride) {
  constexpr std::size_t kScratch = 1024;
  alignas(64) Scalar sp[kScratch], sg[kScratch], sm[kScratch], sv[kScratch];
  ensure(width >= 1 && width <= kScratch, "adam_apply_rows: row width ", width, " is not in 1..", kScratch);
  const std::size_t chunk = kScratch / width;
  const bool gather_p = p_stride != width, gather_g = g_stride != width, gather_mv = mv_stride != width;
  for (std::size_t r0 = 0; r0 < rows; r0 += chunk) {
    const std::size_t nr = std::min(chunk, rows - r0);
    Scalar* cp = gather_p ? sp : p + r0 * width;
    const Scalar* cg = gather_g ? sg : g + r0 * width;
    Scalar* cm = gather_mv ? sm : m + r0 * width;
    Scalar* cv = gather_mv ? sv : v + r0 * width;
    // Plain loops, not std::copy_n: a library call per 3-value row cost more than the copy.
    auto copy_rows = [&](const Scalar* from, std::size_t from_stride, Scalar* to, std::size_t to_stride) {
      for (std::size_t r = 0; r < nr; ++r)
        for (std::size_t k = 0; k < width; ++k) to[r * to_stride + k] = from[r * from_stride + k];
    };
    if (gather_p) copy_rows(p + r0 * p_stride, p_stride, sp, width);
    if (gather_g) copy_rows(g + r0 * g_stride, g_stride, sg, width);
    if (gather_mv) {
      copy_rows(m + r0 * mv_stride, mv_stride, sm, width);
      copy_rows(v + r0 * mv_stride, mv_stride, sv, width);
    }
    adam_apply(c, cp, cg, cm, cv, nr * width);
    if (gather_p) copy_rows(sp, width, p + r0 * p_stride, p_stride);
    if (gather_mv) {
      copy_rows(sm, width, m + r0 * mv_stride, mv_stride);
      copy_rows(sv, width, v + r0 * mv_stride, mv_stride);
    }
  }
}

// Same update as Adam::update, DC and rest at their own rates.
template <class Scalar>
void step_sh(Adam<Scalar>& adam, GaussianScene<Scalar>& scene, const std::vector<Scalar>& grad, int threads) {
  auto& dc = adam.group(kShDcGroup);
  auto& rest = adam.group(kShRestGroup);
  const std::size_t n = scene.size();
  const std::size_t k3 = 3 * std::size_t(scene.sh_coefficients());
  ensure(grad.size() == n * k3, "Trainer: SH gradient has ", grad.size(), " values, expected ", n * k3);
  const std::size_t rw = std::size_t(rest.row_width);
  ++dc.step;
  ++rest.step;
  const AdamStep<Scalar> cd = AdamStep<Scalar>::of(adam.params(), double(dc.lr), dc.step);
  const AdamStep<Scalar> cr = AdamStep<Scalar>::of(adam.params(), double(rest.lr), rest.step);
  Scalar* sh = scene.sh.data();
  const std::size_t per_block = std::max<std::size_t>(1, kAdamBlock / k3);
  parallel_for((n + per_block - 1) / per_block, threads, [&](std::size_t b, int) {
    const std::size_t i0 = b * per_block, rows = std::min(n, i0 + per_block) - i0;
    Scalar* p = sh + i0 * k3;
    const Scalar* g = grad.data() + i0 * k3;
    adam_apply_rows(cd, rows, 3, p, k3, g, k3, dc.m.data() + 3 * i0, dc.v.data() + 3 * i0, 3);
    if (k3 > 3)
      adam_apply_rows(cr, rows, k3 - 3, p + 3, k3, g + 3, k3, rest.m.data() + i0 * rw, rest.v.data() + i0 * rw, rw);
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

#pragma once
// Photometric training losses on interleaved images (core/image.hpp), values in [0, 1]:
//
//   l1_loss        mean |pred - target| over all pixels and channels
//   ssim           structural similarity, mean over pixels and channels
//   combined_loss  (1 - lambda) L1 + lambda (1 - SSIM), lambda = 0.2 (3DGS)
//
// each with its vector-Jacobian product with respect to `pred` (the rendered image);
// `target` is a constant. SSIM itself (window, constants, border rule,
// workspace) is image/ssim.hpp.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/image/ssim.hpp"

namespace orbitforge {

// The components of combined_loss, for progress reports.
template <class Scalar>
struct LossTerms {
  Scalar total = 0;  // (1 - lambda) l1 + lambda (1 - ssim)
  Scalar l1 = 0;
  Scalar ssim = 0;
  double mse = 0;    // mean squared error (for PSNR; no gradient)
};

namespace losses_detail {

using ssim_detail::check_images;
using ssim_detail::sum_in_order;

// Sums of |a - b| and (a - b)^2 over n values, vectorised explicitly (GCC keeps
// float reductions scalar, and these run on every training step).
template <class Scalar>
void error_sums(const Scalar* a, const Scalar* b, std::size_t n, double& abs_sum, double& sq_sum) {
  using B = simd::native_batch<Scalar>;
  B sa(Scalar(0)), sq(Scalar(0));
  std::size_t i = 0;
  for (; i + B::size <= n; i += B::size) {
    const B d = B::load_unaligned(a + i) - B::load_unaligned(b + i);
    sa = sa + simd::abs(d);
    sq = simd::fma(d, d, sq);
  }
  alignas(64) Scalar la[B::size], lq[B::size];
  sa.store_unaligned(la);
  sq.store_unaligned(lq);
  Scalar ta = 0, tq = 0;
  for (std::size_t l = 0; l < B::size; ++l) {
    ta += la[l];
    tq += lq[l];
  }
  for (; i < n; ++i) {
    const Scalar d = a[i] - b[i];
    ta += std::abs(d);
    tq += d * d;
  }
  abs_sum = double(ta);
  sq_sum = double(tq);
}

// v += g sign(a - b) (0 where a == b) over n values, branch-free.
template <class Scalar>
void add_sign_gradient(const Scalar* a, const Scalar* b, Scalar* v, std::size_t n, Scalar g) {
  using B = simd::native_batch<Scalar>;
  const B zero(Scalar(0)), pos(g), neg(-g);
  std::size_t i = 0;
  for (; i + B::size <= n; i += B::size) {
    const B d = B::load_unaligned(a + i) - B::load_unaligned(b + i);
    const B s = simd::select(d > zero, pos, simd::select(d < zero, neg, zero));
    (B::load_unaligned(v + i) + s).store_unaligned(v + i);
  }
  for (; i < n; ++i) {
    const Scalar d = a[i] - b[i];
    v[i] += d > 0 ? g : (d < 0 ? -g : Scalar(0));
  }
}

}  // namespace losses_detail

// ---------------------------------------------------------------- L1

// inputs: pred, target [H][W][C]. Returns mean |pred - target|.
template <class Scalar>
Scalar l1_loss(const Image<Scalar>& pred, const Image<Scalar>& target) {
  losses_detail::check_images("l1_loss", pred, target);
  const std::size_t n = pred.data.size();
  const Scalar* a = pred.data.data();
  const Scalar* b = target.data.data();
  // Sum in blocks of Scalar, blocks added in double: fast and accurate enough for float.
  double total = 0;
  constexpr std::size_t block = 4096;
  for (std::size_t s = 0; s < n; s += block) {
    const std::size_t e = std::min(n, s + block);
    Scalar part = 0;
    for (std::size_t i = s; i < e; ++i) part += std::abs(a[i] - b[i]);
    total += double(part);
  }
  return Scalar(total / double(n));
}

// inputs:      pred, target [H][W][C]
// grad output: v_l1 (scalar)
// grad input:  v_pred [H][W][C] (resized; overwritten, or added to when accumulate)
// d|p - t|/dp is taken as sign(p - t), and 0 where p == t.
template <class Scalar>
void l1_loss_vjp(const Image<Scalar>& pred, const Image<Scalar>& target, Scalar v_l1, Image<Scalar>& v_pred,
                 bool accumulate = false) {
  losses_detail::check_images("l1_loss_vjp", pred, target);
  if (accumulate) {
    ensure(v_pred.same_shape(pred) && v_pred.data.size() == pred.data.size(),
           "l1_loss_vjp: accumulate into a gradient image of a different shape");
  } else if (!v_pred.same_shape(pred) || v_pred.data.size() != pred.data.size()) {
    v_pred = Image<Scalar>(pred.width, pred.height, pred.channels);
  }
  const std::size_t n = pred.data.size();
  const Scalar g = v_l1 / Scalar(n);
  const Scalar* a = pred.data.data();
  const Scalar* b = target.data.data();
  Scalar* v = v_pred.data.data();
  for (std::size_t i = 0; i < n; ++i) {
    const Scalar d = a[i] - b[i];
    const Scalar s = d > 0 ? g : (d < 0 ? -g : Scalar(0));
    v[i] = accumulate ? v[i] + s : s;
  }
}

// ---------------------------------------------------------------- combined

struct CombinedLossParams {
  double lambda = 0.2;  // weight of (1 - SSIM); 3DGS uses 0.2
  SsimParams ssim;
};

// inputs:     pred, target [H][W][C]
// grad input: v_pred [H][W][C] = d total / d pred (resized, overwritten)
// Returns total = (1 - lambda) L1 + lambda (1 - SSIM) and its two terms.
// Throws when the loss is not finite (a NaN or infinity in either image);
// v_pred then holds no gradient.
template <class Scalar>
LossTerms<Scalar> combined_loss(const Image<Scalar>& pred, const Image<Scalar>& target, Image<Scalar>& v_pred,
                                SsimWorkspace<Scalar>& ws, const CombinedLossParams& params = {},
                                int threads = 0) {
  using namespace losses_detail;
  ensure(params.lambda >= 0 && params.lambda <= 1, "combined_loss: lambda must be in [0, 1], got ",
         params.lambda);
  check_images("combined_loss", pred, target);
  threads = resolve_threads(threads);
  const Scalar lambda = Scalar(params.lambda);
  const int H = pred.height;
  const std::size_t row = std::size_t(pred.width) * std::size_t(pred.channels);
  const std::size_t n = row * std::size_t(H);
  // SSIM and its gradient in one pass over the rows (image/ssim.hpp), with the
  // L1 term's sums and gradient done per row as that pass finishes the row (its
  // pixels still in cache) instead of in passes of their own; rows are added in
  // order, so the sums are the same for any thread count.
  const auto at = [&](int y) { return std::size_t(y) * row; };
  ws.abs_rows.resize(std::size_t(H));
  ws.sq_rows.resize(std::size_t(H));
  const Scalar g = (1 - lambda) / Scalar(n);  // l1_loss_vjp's rule, times 1 - lambda
  LossTerms<Scalar> out;
  out.ssim = ssim_and_vjp_with(
      pred, target, -lambda, ws, v_pred, params.ssim, threads,
      [&](int y) {
        error_sums(pred.data.data() + at(y), target.data.data() + at(y), row, ws.abs_rows[std::size_t(y)],
                   ws.sq_rows[std::size_t(y)]);
      },
      [&](int y) {
        add_sign_gradient(pred.data.data() + at(y), target.data.data() + at(y), v_pred.data.data() + at(y), row, g);
      });
  out.l1 = Scalar(sum_in_order(ws.abs_rows, std::size_t(H)) / double(n));
  out.mse = sum_in_order(ws.sq_rows, std::size_t(H)) / double(n);
  out.total = (1 - lambda) * out.l1 + lambda * (1 - out.ssim);
  ensure(std::isfinite(double(out.total)), "combined_loss: loss is not finite (L1 ", out.l1, ", SSIM ",
         out.ssim, "): the prediction or the target holds NaN or infinity");
  return out;
}

// Same, with lambda given directly.
template <class Scalar>
LossTerms<Scalar> combined_loss(const Image<Scalar>& pred, const Image<Scalar>& target, Image<Scalar>& v_pred,
                                SsimWorkspace<Scalar>& ws, double lambda, int threads = 0) {
  CombinedLossParams p;
  p.lambda = lambda;
  return combined_loss(pred, target, v_pred, ws, p, threads);
}

}  // namespace orbitforge

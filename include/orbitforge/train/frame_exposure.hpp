#pragma once
// Per-frame exposure and white balance, for photographs whose camera changed its
// exposure or colour balance between shots. Training frame f's render c is mapped
// by an affine colour transform before the loss,
//
//   c' = clip(A_f c + b_f, 0, 1)   (A_f 3x3, b_f 3; stored as 12 values, A row-major, then b)
//
// so that a frame shot brighter or warmer than the others does not pull the
// scene's colours, or grow floaters, to explain it. The transforms are learned
// with the scene and are not part of it: every other render (evaluation, a bake,
// held-out views, the still check) shows the scene's own colours.
//
// A_f is diagonal: a gain per channel (exposure scales all three, white balance
// each) and an offset (black level). Only these six values learn; the
// off-diagonal entries stay zero, since a full colour matrix per frame also fitted
// the view-dependent colour that sparse photographs leave unconstrained (on the
// dino ring it cost 1.1 dB on withheld photographs of unchanged exposure).
//
// A common change of every A_f and b_f could be absorbed by the scene's colours,
// so after each step the transforms are recentred: their mean over the frames
// stays the identity, and the scene keeps the frames' average exposure (with one
// frame, nothing moves). A step updates the drawn frame's transform only (its
// Adam moments; the other frames' stay as they are), with the group's step count
// in the bias correction.
#include <algorithm>
#include <cstddef>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/nn/adam.hpp"
#include "orbitforge/train/losses.hpp"

namespace orbitforge {

template <class Scalar>
class FrameExposure {
 public:
  static constexpr int kWidth = 12;  // A_f (row-major), then b_f

  FrameExposure() = default;  // off: loss_and_step() is combined_loss on the render itself
  // `frames` identity transforms, learned at rate lr.
  FrameExposure(std::size_t frames, const AdamParams& adam, double lr) : adam_(adam) {
    ensure(frames > 0, "FrameExposure: no frames");
    ensure(lr > 0, "FrameExposure: the learning rate must be positive, got ", lr);
    transforms_.assign(frames * kWidth, Scalar(0));
    for (std::size_t f = 0; f < frames; ++f)
      for (int k = 0; k < 3; ++k) transforms_[f * kWidth + std::size_t(4 * k)] = Scalar(1);
    adam_.add_group("exposure", frames, kWidth, Scalar(lr));
  }
  // From a checkpoint's state (checked against each other).
  FrameExposure(std::vector<Scalar> transforms, Adam<Scalar> adam)
      : transforms_(std::move(transforms)), adam_(std::move(adam)) {
    ensure(transforms_.size() % kWidth == 0, "FrameExposure: ", transforms_.size(),
           " values are not whole transforms of ", kWidth);
    ensure(adam_.group_count() == 1 && adam_.group(0).rows == frames() && adam_.group(0).row_width == kWidth,
           "FrameExposure: the optimizer state does not match ", frames(), " transforms");
  }

  bool enabled() const { return !transforms_.empty(); }
  std::size_t frames() const { return transforms_.size() / kWidth; }
  const std::vector<Scalar>& transforms() const { return transforms_; }
  const Scalar* transform(std::size_t f) const { return transforms_.data() + f * kWidth; }
  const Adam<Scalar>& optimizer() const { return adam_; }

  // out = A_f c + b_f at every pixel of a 3-channel image (not clipped).
  void apply(std::size_t f, const Image<Scalar>& render, Image<Scalar>& out, int threads = 1) const {
    check(f, render, "apply");
    const Scalar* t = transform(f);
    if (!out.same_shape(render)) out = Image<Scalar>(render.width, render.height, 3);
    const std::size_t row = std::size_t(render.width) * 3;
    parallel_for(std::size_t(render.height), threads, [&](std::size_t y, int) {
      const Scalar* c = render.data.data() + y * row;
      Scalar* o = out.data.data() + y * row;
      for (std::size_t p = 0; p < row; p += 3)
        for (int i = 0; i < 3; ++i)
          o[p + std::size_t(i)] = t[3 * i] * c[p] + t[3 * i + 1] * c[p + 1] + t[3 * i + 2] * c[p + 2] + t[9 + i];
    });
  }

  // The vector-Jacobian product of apply: v_render = A_f^T v_out, and in v_transform
  // (12 values) d loss / d (A_f, b_f). Rows are summed in order: the same for any
  // thread count.
  void apply_vjp(std::size_t f, const Image<Scalar>& render, const Image<Scalar>& v_out, Image<Scalar>& v_render,
                 Scalar v_transform[kWidth], int threads = 1) {
    check(f, render, "apply_vjp");
    ensure(v_out.same_shape(render), "FrameExposure::apply_vjp: the gradient's shape differs from the render's");
    const Scalar* t = transform(f);
    if (!v_render.same_shape(render)) v_render = Image<Scalar>(render.width, render.height, 3);
    const std::size_t H = std::size_t(render.height), row = std::size_t(render.width) * 3;
    row_sums_.assign(H * kWidth, 0.0);
    parallel_for(H, threads, [&](std::size_t y, int) {
      const Scalar* c = render.data.data() + y * row;
      const Scalar* g = v_out.data.data() + y * row;
      Scalar* v = v_render.data.data() + y * row;
      double* s = row_sums_.data() + y * kWidth;
      for (std::size_t p = 0; p < row; p += 3) {
        for (int j = 0; j < 3; ++j)
          v[p + std::size_t(j)] = t[j] * g[p] + t[3 + j] * g[p + 1] + t[6 + j] * g[p + 2];
        for (int i = 0; i < 3; ++i) {
          const double gi = double(g[p + std::size_t(i)]);
          for (int j = 0; j < 3; ++j) s[3 * i + j] += gi * double(c[p + std::size_t(j)]);
          s[9 + i] += gi;
        }
      }
    });
    for (int k = 0; k < kWidth; ++k) {
      double sum = 0;
      for (std::size_t y = 0; y < H; ++y) sum += row_sums_[y * kWidth + std::size_t(k)];
      v_transform[k] = Scalar(sum);
    }
  }

  // One Adam step of frame f's gains and offsets along v_transform (its off-diagonal
  // entries are ignored), then the recentring.
  void step(std::size_t f, const Scalar v_transform_full[kWidth]) {
    ensure(enabled() && f < frames(), "FrameExposure::step: frame ", f, " of ", frames());
    Scalar v_transform[kWidth];
    for (int k = 0; k < kWidth; ++k) v_transform[k] = k < 9 && k % 4 != 0 ? Scalar(0) : v_transform_full[k];
    auto& g = adam_.group(0);
    ++g.step;
    Scalar* t = transforms_.data() + f * kWidth;
    Scalar before[kWidth];
    std::copy(t, t + kWidth, before);
    adam_apply(AdamStep<Scalar>::of(adam_.params(), double(g.lr), g.step), t, v_transform, g.m.data() + f * kWidth,
               g.v.data() + f * kWidth, std::size_t(kWidth));
    const Scalar inv_n = Scalar(1) / Scalar(frames());
    for (int k = 0; k < kWidth; ++k) {
      const Scalar shift = (t[k] - before[k]) * inv_n;
      for (std::size_t r = 0; r < frames(); ++r) transforms_[r * kWidth + std::size_t(k)] -= shift;
    }
  }

  // A training step's loss of frame f: combined_loss of the mapped render, clipped
  // to [0, 1] as the camera's file was, against the target; its gradient w.r.t. the
  // render in v_render, and the transform's step. Without the clip a frame shot
  // brighter than the rest maps a white backdrop above 1, and the scene grows dark
  // veils to meet the file's clipped 1 (cool_teddy with a white backdrop: -8.6 dB on
  // withheld frames). Off: combined_loss of the render itself.
  LossTerms<Scalar> loss_and_step(std::size_t f, const Image<Scalar>& render, const Image<Scalar>& target,
                                  Image<Scalar>& v_render, SsimWorkspace<Scalar>& ws, double lambda, int threads) {
    if (!enabled()) return combined_loss(render, target, v_render, ws, lambda, threads);
    apply(f, render, mapped_, threads);
    clipped_ = mapped_;
    for (Scalar& v : clipped_.data) v = std::min(Scalar(1), std::max(Scalar(0), v));
    const LossTerms<Scalar> loss = combined_loss(clipped_, target, v_mapped_, ws, lambda, threads);
    for (std::size_t i = 0; i < v_mapped_.data.size(); ++i)  // the clip passes no gradient where it clips
      if (mapped_.data[i] != clipped_.data[i]) v_mapped_.data[i] = Scalar(0);
    Scalar v_t[kWidth];
    apply_vjp(f, render, v_mapped_, v_render, v_t, threads);
    step(f, v_t);
    return loss;
  }

 private:
  void check(std::size_t f, const Image<Scalar>& render, const char* what) const {
    ensure(enabled() && f < frames(), "FrameExposure::", what, ": frame ", f, " of ", frames());
    ensure(render.channels == 3, "FrameExposure::", what, ": needs 3 channels, got ", render.channels);
  }

  std::vector<Scalar> transforms_;  // [frames][12]
  Adam<Scalar> adam_;
  Image<Scalar> mapped_, clipped_, v_mapped_;
  std::vector<double> row_sums_;
};

}  // namespace orbitforge

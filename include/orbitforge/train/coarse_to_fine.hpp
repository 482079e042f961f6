#pragma once
// Coarse-to-fine (TrainParams::coarse_levels, coarse_fraction): which image level
// an iteration trains at, and the downsampled frames, built on first use.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/train/train_frame.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

// coarse_levels chosen by the budget (the method's default, pipeline/params.hpp):
// at 10,000 iterations a half-size first half kept R1 within run-to-run spread
// on the recorded videos and took 11-23 % off the method's time; at 3,000 it
// cost 0.6 to 0.9 dB held out and at 5,000 up to 0.64 dB on withheld frames,
// too few full-size iterations being left to recover the detail
// (docs/benchmarks.md, "Coarse-to-fine and the plateau stop at the paper's
// budget", "Coarse-to-fine at 5,000 iterations").
constexpr int kCoarseLevelsByBudget = -1;
constexpr int kCoarseByBudgetFrom = 10000;

// p.coarse_levels with kCoarseLevelsByBudget resolved against p.iterations.
inline int resolved_coarse_levels(const TrainParams& p) {
  if (p.coarse_levels != kCoarseLevelsByBudget) return p.coarse_levels;
  return p.iterations >= kCoarseByBudgetFrom ? 1 : 0;
}

inline void check_coarse_params(const TrainParams& p) {
  ensure(p.coarse_levels >= kCoarseLevelsByBudget && p.coarse_levels <= 6 && p.coarse_fraction >= 0 &&
             p.coarse_fraction <= 1,
         "Trainer: coarse_levels must be 0..6 (or -1: by the budget) and coarse_fraction 0..1, got ",
         p.coarse_levels, " and ", p.coarse_fraction);
}

// The image level of iteration `it` (1-based) under the coarse-to-fine schedule:
// falls linearly from coarse_levels to 0 over the first coarse_fraction of the budget.
inline int coarse_level_at(const TrainParams& p, int it) {
  if (p.coarse_levels <= 0 || !(p.coarse_fraction > 0)) return 0;
  const double span = p.coarse_fraction * double(p.iterations);
  const double left = 1.0 - double(it - 1) / span;  // 1 at the start, 0 at the end of the span
  return left <= 0 ? 0 : std::min(p.coarse_levels, int(std::ceil(left * p.coarse_levels)));
}

// The first iteration after the coarse span (0 when coarse-to-fine is off): from
// here on every frame is at full size.
inline int coarse_span_end(const TrainParams& p) {
  return p.coarse_levels > 0 ? int(std::ceil(p.coarse_fraction * p.iterations)) + 1 : 0;
}

// coarse_level_at, except that iterations up to `full_size_until` (the still-scene
// check's, still_check.hpp) train at full size. A field fitted to half-size frames
// learns faster than one fitted to full-size frames (cool_teddy: 0.40 dB over its
// bake after 500 deforming iterations at half size, 0.01 dB at full size), so
// checking inside the coarse span would let coarse-to-fine decide whether a scene moves.
inline int image_level_at(const TrainParams& p, int it, int full_size_until) {
  return it <= full_size_until ? 0 : coarse_level_at(p, it);
}

// The training frames at image levels >= 1, each built on first use: a level
// halves the one above (2x2 box filter; an odd last row or column is dropped) and
// the camera keeps its pose with fx, fy, cx, cy scaled by 2^-level.
template <class Scalar>
class CoarseFrames {
 public:
  const TrainFrame<Scalar>& at(const std::vector<TrainFrame<Scalar>>& frames, std::size_t fi, int level) {
    if (levels_.size() != frames.size()) levels_.assign(frames.size(), {});
    auto& levels = levels_[fi];
    while (int(levels.size()) < level) levels.push_back(halved(levels.empty() ? frames[fi] : levels.back()));
    return levels[std::size_t(level - 1)];
  }

  void clear() { levels_.clear(); }  // the frames changed: each level is built again on use

  static TrainFrame<Scalar> halved(const TrainFrame<Scalar>& above) {
    TrainFrame<Scalar> f = above;
    const int w = std::max(1, above.image.width / 2), h = std::max(1, above.image.height / 2);
    f.image = Image<Scalar>(w, h, 3);
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x)
        for (int c = 0; c < 3; ++c) {
          const int x1 = std::min(2 * x + 1, above.image.width - 1), y1 = std::min(2 * y + 1, above.image.height - 1);
          f.image(x, y, c) = Scalar(0.25) * (above.image(2 * x, 2 * y, c) + above.image(x1, 2 * y, c) +
                                             above.image(2 * x, y1, c) + above.image(x1, y1, c));
        }
    Intrinsics<Scalar>& k = f.camera.intrinsics;
    k.fx *= Scalar(0.5), k.fy *= Scalar(0.5), k.cx *= Scalar(0.5), k.cy *= Scalar(0.5);
    k.width = w, k.height = h;
    return f;
  }

 private:
  std::vector<std::vector<TrainFrame<Scalar>>> levels_;  // [frame][level - 1]
};

}  // namespace orbitforge

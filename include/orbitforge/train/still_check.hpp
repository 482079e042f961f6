#pragma once
// The still-scene check (TrainParams::still_check_iterations): some time after
// the deformation warm-up, bake the field (MedianGS) and compare how well the
// bake and the deformed model fit frames held back from training until then. A
// field that gains too little over its bake is not worth its cost: the bake
// replaces the scene and training goes on static.
//
// Two figures decide, and the field is kept when either reaches its threshold:
//   gain_db         the mean over the frames of the deformed model's PSNR minus
//                   the bake's (whole images);
//   region_gain_db  the kStillRegionRank-th largest gain over a kStillRegions x
//                   kStillRegions grid of image regions, each region's squared
//                   error summed over the frames, with kStillRegionFloor added
//                   to both mean squared errors so that a region both fit almost
//                   exactly (a plain backdrop) cannot show a large ratio of two
//                   tiny errors.
// A part of the object that moves changes a few regions and is diluted in the
// whole-image mean; the region figure keeps it. The rank was chosen on three
// recorded videos with and without a moving part and checked on two others. The
// floor is about the error a fit of generated frames has anyway at the check
// (whole images 5e-4 to 2e-3): with cameras estimated from the frames, a region
// of plain backdrop next to the object's outline, which both fit to 33 and 37
// dB, gained 3.08 dB at a floor of 1e-4 and kept a still recording's field; at
// 1e-3 it gains 0.97 (docs/benchmarks.md, "The region figure's floor").
// The frames compared on are held back from training until the check
// (TrainParams::still_holdout_every): fit to a frame, a field also absorbs the
// generated frame's own changes, and on training frames a still video's best
// region gained as much as a moving part's; on frames it has not seen, a field
// gains where motion follows from the neighbouring frames in time.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdio>
#include <string>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/deform/median_baker.hpp"
#include "orbitforge/io/checkpoint.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/train_frame.hpp"
#include "orbitforge/train/train_params.hpp"

namespace orbitforge {

inline void check_still_params(const TrainParams& p) {
  ensure(p.still_check_iterations >= 0 && std::isfinite(p.still_gain_db) && std::isfinite(p.still_region_gain_db) &&
             p.still_bake_samples >= 2,
         "Trainer: still_check_iterations must be >= 0, still_gain_db and still_region_gain_db finite and "
         "still_bake_samples >= 2");
  ensure(p.still_holdout_every == 0 || p.still_holdout_every >= 2,
         "Trainer: still_holdout_every must be 0 (no frame held back) or >= 2, got ", p.still_holdout_every);
}

// Whether training frame `frame` is held back for the still check
// (TrainParams::still_holdout_every). Frame 0 never is, so training always has
// a frame to draw.
inline bool held_for_still_check(const TrainParams& p, std::size_t frame) {
  const std::size_t k = p.still_holdout_every >= 2 ? std::size_t(p.still_holdout_every) : 0;
  return k != 0 && frame % k == k / 2;
}

// The frames of `count` training frames the check compares on: those held back,
// or, when none is, up to 8 spread over all of them.
inline std::vector<std::size_t> still_check_frames(const TrainParams& p, std::size_t count) {
  std::vector<std::size_t> held;
  for (std::size_t i = 0; i < count; ++i)
    if (held_for_still_check(p, i)) held.push_back(i);
  if (!held.empty()) return held;
  const std::size_t k = std::min<std::size_t>(8, count);
  for (std::size_t j = 0; j < k; ++j) held.push_back(j * count / k);
  return held;
}

// The iteration at whose end the check runs (0: it does not), given the
// deformation warm-up (TrainSchedule::warmup).
inline int still_check_iteration(const TrainParams& p, int warmup) {
  return p.deformable && p.still_check_iterations > 0 ? warmup + p.still_check_iterations : 0;
}

inline constexpr int kStillRegions = 8;
inline constexpr int kStillRegionRank = 1;
inline constexpr double kStillRegionFloor = 1e-3;  // a mean squared error of 30 dB

// Squared errors of renders (clamped to [0, 1]) against frames, summed per region
// of a kStillRegions x kStillRegions grid (row-major; regions of a frame smaller
// than the grid are empty and score 0).
class RegionErrors {
 public:
  template <class Scalar>
  void add(const Image<Scalar>& render, const Image<Scalar>& frame) {
    ensure(render.width == frame.width && render.height == frame.height && render.channels == frame.channels,
           "RegionErrors: render and frame differ in size");
    for (int y = 0; y < frame.height; ++y) {
      const int ry = y * kStillRegions / frame.height;
      for (int x = 0; x < frame.width; ++x) {
        const std::size_t r = std::size_t(ry * kStillRegions + x * kStillRegions / frame.width);
        const std::size_t i = (std::size_t(y) * std::size_t(frame.width) + std::size_t(x)) * std::size_t(frame.channels);
        for (int c = 0; c < frame.channels; ++c) {
          const double d = std::min(1.0, std::max(0.0, double(render.data[i + std::size_t(c)]))) -
                           double(frame.data[i + std::size_t(c)]);
          sse_[r] += d * d;
        }
        count_[r] += std::size_t(frame.channels);
      }
    }
  }
  // The region's mean squared error (0 for an empty region).
  double mse(int region) const {
    const std::size_t r = std::size_t(region);
    return count_[r] ? sse_[r] / double(count_[r]) : 0.0;
  }
  // Over the whole image, as PSNR (100 for an exact fit).
  double psnr() const {
    double se = 0;
    std::size_t n = 0;
    for (std::size_t r = 0; r < sse_.size(); ++r) se += sse_[r], n += count_[r];
    const double m = se / double(std::max<std::size_t>(1, n));
    return m > 0 ? -10.0 * std::log10(m) : 100.0;
  }
  RegionErrors& operator+=(const RegionErrors& o) {
    for (std::size_t r = 0; r < sse_.size(); ++r) sse_[r] += o.sse_[r], count_[r] += o.count_[r];
    return *this;
  }

 private:
  std::array<double, kStillRegions * kStillRegions> sse_{};
  std::array<std::size_t, kStillRegions * kStillRegions> count_{};
};

// PSNR of a render (clamped to [0, 1]) against a frame.
template <class Scalar>
double fit_psnr(const Image<Scalar>& render, const Image<Scalar>& frame) {
  RegionErrors e;
  e.add(render, frame);
  return e.psnr();
}

// How much better `deformed` fits each region than `baked`, in dB, floored as the
// header says; returns the rank-th largest (1: the largest) and stores its region.
inline double region_gain_db(const RegionErrors& deformed, const RegionErrors& baked, int rank = kStillRegionRank,
                             int* region = nullptr) {
  constexpr int n = kStillRegions * kStillRegions;
  ensure(rank >= 1 && rank <= n, "region_gain_db: rank ", rank, " outside 1..", n);
  std::array<std::pair<double, int>, n> gains;
  for (int r = 0; r < n; ++r)
    gains[std::size_t(r)] = {
        10.0 * std::log10((baked.mse(r) + kStillRegionFloor) / (deformed.mse(r) + kStillRegionFloor)), r};
  // Descending gain, ties by region: the same grid always names the same region.
  std::nth_element(gains.begin(), gains.begin() + (rank - 1), gains.end(), [](const auto& a, const auto& b) {
    return a.first > b.first || (a.first == b.first && a.second < b.second);
  });
  if (region) *region = gains[std::size_t(rank - 1)].second;
  return gains[std::size_t(rank - 1)].first;
}

template <class Scalar>
struct StillVerdict {
  GaussianScene<Scalar> baked;  // the field baked into the scene (same size and row order)
  double gain_db = 0;           // the deformed model's mean PSNR over the bake's, whole images
  double region_gain_db = 0;    // the same in the region of rank kStillRegionRank
  int region = 0;               // that region, row-major in the kStillRegions grid
  // Both figures under their thresholds (still_gain_db, still_region_gain_db):
  // keep the bake, train static.
  bool bake = false;
};

// The check on frames[i] for i in `compare` (still_check_frames). render_deformed(camera,
// time) renders the deformed model (an image valid until `renderer` renders again).
template <class Scalar, class RenderDeformed>
StillVerdict<Scalar> check_still_scene(const GaussianScene<Scalar>& scene, const DeformationField<Scalar>& field,
                                       const std::vector<TrainFrame<Scalar>>& frames,
                                       const std::vector<std::size_t>& compare, Renderer<Scalar>& renderer,
                                       const TrainParams& p, RenderDeformed&& render_deformed) {
  ensure(!compare.empty(), "check_still_scene: no frame to compare on");
  MedianBakeParams mp;
  mp.samples = p.still_bake_samples;
  mp.threads = p.threads;
  StillVerdict<Scalar> v;
  v.baked = bake_median(scene, FieldDeformation<Scalar>(field, p.threads), mp);
  const std::size_t k = compare.size();
  RegionErrors deformed_regions, baked_regions;
  for (std::size_t j = 0; j < k; ++j) {
    ensure(compare[j] < frames.size(), "check_still_scene: frame ", compare[j], " of ", frames.size());
    const TrainFrame<Scalar>& f = frames[compare[j]];
    RegionErrors deformed, baked;  // this frame's
    deformed.add(render_deformed(f.camera, f.time), f.image);
    baked.add(renderer.render(SceneView<Scalar>(v.baked), f.camera).color, f.image);
    v.gain_db += (deformed.psnr() - baked.psnr()) / double(k);
    deformed_regions += deformed;
    baked_regions += baked;
  }
  v.region_gain_db = region_gain_db(deformed_regions, baked_regions, kStillRegionRank, &v.region);
  v.bake = v.gain_db < p.still_gain_db && v.region_gain_db < p.still_region_gain_db;
  return v;
}

// The verdict as a log line: "the field fits the frames G dB better than its bake
// (R dB in its best region, (row, column) of 8 x 8): baked in, training static".
inline std::string still_verdict_text(const ShortcutState& sc) {
  char m[200];
  std::snprintf(m, sizeof(m),
                "the field fits the frames %.3f dB better than its bake (%.3f dB in its %s region, (%d, %d) of %d x "
                "%d): %s",
                sc.field_gain_db, sc.field_region_gain_db, kStillRegionRank == 1 ? "best" : "ranked",
                sc.field_region / kStillRegions,
                sc.field_region % kStillRegions, kStillRegions, kStillRegions,
                sc.field_baked ? "baked in, training static" : "training deformable");
  return m;
}

// Writes the verdict's figures into the state the trainer keeps and checkpoints
// (field_baked is set where the bake replaces the scene).
template <class Scalar>
void record_still_verdict(const StillVerdict<Scalar>& v, ShortcutState& sc) {
  sc.still_checked = true;
  sc.field_gain_db = v.gain_db;
  sc.field_region_gain_db = v.region_gain_db;
  sc.field_region = v.region;
}

}  // namespace orbitforge

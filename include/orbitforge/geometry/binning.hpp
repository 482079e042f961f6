#pragma once
// Source cameras -> canonical bins (paper, "Source-Supported Views and
// Completion Gap"). Azimuths are measured from theta0 in the orbit's direction
// of motion d (+1 counter-clockwise about n, -1 clockwise):
//
//   delta_t = wrap_[0,360)( d (theta_t - theta0) )
//   k_t     = clip( round(delta_t / 360 (N - 1)), 0, N - 1 )     S_obs = { k_t }
//
// S_arc is the continuous arc the first reconstruction can render: [0, K] with K
// the largest bin reached along the UNWRAPPED source trajectory (in source-frame
// order; consecutive deltas are unwrapped by their shortest step). So jitter
// behind theta0 at the start (delta = 359.7) counts as -0.3 and does not make
// the arc the whole orbit, and overshoot past 360 gives K >= N - 1, i.e. the
// whole orbit is the arc. U_gap is the complement; bin N - 1 (the duplicate of
// bin 0) belongs to it unless the source closes the loop.
// Note S_obs follows the paper's formula literally: a frame just behind theta0
// (delta 359.7) is observed at bin N - 1, the same view as bin 0.
#include <algorithm>
#include <cmath>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"

namespace orbitforge {

// Canonical bin of a delta in [0, 360).
template <class Scalar>
int azimuth_to_bin(Scalar delta_deg, int views) {
  ensure(views >= 2, "azimuth_to_bin: need at least 2 canonical views, got ", views);
  ensure(std::isfinite(delta_deg), "azimuth_to_bin: non-finite azimuth");
  const double k = std::round(double(delta_deg) / 360.0 * double(views - 1));
  return int(std::clamp(k, 0.0, double(views - 1)));
}

struct SupportBins {
  int views = 0;
  std::vector<int> source_bins;  // k_t per source camera, source order
  std::vector<int> observed;     // S_obs, sorted, unique
  std::vector<int> arc;          // S_arc = [0, arc_end]
  std::vector<int> gap;          // U_gap, sorted
  int arc_end = 0;               // min(N - 1, max(0, unwrapped_max))
  int unwrapped_max = 0;         // K: largest unwrapped bin reached (may exceed N - 1)
  bool in_arc(int bin) const { return bin >= 0 && bin <= arc_end; }
};

// `azimuth_deg`: source-camera azimuths about the orbit centre in source order
// (any range); theta0_deg: the canonical start; direction: +1 or -1.
template <class Scalar>
SupportBins bin_sources(const std::vector<Scalar>& azimuth_deg, Scalar theta0_deg, int direction, int views) {
  ensure(views >= 2, "bin_sources: need at least 2 canonical views, got ", views);
  ensure(direction == 1 || direction == -1, "bin_sources: direction must be +1 or -1, got ", direction);
  ensure(!azimuth_deg.empty(), "bin_sources: no source cameras");
  ensure(std::isfinite(theta0_deg), "bin_sources: non-finite theta0");
  SupportBins s;
  s.views = views;
  double unwrapped = 0, prev = 0, max_unwrapped = -1e300;
  for (std::size_t t = 0; t < azimuth_deg.size(); ++t) {
    ensure(std::isfinite(azimuth_deg[t]), "bin_sources: non-finite azimuth of source camera ", t);
    const double delta = wrap_deg_360(double(direction) * (double(azimuth_deg[t]) - double(theta0_deg)));
    s.source_bins.push_back(azimuth_to_bin(delta, views));
    // The first camera's position is taken as is relative to theta0 (shortest way),
    // each later one by its shortest step from the previous.
    unwrapped = t == 0 ? wrap_deg_180(delta) : unwrapped + wrap_deg_180(delta - prev);
    prev = delta;
    max_unwrapped = std::max(max_unwrapped, unwrapped);
  }
  s.unwrapped_max = int(std::lround(max_unwrapped / 360.0 * double(views - 1)));
  s.arc_end = std::clamp(s.unwrapped_max, 0, views - 1);
  s.observed = s.source_bins;
  std::sort(s.observed.begin(), s.observed.end());
  s.observed.erase(std::unique(s.observed.begin(), s.observed.end()), s.observed.end());
  for (int k = 0; k < views; ++k) (k <= s.arc_end ? s.arc : s.gap).push_back(k);
  return s;
}

}  // namespace orbitforge

#pragma once
// Does a set of source cameras look like the orbit fit_orbit assumes (constant
// radius, constant height, constant angular speed, one look-at point)? A
// generated video is not rigid, and on a short arc COLMAP can under-rotate the
// later frames (registration drift): the centres then still lie near a circle,
// but the angular steps shrink. The canonical orbit extrapolates the source arc
// to 360 degrees, so a wrong speed puts every completed view in the wrong place.
//
// Figures (steps are per frame: a step across an unregistered frame is divided
// by the frame-index difference, so a gap is not a speed change):
//  - per-frame azimuth steps along the motion direction and their median;
//  - frames whose step is outside [step_low, step_high] x median (a jump or a
//    stall: one frame registered in the wrong place);
//  - speed trend: mean step of the second half / mean step of the first half,
//    and the most extreme such ratio over every split with at least min_split
//    steps on each side (drift that sets in late does not dilute into halves);
//  - circle RMSE / r, height std / r, mean look-at ray error.
// The default thresholds are set from measurements. On the five recorded v3d
// videos' all-frame COLMAP models (frames 1-33 and all 90) the figures are within
//   steps 0.83-1.17x the median, trend 0.968-1.010 (halves) / 0.951-1.049
//   (best split), circle RMSE / r <= 0.0046, height std / r <= 0.0056,
//   look-at error <= 0.23 degrees;
// a drifted arc (the later half's rotation compressed by 0.8) gives a trend of
// 0.80, and the drift recorded on one video (frame 33 at 102.6 instead of 124.7
// degrees after agreeing up to frame 17) about 0.64. trend_low = 0.87 sits
// midway (in log) between 0.951 and 0.80; the geometric limits are about twice
// the largest value measured on good videos. COLMAP run on frames 1-33 alone
// gives trends 0.978-0.996 / 0.965-1.015 on four videos and 0.935 / 0.899 on
// sunflower, whose 33-frame arc is 4.9 degrees shorter than in the all-frame
// model (107.6 against 112.5): a mild drift, below what the check flags.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/orbit.hpp"

namespace orbitforge {

struct OrbitCheckParams {
  double step_low = 0.5, step_high = 1.5;  // per-frame step / median step outside this: the frame is flagged
  double trend_low = 0.87;                  // mean-step ratio (later / earlier) below this, or above
                                            // 1 / trend_low: the speed drifts
  int min_split = 8;                        // steps on each side of a trend split
  double max_circle_rmse = 0.01;            // circle RMSE / radius
  double max_height_std = 0.012;            // height std / radius
  double max_lookat_error_deg = 0.5;        // mean angle between optical axes and the look-at point
};

struct OrbitCheck {
  bool ok = true;
  std::vector<std::string> warnings;        // one sentence each, with the figure and its threshold
  std::vector<std::string> flagged_frames;  // names of frames whose step departs from the median
  // The figures the warnings are made of.
  std::vector<double> steps_deg;  // per-frame step into each successful camera after the first (motion direction)
  double median_step_deg = 0;
  double trend_halves = 1;        // mean step of the second half / first half
  double trend_split = 1;         // the ratio over the most extreme split (furthest from 1 in log)
  int trend_split_frame = -1;     // index into fit.source of the first camera after that split
  double circle_rmse = 0;         // relative to the radius
  double height_std = 0;          // relative to the radius
  double lookat_error_deg = 0;
};

namespace detail {
inline double orbit_check_mean(const std::vector<double>& v, std::size_t a, std::size_t b) {
  double s = 0;
  for (std::size_t i = a; i < b; ++i) s += v[i];
  return b > a ? s / double(b - a) : 0.0;
}
}  // namespace detail

// `fit` must come from fit_orbit(source, ...) (its source list indexes `source`).
template <class Scalar>
OrbitCheck check_orbit(const std::vector<FrameCamera<Scalar>>& source, const OrbitFit<Scalar>& fit,
                       const OrbitCheckParams& p = {}) {
  ensure(p.step_low > 0 && p.step_low < 1 && p.step_high > 1, "check_orbit: step bounds ", p.step_low, ", ",
         p.step_high, " must bracket 1");
  ensure(p.trend_low > 0 && p.trend_low < 1, "check_orbit: trend_low ", p.trend_low, " outside (0, 1)");
  ensure(p.min_split >= 1, "check_orbit: min_split ", p.min_split, " below 1");
  OrbitCheck c;
  const auto& g = fit.orbit;
  const double r = double(g.radius);
  ensure(r > 0 && std::isfinite(r), "check_orbit: orbit radius ", r);
  for (const auto& s : fit.source)
    ensure(s.input_index >= 0 && std::size_t(s.input_index) < source.size(), "check_orbit: the fit's source '",
           s.name, "' has index ", s.input_index, " outside the ", source.size(), " source cameras");
  auto warn = [&](const auto&... parts) {
    std::ostringstream os;
    os.precision(3);
    (os << ... << parts);
    c.warnings.push_back(os.str());
    c.ok = false;
  };

  // Geometry of the centres (the fit's own figures, made relative to r).
  c.circle_rmse = double(fit.diagnostics.circle_rmse) / r;
  double h_mean = 0, h_sq = 0;
  for (const auto& s : fit.source) {
    const double h = double((source[s.input_index].camera.center() - g.center).dot(g.normal));
    h_mean += h;
    h_sq += h * h;
  }
  const double n_src = double(std::max<std::size_t>(fit.source.size(), 1));
  h_mean /= n_src;
  c.height_std = std::sqrt(std::max(0.0, h_sq / n_src - h_mean * h_mean)) / r;
  c.lookat_error_deg = double(fit.diagnostics.lookat_error_deg);
  if (c.circle_rmse > p.max_circle_rmse)
    warn("camera centres are off a circle: RMSE ", c.circle_rmse, " of the radius (limit ", p.max_circle_rmse, ")");
  if (c.height_std > p.max_height_std)
    warn("camera heights above the orbit plane vary: std ", c.height_std, " of the radius (limit ",
         p.max_height_std, ")");
  if (c.lookat_error_deg > p.max_lookat_error_deg)
    warn("optical axes miss the common look-at point by ", c.lookat_error_deg, " degrees on average (limit ",
         p.max_lookat_error_deg, ")");

  // Angular steps along the motion direction, per frame.
  for (std::size_t t = 1; t < fit.source.size(); ++t) {
    const int frames = std::max(1, fit.source[t].input_index - fit.source[t - 1].input_index);
    const double d = double(g.direction) *
                     wrap_deg_180(double(fit.source[t].azimuth_deg) - double(fit.source[t - 1].azimuth_deg));
    c.steps_deg.push_back(d / frames);
  }
  const std::size_t m = c.steps_deg.size();
  if (m < 2) {
    warn("too few cameras (", fit.source.size(), ") to measure the angular speed");
    return c;
  }
  std::vector<double> sorted = c.steps_deg;
  std::sort(sorted.begin(), sorted.end());
  c.median_step_deg = m % 2 ? sorted[m / 2] : 0.5 * (sorted[m / 2 - 1] + sorted[m / 2]);
  const double med = c.median_step_deg;
  if (!(med > 0)) {
    warn("the median angular step is ", med, " degrees: the cameras do not move along the orbit");
    return c;
  }
  for (std::size_t t = 0; t < m; ++t) {
    const double ratio = c.steps_deg[t] / med;
    if (ratio < p.step_low || ratio > p.step_high) {
      const std::string& name = fit.source[t + 1].name;
      c.flagged_frames.push_back(name);
      warn("frame ", name, ": step ", c.steps_deg[t], " degrees is ", ratio, "x the median ", med, " (outside ",
           p.step_low, "-", p.step_high, "x)");
    }
  }

  // Speed trend. The log ratio treats speeding up and slowing down alike.
  const double first = detail::orbit_check_mean(c.steps_deg, 0, m / 2);
  const double second = detail::orbit_check_mean(c.steps_deg, m - m / 2, m);
  c.trend_halves = first > 0 ? second / first : 0.0;
  double worst = 0;
  for (std::size_t k = std::size_t(p.min_split); k + std::size_t(p.min_split) <= m; ++k) {
    const double a = detail::orbit_check_mean(c.steps_deg, 0, k), b = detail::orbit_check_mean(c.steps_deg, k, m);
    const double ratio = a > 0 && b > 0 ? b / a : 0.0;
    const double dev = ratio > 0 ? std::abs(std::log(ratio)) : INFINITY;
    if (dev > worst || c.trend_split_frame < 0) {
      worst = dev;
      c.trend_split = ratio;
      c.trend_split_frame = int(k + 1);
    }
  }
  const double lo = p.trend_low, hi = 1.0 / p.trend_low;
  auto outside = [&](double ratio) { return !(ratio >= lo && ratio <= hi); };
  if (outside(c.trend_halves))
    warn("angular speed drifts: the second half's mean step is ", c.trend_halves, "x the first half's (limits ", lo,
         "-", hi, "); registration drift would under-rotate the later frames");
  if (c.trend_split_frame >= 0 && outside(c.trend_split) && !outside(c.trend_halves))
    warn("angular speed changes at frame ", fit.source[std::size_t(c.trend_split_frame)].name, ": mean step after it is ",
         c.trend_split, "x the mean before (limits ", lo, "-", hi, ")");
  return c;
}

}  // namespace orbitforge

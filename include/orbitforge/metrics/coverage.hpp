#pragma once
// Orbit coverage (paper, "Coverage First, Smoothness Second", Eq. span) and the
// temporal trace diagnostics of the completion ablations.
//
//  span A      = 360 - largest circular gap between the sorted azimuths (degrees)
//  progress M  = fraction of adjacent steps (in sequence order, wrapped to
//                (-180, 180]) that move in the dominant direction; zero steps
//                count for neither direction; dominant = the sign with more steps
//  closed gate = A > 330 and M > 0.9
//
// Temporal trace over per-frame reference positions x_j (e.g. which frame of a
// reference orbit of `period` frames each generated frame shows):
//  step_j         = wrap(x_{j+1} - x_j) into (-period/2, period/2]
//  absolute turns = sum |step_j| / period;   net turns = sum step_j / period
//  stall fraction = share of steps with |step_j| < stall_threshold (1 reference step)
//  reversals      = sign changes between consecutive non-trivial steps (|step| >= threshold)
#include <algorithm>
#include <cmath>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"

namespace orbitforge {

template <class Scalar>
Scalar azimuth_span_deg(const std::vector<Scalar>& azimuth_deg) {
  ensure(!azimuth_deg.empty(), "azimuth_span_deg: no azimuths");
  std::vector<double> a;
  for (auto x : azimuth_deg) {
    ensure(std::isfinite(x), "azimuth_span_deg: non-finite azimuth");
    a.push_back(wrap_deg_360(double(x)));
  }
  if (a.size() == 1) return 0;
  std::sort(a.begin(), a.end());
  double gap = a.front() + 360.0 - a.back();
  for (std::size_t i = 1; i < a.size(); ++i) gap = std::max(gap, a[i] - a[i - 1]);
  return Scalar(360.0 - gap);
}

template <class Scalar>
Scalar monotone_progress(const std::vector<Scalar>& azimuth_deg) {
  if (azimuth_deg.size() < 2) return 0;  // no steps: no progress
  std::size_t pos = 0, neg = 0;
  for (std::size_t i = 1; i < azimuth_deg.size(); ++i) {
    ensure(std::isfinite(azimuth_deg[i]) && std::isfinite(azimuth_deg[i - 1]), "monotone_progress: non-finite azimuth");
    const double s = wrap_deg_180(double(azimuth_deg[i]) - double(azimuth_deg[i - 1]));
    if (s > 0) ++pos;
    else if (s < 0) ++neg;
  }
  return Scalar(double(std::max(pos, neg)) / double(azimuth_deg.size() - 1));
}

template <class Scalar>
struct Coverage {
  Scalar span_deg = 0;  // A
  Scalar monotone = 0;  // M
  bool closed = false;
};

struct CoverageParams {
  double min_span_deg = 330;  // A >
  double min_monotone = 0.9;  // M >
};

template <class Scalar>
Coverage<Scalar> orbit_coverage(const std::vector<Scalar>& azimuth_deg, const CoverageParams& p = {}) {
  Coverage<Scalar> c;
  c.span_deg = azimuth_span_deg(azimuth_deg);
  c.monotone = monotone_progress(azimuth_deg);
  c.closed = double(c.span_deg) > p.min_span_deg && double(c.monotone) > p.min_monotone;
  return c;
}

struct TemporalTrace {
  double absolute_turns = 0;
  double net_turns = 0;
  double stall_fraction = 0;
  int reversals = 0;
  int steps = 0;
};

struct TraceParams {
  double period = 360;          // reference positions per full turn
  double stall_threshold = 1;   // reference steps
};

inline TemporalTrace temporal_trace(const std::vector<double>& positions, const TraceParams& p = {}) {
  ensure(p.period > 0, "temporal_trace: period must be positive, got ", p.period);
  TemporalTrace tr;
  if (positions.size() < 2) return tr;
  double sum = 0, sum_abs = 0;
  int stalls = 0, last_sign = 0;
  for (std::size_t i = 1; i < positions.size(); ++i) {
    ensure(std::isfinite(positions[i]) && std::isfinite(positions[i - 1]), "temporal_trace: non-finite position ", i);
    double s = std::fmod(positions[i] - positions[i - 1], p.period);
    if (s > p.period / 2) s -= p.period;
    if (s <= -p.period / 2) s += p.period;
    sum += s;
    sum_abs += std::abs(s);
    if (std::abs(s) < p.stall_threshold) {
      ++stalls;
      continue;
    }
    const int sign = s > 0 ? 1 : -1;
    if (last_sign != 0 && sign != last_sign) ++tr.reversals;
    last_sign = sign;
  }
  tr.steps = int(positions.size() - 1);
  tr.absolute_turns = sum_abs / p.period;
  tr.net_turns = sum / p.period;
  tr.stall_fraction = double(stalls) / tr.steps;
  return tr;
}

}  // namespace orbitforge

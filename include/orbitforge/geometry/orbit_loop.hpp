#pragma once
// How a video's cameras go round their orbit: the turn per frame between
// neighbours, in frame order, on an orbit fitted to all of them, and the turn
// from the last frame back to the first.
//
// A video that orbits the whole way ends one step before it began, so a model
// of its cameras should close with one more even step. A model that was never
// told so (a sequential matcher never matches the last frames with the first)
// under-rotates a little at every step and stops short: its last step is
// several mean steps wide and its far side is turned from where the frames
// were shot (docs/cameras.md, "A reference that closes the loop").
#include <algorithm>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/orbit.hpp"

namespace orbitforge {

struct OrbitLoop {
  int cameras = 0;
  double mean_step_deg = 0;      // per frame, over the first to the last camera
  double smallest_step_deg = 0;  // per frame, between neighbouring cameras
  double largest_step_deg = 0;
  double last_to_first_deg = 0;  // from the last camera on round to the first, in the direction of travel
};

// `cams` in frame order, `frame` their frame numbers (increasing); at least 4.
template <class Scalar>
OrbitLoop orbit_loop(const std::vector<FrameCamera<Scalar>>& cams, const std::vector<int>& frame) {
  ensure(cams.size() >= 4 && cams.size() == frame.size(), "orbit_loop: ", cams.size(), " cameras and ", frame.size(),
         " frame numbers (at least 4 of each, as many of one as of the other)");
  for (std::size_t k = 1; k < frame.size(); ++k)
    ensure(frame[k] > frame[k - 1], "orbit_loop: frame numbers must increase (", frame[k - 1], ", then ", frame[k], ")");
  OrbitParams op;
  op.views = int(cams.size());
  const OrbitGeometry<Scalar>& g = fit_orbit(cams, op).orbit;
  std::vector<double> az, turn;  // azimuth per camera; signed turn from the camera before
  for (const auto& c : cams) az.push_back(double(orbit_azimuth_deg<Scalar>(c.camera.center(), g.center, g.e1, g.e2)));
  double total = 0;
  for (std::size_t k = 1; k < az.size(); ++k) total += turn.emplace_back(double(wrap_deg_180(az[k] - az[k - 1])));
  const double sign = total < 0 ? -1.0 : 1.0;  // the direction of travel
  OrbitLoop l;
  l.cameras = int(cams.size());
  l.mean_step_deg = sign * total / double(frame.back() - frame.front());
  for (std::size_t k = 1; k < az.size(); ++k) {
    const double step = sign * turn[k - 1] / double(frame[k] - frame[k - 1]);
    l.smallest_step_deg = k == 1 ? step : std::min(l.smallest_step_deg, step);
    l.largest_step_deg = std::max(l.largest_step_deg, step);
  }
  l.last_to_first_deg = double(wrap_deg_360(sign * (az.front() - az.back())));
  return l;
}

}  // namespace orbitforge

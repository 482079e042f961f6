#pragma once
// Angle wrapping in degrees, shared by orbit fitting, binning and coverage.
#include <cmath>

namespace orbitforge {

// Wrap to [0, 360).
template <class Scalar>
Scalar wrap_deg_360(Scalar deg) {
  Scalar w = std::fmod(deg, Scalar(360));
  if (w < 0) w += Scalar(360);
  if (w >= Scalar(360)) w -= Scalar(360);  // fmod(-tiny) + 360 can round up to 360
  return w;
}

// Wrap to (-180, 180].
template <class Scalar>
Scalar wrap_deg_180(Scalar deg) {
  Scalar w = wrap_deg_360(deg);
  if (w > Scalar(180)) w -= Scalar(360);
  return w;
}

}  // namespace orbitforge

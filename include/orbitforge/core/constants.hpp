#pragma once
// Precision-dependent tolerances in one place (Sophus style). Code that needs a
// tolerance asks Constants<Scalar> rather than hard-coding a number.
#include <cmath>
#include <limits>

namespace orbitforge {

template <class Scalar>
struct Constants {
  static constexpr Scalar pi() { return Scalar(3.141592653589793238462643383279502884L); }
  static constexpr Scalar deg2rad(Scalar d) { return d * pi() / Scalar(180); }
  static constexpr Scalar rad2deg(Scalar r) { return r * Scalar(180) / pi(); }
  // Machine epsilon of the precision.
  static constexpr Scalar epsilon() { return std::numeric_limits<Scalar>::epsilon(); }
  // Threshold below which a length or determinant counts as zero in geometry.
  static constexpr Scalar small() { return std::numeric_limits<Scalar>::epsilon() * Scalar(1e3); }
  // Central finite-difference step suited to the precision (~cbrt(eps)).
  static Scalar fd_step() { return std::cbrt(std::numeric_limits<Scalar>::epsilon()); }
};

}  // namespace orbitforge

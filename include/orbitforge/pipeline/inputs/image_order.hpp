#pragma once
// The order a COLMAP folder's images are numbered in (frame numbers, --frames,
// --holdout-every): their names, as a video's frames are, or their place around
// the ring their cameras lie on, for photographs whose names are not the order
// they were taken around the object in.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <numeric>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/plane_fit.hpp"

namespace orbitforge {

enum class ImageOrder { name, ring };

inline const char* image_order_name(ImageOrder o) { return o == ImageOrder::ring ? "ring" : "name"; }

inline ImageOrder parse_image_order(const std::string& s) {
  if (s == "name") return ImageOrder::name;
  if (s == "ring") return ImageOrder::ring;
  fail("image order must be name or ring, not '", s, "'");
}

// The positions of `frames` in ring order: registered cameras by azimuth about
// the normal of the plane fitted to their centres, starting after the largest
// angular gap (so a partial ring runs from one end to the other) and turning the
// way name order turns on the whole; frames without a camera follow, in name
// order. Azimuths are taken about the centres' centroid, which keeps the order
// of points along an arc. Needs three registered cameras.
template <class Scalar>
std::vector<std::size_t> ring_order(const std::vector<FrameCamera<Scalar>>& frames) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  std::vector<std::size_t> registered, unregistered;
  std::vector<Vec3> centres;
  Vec3 up = Vec3::Zero(), forward = Vec3::Zero();
  for (std::size_t i = 0; i < frames.size(); ++i) {
    if (!frames[i].valid) {
      unregistered.push_back(i);
      continue;
    }
    registered.push_back(i);
    centres.push_back(frames[i].camera.center());
    up += frames[i].camera.up();
    forward += frames[i].camera.forward();
  }
  ensure(registered.size() >= 3, "ring order: needs at least 3 registered cameras, the model has ",
         registered.size());
  const PlaneFit<Scalar> plane = fit_plane(centres, up, forward);
  std::vector<double> azimuth(registered.size());
  for (std::size_t k = 0; k < registered.size(); ++k) {
    const auto q = plane.to_plane(centres[k]);
    azimuth[k] = Constants<double>::rad2deg(std::atan2(double(q[1]), double(q[0])));
  }
  // Which way name order turns: the sign of its wrapped steps' sum.
  double turn = 0;
  for (std::size_t k = 1; k < azimuth.size(); ++k) turn += wrap_deg_180(azimuth[k] - azimuth[k - 1]);
  std::vector<std::size_t> by_az(registered.size());
  std::iota(by_az.begin(), by_az.end(), std::size_t(0));
  std::stable_sort(by_az.begin(), by_az.end(), [&](std::size_t a, std::size_t b) { return azimuth[a] < azimuth[b]; });
  // Start after the largest gap between neighbours (cyclically).
  std::size_t start = 0;
  double widest = -1;
  for (std::size_t k = 0; k < by_az.size(); ++k) {
    const std::size_t next = (k + 1) % by_az.size();
    const double gap = wrap_deg_360(azimuth[by_az[next]] - azimuth[by_az[k]]);
    if (gap > widest) {
      widest = gap;
      start = next;
    }
  }
  std::rotate(by_az.begin(), by_az.begin() + std::ptrdiff_t(start), by_az.end());
  if (turn < 0) std::reverse(by_az.begin(), by_az.end());
  std::vector<std::size_t> order;
  for (std::size_t k : by_az) order.push_back(registered[k]);
  order.insert(order.end(), unregistered.begin(), unregistered.end());
  return order;
}

}  // namespace orbitforge

#pragma once
// The size of a scene as its training cameras give it: densification's
// thresholds, the deformation field's input scale and the random initial cloud
// are measured against it.
#include <algorithm>
#include <cmath>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

// The mean of the cameras' centres.
template <class Scalar>
typename Camera<Scalar>::Vec3 mean_camera_center(const std::vector<Camera<Scalar>>& cameras) {
  ensure(!cameras.empty(), "mean_camera_center: no cameras");
  typename Camera<Scalar>::Vec3 mean = Camera<Scalar>::Vec3::Zero();
  for (const auto& c : cameras) mean += c.center();
  return mean / Scalar(cameras.size());
}

// Scene extent as 3DGS defines it (getNerfppNorm): 1.1 times the largest distance of a
// camera centre from the mean camera centre.
template <class Scalar>
Scalar camera_extent(const std::vector<Camera<Scalar>>& cameras) {
  ensure(!cameras.empty(), "camera_extent: no cameras");
  const typename Camera<Scalar>::Vec3 mean = mean_camera_center(cameras);
  Scalar r = 0;
  for (const auto& c : cameras) r = std::max(r, (c.center() - mean).norm());
  ensure(std::isfinite(double(r)), "camera_extent: non-finite camera centre");
  return Scalar(1.1) * r;
}

// camera_extent where it is a length to scale by (the trainer's scene scale, the
// random cloud's distances): 1 for a single camera, or for cameras within 1e-6
// of one point, which give no extent.
template <class Scalar>
Scalar camera_extent_or_one(const std::vector<Camera<Scalar>>& cameras) {
  const Scalar e = cameras.size() > 1 ? camera_extent(cameras) : Scalar(0);
  return e > Scalar(1e-6) ? e : Scalar(1);
}

}  // namespace orbitforge

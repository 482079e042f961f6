#pragma once
// One training frame: an image, its camera, its time code and its sampling
// weight; and the check the Trainer makes of a set of them.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"

namespace orbitforge {

template <class Scalar>
struct TrainFrame {
  Image<Scalar> image;     // [H][W][3], values in [0, 1], H x W = the camera's image size
  Camera<Scalar> camera;
  Scalar time = 0;         // time code in [0, 1] (deformable training)
  std::string name;
  int repeats = 1;         // times the frame is drawn per pass over the frames (sampling weight, >= 1)
};

// The frames' cameras, in frame order.
template <class Scalar>
std::vector<Camera<Scalar>> frame_cameras(const std::vector<TrainFrame<Scalar>>& frames) {
  std::vector<Camera<Scalar>> cams;
  cams.reserve(frames.size());
  for (const auto& f : frames) cams.push_back(f.camera);
  return cams;
}

// The longest side, in pixels, of any frame's image.
template <class Scalar>
int longer_side(const std::vector<TrainFrame<Scalar>>& frames) {
  int n = 0;
  for (const auto& f : frames) n = std::max({n, f.image.width, f.image.height});
  return n;
}

// Draws per pass over the frames (FrameOrder): the sum of their repeats
// (those outside 1..1000 are refused by check_train_frames; they count 0 here).
template <class Scalar>
std::size_t draws_per_pass(const std::vector<TrainFrame<Scalar>>& frames) {
  std::size_t n = 0;
  for (const auto& f : frames) n += f.repeats >= 1 && f.repeats <= 1000 ? std::size_t(f.repeats) : 0;
  return n;
}

// Refuses an empty set and any frame whose image is not RGB of its camera's size,
// whose camera or time code is not finite, or whose repeats lie outside 1..1000.
template <class Scalar>
void check_train_frames(const std::vector<TrainFrame<Scalar>>& frames) {
  ensure(!frames.empty(), "Trainer: no frames");
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const auto& f = frames[i];
    ensure(f.image.channels == 3 && f.image.width == f.camera.intrinsics.width &&
               f.image.height == f.camera.intrinsics.height && !f.image.empty(),
           "Trainer: frame ", i, " (", f.name, ") has a ", f.image.width, "x", f.image.height, "x", f.image.channels,
           " image for a ", f.camera.intrinsics.width, "x", f.camera.intrinsics.height,
           " camera (need RGB of the camera's size)");
    ensure(f.camera.is_finite(), "Trainer: frame ", i, " (", f.name, ") has a non-finite camera");
    ensure(std::isfinite(double(f.time)), "Trainer: frame ", i, " (", f.name, ") has a non-finite time code");
    ensure(f.repeats >= 1 && f.repeats <= 1000, "Trainer: frame ", i, " (", f.name, ") has repeats ", f.repeats,
           " (need 1..1000)");
  }
}

}  // namespace orbitforge

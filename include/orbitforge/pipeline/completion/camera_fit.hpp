#pragma once
// The completion's frames fitted to the scene G1 is learning: each frame's
// camera turned and zoomed about its centre so that the scene, held fixed,
// renders its image best (metrics/view_alignment.hpp).
//
// A completion frame arrives at the camera it was requested at, and a video
// model lands a degree or two off it; the oracle's recorded frames come from
// another estimate than the source cameras. Trained where it does not belong, a
// frame pulls G1's surfaces apart at the seams with its neighbours. Part way
// through G1 the scene already agrees with most of its frames, so a frame that
// disagrees shows it as a turn of its image, which the fit finds; no other
// frame, and no held-out image, takes part.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <nlohmann/json.hpp>
#include <vector>

#include "orbitforge/metrics/view_alignment.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/train_frame.hpp"

namespace orbitforge {

struct FrameCameraFit {
  int frames = 0;    // frames that were fitted
  int moved = 0;     // of which the fit moved (the others keep their camera)
  double turn_mean_deg = 0, turn_max_deg = 0;
  double zoom_change_mean = 0, zoom_change_max = 0;  // |s - 1|

  nlohmann::json json() const {
    return {{"frames", frames},
            {"moved", moved},
            {"turn_mean_deg", turn_mean_deg},
            {"turn_max_deg", turn_max_deg},
            {"zoom_change_mean", zoom_change_mean},
            {"zoom_change_max", zoom_change_max}};
  }
};

// Fits the camera of every frame k with movable[k] to its image, `scene` held
// fixed, and moves it where the fit lowers the error (within the alignment's
// limits). Frames without the flag are left as they are.
template <class Scalar>
FrameCameraFit fit_frame_cameras(Renderer<Scalar>& renderer, const GaussianScene<Scalar>& scene,
                                 std::vector<TrainFrame<Scalar>>& frames, const std::vector<bool>& movable,
                                 const ViewAlignmentParams& params = {}) {
  ensure(movable.size() == frames.size(), "fit_frame_cameras: ", movable.size(), " flags for ", frames.size(),
         " frames");
  FrameCameraFit fit;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    if (!movable[k]) continue;
    TrainFrame<Scalar>& f = frames[k];
    ++fit.frames;
    const Image<Scalar> rendered = renderer.render(SceneView<Scalar>(scene), f.camera).color;
    const ViewAlignment a = fit_view_alignment(rendered, f.image, f.camera.intrinsics, params);
    if (!a.refined) continue;
    f.camera = aligned_camera(f.camera, a);
    ++fit.moved;
    const double zoom_change = std::abs(a.zoom - 1);
    fit.turn_mean_deg += a.angle_deg;
    fit.turn_max_deg = std::max(fit.turn_max_deg, a.angle_deg);
    fit.zoom_change_mean += zoom_change;
    fit.zoom_change_max = std::max(fit.zoom_change_max, zoom_change);
  }
  if (fit.moved > 0) {
    fit.turn_mean_deg /= fit.moved;
    fit.zoom_change_mean /= fit.moved;
  }
  return fit;
}

}  // namespace orbitforge

#pragma once
// Training frames rendered from a small synthetic scene (pipeline/inputs/synthetic_input.hpp)
// at its true cameras: count frames of size x size pixels (width x size when width
// is given), on a background colour (white unless given), time codes spread over [0, 1]; a
// random initial scene and settings to train on them.
#include <array>
#include <vector>

#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

namespace orbitforge_test {

template <class S>
std::vector<orbitforge::TrainFrame<S>> tiny_frames(int count = 8, int size = 32, int width = 0,
                                                   std::array<double, 3> background = {1, 1, 1}) {
  using namespace orbitforge;
  SyntheticInputParams p;
  p.frames = count;
  p.source_frames = count;
  p.height = size;
  p.width = width > 0 ? width : size;
  p.focal = 1.25 * size;
  p.object_gaussians = 200;
  p.ground_gaussians = 100;
  const auto in = make_synthetic_input<S>(p);
  RenderParams<S> rp;
  rp.threads = 1;
  rp.background = {S(background[0]), S(background[1]), S(background[2])};
  Renderer<S> r(rp);
  std::vector<TrainFrame<S>> frames;
  for (int i = 0; i < count; ++i) {
    TrainFrame<S> f;
    f.camera = in.true_cameras[std::size_t(i)];
    f.image = r.render(SceneView<S>(in.scene), f.camera).color;
    f.time = S(i) / S(count - 1);
    frames.push_back(std::move(f));
  }
  return frames;
}

// A random initial cloud of `points` Gaussians around the frames' cameras (seeded).
template <class S>
orbitforge::GaussianScene<S> tiny_init(const std::vector<orbitforge::TrainFrame<S>>& frames,
                                       std::size_t points = 300) {
  using namespace orbitforge;
  InitParams ip;
  ip.random_points = points;
  ip.seed = 3;
  return init_random(frame_cameras(frames), ip);
}

// Training settings for these frames: one thread, a fixed seed, white background.
inline orbitforge::TrainParams tiny_params(int iterations) {
  orbitforge::TrainParams p;
  p.iterations = iterations;
  p.threads = 1;
  p.seed = 11;
  p.background = {1, 1, 1};
  // The published interval (100 of 30000) scaled to these tiny budgets would densify
  // every iteration; every budget/30 iterations keeps the scenes small and fast.
  p.densify_schedule.densify_interval = 1000;
  return p;
}

}  // namespace orbitforge_test

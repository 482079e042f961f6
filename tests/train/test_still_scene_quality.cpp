// The still-scene check's measure means something: a deformation field fitted to
// a moving object gains more over its MedianGS bake than one fitted to a still
// scene. A quality check of two short trainings (registered in normal builds
// only; the check's code paths run sanitized in train.training_levers).
#include <catch2/catch.hpp>

#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

using namespace orbitforge;

TEST_CASE("still-scene check: a field fitted to a moving object gains more over its bake than a still one's",
          "[train][levers]") {
  // The same synthetic scene, still and with every Gaussian above the ground
  // moving sideways by 0.3 of the camera distance over the time codes.
  auto frames_of = [](double travel) {
    SyntheticInputParams sp;
    sp.frames = sp.source_frames = 6;
    sp.width = sp.height = 32;
    sp.focal = 40;
    sp.object_gaussians = 200;
    sp.ground_gaussians = 100;
    const auto in = make_synthetic_input<float>(sp);
    RenderParams<float> rp;
    rp.threads = 1;
    rp.background = {1, 1, 1};
    Renderer<float> r(rp);
    std::vector<TrainFrame<float>> frames;
    for (int i = 0; i < sp.frames; ++i) {
      TrainFrame<float> f;
      f.camera = in.true_cameras[std::size_t(i)];
      f.time = float(i) / float(sp.frames - 1);
      GaussianScene<float> moved = in.scene;
      const float shift = float(travel * (f.time - 0.5) * f.camera.center().norm());
      for (std::size_t g = 0; g < moved.size(); ++g)
        if (g < std::size_t(sp.object_gaussians)) moved.means[3 * g] += shift;
      f.image = r.render(SceneView<float>(moved), f.camera).color;
      frames.push_back(std::move(f));
    }
    return frames;
  };
  auto gain_after_fit = [](const std::vector<TrainFrame<float>>& frames) {
    TrainParams p;
    p.threads = 1;
    p.background = {1, 1, 1};
    p.min_densify_interval = 50;
    p.iterations = 1000;
    p.deformable = true;
    p.warmup_iterations = 100;
    p.deform_reference_budget = p.iterations;
    p.still_check_iterations = 700;
    p.still_gain_db = -1e6;
    std::vector<Camera<float>> cams;
    for (const auto& f : frames) cams.push_back(f.camera);
    InitParams ip;
    ip.random_points = 1500;
    Trainer<float> t(frames, init_random(cams, camera_extent(cams), ip), p);
    t.train(800);
    REQUIRE(t.last_progress().shortcuts.still_checked);
    return t.last_progress().shortcuts.field_gain_db;
  };
  const double still = gain_after_fit(frames_of(0)), moving = gain_after_fit(frames_of(0.3));
  INFO("the field's gain: still " << still << " dB, moving " << moving << " dB");
  REQUIRE(moving > still + 1.0);
}


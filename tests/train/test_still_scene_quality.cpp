// The still-scene check's measure means something: a deformation field fitted to
// a moving object gains more over its MedianGS bake, on the frames held back for
// the check, than one fitted to a still scene, and at the default thresholds
// (TrainParams::still_gain_db, still_region_gain_db) one whose object moves only
// in part is kept, while a still scene is baked. Quality checks of short trainings
// (registered in normal builds only; the check's code paths run sanitized in
// train.training_levers).
#include <catch2/catch.hpp>

#include <algorithm>
#include <numeric>

#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

using namespace orbitforge;

namespace {

constexpr int kFrames = 24, kObjectGaussians = 200;

// The synthetic scene's frames, with the object's highest `part` (a fraction of
// its Gaussians, by height) moving sideways by `travel` of the camera distance
// over the time codes.
std::vector<TrainFrame<float>> frames_of(double travel, double part) {
  SyntheticInputParams sp;
  sp.frames = sp.source_frames = kFrames;
  sp.width = sp.height = 32;
  sp.focal = 40;
  sp.object_gaussians = kObjectGaussians;
  sp.ground_gaussians = 100;
  const auto in = make_synthetic_input<float>(sp);
  std::vector<std::size_t> by_height(kObjectGaussians);
  std::iota(by_height.begin(), by_height.end(), std::size_t(0));
  std::sort(by_height.begin(), by_height.end(),
            [&](std::size_t a, std::size_t b) { return in.scene.means[3 * a + 2] > in.scene.means[3 * b + 2]; });
  by_height.resize(std::size_t(std::lround(part * kObjectGaussians)));
  RenderParams<float> rp;
  rp.threads = 1;
  rp.background = {1, 1, 1};
  Renderer<float> r(rp);
  std::vector<TrainFrame<float>> frames;
  for (int i = 0; i < kFrames; ++i) {
    TrainFrame<float> f;
    f.camera = in.true_cameras[std::size_t(i)];
    f.time = float(i) / float(kFrames - 1);
    GaussianScene<float> moved = in.scene;
    const float shift = float(travel * (f.time - 0.5) * f.camera.center().norm());
    for (std::size_t g : by_height) moved.means[3 * g] += shift;
    f.image = r.render(SceneView<float>(moved), f.camera).color;
    frames.push_back(std::move(f));
  }
  return frames;
}

// The still check's state after a deformable training with the check 500
// iterations after a warm-up of 100 (about 20 visits per frame, as in a
// 33-frame video's check), at the given thresholds.
ShortcutState check_after_fit(const std::vector<TrainFrame<float>>& frames, double gain_db, double region_gain_db) {
  TrainParams p;
  p.threads = 1;
  p.background = {1, 1, 1};
  p.min_densify_interval = 50;
  p.iterations = 1000;
  p.deformable = true;
  p.warmup_iterations = 100;
  p.deform_reference_budget = p.iterations;
  p.still_check_iterations = 500;
  p.still_gain_db = gain_db;
  p.still_region_gain_db = region_gain_db;
  InitParams ip;
  ip.random_points = 1500;
  Trainer<float> t(frames, init_random(frame_cameras(frames), ip), p);
  t.train(600);
  REQUIRE(t.shortcuts().still_checked);
  return t.shortcuts();
}

}  // namespace

TEST_CASE("still-scene check: a field fitted to a moving object gains more over its bake than a still one's",
          "[train][levers]") {
  const ShortcutState still = check_after_fit(frames_of(0, 1), -1e6, -1e6);
  const ShortcutState moving = check_after_fit(frames_of(0.3, 1), -1e6, -1e6);
  INFO("the field's gain: still " << still.field_gain_db << " dB, moving " << moving.field_gain_db << " dB");
  // The whole-image gains lie either side of the default threshold, so the
  // check keeps the moving field and bakes the still one. Their separation is
  // pinned looser than the region figure's: the moving fit's gain came out at
  // 1.29 and 1.19 dB with the field's products summed in two orders (Eigen's
  // GEMM, the dense kernels), the still one's at 0.21.
  const TrainParams defaults;
  REQUIRE(moving.field_gain_db > defaults.still_gain_db);
  REQUIRE(still.field_gain_db < defaults.still_gain_db);
  REQUIRE(moving.field_gain_db > still.field_gain_db + 0.75);
  REQUIRE(moving.field_region_gain_db > still.field_region_gain_db + 1.0);
}

TEST_CASE("still-scene check at the default thresholds: a part that moves is kept, a still scene is baked",
          "[train][levers]") {
  const TrainParams defaults;
  const ShortcutState still = check_after_fit(frames_of(0, 1), defaults.still_gain_db, defaults.still_region_gain_db);
  const ShortcutState part = check_after_fit(frames_of(0.3, 0.15), defaults.still_gain_db,
                                             defaults.still_region_gain_db);
  INFO("still: " << still_verdict_text(still));
  INFO("top 15 % of the object moving: " << still_verdict_text(part));
  CHECK_FALSE(part.field_baked);
  // The part's gain is where it moves: its best region gains more than the
  // whole image. (On the held-back frames the whole-image figure, 0.61 dB
  // against 0.25, keeps it too; on the training frames it was under 1.0 dB, the
  // threshold of a check on those.)
  CHECK(part.field_region_gain_db > part.field_gain_db + 0.5);
  // The still scene is below both thresholds and baked. Its best 4 x 4-pixel
  // region moves with rounding (0.77 and 1.27 dB on two machines, 1.64 at
  // 64x64), well under the 3.0 dB region threshold.
  CHECK(still.field_gain_db < defaults.still_gain_db);
  CHECK(still.field_region_gain_db < defaults.still_region_gain_db);
  CHECK(still.field_baked);
}

// Work a scene does not need: the still-scene check that bakes a field which
// gains nothing over its bake, and the plateau stop
// (TrainParams::still_check_iterations, plateau_window), with their checkpoints.
#include <catch2/catch.hpp>
#include <sstream>

#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "train/synthetic_frames.hpp"

using namespace orbitforge;

namespace {

std::vector<TrainFrame<float>> frames_for_levers() { return orbitforge_test::tiny_frames<float>(6, 32); }

TrainParams lever_params() {
  TrainParams p;
  p.iterations = 600;
  p.threads = 1;
  p.background = {1, 1, 1};
  p.min_densify_interval = 50;
  return p;
}

// Deformable, warm-up to 100, the still-scene check at iteration 150.
TrainParams still_check_params() {
  TrainParams p = lever_params();
  p.deformable = true;
  p.warmup_iterations = 100;
  p.deform_reference_budget = p.iterations;
  p.still_check_iterations = 50;
  return p;
}

GaussianScene<float> lever_init(const std::vector<TrainFrame<float>>& frames) {
  InitParams ip;
  ip.random_points = 1500;
  return init_random(frame_cameras(frames), ip);
}

}  // namespace

TEST_CASE("still-scene check: a field that gains too little is baked in and training goes on static",
          "[train][levers]") {
  const auto frames = frames_for_levers();
  TrainParams p = still_check_params();
  p.still_gain_db = 1e6;  // every field gains too little
  const int check_at = 150;
  Trainer<float> t(frames, lever_init(frames), p);
  t.train(check_at - 1);
  REQUIRE(t.field() != nullptr);
  REQUIRE_FALSE(t.last_progress().shortcuts.still_checked);
  // The bake at the check changes the scene by the field's median offsets only.
  const TrainProgress& at = t.step();
  REQUIRE(at.shortcuts.still_checked);
  REQUIRE(at.shortcuts.field_baked);
  REQUIRE(t.field_baked());
  REQUIRE(t.field() == nullptr);
  REQUIRE_FALSE(t.deforming_at(t.iteration() + 1));
  // Static from here; a checkpoint taken now resumes to the same scene.
  std::stringstream ckpt;
  t.save_checkpoint(ckpt);
  t.train(300);
  REQUIRE_FALSE(t.last_progress().deforming);
  Trainer<float> resumed(frames, lever_init(frames), p);
  resumed.load_checkpoint(ckpt);
  REQUIRE(resumed.field_baked());
  REQUIRE(resumed.field() == nullptr);
  resumed.train(300);
  REQUIRE(resumed.scene().means == t.scene().means);
  REQUIRE(resumed.scene().sh == t.scene().sh);

  // A threshold no field misses: training stays deformable.
  p.still_gain_db = -1e6;
  Trainer<float> moving(frames, lever_init(frames), p);
  moving.train(check_at);
  REQUIRE(moving.last_progress().shortcuts.still_checked);
  REQUIRE_FALSE(moving.field_baked());
  REQUIRE(moving.field() != nullptr);
  moving.train(check_at + 1);
  REQUIRE(moving.last_progress().deforming);
}

TEST_CASE("still-scene check: the frames it compares on are held back from training until it has decided",
          "[train][levers]") {
  const auto frames = frames_for_levers();  // 6 frames: frame 3 is held back (still_holdout_every 7)
  TrainParams p = still_check_params();
  p.still_gain_db = -1e6;  // the field is kept, so training goes on deformable
  REQUIRE(still_check_frames(p, frames.size()) == std::vector<std::size_t>{3});
  std::vector<int> before(frames.size(), 0), after(frames.size(), 0);
  Trainer<float> t(frames, lever_init(frames), p);
  t.train(300, [&](const TrainProgress& pr) { (pr.iteration <= 150 ? before : after)[pr.frame] += 1; });
  REQUIRE(t.last_progress().shortcuts.still_checked);
  CHECK(before[3] == 0);
  CHECK(after[3] > 0);
  for (std::size_t i : {0, 1, 2, 4, 5}) CHECK(before[i] > 0);
  // With none held back every frame is drawn from the start.
  p.still_holdout_every = 0;
  std::vector<int> all(frames.size(), 0);
  Trainer<float> u(frames, lever_init(frames), p);
  u.train(150, [&](const TrainProgress& pr) { all[pr.frame] += 1; });
  CHECK(all[3] > 0);
}

TEST_CASE("still-scene check under coarse-to-fine: the iterations up to the check train at full size",
          "[train][levers]") {
  const auto frames = frames_for_levers();
  TrainParams p = still_check_params();
  p.coarse_levels = 1;
  p.coarse_fraction = 0.5;  // iterations 1-300 at half size without the check
  Trainer<float> t(frames, lever_init(frames), p);
  REQUIRE(t.still_check_iteration() == 150);
  int full = 0, half = 0;
  t.train(320, [&](const TrainProgress& pr) {
    REQUIRE(pr.image_level == t.image_level_at(pr.iteration));
    if (pr.iteration <= 150) REQUIRE(pr.image_level == 0);
    (pr.image_level == 0 ? full : half) += 1;
    if (pr.iteration == 150) REQUIRE(pr.shortcuts.still_checked);
  });
  REQUIRE(half == 150);  // 151-300
  REQUIRE(full == 170);
  // Without the check the coarse span starts at the first iteration.
  p.still_check_iterations = 0;
  Trainer<float> plain(frames, lever_init(frames), p);
  REQUIRE(plain.still_check_iteration() == 0);
  REQUIRE(plain.image_level_at(1) == 1);
  REQUIRE(plain.image_level_at(300) == 1);
  REQUIRE(plain.image_level_at(301) == 0);
}

TEST_CASE("plateau stop: training ends once a window of whole passes stops improving", "[train][levers]") {
  const auto frames = frames_for_levers();  // 6 frames: windows of 60 for plateau_window 55
  TrainParams p = lever_params();
  p.iterations = 3000;
  p.densify = false;
  p.plateau_window = 55;
  p.plateau_tolerance = 0.01;
  Trainer<float> t(frames, lever_init(frames), p);
  int windows = 0;
  double previous = 0;
  while (!t.finished()) {
    const TrainProgress& pr = t.step();
    if (pr.iteration % 60 == 0) {
      ++windows;
      REQUIRE(pr.shortcuts.plateau_last > 0);
      if (previous > 0) REQUIRE(pr.shortcuts.plateau_previous == previous);
      previous = pr.shortcuts.plateau_last;
    } else {
      REQUIRE_FALSE(pr.shortcuts.stopped);
    }
  }
  const TrainProgress& last = t.last_progress();
  INFO("stopped at " << last.iteration << " after " << windows << " windows");
  REQUIRE(last.shortcuts.stopped);
  REQUIRE(last.iteration < p.iterations);
  REQUIRE(last.iteration % 60 == 0);
  const ShortcutState& sc = last.shortcuts;
  REQUIRE(sc.plateau_previous - sc.plateau_last < 0.01 * sc.plateau_previous);
  REQUIRE(t.finished());
  REQUIRE_THROWS_WITH(t.step(), Catch::Contains("plateau"));

  // Resumed from a checkpoint before the stop, it stops at the same iteration
  // with the same scene.
  Trainer<float> first(frames, lever_init(frames), p);
  first.train(last.iteration - 90);
  std::stringstream ckpt;
  first.save_checkpoint(ckpt);
  Trainer<float> resumed(frames, lever_init(frames), p);
  resumed.load_checkpoint(ckpt);
  while (!resumed.finished()) resumed.step();
  REQUIRE(resumed.iteration() == last.iteration);
  REQUIRE(resumed.scene().means == t.scene().means);

  // While densification runs (here: until past the budget) no window counts.
  p.densify = true;
  p.iterations = 400;
  p.reference_budget = 400;  // the published schedule unscaled: densification until 15,000
  Trainer<float> densifying(frames, lever_init(frames), p);
  densifying.train(p.iterations);
  REQUIRE(densifying.iteration() == p.iterations);
  REQUIRE_FALSE(densifying.last_progress().shortcuts.stopped);
  REQUIRE(densifying.last_progress().shortcuts.plateau_last == 0);
}

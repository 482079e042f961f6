// Coarse-to-fine training (TrainParams::coarse_levels): the level schedule, and
// a coarse start that still fits the full-size frames.
#include <catch2/catch.hpp>

#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "train/synthetic_frames.hpp"

using namespace orbitforge;

TEST_CASE("coarse-to-fine: the level falls from coarse_levels to 0 over coarse_fraction of the budget",
          "[train][coarse]") {
  TrainParams p;
  p.iterations = 1000;
  REQUIRE(coarse_level_at(p, 1) == 0);  // off by default
  p.coarse_levels = 2;
  p.coarse_fraction = 0.5;
  REQUIRE(coarse_level_at(p, 1) == 2);
  REQUIRE(coarse_level_at(p, 250) == 2);
  REQUIRE(coarse_level_at(p, 251) == 1);
  REQUIRE(coarse_level_at(p, 500) == 1);
  REQUIRE(coarse_level_at(p, 501) == 0);
  REQUIRE(coarse_level_at(p, 1000) == 0);
  p.coarse_levels = 7;
  REQUIRE_THROWS_WITH((Trainer<float>({}, GaussianScene<float>{}, p)), Catch::Contains("Trainer"));
}

TEST_CASE("coarse-to-fine by budget: one level from 10,000 iterations, none below", "[train][coarse]") {
  TrainParams p;
  p.coarse_levels = kCoarseLevelsByBudget;
  for (const auto& [iters, levels] : {std::pair<int, int>{3000, 0}, {5000, 0}, {9999, 0}, {10000, 1}, {30000, 1}}) {
    p.iterations = iters;
    CHECK(resolved_coarse_levels(p) == levels);
  }
  p.coarse_levels = 0;  // an explicit choice holds at any budget
  CHECK(resolved_coarse_levels(p) == 0);
  p.coarse_levels = 2;
  p.iterations = 3000;
  CHECK(resolved_coarse_levels(p) == 2);

  // The trainer trains at the resolved schedule: half size after the still
  // check up to half the budget, at 10,000 iterations only.
  const auto frames = orbitforge_test::tiny_frames<float>(4, 32, 32);
  const auto init = orbitforge_test::tiny_init(frames, 50);
  TrainParams t;
  t.coarse_levels = kCoarseLevelsByBudget;
  t.iterations = 10000;
  const Trainer<float> paper_budget(frames, init, t);
  CHECK(paper_budget.params().coarse_levels == 1);
  CHECK(paper_budget.image_level_at(1) == 1);
  CHECK(paper_budget.image_level_at(5000) == 1);
  CHECK(paper_budget.image_level_at(5001) == 0);
  t.iterations = 3000;
  const Trainer<float> default_budget(frames, init, t);
  CHECK(default_budget.params().coarse_levels == 0);
  CHECK(default_budget.image_level_at(1) == 0);
  t.coarse_levels = -2;
  CHECK_THROWS_WITH((Trainer<float>(frames, init, t)),
                    Catch::Contains("coarse_levels must be 0..6"));
}

TEST_CASE("coarse-to-fine training fits the full-size frames as well as full-size training", "[train][coarse]") {
  const auto frames = orbitforge_test::tiny_frames<float>(6, 48, 64);
  auto fit = [&](int levels) {
    InitParams ip;
    ip.random_points = 2000;
    TrainParams p;
    p.iterations = 600;
    p.threads = 2;
    p.background = {1, 1, 1};
    p.min_densify_interval = 50;
    p.coarse_levels = levels;
    Trainer<float> t(frames, init_random(frame_cameras(frames), ip), p);
    int coarse_steps = 0;
    while (t.iteration() < p.iterations) {
      const TrainProgress& pr = t.step();
      REQUIRE(pr.image_level == coarse_level_at(p, pr.iteration));
      if (pr.image_level > 0) ++coarse_steps;
    }
    double psnr_sum = 0;
    for (const auto& f : frames) psnr_sum += psnr(clamp01(t.render(f.camera, f.time)), f.image);
    return std::make_pair(psnr_sum / double(frames.size()), coarse_steps);
  };
  const auto full = fit(0), coarse = fit(2);
  INFO("full-size " << full.first << " dB, coarse-to-fine " << coarse.first << " dB");
  REQUIRE(full.second == 0);
  REQUIRE(coarse.second == 300);
  REQUIRE(full.first > 20);
  // Tiny scenes vary by about 1.3 dB between builds (the sanitizer build's -O1
  // rounds differently); a wrong coarse camera costs 8 dB.
  REQUIRE(coarse.first > full.first - 2.0);
}

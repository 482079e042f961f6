// The Trainer's parts on their own (train/schedules.hpp, frame_order.hpp,
// coarse_to_fine.hpp, plateau_stop.hpp, still_check.hpp, gaussian_adam.hpp,
// densify_driver.hpp): each decides from its inputs alone, here on synthetic ones.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>
#include <vector>

#include "orbitforge/train/coarse_to_fine.hpp"
#include "orbitforge/train/densify_driver.hpp"
#include "orbitforge/train/frame_order.hpp"
#include "orbitforge/train/gaussian_adam.hpp"
#include "orbitforge/train/plateau_stop.hpp"
#include "orbitforge/train/schedules.hpp"
#include "orbitforge/train/still_check.hpp"

using namespace orbitforge;

TEST_CASE("schedules: learning rates follow lr_init^(1-t) lr_final^t, scaled by the extent", "[train][parts]") {
  TrainParams p;
  p.iterations = 1000;
  const double extent = 2.5;
  const ExponentialLr pos = position_lr(p, extent);
  for (int it : {0, 1, 250, 500, 1000, 2000}) {
    const double t = std::min(1.0, double(it) / 1000.0);
    const double expected = std::pow(p.position_lr_init * extent, 1 - t) * std::pow(p.position_lr_final * extent, t);
    CHECK(pos(it) == Approx(expected).epsilon(1e-12));
  }
  p.position_lr_steps = 400;  // decays over its own steps, then holds lr_final
  CHECK(position_lr(p, 1.0)(200) == Approx(std::sqrt(p.position_lr_init * p.position_lr_final)).epsilon(1e-12));
  CHECK(position_lr(p, 1.0)(800) == Approx(p.position_lr_final).epsilon(1e-12));
  // The field's rate: not scaled by the extent, over the budget by default.
  const ExponentialLr f = deformation_lr(p);
  CHECK(f(0) == Approx(p.deform_lr_init).epsilon(1e-12));
  CHECK(f(500) == Approx(std::sqrt(p.deform_lr_init * p.deform_lr_final)).epsilon(1e-12));
  CHECK(f(1000) == Approx(p.deform_lr_final).epsilon(1e-12));
}

TEST_CASE("schedules: SH interval, warm-up and densification scale with the budget", "[train][parts]") {
  TrainParams p;
  p.iterations = 3000;  // a tenth of the reference budget
  const TrainSchedule s = TrainSchedule::make(p);
  CHECK(s.sh_interval == 100);
  CHECK(s.warmup == 225);  // 3000 * 3000 / 40000
  CHECK(s.densify.densify_until == 1500);
  CHECK(s.raises_sh_degree_at(100));
  CHECK(s.raises_sh_degree_at(300));
  CHECK_FALSE(s.raises_sh_degree_at(150));
  // Densification follows the number of frames as well as the budget.
  p.min_densify_interval = 50;
  CHECK(TrainSchedule::make(p, 29).densify.densify_interval == 50);
  CHECK(TrainSchedule::make(p, 400).densify.densify_interval == 200);
  CHECK(TrainSchedule::make(p, 400).densify.opacity_reset_interval == 1200);
  p.densify_interval_passes = p.opacity_reset_passes = 0;
  CHECK(TrainSchedule::make(p, 400).densify.densify_interval == 50);
  p.iterations = 10;  // the SH interval stays >= 1
  CHECK(TrainSchedule::make(p).sh_interval == 1);
  p.max_sh_degree = 4;
  CHECK_THROWS_WITH(TrainSchedule::make(p), Catch::Contains("max_sh_degree"));
}

TEMPLATE_TEST_CASE("schedules: raising the SH degree keeps the lower bands and zeroes the new one", "[train][parts]",
                   float, double) {
  GaussianScene<TestType> s;
  s.resize(2, 1);
  for (std::size_t i = 0; i < s.sh.size(); ++i) s.sh[i] = TestType(i + 1);
  const std::vector<TestType> before = s.sh;
  raise_sh_degree(s);
  REQUIRE(s.sh_degree == 2);
  REQUIRE(s.sh.size() == 2 * 9 * 3);
  for (std::size_t g = 0; g < 2; ++g)
    for (std::size_t k = 0; k < 27; ++k)
      CHECK(s.sh[g * 27 + k] == (k < 12 ? before[g * 12 + k] : TestType(0)));
}

TEMPLATE_TEST_CASE("schedules: time noise is annealed, divided by the draws left, and off draws nothing",
                   "[train][parts]", float, double) {
  TrainParams p;
  std::mt19937 rng(3), copy = rng;
  CHECK(time_noise_at<TestType>(p, 10, 4, rng) == TestType(0));  // off by default
  CHECK(rng == copy);
  p.time_noise = 0.1;
  p.time_noise_steps = 1000;
  const TestType got = time_noise_at<TestType>(p, 250, 4, rng);
  std::normal_distribution<double> n(0.0, 1.0);
  CHECK(got == TestType(n(copy) * 0.1 * 0.75 / 4.0));
  CHECK(time_noise_at<TestType>(p, 1000, 1, rng) == TestType(0));  // fully annealed
}

TEST_CASE("frame order: every pass is a permutation of the weighted draws, reshuffled each pass",
          "[train][parts]") {
  const std::vector<int> repeats = {1, 3, 2, 1};
  FrameOrder order(repeats);
  REQUIRE(order.pass_length() == 7);
  std::mt19937 rng(11);
  std::vector<std::vector<std::size_t>> passes;
  for (int pass = 0; pass < 4; ++pass) {
    std::vector<std::size_t> drawn;
    for (int k = 0; k < 7; ++k) {
      drawn.push_back(order.next(rng));
      CHECK(order.remaining_with_last() == std::size_t(7 - k));
    }
    passes.push_back(drawn);
    std::vector<int> count(4, 0);
    for (std::size_t f : drawn) ++count.at(f);
    CHECK(count == repeats);
  }
  CHECK(std::any_of(passes.begin() + 1, passes.end(), [&](const auto& p) { return p != passes.front(); }));

  // The same seed gives the same order; a restored order continues it.
  FrameOrder again(repeats), resumed(repeats);
  std::mt19937 rng2(11);
  for (int k = 0; k < 10; ++k) REQUIRE(again.next(rng2) == passes[std::size_t(k / 7)][std::size_t(k % 7)]);
  std::mt19937 rng3 = rng2;
  resumed.restore(again.order(), again.cursor());
  for (int k = 0; k < 10; ++k) REQUIRE(resumed.next(rng3) == again.next(rng2));
  CHECK_THROWS_WITH(resumed.restore(std::vector<std::size_t>(6), 0), Catch::Contains("frame order of 6"));
}

TEMPLATE_TEST_CASE("coarse-to-fine: a level halves the image by 2x2 boxes and the intrinsics with it",
                   "[train][parts]", float, double) {
  TrainFrame<TestType> f;
  f.image = Image<TestType>(5, 4, 3);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 5; ++x)
      for (int c = 0; c < 3; ++c) f.image(x, y, c) = TestType(x + 10 * y + 100 * c);
  f.camera.intrinsics = {TestType(40), TestType(44), TestType(2.5), TestType(2), 5, 4};
  std::vector<TrainFrame<TestType>> frames = {f};
  CoarseFrames<TestType> coarse;
  const TrainFrame<TestType>& h = coarse.at(frames, 0, 1);
  REQUIRE(h.image.width == 2);  // the odd last column is dropped
  REQUIRE(h.image.height == 2);
  for (int y = 0; y < 2; ++y)
    for (int x = 0; x < 2; ++x)
      CHECK(h.image(x, y, 1) == Approx(double(2 * x + 0.5 + 10 * (2 * y + 0.5) + 100)));
  CHECK(h.camera.intrinsics.fx == TestType(20));
  CHECK(h.camera.intrinsics.cy == TestType(1));
  const TrainFrame<TestType>& q = coarse.at(frames, 0, 2);
  CHECK(q.image.width == 1);
  CHECK(q.camera.intrinsics.fy == TestType(11));
  CHECK(coarse.at(frames, 0, 1).image.data == CoarseFrames<TestType>::halved(f).image.data);

  TrainParams p;
  p.iterations = 100;
  p.coarse_levels = 2;
  CHECK(coarse_span_end(p) == 51);
  CHECK(image_level_at(p, 10, 0) == 2);
  CHECK(image_level_at(p, 10, 20) == 0);  // full size up to the still-scene check
}

TEST_CASE("plateau stop: decides on a synthetic loss curve", "[train][parts]") {
  TrainParams p;
  p.iterations = 1000;
  p.plateau_window = 25;
  p.plateau_tolerance = 0.01;
  const PlateauStop stop = PlateauStop::make(p, 6, 100);  // passes of 6 draws: windows of 30
  REQUIRE(stop.window == 30);
  // A loss falling by 10% per window, flat from iteration 301 on.
  auto loss = [](int it) { return it <= 300 ? std::pow(0.9, (it - 1) / 30) : std::pow(0.9, 9); };
  ShortcutState s;
  int stopped_at = 0;
  for (int it = 1; it <= 1000 && !s.stopped; ++it) {
    stop.track(it, loss(it), s);
    if (it == 90) CHECK(s.plateau_last == 0);  // window 61..90 starts before quiet_from (100)
    if (it == 150) CHECK(s.plateau_last == Approx(std::pow(0.9, 4)));
    if (s.stopped) stopped_at = it;
  }
  CHECK(stopped_at == 330);  // the first flat window (301..330) improved on 271..300 by 0%
  CHECK(s.plateau_previous == Approx(s.plateau_last));

  // A negative tolerance only records; a stop at the budget's last iteration is none.
  p.plateau_tolerance = -1;
  ShortcutState r;
  const PlateauStop record = PlateauStop::make(p, 6, 0);
  for (int it = 1; it <= 600; ++it) record.track(it, 1.0, r);
  CHECK_FALSE(r.stopped);
  CHECK(r.plateau_last == 1.0);
  p.plateau_tolerance = 0.01;
  p.iterations = 60;
  ShortcutState e;
  const PlateauStop at_end = PlateauStop::make(p, 6, 0);
  for (int it = 1; it <= 60; ++it) at_end.track(it, 1.0, e);
  CHECK_FALSE(e.stopped);
  CHECK(PlateauStop::make(TrainParams{}, 6, 0).window == 0);  // off by default
}

TEST_CASE("plateau stop: windows count once densification, warm-up, still check and coarse span are over",
          "[train][parts]") {
  TrainParams p;
  p.iterations = 1000;
  const TrainSchedule s = TrainSchedule::make(p);
  CHECK(plateau_quiet_from(p, s, 0) == s.densify.densify_until);
  p.densify = false;
  CHECK(plateau_quiet_from(p, s, 0) == 0);
  p.deformable = true;
  CHECK(plateau_quiet_from(p, s, 0) == s.warmup + 1);
  CHECK(plateau_quiet_from(p, s, s.warmup + 50) == s.warmup + 51);
  p.coarse_levels = 1;
  p.coarse_fraction = 0.9;
  CHECK(plateau_quiet_from(p, s, 0) == 901);
}

TEMPLATE_TEST_CASE("still check: the iteration it runs at, and the PSNR it compares", "[train][parts]", float,
                   double) {
  TrainParams p;
  p.still_check_iterations = 50;
  CHECK(still_check_iteration(p, 100) == 0);  // static training: never
  p.deformable = true;
  CHECK(still_check_iteration(p, 100) == 150);
  Image<TestType> a(2, 2, 3), b(2, 2, 3);
  for (auto& v : a.data) v = TestType(0.5);
  for (auto& v : b.data) v = TestType(0.6);
  CHECK(fit_psnr(a, b) == Approx(20.0).epsilon(1e-5));  // mse 0.01
  CHECK(fit_psnr(a, a) == 100.0);
  for (auto& v : a.data) v = TestType(1.7);  // renders are clamped to [0, 1]
  for (auto& v : b.data) v = TestType(1.0);
  CHECK(fit_psnr(a, b) == 100.0);
}

TEST_CASE("still check: the frames held back for it", "[train][parts]") {
  TrainParams p;  // still_holdout_every 7: frames 3, 10, 17, ...
  CHECK(still_check_frames(p, 29) == std::vector<std::size_t>{3, 10, 17, 24});
  CHECK_FALSE(held_for_still_check(p, 0));
  CHECK(held_for_still_check(p, 10));
  // Too few frames to hold one back: up to 8 spread over all of them.
  CHECK(still_check_frames(p, 3) == std::vector<std::size_t>{0, 1, 2});
  p.still_holdout_every = 0;
  CHECK_FALSE(held_for_still_check(p, 3));
  CHECK(still_check_frames(p, 16) == std::vector<std::size_t>{0, 2, 4, 6, 8, 10, 12, 14});
  p.still_holdout_every = 2;  // every other frame from frame 1
  CHECK(still_check_frames(p, 5) == std::vector<std::size_t>{1, 3});
  p.still_holdout_every = 1;  // would hold back every frame
  CHECK_THROWS_WITH(check_still_params(p), Catch::Contains("still_holdout_every"));
}

TEMPLATE_TEST_CASE("still check: the region figure finds a change the whole-image mean dilutes", "[train][parts]", float,
                   double) {
  // 64x64 frames, regions of 8x8 pixels: the deformed render is off by 0.05
  // everywhere, the bake by 0.2 in regions (2, 5) and (2, 6) and 0.05 elsewhere.
  Image<TestType> frame(64, 64, 3), deformed(64, 64, 3), baked(64, 64, 3);
  for (int y = 0; y < 64; ++y)
    for (int x = 0; x < 64; ++x)
      for (int c = 0; c < 3; ++c) {
        const TestType v = TestType(0.25 + 0.5 * ((x + y + c) % 2));
        frame(x, y, c) = v;
        deformed(x, y, c) = v + TestType(0.05);
        baked(x, y, c) = v + TestType(y / 8 == 2 && (x / 8 == 5 || x / 8 == 6) ? 0.2 : 0.05);
      }
  RegionErrors rd, rb;
  rd.add(deformed, frame);
  rb.add(baked, frame);
  const double expected = 10 * std::log10((0.04 + kStillRegionFloor) / (2.5e-3 + kStillRegionFloor));
  int first = -1, second = -1, third = -1;
  CHECK(region_gain_db(rd, rb, 1, &first) == Approx(expected).epsilon(1e-4));
  CHECK(region_gain_db(rd, rb, 2, &second) == Approx(expected).epsilon(1e-4));
  CHECK(std::abs(region_gain_db(rd, rb, 3, &third)) < 1e-4);  // the other regions gain nothing
  CHECK(first == 2 * kStillRegions + 5);  // equal gains: the lower region first
  CHECK(second == 2 * kStillRegions + 6);
  const double whole = fit_psnr(deformed, frame) - fit_psnr(baked, frame);
  CHECK(whole < 2.0);  // 2 of 64 regions: the mean gains under 2 dB, the regions 11.9 dB
  CHECK(expected > 10.0);
  // Renders are clamped to [0, 1] as fit_psnr's; regions both fit to far below the
  // floor score about 0, not the ratio of two tiny errors.
  RegionErrors exact, near;
  exact.add(frame, frame);
  Image<TestType> off = frame;
  for (auto& v : off.data) v += TestType(1e-3);
  near.add(off, frame);
  CHECK(std::abs(region_gain_db(exact, near, 1)) < 0.05);
  CHECK_THROWS_AS(rd.add(Image<TestType>(8, 8, 3), frame), Error);
  CHECK_THROWS_AS(region_gain_db(rd, rb, 0), Error);
}

TEMPLATE_TEST_CASE("still check: a region both fit closely stays under the region threshold; a moving part's does not",
                   "[train][parts]", float, double) {
  // robot's still recording on the user's path: in a region of backdrop beside
  // the outline the bake's mean squared error was 4.8e-4 and the field's 1.9e-4
  // (3.08 dB with a floor of 1e-4, over the 3.0 dB threshold). A part that moves
  // leaves the bake an error of the order of 1e-2 where the field has 1e-3.
  const auto errors = [](double region_error, double elsewhere) {
    Image<TestType> frame(64, 64, 3), render(64, 64, 3);
    for (int y = 0; y < 64; ++y)
      for (int x = 0; x < 64; ++x)
        for (int c = 0; c < 3; ++c) {
          frame(x, y, c) = TestType(0.5);
          const bool in_region = y / 8 == 3 && x / 8 == 1;
          render(x, y, c) = TestType(0.5 + std::sqrt(in_region ? region_error : elsewhere));
        }
    RegionErrors e;
    e.add(render, frame);
    return e;
  };
  const double threshold = TrainParams{}.still_region_gain_db;
  int region = -1;
  const double backdrop = region_gain_db(errors(1.9e-4, 1e-3), errors(4.8e-4, 1e-3), 1, &region);
  CHECK(region == 3 * kStillRegions + 1);
  CHECK(backdrop == Approx(10 * std::log10((4.8e-4 + kStillRegionFloor) / (1.9e-4 + kStillRegionFloor))).epsilon(1e-3));
  CHECK(backdrop < threshold - 1.5);
  const double part = region_gain_db(errors(1e-3, 1e-3), errors(1e-2, 1e-3), 1, &region);
  CHECK(region == 3 * kStillRegions + 1);
  CHECK(part > threshold + 3.0);
}

TEMPLATE_TEST_CASE("gaussian adam: the SH step updates DC and rest rows at their own rates, bit for bit as row by "
                   "row, at every degree and thread count",
                   "[train][parts]", float, double) {
  using S = TestType;
  TrainParams p;  // max SH degree 3: rest moments are 45 wide at every degree
  const std::size_t n = 1007;  // several parallel blocks and gather chunks, and a ragged last one
  std::mt19937 rng(3);
  std::normal_distribution<double> nd(0.0, 1.0);
  for (int degree = 0; degree <= 3; ++degree) {
    GaussianScene<S> start;
    start.resize(n, degree);
    for (auto& v : start.sh) v = S(nd(rng));
    GaussianSceneGrad<S> grad;
    grad.assign_zero(n, degree);
    std::vector<std::vector<S>> sh_grads(2);
    for (auto& g : sh_grads) {
      g.resize(start.sh.size());
      for (auto& v : g) v = S(0.1 * nd(rng));
    }
    // Reference: each Gaussian's DC and rest rows updated on their own.
    GaussianScene<S> ref = start;
    Adam<S> ref_adam = make_gaussian_adam<S>(p, n);
    const std::size_t k3 = 3 * std::size_t(ref.sh_coefficients()), rw = std::size_t(sh_rest_width(p.max_sh_degree));
    for (const auto& g : sh_grads) {
      auto& dc = ref_adam.group(kShDcGroup);
      auto& rest = ref_adam.group(kShRestGroup);
      const auto cd = AdamStep<S>::of(ref_adam.params(), double(dc.lr), ++dc.step);
      const auto cr = AdamStep<S>::of(ref_adam.params(), double(rest.lr), ++rest.step);
      for (std::size_t i = 0; i < n; ++i) {
        adam_apply(cd, ref.sh.data() + i * k3, g.data() + i * k3, dc.m.data() + 3 * i, dc.v.data() + 3 * i, 3);
        adam_apply(cr, ref.sh.data() + i * k3 + 3, g.data() + i * k3 + 3, rest.m.data() + i * rw,
                   rest.v.data() + i * rw, k3 - 3);
      }
    }
    for (int threads : {1, 2, 3}) {
      INFO("degree " << degree << ", threads " << threads);
      GaussianScene<S> scene = start;
      Adam<S> adam = make_gaussian_adam<S>(p, n);
      for (const auto& g : sh_grads) {
        grad.sh = g;
        step_gaussians(adam, scene, grad, threads);
      }
      CHECK(scene.sh == ref.sh);
      CHECK(adam.group(kShDcGroup).m == ref_adam.group(kShDcGroup).m);
      CHECK(adam.group(kShDcGroup).v == ref_adam.group(kShDcGroup).v);
      CHECK(adam.group(kShRestGroup).m == ref_adam.group(kShRestGroup).m);
      CHECK(adam.group(kShRestGroup).v == ref_adam.group(kShRestGroup).v);
      CHECK(scene.sh != start.sh);
      // Moments of the bands above the active degree stay zero.
      bool above_zero = true;
      for (std::size_t i = 0; i < n; ++i)
        for (std::size_t k = k3 - 3; k < rw; ++k) above_zero = above_zero && adam.group(kShRestGroup).v[i * rw + k] == S(0);
      CHECK(above_zero);
    }
  }
}

TEMPLATE_TEST_CASE("densify driver: opacity resets zero the opacities' moments; off does nothing", "[train][parts]",
                   float, double) {
  TrainParams p;
  p.background = {1, 1, 1};  // white: 3DGS also resets at densify_from (500), where nothing densifies
  GaussianScene<TestType> scene;
  scene.resize(4, 0);
  for (auto& o : scene.opacity_logits) o = TestType(2);
  for (auto& q : scene.rotations) q = TestType(0);
  for (std::size_t i = 0; i < 4; ++i) scene.rotations[4 * i] = TestType(1);
  Adam<TestType> adam = make_gaussian_adam<TestType>(p, 4);
  REQUIRE(adam.group_count() == kGaussianGroupCount);
  REQUIRE(adam.group(kScalesGroup).name == "log_scales");
  for (int g = 0; g < adam.group_count(); ++g) std::fill(adam.group(g).m.begin(), adam.group(g).m.end(), TestType(1));
  DensifyStats<TestType> stats;
  stats.reset(4);
  std::mt19937 rng(0);
  const std::vector<TestType> grad(4, TestType(0));
  const std::vector<std::int32_t> radius(4, 3);
  const TrainSchedule s = TrainSchedule::make(p);
  DensifyDriver<TestType> driver(p, s.densify, 64);
  driver.step(500, 1, grad, radius, scene, stats, adam, TestType(1), rng);  // an opacity reset, level 1
  CHECK(stats.count == std::vector<std::uint32_t>(4, 1));
  CHECK(stats.max_radius == std::vector<TestType>(4, TestType(6)));  // radii in full-size pixels
  CHECK(adam.group(kOpacityGroup).m == std::vector<TestType>(4, TestType(0)));
  CHECK(adam.group(kMeansGroup).m == std::vector<TestType>(12, TestType(1)));
  CHECK(scene.opacity_logits[0] < TestType(-4));
  p.densify = false;
  DensifyDriver<TestType> off(p, s.densify, 64);
  off.step(500, 0, grad, radius, scene, stats, adam, TestType(1), rng);
  CHECK(stats.count == std::vector<std::uint32_t>(4, 1));
}

TEMPLATE_TEST_CASE("densify driver: with a random background, the screen-size limit is a fraction of the frames' "
                   "longer side",
                   "[train][parts]", float, double) {
  using S = TestType;
  TrainParams p;
  p.random_background = true;
  p.densify_params.max_screen_fraction = 0.25;
  p.densify_params.min_gaussians = 0;
  const TrainSchedule s = TrainSchedule::make(p);
  // At the first densification after the first opacity reset (size pruning on),
  // two opaque Gaussians, 40 and 3 pixels in radius on screen.
  const int it = (s.densify.opacity_reset_interval / s.densify.densify_interval + 1) * s.densify.densify_interval;
  REQUIRE(s.densify.densifies_at(it));
  REQUIRE(s.densify.size_prune_at(it));
  for (int side : {128, 256, 0}) {  // 0: a fixed background below, 3DGS's 20 pixels
    p.random_background = side != 0;
    if (side == 0) side = 256;
    GaussianScene<S> scene;
    scene.resize(2, 0);
    scene.opacity_logits = {S(3), S(3)};
    scene.rotations = {S(1), S(0), S(0), S(0), S(1), S(0), S(0), S(0)};
    for (auto& v : scene.log_scales) v = std::log(S(0.001));
    Adam<S> adam = make_gaussian_adam<S>(p, 2);
    DensifyStats<S> stats;
    stats.reset(2);
    std::mt19937 rng(0);
    DensifyDriver<S> driver(p, s.densify, side);
    const DensifyCounts c = driver.step(it, 0, std::vector<S>(2, S(0)), std::vector<std::int32_t>{40, 3}, scene,
                                        stats, adam, S(1), rng);
    INFO("longer side " << side << ", random background " << p.random_background);
    // 0.25 of 128 is 32 pixels: too large; of 256, 64 pixels: it stays; 20 pixels: too large.
    const bool pruned = side == 128 || !p.random_background;
    CHECK(c.pruned == (pruned ? 1u : 0u));
    CHECK(c.pruned_by_size == c.pruned);
    CHECK(scene.size() == (pruned ? 1u : 2u));
  }
}

// Per-frame exposure compensation (train/frame_exposure.hpp): the transform and
// its vector-Jacobian product against finite differences, the recentred step, and
// training on frames whose exposure and white balance differ: the scene keeps the
// frames' average colours, where training without it does not; checkpoints carry
// the transforms.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <sstream>

#include "orbitforge/metrics/image.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/frame_exposure.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"
#include "train/synthetic_frames.hpp"

using namespace orbitforge;

namespace {

template <class S>
FrameExposure<S> random_exposure(std::size_t frames, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-0.3, 0.3);
  std::vector<S> t(frames * 12);
  for (std::size_t f = 0; f < frames; ++f)
    for (int k = 0; k < 12; ++k) t[f * 12 + std::size_t(k)] = S((k < 9 && k % 4 == 0 ? 1.0 : 0.0) + u(rng));
  Adam<S> adam;
  adam.add_group("exposure", frames, 12, S(1e-2));
  return FrameExposure<S>(std::move(t), std::move(adam));
}

template <class S>
Image<S> random_colors(int w, int h, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  Image<S> img(w, h, 3);
  for (auto& v : img.data) v = S(u(rng));
  return img;
}

template <class S>
double dot(const Image<S>& a, const Image<S>& b) {
  double s = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) s += double(a.data[i]) * double(b.data[i]);
  return s;
}

// The frames' colours changed per frame by a gain per channel whose mean over
// the frames is 1 (exposure and white balance), clamped to [0, 1] as a camera would.
template <class S>
std::vector<TrainFrame<S>> exposed(std::vector<TrainFrame<S>> frames) {
  const double pi = 3.14159265358979323846;
  for (std::size_t i = 0; i < frames.size(); ++i) {
    const double a = 2 * pi * double(i) / double(frames.size());
    const double gain[3] = {1 + 0.25 * std::cos(a), 1 + 0.2 * std::sin(a), 1 - 0.2 * std::cos(a + 1)};
    auto& d = frames[i].image.data;
    for (std::size_t p = 0; p < d.size(); ++p) d[p] = S(std::min(1.0, double(d[p]) * gain[p % 3]));
  }
  return frames;
}

TrainParams exposure_train_params(int iterations, bool compensate) {
  TrainParams p = orbitforge_test::tiny_params(iterations);
  p.background = {0.5, 0.5, 0.5};
  p.exposure_compensation = compensate;
  p.exposure_lr = 5e-3;
  return p;
}

}  // namespace

TEMPLATE_TEST_CASE("frame exposure: apply and its vjp match finite differences", "[train][exposure]", float, double) {
  using S = TestType;
  FrameExposure<S> ex = random_exposure<S>(3, 7);
  const Image<S> c = random_colors<S>(5, 4, 1), w = random_colors<S>(5, 4, 2);
  Image<S> out, v_render;
  ex.apply(1, c, out);
  // The transform itself, at one pixel.
  const S* t = ex.transform(1);
  for (int i = 0; i < 3; ++i)
    CHECK(out(2, 3, i) == Approx(t[3 * i] * c(2, 3, 0) + t[3 * i + 1] * c(2, 3, 1) + t[3 * i + 2] * c(2, 3, 2) + t[9 + i])
                              .epsilon(1e-5));
  // L = <w, apply(c)>: v_out = w.
  S v_t[12];
  ex.apply_vjp(1, c, w, v_render, v_t);
  const double h = std::is_same<S, float>::value ? 1e-2 : 1e-5, tol = std::is_same<S, float>::value ? 2e-3 : 1e-8;
  for (int k = 0; k < 12; ++k) {
    std::vector<S> plus = ex.transforms(), minus = ex.transforms();
    plus[12 + std::size_t(k)] += S(h), minus[12 + std::size_t(k)] -= S(h);
    Adam<S> a;
    a.add_group("exposure", 3, 12, S(1e-2));
    const FrameExposure<S> ep(plus, a), em(minus, a);
    Image<S> op, om;
    ep.apply(1, c, op), em.apply(1, c, om);
    const double fd = (dot(op, w) - dot(om, w)) / (2 * h);
    INFO("transform value " << k);
    CHECK(double(v_t[k]) == Approx(fd).epsilon(tol).margin(tol));
  }
  for (std::size_t i = 0; i < c.data.size(); i += 7) {
    Image<S> cp = c, cm = c, op, om;
    cp.data[i] += S(h), cm.data[i] -= S(h);
    ex.apply(1, cp, op), ex.apply(1, cm, om);
    const double fd = (dot(op, w) - dot(om, w)) / (2 * h);
    INFO("render value " << i);
    CHECK(double(v_render.data[i]) == Approx(fd).epsilon(tol).margin(tol));
  }
  // Any thread count gives the same bits.
  Image<S> v2;
  S v_t2[12];
  ex.apply_vjp(1, c, w, v2, v_t2, 3);
  CHECK(v2.data == v_render.data);
  for (int k = 0; k < 12; ++k) CHECK(v_t2[k] == v_t[k]);
}

TEST_CASE("frame exposure: a step moves the drawn frame and keeps the mean transform the identity",
          "[train][exposure]") {
  using S = double;
  FrameExposure<S> ex(4, AdamParams{}, 1e-2);
  for (std::size_t f = 0; f < 4; ++f) CHECK(ex.transform(f)[0] == 1.0);
  S g[12] = {};
  g[0] = 1;   // the red gain of frame 2 is too high
  g[11] = -1; // its blue offset too low
  ex.step(2, g);
  ex.step(2, g);
  CHECK(ex.transform(2)[0] < 1.0);
  CHECK(ex.transform(2)[11] > 0.0);
  CHECK(ex.transform(0)[0] > 1.0);  // the others take the opposite share
  for (int k = 0; k < 12; ++k) {
    double mean = 0;
    for (std::size_t f = 0; f < 4; ++f) mean += ex.transform(f)[k] / 4;
    CHECK(mean == Approx(k < 9 && k % 4 == 0 ? 1.0 : 0.0).margin(1e-12));
  }
  // Only frame 2's moments moved.
  const auto& m = ex.optimizer().group(0).m;
  for (std::size_t i = 0; i < m.size(); ++i) CHECK((m[i] != 0) == (i == 24 || i == 35));
  CHECK_THROWS_AS(ex.step(4, g), Error);
  CHECK_THROWS_AS(FrameExposure<S>(4, AdamParams{}, 0.0), Error);
}

TEST_CASE("frame exposure: the mapped render is clipped to [0, 1] as the frame's file was", "[train][exposure]") {
  using S = double;
  // A frame shot 1.2x brighter: its white backdrop is 1 in the file, and 1.2 mapped.
  // (Frame 1, 0.8x, keeps the mean the identity.)
  std::vector<S> t = {1.2, 0, 0, 0, 1.2, 0, 0, 0, 1.2, 0, 0, 0, 0.8, 0, 0, 0, 0.8, 0, 0, 0, 0.8, 0, 0, 0};
  Adam<S> adam;
  adam.add_group("exposure", 2, 12, S(1e-2));
  FrameExposure<S> ex(t, adam);
  const Image<S> white(8, 8, 3, S(1));
  Image<S> v;
  SsimWorkspace<S> ws;
  const LossTerms<S> loss = ex.loss_and_step(0, white, white, v, ws, 0.2, 1);
  CHECK(loss.total == Approx(0).margin(1e-12));
  for (S g : v.data) CHECK(g == 0);
  CHECK(ex.transform(0)[0] == 1.2);  // no gradient: the gain stays
  // Below the clip the gradient flows: a grey frame mapped too bright.
  const Image<S> grey(8, 8, 3, S(0.5));
  ex.loss_and_step(0, grey, grey, v, ws, 0.2, 1);
  CHECK(v.data[0] > 0);
  CHECK(ex.transform(0)[0] < 1.2);
}

TEST_CASE("frame exposure: training on frames of differing exposure keeps the scene's colours", "[train][exposure]") {
  using S = float;
  const auto clean = orbitforge_test::tiny_frames<S>(8, 32, 0, {0.5, 0.5, 0.5});
  const auto frames = exposed(clean);
  const int iters = 400;
  auto fit = [&](bool compensate, std::vector<double>* red_gains) {
    Trainer<S> t(frames, orbitforge_test::tiny_init(frames), exposure_train_params(iters, compensate));
    t.train(iters);
    // The scene alone, against the frames before their exposure changed.
    RenderParams<S> rp;
    rp.threads = 1;
    rp.background = {0.5f, 0.5f, 0.5f};
    Renderer<S> r(rp);
    double mean = 0;
    for (const auto& f : clean) mean += psnr(r.render(SceneView<S>(t.scene()), f.camera).color, f.image) / 8;
    if (red_gains)
      for (std::size_t f = 0; f < 8; ++f) red_gains->push_back(double(t.exposure().transform(f)[0]));
    return mean;
  };
  std::vector<double> red;
  const double without = fit(false, nullptr), with = fit(true, &red);
  INFO("scene against the clean frames: " << without << " dB without compensation, " << with << " dB with");
  CHECK(with > without + 2);
  // The learned red gains follow the frames' 1 + 0.25 cos(2 pi f / 8) (part of the way in 50 steps per
  // frame): their correlation with it over the frames.
  double sx = 0, sy = 0, sxx = 0, syy = 0, sxy = 0;
  for (std::size_t f = 0; f < 8; ++f) {
    const double x = std::cos(2 * 3.14159265358979323846 * double(f) / 8), y = red[f];
    sx += x, sy += y, sxx += x * x, syy += y * y, sxy += x * y;
  }
  const double corr = (8 * sxy - sx * sy) / std::sqrt((8 * sxx - sx * sx) * (8 * syy - sy * sy));
  INFO("red gains, frame 0 and 4: " << red[0] << ", " << red[4] << "; correlation with the truth " << corr);
  CHECK(corr > 0.9);
  CHECK(red[0] > red[4] + 0.08);
}

TEST_CASE("frame exposure: checkpoints carry the transforms, and a mismatch is refused", "[train][exposure]") {
  using S = float;
  const auto frames = exposed(orbitforge_test::tiny_frames<S>(8, 24, 0, {0.5, 0.5, 0.5}));
  const int budget = 60, n = 23;
  Trainer<S> full(frames, orbitforge_test::tiny_init(frames), exposure_train_params(budget, true));
  full.train(budget);
  Trainer<S> first(frames, orbitforge_test::tiny_init(frames), exposure_train_params(budget, true));
  first.train(n);
  std::stringstream ss(std::ios::in | std::ios::out | std::ios::binary);
  first.save_checkpoint(ss);
  const std::string bytes = ss.str();
  Trainer<S> resumed(frames, orbitforge_test::tiny_init(frames), exposure_train_params(budget, true));
  resumed.load_checkpoint(ss);
  resumed.train(budget);
  CHECK(resumed.exposure().transforms() == full.exposure().transforms());
  CHECK(resumed.scene().means == full.scene().means);
  CHECK(resumed.scene().sh == full.scene().sh);

  std::stringstream again(bytes, std::ios::in | std::ios::binary);
  Trainer<S> plain(frames, orbitforge_test::tiny_init(frames), exposure_train_params(budget, false));
  CHECK_THROWS_WITH(plain.load_checkpoint(again), Catch::Contains("with exposure compensation"));
  CHECK(plain.iteration() == 0);
}

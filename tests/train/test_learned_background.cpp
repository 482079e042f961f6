// A background colour learned with the scene (train/learned_background.hpp): its
// gradient through the renderer and the sigmoid against finite differences, its
// step, training on frames over a coloured backdrop (the colour is found, and the
// model leaves the backdrop to it), checkpoints, and the settings it refuses.
#include <catch2/catch.hpp>

#include <cmath>
#include <sstream>

#include "orbitforge/metrics/image.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/learned_background.hpp"
#include "orbitforge/train/trainer.hpp"
#include "train/synthetic_frames.hpp"

using namespace orbitforge;

namespace {

TrainParams learned_params(int iterations, bool learned) {
  TrainParams p = orbitforge_test::tiny_params(iterations);
  p.background = {0.5, 0.5, 0.5};
  p.learned_background = learned;
  return p;
}

const std::array<double, 3> kBackdrop{{0.8, 0.3, 0.2}};

}  // namespace

TEMPLATE_TEST_CASE("learned background: the logits' gradient through the renderer matches finite differences",
                   "[train][background]", float, double) {
  using S = TestType;
  const auto frames = orbitforge_test::tiny_frames<S>(3, 24);
  const GaussianScene<S> scene = orbitforge_test::tiny_init(frames);
  const Camera<S>& camera = frames[0].camera;
  // L(u) = <w, render(background = sigmoid(u))> for a fixed weight image w.
  Image<S> w(camera.intrinsics.width, camera.intrinsics.height, 3);
  for (std::size_t i = 0; i < w.data.size(); ++i) w.data[i] = S(std::sin(0.37 * double(i)) + 0.2);
  const LearnedBackground<S> bg({0.6, 0.35, 0.25}, AdamParams{}, 1e-2);
  RenderParams<S> rp;
  rp.threads = 1;
  Renderer<S> r(rp);
  auto loss = [&](const std::array<S, 3>& color) {
    r.params().background = color;
    const Image<S>& img = r.render(SceneView<S>(scene), camera).color;
    double l = 0;
    for (std::size_t i = 0; i < img.data.size(); ++i) l += double(img.data[i]) * double(w.data[i]);
    return l;
  };
  loss(bg.color());
  r.backward(SceneView<S>(scene), camera, w);
  const std::array<S, 3> v_u = bg.logit_gradient(r.background_gradient());
  // Some of the image is uncovered, so the background matters.
  CHECK(std::abs(double(r.background_gradient()[0])) > 1);
  const double h = std::is_same<S, float>::value ? 1e-2 : 1e-5, tol = std::is_same<S, float>::value ? 2e-3 : 1e-8;
  for (int c = 0; c < 3; ++c) {
    auto at = [&](double du) {
      std::vector<S> u = bg.logits();
      u[std::size_t(c)] += S(du);
      Adam<S> a;
      a.add_group("background", 1, 3, S(1e-2));
      return loss(LearnedBackground<S>(u, a).color());
    };
    const double fd = (at(h) - at(-h)) / (2 * h);
    INFO("channel " << c << ": analytic " << v_u[std::size_t(c)] << ", finite difference " << fd);
    CHECK(double(v_u[std::size_t(c)]) == Approx(fd).epsilon(tol).margin(tol));
  }
}

TEST_CASE("learned background: steps move the colour to the one the gradient asks for", "[train][background]") {
  using S = double;
  LearnedBackground<S> bg({0.5, 0.5, 0.5}, AdamParams{}, 5e-2);
  for (int i = 0; i < 400; ++i) {
    const std::array<S, 3> c = bg.color();
    bg.step({c[0] - kBackdrop[0], c[1] - kBackdrop[1], c[2] - kBackdrop[2]});  // d/dc of |c - target|^2 / 2
  }
  for (int c = 0; c < 3; ++c) CHECK(bg.color()[std::size_t(c)] == Approx(kBackdrop[std::size_t(c)]).margin(0.01));
  // Colours at the ends stay inside (0, 1); bad settings are refused.
  const LearnedBackground<S> edge({0, 1, 2}, AdamParams{}, 1e-2);
  for (S v : edge.color()) CHECK((v > 0 && v < 1));
  CHECK_THROWS_WITH(LearnedBackground<S>({0.5, 0.5, 0.5}, AdamParams{}, 0), Catch::Contains("learning rate"));
  CHECK_THROWS_WITH(LearnedBackground<S>({0.5, std::nan(""), 0.5}, AdamParams{}, 1e-2), Catch::Contains("finite"));
  CHECK_FALSE(LearnedBackground<S>().enabled());
  CHECK_THROWS_AS(LearnedBackground<S>().color(), Error);
}

TEST_CASE("learned background: training finds the backdrop's colour, and the model leaves the backdrop to it",
          "[train][background]") {
  using S = float;
  const auto frames = orbitforge_test::tiny_frames<S>(8, 32, 0, kBackdrop);
  const int iters = 400;
  Trainer<S> t(frames, orbitforge_test::tiny_init(frames), learned_params(iters, true));
  t.train(iters);
  const std::array<S, 3> color = t.background();
  // The same model at its learned colour and at the grey it started from: where
  // it leaves the backdrop uncovered, only the learned colour matches the frames.
  RenderParams<S> rp;
  rp.threads = 1;
  rp.background = {0.5f, 0.5f, 0.5f};
  Renderer<S> grey(rp);
  double at_learned = 0, at_grey = 0;
  for (const auto& f : frames) {
    at_learned += psnr(t.render(f.camera, f.time), f.image) / double(frames.size());
    at_grey += psnr(grey.render(SceneView<S>(t.scene()), f.camera).color, f.image) / double(frames.size());
  }
  INFO("learned colour " << color[0] << ", " << color[1] << ", " << color[2] << "; training PSNR " << at_learned
                         << " dB at it, " << at_grey << " dB at the starting grey");
  for (int c = 0; c < 3; ++c) CHECK(color[std::size_t(c)] == Approx(kBackdrop[std::size_t(c)]).margin(0.05));
  CHECK(at_learned > at_grey + 3);
}

TEST_CASE("learned background: checkpoints carry the colour, resume exactly, and a mismatch is refused",
          "[train][background]") {
  using S = float;
  const auto frames = orbitforge_test::tiny_frames<S>(6, 24, 0, kBackdrop);
  const int budget = 60, n = 23;
  Trainer<S> full(frames, orbitforge_test::tiny_init(frames), learned_params(budget, true));
  full.train(budget);
  Trainer<S> first(frames, orbitforge_test::tiny_init(frames), learned_params(budget, true));
  first.train(n);
  std::stringstream ss(std::ios::in | std::ios::out | std::ios::binary);
  first.save_checkpoint(ss);
  Trainer<S> resumed(frames, orbitforge_test::tiny_init(frames), learned_params(budget, true));
  resumed.load_checkpoint(ss);
  CHECK(resumed.background() == first.background());
  CHECK(resumed.background() != full.background());  // the colour moved after iteration n
  resumed.train(budget);
  CHECK(resumed.background() == full.background());
  CHECK(resumed.scene().means == full.scene().means);

  std::stringstream again(std::ios::in | std::ios::out | std::ios::binary);
  first.save_checkpoint(again);
  Trainer<S> without(frames, orbitforge_test::tiny_init(frames), learned_params(budget, false));
  CHECK_THROWS_WITH(without.load_checkpoint(again), Catch::Contains("learned background"));

  TrainParams both = learned_params(budget, true);
  both.random_background = true;
  CHECK_THROWS_WITH(Trainer<S>(frames, orbitforge_test::tiny_init(frames), both), Catch::Contains("exclude each other"));
}

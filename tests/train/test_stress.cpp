// Numerics stress suite (docs/numerics.md): results must not depend on where or
// how big the recorded model is, degenerate Gaussians must not poison forward or
// backward passes, a camera may sit inside a Gaussian, and float training must
// follow double training. Each bound sits above the figure measured when it was
// set (stated beside it) and well below what the failure it guards against gives.
//
// The recorded model is moved in double (as a loader reads a COLMAP model) and
// brought into the normalised frame (splat/scene_frame.hpp) before the Scalar
// maths, as load_colmap_input(..., normalise = true) does.
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <vector>

#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/splat/scene_frame.hpp"
#include "orbitforge/train/init.hpp"
#include "orbitforge/train/trainer.hpp"

using namespace orbitforge;

namespace stress {

// A small synthetic scene in double: its ground truth and 8 cameras, 32 x 32.
struct World {
  GaussianScene<double> scene;
  std::vector<Camera<double>> cameras;
};

World small_world() {
  SyntheticInputParams p;
  p.frames = p.source_frames = 8;
  p.width = p.height = 32;
  p.focal = 40;
  p.object_gaussians = 200;
  p.ground_gaussians = 100;
  const auto in = make_synthetic_input<double>(p);
  return {in.scene, in.true_cameras};
}

// The world as a user would record it: every length times s, then moved by d.
Camera<double> relocate(const Camera<double>& c, double s, const Eigen::Vector3d& d) {
  return Camera<double>::from_world_T_camera(c.R.transpose(), s * c.center() + d, c.intrinsics);
}
GaussianScene<double> relocate(GaussianScene<double> g, double s, const Eigen::Vector3d& d) {
  for (std::size_t i = 0; i < g.size(); ++i)
    for (int a = 0; a < 3; ++a) g.means[3 * i + std::size_t(a)] = s * g.means[3 * i + std::size_t(a)] + d[a];
  for (auto& v : g.log_scales) v += std::log(s);
  return g;
}

// What the Scalar maths sees of a moved world: normalised in double, then cast.
template <class S>
struct Seen {
  SceneFrame frame;
  GaussianScene<S> scene;
  std::vector<Camera<S>> cameras;
};

template <class S>
Seen<S> seen(const World& w, double s, const Eigen::Vector3d& d, bool normalise = true) {
  std::vector<Camera<double>> cams;
  std::vector<Eigen::Vector3d> centres;
  for (const auto& c : w.cameras) cams.push_back(relocate(c, s, d)), centres.push_back(cams.back().center());
  Seen<S> r;
  if (normalise) r.frame = fit_scene_frame(centres);
  r.scene = r.frame.to_normalised(relocate(w.scene, s, d)).template cast<S>();
  for (const auto& c : cams) r.cameras.push_back(r.frame.to_normalised(c).template cast<S>());
  return r;
}

template <class S>
std::vector<Image<S>> render_all(const GaussianScene<S>& g, const std::vector<Camera<S>>& cams) {
  RenderParams<S> rp;
  rp.threads = 1;
  rp.background = {S(1), S(1), S(1)};
  Renderer<S> r(rp);
  std::vector<Image<S>> out;
  for (const auto& c : cams) out.push_back(r.render(SceneView<S>(g), c).color);
  return out;
}

template <class S>
double max_abs_diff(const std::vector<Image<S>>& a, const std::vector<Image<S>>& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.size(); ++i)
    for (std::size_t j = 0; j < a[i].data.size(); ++j) {
      const double d = std::abs(double(a[i].data[j]) - double(b[i].data[j]));
      m = std::isfinite(d) ? std::max(m, d) : 1e30;
    }
  return m;
}

// The moves of the suite: translations up to 1e6 and scales 1e-4 .. 1e4.
struct Move {
  double s;
  Eigen::Vector3d d;
};
std::vector<Move> moves() {
  return {{1, {3.9e3, 0, 0}}, {1, {1.2e5, -7e4, 5e4}}, {1, {1e6, 1e6, -1e6}}, {1e-4, {0, 0, 0}},
          {1e-3, {0, 0, 0}},  {1e4, {0, 0, 0}},        {1e-4, {1e6, 0, 0}}, {1e4, {-1e6, 2e6, 1e6}}};
}

template <class S>
TrainParams short_training(int iterations) {
  TrainParams p;
  p.iterations = iterations;
  p.threads = 1;
  p.seed = 5;
  p.background = {1, 1, 1};
  p.densify_schedule.densify_interval = 1000;  // few densifications: small, fast scenes
  return p;
}

// Trains from the ground-truth means (grey, 3DGS initial scales) on the frames the
// true scene gives at the seen cameras; returns the mean PSNR over those frames.
template <class S>
double train_psnr(const Seen<S>& v, const std::vector<Image<S>>& targets, int iterations) {
  std::vector<TrainFrame<S>> frames;
  for (std::size_t i = 0; i < v.cameras.size(); ++i) {
    TrainFrame<S> f;
    f.camera = v.cameras[i];
    f.image = targets[i];
    f.time = S(0);
    frames.push_back(std::move(f));
  }
  std::vector<S> colors(v.scene.means.size(), S(0.5));
  InitParams ip;
  ip.seed = 3;
  Trainer<S> t(frames, init_from_points(v.scene.means, colors, ip), short_training<S>(iterations));
  t.train(iterations);
  double p = 0;
  for (const auto& f : frames) p += psnr(clamp01(t.render(f.camera, S(0))), f.image) / double(frames.size());
  return p;
}

template <class S, class A>
bool all_finite(const std::vector<S, A>& v) {
  for (S x : v)
    if (!std::isfinite(x)) return false;
  return true;
}

}  // namespace stress

TEMPLATE_TEST_CASE("stress: renders of a moved or rescaled model match the unmoved one", "[train][stress]", float,
                   double) {
  using S = TestType;
  const stress::World w = stress::small_world();
  const auto base_view = stress::seen<S>(w, 1, Eigen::Vector3d::Zero());
  const auto base = stress::render_all(base_view.scene, base_view.cameras);
  for (const auto& m : stress::moves()) {
    CAPTURE(m.s, m.d.norm());
    const auto v = stress::seen<S>(w, m.s, m.d);
    const double diff = stress::max_abs_diff(base, stress::render_all(v.scene, v.cameras));
    // The bound: the working precision, plus how finely the user's own frame (double)
    // holds a model of size s at distance |d|, relative to its size. Measured: float
    // <= 6.6e-7 (eps 1.2e-7), double 1.4e-9 at s = 1 and |d| = 1e6, and 1.05e-5 at
    // s = 1e-4 and |d| = 1e6 (the input itself resolves only 2.2e-6 of the model
    // there). Before scene_frame's "one place" threshold was fixed that case gave 0.93.
    const double user_eps = std::numeric_limits<double>::epsilon() * m.d.norm() / m.s;
    CHECK(diff < 50 * (double(std::numeric_limits<S>::epsilon()) + user_eps));
    // Outputs go back to the user's frame: means within double rounding of the move.
    const auto back = v.frame.to_user(v.scene.template cast<double>());
    const auto moved = stress::relocate(w.scene, m.s, m.d);
    double err = 0;
    for (std::size_t i = 0; i < back.means.size(); ++i)
      err = std::max(err, std::abs(back.means[i] - moved.means[i]) / m.s);
    // Measured (relative to the model's size): float <= 1.26e-7 (its own rounding), double
    // printed as 0.0 by Catch (below 1e-10).
    CHECK(err < (sizeof(S) == 4 ? 1e-6 : 1e-9));
  }
  if (sizeof(S) == 4) {
    // Without the normalised frame the float maths fails at 1e6: the check can fail.
    const auto raw = stress::seen<S>(w, 1, {1e6, 1e6, -1e6}, /*normalise=*/false);
    // Measured: 0.73 (parts of the object land pixels away).
    CHECK(stress::max_abs_diff(base, stress::render_all(raw.scene, raw.cameras)) > 0.05);
  }
}

TEMPLATE_TEST_CASE("stress: a short training on a moved or rescaled model matches the unmoved one",
                   "[train][stress]", float, double) {
  using S = TestType;
  const int iterations = 50;  // about 1 s (release); the sanitizer build runs the same
  const stress::World w = stress::small_world();
  const auto base_view = stress::seen<S>(w, 1, Eigen::Vector3d::Zero());
  const auto targets = stress::render_all(base_view.scene, base_view.cameras);
  const double base = stress::train_psnr(base_view, targets, iterations);
  INFO("unmoved: " << base << " dB");
  // Measured at 50 iterations: 15.15 dB in float and double (23.03 dB at 200): the
  // check says that training ran, the comparison below is the point.
  CHECK(base > 13);
  for (const auto& m : {stress::moves()[2], stress::moves()[3], stress::moves()[7]}) {
    CAPTURE(m.s, m.d.norm());
    const double p = stress::train_psnr(stress::seen<S>(w, m.s, m.d), targets, iterations);
    // Measured at 50 iterations: double <= 2.5e-9 dB, float <= 1.8e-6 dB (at 200:
    // double 5.6e-5 dB at a 1e6 move).
    CHECK(std::abs(p - base) < (sizeof(S) == 4 ? 0.1 : 1e-3));
  }
}

TEMPLATE_TEST_CASE("stress: degenerate Gaussians give finite images and gradients", "[train][stress]", float,
                   double) {
  using S = TestType;
  const stress::World w = stress::small_world();
  const auto v = stress::seen<S>(w, 1, Eigen::Vector3d::Zero());
  GaussianScene<S> g = v.scene;
  // Among the ordinary ones: tiny, huge, near-zero quaternion, saturated opacities.
  const std::size_t n = g.size();
  for (std::size_t i = 0; i < 3; ++i) g.log_scales[3 * 0 + i] = S(std::log(1e-8));
  for (std::size_t i = 0; i < 3; ++i) g.log_scales[3 * 1 + i] = S(std::log(1e4));
  g.log_scales[3 * 2] = S(std::log(1e4));  // one axis huge, one tiny: a needle
  g.log_scales[3 * 2 + 1] = S(std::log(1e-8));
  for (int k = 0; k < 4; ++k) g.rotations[4 * 3 + std::size_t(k)] = S(1e-30);
  for (int k = 0; k < 4; ++k) g.rotations[4 * 4 + std::size_t(k)] = S(k == 1 ? 1e-19 : 0);
  g.opacity_logits[5] = S(40);
  g.opacity_logits[6] = S(-40);
  g.opacity_logits[1] = S(40);  // the huge one, opaque: it covers every view
  REQUIRE(n > 7);
  RenderParams<S> rp;
  rp.threads = 1;
  Renderer<S> r(rp);
  std::size_t visible = 0, visible_intact = 0;
  for (const auto& cam : v.cameras) {
    visible_intact += r.render(SceneView<S>(v.scene), cam).frame.projection.visible;
    const auto& out = r.render(SceneView<S>(g), cam);
    CHECK(stress::all_finite(out.color.data));
    visible += out.frame.projection.visible;
    Image<S> v_color(cam.intrinsics.width, cam.intrinsics.height, 3);
    for (std::size_t j = 0; j < v_color.data.size(); ++j) v_color.data[j] = S(j % 7) / S(7) - S(0.4);
    const auto& gr = r.backward(SceneView<S>(g), cam, v_color);
    CHECK(stress::all_finite(gr.means));
    CHECK(stress::all_finite(gr.rotations));
    CHECK(stress::all_finite(gr.scales));
    CHECK(stress::all_finite(gr.opacity_logits));
    CHECK(stress::all_finite(gr.sh));
  }
  // At most the 7 damaged Gaussians lost per view. Measured visible: 2235 (float), 2247
  // (double) over the 8 views; the intact count was not recorded.
  CHECK(visible + 7 * v.cameras.size() >= visible_intact);
  // And training through them stays finite.
  std::vector<TrainFrame<S>> frames;
  const auto targets = stress::render_all(v.scene, v.cameras);
  for (std::size_t i = 0; i < v.cameras.size(); ++i) {
    frames.emplace_back();
    frames.back().image = targets[i];
    frames.back().camera = v.cameras[i];
  }
  Trainer<S> t(frames, g, stress::short_training<S>(30));
  t.train(30);
  CHECK(stress::all_finite(t.scene().means));
  CHECK(stress::all_finite(t.scene().log_scales));
  CHECK(stress::all_finite(t.scene().sh));
}

TEMPLATE_TEST_CASE("stress: a camera inside a Gaussian", "[train][stress]", float, double) {
  using S = TestType;
  GaussianScene<S> g;
  g.resize(2, 0);
  // Gaussian 0 around the camera (at the origin, looking along +z): mean just in
  // front of the near plane, scale 1 (the camera is half a sigma from its centre).
  g.means = {S(0), S(0), S(0.5), S(0), S(0), S(5)};
  g.log_scales = {S(0), S(0), S(0), S(-1), S(-1), S(-1)};
  g.opacity_logits = {S(0), S(2)};
  g.sh = {S(1), S(0), S(0), S(0), S(0), S(1)};
  Camera<S> cam;
  cam.intrinsics = {S(40), S(40), S(16), S(16), 32, 32};
  RenderParams<S> rp;
  rp.threads = 1;
  Renderer<S> r(rp);
  const auto& out = r.render(SceneView<S>(g), cam);
  CHECK(out.frame.projection.visible == 2);
  CHECK(stress::all_finite(out.color.data));
  // The near Gaussian fills the view: alpha 0.5 at the centre, and no pixel
  // shows the background unblended. Measured: largest transmittance 0.518.
  double tmax = 0;
  for (S tr : out.transmittance.data) tmax = std::max(tmax, double(tr));
  CHECK(tmax < 0.6);
  Image<S> v_color(32, 32, 3);
  for (auto& x : v_color.data) x = S(1);
  const auto& gr = r.backward(SceneView<S>(g), cam, v_color);
  CHECK(stress::all_finite(gr.means));
  CHECK(stress::all_finite(gr.scales));
  CHECK(stress::all_finite(gr.rotations));
  // At and behind the camera: culled, not NaN.
  g.means[2] = S(0);
  const auto& at = r.render(SceneView<S>(g), cam);
  CHECK(at.frame.projection.culled_near == 1);
  CHECK(stress::all_finite(at.color.data));
}

TEST_CASE("stress: float training follows double training", "[train][stress]") {
  // 2,000 iterations take minutes (docs/numerics.md gives that run); CI runs 100.
  const int iterations = 100;
  const stress::World w = stress::small_world();
  const auto vd = stress::seen<double>(w, 1, Eigen::Vector3d::Zero());
  const auto vf = stress::seen<float>(w, 1, Eigen::Vector3d::Zero());
  const auto targets_d = stress::render_all(vd.scene, vd.cameras);
  std::vector<Image<float>> targets_f;
  for (const auto& im : targets_d) {
    Image<float> f(im.width, im.height, im.channels);
    for (std::size_t j = 0; j < im.data.size(); ++j) f.data[j] = float(im.data[j]);
    targets_f.push_back(std::move(f));
  }
  const double pd = stress::train_psnr(vd, targets_d, iterations);
  const double pf = stress::train_psnr(vf, targets_f, iterations);
  INFO("double " << pd << " dB, float " << pf << " dB");
  // Measured at 2,000 iterations: double 49.44 dB, float 48.08 dB (1.35 dB apart, both at
  // an MSE near 1e-5 where float rounding sets the floor); at 100: float 19.35 dB,
  // 0.18 dB from double.
  CHECK(std::abs(pd - pf) < 0.5);
  CHECK(pf > 17);
}

// A host's own storage rendered through an adaptor: an array of structs in double
// precision with activated scales and (x, y, z, w) quaternions, as another
// renderer might keep them. Its images and gradients must equal those of the
// library's own SoA scene holding the same Gaussians.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <type_traits>
#include <vector>

#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"

using namespace orbitforge;

namespace {

struct HostGaussian {
  double position[3];
  double quat_xyzw[4];
  double sigma[3];   // standard deviations
  double opacity;    // in (0, 1)
  double rgb_dc[3];  // degree-0 SH
};

struct HostAdaptor {
  using scalar_type = double;
  static constexpr ScaleMode scale_mode = ScaleMode::activated;
  const std::vector<HostGaussian>* g;
  std::size_t size() const { return g->size(); }
  int sh_degree() const { return 0; }
  void mean(std::size_t i, double out[3]) const {
    for (int a = 0; a < 3; ++a) out[a] = (*g)[i].position[a];
  }
  void rotation(std::size_t i, double out[4]) const {  // the library wants w first
    const auto& q = (*g)[i].quat_xyzw;
    out[0] = q[3], out[1] = q[0], out[2] = q[1], out[3] = q[2];
  }
  void scale(std::size_t i, double out[3]) const {
    for (int a = 0; a < 3; ++a) out[a] = (*g)[i].sigma[a];
  }
  double opacity_logit(std::size_t i) const { return std::log((*g)[i].opacity / (1 - (*g)[i].opacity)); }
  double sh(std::size_t i, int, int c) const { return (*g)[i].rgb_dc[c]; }
};

struct MissingScaleMode {
  using scalar_type = float;
  std::size_t size() const { return 0; }
  int sh_degree() const { return 0; }
  void mean(std::size_t, float*) const {}
  void rotation(std::size_t, float*) const {}
  void scale(std::size_t, float*) const {}
  float opacity_logit(std::size_t) const { return 0; }
  float sh(std::size_t, int, int) const { return 0; }
};

static_assert(is_scene_adaptor_v<HostAdaptor>, "the host adaptor satisfies the contract");
static_assert(is_scene_adaptor_v<SceneView<float>> && is_scene_adaptor_v<SceneView<double>>,
              "the library's own view satisfies it");
static_assert(!is_scene_adaptor_v<MissingScaleMode>, "a missing scale_mode is detected");
static_assert(!is_scene_adaptor_v<int>, "a non-adaptor is detected");

// Random Gaussians in front of the default camera, as the host's structs and as
// the library's SoA scene.
void make_host_scene(std::mt19937& rng, std::vector<HostGaussian>& host, GaussianScene<double>& scene) {
  std::uniform_real_distribution<double> u(-1, 1), pos(0.05, 0.95);
  host.resize(300);
  scene.resize(host.size(), 0);
  for (std::size_t i = 0; i < host.size(); ++i) {
    HostGaussian& h = host[i];
    for (int a = 0; a < 3; ++a) h.position[a] = 0.8 * u(rng);
    h.position[2] += 4;
    double n = 0;
    for (double& q : h.quat_xyzw) {
      q = u(rng);
      n += q * q;
    }
    for (double& q : h.quat_xyzw) q /= std::sqrt(n);
    for (double& s : h.sigma) s = 0.03 + 0.1 * pos(rng);
    h.opacity = pos(rng);
    for (double& c : h.rgb_dc) c = u(rng);
    for (int a = 0; a < 3; ++a) {
      scene.means[3 * i + a] = h.position[a];
      scene.log_scales[3 * i + a] = std::log(h.sigma[a]);
      scene.sh[3 * i + a] = h.rgb_dc[a];
    }
    scene.rotations[4 * i] = h.quat_xyzw[3];
    for (int a = 0; a < 3; ++a) scene.rotations[4 * i + 1 + a] = h.quat_xyzw[a];
    scene.opacity_logits[i] = std::log(h.opacity / (1 - h.opacity));
  }
}

// Random host Gaussians (as structs and as the library's scene), a 64x48 camera
// at the origin looking down +z, and a random dL/d(colour) for it.
struct HostFixture {
  std::mt19937 rng;
  std::vector<HostGaussian> host;
  GaussianScene<double> scene;
  Camera<double> cam;
  Image<double> v{64, 48, 3};
  explicit HostFixture(unsigned seed) : rng(seed) {
    make_host_scene(rng, host, scene);
    cam.intrinsics = {60, 60, 32, 24, 64, 48};
    std::uniform_real_distribution<double> gv(-1, 1);
    for (double& x : v.data) x = gv(rng);
  }
  HostAdaptor adaptor() const { return HostAdaptor{&host}; }
};
}  // namespace

TEST_CASE("an array-of-structs double adaptor renders and differentiates like the library's scene",
          "[splat][adaptor]") {
  HostFixture fx(3);
  const auto& [rng, host, scene, cam, v] = fx;
  const HostAdaptor adaptor = fx.adaptor();

  Renderer<double> a, b;
  const Image<double> img_host = a.render(adaptor, cam).color;
  const Image<double> img_lib = b.render(SceneView<double>(scene), cam).color;
  REQUIRE(a.render(adaptor, cam).frame.gaussians_visible > 100);
  double max_diff = 0;
  for (std::size_t k = 0; k < img_host.data.size(); ++k)
    max_diff = std::max(max_diff, std::abs(img_host.data[k] - img_lib.data[k]));
  REQUIRE(max_diff < 1e-12);

  // Gradients in each adaptor's own parametrisation: activated scales get
  // d/ds = (d/d log s) / s; means, opacity logits and SH agree; the quaternion
  // gradient is in the order the adaptor returned it (w first).
  const GaussianSceneGrad<double> g_host = a.backward(adaptor, cam, v);
  const GaussianSceneGrad<double> g_lib = b.backward(SceneView<double>(scene), cam, v);
  double worst = 0, largest = 0;
  for (std::size_t i = 0; i < host.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double d_scale = g_host.scales[3 * i + c];  // the field holds d/d(what scale() returned)
      const double expect = g_lib.scales[3 * i + c] / host[i].sigma[c];
      worst = std::max(worst, std::abs(d_scale - expect));
      largest = std::max(largest, std::abs(expect));
      REQUIRE(g_host.means[3 * i + c] == Approx(g_lib.means[3 * i + c]).margin(1e-12));
    }
  REQUIRE(largest > 1e-3);
  REQUIRE(worst <= 1e-9 * largest);
  for (std::size_t i = 0; i < host.size(); ++i) {
    REQUIRE(g_host.opacity_logits[i] == Approx(g_lib.opacity_logits[i]).margin(1e-12));
    for (int k = 0; k < 4; ++k) REQUIRE(g_host.rotations[4 * i + k] == Approx(g_lib.rotations[4 * i + k]).margin(1e-12));
  }
}

TEST_CASE("backward writes into the host's own arrays, in the host's parametrisation", "[splat][adaptor]") {
  HostFixture fx(5);
  auto& [rng, host, scene, cam, v] = fx;  // the finite differences below move host values
  const HostAdaptor adaptor = fx.adaptor();

  Renderer<double> lib;
  lib.render(SceneView<double>(scene), cam);
  const GaussianSceneGrad<double> g = lib.backward(SceneView<double>(scene), cam, v);

  // The host keeps one gradient struct per Gaussian; one field is not asked for
  // and must stay untouched.
  struct HostGrad {
    double xyz[3], quat_xyzw[4], sigma[3], log_sigma[3], opacity, logit, rgb_dc[3], untouched;
  };
  const double nan = std::numeric_limits<double>::quiet_NaN();
  std::vector<HostGrad> hg(host.size(), HostGrad{{nan, nan, nan}, {nan, nan, nan, nan}, {nan, nan, nan},
                                                 {nan, nan, nan}, nan, nan, {nan, nan, nan}, 7.0});
  SceneGradView<double> view;
  view.size = hg.size();
  const std::ptrdiff_t stride = sizeof(HostGrad);
  view.means = strided(hg[0].xyz, stride);
  view.rotations = strided(hg[0].quat_xyzw, stride);
  view.rotation_order = QuatOrder::xyzw;
  view.scales = strided(hg[0].sigma, stride);
  view.log_scales = strided(hg[0].log_sigma, stride);
  view.opacities = strided(&hg[0].opacity, stride);
  view.opacity_logits = strided(&hg[0].logit, stride);
  view.sh = strided(hg[0].rgb_dc, stride);
  view.sh_coefficients = 1;
  Renderer<double> r;
  r.render(adaptor, cam);
  r.backward(adaptor, cam, v, view);

  double largest_sigma = 0;
  for (std::size_t i = 0; i < host.size(); ++i) {
    const HostGrad& h = hg[i];
    const double o = host[i].opacity;
    for (int a = 0; a < 3; ++a) {
      REQUIRE(h.xyz[a] == Approx(g.means[3 * i + a]).margin(1e-12));
      REQUIRE(h.log_sigma[a] == Approx(g.scales[3 * i + a]).margin(1e-12));
      REQUIRE(h.sigma[a] == Approx(g.scales[3 * i + a] / host[i].sigma[a]).margin(1e-10));
      REQUIRE(h.rgb_dc[a] == Approx(g.sh[3 * i + a]).margin(1e-12));
      largest_sigma = std::max(largest_sigma, std::abs(h.sigma[a]));
    }
    REQUIRE(h.quat_xyzw[3] == Approx(g.rotations[4 * i]).margin(1e-12));
    for (int a = 0; a < 3; ++a) REQUIRE(h.quat_xyzw[a] == Approx(g.rotations[4 * i + 1 + a]).margin(1e-12));
    REQUIRE(h.logit == Approx(g.opacity_logits[i]).margin(1e-12));
    REQUIRE(h.opacity * o * (1 - o) == Approx(g.opacity_logits[i]).margin(1e-12));
    REQUIRE(h.untouched == 7.0);
  }
  REQUIRE(largest_sigma > 1e-3);

  // Finite differences of L = <v, colour> in the host's own parameters.
  auto loss = [&] {
    Renderer<double> f;
    const Image<double>& c = f.render(adaptor, cam).color;
    double l = 0;
    for (std::size_t k = 0; k < c.data.size(); ++k) l += v.data[k] * c.data[k];
    return l;
  };
  int checked = 0;
  for (std::size_t i = 0; i < host.size() && checked < 6; i += 37) {
    if (std::abs(hg[i].opacity) < 1e-3) continue;
    const double h = 1e-6;
    auto fd = [&](double& x) {
      const double x0 = x;
      x = x0 + h;
      const double lp = loss();
      x = x0 - h;
      const double lm = loss();
      x = x0;
      return (lp - lm) / (2 * h);
    };
    REQUIRE(fd(host[i].opacity) == Approx(hg[i].opacity).epsilon(1e-4).margin(1e-7));
    REQUIRE(fd(host[i].sigma[0]) == Approx(hg[i].sigma[0]).epsilon(1e-4).margin(1e-7));
    REQUIRE(fd(host[i].quat_xyzw[1]) == Approx(hg[i].quat_xyzw[1]).epsilon(1e-4).margin(1e-7));
    ++checked;
  }
  REQUIRE(checked >= 3);

  // A view of the wrong size is refused before anything is written.
  SceneGradView<double> small = view;
  small.size = host.size() - 1;
  REQUIRE_THROWS_WITH(r.backward(adaptor, cam, v, small), Catch::Contains("gradient view is for 299 Gaussians"));
}

namespace {
// Struct-of-arrays Gaussians with standard deviations (ScaleMode::activated) in
// precision S, SH degree 1.
template <class S>
struct ActivatedScene {
  using scalar_type = S;
  static constexpr ScaleMode scale_mode = ScaleMode::activated;
  std::vector<S> means, quats, sigmas, logits, coefficients;
  std::size_t size() const { return logits.size(); }
  int sh_degree() const { return 1; }
  void mean(std::size_t i, S out[3]) const { std::copy_n(&means[3 * i], 3, out); }
  void rotation(std::size_t i, S out[4]) const { std::copy_n(&quats[4 * i], 4, out); }
  void scale(std::size_t i, S out[3]) const { std::copy_n(&sigmas[3 * i], 3, out); }
  S opacity_logit(std::size_t i) const { return logits[i]; }
  S sh(std::size_t i, int k, int c) const { return coefficients[(4 * i + std::size_t(k)) * 3 + std::size_t(c)]; }
  template <class T>
  ActivatedScene<T> cast() const {
    auto to = [](const std::vector<S>& v) { return std::vector<T>(v.begin(), v.end()); };
    return {to(means), to(quats), to(sigmas), to(logits), to(coefficients)};
  }
};
}  // namespace

TEMPLATE_TEST_CASE("the activated scale gradient is d loss / d sigma (finite differences)", "[splat][adaptor][grad]",
                   float, double) {
  using S = TestType;
  std::mt19937 rng(41);
  std::uniform_real_distribution<double> u(-1, 1), pos(0, 1);
  ActivatedScene<double> sd;
  const std::size_t n = 60;
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) sd.means.push_back(0.7 * u(rng) + (a == 2 ? 4 : 0));
    for (int a = 0; a < 4; ++a) sd.quats.push_back(u(rng));
    for (int a = 0; a < 3; ++a) sd.sigmas.push_back(0.05 + 0.12 * pos(rng));
    sd.logits.push_back(1.5 * u(rng));
    for (int k = 0; k < 12; ++k) sd.coefficients.push_back(0.5 * u(rng));
  }
  Camera<double> cam_d;
  cam_d.intrinsics = {60, 60, 32, 24, 64, 48};
  Image<double> v_d(64, 48, 3);
  for (double& x : v_d.data) x = u(rng);
  auto loss = [&](const ActivatedScene<double>& s) {  // <v, colour>, in double
    Renderer<double> r;
    const Image<double>& c = r.render(s, cam_d).color;
    double l = 0;
    for (std::size_t k = 0; k < c.data.size(); ++k) l += v_d.data[k] * c.data[k];
    return l;
  };

  // The analytic gradient in precision S.
  const ActivatedScene<S> s = sd.cast<S>();
  Camera<S> cam;
  cam.intrinsics = {S(60), S(60), S(32), S(24), 64, 48};
  Image<S> v(64, 48, 3);
  for (std::size_t k = 0; k < v.data.size(); ++k) v.data[k] = S(v_d.data[k]);
  Renderer<S> r;
  r.render(s, cam);
  const GaussianSceneGrad<S>& g = r.backward(s, cam, v);
  REQUIRE(g.scale_mode == ScaleMode::activated);
  REQUIRE(g.scales.size() == 3 * n);
  double largest = 0;
  for (S x : g.scales) largest = std::max(largest, std::abs(double(x)));
  REQUIRE(largest > 1e-2);

  // Central differences in double on every sigma with a gradient worth checking.
  const double rel = std::is_same<S, float>::value ? 2e-3 : 1e-6;
  int checked = 0;
  for (std::size_t j = 0; j < 3 * n; ++j) {
    if (std::abs(double(g.scales[j])) < 0.05 * largest) continue;
    const double h = 1e-6, x0 = sd.sigmas[j];
    sd.sigmas[j] = x0 + h;
    const double lp = loss(sd);
    sd.sigmas[j] = x0 - h;
    const double lm = loss(sd);
    sd.sigmas[j] = x0;
    const double fd = (lp - lm) / (2 * h);
    INFO("sigma " << j << ": analytic " << g.scales[j] << ", finite differences " << fd);
    CHECK(std::abs(double(g.scales[j]) - fd) <= rel * (largest + std::abs(fd)));
    ++checked;
  }
  REQUIRE(checked >= 10);
}

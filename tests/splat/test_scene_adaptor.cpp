// A host's own storage rendered through an adaptor: an array of structs in double
// precision with activated scales and (x, y, z, w) quaternions, as another
// renderer might keep them. Its images and gradients must equal those of the
// library's own SoA scene holding the same Gaussians.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>

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

}  // namespace

TEST_CASE("an array-of-structs double adaptor renders and differentiates like the library's scene",
          "[splat][adaptor]") {
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1), pos(0.05, 0.95);
  std::vector<HostGaussian> host(300);
  GaussianScene<double> scene;
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
  Camera<double> cam;
  cam.intrinsics = {60, 60, 32, 24, 64, 48};
  const HostAdaptor adaptor{&host};

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
  Image<double> v(64, 48, 3);
  std::uniform_real_distribution<double> gv(-1, 1);
  for (double& x : v.data) x = gv(rng);
  const GaussianSceneGrad<double> g_host = a.backward(adaptor, cam, v);
  const GaussianSceneGrad<double> g_lib = b.backward(SceneView<double>(scene), cam, v);
  double worst = 0, largest = 0;
  for (std::size_t i = 0; i < host.size(); ++i)
    for (int c = 0; c < 3; ++c) {
      const double d_scale = g_host.log_scales[3 * i + c];  // the field holds d/d(what scale() returned)
      const double expect = g_lib.log_scales[3 * i + c] / host[i].sigma[c];
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

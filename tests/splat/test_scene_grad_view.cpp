// SceneGradView's layout contract: the SH extent bounds what is written (a host
// array of DC terms only is never overrun by a higher-degree adaptor; a longer
// one gets zeros past the adaptor's coefficients), and unsafe strides, pointers
// or extents are refused naming the field, before anything is written.
#include <catch2/catch.hpp>

#include <cstdint>
#include <random>
#include <vector>

#include "orbitforge/splat/renderer.hpp"

using namespace orbitforge;

namespace {

// Random Gaussians of SH degree `degree` in front of a 64x48 camera at the
// origin looking down +z, rendered once, and a random dL/d(colour).
struct GradViewFixture {
  GaussianScene<double> scene;
  Camera<double> cam;
  Image<double> v{64, 48, 3};
  Renderer<double> r;
  GaussianSceneGrad<double> lib;  // the same gradients in the library's own arrays
  GradViewFixture(int degree, unsigned seed) {
    std::mt19937 rng(seed);
    std::uniform_real_distribution<double> u(-1, 1);
    scene.resize(120, degree);
    for (std::size_t i = 0; i < scene.size(); ++i) {
      for (int a = 0; a < 3; ++a) scene.means[3 * i + a] = 0.8 * u(rng) + (a == 2 ? 4 : 0);
      for (int a = 0; a < 4; ++a) scene.rotations[4 * i + a] = u(rng);
      for (int a = 0; a < 3; ++a) scene.log_scales[3 * i + a] = -2.6 + 0.5 * u(rng);
      scene.opacity_logits[i] = 1.5 * u(rng);
    }
    for (double& c : scene.sh) c = 0.5 * u(rng);
    cam.intrinsics = {60, 60, 32, 24, 64, 48};
    for (double& x : v.data) x = u(rng);
    r.render(SceneView<double>(scene), cam);
    lib = r.backward(SceneView<double>(scene), cam, v);
  }
  void backward_into(const SceneGradView<double>& view) { r.backward(SceneView<double>(scene), cam, v, view); }
};

constexpr double kGuard = 7.0;  // a value no gradient of these scenes takes

}  // namespace

TEST_CASE("a DC-only host SH array is not overrun by a higher-degree adaptor", "[splat][grad_view]") {
  for (int degree : {1, 3}) {
    GradViewFixture fx(degree, 11u + unsigned(degree));
    const std::size_t n = fx.scene.size(), k_lib = std::size_t(sh_coefficient_count(degree));
    // Packed [N][3], then a guard zone as long as the rest of a degree-3 layout.
    std::vector<double> host(3 * n + 3 * 15, kGuard);
    SceneGradView<double> view;
    view.size = n;
    view.sh = strided(host.data(), 3 * sizeof(double));
    view.sh_coefficients = 1;
    fx.backward_into(view);
    double largest = 0;
    for (std::size_t i = 0; i < n; ++i)
      for (int c = 0; c < 3; ++c) {
        REQUIRE(host[3 * i + c] == Approx(fx.lib.sh[k_lib * 3 * i + c]).margin(1e-12));
        largest = std::max(largest, std::abs(host[3 * i + c]));
      }
    REQUIRE(largest > 1e-4);
    for (std::size_t j = 3 * n; j < host.size(); ++j) REQUIRE(host[j] == kGuard);
  }
}

TEST_CASE("a host SH array longer than the adaptor's gets zeros past its coefficients", "[splat][grad_view]") {
  GradViewFixture fx(1, 21);
  const std::size_t n = fx.scene.size();
  // 16 coefficients per Gaussian, coefficient-major, with a padded channel triple
  // (4 values) or packed (3: the backward copies each Gaussian's run at once),
  // then a guard value per Gaussian.
  for (const std::size_t kCoef : {std::size_t(4), std::size_t(3)}) {
    INFO("values per coefficient " << kCoef);
    const std::size_t kPer = 16 * kCoef + 1;
    std::vector<double> host(n * kPer, kGuard);
    SceneGradView<double> view;
    view.size = n;
    view.sh = strided(host.data(), std::ptrdiff_t(kPer * sizeof(double)));
    view.sh_coefficients = 16;
    view.sh_coefficient_stride_bytes = kCoef * sizeof(double);
    fx.backward_into(view);
    int nonzero_rest = 0;
    for (std::size_t i = 0; i < n; ++i) {
      const double* h = &host[i * kPer];
      for (std::size_t k = 0; k < 16; ++k) {
        for (int c = 0; c < 3; ++c) {
          const double expect = k < 4 ? fx.lib.sh[(4 * i + k) * 3 + std::size_t(c)] : 0.0;
          REQUIRE(h[kCoef * k + std::size_t(c)] == Approx(expect).margin(1e-12));
          if (k >= 1 && k < 4 && expect != 0) ++nonzero_rest;
        }
        if (kCoef == 4) REQUIRE(h[kCoef * k + 3] == kGuard);  // the padding
      }
      REQUIRE(h[kPer - 1] == kGuard);
    }
    REQUIRE(nonzero_rest > 0);
  }
}

TEST_CASE("unsafe gradient-view layouts are refused by field name before anything is written", "[splat][grad_view]") {
  GradViewFixture fx(2, 31);
  const std::size_t n = fx.scene.size();
  std::vector<double> buf(16 * 3 * n + 8, kGuard);
  const std::ptrdiff_t d = sizeof(double);
  struct Field {
    const char* name;
    Strided<double> SceneGradView<double>::*member;
    std::ptrdiff_t values;  // written per Gaussian
  };
  const Field fields[] = {{"means", &SceneGradView<double>::means, 3},
                          {"rotations", &SceneGradView<double>::rotations, 4},
                          {"scales", &SceneGradView<double>::scales, 3},
                          {"log_scales", &SceneGradView<double>::log_scales, 3},
                          {"opacities", &SceneGradView<double>::opacities, 1},
                          {"opacity_logits", &SceneGradView<double>::opacity_logits, 1},
                          {"screen_grad_norm", &SceneGradView<double>::screen_grad_norm, 1},
                          {"screen_grad_ndc_norm", &SceneGradView<double>::screen_grad_ndc_norm, 1}};
  auto refused = [&](const SceneGradView<double>& view, const std::string& what) {
    INFO(what);
    REQUIRE_THROWS_WITH(fx.backward_into(view), Catch::Contains(what));
    for (double x : buf) REQUIRE(x == kGuard);
  };
  for (const Field& f : fields) {
    const std::string name = std::string("SceneGradView::") + f.name;
    SceneGradView<double> view;
    view.size = n;
    view.*(f.member) = strided(buf.data(), f.values * d);
    fx.backward_into(view);  // the packed layout is accepted
    std::fill(buf.begin(), buf.end(), kGuard);
    view.*(f.member) = strided(buf.data(), 0);
    refused(view, name + ": stride_bytes is 0");
    view.*(f.member) = strided(buf.data(), f.values * d - d);
    refused(view, name + ": stride_bytes is " + std::to_string(f.values * d - d));
    view.*(f.member) = strided(buf.data(), f.values * d + 1);
    refused(view, name + ": stride_bytes " + std::to_string(f.values * d + 1) + " is not a multiple");
    view.*(f.member) = strided(reinterpret_cast<double*>(reinterpret_cast<char*>(buf.data()) + 1), 8 * d);
    refused(view, name + ": the pointer is not aligned");
  }
  SceneGradView<double> view;
  view.size = n;
  view.sh = strided(buf.data(), 3 * d);
  refused(view, "SceneGradView::sh_coefficients is 0");
  view.sh_coefficients = 17;
  refused(view, "SceneGradView::sh_coefficients is 17");
  view.sh_coefficients = 9;  // the adaptor's own extent, but packed for 1
  refused(view, "SceneGradView::sh: stride_bytes is 24, shorter than the 216 bytes");
  view.sh = strided(buf.data(), 9 * 3 * d);
  view.sh_coefficient_stride_bytes = 2 * d;
  refused(view, "SceneGradView::sh_coefficient_stride_bytes is 16");
  view.sh_coefficient_stride_bytes = 3 * d;
  fx.backward_into(view);
  for (std::size_t j = 0; j < 27 * n; ++j) REQUIRE(buf[j] == Approx(fx.lib.sh[j]).margin(1e-12));
}

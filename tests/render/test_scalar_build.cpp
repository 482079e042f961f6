// The renderer compiled with ORBITFORGE_NO_SIMD (the scalar build every kernel
// must keep): native_batch is the one-lane scalar batch here, and the results
// must match the reference with the same tolerances as the SIMD build (the
// rasterizer on given splats, the full renderer on a scene), and its backward
// must match finite differences.
#define ORBITFORGE_NO_SIMD 1
#include <catch2/catch.hpp>

#include "orbitforge/splat/renderer.hpp"
#include "render/reference_renderer.hpp"

using namespace orbitforge;
using namespace orbitforge_test;

static_assert(simd::native_batch<float>::size == 1, "ORBITFORGE_NO_SIMD must select the scalar kernels");
static_assert(ORBITFORGE_SIMD_ENABLED == 0, "ORBITFORGE_NO_SIMD must disable the xsimd path");

TEMPLATE_TEST_CASE("scalar build matches the reference", "[render][scalar]", float, double) {
  using S = TestType;
  const double tol = sizeof(S) == 4 ? 1e-5 : 1e-10;
  const std::array<S, 3> bg{{S(0.2), S(0.5), S(0.9)}};
  for (int tile : {7, 16}) {
    auto s = random_splats<S>(500, 45, 33, 1);
    BinWorkspace<S> bins;
    bin_splats(s, 45, 33, tile, bins);
    RasterParams<S> p;
    p.background = bg;
    p.threads = 2;
    RasterOutput<S> out;
    RasterWorkspace<S> ws;
    rasterize(bins, p, out, ws);
    const auto ref = reference_rasterize(s, 45, 33, bg);
    CHECK(max_abs_diff(out.color, ref.color) <= tol);
    CHECK(max_abs_diff(out.depth, ref.depth) <= 20 * tol);
    CHECK(max_abs_diff(out.count, ref.count) == 0);
  }
}

TEMPLATE_TEST_CASE("scalar build: the full renderer matches the independent reference", "[render][scalar]", float,
                   double) {
  using S = TestType;
  std::mt19937 rng(8);
  std::uniform_real_distribution<double> u(-1, 1);
  GaussianScene<S> scene;
  scene.resize(300, 2);
  for (std::size_t i = 0; i < scene.size(); ++i) {
    for (int a = 0; a < 3; ++a) scene.means[3 * i + a] = S(u(rng));
    for (int a = 0; a < 4; ++a) scene.rotations[4 * i + a] = S(u(rng));
    for (int a = 0; a < 3; ++a) scene.log_scales[3 * i + a] = S(-2.3 + 0.6 * u(rng));
    scene.opacity_logits[i] = S(1.5 * u(rng));
  }
  for (auto& v : scene.sh) v = S(0.4 * u(rng));
  Camera<S> cam;
  cam.intrinsics = {S(50), S(50), S(21.3), S(14.8), 41, 29};
  cam.R = Eigen::AngleAxis<S>(S(0.2), Eigen::Matrix<S, 3, 1>(S(0.3), S(1), S(-0.2)).normalized()).toRotationMatrix();
  cam.t = Eigen::Matrix<S, 3, 1>(S(0.1), S(0.05), S(4));
  RenderParams<S> p;
  p.background = {{S(0.2), S(0.5), S(0.9)}};
  p.threads = 2;
  Renderer<S> r(p);
  const ReferenceComparison c = compare_with_reference(r.render(SceneView<S>(scene), cam), SceneView<S>(scene), cam,
                                                       p.background);
  INFO("fragile pixels " << c.fragile << " of " << c.pixels);
  CHECK(c.worst_color <= reference_tol<S>());
  CHECK(c.worst_T <= reference_tol<S>());
  CHECK(c.count_mismatch == 0);
  CHECK(c.fragile * 25 <= c.pixels + 25);
}

TEST_CASE("scalar build backward matches finite differences", "[render][scalar][grad]") {
  RandomSplatOptions o;
  o.opacity_max = 0.9;
  o.sigma_min = 1.5;
  o.sigma_max = 6;
  auto s = random_splats<double>(25, 20, 17, 2, o);
  clear_thresholds(s, 20, 17, 1e-3);
  Imaged wc(20, 17, 3);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (auto& v : wc.data) v = u(rng);
  RasterParams<double> p;
  auto loss = [&](const ProjectedSplats<double>& sp) {
    BinWorkspace<double> bins;
    bin_splats(sp, 20, 17, 8, bins);
    RasterOutput<double> out;
    RasterWorkspace<double> ws;
    rasterize(bins, p, out, ws);
    double L = 0;
    for (std::size_t i = 0; i < wc.data.size(); ++i) L += wc.data[i] * out.color.data[i];
    return L;
  };
  BinWorkspace<double> bins;
  bin_splats(s, 20, 17, 8, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize(bins, p, out, ws);
  RasterGradOutput<double> g;
  rasterize_vjp(bins, p, out, wc, nullptr, nullptr, s.size(), g, ws);
  double scale = 0;
  for (double x : g.splats.v_mean_x) scale = std::max(scale, std::abs(x));
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (s.radius[i] <= 0) continue;
    const double x0 = s.mean_x[i], h = 1e-5;
    s.mean_x[i] = x0 + h;
    const double lp = loss(s);
    s.mean_x[i] = x0 - h;
    const double lm = loss(s);
    s.mean_x[i] = x0;
    const double fd = (lp - lm) / (2 * h);
    CHECK(std::abs(fd - g.splats.v_mean_x[i]) <= 1e-6 * std::max(std::abs(fd), 1e-2 * scale));
  }
}

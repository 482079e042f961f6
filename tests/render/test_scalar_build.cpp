// The renderer compiled with ORBITFORGE_NO_SIMD (the scalar build every kernel
// must keep): native_batch is the one-lane scalar batch here. Every forward and
// VJP is instantiated in float and double and checked: the rasterizer and the
// full renderer against the independent reference, with the SIMD build's
// tolerances; the batch projection and its VJP against the per-Gaussian
// reference (project_gaussian / project_gaussian_vjp) as the SIMD build's tests
// check them; SH and the whole backward (both Renderer::backward forms, log and
// activated adaptors) against finite differences in double, and float against
// double.
#define ORBITFORGE_NO_SIMD 1
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <type_traits>
#include <vector>

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

namespace {

// Random Gaussians in front of a 41x29 camera, SH degree `degree`.
template <class S>
GaussianScene<S> scalar_scene(std::size_t n, int degree, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  GaussianScene<S> scene;
  scene.resize(n, degree);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) scene.means[3 * i + a] = S(0.7 * u(rng));
    for (int a = 0; a < 4; ++a) scene.rotations[4 * i + a] = S(u(rng));
    for (int a = 0; a < 3; ++a) scene.log_scales[3 * i + a] = S(-2.0 + 0.5 * u(rng));
    scene.opacity_logits[i] = S(1.5 * u(rng));
  }
  for (auto& v : scene.sh) v = S(0.4 * u(rng));
  return scene;
}

template <class S>
Camera<S> scalar_camera() {
  Camera<S> cam;
  cam.intrinsics = {S(40), S(40), S(20.5), S(14.5), 41, 29};
  cam.R = Eigen::AngleAxis<S>(S(0.2), Eigen::Matrix<S, 3, 1>(S(0.3), S(1), S(-0.2)).normalized()).toRotationMatrix();
  cam.t = Eigen::Matrix<S, 3, 1>(S(0.1), S(0.05), S(3.5));
  return cam;
}

template <class T, class S>
std::vector<T> cast_all(const std::vector<S>& v) { return std::vector<T>(v.begin(), v.end()); }

template <class T, class S>
GaussianScene<T> cast_scene(const GaussianScene<S>& s) {
  GaussianScene<T> t;
  t.resize(s.size(), s.sh_degree);
  t.means = cast_all<T>(s.means);
  t.rotations = cast_all<T>(s.rotations);
  t.log_scales = cast_all<T>(s.log_scales);
  t.opacity_logits = cast_all<T>(s.opacity_logits);
  t.sh = cast_all<T>(s.sh);
  return t;
}

// Largest |a - b| over the largest |b|: a relative error of a whole group.
template <class A, class AA, class B, class BA>
double group_error(const std::vector<A, AA>& a, const std::vector<B, BA>& b) {
  REQUIRE(a.size() == b.size());
  double worst = 0, largest = 0;
  for (std::size_t i = 0; i < a.size(); ++i) {
    worst = std::max(worst, std::abs(double(a[i]) - double(b[i])));
    largest = std::max(largest, std::abs(double(b[i])));
  }
  REQUIRE(largest > 0);
  return worst / largest;
}

}  // namespace

TEMPLATE_TEST_CASE("scalar build: the batch projection and its VJP match the per-Gaussian reference",
                   "[render][scalar]", float, double) {
  using S = TestType;
  const double tol = std::is_same<S, float>::value ? 2e-4 : 1e-10;
  for (int degree : {0, 1, 3}) {
    const GaussianScene<S> scene = scalar_scene<S>(200, degree, 30u + unsigned(degree));
    const SceneView<S> view(scene);
    const Camera<S> camera = scalar_camera<S>();
    const ProjectionParams pp;
    ProjectedSplats<S> out;
    ProjectionStats stats;
    project_scene(view, camera, pp, out, &stats, 2);
    const auto cam = ProjectionCamera<S>::make(camera, pp);
    const int k_count = sh_coefficient_count(degree);
    std::mt19937 rng(7);
    std::uniform_real_distribution<double> u(-1, 1);
    ProjectedSplatsGrad<S> v_in;
    v_in.assign_zero(scene.size());
    for (auto* f : {&v_in.v_mean_x, &v_in.v_mean_y, &v_in.v_conic_a, &v_in.v_conic_b, &v_in.v_conic_c,
                    &v_in.v_opacity, &v_in.v_color_r, &v_in.v_color_g, &v_in.v_color_b, &v_in.v_depth})
      for (auto& x : *f) x = S(u(rng));
    GaussianSceneGrad<S> g;
    project_scene_vjp(view, camera, pp, out, v_in, g, Freeze{}, 2);
    REQUIRE(stats.visible > 50);
    std::size_t compared = 0;
    for (std::size_t i = 0; i < scene.size(); ++i) {
      S sh_buf[48];
      GaussianParams<S> p;
      detail::gather_gaussian(view, i, degree, p, sh_buf);
      Splat<S> ref;
      project_gaussian(cam, p, ref);
      INFO("degree " << degree << " Gaussian " << i);
      REQUIRE(out.radius[i] == ref.radius);
      if (ref.radius == 0) continue;
      const S got[] = {out.mean_x[i], out.mean_y[i], out.conic_a[i], out.conic_b[i], out.conic_c[i], out.opacity[i],
                       out.color_r[i], out.color_g[i], out.color_b[i], out.depth[i]};
      const S want[] = {ref.mean_x, ref.mean_y, ref.conic_a, ref.conic_b, ref.conic_c, ref.opacity,
                        ref.color[0], ref.color[1], ref.color[2], ref.depth};
      for (int f = 0; f < 10; ++f) CHECK(double(got[f]) == Approx(double(want[f])).epsilon(tol).margin(tol));
      // The VJP of this Gaussian by the reference, in the adaptor's parametrisation (log s).
      SplatGrad<S> vg{v_in.v_mean_x[i], v_in.v_mean_y[i], v_in.v_conic_a[i], v_in.v_conic_b[i], v_in.v_conic_c[i],
                      v_in.v_opacity[i], {v_in.v_color_r[i], v_in.v_color_g[i], v_in.v_color_b[i]}, v_in.v_depth[i]};
      S v_mean[3], v_quat[4], v_scale[3], v_logit, v_sh[48];
      project_gaussian_vjp(cam, p, vg, Freeze{}, v_mean, v_quat, v_scale, &v_logit, v_sh);
      double mag = 1;
      for (S x : v_mean) mag = std::max(mag, std::abs(double(x)));
      for (S x : v_quat) mag = std::max(mag, std::abs(double(x)));
      const double gt = tol * mag;
      for (int a = 0; a < 3; ++a) CHECK(std::abs(double(g.means[3 * i + a]) - double(v_mean[a])) <= gt);
      for (int a = 0; a < 4; ++a) CHECK(std::abs(double(g.rotations[4 * i + a]) - double(v_quat[a])) <= gt);
      for (int a = 0; a < 3; ++a)
        CHECK(std::abs(double(g.scales[3 * i + a]) - double(v_scale[a]) * double(p.scale[a])) <= gt);
      CHECK(std::abs(double(g.opacity_logits[i]) - double(v_logit)) <= gt);
      for (int k = 0; k < 3 * k_count; ++k)
        CHECK(std::abs(double(g.sh[std::size_t(3 * k_count) * i + std::size_t(k)]) - double(v_sh[k])) <= gt);
      ++compared;
    }
    REQUIRE(compared > 50);
  }
}

TEMPLATE_TEST_CASE("scalar build: SH colour and its VJP on scalar values and on one-lane batches",
                   "[render][scalar]", float, double) {
  using S = TestType;
  using B = simd::native_batch<S>;
  std::mt19937 rng(12);
  std::uniform_real_distribution<double> u(-1, 1);
  for (int degree = 0; degree <= 3; ++degree) {
    const int k = sh_coefficient_count(degree);
    double sh_d[48], dir_d[3] = {u(rng), u(rng), 1.5 + u(rng)}, v_rgb_d[3] = {u(rng), u(rng), u(rng)};
    for (int j = 0; j < 3 * k; ++j) sh_d[j] = 0.5 * u(rng);
    // Finite differences of <v_rgb, colour> in double.
    auto loss = [&](const double* sh, const double* dir) {
      double rgb[3];
      sh_to_color(degree, sh, dir, rgb);
      return v_rgb_d[0] * rgb[0] + v_rgb_d[1] * rgb[1] + v_rgb_d[2] * rgb[2];
    };
    S sh[48], dir[3], v_rgb[3], v_sh[48], v_dir[3];
    for (int j = 0; j < 3 * k; ++j) sh[j] = S(sh_d[j]);
    for (int a = 0; a < 3; ++a) dir[a] = S(dir_d[a]), v_rgb[a] = S(v_rgb_d[a]);
    sh_to_color_vjp(degree, sh, dir, v_rgb, v_sh, v_dir);
    const double tol = std::is_same<S, float>::value ? 1e-4 : 1e-7;
    const double h = 1e-6;
    for (int j = 0; j < 3 * k; ++j) {
      const double x0 = sh_d[j];
      sh_d[j] = x0 + h;
      const double lp = loss(sh_d, dir_d);
      sh_d[j] = x0 - h;
      const double lm = loss(sh_d, dir_d);
      sh_d[j] = x0;
      CHECK(double(v_sh[j]) == Approx((lp - lm) / (2 * h)).margin(tol));
    }
    for (int a = 0; a < 3; ++a) {
      const double x0 = dir_d[a];
      dir_d[a] = x0 + h;
      const double lp = loss(sh_d, dir_d);
      dir_d[a] = x0 - h;
      const double lm = loss(sh_d, dir_d);
      dir_d[a] = x0;
      CHECK(double(v_dir[a]) == Approx((lp - lm) / (2 * h)).margin(tol));
    }
    // The basis and its VJP on one-lane batches (the projection's lanes) give the scalar values.
    const S n = std::sqrt(dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]);
    const S d[3] = {dir[0] / n, dir[1] / n, dir[2] / n};
    S b[16], v_b[16], v_d[3];
    B bb[16], bv_b[16], bv_d[3];
    for (int j = 0; j < 16; ++j) v_b[j] = S(u(rng)), bv_b[j] = B(v_b[j]);
    sh_basis(degree, d[0], d[1], d[2], b);
    sh_basis(degree, B(d[0]), B(d[1]), B(d[2]), bb);
    sh_basis_vjp(degree, d[0], d[1], d[2], v_b, v_d);
    sh_basis_vjp(degree, B(d[0]), B(d[1]), B(d[2]), bv_b, bv_d);
    // The same arithmetic; the compiler may contract it into fma differently.
    const double eps = 8 * double(std::numeric_limits<S>::epsilon());
    for (int j = 0; j < k; ++j) CHECK(double(simd::hadd(bb[j])) == Approx(double(b[j])).epsilon(eps).margin(eps));
    for (int a = 0; a < 3; ++a) CHECK(double(simd::hadd(bv_d[a])) == Approx(double(v_d[a])).epsilon(eps).margin(eps));
    if (degree > 0) CHECK(std::abs(double(v_d[0])) + std::abs(double(v_d[1])) + std::abs(double(v_d[2])) > 0);
  }
}

namespace {
// <w, colour> + <w_alpha, 1 - T> of a render, in double.
template <class Scene>
double render_loss(const Scene& scene, const Camera<double>& cam, const Image<double>& w, const Image<double>& wa) {
  Renderer<double> r;
  const RenderOutput<double>& o = r.render(scene, cam);
  double l = 0;
  for (std::size_t k = 0; k < o.color.data.size(); ++k) l += w.data[k] * o.color.data[k];
  for (std::size_t k = 0; k < o.transmittance.data.size(); ++k) l += wa.data[k] * (1 - o.transmittance.data[k]);
  return l;
}

// Central differences of f over every value of `x` whose analytic gradient is
// at least 2% of the group's largest; checks them against `g`.
template <class F>
void check_fd(const char* group, std::vector<double>& x, const std::vector<double>& g, F&& f) {
  double largest = 0;
  for (double v : g) largest = std::max(largest, std::abs(v));
  REQUIRE(largest > 0);
  int checked = 0;
  for (std::size_t j = 0; j < x.size(); j += 1 + x.size() / 40) {
    if (std::abs(g[j]) < 0.02 * largest) continue;
    const double h = 1e-6, x0 = x[j];
    x[j] = x0 + h;
    const double lp = f();
    x[j] = x0 - h;
    const double lm = f();
    x[j] = x0;
    const double fd = (lp - lm) / (2 * h);
    INFO(group << "[" << j << "]: analytic " << g[j] << ", finite differences " << fd);
    CHECK(std::abs(g[j] - fd) <= 1e-5 * (largest + std::abs(fd)));
    ++checked;
  }
  INFO(group);
  CHECK(checked >= 5);
}
}  // namespace

TEST_CASE("scalar build: Renderer::backward matches finite differences (log and activated adaptors)",
          "[render][scalar][grad]") {
  GaussianScene<double> scene = scalar_scene<double>(60, 2, 50);
  const Camera<double> cam = scalar_camera<double>();
  Image<double> w(41, 29, 3), wa(41, 29, 1);
  std::mt19937 rng(51);
  std::uniform_real_distribution<double> u(-1, 1);
  for (double& x : w.data) x = u(rng);
  for (double& x : wa.data) x = u(rng);
  Renderer<double> r;
  r.render(SceneView<double>(scene), cam);
  const GaussianSceneGrad<double> g = r.backward(SceneView<double>(scene), cam, w, &wa);
  REQUIRE(g.scale_mode == ScaleMode::log);
  auto f = [&] { return render_loss(SceneView<double>(scene), cam, w, wa); };
  check_fd("means", scene.means, g.means, f);
  check_fd("rotations", scene.rotations, g.rotations, f);
  check_fd("log_scales", scene.log_scales, g.scales, f);
  check_fd("opacity_logits", scene.opacity_logits, g.opacity_logits, f);
  check_fd("sh", scene.sh, g.sh, f);

  // Activated scales through DeformedSceneView: d/d of the offsets, and the
  // SceneGradView form writes the same values in other parametrisations.
  std::vector<double> dx(3 * scene.size()), dq(4 * scene.size()), ds(3 * scene.size());
  for (double& x : dx) x = 0.05 * u(rng);
  for (double& x : dq) x = 0.05 * u(rng);
  for (double& x : ds) x = 0.02 * u(rng);
  auto view = [&] { return DeformedSceneView<double>(scene, dx.data(), dq.data(), ds.data()); };
  r.render(view(), cam);
  const GaussianSceneGrad<double> gd = r.backward(view(), cam, w, &wa);
  REQUIRE(gd.scale_mode == ScaleMode::activated);
  auto fd_view = [&] { return render_loss(view(), cam, w, wa); };
  check_fd("dx", dx, gd.means, fd_view);
  check_fd("dq", dq, gd.rotations, fd_view);
  check_fd("ds", ds, gd.scales, fd_view);

  struct HostGrad { double mean[3], quat_xyzw[4], sigma[3], log_sigma[3], opacity, logit, sh[9 * 3]; };
  std::vector<HostGrad> hg(scene.size());
  SceneGradView<double> into;
  into.size = hg.size();
  const std::ptrdiff_t st = sizeof(HostGrad);
  into.means = strided(hg[0].mean, st);
  into.rotations = strided(hg[0].quat_xyzw, st);
  into.rotation_order = QuatOrder::xyzw;
  into.scales = strided(hg[0].sigma, st);
  into.log_scales = strided(hg[0].log_sigma, st);
  into.opacities = strided(&hg[0].opacity, st);
  into.opacity_logits = strided(&hg[0].logit, st);
  into.sh = strided(hg[0].sh, st);
  into.sh_coefficients = 9;
  r.backward(view(), cam, w, into, &wa);
  for (std::size_t i = 0; i < hg.size(); ++i) {
    double sigma[3];
    view().scale(i, sigma);
    const double o = 1 / (1 + std::exp(-scene.opacity_logits[i]));
    for (int a = 0; a < 3; ++a) {
      REQUIRE(hg[i].mean[a] == Approx(gd.means[3 * i + a]).margin(1e-12));
      REQUIRE(hg[i].sigma[a] == Approx(gd.scales[3 * i + a]).margin(1e-12));
      REQUIRE(hg[i].log_sigma[a] == Approx(gd.scales[3 * i + a] * sigma[a]).margin(1e-12));
    }
    REQUIRE(hg[i].quat_xyzw[3] == Approx(gd.rotations[4 * i]).margin(1e-12));
    REQUIRE(hg[i].logit == Approx(gd.opacity_logits[i]).margin(1e-12));
    REQUIRE(hg[i].opacity * o * (1 - o) == Approx(gd.opacity_logits[i]).margin(1e-12));
    for (int j = 0; j < 27; ++j) REQUIRE(hg[i].sh[j] == Approx(gd.sh[27 * i + std::size_t(j)]).margin(1e-12));
  }
}

TEST_CASE("scalar build: the float renderer's image and gradients agree with double", "[render][scalar][grad]") {
  const GaussianScene<double> sd = scalar_scene<double>(150, 3, 60);
  const GaussianScene<float> sf = cast_scene<float>(sd);
  const Camera<double> cd = scalar_camera<double>();
  const Camera<float> cf = scalar_camera<float>();
  Image<double> wd(41, 29, 3);
  std::mt19937 rng(61);
  std::uniform_real_distribution<double> u(-1, 1);
  for (double& x : wd.data) x = u(rng);
  Image<float> wf(41, 29, 3);
  for (std::size_t k = 0; k < wd.data.size(); ++k) wf.data[k] = float(wd.data[k]);
  Renderer<double> rd;
  Renderer<float> rf;
  const Image<double> img_d = rd.render(SceneView<double>(sd), cd).color;
  const Image<float> img_f = rf.render(SceneView<float>(sf), cf).color;
  CHECK(group_error(img_f.data, img_d.data) < 1e-4);
  const GaussianSceneGrad<double> gd = rd.backward(SceneView<double>(sd), cd, wd);
  const GaussianSceneGrad<float> gf = rf.backward(SceneView<float>(sf), cf, wf);
  // Relative to each group's largest value; far above float rounding only where
  // a pixel's blend decision flips between the precisions.
  CHECK(group_error(gf.means, gd.means) < 2e-3);
  CHECK(group_error(gf.rotations, gd.rotations) < 2e-3);
  CHECK(group_error(gf.scales, gd.scales) < 2e-3);
  CHECK(group_error(gf.opacity_logits, gd.opacity_logits) < 2e-3);
  CHECK(group_error(gf.sh, gd.sh) < 2e-3);
  // The rasterizer's own VJP, float against double on the same projected splats.
  CHECK(group_error(rf.projected_gradients().v_conic_a, rd.projected_gradients().v_conic_a) < 2e-3);
  CHECK(group_error(rf.projected_gradients().v_opacity, rd.projected_gradients().v_opacity) < 2e-3);
}

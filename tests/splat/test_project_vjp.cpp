// Finite-difference checks (double, central differences) of every per-Gaussian
// VJP and of the composed projection, plus freeze flags and culled Gaussians.
#include <catch2/catch.hpp>

#include <cmath>
#include <functional>
#include <random>
#include <vector>

#include "orbitforge/splat/project.hpp"

using namespace orbitforge;
using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;

namespace {

const double kRelTol = 1e-6;

// Central difference of f w.r.t. x (restored afterwards): the five-point stencil
// (Richardson-extrapolated central differences, error O(h^4)), so that a step
// large enough to keep rounding noise of a large L small is still accurate.
double central(const std::function<double()>& f, double& x, double h) {
  const double keep = x;
  auto at = [&](double d) {
    x = keep + d;
    const double v = f();
    x = keep;
    return v;
  };
  const double d1 = at(h) - at(-h), d2 = at(2 * h) - at(-2 * h);
  return (8 * d1 - d2) / (12 * h);
}

// |analytic - fd| <= 1e-6 * max(|fd|, floor), floor = 1e-3 * the largest |fd| of
// the group (entries that are exactly zero analytically stay below it).
void check_group(const char* name, const std::vector<double>& analytic, const std::vector<double>& fd) {
  REQUIRE(analytic.size() == fd.size());
  double gmax = 0;
  for (double v : fd) gmax = std::max(gmax, std::abs(v));
  for (std::size_t j = 0; j < fd.size(); ++j) {
    INFO(name << "[" << j << "] analytic " << analytic[j] << " fd " << fd[j]);
    REQUIRE(std::abs(analytic[j] - fd[j]) <= kRelTol * std::max(std::abs(fd[j]), 1e-3 * gmax + 1e-12));
  }
}

std::vector<double> fd_of(const std::function<double()>& f, double* params, std::size_t n, double h = 1e-3) {
  std::vector<double> g(n);
  for (std::size_t j = 0; j < n; ++j) g[j] = central(f, params[j], h * std::max(1.0, std::abs(params[j])));
  return g;
}

Camerad make_camera(int w = 80, int h = 60) {
  Intrinsics<double> k{70, 65, 0.5 * w + 3.25, 0.5 * h - 1.5, w, h};
  return Camerad::look_at(Vec3(0.4, -0.3, -4), Vec3(0.05, 0.02, 0), Vec3(0.1, -1, 0), k);
}

// Random Gaussians well inside the view (no x/z clamp), colour away from the clamp.
GaussianScened random_scene(std::mt19937& rng, std::size_t n, int degree) {
  GaussianScened s;
  s.resize(n, degree);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = 0.8 * u(rng);
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = nd(rng);
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = -1.8 + 0.5 * u(rng);
    s.opacity_logits[i] = 1.5 * u(rng);
  }
  for (auto& v : s.sh) v = 0.3 * u(rng);
  for (std::size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) s.sh[3 * s.sh_coefficients() * i + c] += 2.0;
  return s;
}

// Random weights for every ProjectedSplats output: L = sum w . outputs.
ProjectedSplatsGrad<double> random_weights(std::mt19937& rng, std::size_t n) {
  std::uniform_real_distribution<double> u(-1, 1);
  ProjectedSplatsGrad<double> w;
  w.assign_zero(n);
  for (auto* v : {&w.v_mean_x, &w.v_mean_y, &w.v_conic_a, &w.v_conic_b, &w.v_conic_c, &w.v_opacity, &w.v_color_r,
                  &w.v_color_g, &w.v_color_b, &w.v_depth})
    for (auto& x : *v) x = u(rng);
  return w;
}

double weighted_sum(const ProjectedSplats<double>& p, const ProjectedSplatsGrad<double>& w) {
  double L = 0;
  for (std::size_t i = 0; i < p.size(); ++i) {
    if (p.radius[i] <= 0) continue;
    L += w.v_mean_x[i] * p.mean_x[i] + w.v_mean_y[i] * p.mean_y[i] + w.v_conic_a[i] * p.conic_a[i] +
         w.v_conic_b[i] * p.conic_b[i] + w.v_conic_c[i] * p.conic_c[i] + w.v_opacity[i] * p.opacity[i] +
         w.v_color_r[i] * p.color_r[i] + w.v_color_g[i] * p.color_g[i] + w.v_color_b[i] * p.color_b[i] +
         w.v_depth[i] * p.depth[i];
  }
  return L;
}

template <class Scene>
double scene_loss(const Scene& scene, const Camerad& cam, const ProjectedSplatsGrad<double>& w,
                  std::vector<std::int32_t>* radius_out = nullptr) {
  ProjectedSplats<double> p;
  project_scene(scene, cam, ProjectionParams{}, p, nullptr, 1);
  if (radius_out) *radius_out = p.radius;
  return weighted_sum(p, w);
}

}  // namespace

TEST_CASE("quat_to_rotmat_vjp: through the normalisation", "[splat][project][grad]") {
  std::mt19937 rng(1);
  std::normal_distribution<double> nd;
  for (int trial = 0; trial < 10; ++trial) {
    double q[4];
    for (auto& v : q) v = 2 * nd(rng);
    Mat3 W;
    for (int j = 0; j < 9; ++j) W.data()[j] = nd(rng);
    auto f = [&]() {
      Mat3 R;
      quat_to_rotmat(q, R);
      return (R.array() * W.array()).sum();
    };
    double v_q[4];
    quat_to_rotmat_vjp(q, W, v_q);
    check_group("v_q", std::vector<double>(v_q, v_q + 4), fd_of(f, q, 4));
    // The gradient is orthogonal to q (scale invariance).
    REQUIRE(std::abs(v_q[0] * q[0] + v_q[1] * q[1] + v_q[2] * q[2] + v_q[3] * q[3]) < 1e-12);
  }
}

TEST_CASE("covariance3d_vjp: any sign of scale", "[splat][project][grad]") {
  std::mt19937 rng(2);
  std::normal_distribution<double> nd;
  for (int trial = 0; trial < 10; ++trial) {
    Mat3 R, W;
    for (int j = 0; j < 9; ++j) R.data()[j] = nd(rng), W.data()[j] = nd(rng);
    double s[3] = {nd(rng), -std::abs(nd(rng)), 0.3 * nd(rng)};
    auto f = [&]() {
      Mat3 S;
      covariance3d(R, s, S);
      return (S.array() * W.array()).sum();
    };
    Mat3 v_R;
    double v_s[3];
    covariance3d_vjp(R, s, W, v_R, v_s);
    check_group("v_s", std::vector<double>(v_s, v_s + 3), fd_of(f, s, 3));
    check_group("v_R", std::vector<double>(v_R.data(), v_R.data() + 9), fd_of(f, R.data(), 9));
  }
}

TEST_CASE("project_covariance_vjp: unclamped and clamped Jacobian", "[splat][project][grad]") {
  std::mt19937 rng(3);
  std::normal_distribution<double> nd;
  const Mat3 Wc = Eigen::Quaterniond(0.9, 0.1, -0.3, 0.2).normalized().toRotationMatrix();
  const double fx = 80, fy = 70, lim_x = 0.6, lim_y = 0.5;
  // t_x / t_z: inside, beyond +lim, beyond -lim.
  const double ratios[][2] = {{0.2, -0.1}, {0.9, 0.1}, {-0.1, -0.8}, {-0.7, 0.7}};
  for (const auto& r : ratios) {
    double t[3] = {r[0] * 3, r[1] * 3, 3};
    Mat3 A;
    for (int j = 0; j < 9; ++j) A.data()[j] = nd(rng);
    Mat3 Sigma = A * A.transpose() + Mat3::Identity() * 0.1;
    const double w[3] = {nd(rng), nd(rng), nd(rng)};
    auto f = [&]() {
      double cov[3];
      project_covariance(t, Sigma, Wc, fx, fy, lim_x, lim_y, 0.3, cov);
      return w[0] * cov[0] + w[1] * cov[1] + w[2] * cov[2];
    };
    double v_t[3] = {0, 0, 0};
    Mat3 v_Sigma;
    project_covariance_vjp(t, Sigma, Wc, fx, fy, lim_x, lim_y, w, v_t, &v_Sigma);
    check_group("v_t", std::vector<double>(v_t, v_t + 3), fd_of(f, t, 3));
    // Sigma is symmetric: perturb (i, j) and (j, i) together; the gradient of that
    // perturbation is v_Sigma(i, j) + v_Sigma(j, i) (the diagonal: v_Sigma(i, i)).
    std::vector<double> an, fd;
    for (int i = 0; i < 3; ++i)
      for (int j = i; j < 3; ++j) {
        double e = 0;
        auto fs = [&]() {
          Mat3 keep = Sigma;
          Sigma(i, j) += e;
          if (i != j) Sigma(j, i) += e;
          const double v = f();
          Sigma = keep;
          return v;
        };
        fd.push_back(central(fs, e, 1e-3));
        an.push_back(i == j ? v_Sigma(i, i) : v_Sigma(i, j) + v_Sigma(j, i));
      }
    check_group("v_Sigma", an, fd);
    REQUIRE((v_Sigma - v_Sigma.transpose()).cwiseAbs().maxCoeff() < 1e-12 * v_Sigma.cwiseAbs().maxCoeff());
    if (std::abs(r[0]) > lim_x) {
      // Clamped x: no gradient through t_x via J (the mean term is separate).
      double v_t2[3] = {0, 0, 0};
      project_covariance_vjp(t, Sigma, Wc, fx, fy, lim_x, lim_y, w, v_t2, nullptr);
      REQUIRE(v_t2[0] == 0.0);
    }
  }
}

TEST_CASE("inverse2x2_vjp", "[splat][project][grad]") {
  double cov[3] = {2.5, -0.7, 1.3};
  const double w[3] = {0.3, -1.2, 0.8};
  auto f = [&]() {
    double c[3];
    inverse2x2(cov, c);
    return w[0] * c[0] + w[1] * c[1] + w[2] * c[2];
  };
  double conic[3], v_cov[3];
  inverse2x2(cov, conic);
  inverse2x2_vjp(conic, w, v_cov);
  check_group("v_cov", std::vector<double>(v_cov, v_cov + 3), fd_of(f, cov, 3));
}

TEST_CASE("project_scene_vjp matches finite differences of every output (SceneView, log-scales)",
          "[splat][project][grad]") {
  std::mt19937 rng(42);
  const Camerad cam = make_camera();
  for (int degree = 0; degree <= 3; ++degree) {
    DYNAMIC_SECTION("degree " << degree) {
      GaussianScened s = random_scene(rng, 6, degree);
      const auto w = random_weights(rng, s.size());
      std::vector<std::int32_t> r0;
      auto f = [&]() {
        std::vector<std::int32_t> r;
        const double L = scene_loss(SceneView<double>(s), cam, w, &r);
        REQUIRE(r == r0);  // nothing culled or un-culled by a perturbation
        return L;
      };
      ProjectedSplats<double> fwd;
      ProjectionStats st;
      project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, &st, 1);
      r0 = fwd.radius;
      REQUIRE(st.visible == s.size());
      GaussianSceneGrad<double> g;
      project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, g, Freeze{}, 1);
      check_group("means", g.means, fd_of(f, s.means.data(), s.means.size()));
      check_group("rotations", g.rotations, fd_of(f, s.rotations.data(), s.rotations.size()));
      check_group("log_scales", g.scales, fd_of(f, s.log_scales.data(), s.log_scales.size()));
      check_group("opacity_logits", g.opacity_logits, fd_of(f, s.opacity_logits.data(), s.opacity_logits.size()));
      check_group("sh", g.sh, fd_of(f, s.sh.data(), s.sh.size()));
      // Screen-space norms for densification.
      for (std::size_t i = 0; i < s.size(); ++i) {
        REQUIRE(g.screen_grad_norm[i] == Approx(std::hypot(w.v_mean_x[i], w.v_mean_y[i])));
        REQUIRE(g.screen_grad_ndc_norm[i] == Approx(std::hypot(w.v_mean_x[i] * 40, w.v_mean_y[i] * 30)));
      }
    }
  }
}

TEST_CASE("project_scene_vjp: Gaussians beyond the x/z, y/z clamp", "[splat][project][grad]") {
  // Camera at the origin looking down +z; lim_x = 1.3 * 0.5 * 64 / 50 = 0.832.
  Camerad cam;
  cam.intrinsics = {50, 50, 32, 32, 64, 64};
  GaussianScened s;
  s.resize(2, 1);
  const double xs[2][3] = {{1.0 * 3, 0.2 * 3, 3}, {-0.3 * 2, -1.0 * 2, 2}};
  for (int i = 0; i < 2; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = xs[i][a];
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = std::log(0.5 + 0.1 * a);
    s.rotations[4 * i + 0] = 0.9;
    s.rotations[4 * i + 1] = 0.2 * (i + 1);
    s.rotations[4 * i + 2] = -0.3;
    s.rotations[4 * i + 3] = 0.1;
    s.opacity_logits[i] = 1;
    for (int c = 0; c < 3; ++c) s.sh[12 * i + c] = 1.5;
  }
  std::mt19937 rng(5);
  const auto w = random_weights(rng, 2);
  ProjectedSplats<double> fwd;
  ProjectionStats st;
  project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, &st, 1);
  REQUIRE(st.visible == 2);
  auto f = [&]() { return scene_loss(SceneView<double>(s), cam, w); };
  GaussianSceneGrad<double> g;
  project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, g);
  check_group("means", g.means, fd_of(f, s.means.data(), s.means.size()));
  check_group("rotations", g.rotations, fd_of(f, s.rotations.data(), s.rotations.size()));
  check_group("log_scales", g.scales, fd_of(f, s.log_scales.data(), s.log_scales.size()));
}

TEST_CASE("project_scene_vjp through DeformedSceneView: offsets, negative scales, base parameters",
          "[splat][project][grad]") {
  std::mt19937 rng(77);
  const Camerad cam = make_camera();
  for (int degree : {0, 3}) {
    GaussianScened base = random_scene(rng, 5, degree);
    std::normal_distribution<double> nd;
    std::vector<double> dx(15), dq(20), ds(15);
    for (auto& v : dx) v = 0.1 * nd(rng);
    for (auto& v : dq) v = 0.2 * nd(rng);
    for (std::size_t j = 0; j < 15; ++j) ds[j] = 0.05 * nd(rng);
    // Two activated scales made negative.
    ds[1] = -std::exp(base.log_scales[1]) - 0.12;
    ds[7] = -std::exp(base.log_scales[7]) - 0.05;
    const auto w = random_weights(rng, 5);
    auto view = [&]() { return DeformedSceneView<double>(base, dx.data(), dq.data(), ds.data()); };
    auto f = [&]() { return scene_loss(view(), cam, w); };
    ProjectedSplats<double> fwd;
    ProjectionStats st;
    project_scene(view(), cam, ProjectionParams{}, fwd, &st, 1);
    REQUIRE(st.visible == 5);
    GaussianSceneGrad<double> g;
    project_scene_vjp(view(), cam, ProjectionParams{}, fwd, w, g, Freeze{}, 2);
    // W.r.t. what the adaptor exposes = the offsets.
    check_group("v_dx", g.means, fd_of(f, dx.data(), dx.size()));
    check_group("v_dq", g.rotations, fd_of(f, dq.data(), dq.size()));
    check_group("v_ds", g.scales, fd_of(f, ds.data(), ds.size()));
    // Chained to the base scene.
    GaussianSceneGrad<double> gb;
    view().base_gradients(g, gb);
    check_group("base means", gb.means, fd_of(f, base.means.data(), base.means.size()));
    check_group("base rotations", gb.rotations, fd_of(f, base.rotations.data(), base.rotations.size()));
    check_group("base log_scales", gb.scales, fd_of(f, base.log_scales.data(), base.log_scales.size()));
    check_group("base opacity", gb.opacity_logits, fd_of(f, base.opacity_logits.data(), base.opacity_logits.size()));
    check_group("base sh", gb.sh, fd_of(f, base.sh.data(), base.sh.size()));
    // In place gives the same.
    view().base_gradients(g, g);
    REQUIRE(g.rotations == gb.rotations);
    REQUIRE(g.scales == gb.scales);
  }
}

TEST_CASE("project_scene_vjp through DeformedSceneView with relative scale offsets", "[splat][project][grad]") {
  std::mt19937 rng(78);
  const Camerad cam = make_camera();
  GaussianScened base = random_scene(rng, 5, 2);
  std::normal_distribution<double> nd;
  std::vector<double> dx(15), dq(20), ds(15);
  for (auto& v : dx) v = 0.1 * nd(rng);
  for (auto& v : dq) v = 0.2 * nd(rng);
  for (auto& v : ds) v = 0.4 * nd(rng);
  const auto w = random_weights(rng, 5);
  auto view = [&]() { return DeformedSceneView<double>(base, dx.data(), dq.data(), ds.data(), ScaleOffset::log); };
  double sc[3];
  view().scale(2, sc);
  CHECK(sc[1] == Approx(std::exp(base.log_scales[7] + ds[7])));
  auto f = [&]() { return scene_loss(view(), cam, w); };
  ProjectedSplats<double> fwd;
  project_scene(view(), cam, ProjectionParams{}, fwd, nullptr, 1);
  GaussianSceneGrad<double> g;
  project_scene_vjp(view(), cam, ProjectionParams{}, fwd, w, g, Freeze{}, 2);
  std::vector<double> v_ds(15);
  view().scale_offset_gradients(g, v_ds.data());
  check_group("v_ds (relative)", v_ds, fd_of(f, ds.data(), ds.size()));
  GaussianSceneGrad<double> gb;
  view().base_gradients(g, gb);
  check_group("base log_scales (relative)", gb.scales, fd_of(f, base.log_scales.data(), base.log_scales.size()));
  check_group("base means (relative)", gb.means, fd_of(f, base.means.data(), base.means.size()));
}

TEST_CASE("freeze flags: frozen groups untouched, the others unchanged", "[splat][project][grad]") {
  std::mt19937 rng(9);
  const Camerad cam = make_camera();
  const GaussianScened s = random_scene(rng, 200, 3);
  const auto w = random_weights(rng, s.size());
  ProjectedSplats<double> fwd;
  project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, nullptr, 2);
  GaussianSceneGrad<double> full;
  project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, full, Freeze{}, 2);
  const int K = 16;
  for (int mask = 1; mask < 64; mask += 5) {
    Freeze fr;
    fr.means = mask & 1;
    fr.rotations = mask & 2;
    fr.scales = mask & 4;
    fr.opacities = mask & 8;
    fr.sh_dc = mask & 16;
    fr.sh_rest = mask & 32;
    GaussianSceneGrad<double> g;
    g.assign_zero(s.size(), 3);
    const double sentinel = 12345.0;
    for (auto* v : {&g.means, &g.rotations, &g.scales, &g.opacity_logits, &g.sh})
      std::fill(v->begin(), v->end(), sentinel);
    project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, g, fr, 2);
    auto check = [&](const std::vector<double>& got, const std::vector<double>& ref, bool frozen) {
      REQUIRE(got.size() == ref.size());
      for (std::size_t j = 0; j < got.size(); ++j) REQUIRE(got[j] == (frozen ? sentinel : ref[j]));
    };
    check(g.means, full.means, fr.means);
    check(g.rotations, full.rotations, fr.rotations);
    check(g.scales, full.scales, fr.scales);
    check(g.opacity_logits, full.opacity_logits, fr.opacities);
    for (std::size_t i = 0; i < s.size(); ++i)
      for (int j = 0; j < 3 * K; ++j) {
        const bool frozen = j < 3 ? fr.sh_dc : fr.sh_rest;
        REQUIRE(g.sh[3 * K * i + j] == (frozen ? sentinel : full.sh[3 * K * i + j]));
      }
    REQUIRE(g.screen_grad_norm == full.screen_grad_norm);
  }
  // A fresh gradient object: frozen groups come back as zeros of the right size.
  Freeze all{true, true, true, true, true, true};
  GaussianSceneGrad<double> fresh;
  project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, fresh, all, 1);
  REQUIRE(fresh.means.size() == s.means.size());
  REQUIRE(fresh.sh.size() == s.sh.size());
  for (double v : fresh.sh) REQUIRE(v == 0.0);
  for (double v : fresh.rotations) REQUIRE(v == 0.0);
}

TEST_CASE("culled Gaussians get zero gradients", "[splat][project][grad]") {
  std::mt19937 rng(10);
  const Camerad cam = make_camera();
  GaussianScened s = random_scene(rng, 8, 2);
  s.means[3 * 1 + 2] = -10;  // behind the camera
  s.opacity_logits[2] = -8;  // faint
  s.means[3 * 3 + 0] = std::numeric_limits<double>::quiet_NaN();
  s.means[3 * 4 + 0] = 40;  // outside
  const auto w = random_weights(rng, s.size());
  ProjectedSplats<double> fwd;
  ProjectionStats st;
  project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, &st, 1);
  REQUIRE(st.visible == 4);
  GaussianSceneGrad<double> g;
  g.assign_zero(s.size(), 2);
  for (auto* v : {&g.means, &g.rotations, &g.scales, &g.opacity_logits, &g.sh}) std::fill(v->begin(), v->end(), 5.0);
  project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, g, Freeze{}, 1);
  for (int i = 1; i <= 4; ++i) {
    for (int a = 0; a < 3; ++a) REQUIRE(g.means[3 * i + a] == 0.0);
    for (int a = 0; a < 4; ++a) REQUIRE(g.rotations[4 * i + a] == 0.0);
    for (int a = 0; a < 3; ++a) REQUIRE(g.scales[3 * i + a] == 0.0);
    REQUIRE(g.opacity_logits[i] == 0.0);
    for (int j = 0; j < 27; ++j) REQUIRE(g.sh[27 * i + j] == 0.0);
    REQUIRE(g.screen_grad_norm[i] == 0.0);
  }
  for (int i : {0, 5, 6, 7}) REQUIRE(g.means[3 * i] != 0.0);
  for (double v : g.means) REQUIRE(std::isfinite(v));
}

TEST_CASE("float backward agrees with double", "[splat][project][grad]") {
  std::mt19937 rng(12);
  const Camerad cam = make_camera();
  const GaussianScened s = random_scene(rng, 300, 3);
  const auto w = random_weights(rng, s.size());
  ProjectedSplats<double> fwd;
  project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, nullptr, 1);
  GaussianSceneGrad<double> g;
  project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, g);

  const auto sf = s.cast<float>();
  const auto camf = cam.cast<float>();
  ProjectedSplats<float> fwdf;
  project_scene(SceneView<float>(sf), camf, ProjectionParams{}, fwdf, nullptr, 1);
  ProjectedSplatsGrad<float> wf;
  wf.assign_zero(s.size());
  for (std::size_t i = 0; i < s.size(); ++i) {
    wf.v_mean_x[i] = float(w.v_mean_x[i]); wf.v_mean_y[i] = float(w.v_mean_y[i]);
    wf.v_conic_a[i] = float(w.v_conic_a[i]); wf.v_conic_b[i] = float(w.v_conic_b[i]);
    wf.v_conic_c[i] = float(w.v_conic_c[i]); wf.v_opacity[i] = float(w.v_opacity[i]);
    wf.v_color_r[i] = float(w.v_color_r[i]); wf.v_color_g[i] = float(w.v_color_g[i]);
    wf.v_color_b[i] = float(w.v_color_b[i]); wf.v_depth[i] = float(w.v_depth[i]);
  }
  GaussianSceneGrad<float> gf;
  project_scene_vjp(SceneView<float>(sf), camf, ProjectionParams{}, fwdf, wf, gf);
  auto close = [](const std::vector<float>& a, const std::vector<double>& b) {
    double m = 0;
    for (double v : b) m = std::max(m, std::abs(v));
    for (std::size_t j = 0; j < a.size(); ++j) REQUIRE(std::abs(a[j] - b[j]) <= 1e-3 * m);
  };
  close(gf.means, g.means);
  close(gf.rotations, g.rotations);
  close(gf.scales, g.scales);
  close(gf.opacity_logits, g.opacity_logits);
  close(gf.sh, g.sh);
}

TEST_CASE("project_scene_vjp rejects mismatched inputs", "[splat][project][grad]") {
  std::mt19937 rng(13);
  const GaussianScened s = random_scene(rng, 4, 0);
  ProjectedSplats<double> fwd;
  project_scene(SceneView<double>(s), make_camera(), ProjectionParams{}, fwd);
  ProjectedSplatsGrad<double> w;
  w.assign_zero(3);
  GaussianSceneGrad<double> g;
  REQUIRE_THROWS_AS(project_scene_vjp(SceneView<double>(s), make_camera(), ProjectionParams{}, fwd, w, g), Error);
}

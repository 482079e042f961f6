// The batch (SIMD) path of project_scene_vjp against the per-Gaussian reference
// project_gaussian_vjp: in double both agree to rounding; in float both are
// measured against the double reference, and the batch path's error must be of
// the reference's own size. Scenes mix Gaussians beyond the EWA clamp, colours
// clamped at 0, culled Gaussians and a partial last batch.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "orbitforge/splat/project.hpp"

using namespace orbitforge;

namespace project_vjp_batch_test {

template <class S>
Camera<S> camera() {
  Intrinsics<S> k{S(300), S(280), S(131.5), S(93.0), 256, 192};
  return Camera<S>::look_at(Eigen::Matrix<S, 3, 1>(S(0.3), S(-0.4), S(-3.5)), Eigen::Matrix<S, 3, 1>(S(0), S(0), S(0)),
                            Eigen::Matrix<S, 3, 1>(S(0), S(-1), S(0)), k);
}

GaussianScened scene(std::mt19937& rng, std::size_t n, int degree) {
  GaussianScened s;
  s.resize(n, degree);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  std::uniform_int_distribution<int> pick(0, 9);
  const int k_count = sh_coefficient_count(degree);
  for (std::size_t i = 0; i < n; ++i) {
    double* m = &s.means[3 * i];
    double* l = &s.log_scales[3 * i];
    for (int a = 0; a < 3; ++a) m[a] = 1.3 * u(rng);
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = nd(rng);
    for (int a = 0; a < 3; ++a) l[a] = -3 + 0.8 * nd(rng);
    s.opacity_logits[i] = 3 * u(rng);
    for (int k = 0; k < 3 * k_count; ++k) s.sh[3 * k_count * i + k] = 0.4 * u(rng);
    switch (pick(rng)) {
      case 0: m[0] = 2.6 + 0.5 * u(rng); l[0] = -0.6; l[1] = -0.3; break;  // x/z beyond the clamp, still on screen
      case 1: m[1] = 2.2 + 0.4 * u(rng); l[1] = -0.6; l[2] = -0.4; break;  // y/z beyond the clamp
      case 2: s.sh[3 * k_count * i] = -3; break;                             // red clamped at 0
      case 3: m[2] = -8; break;                                              // behind the camera: culled
      case 4: s.opacity_logits[i] = -9; break;                               // faint: culled
      default: break;
    }
  }
  return s;
}

template <class S>
ProjectedSplatsGrad<S> weights(std::mt19937& rng, std::size_t n) {
  ProjectedSplatsGrad<S> w;
  w.assign_zero(n);
  std::uniform_real_distribution<double> u(-1, 1);
  for (auto* a : {&w.v_mean_x, &w.v_mean_y, &w.v_conic_a, &w.v_conic_b, &w.v_conic_c, &w.v_opacity, &w.v_color_r,
                  &w.v_color_g, &w.v_color_b, &w.v_depth})
    for (auto& x : *a) x = S(u(rng));
  return w;
}

// The reference, Gaussian by Gaussian, into a GaussianSceneGrad laid out as
// project_scene_vjp's (log-scale gradients, zeros for culled Gaussians).
template <class S>
GaussianSceneGrad<S> reference(const GaussianScene<S>& s, const Camera<S>& camera, const ProjectedSplats<S>& fwd,
                               const ProjectedSplatsGrad<S>& w) {
  const auto cam = ProjectionCamera<S>::make(camera, ProjectionParams{});
  const int degree = s.sh_degree;
  const int kk = 3 * sh_coefficient_count(degree);
  GaussianSceneGrad<S> g;
  g.assign_zero(s.size(), degree);
  g.screen_grad_norm.assign(s.size(), S(0));
  g.screen_grad_ndc_norm.assign(s.size(), S(0));
  const SceneView<S> view(s);
  for (std::size_t i = 0; i < s.size(); ++i) {
    if (fwd.radius[i] == 0) continue;
    S sh_buf[48], v_mean[3], v_quat[4], v_scale[3], v_logit;
    GaussianParams<S> p;
    detail::gather_gaussian(view, i, degree, p, sh_buf);
    SplatGrad<S> v{w.v_mean_x[i], w.v_mean_y[i], w.v_conic_a[i], w.v_conic_b[i], w.v_conic_c[i], w.v_opacity[i],
                   {w.v_color_r[i], w.v_color_g[i], w.v_color_b[i]}, w.v_depth[i]};
    project_gaussian_vjp(cam, p, v, Freeze{}, v_mean, v_quat, v_scale, &v_logit, &g.sh[std::size_t(kk) * i]);
    for (int a = 0; a < 3; ++a) g.means[3 * i + a] = v_mean[a];
    for (int a = 0; a < 4; ++a) g.rotations[4 * i + a] = v_quat[a];
    for (int a = 0; a < 3; ++a) g.scales[3 * i + a] = v_scale[a] * p.scale[a];
    g.opacity_logits[i] = v_logit;
    g.screen_grad_norm[i] = std::sqrt(v.v_mean_x * v.v_mean_x + v.v_mean_y * v.v_mean_y);
    const S nx = v.v_mean_x * S(0.5) * S(camera.intrinsics.width), ny = v.v_mean_y * S(0.5) * S(camera.intrinsics.height);
    g.screen_grad_ndc_norm[i] = std::sqrt(nx * nx + ny * ny);
  }
  return g;
}

template <class A, class B>
std::vector<std::vector<double>> groups(const GaussianSceneGrad<A>& g, std::size_t i, const GaussianSceneGrad<B>&) {
  const std::size_t kk = g.sh.size() / g.opacity_logits.size();
  auto take = [&](const std::vector<A>& v, std::size_t per) {
    return std::vector<double>(v.begin() + std::ptrdiff_t(per * i), v.begin() + std::ptrdiff_t(per * (i + 1)));
  };
  return {take(g.means, 3), take(g.rotations, 4), take(g.scales, 3), take(g.opacity_logits, 1), take(g.sh, kk),
          take(g.screen_grad_norm, 1), take(g.screen_grad_ndc_norm, 1)};
}

}  // namespace project_vjp_batch_test

namespace pvb = project_vjp_batch_test;  // no using-directive: the layer's tests share one unity file

TEST_CASE("batch projection VJP agrees with project_gaussian_vjp in double", "[splat][project][grad]") {
  for (int degree = 0; degree <= 3; ++degree) {
    std::mt19937 rng(40 + degree);
    const std::size_t n = 16 * 23 + 5;  // a partial last batch on every SIMD width
    const GaussianScened s = pvb::scene(rng, n, degree);
    const auto cam = pvb::camera<double>();
    ProjectedSplats<double> fwd;
    ProjectionStats st;
    project_scene(SceneView<double>(s), cam, ProjectionParams{}, fwd, &st, 1);
    REQUIRE(st.visible > n / 2);
    REQUIRE(st.visible < n);
    const auto w = pvb::weights<double>(rng, n);
    GaussianSceneGrad<double> batch, batch2;
    project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, batch, Freeze{}, 1);
    project_scene_vjp(SceneView<double>(s), cam, ProjectionParams{}, fwd, w, batch2, Freeze{}, 2);
    const auto ref = pvb::reference(s, cam, fwd, w);
    REQUIRE(batch2.means == batch.means);
    REQUIRE(batch2.sh == batch.sh);
    for (std::size_t i = 0; i < n; ++i) {
      const auto gb = pvb::groups(batch, i, ref), gr = pvb::groups(ref, i, ref);
      double all = 0;  // a floor for groups that vanish (rotations of an isotropic Gaussian)
      for (const auto& group : gr)
        for (double v : group) all = std::max(all, std::abs(v));
      for (std::size_t k = 0; k < gb.size(); ++k) {
        double mag = 1e-6 * all;
        for (double v : gr[k]) mag = std::max(mag, std::abs(v));
        for (std::size_t j = 0; j < gb[k].size(); ++j) {
          INFO("degree " << degree << " Gaussian " << i << " group " << k << " entry " << j << ": batch " << gb[k][j]
                         << " reference " << gr[k][j]);
          if (fwd.radius[i] == 0)
            REQUIRE(gb[k][j] == 0.0);
          else
            REQUIRE(std::abs(gb[k][j] - gr[k][j]) <= 1e-10 * mag);
        }
      }
    }
  }
}

TEST_CASE("batch projection VJP in float: errors of the reference's size against double", "[splat][project][grad]") {
  for (int degree : {0, 3}) {
    std::mt19937 rng(50 + degree);
    const std::size_t n = 16 * 40 + 7;
    const GaussianScened sd = pvb::scene(rng, n, degree);
    const auto sf = sd.cast<float>();
    const auto camd = pvb::camera<double>();
    const auto camf = camd.cast<float>();
    ProjectedSplats<float> fwdf;
    project_scene(SceneView<float>(sf), camf, ProjectionParams{}, fwdf, nullptr, 1);
    const auto wf = pvb::weights<float>(rng, n);
    // The double reference on the float inputs, for the Gaussians float kept.
    ProjectedSplats<double> fwdd;
    project_scene(SceneView<double>(sf.cast<double>()), camf.cast<double>(), ProjectionParams{}, fwdd, nullptr, 1);
    for (std::size_t i = 0; i < n; ++i) fwdd.radius[i] = fwdf.radius[i];
    ProjectedSplatsGrad<double> wd;
    wd.assign_zero(n);
    const std::vector<float>* fsrc[10] = {&wf.v_mean_x, &wf.v_mean_y, &wf.v_conic_a, &wf.v_conic_b, &wf.v_conic_c,
                                          &wf.v_opacity, &wf.v_color_r, &wf.v_color_g, &wf.v_color_b, &wf.v_depth};
    std::vector<double>* ddst[10] = {&wd.v_mean_x, &wd.v_mean_y, &wd.v_conic_a, &wd.v_conic_b, &wd.v_conic_c,
                                     &wd.v_opacity, &wd.v_color_r, &wd.v_color_g, &wd.v_color_b, &wd.v_depth};
    for (int f = 0; f < 10; ++f) ddst[f]->assign(fsrc[f]->begin(), fsrc[f]->end());
    const auto exact = pvb::reference(sf.cast<double>(), camf.cast<double>(), fwdd, wd);
    const auto scalar = pvb::reference(sf, camf, fwdf, wf);
    GaussianSceneGrad<float> batch;
    project_scene_vjp(SceneView<float>(sf), camf, ProjectionParams{}, fwdf, wf, batch, Freeze{}, 1);

    // Per group and Gaussian, errors relative to the group's largest value; a
    // Gaussian whose clamp decisions lie within float rounding of the boundary
    // may take the other branch in either float path and is left out.
    double worst_batch = 0, worst_scalar = 0;
    std::size_t compared = 0;
    for (std::size_t i = 0; i < n; ++i) {
      if (fwdf.radius[i] == 0) continue;
      const auto ge = pvb::groups(exact, i, exact), gb = pvb::groups(batch, i, exact), gs = pvb::groups(scalar, i, exact);
      bool near_branch = false;
      for (std::size_t k = 0; k < ge.size(); ++k)
        for (std::size_t j = 0; j < ge[k].size(); ++j)
          if (std::abs(gs[k][j] - ge[k][j]) > 1e-2 * (std::abs(ge[k][j]) + 1e-3)) near_branch = true;
      if (near_branch) continue;
      ++compared;
      for (std::size_t k = 0; k < ge.size(); ++k) {
        double mag = 0;
        for (double v : ge[k]) mag = std::max(mag, std::abs(v));
        if (mag == 0) continue;
        for (std::size_t j = 0; j < ge[k].size(); ++j) {
          worst_batch = std::max(worst_batch, std::abs(gb[k][j] - ge[k][j]) / mag);
          worst_scalar = std::max(worst_scalar, std::abs(gs[k][j] - ge[k][j]) / mag);
        }
      }
    }
    INFO("degree " << degree << ": " << compared << " Gaussians compared; worst relative error batch " << worst_batch
                   << ", reference " << worst_scalar);
    REQUIRE(compared > n / 2);
    REQUIRE(worst_batch <= std::max(4 * worst_scalar, 1e-5));
  }
}

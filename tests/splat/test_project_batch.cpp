// The batch (SIMD) path of project_scene against the scalar reference
// project_gaussian: identical culling reasons, radii and rectangles, values
// within float rounding, on random scenes mixed with every kind of cull.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
#include <random>
#include <vector>

#include "orbitforge/splat/project.hpp"

using namespace orbitforge;

namespace project_batch_test {

template <class S>
Camera<S> camera() {
  Intrinsics<S> k{S(300), S(280), S(131.5), S(93.0), 256, 192};
  return Camera<S>::look_at(Eigen::Matrix<S, 3, 1>(S(0.3), S(-0.4), S(-3.5)), Eigen::Matrix<S, 3, 1>(S(0), S(0), S(0)),
                            Eigen::Matrix<S, 3, 1>(S(0), S(-1), S(0)), k);
}

// Random Gaussians, each with probability ~1/3 one of the special cases below.
template <class S>
GaussianScene<S> mixed_scene(std::mt19937& rng, std::size_t n, int degree, const Camera<S>& cam) {
  GaussianScene<S> s;
  s.resize(n, degree);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  std::uniform_int_distribution<int> pick(0, 44);
  const int k_count = sh_coefficient_count(degree);
  const S nan = std::numeric_limits<S>::quiet_NaN(), inf = std::numeric_limits<S>::infinity();
  const Eigen::Matrix<S, 3, 1> c = cam.center();
  const double logit_min = std::log((1.0 / 255.0) / (1.0 - 1.0 / 255.0));
  for (std::size_t i = 0; i < n; ++i) {
    S* m = &s.means[3 * i];
    S* q = &s.rotations[4 * i];
    S* l = &s.log_scales[3 * i];
    for (int a = 0; a < 3; ++a) m[a] = S(1.3 * u(rng));
    for (int a = 0; a < 4; ++a) q[a] = S(nd(rng));
    for (int a = 0; a < 3; ++a) l[a] = S(-3.5 + 1.2 * nd(rng));
    s.opacity_logits[i] = S(3 * u(rng));
    for (int k = 0; k < 3 * k_count; ++k) s.sh[3 * k_count * i + k] = S(0.4 * u(rng));
    switch (pick(rng)) {
      case 0: m[2] = S(-4 - 2 * std::abs(u(rng))); break;                   // behind the camera
      case 1: m[2] = S(c[2] + 0.01 + 1e-7 * u(rng)); m[0] = S(c[0]); break;  // at the near plane
      case 2: m[0] = S(20 * (u(rng) > 0 ? 1 : -1) + u(rng)); break;           // outside the image
      case 3: m[1] = S(6 + 2 * u(rng)); l[0] = l[1] = l[2] = S(-1); break;    // partly outside
      case 4: s.opacity_logits[i] = S(-6 - 3 * std::abs(u(rng))); break;     // faint
      case 5: s.opacity_logits[i] = S(logit_min + 1e-6 * u(rng)); break;     // at alpha_min
      case 6: s.opacity_logits[i] = S(logit_min + 0.02 * std::abs(u(rng))); l[0] = l[1] = l[2] = S(-7); break;
      case 7: m[int(3 * std::abs(u(rng))) % 3] = u(rng) > 0 ? nan : inf; break;
      case 8: q[int(4 * std::abs(u(rng))) % 4] = nan; break;
      case 9: l[int(3 * std::abs(u(rng))) % 3] = u(rng) > 0 ? -inf : inf; break;
      case 10: s.opacity_logits[i] = nan; break;
      case 11: s.sh[3 * k_count * i + std::size_t(3 * k_count * std::abs(u(rng))) % (3 * k_count)] = -inf; break;
      case 12: q[0] = q[1] = q[2] = q[3] = S(0); break;                     // zero quaternion
      case 13: l[0] = S(20 + 100 * std::abs(u(rng))); break;                 // huge (exp may overflow)
      case 14: l[0] = l[1] = l[2] = S(-40 - 20 * std::abs(u(rng))); break;  // tiny (s^2 underflows)
      case 15: l[0] = l[1] = S(-12); l[2] = S(0.5); break;                  // needle
      default: break;
    }
  }
  return s;
}

template <class S>
struct Reference {
  ProjectionStats stats;
  std::vector<Splat<S>> splats;
  std::vector<CullReason> why;
  std::vector<double> cov_mag;  // bound on |terms| summed into cov2d: s_max^2 |J|^2
  std::vector<double> z_cond;   // (|R_2| |x| + |t_2|) / t_z: t_z's relative rounding in units
};

template <class Scene>
Reference<typename Scene::scalar_type> reference(const Scene& scene, const ProjectionCamera<typename Scene::scalar_type>& cam) {
  using S = typename Scene::scalar_type;
  Reference<S> r;
  const std::size_t n = scene.size();
  r.splats.resize(n);
  r.why.resize(n);
  r.cov_mag.resize(n);
  r.z_cond.resize(n);
  S buf[48];
  GaussianParams<S> g;
  for (std::size_t i = 0; i < n; ++i) {
    detail::gather_gaussian(scene, i, scene.sh_degree(), g, buf);
    r.why[i] = project_gaussian(cam, g, r.splats[i]);
    double s2 = 0;
    for (int a = 0; a < 3; ++a) s2 = std::max(s2, double(g.scale[a]) * double(g.scale[a]));
    const double lim2 = std::max(double(cam.lim_x), double(cam.lim_y)) * std::max(double(cam.lim_x), double(cam.lim_y));
    const double z = double(r.splats[i].depth);
    double zs = std::abs(double(cam.t[2]));
    for (int a = 0; a < 3; ++a) zs += std::abs(double(cam.R(2, a)) * double(g.mean[a]));
    r.z_cond[i] = zs / z;
    r.cov_mag[i] = s2 * (double(cam.fx) * cam.fx + double(cam.fy) * cam.fy) * (1 + lim2) / (z * z);
    std::size_t* counts[5] = {&r.stats.visible, &r.stats.culled_near, &r.stats.culled_outside, &r.stats.culled_faint,
                              &r.stats.culled_nonfinite};
    ++*counts[int(r.why[i])];
  }
  return r;
}

// The batch kernel with batch type B, straight (no chunks, no threads).
template <class B, class Scene>
ProjectionStats run_lanes(const Scene& scene, const ProjectionCamera<typename Scene::scalar_type>& cam,
                          ProjectedSplats<typename Scene::scalar_type>& out) {
  using S = typename Scene::scalar_type;
  constexpr std::size_t W = B::size;
  const std::size_t n = scene.size();
  out.resize(n);
  std::size_t local[5] = {0, 0, 0, 0, 0};
  detail::GaussianLanes<S, int(W)> lanes{};
  for (std::size_t i = 0; i < n; i += W)
    detail::project_lanes<B>(scene, cam, scene.sh_degree(), i, int(std::min(W, n - i)), lanes, out, local);
  ProjectionStats st;
  st.visible = local[0];
  st.culled_near = local[1];
  st.culled_outside = local[2];
  st.culled_faint = local[3];
  st.culled_nonfinite = local[4];
  return st;
}

struct Mismatch {
  std::size_t radius = 0, rect = 0, value = 0;
  double worst = 0;  // largest error in units of the tolerance
};

// Values: |batch - reference| <= tol * scale, scale = the magnitude of the terms
// summed into the value: u = fx t_x / t_z + cx and v likewise, with t_z's own
// relative rounding (z_cond units: t_z = R_2 x + t_2 cancels near the camera
// plane) carried into u, v, the depth and the conic; the conic's
// relative error is that of cov2d (whose terms reach cov_mag, its eigenvalues
// are >= eps2d = 0.3) times the 2x2 condition number; colours are sums of terms
// of size ~1.
template <class S>
Mismatch compare(const ProjectedSplats<S>& out, const Reference<S>& ref, const ProjectionCamera<S>& cam) {
  Mismatch m;
  const double tol = 16 * double(std::numeric_limits<S>::epsilon());
  for (std::size_t i = 0; i < ref.splats.size(); ++i) {
    const Splat<S>& r = ref.splats[i];
    if (out.radius[i] != r.radius) {
      ++m.radius;
      continue;
    }
    if (ref.why[i] != CullReason::none) continue;
    if (out.rect_x0[i] != r.rect_x0 || out.rect_x1[i] != r.rect_x1 || out.rect_y0[i] != r.rect_y0 ||
        out.rect_y1[i] != r.rect_y1) {
      ++m.rect;
      continue;
    }
    const double a = r.conic_a, b = r.conic_b, c = r.conic_c;
    const double kappa = (a * c + b * b) / (a * c - b * b);
    const double zc = ref.z_cond[i];
    const double conic_scale = kappa * (std::abs(a) + std::abs(c)) * (1 + ref.cov_mag[i] / 0.3) * zc;
    const double got[10] = {out.mean_x[i], out.mean_y[i], out.conic_a[i], out.conic_b[i], out.conic_c[i],
                            out.opacity[i], out.color_r[i], out.color_g[i], out.color_b[i], out.depth[i]};
    const double want[10] = {r.mean_x, r.mean_y, a, b, c, r.opacity, r.color[0], r.color[1], r.color[2], r.depth};
    const double du = std::abs(want[0] - double(cam.cx)), dv = std::abs(want[1] - double(cam.cy));
    const double scale[10] = {1 + std::abs(want[0]) + std::abs(double(cam.cx)) + du * zc,
                              1 + std::abs(want[1]) + std::abs(double(cam.cy)) + dv * zc,
                              conic_scale, conic_scale, conic_scale, std::abs(want[5]), 1.0, 1.0, 1.0,
                              std::abs(want[9]) * zc};
    bool bad = false;
    for (int f = 0; f < 10; ++f) {
      const double e = std::abs(got[f] - want[f]) / (tol * scale[f]);
      m.worst = std::max(m.worst, e);
      bad = bad || !(e <= 1);
    }
    m.value += bad ? 1 : 0;
  }
  return m;
}

template <class S>
void check_same(const ProjectionStats& a, const ProjectionStats& b) {
  CHECK(a.visible == b.visible);
  CHECK(a.culled_near == b.culled_near);
  CHECK(a.culled_outside == b.culled_outside);
  CHECK(a.culled_faint == b.culled_faint);
  CHECK(a.culled_nonfinite == b.culled_nonfinite);
}

// project_scene on `view` against the reference: the same decisions, values
// within rounding. Returns project_scene's statistics.
template <class S, class Scene, class Ref>
ProjectionStats check_project_scene(const Scene& view, const Camera<S>& cam, const ProjectionParams& params,
                                    const Ref& ref, int threads) {
  const auto pc = ProjectionCamera<S>::make(cam, params);
  ProjectedSplats<S> out;
  ProjectionStats st;
  project_scene(view, cam, params, out, &st, threads);
  check_same<S>(st, ref.stats);
  const Mismatch m = compare(out, ref, pc);
  CAPTURE(m.worst);
  CHECK(m.radius == 0);
  CHECK(m.rect == 0);
  CHECK(m.value == 0);
  return st;
}

}  // namespace project_batch_test

using namespace project_batch_test;

TEMPLATE_TEST_CASE("batch projection: same culling, radii and rectangles as project_gaussian, values within rounding",
                   "[splat][project][batch]", float, double) {
  using S = TestType;
  const auto cam = camera<S>();
  std::mt19937 rng(11);
  constexpr std::size_t W = simd::native_batch<S>::size;
  for (int degree = 0; degree <= 3; ++degree)
    for (std::size_t n : {std::size_t(1), W - 1 + (W == 1), W, W + 1, 3 * W + 5, std::size_t(4099)})
      for (bool tight : {true, false}) {
        CAPTURE(degree, n, tight);
        ProjectionParams params;
        params.tight_extents = tight;
        params.chunk = n > 100 ? 1000 : 7;  // chunk ends that are not batch ends
        const auto pc = ProjectionCamera<S>::make(cam, params);
        const auto scene = mixed_scene<S>(rng, n, degree, cam);
        const SceneView<S> view(scene);
        const auto ref = reference(view, pc);
        check_project_scene(view, cam, params, ref, n > 100 ? 2 : 1);

        // The one-lane kernel (what ORBITFORGE_NO_SIMD builds) agrees as well.
        ProjectedSplats<S> out1;
        check_same<S>(run_lanes<simd::scalar_batch<S>>(view, pc, out1), ref.stats);
        const Mismatch m1 = compare(out1, ref, pc);
        CHECK(m1.radius == 0);
        CHECK(m1.rect == 0);
        CHECK(m1.value == 0);
      }
}

TEMPLATE_TEST_CASE("batch projection through an activated-scale adaptor (signed scales, offsets)",
                   "[splat][project][batch]", float, double) {
  using S = TestType;
  const auto cam = camera<S>();
  std::mt19937 rng(12);
  std::normal_distribution<double> nd;
  for (int degree : {0, 3}) {
    const std::size_t n = 2053;
    const auto base = mixed_scene<S>(rng, n, degree, cam);
    std::vector<S> dx(3 * n), dq(4 * n), ds(3 * n);
    for (auto& v : dx) v = S(0.05 * nd(rng));
    for (auto& v : dq) v = S(0.1 * nd(rng));
    for (auto& v : ds) v = S(0.05 * nd(rng));  // additive: some scales end negative
    ds[7] = std::numeric_limits<S>::quiet_NaN();
    const DeformedSceneView<S> view(base, dx.data(), dq.data(), ds.data());
    ProjectionParams params;
    const auto pc = ProjectionCamera<S>::make(cam, params);
    CAPTURE(degree);
    check_project_scene(view, cam, params, reference(view, pc), 1);
  }
}

TEST_CASE("batch projection: a large random scene decides every Gaussian as the reference does",
          "[splat][project][batch]") {
  // Many Gaussians near rectangle and radius boundaries: the lanes the batch path
  // hands to the reference must include every one whose decision could differ.
  using S = float;
  const auto cam = camera<S>();
  std::mt19937 rng(13);
#ifdef ORBITFORGE_TEST_QUICK
  const std::size_t n = 20000;
#else
  const std::size_t n = 200000;
#endif
  const auto scene = mixed_scene<S>(rng, n, 3, cam);
  const SceneView<S> view(scene);
  ProjectionParams params;
  const auto pc = ProjectionCamera<S>::make(cam, params);
  const ProjectionStats st = check_project_scene(view, cam, params, reference(view, pc), 2);
  CHECK(st.visible > n / 2);
}

TEMPLATE_TEST_CASE("batch projection: round splats at a step of the radius decide as the reference does",
                   "[splat][project][batch]", float, double) {
  // A round splat's 3-sigma radius is ceil(3 sqrt(lambda)), lambda the larger
  // eigenvalue of its 2D covariance. Each splat here gets the log-scale, to the
  // last bit, where the reference's radius steps up (found by bisection), or a
  // few units in the last place either side: where the two paths' rounding
  // could part, the batch path must hand the lane to the reference.
  using S = TestType;
  const auto cam = camera<S>();
  ProjectionParams params;
  params.tight_extents = false;  // the radius alone bounds the rectangle
  const auto pc = ProjectionCamera<S>::make(cam, params);
  std::mt19937 rng(14);
  std::uniform_real_distribution<double> u(-1, 1);
  const std::size_t n = 3000;
  GaussianScene<S> scene;
  scene.resize(n, 0);
  auto radius_of = [&](std::size_t i, S log_scale) {
    GaussianParams<S> g{};
    for (int a = 0; a < 3; ++a) g.mean[a] = scene.means[3 * i + std::size_t(a)];
    for (int a = 0; a < 4; ++a) g.quat[a] = scene.rotations[4 * i + std::size_t(a)];
    for (int a = 0; a < 3; ++a) g.scale[a] = std::exp(log_scale);
    g.opacity_logit = scene.opacity_logits[i];
    g.sh_degree = 0;
    g.sh = &scene.sh[3 * i];
    Splat<S> sp;
    return project_gaussian(pc, g, sp) == CullReason::none ? sp.radius : -1;
  };
  std::size_t stepped = 0;
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) scene.means[3 * i + std::size_t(a)] = S(0.6 * u(rng));
    for (int a = 0; a < 4; ++a) scene.rotations[4 * i + std::size_t(a)] = S(u(rng) + (a == 0 ? 2 : 0));
    scene.opacity_logits[i] = S(2);
    for (int c = 0; c < 3; ++c) scene.sh[3 * i + std::size_t(c)] = S(0.3);
    // Bisect on the log-scale between a radius of a few pixels and one 4-8
    // pixels larger, down to adjacent values of S.
    S lo = S(-4.5 + 0.3 * u(rng)), hi = lo + S(0.5);
    const int r_lo = radius_of(i, lo), r_hi = radius_of(i, hi);
    REQUIRE(r_lo > 0);
    REQUIRE(r_hi > r_lo);
    for (int it = 0; it < 200; ++it) {
      const S mid = lo + (hi - lo) / 2;
      if (!(mid > lo && mid < hi)) break;
      (radius_of(i, mid) == r_lo ? lo : hi) = mid;
    }
    stepped += radius_of(i, hi) > radius_of(i, lo) ? 1 : 0;
    S l = (i % 3 == 0) ? lo : hi;
    for (int k = int(i % 7) - 3; k != 0; k += k > 0 ? -1 : 1)
      l = std::nextafter(l, k > 0 ? std::numeric_limits<S>::infinity() : -std::numeric_limits<S>::infinity());
    for (int a = 0; a < 3; ++a) scene.log_scales[3 * i + std::size_t(a)] = l;
  }
  CHECK(stepped == n);
  const SceneView<S> view(scene);
  const ProjectionStats st = check_project_scene(view, cam, params, reference(view, pc), 1);
  CHECK(st.visible == n);
}

namespace project_batch_test {

// A SceneView without sh_data(): the batch path reads each coefficient through sh().
template <class S>
struct ShByCall {
  using scalar_type = S;
  static constexpr ScaleMode scale_mode = ScaleMode::log;
  const SceneView<S>& v;
  std::size_t size() const { return v.size(); }
  int sh_degree() const { return v.sh_degree(); }
  void mean(std::size_t i, S out[3]) const { v.mean(i, out); }
  void rotation(std::size_t i, S out[4]) const { v.rotation(i, out); }
  void scale(std::size_t i, S out[3]) const { v.scale(i, out); }
  S opacity_logit(std::size_t i) const { return v.opacity_logit(i); }
  S sh(std::size_t i, int k, int c) const { return v.sh(i, k, c); }
};

template <class S>
bool same_bits(const std::vector<S>& a, const std::vector<S>& b) {
  return a.size() == b.size() && (a.empty() || std::memcmp(a.data(), b.data(), a.size() * sizeof(S)) == 0);
}

}  // namespace project_batch_test

TEMPLATE_TEST_CASE("batch projection: coefficients transposed from sh_data() give the bits read through sh()",
                   "[splat][project][batch]", float, double) {
  using S = TestType;
  static_assert(adaptor_detail::has_sh_data<SceneView<S>>::value, "SceneView exposes its coefficients");
  static_assert(adaptor_detail::has_sh_data<DeformedSceneView<S>>::value, "so does DeformedSceneView");
  static_assert(!adaptor_detail::has_sh_data<ShByCall<S>>::value, "the wrapper hides them");
  const auto cam = camera<S>();
  std::mt19937 rng(15);
  std::uniform_real_distribution<double> u(-1, 1);
  constexpr std::size_t W = simd::native_batch<S>::size;
  // Whole batches only, a partial last batch, and sizes where the last whole
  // batch's blocks would read past the array (degree 0 to 2: 3 k is not a
  // multiple of the lane count).
  for (int degree = 0; degree <= 3; ++degree)
    for (std::size_t n : {W, 2 * W + 3, 4 * W, std::size_t(1001)}) {
      CAPTURE(degree, n);
      const auto scene = mixed_scene<S>(rng, n, degree, cam);
      const SceneView<S> view(scene);
      const ShByCall<S> by_call{view};
      ProjectedSplats<S> a, b;
      ProjectionStats sa, sb;
      project_scene(view, cam, ProjectionParams{}, a, &sa, 1);
      project_scene(by_call, cam, ProjectionParams{}, b, &sb, 1);
      check_same<S>(sa, sb);
      CHECK(a.radius == b.radius);
      CHECK(a.rect_x0 == b.rect_x0);
      CHECK(a.rect_y1 == b.rect_y1);
      for (auto f : {&ProjectedSplats<S>::mean_x, &ProjectedSplats<S>::conic_b, &ProjectedSplats<S>::opacity,
                     &ProjectedSplats<S>::color_r, &ProjectedSplats<S>::color_g, &ProjectedSplats<S>::color_b,
                     &ProjectedSplats<S>::depth})
        CHECK(same_bits(a.*f, b.*f));

      // The VJP gathers its lanes the same way.
      ProjectedSplatsGrad<S> w;
      w.assign_zero(n);
      for (auto* g : {&w.v_mean_x, &w.v_conic_a, &w.v_opacity, &w.v_color_r, &w.v_color_g, &w.v_color_b, &w.v_depth})
        for (auto& x : *g) x = S(u(rng));
      GaussianSceneGrad<S> ga, gb;
      project_scene_vjp(view, cam, ProjectionParams{}, a, w, ga, Freeze{}, 1);
      project_scene_vjp(by_call, cam, ProjectionParams{}, a, w, gb, Freeze{}, 1);
      CHECK(same_bits(ga.sh, gb.sh));
      CHECK(same_bits(ga.means, gb.means));
      CHECK(same_bits(ga.opacity_logits, gb.opacity_logits));
    }
}

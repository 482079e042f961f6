#include <catch2/catch.hpp>

#include <Eigen/Geometry>
#include <cmath>
#include <limits>
#include <random>

#include "orbitforge/splat/project.hpp"

using namespace orbitforge;

namespace {

template <class S>
Camera<S> test_camera(int w = 64, int h = 48) {
  Intrinsics<S> k{S(60), S(55), S(0.5 * w + 1.5), S(0.5 * h - 2.0), w, h};
  Camera<S> cam = Camera<S>::look_at(Eigen::Matrix<S, 3, 1>(S(0.3), S(-0.2), S(-4)),
                                     Eigen::Matrix<S, 3, 1>(S(0), S(0), S(0)),
                                     Eigen::Matrix<S, 3, 1>(S(0), S(-1), S(0)), k);
  return cam;
}

// Random Gaussians around the origin, visible from test_camera.
template <class S>
GaussianScene<S> random_scene(std::mt19937& rng, std::size_t n, int degree, double spread = 1.0) {
  GaussianScene<S> s;
  s.resize(n, degree);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = S(spread * u(rng));
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = S(nd(rng));
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = S(-2.5 + 0.7 * u(rng));
    s.opacity_logits[i] = S(2 * u(rng));
  }
  for (auto& v : s.sh) v = S(0.3 * u(rng));
  return s;
}

template <class S>
GaussianScene<S> single(const Eigen::Matrix<S, 3, 1>& x, S log_scale, S logit = S(0), int degree = 0) {
  GaussianScene<S> s;
  s.resize(1, degree);
  for (int a = 0; a < 3; ++a) {
    s.means[a] = x[a];
    s.log_scales[a] = log_scale;
  }
  s.opacity_logits[0] = logit;
  return s;
}

}  // namespace

TEMPLATE_TEST_CASE("quat_to_rotmat: normalises and matches Eigen", "[splat][project]", float, double) {
  using S = TestType;
  std::mt19937 rng(3);
  std::normal_distribution<double> nd;
  for (int trial = 0; trial < 50; ++trial) {
    S q[4];
    for (auto& v : q) v = S(3 * nd(rng));
    Eigen::Matrix<S, 3, 3> R;
    quat_to_rotmat(q, R);
    const Eigen::Quaternion<S> eq(q[0], q[1], q[2], q[3]);
    const Eigen::Matrix<S, 3, 3> ref = eq.normalized().toRotationMatrix();
    const S tol = std::is_same<S, float>::value ? S(1e-5) : S(1e-13);
    REQUIRE((R - ref).cwiseAbs().maxCoeff() < tol);
    REQUIRE((R * R.transpose() - Eigen::Matrix<S, 3, 3>::Identity()).cwiseAbs().maxCoeff() < tol);
  }
}

TEMPLATE_TEST_CASE("projection of an isotropic Gaussian: mean, conic, radius, colour", "[splat][project]", float,
                   double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  // Camera at the origin looking down +z, identity pose.
  Camera<S> cam;
  cam.intrinsics = {S(100), S(80), S(30), S(20), 64, 40};
  const S z = S(5), sigma = S(0.1);
  auto scene = single<S>(Vec3(S(0.5), S(-0.25), z), std::log(sigma), S(1.5), 1);
  scene.sh[0] = S(1);            // DC red
  scene.sh[3 * 2 + 1] = S(0.4);  // k=2 (C1 z) green
  ProjectedSplats<S> out;
  ProjectionStats st;
  project_scene(SceneView<S>(scene), cam, ProjectionParams{}, out, &st, 1);
  REQUIRE(st.visible == 1);
  REQUIRE(out.radius[0] > 0);
  const double tol = std::is_same<S, float>::value ? 1e-4 : 1e-10;
  REQUIRE(out.mean_x[0] == Approx(100 * 0.5 / 5 + 30).epsilon(tol));
  REQUIRE(out.mean_y[0] == Approx(80 * -0.25 / 5 + 20).epsilon(tol));
  REQUIRE(out.depth[0] == Approx(5).epsilon(tol));
  REQUIRE(out.opacity[0] == Approx(1 / (1 + std::exp(-1.5))).epsilon(tol));
  // The EWA covariance of an isotropic 3D Gaussian off-axis: J Sigma J^T, J from
  // the formula (no clamping here), + 0.3.
  const double x = 0.5, y = -0.25, zz = 5, s2 = 0.01, fx = 100, fy = 80;
  const double j00 = fx / zz, j02 = -fx * x / (zz * zz), j11 = fy / zz, j12 = -fy * y / (zz * zz);
  const double cxx = s2 * (j00 * j00 + j02 * j02) + 0.3, cxy = s2 * j02 * j12, cyy = s2 * (j11 * j11 + j12 * j12) + 0.3;
  const double det = cxx * cyy - cxy * cxy;
  REQUIRE(out.conic_a[0] == Approx(cyy / det).epsilon(tol));
  REQUIRE(out.conic_b[0] == Approx(-cxy / det).epsilon(tol));
  REQUIRE(out.conic_c[0] == Approx(cxx / det).epsilon(tol));
  const double mid = 0.5 * (cxx + cyy), lmax = mid + std::sqrt(mid * mid - det);
  REQUIRE(out.radius[0] == int(std::ceil(3 * std::sqrt(lmax))));
  // Colour: direction = mean - camera centre = mean.
  const double n = std::sqrt(x * x + y * y + zz * zz);
  REQUIRE(out.color_r[0] == Approx(0.28209479177387814 + 0.5).epsilon(tol));
  REQUIRE(out.color_g[0] == Approx(0.4886025119029199 * (zz / n) * 0.4 + 0.5).epsilon(tol));
  REQUIRE(out.color_b[0] == Approx(0.5).epsilon(tol));
}

TEMPLATE_TEST_CASE("anisotropic Gaussian on the optical axis of a rotated camera: closed form", "[splat][project]",
                   float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  // Gaussian rotation: 120 deg about (1, 1, 1), q = (1, 1, 1, 1) un-normalised:
  // local x, y, z -> world y, z, x. Camera rows (right, down, forward) = world z,
  // x, y, so camera x, y, z see the Gaussian's local y, z, x: camera-space
  // covariance diag(s2^2, s3^2, s1^2). (The transposed camera or the conjugate
  // quaternion would give another permutation.)
  const double s1 = 0.3, s2 = 0.2, s3 = 0.1, z = 4, fx = 100, fy = 80, cx = 31.5, cy = 19.25;
  Camera<S> cam;
  cam.intrinsics = {S(fx), S(fy), S(cx), S(cy), 64, 40};
  cam.R << 0, 0, 1, 1, 0, 0, 0, 1, 0;
  const Vec3 mean(S(0.2), S(-0.3), S(0.4));
  const Vec3 centre = mean - S(z) * Vec3(0, 1, 0);  // the mean on the optical axis at depth z
  cam.t = -cam.R * centre;
  auto scene = single<S>(mean, S(0), S(0.7), 1);
  for (int q = 0; q < 4; ++q) scene.rotations[std::size_t(q)] = S(1);
  scene.log_scales[0] = S(std::log(s1));
  scene.log_scales[1] = S(std::log(s2));
  scene.log_scales[2] = S(std::log(s3));
  scene.sh[3 * 1 + 0] = S(0.5);   // k = 1: -C1 y
  scene.sh[3 * 3 + 1] = S(0.7);   // k = 3: -C1 x (x = 0 here)
  scene.sh[3 * 1 + 2] = S(-0.2);
  ProjectedSplats<S> out;
  project_scene(SceneView<S>(scene), cam, ProjectionParams{}, out, nullptr, 1);
  REQUIRE(out.radius[0] > 0);
  const double tol = std::is_same<S, float>::value ? 1e-5 : 1e-12;
  // On the axis J = diag(fx / z, fy / z) (no z column): cov2d is diagonal.
  const double cxx = (fx / z) * (fx / z) * s2 * s2 + 0.3, cyy = (fy / z) * (fy / z) * s3 * s3 + 0.3;  // 25.3, 4.3
  CHECK(out.mean_x[0] == Approx(cx).epsilon(tol));
  CHECK(out.mean_y[0] == Approx(cy).epsilon(tol));
  CHECK(out.depth[0] == Approx(z).epsilon(tol));
  CHECK(out.conic_a[0] == Approx(1 / cxx).epsilon(tol));
  CHECK(std::abs(double(out.conic_b[0])) < tol);
  CHECK(out.conic_c[0] == Approx(1 / cyy).epsilon(tol));
  CHECK(out.radius[0] == 16);  // ceil(3 sqrt(25.3)) = ceil(15.09)
  // Viewing direction = world +y: basis (C0, -C1, 0, 0).
  const double C1 = 0.4886025119029199;
  CHECK(out.color_r[0] == Approx(0.5 - C1 * 0.5).epsilon(tol));
  CHECK(out.color_g[0] == Approx(0.5).epsilon(tol));
  CHECK(out.color_b[0] == Approx(0.5 + C1 * 0.2).epsilon(tol));
}

TEMPLATE_TEST_CASE("anisotropic Gaussian off-axis, rotated camera, with and without the clamp: closed form",
                   "[splat][project]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  const double fx = 100, fy = 80, cx = 31.5, cy = 19.25;
  const int W = 64, H = 40;
  const double lim_x = 1.3 * 0.5 * W / fx, lim_y = 1.3 * 0.5 * H / fy;  // 0.416, 0.325
  // Camera rows (right, down, forward) = world y, z, x.
  Camera<S> cam;
  cam.intrinsics = {S(fx), S(fy), S(cx), S(cy), W, H};
  cam.R << 0, 1, 0, 0, 0, 1, 1, 0, 0;
  const Vec3 centre(S(0.3), S(-0.2), S(0.1));
  cam.t = -cam.R * centre;
  struct Case { double tx, ty, tz, s1, s2, s3; };
  // Inside the clamp; x/z beyond it (u off the image, the Gaussian large enough to
  // reach in); y/z beyond it.
  for (const Case c : {Case{1.0, -0.8, 4, 0.15, 0.25, 0.1}, Case{2.4, 0.3, 4, 1.6, 0.9, 0.5},
                       Case{0.2, -1.6, 4, 0.2, 0.35, 1.1}}) {
    INFO("camera-space mean " << c.tx << ", " << c.ty << ", " << c.tz);
    // Gaussian rotation 45 deg about world z, q = (cos 22.5, 0, 0, sin 22.5):
    // Sigma_world = [[p, m, 0], [m, p, 0], [0, 0, s3^2]], p = (s1^2 + s2^2) / 2,
    // m = (s1^2 - s2^2) / 2. In camera space (x, y, z) = world (y, z, x):
    // Sxx = p, Syy = s3^2, Szz = p, Sxz = m, Sxy = Syz = 0.
    const double p = 0.5 * (c.s1 * c.s1 + c.s2 * c.s2), m = 0.5 * (c.s1 * c.s1 - c.s2 * c.s2);
    const double Sxx = p, Syy = c.s3 * c.s3, Szz = p, Sxz = m;
    const Vec3 mean = centre + cam.R.transpose() * Vec3(S(c.tx), S(c.ty), S(c.tz));
    auto scene = single<S>(mean, S(0), S(2), 0);
    const double half = 3.14159265358979323846 / 8;
    scene.rotations[0] = S(std::cos(half));
    scene.rotations[3] = S(std::sin(half));
    scene.log_scales[0] = S(std::log(c.s1));
    scene.log_scales[1] = S(std::log(c.s2));
    scene.log_scales[2] = S(std::log(c.s3));
    ProjectedSplats<S> out;
    project_scene(SceneView<S>(scene), cam, ProjectionParams{}, out, nullptr, 1);
    REQUIRE(out.radius[0] > 0);
    // J = [[A, 0, B], [0, C, D]], A = fx/z, B = -fx tx'/z^2, C = fy/z, D = -fy ty'/z^2,
    // tx' = clamp(tx/z, +-lim_x) z (likewise y).
    const double z = c.tz;
    const double txc = std::max(-lim_x, std::min(lim_x, c.tx / z)) * z;
    const double tyc = std::max(-lim_y, std::min(lim_y, c.ty / z)) * z;
    const double A = fx / z, B = -fx * txc / (z * z), C = fy / z, D = -fy * tyc / (z * z);
    const double cxx = A * A * Sxx + 2 * A * B * Sxz + B * B * Szz + 0.3;
    const double cxy = A * D * Sxz + B * D * Szz;  // + A C Sxy + B C Syz, both zero
    const double cyy = C * C * Syy + D * D * Szz + 0.3;
    const double det = cxx * cyy - cxy * cxy;
    const double mid = 0.5 * (cxx + cyy), r3 = 3 * std::sqrt(mid + std::sqrt(mid * mid - det));
    INFO("cov2d " << cxx << " " << cxy << " " << cyy << ", 3 sqrt(lambda_max) " << r3);
    const double tol = std::is_same<S, float>::value ? 2e-5 : 1e-11;
    CHECK(out.mean_x[0] == Approx(fx * c.tx / z + cx).epsilon(tol));
    CHECK(out.mean_y[0] == Approx(fy * c.ty / z + cy).epsilon(tol));
    CHECK(out.depth[0] == Approx(z).epsilon(tol));
    CHECK(out.conic_a[0] == Approx(cyy / det).epsilon(tol));
    CHECK(out.conic_b[0] == Approx(-cxy / det).epsilon(tol));
    CHECK(out.conic_c[0] == Approx(cxx / det).epsilon(tol));
    REQUIRE(std::abs(r3 - std::round(r3)) > 1e-3);  // the ceil below is not a rounding coin toss
    CHECK(out.radius[0] == int(std::ceil(r3)));
  }
}

TEMPLATE_TEST_CASE("culling: near plane, outside, faint, non-finite; stats add up", "[splat][project]", float,
                   double) {
  using S = TestType;
  Camera<S> cam;
  cam.intrinsics = {S(100), S(100), S(32), S(32), 64, 64};
  const S inf = std::numeric_limits<S>::infinity(), nan = std::numeric_limits<S>::quiet_NaN();
  GaussianScene<S> s;
  s.resize(13, 1);
  auto put = [&](int i, S x, S y, S z, S ls, S logit) {
    s.means[3 * i] = x; s.means[3 * i + 1] = y; s.means[3 * i + 2] = z;
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = ls;
    s.opacity_logits[i] = logit;
  };
  put(0, 0, 0, 2, S(-3), 0);           // visible
  put(1, 0, 0, -1, S(-3), 0);          // behind the camera
  put(2, 0, 0, S(0.005), S(-3), 0);    // centre between camera and near plane
  put(3, 0, 0, S(0.02), S(-1), 0);     // straddles the near plane: kept, finite
  put(4, 50, 0, 2, S(-3), 0);          // far outside the view
  put(5, 0, 0, 2, S(-3), S(-6));       // opacity 0.0025 < 1/255
  put(6, nan, 0, 2, S(-3), 0);         // NaN mean
  put(7, 0, 0, 2, inf, 0);             // infinite scale
  put(8, 0, 0, 2, S(-3), 0);
  s.sh[3 * (4 * 8 + 2) + 1] = nan;     // NaN in a degree-1 SH coefficient
  put(9, 0, 0, 2, S(-3), 0);
  for (int a = 0; a < 4; ++a) s.rotations[4 * 9 + a] = 0;  // zero quaternion
  put(10, 0, 0, 2, S(-3), inf);        // infinite opacity logit
  put(11, 0, 0, 2, S(-3), 0);
  s.log_scales[3 * 11 + 2] = -inf;     // flattened: zero scale on one axis, still finite
  put(12, S(0.3), S(0.2), 2, S(-12), 0);  // far below one pixel
  ProjectedSplats<S> out;
  ProjectionStats st;
  project_scene(SceneView<S>(s), cam, ProjectionParams{}, out, &st, 2);
  REQUIRE(st.total() == 13);
  REQUIRE(st.visible == 4);
  REQUIRE(st.culled_near == 2);
  REQUIRE(st.culled_outside == 1);
  REQUIRE(st.culled_faint == 1);
  REQUIRE(st.culled_nonfinite == 5);
  const int visible[] = {0, 3, 11, 12};
  for (int i = 0; i < 13; ++i) {
    const bool vis = std::find(std::begin(visible), std::end(visible), i) != std::end(visible);
    INFO("Gaussian " << i);
    REQUIRE((out.radius[i] > 0) == vis);
    if (!vis) continue;
    for (S v : {out.mean_x[i], out.mean_y[i], out.conic_a[i], out.conic_b[i], out.conic_c[i], out.opacity[i],
                out.color_r[i], out.depth[i]})
      REQUIRE(std::isfinite(v));
    REQUIRE(out.conic_a[i] > 0);
    REQUIRE(out.conic_a[i] * out.conic_c[i] - out.conic_b[i] * out.conic_b[i] > 0);
    REQUIRE(out.rect_x0[i] >= 0);
    REQUIRE(out.rect_x1[i] < 64);
    REQUIRE(out.rect_x0[i] <= out.rect_x1[i]);
    REQUIRE(out.rect_y0[i] <= out.rect_y1[i]);
  }
  // The sub-pixel Gaussian's footprint is the dilation alone: conic ~ 1/0.3.
  REQUIRE(out.conic_a[12] == Approx(1 / 0.3).epsilon(1e-4));
  REQUIRE(out.radius[12] == 2);
  // The straddling one covers the whole image.
  REQUIRE(out.rect_x0[3] == 0);
  REQUIRE(out.rect_x1[3] == 63);
}

TEMPLATE_TEST_CASE("rectangles: 3-sigma square exactly, tight one never loses a pixel", "[splat][project]", float,
                   double) {
  using S = TestType;
  std::mt19937 rng(99);
  const auto cam = test_camera<S>(45, 31);
  auto scene = random_scene<S>(rng, 400, 0, 1.5);
  // Wide opacity range, some large Gaussians.
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::size_t i = 0; i < scene.size(); ++i) {
    scene.opacity_logits[i] = S(-5.5 + 11 * 0.5 * (1 + u(rng)));
    if (i % 7 == 0)
      for (int a = 0; a < 3; ++a) scene.log_scales[3 * i + a] += S(1.5);
  }
  ProjectionParams loose, tight;
  loose.tight_extents = false;
  tight.tight_extents = true;
  ProjectedSplats<S> a, b;
  ProjectionStats sa, sb;
  project_scene(SceneView<S>(scene), cam, loose, a, &sa, 1);
  project_scene(SceneView<S>(scene), cam, tight, b, &sb, 2);
  REQUIRE(sa.visible > 100);
  std::size_t pixels_loose = 0, pixels_tight = 0;
  const int W = cam.intrinsics.width, H = cam.intrinsics.height;
  for (std::size_t i = 0; i < scene.size(); ++i) {
    if (a.radius[i] <= 0) {
      REQUIRE(b.radius[i] <= 0);
      continue;
    }
    const S r = S(a.radius[i]);
    for (int y = 0; y < H; ++y)
      for (int x = 0; x < W; ++x) {
        const S px = S(x) + S(0.5), py = S(y) + S(0.5);
        const S dx = px - a.mean_x[i], dy = py - a.mean_y[i];
        const bool in_square = std::abs(dx) <= r && std::abs(dy) <= r;
        const bool in_a = x >= a.rect_x0[i] && x <= a.rect_x1[i] && y >= a.rect_y0[i] && y <= a.rect_y1[i];
        REQUIRE(in_a == in_square);
        pixels_loose += in_a;
        const S power = S(-0.5) * (a.conic_a[i] * dx * dx + a.conic_c[i] * dy * dy) - a.conic_b[i] * dx * dy;
        const S alpha = std::min(S(0.99), a.opacity[i] * std::exp(power));
        const bool reaches = in_square && alpha >= S(1) / S(255);
        if (b.radius[i] <= 0) {
          REQUIRE(!reaches);
          continue;
        }
        const bool in_b = x >= b.rect_x0[i] && x <= b.rect_x1[i] && y >= b.rect_y0[i] && y <= b.rect_y1[i];
        pixels_tight += in_b;
        if (reaches) REQUIRE(in_b);
        if (in_b) REQUIRE(in_a);
      }
  }
  REQUIRE(pixels_tight < pixels_loose);
  REQUIRE(sb.visible + sb.culled_faint == sa.visible + sa.culled_faint);
}

TEMPLATE_TEST_CASE("threads and chunking do not change the result", "[splat][project]", float, double) {
  using S = TestType;
  std::mt19937 rng(5);
  const auto cam = test_camera<S>();
  const auto scene = random_scene<S>(rng, 3000, 3);
  ProjectionParams p;
  p.chunk = 97;
  ProjectedSplats<S> a, b;
  ProjectionStats sa, sb;
  project_scene(SceneView<S>(scene), cam, p, a, &sa, 1);
  project_scene(SceneView<S>(scene), cam, p, b, &sb, 2);
  REQUIRE(sa.visible == sb.visible);
  REQUIRE(sa.total() == 3000);
  REQUIRE(a.radius == b.radius);
  REQUIRE(a.rect_x0 == b.rect_x0);
  for (std::size_t i = 0; i < scene.size(); ++i)
    if (a.radius[i] > 0) {
      REQUIRE(a.conic_a[i] == b.conic_a[i]);
      REQUIRE(a.color_b[i] == b.color_b[i]);
    }
}

TEST_CASE("float projection matches double", "[splat][project]") {
  std::mt19937 rng(8);
  const auto camd = test_camera<double>();
  const auto camf = test_camera<float>();
  for (int degree = 0; degree <= 3; ++degree) {
    const auto scened = random_scene<double>(rng, 500, degree);
    const auto scenef = scened.cast<float>();
    ProjectedSplats<double> d;
    ProjectedSplats<float> f;
    project_scene(SceneView<double>(scened), camd, ProjectionParams{}, d, nullptr, 1);
    project_scene(SceneView<float>(scenef), camf, ProjectionParams{}, f, nullptr, 1);
    std::size_t checked = 0;
    for (std::size_t i = 0; i < scened.size(); ++i) {
      if (d.radius[i] <= 0 || f.radius[i] <= 0) continue;
      ++checked;
      auto rel = [](double a, double b) { return std::abs(a - b) / std::max(1.0, std::abs(b)); };
      REQUIRE(rel(f.mean_x[i], d.mean_x[i]) < 1e-5);
      REQUIRE(rel(f.mean_y[i], d.mean_y[i]) < 1e-5);
      const double cs = std::abs(d.conic_a[i]) + std::abs(d.conic_c[i]);
      REQUIRE(std::abs(f.conic_a[i] - d.conic_a[i]) < 1e-4 * cs);
      REQUIRE(std::abs(f.conic_b[i] - d.conic_b[i]) < 1e-4 * cs);
      REQUIRE(std::abs(f.conic_c[i] - d.conic_c[i]) < 1e-4 * cs);
      REQUIRE(rel(f.opacity[i], d.opacity[i]) < 1e-6);
      REQUIRE(rel(f.color_r[i], d.color_r[i]) < 1e-5);
      REQUIRE(rel(f.color_g[i], d.color_g[i]) < 1e-5);
      REQUIRE(rel(f.depth[i], d.depth[i]) < 1e-6);
    }
    REQUIRE(checked > 200);
  }
}

TEMPLATE_TEST_CASE("DeformedSceneView renders the same as the materialised deformed scene", "[splat][project]",
                   float, double) {
  using S = TestType;
  std::mt19937 rng(21);
  const auto cam = test_camera<S>();
  const auto base = random_scene<S>(rng, 300, 2);
  std::normal_distribution<double> nd;
  std::vector<S> dx(3 * 300), dq(4 * 300), ds(3 * 300);
  for (auto& v : dx) v = S(0.1 * nd(rng));
  for (auto& v : dq) v = S(0.1 * nd(rng));
  for (auto& v : ds) v = S(0.02 * nd(rng));
  GaussianScene<S> mat = base;
  for (std::size_t i = 0; i < 300; ++i) {
    for (int a = 0; a < 3; ++a) mat.means[3 * i + a] += dx[3 * i + a];
    const S* q = &base.rotations[4 * i];
    const S n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int a = 0; a < 4; ++a) mat.rotations[4 * i + a] = q[a] / n + dq[4 * i + a];
    // |s| as log-scale: the covariance only sees s^2.
    for (int a = 0; a < 3; ++a)
      mat.log_scales[3 * i + a] = std::log(std::abs(std::exp(base.log_scales[3 * i + a]) + ds[3 * i + a]));
  }
  ProjectedSplats<S> a, b;
  project_scene(DeformedSceneView<S>(base, dx.data(), dq.data(), ds.data()), cam, ProjectionParams{}, a, nullptr, 1);
  project_scene(SceneView<S>(mat), cam, ProjectionParams{}, b, nullptr, 1);
  const double tol = std::is_same<S, float>::value ? 1e-4 : 1e-10;
  std::size_t kept = 0;
  for (std::size_t i = 0; i < 300; ++i) {
    REQUIRE(a.radius[i] == b.radius[i]);
    if (a.radius[i] <= 0) continue;
    ++kept;
    REQUIRE(a.conic_a[i] == Approx(b.conic_a[i]).epsilon(tol));
    REQUIRE(a.mean_x[i] == Approx(b.mean_x[i]).epsilon(tol));
    REQUIRE(a.color_g[i] == Approx(b.color_g[i]).epsilon(tol));
  }
  REQUIRE(kept > 100);
  // Null offsets: the base scene itself.
  project_scene(DeformedSceneView<S>(base, nullptr, nullptr, nullptr), cam, ProjectionParams{}, a, nullptr, 1);
  project_scene(SceneView<S>(base), cam, ProjectionParams{}, b, nullptr, 1);
  for (std::size_t i = 0; i < 300; ++i)
    if (b.radius[i] > 0) REQUIRE(a.conic_c[i] == Approx(b.conic_c[i]).epsilon(tol));
}

TEST_CASE("bad input raises orbitforge::Error", "[splat][project]") {
  GaussianScened s;
  s.resize(2, 1);
  s.means.pop_back();
  ProjectedSplats<double> out;
  REQUIRE_THROWS_AS(project_scene(SceneView<double>(s), test_camera<double>(), ProjectionParams{}, out), Error);
  s.resize(2, 1);
  Camerad cam = test_camera<double>();
  cam.intrinsics.width = 0;
  REQUIRE_THROWS_AS(project_scene(SceneView<double>(s), cam, ProjectionParams{}, out), Error);
  // Empty scene: fine.
  s.resize(0, 0);
  ProjectionStats st;
  project_scene(SceneView<double>(s), test_camera<double>(), ProjectionParams{}, out, &st);
  REQUIRE(out.size() == 0);
  REQUIRE(st.total() == 0);
}

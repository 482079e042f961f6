#pragma once
// A plain, obviously correct reference renderer: its own projection and SH colour
// (double, from the formulas), then for every pixel walk ALL Gaussians sorted by
// (depth, index) and blend with the rules of docs/conventions.md. No tiles, no
// SIMD, no threads, no early culling beyond the rect test. Plus helpers that build
// random ProjectedSplats for tests.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <set>
#include <vector>

#include "orbitforge/core/image.hpp"
#include <Eigen/Core>
#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"

namespace orbitforge_test {

using orbitforge::Image;
using orbitforge::ProjectedSplats;

template <class S>
struct ReferenceImages {
  Image<S> color, transmittance, depth;
  Image<std::int32_t> count;
};

// Same constants as RasterRules, spelled out.
// Tolerance of the SIMD renderer against the reference in the same precision.
template <class S> constexpr double same_precision_tol() { return sizeof(S) == 4 ? 1e-5 : 1e-10; }

template <class S> constexpr S ref_max_alpha() { return S(0.99); }
template <class S> constexpr S ref_min_alpha() { return S(1) / S(255); }
template <class S> constexpr S ref_min_T() { return S(1e-4); }

template <class S>
std::vector<std::size_t> reference_depth_order(const ProjectedSplats<S>& s) {
  std::vector<std::size_t> idx;
  for (std::size_t i = 0; i < s.size(); ++i)
    if (s.radius[i] > 0) idx.push_back(i);
  std::stable_sort(idx.begin(), idx.end(), [&](std::size_t a, std::size_t b) { return s.depth[a] < s.depth[b]; });
  return idx;
}

template <class S>
S reference_power(const ProjectedSplats<S>& s, std::size_t i, S px, S py) {
  const S dx = px - s.mean_x[i], dy = py - s.mean_y[i];
  return S(-0.5) * (s.conic_a[i] * dx * dx + s.conic_c[i] * dy * dy) - s.conic_b[i] * dx * dy;
}

template <class S>
bool reference_in_rect(const ProjectedSplats<S>& s, std::size_t i, int x, int y) {
  return x >= s.rect_x0[i] && x <= s.rect_x1[i] && y >= s.rect_y0[i] && y <= s.rect_y1[i];
}

template <class S>
ReferenceImages<S> reference_rasterize(const ProjectedSplats<S>& s, int width, int height,
                                       std::array<S, 3> background = {{0, 0, 0}}) {
  ReferenceImages<S> out{Image<S>(width, height, 3), Image<S>(width, height, 1), Image<S>(width, height, 1),
                         Image<std::int32_t>(width, height, 1)};
  const std::vector<std::size_t> order = reference_depth_order(s);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      const S px = S(x) + S(0.5), py = S(y) + S(0.5);
      S T = 1, c[3] = {0, 0, 0}, d = 0;
      int n = 0;
      for (std::size_t i : order) {
        if (!reference_in_rect(s, i, x, y)) continue;
        const S power = reference_power(s, i, px, py);
        if (power > 0) continue;
        const S alpha = std::min(ref_max_alpha<S>(), s.opacity[i] * std::exp(power));
        if (alpha < ref_min_alpha<S>()) continue;
        const S T_next = T * (1 - alpha);
        if (T_next < ref_min_T<S>()) break;  // pixel done, this Gaussian not blended
        const S w = alpha * T;
        c[0] += w * s.color_r[i];
        c[1] += w * s.color_g[i];
        c[2] += w * s.color_b[i];
        d += w * s.depth[i];
        T = T_next;
        ++n;
      }
      for (int ch = 0; ch < 3; ++ch) out.color(x, y, ch) = c[ch] + T * background[std::size_t(ch)];
      out.transmittance(x, y) = T;
      out.depth(x, y) = d;
      out.count(x, y) = n;
    }
  return out;
}

// Gaussians that have a (pixel, Gaussian) pair within a relative margin `rel` of
// a threshold (alpha clamp, 1/255 skip, 1e-4 stop), evaluated in double.
template <class S>
std::set<std::size_t> threshold_violators(const ProjectedSplats<S>& s, int width, int height, double rel) {
  std::set<std::size_t> bad;
  const std::vector<std::size_t> order = reference_depth_order(s);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      double T = 1;
      for (std::size_t i : order) {
        if (!reference_in_rect(s, i, x, y)) continue;
        const double dx = x + 0.5 - double(s.mean_x[i]), dy = y + 0.5 - double(s.mean_y[i]);
        const double power =
            -0.5 * (double(s.conic_a[i]) * dx * dx + double(s.conic_c[i]) * dy * dy) - double(s.conic_b[i]) * dx * dy;
        if (power > 0) continue;
        const double raw = double(s.opacity[i]) * std::exp(power);
        if (std::abs(raw - 0.99) < rel * 0.99) bad.insert(i);
        const double alpha = std::min(0.99, raw);
        if (std::abs(alpha - 1.0 / 255) < rel / 255) bad.insert(i);
        if (alpha < 1.0 / 255) continue;
        const double T_next = T * (1 - alpha);
        if (std::abs(T_next - 1e-4) < rel * 1e-4) bad.insert(i);
        if (T_next < 1e-4) break;
        T = T_next;
      }
    }
  return bad;
}

struct RandomSplatOptions {
  double sigma_min = 0.6, sigma_max = 12;  // pixels
  double opacity_min = 0.05, opacity_max = 1.0;
  double margin = 10;                       // means spread this far beyond the image
  double depth_min = 1, depth_max = 20;
};

// Sets the radius (3 sigma) and rect of Gaussian i from its conic, as the
// projection stage does; radius 0 when the rect misses the image.
template <class S>
void set_rect_from_conic(ProjectedSplats<S>& s, std::size_t i, int width, int height) {
  const double a = s.conic_a[i], b = s.conic_b[i], c = s.conic_c[i];
  const double det = a * c - b * b;
  const double ca = c / det, cb = -b / det, cc = a / det;  // covariance
  const double mid = 0.5 * (ca + cc), disc = std::sqrt(std::max(0.1, mid * mid - (ca * cc - cb * cb)));
  const int r = int(std::ceil(3 * std::sqrt(mid + disc)));
  const double mx = s.mean_x[i], my = s.mean_y[i];
  const int x0 = std::max(0, int(std::ceil(mx - r - 0.5))), x1 = std::min(width - 1, int(std::floor(mx + r - 0.5)));
  const int y0 = std::max(0, int(std::ceil(my - r - 0.5))), y1 = std::min(height - 1, int(std::floor(my + r - 0.5)));
  s.radius[i] = (x0 <= x1 && y0 <= y1) ? r : 0;
  s.rect_x0[i] = x0; s.rect_x1[i] = x1; s.rect_y0[i] = y0; s.rect_y1[i] = y1;
}

template <class S>
ProjectedSplats<S> random_splats(std::size_t n, int width, int height, std::uint32_t seed,
                                 const RandomSplatOptions& o = {}) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(0, 1);
  ProjectedSplats<S> s;
  s.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    s.mean_x[i] = S(-o.margin + u(rng) * (width + 2 * o.margin));
    s.mean_y[i] = S(-o.margin + u(rng) * (height + 2 * o.margin));
    const double s1 = o.sigma_min + u(rng) * (o.sigma_max - o.sigma_min);
    const double s2 = o.sigma_min + u(rng) * (o.sigma_max - o.sigma_min);
    const double th = u(rng) * 3.141592653589793;
    const double ct = std::cos(th), st = std::sin(th);
    // conic = R diag(1/s1^2, 1/s2^2) R^T
    const double i1 = 1 / (s1 * s1), i2 = 1 / (s2 * s2);
    s.conic_a[i] = S(ct * ct * i1 + st * st * i2);
    s.conic_b[i] = S(ct * st * (i1 - i2));
    s.conic_c[i] = S(st * st * i1 + ct * ct * i2);
    s.opacity[i] = S(o.opacity_min + u(rng) * (o.opacity_max - o.opacity_min));
    s.color_r[i] = S(u(rng)); s.color_g[i] = S(u(rng)); s.color_b[i] = S(u(rng));
    s.depth[i] = S(o.depth_min + u(rng) * (o.depth_max - o.depth_min));
    set_rect_from_conic(s, i, width, height);
  }
  return s;
}

// Nudges the opacity of Gaussians that sit near a threshold until none does.
template <class S>
void clear_thresholds(ProjectedSplats<S>& s, int width, int height, double rel = 1e-3) {
  for (int iter = 0; iter < 50; ++iter) {
    const auto bad = threshold_violators(s, width, height, rel);
    if (bad.empty()) return;
    for (std::size_t i : bad) s.opacity[i] = S(double(s.opacity[i]) * 0.93);
  }
}

template <class T>
double max_abs_diff(const Image<T>& a, const Image<T>& b) {
  double m = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) m = std::max(m, std::abs(double(a.data[i]) - double(b.data[i])));
  return m;
}

// ---------------------------------------------------------------------------
// Reference projection and SH colour, written from the formulas of
// docs/conventions.md in double precision; it shares no code with
// splat/project*.hpp or splat/sh.hpp, so a bug there cannot cancel out.

// Real SH basis, degree <= 3, at the unit direction d, with the normalisation
// constants derived from their closed forms and the sign pattern of 3DGS.
inline void reference_sh_basis(int degree, const Eigen::Vector3d& d, double b[16]) {
  const double pi = 3.14159265358979323846;
  const double x = d.x(), y = d.y(), z = d.z();
  b[0] = 0.5 * std::sqrt(1 / pi);
  if (degree < 1) return;
  const double c1 = 0.5 * std::sqrt(3 / pi);
  b[1] = -c1 * y;
  b[2] = c1 * z;
  b[3] = -c1 * x;
  if (degree < 2) return;
  const double c2a = 0.5 * std::sqrt(15 / pi), c2b = 0.25 * std::sqrt(5 / pi), c2c = 0.25 * std::sqrt(15 / pi);
  b[4] = c2a * x * y;
  b[5] = -c2a * y * z;
  b[6] = c2b * (3 * z * z - 1);  // = 2 z^2 - x^2 - y^2 on the unit sphere
  b[7] = -c2a * x * z;
  b[8] = c2c * (x * x - y * y);
  if (degree < 3) return;
  const double c30 = 0.25 * std::sqrt(35 / (2 * pi)), c31 = 0.5 * std::sqrt(105 / pi),
               c32 = 0.25 * std::sqrt(21 / (2 * pi)), c33 = 0.25 * std::sqrt(7 / pi),
               c35 = 0.25 * std::sqrt(105 / pi);
  b[9] = -c30 * y * (3 * x * x - y * y);
  b[10] = c31 * x * y * z;
  b[11] = -c32 * y * (5 * z * z - 1);  // 4 z^2 - x^2 - y^2
  b[12] = c33 * z * (5 * z * z - 3);   // 2 z^2 - 3 x^2 - 3 y^2
  b[13] = -c32 * x * (5 * z * z - 1);
  b[14] = c35 * z * (x * x - y * y);
  b[15] = -c30 * x * (x * x - 3 * y * y);
}

// The projected scene in double, plus each Gaussian's unrounded 3 sqrt(lambda_max).
struct ReferenceProjection {
  ProjectedSplats<double> splats;
  std::vector<double> radius_exact;
};

template <class Scene>
ReferenceProjection reference_project(const Scene& scene, const orbitforge::Camera<typename Scene::scalar_type>& cam) {
  using S = typename Scene::scalar_type;
  const Eigen::Matrix3d W = cam.R.template cast<double>();
  const Eigen::Vector3d tc = cam.t.template cast<double>();
  const Eigen::Vector3d centre = -W.transpose() * tc;
  const auto& k = cam.intrinsics;
  const double fx = double(k.fx), fy = double(k.fy), cx = double(k.cx), cy = double(k.cy);
  const double lim_x = 1.3 * 0.5 * k.width / fx, lim_y = 1.3 * 0.5 * k.height / fy;
  const int degree = scene.sh_degree(), n_coef = (degree + 1) * (degree + 1);
  ReferenceProjection ref;
  ProjectedSplats<double>& s = ref.splats;
  s.resize(scene.size());
  ref.radius_exact.assign(scene.size(), 0.0);
  for (std::size_t i = 0; i < scene.size(); ++i) {
    s.radius[i] = 0;
    S m[3], q[4], sc[3];
    scene.mean(i, m);
    scene.rotation(i, q);
    scene.scale(i, sc);
    const double logit = double(scene.opacity_logit(i));
    std::vector<double> sh(std::size_t(3 * n_coef));
    for (int c = 0; c < n_coef; ++c)
      for (int ch = 0; ch < 3; ++ch) sh[std::size_t(3 * c + ch)] = double(scene.sh(i, c, ch));
    const Eigen::Vector3d mean(m[0], m[1], m[2]);
    Eigen::Vector3d scale(sc[0], sc[1], sc[2]);
    if (Scene::scale_mode == orbitforge::ScaleMode::log) scale = scale.array().exp();
    const Eigen::Vector4d quat(q[0], q[1], q[2], q[3]);
    bool finite = mean.allFinite() && scale.allFinite() && quat.allFinite() && std::isfinite(logit);
    for (double v : sh) finite = finite && std::isfinite(v);
    if (!finite || quat.norm() == 0) continue;

    const Eigen::Vector3d t = W * mean + tc;
    if (!(t.z() > 0.01)) continue;  // near plane
    const Eigen::Matrix3d Rq = Eigen::Quaterniond(q[0], q[1], q[2], q[3]).normalized().toRotationMatrix();
    const Eigen::Matrix3d Sigma = Rq * scale.array().square().matrix().asDiagonal() * Rq.transpose();
    const double txc = std::max(-lim_x, std::min(lim_x, t.x() / t.z())) * t.z();
    const double tyc = std::max(-lim_y, std::min(lim_y, t.y() / t.z())) * t.z();
    Eigen::Matrix<double, 2, 3> J;
    J << fx / t.z(), 0, -fx * txc / (t.z() * t.z()), 0, fy / t.z(), -fy * tyc / (t.z() * t.z());
    const Eigen::Matrix2d cov = J * W * Sigma * W.transpose() * J.transpose() + 0.3 * Eigen::Matrix2d::Identity();
    const double det = cov.determinant();
    if (!(det > 0) || !cov.allFinite()) continue;
    const Eigen::Matrix2d conic = cov.inverse();
    const double opacity = 1 / (1 + std::exp(-logit));
    if (opacity < 1.0 / 255) continue;  // never blended (alpha <= opacity)

    const double u = fx * t.x() / t.z() + cx, v = fy * t.y() / t.z() + cy;
    const double lambda_max = Eigen::SelfAdjointEigenSolver<Eigen::Matrix2d>(cov).eigenvalues().maxCoeff();
    const double r3 = 3 * std::sqrt(lambda_max);
    const int r = int(std::ceil(r3));
    // Pixels x whose centre x + 0.5 lies within r of u, clipped to the image.
    const int x0 = std::max(0, int(std::ceil(u - r - 0.5))), x1 = std::min(k.width - 1, int(std::floor(u + r - 0.5)));
    const int y0 = std::max(0, int(std::ceil(v - r - 0.5))), y1 = std::min(k.height - 1, int(std::floor(v + r - 0.5)));
    if (x0 > x1 || y0 > y1) continue;

    double b[16];
    reference_sh_basis(degree, (mean - centre).normalized(), b);
    double rgb[3];
    for (int ch = 0; ch < 3; ++ch) {
      double sum = 0.5;
      for (int c = 0; c < n_coef; ++c) sum += b[c] * sh[std::size_t(3 * c + ch)];
      rgb[ch] = std::max(0.0, sum);
    }
    s.mean_x[i] = u;
    s.mean_y[i] = v;
    s.conic_a[i] = conic(0, 0);
    s.conic_b[i] = conic(0, 1);
    s.conic_c[i] = conic(1, 1);
    s.opacity[i] = opacity;
    s.color_r[i] = rgb[0];
    s.color_g[i] = rgb[1];
    s.color_b[i] = rgb[2];
    s.depth[i] = t.z();
    s.radius[i] = r;
    s.rect_x0[i] = x0; s.rect_x1[i] = x1; s.rect_y0[i] = y0; s.rect_y1[i] = y1;
    ref.radius_exact[i] = r3;
  }
  return ref;
}

// Pixels whose value may legitimately differ between a float renderer and the
// double reference: some Gaussian there is within relative margin `rel` of a
// blending threshold, its pixel centre lies within `edge` pixels of its rect
// border or its 3 sqrt(lambda) within `rel` of an integer (the rect may be one
// pixel larger or smaller), or two Gaussians there have depths within `depth_rel`.
inline std::vector<bool> reference_fragile_pixels(const ReferenceProjection& ref, int width, int height,
                                                  double rel, double edge, double depth_rel) {
  const ProjectedSplats<double>& s = ref.splats;
  std::vector<bool> fragile(std::size_t(width) * std::size_t(height), false);
  const std::vector<std::size_t> order = reference_depth_order(s);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x) {
      bool f = false;
      double T = 1, prev_depth = -1;
      const double px = x + 0.5, py = y + 0.5;
      for (std::size_t i : order) {
        const double r = s.radius[i], ex = std::abs(px - s.mean_x[i]), ey = std::abs(py - s.mean_y[i]);
        const double r3 = ref.radius_exact[i];
        const bool radius_unsure = std::abs(r3 - std::round(r3)) < rel * std::max(1.0, r3);
        if ((std::abs(ex - r) < edge && ey < r + edge) || (std::abs(ey - r) < edge && ex < r + edge)) f = true;
        if (radius_unsure && ex <= r + 1 && ey <= r + 1 && (ex > r - 1 || ey > r - 1)) f = true;
        if (!reference_in_rect(s, i, x, y)) continue;
        if (std::abs(s.depth[i] - prev_depth) < depth_rel * s.depth[i]) f = true;
        prev_depth = s.depth[i];
        const double power = reference_power(s, i, px, py);
        if (power > 0) continue;
        const double raw = s.opacity[i] * std::exp(power);
        if (std::abs(raw - 0.99) < rel * 0.99) f = true;
        const double alpha = std::min(0.99, raw);
        if (std::abs(alpha - 1.0 / 255) < rel / 255) f = true;
        if (alpha < 1.0 / 255) continue;
        const double T_next = T * (1 - alpha);
        if (std::abs(T_next - 1e-4) < rel * 1e-4) f = true;
        if (T_next < 1e-4) break;
        T = T_next;
      }
      fragile[std::size_t(y) * std::size_t(width) + std::size_t(x)] = f;
    }
  return fragile;
}

// Largest difference of a library image from the double reference that
// rounding allows: float carries ~1e-7 relative error through u (up to ~1e3 px:
// measured 6e-6 there, 7e-7 on small images), the conic and tens of blended
// layers; double only round-off (measured 1.4e-14).
template <class S> constexpr double reference_tol() { return sizeof(S) == 4 ? 2e-5 : 1e-12; }

struct ReferenceComparison {
  double worst_color = 0, worst_T = 0;  // over the pixels that are not fragile
  std::size_t count_mismatch = 0, fragile = 0, pixels = 0;
};

// A rendered image (color, transmittance, count) against reference_project +
// reference_rasterize, skipping the pixels reference_fragile_pixels flags with
// margins a few times the rounding of S: on alpha and lambda, on u (which grows
// with the image size) and on depth.
template <class Output, class Scene>
ReferenceComparison compare_with_reference(const Output& out, const Scene& scene,
                                           const orbitforge::Camera<typename Scene::scalar_type>& cam,
                                           std::array<typename Scene::scalar_type, 3> bg) {
  const ReferenceProjection proj = reference_project(scene, cam);
  const int w = cam.intrinsics.width, h = cam.intrinsics.height;
  const auto ref =
      reference_rasterize(proj.splats, w, h, std::array<double, 3>{{double(bg[0]), double(bg[1]), double(bg[2])}});
  const bool f32 = sizeof(typename Scene::scalar_type) == 4;
  const double rel = f32 ? 2e-5 : 1e-10, edge = f32 ? 1e-6 * std::max(w, h) + 2e-5 : 1e-9;
  const std::vector<bool> fragile = reference_fragile_pixels(proj, w, h, rel, edge, f32 ? 1.5e-6 : 1e-12);
  ReferenceComparison c;
  c.pixels = std::size_t(w) * std::size_t(h);
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      if (fragile[std::size_t(y) * std::size_t(w) + std::size_t(x)]) { ++c.fragile; continue; }
      for (int ch = 0; ch < 3; ++ch)
        c.worst_color = std::max(c.worst_color, std::abs(double(out.color(x, y, ch)) - ref.color(x, y, ch)));
      c.worst_T = std::max(c.worst_T, std::abs(double(out.transmittance(x, y)) - ref.transmittance(x, y)));
      if (out.count(x, y) != ref.count(x, y)) ++c.count_mismatch;
    }
  return c;
}

// Full reference from a scene (any adaptor, any precision): the projection above,
// then the per-pixel reference, all in double.
template <class Scene>
ReferenceImages<double> reference_render(const Scene& scene,
                                         const orbitforge::Camera<typename Scene::scalar_type>& camera,
                                         std::array<typename Scene::scalar_type, 3> background) {
  const ReferenceProjection p = reference_project(scene, camera);
  return reference_rasterize(p.splats, camera.intrinsics.width, camera.intrinsics.height,
                             std::array<double, 3>{{double(background[0]), double(background[1]), double(background[2])}});
}

}  // namespace orbitforge_test

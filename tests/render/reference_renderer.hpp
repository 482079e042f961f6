#pragma once
// A plain, obviously correct reference for the per-pixel stages: for every pixel,
// walk ALL Gaussians sorted by (depth, index) and blend with the rules of
// docs/conventions.md. No tiles, no SIMD, no threads, no early culling beyond the
// rect test. Plus helpers that build random ProjectedSplats for tests.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <set>
#include <vector>

#include "orbitforge/core/image.hpp"
#include "orbitforge/splat/project.hpp"
#include "orbitforge/splat/projected.hpp"

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

// Full reference from a scene: the project helper's per-Gaussian projection
// (single thread), then the per-pixel reference above.
template <class Scene>
ReferenceImages<typename Scene::scalar_type> reference_render(
    const Scene& scene, const orbitforge::Camera<typename Scene::scalar_type>& camera,
    std::array<typename Scene::scalar_type, 3> background, const orbitforge::ProjectionParams& pp = {}) {
  ProjectedSplats<typename Scene::scalar_type> s;
  orbitforge::project_scene(scene, camera, pp, s, nullptr, 1);
  return reference_rasterize(s, camera.intrinsics.width, camera.intrinsics.height, background);
}

}  // namespace orbitforge_test

#pragma once
// Initial Gaussian scenes for training (3DGS, section 5.1):
//   - from a sparse point cloud (COLMAP points3D): one Gaussian per point, colour
//     from the point's RGB (SH DC), isotropic scale = sqrt(mean squared distance to
//     the 3 nearest other points) (3DGS's distCUDA2), identity rotation, opacity 0.1;
//   - without points: a random cloud inside the cameras' view volume (random pixel
//     of a random camera, random depth), random colours.
// Both are deterministic for a fixed seed.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <random>
#include <unordered_map>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/train/camera_extent.hpp"

namespace orbitforge {

struct InitParams {
  double opacity = 0.1;             // initial opacity of every Gaussian (3DGS: 0.1)
  double min_scale = 1e-7;          // floor of the nearest-neighbour scale (3DGS clamps dist2 at 1e-7)
  std::size_t random_points = 100000;  // random cloud size when there are no points
  double depth_min = 0.2, depth_max = 1.6;  // random depths, as multiples of the view distance
  unsigned seed = 0;
};

// Mean squared distance of each point to its (up to) 3 nearest other points.
// points: [N][3]. Uniform grid with cells of ~2 points each, rings searched
// outwards until the 3rd best distance is inside the searched radius: exact.
template <class Scalar>
std::vector<Scalar> mean_sq_distance_3nn(const std::vector<Scalar>& points) {
  ensure(points.size() % 3 == 0, "mean_sq_distance_3nn: ", points.size(), " values is not a whole number of points");
  const std::size_t n = points.size() / 3;
  std::vector<Scalar> out(n, Scalar(0));
  if (n < 2) return out;
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) lo[a] = hi[a] = double(points[a]);
  for (std::size_t i = 0; i < n; ++i)
    for (int a = 0; a < 3; ++a) {
      const double v = double(points[3 * i + a]);
      ensure(std::isfinite(v), "mean_sq_distance_3nn: point ", i, " is not finite");
      lo[a] = std::min(lo[a], v);
      hi[a] = std::max(hi[a], v);
    }
  double volume = 1;
  double max_side = 0;
  for (int a = 0; a < 3; ++a) max_side = std::max(max_side, hi[a] - lo[a]);
  if (max_side <= 0) return out;  // all points coincide
  for (int a = 0; a < 3; ++a) volume *= std::max(hi[a] - lo[a], max_side * 1e-3);
  const double cell = std::max(std::cbrt(volume * 2.0 / double(n)), max_side * 1e-6);
  auto coord = [&](double v, int a) { return std::int64_t(std::floor((v - lo[a]) / cell)); };
  auto key = [](std::int64_t x, std::int64_t y, std::int64_t z) {
    return (std::uint64_t(x) * 73856093ull) ^ (std::uint64_t(y) * 19349663ull) ^ (std::uint64_t(z) * 83492791ull);
  };
  std::unordered_map<std::uint64_t, std::vector<std::uint32_t>> grid;
  grid.reserve(n);
  std::vector<std::array<std::int64_t, 3>> cells(n);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) cells[i][a] = coord(double(points[3 * i + a]), a);
    grid[key(cells[i][0], cells[i][1], cells[i][2])].push_back(std::uint32_t(i));
  }
  std::int64_t max_ring = 0;
  for (int a = 0; a < 3; ++a) max_ring = std::max(max_ring, coord(hi[a], a) + 1);
  const int want = int(std::min<std::size_t>(3, n - 1));
  for (std::size_t i = 0; i < n; ++i) {
    double best[3] = {INFINITY, INFINITY, INFINITY};
    for (std::int64_t r = 0; r <= max_ring; ++r) {
      // Shell of cells at Chebyshev distance r.
      for (std::int64_t dx = -r; dx <= r; ++dx)
        for (std::int64_t dy = -r; dy <= r; ++dy)
          for (std::int64_t dz = -r; dz <= r; ++dz) {
            if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != r) continue;
            const auto it = grid.find(key(cells[i][0] + dx, cells[i][1] + dy, cells[i][2] + dz));
            if (it == grid.end()) continue;
            for (std::uint32_t j : it->second) {
              if (j == i) continue;
              // Hash collisions may put far points in a bucket: harmless (distances are exact).
              double d2 = 0;
              for (int a = 0; a < 3; ++a) {
                const double d = double(points[3 * i + a]) - double(points[3 * std::size_t(j) + a]);
                d2 += d * d;
              }
              if (d2 < best[2]) {
                best[2] = d2;
                if (best[2] < best[1]) std::swap(best[1], best[2]);
                if (best[1] < best[0]) std::swap(best[0], best[1]);
              }
            }
          }
      // Every point outside the searched shells is farther than r * cell.
      const double reach = double(r) * cell;
      if (best[want - 1] <= reach * reach) break;
    }
    double s = 0;
    for (int k = 0; k < want; ++k) s += best[k];
    out[i] = Scalar(s / double(want));
  }
  return out;
}

// points [N][3], colors [N][3] in [0, 1]. Returns a degree-0 scene.
template <class Scalar>
GaussianScene<Scalar> init_from_points(const std::vector<Scalar>& points, const std::vector<Scalar>& colors,
                                       const InitParams& p = {}) {
  ensure(points.size() % 3 == 0 && colors.size() == points.size(), "init_from_points: ", points.size() / 3,
         " points and ", colors.size() / 3, " colours (need one RGB colour per point)");
  ensure(!points.empty(), "init_from_points: no points");
  ensure(p.opacity > 0 && p.opacity < 1, "init_from_points: opacity must be in (0, 1), got ", p.opacity);
  const std::size_t n = points.size() / 3;
  const std::vector<Scalar> d2 = mean_sq_distance_3nn(points);
  GaussianScene<Scalar> s;
  s.resize(n, 0);
  s.means = points;
  const Scalar lo = logit(Scalar(p.opacity));
  for (std::size_t i = 0; i < n; ++i) {
    const Scalar ls = Scalar(0.5) * std::log(std::max(d2[i], Scalar(p.min_scale)));
    for (int a = 0; a < 3; ++a) {
      s.log_scales[3 * i + a] = ls;
      s.sh[3 * i + a] = rgb_to_sh_dc(colors[3 * i + a]);
    }
    s.opacity_logits[i] = lo;
  }
  return s;
}

// A random cloud in the cameras' view volume: a random camera, a random pixel, a
// depth uniform in [depth_min, depth_max] times that camera's distance to the
// centroid of all camera centres (or, for cameras bunched together, their extent
// scale `fallback_distance`); colours uniform; scales from nearest neighbours.
// The largest random cloud init_random makes: 10 million Gaussians are a few
// GiB with degree-3 SH, far beyond what a scene starts from.
constexpr std::size_t kMaxRandomPoints = 10000000;

template <class Scalar>
GaussianScene<Scalar> init_random(const std::vector<Camera<Scalar>>& cameras, Scalar fallback_distance,
                                  const InitParams& p = {}) {
  ensure(!cameras.empty(), "init_random: no cameras");
  ensure(p.random_points > 0 && p.random_points <= kMaxRandomPoints, "init_random: random_points must lie in [1, ",
         kMaxRandomPoints, "], not ", p.random_points);
  ensure(p.depth_min > 0 && p.depth_max > p.depth_min, "init_random: need 0 < depth_min < depth_max");
  typename Camera<Scalar>::Vec3 centroid = Camera<Scalar>::Vec3::Zero();
  for (const auto& c : cameras) centroid += c.center();
  centroid /= Scalar(cameras.size());
  std::mt19937 rng(p.seed);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  std::vector<Scalar> pts(3 * p.random_points), cols(3 * p.random_points);
  for (std::size_t i = 0; i < p.random_points; ++i) {
    const auto& c = cameras[std::min(cameras.size() - 1, std::size_t(u(rng) * double(cameras.size())))];
    const auto& k = c.intrinsics;
    ensure(k.width > 0 && k.height > 0 && k.fx > 0 && k.fy > 0, "init_random: camera without a valid image size");
    const double px = u(rng) * k.width, py = u(rng) * k.height;
    double dist = double((c.center() - centroid).norm());
    if (!(dist > 1e-6 * double(fallback_distance))) dist = double(fallback_distance);
    const double z = dist * (p.depth_min + (p.depth_max - p.depth_min) * u(rng));
    const typename Camera<Scalar>::Vec3 xc(Scalar((px - double(k.cx)) / double(k.fx) * z),
                                           Scalar((py - double(k.cy)) / double(k.fy) * z), Scalar(z));
    const typename Camera<Scalar>::Vec3 xw = c.R.transpose() * (xc - c.t);
    for (int a = 0; a < 3; ++a) {
      pts[3 * i + a] = xw[a];
      cols[3 * i + a] = Scalar(u(rng));
    }
  }
  return init_from_points(pts, cols, p);
}

// init_random at the cameras' own scale: the distance for bunched cameras is
// their extent (camera_extent_or_one), the scene scale the trainer uses.
template <class Scalar>
GaussianScene<Scalar> init_random(const std::vector<Camera<Scalar>>& cameras, const InitParams& p = {}) {
  ensure(!cameras.empty(), "init_random: no cameras");
  return init_random(cameras, camera_extent_or_one(cameras), p);
}

}  // namespace orbitforge

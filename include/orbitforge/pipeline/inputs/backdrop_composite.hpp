#pragma once
// A real object on a textured, uneven backdrop: photographs of an object on
// black (the Middlebury rings) composited over a wall of Gaussians rendered at
// each photograph's own camera. The wall is one 3D surface that every view
// agrees on, so the composite is a consistent scene whose borders disagree, as
// a handheld capture's do: the case where a constant background colour fails.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <random>
#include <vector>

#include <Eigen/Dense>

#include "orbitforge/core/error.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"

namespace orbitforge {

struct BackdropCompositeParams {
  double wall_radius = 2.0;      // the wall's cylinder, in units of the cameras' ring radius
  double wall_half_height = 2.5;  // above and below the ring's centre, same unit
  int wall_gaussians = 40000;     // placed where some camera sees the wall
  // Foreground: a pixel's largest channel above black_level + black_ramp is the
  // object; below black_level it is the photograph's black backdrop.
  double black_level = 0.04, black_ramp = 0.06;
  std::uint64_t seed = 1;
  int threads = 0;
};

namespace backdrop_detail {

// Colour of the wall at (azimuth, height): patches of a palette, stripes and a
// slow brightness falloff, so that no constant colour explains it.
template <class Scalar>
Eigen::Matrix<Scalar, 3, 1> wall_color(double az, double h, std::uint64_t seed) {
  const int cell_a = int(std::floor(az * 24 / (2 * 3.14159265358979))), cell_h = int(std::floor(h * 3));
  std::uint64_t k = std::uint64_t(cell_a + 1000) * 73856093u ^ std::uint64_t(cell_h + 1000) * 19349663u ^ seed;
  k ^= k >> 13;
  k *= 0x5bd1e995u;
  k ^= k >> 15;
  static const double palette[6][3] = {{0.78, 0.42, 0.25}, {0.30, 0.55, 0.35}, {0.85, 0.80, 0.55},
                                       {0.25, 0.35, 0.65}, {0.60, 0.30, 0.50}, {0.55, 0.55, 0.55}};
  const double* c = palette[k % 6];
  const double stripe = 0.75 + 0.25 * std::cos(az * 96 + h * 11);
  const double light = 0.55 + 0.45 * (0.5 + 0.5 * std::cos(az - 0.7)) * std::exp(-0.15 * h * h);
  Eigen::Matrix<Scalar, 3, 1> rgb;
  for (int i = 0; i < 3; ++i) rgb[i] = Scalar(std::min(1.0, c[i] * stripe * light));
  return rgb;
}

}  // namespace backdrop_detail

// The wall for the input's registered cameras: a cylinder about the axis of
// their ring (the normal of the plane through their centres), Gaussians only
// where at least one camera sees it.
template <class Scalar>
GaussianScene<Scalar> backdrop_wall(const PipelineInput<Scalar>& in, const BackdropCompositeParams& p) {
  std::vector<Eigen::Vector3d> centres;
  std::vector<Camera<double>> cams;
  for (const auto& fc : in.cameras)
    if (fc.valid) {
      cams.push_back(fc.camera.template cast<double>());
      centres.push_back(cams.back().center());
    }
  ensure(cams.size() >= 3, "backdrop_wall: needs at least 3 cameras, the input has ", cams.size());
  Eigen::Vector3d mean = Eigen::Vector3d::Zero();
  for (const auto& c : centres) mean += c;
  mean /= double(centres.size());
  Eigen::Matrix3d scatter = Eigen::Matrix3d::Zero();
  double ring = 0;
  for (const auto& c : centres) {
    scatter += (c - mean) * (c - mean).transpose();
    ring += (c - mean).norm();
  }
  ring /= double(centres.size());
  ensure(ring > 0, "backdrop_wall: the cameras share one centre");
  const Eigen::Vector3d axis = Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d>(scatter).eigenvectors().col(0);
  const Eigen::Vector3d e1 = axis.unitOrthogonal(), e2 = axis.cross(e1);
  const double R = p.wall_radius * ring, H = p.wall_half_height * ring, pi = 3.14159265358979;

  // Candidates uniform on the cylinder; keep those some camera sees in front of it.
  std::mt19937_64 rng(p.seed);
  std::uniform_real_distribution<double> uni(0, 1);
  const auto seen = [&](const Eigen::Vector3d& x) {
    for (const auto& c : cams) {
      const Eigen::Vector3d xc = c.to_camera(x);
      if (xc.z() <= 0) continue;
      const double u = c.intrinsics.fx * xc.x() / xc.z() + c.intrinsics.cx,
                   v = c.intrinsics.fy * xc.y() / xc.z() + c.intrinsics.cy;
      const double mu = 0.05 * c.intrinsics.width, mv = 0.05 * c.intrinsics.height;
      if (u > -mu && u < c.intrinsics.width + mu && v > -mv && v < c.intrinsics.height + mv) return true;
    }
    return false;
  };
  std::vector<std::array<double, 2>> kept;
  long tried = 0;
  const long max_tries = 400L * std::max(1, p.wall_gaussians);
  while (int(kept.size()) < p.wall_gaussians && tried < max_tries) {
    ++tried;
    const double az = uni(rng) * 2 * pi, h = (uni(rng) * 2 - 1) * H;
    if (seen(mean + R * (std::cos(az) * e1 + std::sin(az) * e2) + h * axis)) kept.push_back({az, h});
  }
  ensure(!kept.empty(), "backdrop_wall: no camera sees the wall");
  // Gaussians about as wide as their spacing on the part of the wall that is seen.
  const double seen_area = 2 * pi * R * 2 * H * double(kept.size()) / double(tried);
  const double size = std::sqrt(seen_area / double(kept.size()));
  GaussianScene<Scalar> s;
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  for (const auto& [az, h] : kept) {
    const Eigen::Vector3d radial = std::cos(az) * e1 + std::sin(az) * e2;
    const Eigen::Vector3d x = mean + R * radial + h * axis;
    const Eigen::Quaterniond q = Eigen::Quaterniond::FromTwoVectors(Eigen::Vector3d::UnitZ(), radial);
    synthetic_detail::push_gaussian(s, Vec3(x.cast<Scalar>()), q.cast<Scalar>(),
                                    Vec3(Scalar(size), Scalar(size), Scalar(size * 0.1)), Scalar(0.98),
                                    backdrop_detail::wall_color<Scalar>(az, h / ring, p.seed));
  }
  return s;
}

// Every registered frame's image becomes its photograph over the wall rendered
// at its camera (the foreground is what is not the photograph's black).
template <class Scalar>
void composite_on_backdrop(PipelineInput<Scalar>& in, const BackdropCompositeParams& p) {
  ensure(p.black_ramp > 0, "composite_on_backdrop: black_ramp must be positive");
  const GaussianScene<Scalar> wall = backdrop_wall(in, p);
  RenderParams<Scalar> rp;
  rp.threads = p.threads;
  rp.background = {Scalar(0.5), Scalar(0.5), Scalar(0.5)};  // where the wall leaves a hole
  Renderer<Scalar> r(rp);
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    if (!in.cameras[i].valid) continue;
    Image<Scalar>& img = in.images[i];
    const Image<Scalar> back = r.render(SceneView<Scalar>(wall), in.cameras[i].camera).color;
    ensure(back.width == img.width && back.height == img.height, "composite_on_backdrop: frame ", i,
           " is not at its camera's size");
    for (int y = 0; y < img.height; ++y)
      for (int x = 0; x < img.width; ++x) {
        Scalar m = 0;
        for (int c = 0; c < 3; ++c) m = std::max(m, img(x, y, c));
        const Scalar a = std::clamp((m - Scalar(p.black_level)) / Scalar(p.black_ramp), Scalar(0), Scalar(1));
        for (int c = 0; c < 3; ++c)
          img(x, y, c) = a * img(x, y, c) + (1 - a) * std::clamp(back(x, y, c), Scalar(0), Scalar(1));
      }
  }
  in.description += ", composited on a textured wall (seed " + std::to_string(p.seed) + ")";
}

}  // namespace orbitforge

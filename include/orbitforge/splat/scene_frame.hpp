#pragma once
// The normalised frame a reconstruction works in: a similarity (no rotation)
//
//   x_normalised = scale * (x_user - origin)
//
// fitted to the cameras as 3DGS normalises a scene (getNerfppNorm): origin = the
// mean camera centre, scale = 1 / (1.1 * the largest distance of a camera centre
// from it), so that every camera lies within the unit ball.
//
// Why: parameters are stored and optimised in Scalar (float by default). A scene
// 1e5 units from the origin has float means with a resolution of ~0.008 units and
// camera-space positions R x + t that cancel 1e5-sized terms; a scene 1e-3 units
// big sits inside the absolute tolerances. Fitted and applied in double at load
// (cameras and points), and undone on every output, the float maths sees the same
// numbers wherever and however big the user's scene is.
//
// A similarity without rotation leaves view directions (SH colour) and Gaussian
// rotations unchanged; scales scale, so log-scales shift by log(scale).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <vector>

#include <Eigen/Geometry>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

struct SceneFrame {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();
  double scale = 1;

  bool is_identity() const { return scale == 1 && origin.isZero(0); }
  // Whether the model's origin lies more than 100 scene sizes (the normalised unit)
  // away: float32 positions in the model's frame then resolve less than about
  // 1e-5 of the scene, so files in that frame need float64 positions.
  bool far_from_origin() const { return origin.norm() * scale > 100; }

  Eigen::Vector3d to_normalised(const Eigen::Vector3d& x) const { return scale * (x - origin); }
  Eigen::Vector3d to_user(const Eigen::Vector3d& x) const { return x / scale + origin; }

  // Same rotation, centre moved: t = -R C, so t_n = scale (t + R origin).
  template <class S>
  Camera<S> to_normalised(const Camera<S>& c) const {
    Camera<S> o = c;
    const Eigen::Vector3d t = c.t.template cast<double>(), Ro = c.R.template cast<double>() * origin;
    o.t = (scale * (t + Ro)).template cast<S>();
    return o;
  }
  template <class S>
  Camera<S> to_user(const Camera<S>& c) const {
    Camera<S> o = c;
    const Eigen::Vector3d t = c.t.template cast<double>(), Ro = c.R.template cast<double>() * origin;
    o.t = (t / scale - Ro).template cast<S>();
    return o;
  }

  // A camera in the model's frame for writing to a file, in double. Unless the
  // frame is the identity, the rotation is made orthonormal in double first:
  // far from the origin a reader's centre -R^T t cancels R^T R origin, which a
  // float rotation leaves wrong by about 1e-7 of the distance.
  template <class S>
  Camera<double> to_user_for_file(const Camera<S>& c) const {
    Camera<double> d = c.template cast<double>();
    if (is_identity()) return d;
    d.R = Eigen::Quaterniond(d.R).normalized().toRotationMatrix();
    return to_user(d);
  }

  // Points [N][3] in place (double arithmetic whatever S is).
  template <class S>
  void points_to_normalised(std::vector<S>& xyz) const {
    for (std::size_t i = 0; i + 2 < xyz.size(); i += 3) set3(xyz, i, to_normalised(get3(xyz, i)));
  }

  template <class S>
  GaussianScene<S> to_normalised(GaussianScene<S> g) const {
    points_to_normalised(g.means);
    for (auto& v : g.log_scales) v = S(double(v) + std::log(scale));
    return g;
  }
  template <class S>
  GaussianScene<S> to_user(GaussianScene<S> g) const {
    for (std::size_t i = 0; i + 2 < g.means.size(); i += 3) set3(g.means, i, to_user(get3(g.means, i)));
    for (auto& v : g.log_scales) v = S(double(v) - std::log(scale));
    return g;
  }

 private:
  template <class S>
  static Eigen::Vector3d get3(const std::vector<S>& v, std::size_t i) {
    return {double(v[i]), double(v[i + 1]), double(v[i + 2])};
  }
  template <class S>
  static void set3(std::vector<S>& v, std::size_t i, const Eigen::Vector3d& x) {
    for (int a = 0; a < 3; ++a) v[i + std::size_t(a)] = S(x[a]);
  }
};

// The frame of a set of camera centres (double, so that far-off recorded models
// lose nothing): mean centre, unit ball 1.1 times the largest distance from it.
// Cameras all at one place (or one camera) leave the scale to `points` [N][3]:
// their RMS distance from their centroid; with neither, scale 1.
inline SceneFrame fit_scene_frame(const std::vector<Eigen::Vector3d>& centres, const std::vector<double>& points = {}) {
  SceneFrame f;
  if (centres.empty() && points.size() < 3) return f;
  double r = 0;
  if (!centres.empty()) {
    for (const auto& c : centres) f.origin += c;
    f.origin /= double(centres.size());
    for (const auto& c : centres) r = std::max(r, (c - f.origin).norm());
    r *= 1.1;
  }
  // "All at one place": relative to the coordinates' own size, since a spread of
  // 1e-9 is real for a 1e-6-sized model and rounding for one 1e6 units away. At
  // 1e-13 (a few hundred double roundings): 1e-9 took the cameras of a 1e-4-sized
  // model 1e6 units out (spread 5e-10 of the coordinates) for one place.
  const double tiny = 1e-13 * std::max(r, f.origin.norm());
  if (!(r > tiny) && points.size() >= 3) {
    const std::size_t n = points.size() / 3;
    Eigen::Vector3d m = Eigen::Vector3d::Zero();
    for (std::size_t i = 0; i < n; ++i) m += Eigen::Vector3d(points[3 * i], points[3 * i + 1], points[3 * i + 2]);
    m /= double(n);
    double ss = 0;
    for (std::size_t i = 0; i < n; ++i)
      ss += (Eigen::Vector3d(points[3 * i], points[3 * i + 1], points[3 * i + 2]) - m).squaredNorm();
    if (centres.empty()) f.origin = m;
    r = std::sqrt(ss / double(n));
  }
  ensure(std::isfinite(r) && f.origin.allFinite(), "fit_scene_frame: non-finite camera centres or points");
  f.scale = r > std::max(tiny, 1e-300) ? 1.0 / r : 1.0;
  return f;
}

}  // namespace orbitforge

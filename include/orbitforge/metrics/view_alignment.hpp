#pragma once
// The turn and zoom of a camera, about its own centre, that best align a
// rendered view with the photograph it is scored against.
//
// Scoring a scene at a camera from another estimate (the user's path: the
// reference model's cameras, aligned by one similarity, with its own focal
// length) adds the two estimates' disagreement to the scene's error: a few
// tenths of a degree, or a focal length 3 % off, move a sharp frame's edges by
// several pixels and cost several dB. Fitting each scored view's camera to its
// image, the scene held fixed, separates the two (test-view pose fitting, as
// evaluations of methods with estimated cameras do). The fit is made in the
// image: a camera turned about its centre, or given another focal length, sees
// a homography of what it saw, so no depth is needed; at the distance of an
// object a small sideways shift of the centre looks almost like a turn, and a
// shift along the axis almost like a zoom.
//
// The camera turned by dR (camera_R_world' = dR camera_R_world) with focal
// lengths times s sees at pixel x what the given camera sees at
// W(x) = pi(K dR^T K_s^-1 x~), K_s = K with fx, fy times s. Gauss-Newton on
//   E(dR, s) = sum_x sum_c rho(render_c(W(x)) - target_c(x)),
// rho Huber (a part of the scene that is wrong does not pull the fit), updates
// dR <- exp(w) dR and log s <- log s + l, coarse to fine over 2x2-box pyramids
// (the intrinsics halved with each level, pixel centres at i + 1/2). Pixels
// whose W(x) leaves the rendered image are not counted.
//
// The fit is kept only when it lowers the error over the pixels both images
// share and stays within max_angle_deg and max_zoom; otherwise the camera is
// left as it was.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"

namespace orbitforge {

struct ViewAlignmentParams {
  int levels = 4;               // pyramid levels (the coarsest one first)
  int iterations = 15;          // Gauss-Newton steps per level at most
  bool fit_zoom = true;         // false: the turn alone
  double max_angle_deg = 5.0;   // a larger turn is not a scoring correction: refused
  double max_zoom = 0.1;        // |s - 1| beyond this is refused too
  double huber = 0.1;           // residual (per channel, [0, 1] values) where rho turns linear
  double min_step_deg = 1e-4;   // a level stops once a step is smaller than this
};

struct ViewAlignment {
  Eigen::Matrix3d camera_R_camera = Eigen::Matrix3d::Identity();  // dR: new camera from the given one
  double zoom = 1;             // s: the new focal lengths over the given ones
  double angle_deg = 0;        // |dR|
  double rms_before = 0;       // over the pixels both images share, full size
  double rms_after = 0;
  bool refined = false;        // false: the identity (no gain, or the fit was refused)
};

// The camera `c` turned by a.camera_R_camera about its centre, its focal lengths times a.zoom.
template <class Scalar>
Camera<Scalar> aligned_camera(const Camera<Scalar>& c, const ViewAlignment& a) {
  Camera<Scalar> out = c;
  const auto centre = c.center();
  out.R = (a.camera_R_camera * c.R.template cast<double>()).template cast<Scalar>();
  out.t = -out.R * centre;
  out.intrinsics.fx = Scalar(double(c.intrinsics.fx) * a.zoom);
  out.intrinsics.fy = Scalar(double(c.intrinsics.fy) * a.zoom);
  return out;
}

namespace view_alignment_detail {

// One pyramid level in double, channel-interleaved as Image.
struct Level {
  int w = 0, h = 0, c = 0;
  std::vector<double> v;
  double at(int x, int y, int k) const { return v[(std::size_t(y) * w + x) * c + k]; }
};

template <class Scalar>
Level to_level(const Image<Scalar>& im) {
  Level l{im.width, im.height, im.channels, {}};
  l.v.assign(im.data.begin(), im.data.end());
  return l;
}

inline Level half(const Level& a) {
  Level b{std::max(1, a.w / 2), std::max(1, a.h / 2), a.c, {}};
  b.v.assign(std::size_t(b.w) * b.h * b.c, 0.0);
  for (int y = 0; y < b.h; ++y)
    for (int x = 0; x < b.w; ++x)
      for (int k = 0; k < a.c; ++k) {
        const int x0 = std::min(2 * x, a.w - 1), x1 = std::min(2 * x + 1, a.w - 1);
        const int y0 = std::min(2 * y, a.h - 1), y1 = std::min(2 * y + 1, a.h - 1);
        b.v[(std::size_t(y) * b.w + x) * b.c + k] =
            0.25 * (a.at(x0, y0, k) + a.at(x1, y0, k) + a.at(x0, y1, k) + a.at(x1, y1, k));
      }
  return b;
}

// Whether (u, v) (continuous pixel coordinates, centres at i + 1/2) lies in the
// interior where a bilinear sample of central differences exists.
inline bool inside(const Level& l, double u, double v) {
  const int x0 = int(std::floor(u - 0.5)), y0 = int(std::floor(v - 0.5));
  return x0 >= 1 && y0 >= 1 && x0 + 2 < l.w && y0 + 2 < l.h;
}

// Bilinear sample of channel k and its x / y derivatives at (u, v), which must be inside().
inline void sample(const Level& l, double u, double v, int k, double& value, double& dx, double& dy) {
  const double fx = u - 0.5, fy = v - 0.5;
  const int x0 = int(std::floor(fx)), y0 = int(std::floor(fy));
  const double ax = fx - x0, ay = fy - y0;
  auto lerp = [&](auto f) {
    return (1 - ay) * ((1 - ax) * f(x0, y0) + ax * f(x0 + 1, y0)) + ay * ((1 - ax) * f(x0, y0 + 1) + ax * f(x0 + 1, y0 + 1));
  };
  value = lerp([&](int x, int y) { return l.at(x, y, k); });
  dx = lerp([&](int x, int y) { return 0.5 * (l.at(x + 1, y, k) - l.at(x - 1, y, k)); });
  dy = lerp([&](int x, int y) { return 0.5 * (l.at(x, y + 1, k) - l.at(x, y - 1, k)); });
}

// exp of a rotation vector.
inline Eigen::Matrix3d exp_so3(const Eigen::Vector3d& w) {
  const double a = w.norm();
  if (a < 1e-12) return Eigen::Matrix3d::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

inline double angle_deg(const Eigen::Matrix3d& r) { return Constants<double>::rad2deg(Eigen::AngleAxisd(r).angle()); }

struct Intr {
  double fx, fy, cx, cy;
};

// The ray of pixel (x, y) of the camera with focal lengths times `zoom`.
inline Eigen::Vector3d ray(const Intr& K, double zoom, int x, int y) {
  return {(x + 0.5 - K.cx) / (zoom * K.fx), (y + 0.5 - K.cy) / (zoom * K.fy), 1.0};
}

// The given camera's pixel of ray q (in its frame); false behind it.
inline bool project(const Intr& K, const Eigen::Vector3d& q, double& u, double& v) {
  if (q.z() <= 0) return false;
  u = K.fx * q.x() / q.z() + K.cx;
  v = K.fy * q.y() / q.z() + K.cy;
  return true;
}

// Where pixel (x, y) of the aligned camera lands in the given one's image.
inline bool warp(const Intr& K, const Eigen::Matrix3d& dR_transposed, double zoom, int x, int y, double& u, double& v) {
  return project(K, dR_transposed * ray(K, zoom, x, y), u, v);
}

// Root mean squares of render(W(x)) - target(x) for the identity and for (dR, zoom),
// over the pixels both warps keep inside the render (no robust weight).
inline std::pair<double, double> rms_pair(const Level& render, const Level& target, const Intr& K,
                                          const Eigen::Matrix3d& dR, double zoom) {
  double sum0 = 0, sum1 = 0;
  std::size_t n = 0;
  const Eigen::Matrix3d I = Eigen::Matrix3d::Identity(), Rt = dR.transpose();
  for (int y = 0; y < target.h; ++y)
    for (int x = 0; x < target.w; ++x) {
      double u0, v0, u1, v1, a, b, gx, gy;
      if (!warp(K, I, 1.0, x, y, u0, v0) || !warp(K, Rt, zoom, x, y, u1, v1)) continue;
      if (!inside(render, u0, v0) || !inside(render, u1, v1)) continue;
      for (int k = 0; k < target.c; ++k) {
        sample(render, u0, v0, k, a, gx, gy);
        sample(render, u1, v1, k, b, gx, gy);
        const double t = target.at(x, y, k);
        sum0 += (a - t) * (a - t);
        sum1 += (b - t) * (b - t);
        ++n;
      }
    }
  if (n == 0) return {0.0, 0.0};
  return {std::sqrt(sum0 / double(n)), std::sqrt(sum1 / double(n))};
}

}  // namespace view_alignment_detail

// Fits dR and s (see the top of this file) so that the aligned camera renders
// `target` as closely as possible, given `render`, the scene seen from the given
// camera with intrinsics `K`. The two images must share their size and channels.
template <class Scalar>
ViewAlignment fit_view_alignment(const Image<Scalar>& render, const Image<Scalar>& target, const Intrinsics<Scalar>& K,
                                 const ViewAlignmentParams& p = {}) {
  namespace d = view_alignment_detail;
  ensure(render.same_shape(target) && !render.empty(), "fit_view_alignment: render ", render.width, "x",
         render.height, "x", render.channels, " and target ", target.width, "x", target.height, "x", target.channels,
         " must be non-empty images of one shape");
  ensure(K.is_finite() && K.fx > 0 && K.fy > 0,
         "fit_view_alignment: intrinsics must be finite with positive focal lengths");
  ensure(p.levels >= 1 && p.iterations >= 0 && p.max_angle_deg > 0 && p.max_zoom > 0 && p.huber > 0,
         "fit_view_alignment: levels >= 1, iterations >= 0, max_angle_deg, max_zoom and huber > 0 are required");
  std::vector<d::Level> rp{d::to_level(render)}, tp{d::to_level(target)};
  for (int l = 1; l < p.levels && std::min(rp.back().w, rp.back().h) >= 32; ++l) {
    rp.push_back(d::half(rp.back()));
    tp.push_back(d::half(tp.back()));
  }
  const d::Intr full{double(K.fx), double(K.fy), double(K.cx), double(K.cy)};
  Eigen::Matrix3d dR = Eigen::Matrix3d::Identity();
  double log_zoom = 0;
  const int params = p.fit_zoom ? 4 : 3;
  for (int l = int(rp.size()) - 1; l >= 0; --l) {
    const double sx = double(rp[std::size_t(l)].w) / double(render.width);
    const double sy = double(rp[std::size_t(l)].h) / double(render.height);
    const d::Intr Kl{full.fx * sx, full.fy * sy, full.cx * sx, full.cy * sy};
    const d::Level& R = rp[std::size_t(l)];
    const d::Level& T = tp[std::size_t(l)];
    for (int it = 0; it < p.iterations; ++it) {
      Eigen::Matrix4d H = Eigen::Matrix4d::Zero();
      Eigen::Vector4d g = Eigen::Vector4d::Zero();
      const Eigen::Matrix3d Rt = dR.transpose();
      const double zoom = std::exp(log_zoom);
      for (int y = 0; y < T.h; ++y)
        for (int x = 0; x < T.w; ++x) {
          const Eigen::Vector3d dir = d::ray(Kl, zoom, x, y);
          const Eigen::Vector3d q = Rt * dir;
          double u, v;
          if (!d::project(Kl, q, u, v) || !d::inside(R, u, v)) continue;
          const double iz = 1.0 / q.z();
          // d q / d w for dR <- exp(w) dR: q = dR^T exp(-w) dir ~ dR^T (dir + [dir]x w);
          // d q / d l for s <- s e^l: dir's x and y scale by e^-l.
          Eigen::Matrix<double, 3, 4> Jq;
          Eigen::Matrix3d cross;
          cross << 0, -dir.z(), dir.y(), dir.z(), 0, -dir.x(), -dir.y(), dir.x(), 0;
          Jq.leftCols<3>() = Rt * cross;
          Jq.col(3) = Rt * Eigen::Vector3d(-dir.x(), -dir.y(), 0);
          Eigen::Matrix<double, 2, 3> Jpi;
          Jpi << Kl.fx * iz, 0, -Kl.fx * q.x() * iz * iz, 0, Kl.fy * iz, -Kl.fy * q.y() * iz * iz;
          const Eigen::Matrix<double, 2, 4> Jpix = Jpi * Jq;
          for (int k = 0; k < T.c; ++k) {
            double val, gx, gy;
            d::sample(R, u, v, k, val, gx, gy);
            const double r = val - T.at(x, y, k);
            const double wgt = std::abs(r) <= p.huber ? 1.0 : p.huber / std::abs(r);
            const Eigen::RowVector4d J = gx * Jpix.row(0) + gy * Jpix.row(1);
            H.noalias() += wgt * J.transpose() * J;
            g.noalias() += wgt * r * J.transpose();
          }
        }
      // Levenberg damping keeps a step on a flat image (no texture) small.
      H.diagonal() += Eigen::Vector4d::Constant(1e-6 * std::max(1.0, H.trace()));
      Eigen::Vector4d step = Eigen::Vector4d::Zero();
      step.head(params) = -H.topLeftCorner(params, params).ldlt().solve(g.head(params));
      if (!step.allFinite()) break;
      dR = d::exp_so3(step.head<3>()) * dR;
      log_zoom += step(3);
      if (Constants<double>::rad2deg(step.head<3>().norm()) < p.min_step_deg && std::abs(step(3)) < 1e-6) break;
    }
  }
  ViewAlignment fit;
  const double zoom = std::exp(log_zoom);
  const auto [before, after] = d::rms_pair(rp[0], tp[0], full, dR, zoom);
  fit.rms_before = before;
  fit.rms_after = before;
  const double angle = d::angle_deg(dR);
  if (std::isfinite(after) && after < before && angle <= p.max_angle_deg && std::abs(zoom - 1) <= p.max_zoom) {
    fit.camera_R_camera = dR;
    fit.zoom = zoom;
    fit.angle_deg = angle;
    fit.rms_after = after;
    fit.refined = true;
  }
  return fit;
}

}  // namespace orbitforge

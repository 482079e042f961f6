#pragma once
// An imperfect oracle: the oracle's recorded gap frames, degraded the way a
// video model's completion is imperfect, so that ways of training G1 can be
// compared where it matters (with perfect frames, any G1 that keeps the source
// is close to the oracle bound by construction).
//
// Each completion frame k of the gap, at fraction s in [0, 1] along the gap in
// the orbit's direction (from the supported arc's end), gets, in this order:
//   colour drift   per-channel gain 1 + color_drift * s * (+1, 0, -1) (a slow
//                  warm shift that grows along the generated clip);
//   warp           a smooth displacement (dx, dy) = warp_px * (sin(2 pi f y/H + a),
//                  sin(2 pi f x/W + b)), f = 1.5 cycles, random phases per frame,
//                  bilinear resampling (warp_px in pixels at 512 pixels of width);
//   blur           a Gaussian of blur_px standard deviation (at 512 pixels);
//   time jitter    the frame's camera turned about the orbit axis by a normal
//                  angle of jitter_deg standard deviation: the frame shows a view
//                  slightly off the one it claims, as a clip whose motion runs
//                  unevenly does;
//   camera error   (camera_error_deg > 0; the "perturbed-geometric" provider sets
//                  1) the frame's camera turned about a random axis through the
//                  orbit's look-at point by an angle drawn from [e, 2e]: a video
//                  model that drifts off the requested cameras, so the frame
//                  shows another view than the one it is trained at.
// All draws come from `seed`; the strengths go into the provider's summary.
#include <algorithm>
#include <cmath>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"

namespace orbitforge {

struct PerturbParams {
  double color_drift = 0.08;
  double warp_px = 1.5;
  double blur_px = 0.8;
  double jitter_deg = 0.5;
  double camera_error_deg = 0;
  unsigned seed = 1;
};

namespace perturb_detail {

template <class Scalar>
Image<Scalar> gaussian_blur(const Image<Scalar>& img, double sigma) {
  if (!(sigma > 0)) return img;
  const int r = std::max(1, int(std::ceil(3 * sigma)));
  std::vector<double> k(std::size_t(2 * r + 1));
  double sum = 0;
  for (int i = -r; i <= r; ++i) sum += k[std::size_t(i + r)] = std::exp(-0.5 * i * i / (sigma * sigma));
  for (auto& v : k) v /= sum;
  Image<Scalar> tmp(img.width, img.height, img.channels), out(img.width, img.height, img.channels);
  auto pass = [&](const Image<Scalar>& src, Image<Scalar>& dst, bool horizontal) {
    for (int y = 0; y < src.height; ++y)
      for (int x = 0; x < src.width; ++x)
        for (int c = 0; c < src.channels; ++c) {
          double acc = 0;
          for (int i = -r; i <= r; ++i) {
            const int xx = horizontal ? std::clamp(x + i, 0, src.width - 1) : x;
            const int yy = horizontal ? y : std::clamp(y + i, 0, src.height - 1);
            acc += k[std::size_t(i + r)] * double(src(xx, yy, c));
          }
          dst(x, y, c) = Scalar(acc);
        }
  };
  pass(img, tmp, true);
  pass(tmp, out, false);
  return out;
}

// out(x, y) = img(x + dx(y), y + dy(x)), bilinear, edges clamped.
template <class Scalar>
Image<Scalar> warp(const Image<Scalar>& img, double amplitude, double phase_x, double phase_y) {
  if (!(amplitude > 0)) return img;
  const double two_pi = 2 * Constants<double>::pi(), f = 1.5;
  Image<Scalar> out(img.width, img.height, img.channels);
  for (int y = 0; y < img.height; ++y) {
    const double dx = amplitude * std::sin(two_pi * f * y / img.height + phase_x);
    for (int x = 0; x < img.width; ++x) {
      const double dy = amplitude * std::sin(two_pi * f * x / img.width + phase_y);
      const double sx = std::clamp(x + dx, 0.0, double(img.width - 1)), sy = std::clamp(y + dy, 0.0, double(img.height - 1));
      const int x0 = int(sx), y0 = int(sy);
      const int x1 = std::min(x0 + 1, img.width - 1), y1 = std::min(y0 + 1, img.height - 1);
      const double ax = sx - x0, ay = sy - y0;
      for (int c = 0; c < img.channels; ++c)
        out(x, y, c) = Scalar((1 - ay) * ((1 - ax) * img(x0, y0, c) + ax * img(x1, y0, c)) +
                              ay * ((1 - ax) * img(x0, y1, c) + ax * img(x1, y1, c)));
    }
  }
  return out;
}

// The camera turned by `deg` about the orbit's axis (through its centre).
template <class Scalar>
Camera<Scalar> turn_about_orbit(const Camera<Scalar>& cam, const OrbitFit<Scalar>& fit, double deg) {
  using Vec3 = typename Camera<Scalar>::Vec3;
  const Eigen::Matrix<Scalar, 3, 3> Rw =
      Eigen::AngleAxis<Scalar>(Scalar(deg * Constants<double>::pi() / 180.0), fit.orbit.normal.normalized())
          .toRotationMatrix();
  const Vec3 c = fit.orbit.center + Rw * (cam.center() - fit.orbit.center);
  Camera<Scalar> out = cam;
  out.R = cam.R * Rw.transpose();
  out.t = -out.R * c;
  return out;
}

// The camera turned by `deg` about `axis` through `pivot`: it keeps its distance
// to the pivot and its view of it, from another direction.
template <class Scalar>
Camera<Scalar> turn_about_point(const Camera<Scalar>& cam, const Eigen::Matrix<Scalar, 3, 1>& pivot,
                                const Eigen::Matrix<Scalar, 3, 1>& axis, double deg) {
  const Eigen::Matrix<Scalar, 3, 3> Rw =
      Eigen::AngleAxis<Scalar>(Scalar(deg * Constants<double>::pi() / 180.0), axis.normalized()).toRotationMatrix();
  Camera<Scalar> out = cam;
  out.R = cam.R * Rw.transpose();
  out.t = -out.R * (pivot + Rw * (cam.center() - pivot));
  return out;
}

}  // namespace perturb_detail

template <class Scalar>
class PerturbedOracleCompletion : public OracleCompletion<Scalar> {
 public:
  explicit PerturbedOracleCompletion(PerturbParams p = {}, std::string name = "perturbed")
      : p_(p), name_(std::move(name)) {}
  std::string name() const override { return name_; }
  std::string state_key(const CompletionContext<Scalar>&) const override {
    std::string k = "perturbed " + std::to_string(p_.color_drift) + " " + std::to_string(p_.warp_px) + " " +
                    std::to_string(p_.blur_px) + " " + std::to_string(p_.jitter_deg) + " " + std::to_string(p_.seed);
    if (p_.camera_error_deg > 0) k += " camera " + std::to_string(p_.camera_error_deg);
    return k;
  }

  CompletionResult<Scalar> complete(const CompletionContext<Scalar>& ctx) override {
    using namespace perturb_detail;
    CompletionResult<Scalar> r = OracleCompletion<Scalar>::complete(ctx);
    const auto& fit = *ctx.fit;
    // Fraction along the gap, from the end of the supported arc in the orbit's direction.
    const double period = double(fit.views - 1);
    const double arc_end = double(fit.support.arc.empty() ? 0 : fit.support.arc.back());
    double span = 0;
    for (const auto& f : r.frames) span = std::max(span, std::fmod(f.position - arc_end + period, period));
    std::mt19937 rng(p_.seed);
    std::uniform_real_distribution<double> phase(0, 2 * Constants<double>::pi());
    std::normal_distribution<double> normal(0, 1);
    for (auto& f : r.frames) {
      const double s = span > 0 ? std::fmod(f.position - arc_end + period, period) / span : 0;
      const double px = f.image.width / 512.0;
      for (int y = 0; y < f.image.height; ++y)
        for (int x = 0; x < f.image.width; ++x) {
          f.image(x, y, 0) = std::min(Scalar(1), Scalar(f.image(x, y, 0) * (1 + p_.color_drift * s)));
          f.image(x, y, 2) = std::min(Scalar(1), Scalar(f.image(x, y, 2) * (1 - p_.color_drift * s)));
        }
      const double ax = phase(rng), ay = phase(rng);
      f.image = gaussian_blur(warp(f.image, p_.warp_px * px, ax, ay), p_.blur_px * px);
      f.camera = turn_about_orbit(f.camera, fit, p_.jitter_deg * normal(rng));
      if (p_.camera_error_deg > 0) {
        const Eigen::Matrix<Scalar, 3, 1> axis(Scalar(normal(rng)), Scalar(normal(rng)), Scalar(normal(rng)));
        const double deg = p_.camera_error_deg * (1 + std::uniform_real_distribution<double>(0, 1)(rng));
        f.camera = turn_about_point(f.camera, fit.orbit.look_at, axis, deg);
      }
      f.origin = "perturbed " + f.origin;
    }
    r.summary["perturbation"] = {{"color_drift", p_.color_drift},
                                 {"warp_px_at_512", p_.warp_px},
                                 {"blur_px_at_512", p_.blur_px},
                                 {"jitter_deg", p_.jitter_deg},
                                 {"camera_error_deg", p_.camera_error_deg},
                                 {"seed", p_.seed}};
    r.message += " (perturbed: colour drift " + std::to_string(p_.color_drift) + ", warp " +
                 std::to_string(p_.warp_px) + " px, blur " + std::to_string(p_.blur_px) + " px, jitter " +
                 std::to_string(p_.jitter_deg) + " deg)";
    return r;
  }

 private:
  PerturbParams p_;
  std::string name_;
};

}  // namespace orbitforge

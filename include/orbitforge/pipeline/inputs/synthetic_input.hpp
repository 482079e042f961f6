#pragma once
// A deterministic synthetic "recorded input", so that examples and end-to-end
// tests run on a fresh machine with nothing else: a textured object on a ground
// plane (as a Gaussian scene), the true cameras of a full orbit video around it,
// and the cameras an estimator would have recorded for it: small noise and a
// little frame-to-frame drift, as generated videos have. The first
// `source_frames` frames play the source video; the rest are ground truth for
// the views the method must complete.
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/constants.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

struct SyntheticInputParams {
  int frames = 90;             // frames of the full recorded orbit
  int source_frames = 33;      // the first frames play the source video
  double arc_deg = 360.0 * 88.0 / 90.0;  // azimuth travelled over all frames
  int direction = +1;          // +1 counter-clockwise seen from +z, -1 clockwise
  double radius = 4.0;
  double elevation_deg = 12.0;
  int width = 128, height = 128;
  double focal = 160.0;        // pixels, at width x height
  double position_noise = 0.01;   // camera-centre noise, in units of the radius
  double rotation_noise_deg = 0.2;
  double drift_per_frame = 0.0005;  // slow radius/elevation drift, in radius units per frame
  int object_gaussians = 3000;
  int ground_gaussians = 2000;
  // A textured wall around the whole orbit (radius backdrop_radius, in units of
  // the orbit radius), so that every frame's background is cluttered, as in
  // handheld photographs, instead of the renderer's plain background.
  bool backdrop = false;
  int backdrop_gaussians = 4000;
  double backdrop_radius = 1.75;
  // Multiplies every length (scene, cameras): the method must not depend on the
  // arbitrary unit a camera estimator reconstructs in.
  double world_scale = 1.0;
  unsigned seed = 7;
};

template <class Scalar>
struct SyntheticInput {
  GaussianScene<Scalar> scene;                 // ground truth geometry (degree 0 colour)
  std::vector<Camera<Scalar>> true_cameras;    // the cameras the frames were taken with
  std::vector<FrameCamera<Scalar>> recorded;   // what an estimator recorded (noisy)
  Eigen::Matrix<Scalar, 3, 1> up{0, 0, 1};     // world up
  Eigen::Matrix<Scalar, 3, 1> target{0, 0, Scalar(0.5)};  // the object's centre
};

namespace synthetic_detail {

template <class Scalar>
void push_gaussian(GaussianScene<Scalar>& s, const Eigen::Matrix<Scalar, 3, 1>& x,
                   const Eigen::Quaternion<Scalar>& q, const Eigen::Matrix<Scalar, 3, 1>& scale, Scalar opacity,
                   const Eigen::Matrix<Scalar, 3, 1>& rgb) {
  for (int k = 0; k < 3; ++k) s.means.push_back(x[k]);
  s.rotations.insert(s.rotations.end(), {q.w(), q.x(), q.y(), q.z()});
  for (int k = 0; k < 3; ++k) s.log_scales.push_back(std::log(scale[k]));
  s.opacity_logits.push_back(logit(opacity));
  for (int k = 0; k < 3; ++k) s.sh.push_back(rgb_to_sh_dc(rgb[k]));
}

}  // namespace synthetic_detail

// Texture of the object: coloured bands in azimuth and height, so that every
// side of the orbit looks different (the completion has something to get right).
template <class Scalar>
Eigen::Matrix<Scalar, 3, 1> synthetic_object_color(Scalar azimuth, Scalar height) {
  const Scalar pi = Constants<Scalar>::pi();
  const int sector = int(std::floor((azimuth + pi) / (2 * pi) * 6)) % 6;
  static const Scalar palette[6][3] = {{0.85, 0.20, 0.15}, {0.95, 0.75, 0.10}, {0.20, 0.65, 0.25},
                                       {0.15, 0.45, 0.85}, {0.55, 0.25, 0.75}, {0.95, 0.55, 0.70}};
  const bool stripe = int(std::floor(height * 6)) % 2 == 0;
  const Scalar shade = stripe ? Scalar(1) : Scalar(0.6);
  return {palette[sector][0] * shade, palette[sector][1] * shade, palette[sector][2] * shade};
}

template <class Scalar>
SyntheticInput<Scalar> make_synthetic_input(const SyntheticInputParams& p = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Quat = Eigen::Quaternion<Scalar>;
  ensure(p.frames >= 3 && p.source_frames >= 3 && p.source_frames <= p.frames,
         "make_synthetic_input: need 3 <= source_frames <= frames, got ", p.source_frames, " of ", p.frames);
  SyntheticInput<Scalar> in;
  std::mt19937 rng(p.seed);
  std::uniform_real_distribution<Scalar> uni(0, 1);
  std::normal_distribution<Scalar> gauss(0, 1);
  const Scalar pi = Constants<Scalar>::pi();

  // Object: a vertical capsule-like body (cylinder + cap) of radius 0.6, height 1.2,
  // covered by flat surface Gaussians oriented along the surface.
  auto& s = in.scene;
  s.sh_degree = 0;
  for (int i = 0; i < p.object_gaussians; ++i) {
    const Scalar az = (uni(rng) * 2 - 1) * pi;
    const Scalar h = uni(rng) * Scalar(1.2);
    const Scalar r = Scalar(0.6) * (h > Scalar(0.9) ? std::sqrt(std::max<Scalar>(0, 1 - std::pow((h - 0.9) / 0.3, 2)))
                                                    : Scalar(1));
    const Vec3 x(r * std::cos(az), r * std::sin(az), h);
    const Vec3 normal(std::cos(az), std::sin(az), 0);
    const Quat q = Quat::FromTwoVectors(Vec3::UnitZ(), normal);
    synthetic_detail::push_gaussian(s, x, q, Vec3(Scalar(0.05), Scalar(0.05), Scalar(0.01)), Scalar(0.9),
                                    synthetic_object_color<Scalar>(az, h));
  }
  // Ground: a checkered disk of radius 2.5 at z = 0.
  for (int i = 0; i < p.ground_gaussians; ++i) {
    const Scalar rr = Scalar(2.5) * std::sqrt(uni(rng)), az = (uni(rng) * 2 - 1) * pi;
    const Vec3 x(rr * std::cos(az), rr * std::sin(az), 0);
    const bool check = (int(std::floor(x.x() * 2 + 10)) + int(std::floor(x.y() * 2 + 10))) % 2 == 0;
    const Vec3 rgb = check ? Vec3(Scalar(0.75), Scalar(0.72), Scalar(0.65)) : Vec3(Scalar(0.35), Scalar(0.33), Scalar(0.3));
    synthetic_detail::push_gaussian(s, x, Quat::Identity(), Vec3(Scalar(0.09), Scalar(0.09), Scalar(0.01)),
                                    Scalar(0.95), rgb);
  }

  if (p.backdrop) {
    // Wall from below the floor to above the cameras: bands of colour in azimuth,
    // a checker in height, flat Gaussians facing the orbit's axis.
    const Scalar wall_r = Scalar(p.backdrop_radius * p.radius);
    const Scalar z0 = Scalar(-0.5), z1 = Scalar(p.radius * 1.2);
    const Scalar size = std::sqrt(2 * pi * wall_r * (z1 - z0) / Scalar(std::max(1, p.backdrop_gaussians)));
    for (int i = 0; i < p.backdrop_gaussians; ++i) {
      const Scalar az = (uni(rng) * 2 - 1) * pi, z = z0 + (z1 - z0) * uni(rng);
      const Vec3 x(wall_r * std::cos(az), wall_r * std::sin(az), z);
      const Quat q = Quat::FromTwoVectors(Vec3::UnitZ(), Vec3(std::cos(az), std::sin(az), 0));
      const int band = int(std::floor((az + pi) / (2 * pi) * 16));
      const bool check = (band + int(std::floor(z / (size * 4)))) % 2 == 0;
      const Scalar g = Scalar(0.25) + Scalar(0.5) * Scalar(band % 4) / Scalar(3);
      const Vec3 rgb = check ? Vec3(g, Scalar(0.45), Scalar(1) - g) : Vec3(Scalar(0.9) - g / 2, g, Scalar(0.3));
      synthetic_detail::push_gaussian(s, x, q, Vec3(size, size, size * Scalar(0.1)), Scalar(0.95), rgb);
    }
  }
  if (p.world_scale != 1.0) {
    ensure(p.world_scale > 0 && std::isfinite(p.world_scale), "make_synthetic_input: world_scale must be positive");
    const Scalar w = Scalar(p.world_scale);
    for (auto& v : s.means) v *= w;
    for (auto& v : s.log_scales) v += std::log(w);
    in.target *= w;
  }

  // Cameras on the orbit; the recorded ones get noise and a slow drift.
  const Intrinsics<Scalar> k{Scalar(p.focal), Scalar(p.focal), Scalar(p.width) / 2, Scalar(p.height) / 2, p.width,
                             p.height};
  const Scalar elev = Constants<Scalar>::deg2rad(Scalar(p.elevation_deg));
  for (int f = 0; f < p.frames; ++f) {
    const Scalar az = Scalar(p.direction) * Constants<Scalar>::deg2rad(Scalar(p.arc_deg)) * f / Scalar(p.frames);
    const Vec3 eye = in.target + Scalar(p.radius * p.world_scale) * Vec3(std::cos(elev) * std::cos(az), std::cos(elev) * std::sin(az),
                                                          std::sin(elev));
    in.true_cameras.push_back(Camera<Scalar>::look_at(eye, in.target, in.up, k));

    const Scalar drift = Scalar(p.drift_per_frame) * f * Scalar(p.radius * p.world_scale);
    Vec3 noisy_eye =
        eye + Vec3(gauss(rng), gauss(rng), gauss(rng)) * Scalar(p.position_noise * p.radius * p.world_scale);
    noisy_eye += (eye - in.target).normalized() * drift + in.up * (drift * Scalar(0.5));
    Camera<Scalar> rec = Camera<Scalar>::look_at(noisy_eye, in.target, in.up, k);
    const Scalar rn = Constants<Scalar>::deg2rad(Scalar(p.rotation_noise_deg));
    const Eigen::Matrix<Scalar, 3, 3> jitter =
        (Eigen::AngleAxis<Scalar>(rn * gauss(rng), Vec3::UnitX()) *
         Eigen::AngleAxis<Scalar>(rn * gauss(rng), Vec3::UnitY()) *
         Eigen::AngleAxis<Scalar>(rn * gauss(rng), Vec3::UnitZ()))
            .toRotationMatrix();
    const Vec3 c = rec.center();
    rec.R = jitter * rec.R;
    rec.t = -rec.R * c;
    char name[32];
    std::snprintf(name, sizeof(name), "%03d.png", f + 1);
    in.recorded.push_back({name, rec, true});
  }
  return in;
}

}  // namespace orbitforge

#pragma once
// A Gaussian Splatting scene as a structure of arrays (one array per attribute,
// Gaussian-major inside each), in the parameterisation 3DGS trains:
//
//   means          [N][3]  world position
//   rotations      [N][4]  quaternion (w, x, y, z); need not be normalised
//   log_scales     [N][3]  log of the per-axis standard deviation
//   opacity_logits [N]     opacity = sigmoid(logit)
//   sh             [N][K][3] spherical-harmonic colour coefficients, K = (degree+1)^2,
//                          coefficient-major then RGB; sh[i][0] is the DC term.
//
// The renderer reads scenes through the adaptor contract in splat/scene_adaptor.hpp, which
// GaussianScene satisfies; a host renderer can satisfy it with its own storage.
#include <cmath>
#include <cstddef>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

// How a deformation's scale offset ds combines with a Gaussian's scale s:
//   additive  s' = s + ds        (Deformable 3D Gaussians, and the paper's MedianGS);
//   log       s' = s * exp(ds)   (a relative change: ds is dimensionless).
// With additive offsets a shared offset of a few Gaussians' size shrinks every
// Gaussian near that size to a point; the tiny rendered Gaussians keep large
// positional gradients, densification clones them (their canonical scale is
// small) and the clones stay tiny: on real photographs the count exploded from
// 40k to 500k within 500 iterations while the fit got worse. A relative offset
// cannot reach zero, and splitting a Gaussian halves its rendered size again.
enum class ScaleOffset { additive, log };

inline const char* scale_offset_name(ScaleOffset m) { return m == ScaleOffset::log ? "log" : "additive"; }

inline constexpr int sh_coefficient_count(int degree) { return (degree + 1) * (degree + 1); }

template <class Scalar>
struct GaussianScene {
  using scalar_type = Scalar;

  int sh_degree = 0;  // 0..3
  std::vector<Scalar> means;
  std::vector<Scalar> rotations;
  std::vector<Scalar> log_scales;
  std::vector<Scalar> opacity_logits;
  std::vector<Scalar> sh;

  std::size_t size() const { return opacity_logits.size(); }
  bool empty() const { return opacity_logits.empty(); }
  int sh_coefficients() const { return sh_coefficient_count(sh_degree); }

  // n Gaussians of the given degree: identity rotation, unit scale, opacity 0.5, black.
  void resize(std::size_t n, int degree) {
    ensure(degree >= 0 && degree <= 3, "GaussianScene: SH degree must be 0..3, got ", degree);
    sh_degree = degree;
    means.assign(3 * n, Scalar(0));
    rotations.assign(4 * n, Scalar(0));
    for (std::size_t i = 0; i < n; ++i) rotations[4 * i] = Scalar(1);
    log_scales.assign(3 * n, Scalar(0));
    opacity_logits.assign(n, Scalar(0));
    sh.assign(n * std::size_t(sh_coefficient_count(degree)) * 3, Scalar(0));
  }

  // Throws naming the first array whose length does not match size().
  void check_consistent() const {
    const std::size_t n = size();
    ensure(sh_degree >= 0 && sh_degree <= 3, "GaussianScene: SH degree must be 0..3, got ", sh_degree);
    ensure(means.size() == 3 * n, "GaussianScene: means has ", means.size(), " values, expected ", 3 * n);
    ensure(rotations.size() == 4 * n, "GaussianScene: rotations has ", rotations.size(), " values, expected ",
           4 * n);
    ensure(log_scales.size() == 3 * n, "GaussianScene: log_scales has ", log_scales.size(),
           " values, expected ", 3 * n);
    const std::size_t k = std::size_t(sh_coefficients()) * 3 * n;
    ensure(sh.size() == k, "GaussianScene: sh has ", sh.size(), " values, expected ", k);
  }

  template <class T>
  GaussianScene<T> cast() const {
    GaussianScene<T> o;
    o.sh_degree = sh_degree;
    o.means.assign(means.begin(), means.end());
    o.rotations.assign(rotations.begin(), rotations.end());
    o.log_scales.assign(log_scales.begin(), log_scales.end());
    o.opacity_logits.assign(opacity_logits.begin(), opacity_logits.end());
    o.sh.assign(sh.begin(), sh.end());
    return o;
  }
};

using GaussianScenef = GaussianScene<float>;
using GaussianScened = GaussianScene<double>;

// SH coefficient of degree 0 that maps to RGB c: colour = C0 * dc + 0.5.
template <class Scalar>
constexpr Scalar sh_c0() { return Scalar(0.28209479177387814); }
template <class Scalar>
Scalar rgb_to_sh_dc(Scalar rgb) { return (rgb - Scalar(0.5)) / sh_c0<Scalar>(); }

template <class Scalar>
Scalar sigmoid(Scalar x) { return Scalar(1) / (Scalar(1) + std::exp(-x)); }
template <class Scalar>
Scalar logit(Scalar p) { return std::log(p / (Scalar(1) - p)); }

}  // namespace orbitforge

#pragma once
// Gradients of a loss w.r.t. the parameters of a Gaussian scene, as
// project_scene_vjp (splat/project.hpp) writes them: one array per accessor of
// the scene adaptor (splat/scene_adaptor.hpp), named after it and in the order
// it returns values (the GaussianScene arrays' order):
//
//   means          [N][3]
//   rotations      [N][4]   w.r.t. the quaternion as stored (through the normalisation)
//   scales         [N][3]   w.r.t. what the adaptor's scale() returns (scale_mode says
//                           which): the log standard deviation for ScaleMode::log
//                           (GaussianScene through SceneView), the standard deviation
//                           for ScaleMode::activated (DeformedSceneView, where it is the
//                           gradient w.r.t. the offset ds; see its base_gradients)
//   opacity_logits [N]
//   sh             [N][K][3]
//
// plus, for densification, per Gaussian:
//   screen_grad_norm      |(v_mean_x, v_mean_y)| in pixel units (dL/d pixel).
//   screen_grad_ndc_norm  |(v_mean_x * W/2, v_mean_y * H/2)|: the gradient w.r.t. the
//                         NDC mean (pixel = ((ndc + 1) W - 1) / 2), i.e. the quantity
//                         3DGS accumulates and compares with its 0.0002 threshold.
// Both are zero for Gaussians the projection culled.
#include <cstddef>
#include <vector>

#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"

namespace orbitforge {

// Parameter groups whose gradients the caller does not need. A frozen group's
// array is never written (only sized, zero-filled, when its size is wrong), and
// the work that only it needs is skipped.
struct Freeze {
  bool means = false;
  bool rotations = false;
  bool scales = false;
  bool opacities = false;
  bool sh_dc = false;    // coefficient k = 0
  bool sh_rest = false;  // coefficients k >= 1
};

template <class Scalar>
struct GaussianSceneGrad {
  using scalar_type = Scalar;

  int sh_degree = 0;
  ScaleMode scale_mode = ScaleMode::log;  // the parametrisation `scales` is w.r.t.
  std::vector<Scalar> means;
  std::vector<Scalar> rotations;
  std::vector<Scalar> scales;
  std::vector<Scalar> opacity_logits;
  std::vector<Scalar> sh;
  std::vector<Scalar> screen_grad_norm;
  std::vector<Scalar> screen_grad_ndc_norm;

  std::size_t size() const { return screen_grad_norm.size(); }
  int sh_coefficients() const { return sh_coefficient_count(sh_degree); }

  // All arrays sized for n Gaussians of the given degree and set to zero.
  void assign_zero(std::size_t n, int degree, ScaleMode mode = ScaleMode::log) {
    sh_degree = degree;
    scale_mode = mode;
    means.assign(3 * n, Scalar(0));
    rotations.assign(4 * n, Scalar(0));
    scales.assign(3 * n, Scalar(0));
    opacity_logits.assign(n, Scalar(0));
    sh.assign(n * std::size_t(sh_coefficient_count(degree)) * 3, Scalar(0));
    screen_grad_norm.assign(n, Scalar(0));
    screen_grad_ndc_norm.assign(n, Scalar(0));
  }
};

using GaussianSceneGradf = GaussianSceneGrad<float>;
using GaussianSceneGradd = GaussianSceneGrad<double>;

}  // namespace orbitforge

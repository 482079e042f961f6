#pragma once
// A writable view of a host's gradient storage: the backward pass writes each
// Gaussian's gradients straight into the caller's arrays, in the caller's own
// parametrisation, without a GaussianSceneGrad in between.
//
//   struct HostGrad { double xyz[3], quat_xyzw[4], sigma[3], opacity, rgb_sh[3]; };
//   std::vector<HostGrad> grads(n);
//   orbitforge::SceneGradView<double> view;
//   view.size = n;
//   view.means = orbitforge::strided(grads[0].xyz, sizeof(HostGrad));
//   view.rotations = orbitforge::strided(grads[0].quat_xyzw, sizeof(HostGrad));
//   view.rotation_order = orbitforge::QuatOrder::xyzw;
//   view.scales = orbitforge::strided(grads[0].sigma, sizeof(HostGrad));      // d/d sigma
//   view.opacities = orbitforge::strided(&grads[0].opacity, sizeof(HostGrad)); // d/d opacity
//   view.sh = orbitforge::strided(grads[0].rgb_sh, sizeof(HostGrad));
//   renderer.backward(adaptor, camera, v_color, view);
//
// Every field is a pointer to Gaussian 0's first value and a stride in bytes
// from one Gaussian to the next (an array of structs, a struct of arrays, or
// anything in between). A null field is not wanted: it is never written and the
// work only it needs is skipped. Wanted fields are overwritten (not accumulated);
// Gaussians the projection culled get zeros.
//
// Parametrisation: each group may be asked for in either form, independent of the
// adaptor's own (the derivative is converted):
//   scales      d/d standard deviation s      log_scales      d/d log s  (= s d/ds)
//   opacities   d/d opacity o in (0, 1)       opacity_logits  d/d logit  (= o (1 - o) d/do)
//   rotations   d/d the quaternion as the adaptor returns it (before normalisation),
//               its four values stored in rotation_order
//   sh          coefficient k, channel c at sh + k * sh_coefficient_stride_bytes
//               + c * sizeof(Scalar); k < (degree + 1)^2
//   screen_grad_norm / screen_grad_ndc_norm: |d/d projected mean| in pixels / NDC
//               (what densification accumulates; see scene_grad.hpp)
#include <cstddef>

namespace orbitforge {

enum class QuatOrder { wxyz, xyzw };

template <class Scalar>
struct Strided {
  Scalar* data = nullptr;
  std::ptrdiff_t stride_bytes = 0;

  explicit operator bool() const { return data != nullptr; }
  Scalar* at(std::size_t i) const {
    return reinterpret_cast<Scalar*>(reinterpret_cast<char*>(data) + std::ptrdiff_t(i) * stride_bytes);
  }
};

// strided(&host[0].field, sizeof(host[0])): one field of an array of structs.
template <class Scalar>
Strided<Scalar> strided(Scalar* first, std::ptrdiff_t stride_bytes) {
  return {first, stride_bytes};
}

template <class Scalar>
struct SceneGradView {
  using scalar_type = Scalar;

  std::size_t size = 0;  // must equal the scene's Gaussian count (checked)
  Strided<Scalar> means;
  Strided<Scalar> rotations;
  QuatOrder rotation_order = QuatOrder::wxyz;
  Strided<Scalar> scales, log_scales;
  Strided<Scalar> opacities, opacity_logits;
  Strided<Scalar> sh;
  std::ptrdiff_t sh_coefficient_stride_bytes = 3 * sizeof(Scalar);
  Strided<Scalar> screen_grad_norm, screen_grad_ndc_norm;
};

}  // namespace orbitforge

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
//   view.sh_coefficients = 1;                                                  // rgb_sh holds the DC term
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
//               + c * sizeof(Scalar), for k < sh_coefficients: the extent the host
//               holds per Gaussian, not the adaptor's (degree + 1)^2. Coefficients
//               past the adaptor's count get zeros (the image does not read them);
//               the adaptor's coefficients past the extent are not written.
//   screen_grad_norm / screen_grad_ndc_norm: |d/d projected mean| in pixels / NDC
//               (what densification accumulates; see scene_grad.hpp)
//
// check_grad_view refuses, naming the field, a view whose writes could overrun
// or tear: a zero stride, a stride shorter than what one Gaussian gets written
// (3, 4, 3, 1 values; for sh the extent's footprint), a pointer or stride not a
// multiple of alignof(Scalar), an sh extent outside 1..16. project_scene_vjp
// calls it before writing anything.
#include <cstddef>
#include <cstdint>
#include <cstdlib>

#include "orbitforge/core/error.hpp"

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
  int sh_coefficients = 0;  // per Gaussian at `sh` (1 = DC only, up to 16); required with sh
  std::ptrdiff_t sh_coefficient_stride_bytes = 3 * sizeof(Scalar);
  Strided<Scalar> screen_grad_norm, screen_grad_ndc_norm;
};

namespace detail {
template <class Scalar>
void check_strided(const Strided<Scalar>& f, const char* name, std::ptrdiff_t bytes_written) {
  if (!f) return;
  constexpr std::uintptr_t align = alignof(Scalar);
  ensure(f.stride_bytes != 0, "SceneGradView::", name, ": stride_bytes is 0 (every Gaussian would write to ",
         "the same place)");
  ensure(std::abs(f.stride_bytes) >= bytes_written, "SceneGradView::", name, ": stride_bytes is ", f.stride_bytes,
         ", shorter than the ", bytes_written, " bytes written per Gaussian");
  ensure(reinterpret_cast<std::uintptr_t>(f.data) % align == 0, "SceneGradView::", name,
         ": the pointer is not aligned to ", align, " bytes");
  ensure(std::uintptr_t(std::abs(f.stride_bytes)) % align == 0, "SceneGradView::", name, ": stride_bytes ",
         f.stride_bytes, " is not a multiple of ", align);
}
}  // namespace detail

// Throws orbitforge::Error naming the first field whose layout is unsafe (see above).
template <class Scalar>
void check_grad_view(const SceneGradView<Scalar>& v) {
  constexpr std::ptrdiff_t s1 = sizeof(Scalar);
  detail::check_strided(v.means, "means", 3 * s1);
  detail::check_strided(v.rotations, "rotations", 4 * s1);
  detail::check_strided(v.scales, "scales", 3 * s1);
  detail::check_strided(v.log_scales, "log_scales", 3 * s1);
  detail::check_strided(v.opacities, "opacities", s1);
  detail::check_strided(v.opacity_logits, "opacity_logits", s1);
  detail::check_strided(v.screen_grad_norm, "screen_grad_norm", s1);
  detail::check_strided(v.screen_grad_ndc_norm, "screen_grad_ndc_norm", s1);
  if (!v.sh) return;
  ensure(v.sh_coefficients >= 1 && v.sh_coefficients <= 16, "SceneGradView::sh_coefficients is ", v.sh_coefficients,
         ": say how many coefficients per channel (1 .. 16) the host's sh array holds for each Gaussian");
  const std::ptrdiff_t k_stride = v.sh_coefficient_stride_bytes;
  if (v.sh_coefficients > 1) {
    ensure(std::abs(k_stride) >= 3 * s1, "SceneGradView::sh_coefficient_stride_bytes is ", k_stride,
           ", shorter than the ", 3 * s1, " bytes of a coefficient's three channels");
    ensure(std::abs(k_stride) % s1 == 0, "SceneGradView::sh_coefficient_stride_bytes ", k_stride,
           " is not a multiple of ", s1);
  }
  detail::check_strided(v.sh, "sh", (v.sh_coefficients - 1) * std::abs(k_stride) + 3 * s1);
}

}  // namespace orbitforge

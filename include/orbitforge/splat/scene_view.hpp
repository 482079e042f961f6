#pragma once
// Scene adaptors over the library's own GaussianScene (splat/scene_adaptor.hpp
// has the contract): SceneView reads a GaussianScene; DeformedSceneView renders
// the deformable state x + dx, normalize(q) + dq, exp(log s) + ds of a base scene
// without copying it, and maps gradients back to the base scene and the offsets.
#include <cmath>
#include <cstddef>

#include "orbitforge/core/error.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"
#include "orbitforge/splat/scene_grad.hpp"

namespace orbitforge {


namespace detail {
// Prefetches the cache lines of [p, p + bytes) into L2 (a hint). A batch of
// Gaussians spans about 60 lines, more misses than L1 tracks at once: prefetches
// into L1 (prefetcht0) were no faster than none; into L2 the projection of
// degree-3 scenes of 100k-300k Gaussians took 0.77-0.93x the time, its VJP
// 0.86-0.89x (bench_project).
// GCC's pure-const analysis sees no side effect in __builtin_prefetch, marks a
// function holding only prefetches const and deletes its calls; the volatile
// asm keeps them.
inline void prefetch_bytes(const void* p, std::size_t bytes) {
  const char* c = static_cast<const char*>(p);
  for (std::size_t o = 0; o < bytes; o += 64) {
#if (defined(__GNUC__) || defined(__clang__)) && (defined(__x86_64__) || defined(__i386__))
    asm volatile("prefetcht1 %0" : : "m"(c[o]));
#elif defined(__GNUC__) || defined(__clang__)
    __builtin_prefetch(c + o, 0, 2);
    asm volatile("" : : : "memory");
#else
    (void)c;
#endif
  }
}
}  // namespace detail

// A GaussianScene held by const reference (log-scales).
template <class Scalar>
class SceneView {
 public:
  using scalar_type = Scalar;
  static constexpr ScaleMode scale_mode = ScaleMode::log;

  explicit SceneView(const GaussianScene<Scalar>& s) : s_(s) { s.check_consistent(); }

  std::size_t size() const { return s_.size(); }
  int sh_degree() const { return s_.sh_degree; }
  void mean(std::size_t i, Scalar out[3]) const { copy_n(&s_.means[3 * i], 3, out); }
  void rotation(std::size_t i, Scalar out[4]) const { copy_n(&s_.rotations[4 * i], 4, out); }
  void scale(std::size_t i, Scalar out[3]) const { copy_n(&s_.log_scales[3 * i], 3, out); }
  Scalar opacity_logit(std::size_t i) const { return s_.opacity_logits[i]; }
  Scalar sh(std::size_t i, int k, int c) const { return s_.sh[(i * std::size_t(k_) + std::size_t(k)) * 3 + c]; }
  const Scalar* sh_data() const { return s_.sh.data(); }
  void prefetch(std::size_t first, std::size_t count) const {
    const std::size_t s1 = sizeof(Scalar);
    detail::prefetch_bytes(&s_.means[3 * first], 3 * count * s1);
    detail::prefetch_bytes(&s_.rotations[4 * first], 4 * count * s1);
    detail::prefetch_bytes(&s_.log_scales[3 * first], 3 * count * s1);
    detail::prefetch_bytes(&s_.opacity_logits[first], count * s1);
    detail::prefetch_bytes(&s_.sh[first * k_ * 3], 3 * k_ * count * s1);
  }

 private:
  static void copy_n(const Scalar* a, int n, Scalar* b) {
    for (int j = 0; j < n; ++j) b[j] = a[j];
  }
  const GaussianScene<Scalar>& s_;
  std::size_t k_ = std::size_t(s_.sh_coefficients());
};

// The deformed state of a base scene, as Deformable 3D Gaussians renders it:
//   mean = x + dx,  rotation = normalize(q) + dq  (normalised again by the projection),
//   scale = exp(log s) + ds  (ScaleOffset::additive: activated, any sign) or
//           exp(log s + ds)  (ScaleOffset::log),  opacity and SH of the base.
// dx [N][3], dq [N][4], ds [N][3] are caller-owned arrays; a null pointer means zero.
// The VJP w.r.t. this adaptor gives v_dx = grad.means, v_dq = grad.rotations and
// the activated-scale gradient in grad.scales (scale_offset_gradients() turns
// it into v_ds); base_gradients() chains to the base parameters.
template <class Scalar>
class DeformedSceneView {
 public:
  using scalar_type = Scalar;
  static constexpr ScaleMode scale_mode = ScaleMode::activated;

  DeformedSceneView(const GaussianScene<Scalar>& base, const Scalar* dx, const Scalar* dq, const Scalar* ds,
                    ScaleOffset scale_offset = ScaleOffset::additive)
      : b_(base), dx_(dx), dq_(dq), ds_(ds), mode_(scale_offset) {
    base.check_consistent();
  }

  std::size_t size() const { return b_.size(); }
  int sh_degree() const { return b_.sh_degree; }
  ScaleOffset scale_offset() const { return mode_; }
  void mean(std::size_t i, Scalar out[3]) const {
    for (int a = 0; a < 3; ++a) out[a] = b_.means[3 * i + a] + (dx_ ? dx_[3 * i + a] : Scalar(0));
  }
  void rotation(std::size_t i, Scalar out[4]) const {
    const Scalar* q = &b_.rotations[4 * i];
    const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    for (int a = 0; a < 4; ++a) out[a] = q[a] * inv + (dq_ ? dq_[4 * i + a] : Scalar(0));
  }
  void scale(std::size_t i, Scalar out[3]) const {
    for (int a = 0; a < 3; ++a) {
      const Scalar l = b_.log_scales[3 * i + a], d = ds_ ? ds_[3 * i + a] : Scalar(0);
      out[a] = mode_ == ScaleOffset::log ? std::exp(l + d) : std::exp(l) + d;
    }
  }
  Scalar opacity_logit(std::size_t i) const { return b_.opacity_logits[i]; }
  Scalar sh(std::size_t i, int k, int c) const { return b_.sh[(i * std::size_t(k_) + std::size_t(k)) * 3 + c]; }
  const Scalar* sh_data() const { return b_.sh.data(); }

  // Gradients w.r.t. this view (from project_scene_vjp) -> gradients w.r.t. the base
  // scene (means, rotations through normalize(q), log-scales through exp; opacity and
  // SH unchanged). `base_grad` may be the same object as `view_grad`. Empty arrays
  // (frozen groups never sized) are skipped.
  void base_gradients(const GaussianSceneGrad<Scalar>& view_grad, GaussianSceneGrad<Scalar>& base_grad) const {
    const std::size_t n = size();
    ensure(view_grad.scale_mode == ScaleMode::activated,
           "DeformedSceneView::base_gradients: the gradients are not w.r.t. this view's activated scales");
    if (&base_grad != &view_grad) base_grad = view_grad;
    base_grad.scale_mode = ScaleMode::log;
    if (base_grad.rotations.size() == 4 * n) {
      for (std::size_t i = 0; i < n; ++i) {
        const Scalar* q = &b_.rotations[4 * i];
        Scalar* v = &base_grad.rotations[4 * i];
        const Scalar inv = Scalar(1) / std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
        Scalar dot = 0;
        for (int a = 0; a < 4; ++a) dot += q[a] * inv * v[a];
        for (int a = 0; a < 4; ++a) v[a] = (v[a] - q[a] * inv * dot) * inv;
      }
    }
    if (base_grad.scales.size() == 3 * n)
      for (std::size_t j = 0; j < 3 * n; ++j) {
        // d s' / d log s = exp(log s), times exp(ds) for relative offsets (= s').
        const Scalar d = (mode_ == ScaleOffset::log && ds_) ? ds_[j] : Scalar(0);
        base_grad.scales[j] *= std::exp(b_.log_scales[j] + d);
      }
  }

  // Gradient w.r.t. the scale offsets from the gradient w.r.t. this view's
  // (activated) scales: v_ds = v_s' (additive) or v_s' s' (log). [3 x N].
  void scale_offset_gradients(const GaussianSceneGrad<Scalar>& view_grad, Scalar* v_ds) const {
    const std::size_t n = size();
    ensure(view_grad.scale_mode == ScaleMode::activated,
           "DeformedSceneView::scale_offset_gradients: the gradients are not w.r.t. this view's activated scales");
    ensure(view_grad.scales.size() == 3 * n, "DeformedSceneView: scale gradients for ",
           view_grad.scales.size() / 3, " Gaussians, the view has ", n);
    for (std::size_t j = 0; j < 3 * n; ++j)
      v_ds[j] = mode_ == ScaleOffset::log
                    ? view_grad.scales[j] * std::exp(b_.log_scales[j] + (ds_ ? ds_[j] : Scalar(0)))
                    : view_grad.scales[j];
  }

 private:
  const GaussianScene<Scalar>& b_;
  const Scalar *dx_, *dq_, *ds_;
  ScaleOffset mode_;
  std::size_t k_ = std::size_t(b_.sh_coefficients());
};

}  // namespace orbitforge

#pragma once
// A deforming iteration's forward and backward (Deformable 3D Gaussians): the
// field's offsets at the frame's time code, the deformed render and its loss,
// then the loss's gradient into the field's parameters (through its vjp) and
// into the canonical Gaussians (DeformedSceneView::base_gradients). The
// optimizer steps are the caller's.
#include <Eigen/Core>
#include <cstddef>
#include <vector>

#include "orbitforge/core/image.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/splat/gaussians.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/splat/scene_view.hpp"
#include "orbitforge/train/losses.hpp"
#include "orbitforge/train/train_progress.hpp"

namespace orbitforge {

template <class Scalar>
class DeformedPass {
 public:
  // `scene` deformed by `field` at time code t; the offsets live here until the next call.
  DeformedSceneView<Scalar> view(const GaussianScene<Scalar>& scene, const DeformationField<Scalar>& field, Scalar t,
                                 int threads) {
    const Eigen::Map<const Matrix3X<Scalar>> means(scene.means.data(), 3, Eigen::Index(scene.size()));
    field.evaluate(means, t, ws_, offsets_, threads);
    return DeformedSceneView<Scalar>(scene, offsets_.dx.data(), offsets_.dq.data(), offsets_.ds.data(),
                                     offsets_.scale_offset);
  }

  // Forward and backward at `camera` and time code t: the loss, loss(render, v_color)
  // -> LossTerms with its gradient w.r.t. the render in v_color; v_field() = d loss /
  // d field parameters, base_grad() = d loss / d canonical Gaussians. ms: field
  // (forward and vjp), render, loss and backward times.
  template <class LossFn>
  LossTerms<Scalar> forward_backward(const GaussianScene<Scalar>& scene, const DeformationField<Scalar>& field,
                                     Renderer<Scalar>& renderer, const Camera<Scalar>& camera, Scalar t,
                                     LossFn&& loss_fn, Image<Scalar>& v_color, int threads, double ms[4]) {
    LapTimer lap;
    const Eigen::Index n = Eigen::Index(scene.size());
    const DeformedSceneView<Scalar> dview = view(scene, field, t, threads);
    ms[0] = lap();
    const RenderOutput<Scalar>& out = renderer.render(dview, camera);
    ms[1] = lap();
    const LossTerms<Scalar> loss = loss_fn(out.color, v_color);
    ms[2] = lap();
    const GaussianSceneGrad<Scalar>& vg = renderer.backward(dview, camera, v_color);
    ms[3] = lap();
    // d loss / d offsets = the gradients w.r.t. the deformed view's parameters.
    v_offsets_.resize(n);
    v_offsets_.dx = Eigen::Map<const Matrix3X<Scalar>>(vg.means.data(), 3, n);
    v_offsets_.dq = Eigen::Map<const Matrix4X<Scalar>>(vg.rotations.data(), 4, n);
    dview.scale_offset_gradients(vg, v_offsets_.ds.data());
    v_field_.assign(field.parameter_count(), Scalar(0));
    field.evaluate_vjp(ws_, v_offsets_, v_field_.data(), nullptr, threads);
    dview.base_gradients(vg, base_grad_);
    ms[0] += lap();
    return loss;
  }

  const std::vector<Scalar>& v_field() const { return v_field_; }
  const GaussianSceneGrad<Scalar>& base_grad() const { return base_grad_; }

 private:
  typename DeformationField<Scalar>::Workspace ws_;
  DeformationOffsets<Scalar> offsets_, v_offsets_;
  std::vector<Scalar> v_field_;
  GaussianSceneGrad<Scalar> base_grad_;
};

}  // namespace orbitforge

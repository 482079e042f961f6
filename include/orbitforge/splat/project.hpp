#pragma once
// Projection of a whole scene: project_scene (any scene adaptor ->
// ProjectedSplats, through the SIMD batch path of splat/project_lanes.hpp) and
// project_scene_vjp (ProjectedSplatsGrad -> gradients in a GaussianSceneGrad, or
// in the caller's own arrays through a SceneGradView, splat/scene_grad_view.hpp).
// Conventions and culling rules: splat/project_gaussian.hpp. Including this
// header also gives SceneView and DeformedSceneView (splat/scene_view.hpp).
#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/splat/project_gaussian.hpp"
#include "orbitforge/splat/project_lanes.hpp"
#include "orbitforge/splat/project_lanes_vjp.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/splat/scene_grad_view.hpp"
#include "orbitforge/splat/scene_view.hpp"

namespace orbitforge {

// ---------------------------------------------------------------------------
// Projects every Gaussian of `scene` into `out` (resized to scene.size(); no
// reallocation when its capacity suffices). threads = 0: the default count.
template <class Scene>
void project_scene(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                   const ProjectionParams& params, ProjectedSplats<typename Scene::scalar_type>& out,
                   ProjectionStats* stats = nullptr, int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene: Scene is not a scene adaptor");
  using Scalar = typename Scene::scalar_type;
  const auto cam = ProjectionCamera<Scalar>::make(camera, params);
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();
  out.resize(n);
  const std::size_t chunk = std::max<std::size_t>(1, params.chunk);
  const std::size_t chunks = (n + chunk - 1) / chunk;
  std::atomic<std::size_t> counts[5] = {};
  parallel_for(chunks, threads, [&](std::size_t ci, int) {
    using B = simd::native_batch<Scalar>;
    constexpr std::size_t W = B::size;
    std::size_t local[5] = {0, 0, 0, 0, 0};
    detail::GaussianLanes<Scalar, int(W)> lanes{};
    const std::size_t end = std::min(n, (ci + 1) * chunk);
    constexpr std::size_t ahead = 4 * W;  // prefetch distance (adaptors that offer it)
    for (std::size_t i = ci * chunk; i < end; i += W) {
      if constexpr (adaptor_detail::has_prefetch<Scene>::value)
        if (i + ahead < n) scene.prefetch(i + ahead, std::min(W, n - (i + ahead)));
      detail::project_lanes<B>(scene, cam, degree, i, int(std::min(W, end - i)), lanes, out, local);
    }
    for (int r = 0; r < 5; ++r)
      if (local[r]) counts[r].fetch_add(local[r], std::memory_order_relaxed);
  });
  if (stats) {
    stats->visible = counts[0].load();
    stats->culled_near = counts[1].load();
    stats->culled_outside = counts[2].load();
    stats->culled_faint = counts[3].load();
    stats->culled_nonfinite = counts[4].load();
  }
}

namespace detail {
// The VJP of project_scene into a gradient view. `freeze` says which groups are
// computed (derived from the view's null fields, plus the SH dc/rest split of
// GaussianSceneGrad's Freeze).
template <class Scene>
void project_scene_vjp_into(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                            const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                            const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                            const SceneGradView<typename Scene::scalar_type>& out, const Freeze& freeze,
                            int threads) {
  using Scalar = typename Scene::scalar_type;
  const auto cam = ProjectionCamera<Scalar>::make(camera, params);
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene_vjp: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();
  const int k_count = sh_coefficient_count(degree);
  ensure(fwd.size() == n, "project_scene_vjp: forward result has ", fwd.size(), " Gaussians, scene has ", n);
  ensure(out.size == n, "project_scene_vjp: the gradient view is for ", out.size, " Gaussians, the scene has ", n);
  check_grad_view(out);
  for (const auto* v : {&v_in.v_mean_x, &v_in.v_mean_y, &v_in.v_conic_a, &v_in.v_conic_b, &v_in.v_conic_c,
                        &v_in.v_opacity, &v_in.v_color_r, &v_in.v_color_g, &v_in.v_color_b, &v_in.v_depth})
    ensure(v->size() == n, "project_scene_vjp: a ProjectedSplatsGrad array has ", v->size(), " entries, expected ",
           n);
  detail::GradWanted want;
  want.mean = !freeze.means;
  want.cov3 = !(freeze.rotations && freeze.scales);
  want.sh = !(freeze.sh_dc && freeze.sh_rest);
  // Within the view's extent: the adaptor's coefficients, then zeros for those
  // the host holds beyond them.
  const int extent = out.sh ? out.sh_coefficients : 0;
  want.sh_first = freeze.sh_dc ? 1 : 0;
  want.sh_end = std::min(freeze.sh_rest ? 1 : k_count, extent);
  want.sh_zero_end = freeze.sh_rest ? want.sh_end : std::max(want.sh_end, extent);

  const std::size_t chunk = std::max<std::size_t>(1, params.chunk);
  const std::size_t chunks = (n + chunk - 1) / chunk;
  parallel_for(chunks, threads, [&](std::size_t ci, int) {
    using B = simd::native_batch<Scalar>;
    constexpr std::size_t W = B::size;
    detail::GaussianLanes<Scalar, int(W)> lanes{};
    detail::GradLanes<Scalar, int(W)> grads;
    const std::size_t end = std::min(n, (ci + 1) * chunk);
    constexpr std::size_t ahead = 4 * W;  // prefetch distance (adaptors that offer it)
    for (std::size_t i = ci * chunk; i < end; i += W) {
      if constexpr (adaptor_detail::has_prefetch<Scene>::value)
        if (i + ahead < n) scene.prefetch(i + ahead, std::min(W, n - (i + ahead)));
      detail::project_lanes_vjp<B>(scene, cam, degree, i, int(std::min(W, end - i)), fwd, v_in, out, freeze, want,
                                   lanes, grads);
    }
  });
}
}  // namespace detail

// Gradients into the caller's storage (splat/scene_grad_view.hpp), in the
// parametrisation the view asks for, given the forward result `fwd` (same scene,
// camera and params) and the rasterizer's gradients `v_in`.
template <class Scene>
void project_scene_vjp(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                       const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                       const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                       const SceneGradView<typename Scene::scalar_type>& out, int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene_vjp: Scene is not a scene adaptor");
  Freeze freeze;
  freeze.means = !out.means;
  freeze.rotations = !out.rotations;
  freeze.scales = !out.scales && !out.log_scales;
  freeze.opacities = !out.opacity_logits;  // d/d opacity needs no work
  freeze.sh_dc = freeze.sh_rest = !out.sh;
  detail::project_scene_vjp_into(scene, camera, params, fwd, v_in, out, freeze, threads);
}

// Gradients w.r.t. the scene parameters as the adaptor exposes them, into a
// GaussianSceneGrad (scales holds d/d log s for ScaleMode::log adaptors and d/d s
// for activated ones; out.scale_mode records which). Non-frozen groups of `out`
// are overwritten (zero for culled Gaussians); frozen groups are never written
// (see Freeze), only sized. screen_grad_norm and screen_grad_ndc_norm are always
// written.
template <class Scene>
void project_scene_vjp(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                       const ProjectionParams& params, const ProjectedSplats<typename Scene::scalar_type>& fwd,
                       const ProjectedSplatsGrad<typename Scene::scalar_type>& v_in,
                       GaussianSceneGrad<typename Scene::scalar_type>& out, const Freeze& freeze = {},
                       int threads = 0) {
  static_assert(check_scene_adaptor<Scene>(), "project_scene_vjp: Scene is not a scene adaptor");
  using Scalar = typename Scene::scalar_type;
  const int degree = scene.sh_degree();
  ensure(degree >= 0 && degree <= 3, "project_scene_vjp: SH degree must be 0..3, got ", degree);
  const std::size_t n = scene.size();  // the forward result and v_in are checked against it below
  const std::size_t sh_size = 3 * std::size_t(sh_coefficient_count(degree)) * n;
  auto prepare = [](std::vector<Scalar>& v, std::size_t size, bool frozen) {
    if (!frozen)
      v.resize(size);
    else if (v.size() != size)
      v.assign(size, Scalar(0));
  };
  out.sh_degree = degree;
  out.scale_mode = Scene::scale_mode;
  prepare(out.means, 3 * n, freeze.means);
  prepare(out.rotations, 4 * n, freeze.rotations);
  prepare(out.scales, 3 * n, freeze.scales);
  prepare(out.opacity_logits, n, freeze.opacities);
  prepare(out.sh, sh_size, freeze.sh_dc && freeze.sh_rest);
  if (out.sh.size() != sh_size) out.sh.assign(sh_size, Scalar(0));
  out.screen_grad_norm.resize(n);
  out.screen_grad_ndc_norm.resize(n);

  const std::ptrdiff_t s1 = sizeof(Scalar);
  SceneGradView<Scalar> view;
  view.size = n;
  if (!freeze.means) view.means = strided(out.means.data(), 3 * s1);
  if (!freeze.rotations) view.rotations = strided(out.rotations.data(), 4 * s1);
  if (!freeze.scales)
    (Scene::scale_mode == ScaleMode::log ? view.log_scales : view.scales) = strided(out.scales.data(), 3 * s1);
  if (!freeze.opacities) view.opacity_logits = strided(out.opacity_logits.data(), s1);
  if (!(freeze.sh_dc && freeze.sh_rest)) {
    view.sh = strided(out.sh.data(), 3 * std::ptrdiff_t(sh_coefficient_count(degree)) * s1);
    view.sh_coefficients = sh_coefficient_count(degree);
  }
  view.screen_grad_norm = strided(out.screen_grad_norm.data(), s1);
  view.screen_grad_ndc_norm = strided(out.screen_grad_ndc_norm.data(), s1);
  detail::project_scene_vjp_into(scene, camera, params, fwd, v_in, view, freeze, threads);
}

}  // namespace orbitforge

#pragma once
// The whole renderer: project (EWA + SH colour, splat/project.hpp) -> bin (depth
// sort + tile lists) -> rasterize, and the backward pass in reverse:
// rasterize_vjp -> project_scene_vjp.
//
//   Renderer<float> r(params);
//   const RenderOutput<float>& img = r.render(SceneView<float>(scene), camera);
//   const GaussianSceneGrad<float>& g = r.backward(SceneView<float>(scene), camera, v_color);
//   r.backward(host_adaptor, camera, v_color, host_grad_view);  // into the host's arrays
//
// A Renderer owns every buffer of a frame and reuses them, so rendering frames of
// one size allocates nothing after the first. backward() differentiates the last
// render() and must be given the same scene and camera. It is a method named
// backward, not a free *_vjp function like its stages, because it replays the
// state the last render() recorded (projection, bins, saved transmittance)
// rather than computing from its arguments.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <sstream>
#include <string>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/splat/bin.hpp"
#include "orbitforge/splat/project.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/rasterize.hpp"
#include "orbitforge/splat/rasterize_vjp.hpp"
#include "orbitforge/splat/scene_grad.hpp"

namespace orbitforge {

template <class Scalar>
struct RenderParams {
  std::array<Scalar, 3> background{{0, 0, 0}};
  int threads = 0;              // 0 = default (all hardware threads)
  double near_plane = 0.01;     // cull Gaussians with camera-space z <= near_plane
  int tile_size = 16;           // pixels per tile side (the image does not depend on it)
  bool tight_extents = true;    // opacity-aware rects (never change the image)
  bool background_gradient = true;  // backward() computes background_gradient() (RasterParams)
};

struct RenderStats {
  double project_ms = 0, sort_ms = 0, bin_ms = 0, raster_ms = 0, total_ms = 0;
  double backward_raster_ms = 0, backward_project_ms = 0;  // of the last backward()
  std::size_t gaussians_visible = 0;  // binned (projected and not culled)
  std::size_t tile_entries = 0;       // (tile, Gaussian) pairs
  std::uint64_t pairs_evaluated = 0, contributions = 0;
  int threads = 1;
  ProjectionStats projection;
};

// Share of a scene's Gaussians skipped as non-finite above which programs warn
// (nonfinite_warning); a render that skips every one is an error.
inline constexpr double kNonfiniteWarnShare = 0.01;

// A warning line when more than kNonfiniteWarnShare of the Gaussians a render saw
// were skipped as non-finite; empty otherwise.
inline std::string nonfinite_warning(const RenderStats& s) {
  const std::size_t n = s.projection.total(), bad = s.projection.culled_nonfinite;
  if (n == 0 || !(double(bad) > kNonfiniteWarnShare * double(n))) return {};
  std::ostringstream os;
  os.precision(3);
  os << bad << " of " << n << " Gaussians (" << 100.0 * double(bad) / double(n)
     << " %) were skipped as non-finite (NaN or infinite parameters, a zero quaternion or a degenerate "
        "covariance); the image lacks them";
  return os.str();
}

// Share of a scene's Gaussians culled by the near plane above which programs warn
// (near_cull_warning): beyond the share a camera inside a room leaves behind it,
// so most likely a near plane too far for the scene's scale.
inline constexpr double kNearCullWarnShare = 0.9;

// A warning line when more than kNearCullWarnShare of the Gaussians a render saw
// were culled at or behind the near plane; empty otherwise.
inline std::string near_cull_warning(const RenderStats& s, double near_plane) {
  const std::size_t n = s.projection.total(), culled = s.projection.culled_near;
  if (n == 0 || !(double(culled) > kNearCullWarnShare * double(n))) return {};
  std::ostringstream os;
  os.precision(3);
  os << culled << " of " << n << " Gaussians (" << 100.0 * double(culled) / double(n)
     << " %) were culled by the near plane at camera-space depth " << near_plane
     << ": behind the camera, or the near plane is too far for the scene's scale; the image lacks them";
  return os.str();
}

// Bytes per pixel of a frame: the renderer's outputs (colour x3, transmittance and
// depth in Scalar; blend count and backward replay length in int32), plus 6 for
// the 8-bit copy and encoder of a caller writing a PNG. 34 for float: as measured
// (render_orbit's peak RSS grows by 34.1 bytes per added pixel from an empty
// 2000x2000 frame to an empty 4000x4000 one).
inline std::uint64_t frame_bytes_per_pixel(std::size_t scalar_bytes) { return 5 * scalar_bytes + 8 + 6; }

// The memory of a width x height frame before its tile lists (whose length depends
// on the scene; bin_splats checks them once counted): per pixel as above, per tile
// the list offsets, each thread's counts and the backward's list ends. Saturates
// instead of overflowing.
inline std::uint64_t frame_memory_estimate(std::uint64_t width, std::uint64_t height, int tile_size, int threads,
                                           std::size_t scalar_bytes) {
  const std::uint64_t ts = std::uint64_t(std::max(1, tile_size)), bpp = frame_bytes_per_pixel(scalar_bytes);
  const std::uint64_t tiles = ((width + ts - 1) / ts) * ((height + ts - 1) / ts);
  const std::uint64_t per_tile = 4 * std::uint64_t(std::max(1, threads)) + 8;
  if (width != 0 && height > UINT64_MAX / width / (bpp + per_tile)) return UINT64_MAX;
  return width * height * bpp + tiles * per_tile;
}

// Refuses a frame over the limits (orbitforge/core/limits.hpp) before anything is
// allocated: pixel count, the rasterizer's side limit, estimated memory.
inline void check_frame_size(int width, int height, int tile_size, int threads, std::size_t scalar_bytes) {
  ensure(width > 0 && height > 0, "Renderer::render: the camera's image size is ", width, "x", height);
  const std::uint64_t pixels = std::uint64_t(width) * std::uint64_t(height);
  const std::uint64_t bytes = frame_memory_estimate(std::uint64_t(width), std::uint64_t(height), tile_size, threads,
                                                    scalar_bytes);
  const std::uint64_t max_pixels = limits().max_image_pixels;
  ensure(pixels <= max_pixels, "Renderer::render: a ", width, "x", height, " frame (", pixels, " pixels, about ",
         format_bytes(bytes), " at ", frame_bytes_per_pixel(scalar_bytes), " bytes per pixel) is over the limit of ",
         max_pixels,
         " pixels (orbitforge::Limits::max_image_pixels; raise it with set_limits or ORBITFORGE_MAX_IMAGE_PIXELS)");
  // Pixel positions are float lanes in the rasterizer (rasterize.hpp).
  ensure(width < (1 << 23) && height < (1 << 23), "Renderer::render: a ", width, "x", height,
         " frame; the rasterizer takes sides under 8388608 pixels");
  check_memory_request(bytes, "Renderer::render: a ", width, "x", height, " frame (", pixels, " pixels at ",
                       frame_bytes_per_pixel(scalar_bytes), " bytes, plus per-tile arrays)");
}

template <class Scalar>
struct RenderOutput : RasterOutput<Scalar> {
  // RasterOutput: color [H][W][3], transmittance [H][W][1] (alpha = 1 - T),
  // depth [H][W][1] (unnormalised), count [H][W][1], stats (rasterizer only).
  RenderStats frame;
};

template <class Scalar>
class Renderer {
 public:
  explicit Renderer(const RenderParams<Scalar>& params = {}) : params_(params) {}

  RenderParams<Scalar>& params() { return params_; }
  const RenderParams<Scalar>& params() const { return params_; }

  template <class Scene>
  const RenderOutput<Scalar>& render(const Scene& scene, const Camera<Scalar>& camera) {
    static_assert(check_scene_adaptor<Scene>(), "Renderer::render: Scene is not a scene adaptor");
    static_assert(std::is_same<typename Scene::scalar_type, Scalar>::value, "Renderer: scene of the wrong precision");
    const auto t0 = clock::now();
    const int threads = resolve_threads(params_.threads, "RenderParams::threads");
    const int width = camera.intrinsics.width, height = camera.intrinsics.height;
    check_frame_size(width, height, params_.tile_size, threads, sizeof(Scalar));
    const ProjectionParams pp = projection_params();
    out_.frame = {};
    rendered_ = false;
    auto t1 = t0;
    with_memory_context(
        [&] {
          project_scene(scene, camera, pp, splats_, &out_.frame.projection, threads);
          t1 = clock::now();
          // A blank image with no complaint would hide a diverged or damaged scene.
          ensure(scene.size() == 0 || out_.frame.projection.culled_nonfinite < scene.size(),
                 "Renderer::render: all ", scene.size(),
                 " Gaussians of the scene were skipped as non-finite (NaN or infinite parameters, a zero "
                 "quaternion or a degenerate covariance); nothing to render");
          bin_splats(splats_, width, height, params_.tile_size, bins_, threads);
          rasterize(bins_, raster_params(threads), static_cast<RasterOutput<Scalar>&>(out_), ws_);
        },
        frame_memory_estimate(std::uint64_t(width), std::uint64_t(height), params_.tile_size, threads,
                              sizeof(Scalar)),
        "rendering a ", width, "x", height, " frame of ", scene.size(), " Gaussians");
    const auto t2 = clock::now();
    RenderStats& st = out_.frame;
    st.project_ms = ms(t0, t1);
    st.sort_ms = bins_.sort_ms;
    st.bin_ms = bins_.bin_ms;
    st.raster_ms = out_.stats.ms;
    st.total_ms = ms(t0, t2);
    st.gaussians_visible = bins_.visible();
    st.tile_entries = bins_.pairs();
    st.pairs_evaluated = out_.stats.pairs_evaluated;
    st.contributions = out_.stats.contributions;
    st.threads = threads;
    rendered_ = true;
    camera_ = camera;
    scene_size_ = scene.size();
    return out_;
  }

  // Gradients of a loss w.r.t. the scene parameters (as the adaptor exposes them)
  // given dL/d(colour) [H][W][3] and optionally dL/d(alpha) and dL/d(depth)
  // [H][W][1] of the last render(). Frozen groups are not computed (see Freeze).
  template <class Scene>
  const GaussianSceneGrad<Scalar>& backward(const Scene& scene, const Camera<Scalar>& camera,
                                            const Image<Scalar>& v_color,
                                            const detail::identity_t<Image<Scalar>>* v_alpha = nullptr,
                                            const detail::identity_t<Image<Scalar>>* v_depth = nullptr,
                                            const Freeze& freeze = {}) {
    static_assert(check_scene_adaptor<Scene>(), "Renderer::backward: Scene is not a scene adaptor");
    const int threads = backward_raster(scene, camera, v_color, v_alpha, v_depth);
    const auto t1 = clock::now();
    project_scene_vjp(scene, camera, projection_params(), splats_, raster_grad_.splats, grad_, freeze, threads);
    out_.frame.backward_project_ms = ms(t1, clock::now());
    return grad_;
  }

  // The same, written into the caller's own arrays in the parametrisation `out`
  // asks for (splat/scene_grad_view.hpp); gradients() is left as it was.
  template <class Scene>
  void backward(const Scene& scene, const Camera<Scalar>& camera, const Image<Scalar>& v_color,
                const SceneGradView<Scalar>& out, const detail::identity_t<Image<Scalar>>* v_alpha = nullptr,
                const detail::identity_t<Image<Scalar>>* v_depth = nullptr) {
    static_assert(check_scene_adaptor<Scene>(), "Renderer::backward: Scene is not a scene adaptor");
    const int threads = backward_raster(scene, camera, v_color, v_alpha, v_depth);
    const auto t1 = clock::now();
    project_scene_vjp(scene, camera, projection_params(), splats_, raster_grad_.splats, out, threads);
    out_.frame.backward_project_ms = ms(t1, clock::now());
  }

  const RenderOutput<Scalar>& output() const { return out_; }
  const GaussianSceneGrad<Scalar>& gradients() const { return grad_; }
  const ProjectedSplats<Scalar>& projected() const { return splats_; }
  const ProjectedSplatsGrad<Scalar>& projected_gradients() const { return raster_grad_.splats; }
  const std::array<Scalar, 3>& background_gradient() const { return raster_grad_.v_background; }
  const BinWorkspace<Scalar>& bins() const { return bins_; }

 private:
  using clock = std::chrono::steady_clock;

  // Checks that backward() follows a render() of this scene and camera, runs the
  // rasterizer's backward pass and returns the thread count.
  template <class Scene>
  int backward_raster(const Scene& scene, const Camera<Scalar>& camera, const Image<Scalar>& v_color,
                      const Image<Scalar>* v_alpha, const Image<Scalar>* v_depth) {
    ensure(rendered_, "Renderer::backward: call render() first");
    ensure(scene.size() == scene_size_, "Renderer::backward: scene has ", scene.size(),
           " Gaussians, the last render had ", scene_size_);
    ensure(camera.R == camera_.R && camera.t == camera_.t && camera.intrinsics.fx == camera_.intrinsics.fx &&
               camera.intrinsics.width == camera_.intrinsics.width &&
               camera.intrinsics.height == camera_.intrinsics.height,
           "Renderer::backward: camera differs from the last render()");
    const auto t0 = clock::now();
    const int threads = resolve_threads(params_.threads, "RenderParams::threads");
    rasterize_vjp(bins_, raster_params(threads), static_cast<const RasterOutput<Scalar>&>(out_), v_color,
                       v_alpha, v_depth, splats_.size(), raster_grad_, ws_);
    out_.frame.backward_raster_ms = ms(t0, clock::now());
    return threads;
  }

  ProjectionParams projection_params() const {
    ProjectionParams pp;
    pp.near_plane = params_.near_plane;
    pp.tight_extents = params_.tight_extents;
    pp.alpha_min = double(RasterRules<Scalar>::min_alpha());
    return pp;
  }
  RasterParams<Scalar> raster_params(int threads) const {
    RasterParams<Scalar> rp;
    rp.background = params_.background;
    rp.threads = threads;
    rp.background_gradient = params_.background_gradient;
    return rp;
  }
  template <class T>
  static double ms(T a, T b) { return std::chrono::duration<double, std::milli>(b - a).count(); }

  RenderParams<Scalar> params_;
  ProjectedSplats<Scalar> splats_;
  BinWorkspace<Scalar> bins_;
  RasterWorkspace<Scalar> ws_;
  RenderOutput<Scalar> out_;
  RasterGradOutput<Scalar> raster_grad_;
  GaussianSceneGrad<Scalar> grad_;
  Camera<Scalar> camera_;
  std::size_t scene_size_ = 0;
  bool rendered_ = false;
};

// One-shot convenience (allocates; use a Renderer for sequences of frames).
template <class Scene>
RenderOutput<typename Scene::scalar_type> render(const Scene& scene, const Camera<typename Scene::scalar_type>& camera,
                                                 const RenderParams<typename Scene::scalar_type>& params = {}) {
  Renderer<typename Scene::scalar_type> r(params);
  return r.render(scene, camera);
}

}  // namespace orbitforge

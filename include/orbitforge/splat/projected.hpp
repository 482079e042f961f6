#pragma once
// The hand-over between the per-Gaussian stages (projection + SH colour, see
// project.hpp) and the per-pixel stages (binning + rasterization): one entry per
// input Gaussian, structure of arrays so the rasterizer streams through it.
//
// A Gaussian that projection culls has radius 0 and is ignored downstream; its
// other fields are unspecified. For a kept Gaussian, pixel centre (px, py) gets
//   power = -0.5 (a dx^2 + c dy^2) - b dx dy,  dx = px - mean_x, dy = py - mean_y
//   alpha = min(0.99, opacity * exp(power))
// and only pixels whose centres lie in the rectangle [rect_x0, rect_x1] x
// [rect_y0, rect_y1] (inclusive pixel indices, already clipped to the image) are
// evaluated. That rectangle is the 3-sigma square |px - mean_x| <= radius,
// |py - mean_y| <= radius, optionally tightened to where alpha can reach 1/255;
// tightening never changes the image.
#include <cstdint>
#include <vector>

namespace orbitforge {

template <class Scalar>
struct ProjectedSplats {
  std::vector<Scalar> mean_x, mean_y;        // pixel coordinates of the projected mean
  std::vector<Scalar> conic_a, conic_b, conic_c;  // inverse 2D covariance [[a, b], [b, c]]
  std::vector<Scalar> opacity;               // activated opacity in [0, 1]
  std::vector<Scalar> color_r, color_g, color_b;  // SH colour + 0.5, clamped at 0
  std::vector<Scalar> depth;                 // camera-space z (> near plane)
  std::vector<std::int32_t> radius;          // 3-sigma pixel radius; 0 = culled
  std::vector<std::int32_t> rect_x0, rect_y0, rect_x1, rect_y1;

  std::size_t size() const { return radius.size(); }
  void resize(std::size_t n) {
    for (auto* v : {&mean_x, &mean_y, &conic_a, &conic_b, &conic_c, &opacity, &color_r, &color_g, &color_b, &depth})
      v->resize(n);
    for (auto* v : {&radius, &rect_x0, &rect_y0, &rect_x1, &rect_y1}) v->resize(n);
  }
};

// Gradients of a loss with respect to the ProjectedSplats fields, as the
// rasterizer's backward pass produces them (same indexing; zero for culled).
template <class Scalar>
struct ProjectedSplatsGrad {
  std::vector<Scalar> v_mean_x, v_mean_y;
  std::vector<Scalar> v_conic_a, v_conic_b, v_conic_c;
  std::vector<Scalar> v_opacity;
  std::vector<Scalar> v_color_r, v_color_g, v_color_b;
  std::vector<Scalar> v_depth;

  void assign_zero(std::size_t n) {
    for (auto* v : {&v_mean_x, &v_mean_y, &v_conic_a, &v_conic_b, &v_conic_c, &v_opacity, &v_color_r, &v_color_g,
                    &v_color_b, &v_depth})
      v->assign(n, Scalar(0));
  }
};

}  // namespace orbitforge

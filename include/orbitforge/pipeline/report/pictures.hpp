#pragma once
// Pictures of a pipeline run, drawn into Image<float> (RGB, [0, 1]) and written
// as PNG: a contact sheet of R0 and R1 at 30-degree steps, the support mask on
// the orbit circle, and a top view of the source cameras with the fitted orbit.
#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include "orbitforge/core/image.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/image_io.hpp"

namespace orbitforge {

namespace pictures_detail {

inline void put(Image<float>& img, int x, int y, const std::array<float, 3>& c) {
  if (x < 0 || y < 0 || x >= img.width || y >= img.height) return;
  for (int k = 0; k < 3; ++k) img(x, y, k) = c[std::size_t(k)];
}

inline void disk(Image<float>& img, double cx, double cy, double r, const std::array<float, 3>& c) {
  for (int y = int(std::floor(cy - r)); y <= int(std::ceil(cy + r)); ++y)
    for (int x = int(std::floor(cx - r)); x <= int(std::ceil(cx + r)); ++x)
      if ((x - cx) * (x - cx) + (y - cy) * (y - cy) <= r * r) put(img, x, y, c);
}

inline void line(Image<float>& img, double x0, double y0, double x1, double y1, const std::array<float, 3>& c) {
  const int n = int(std::ceil(std::max(std::abs(x1 - x0), std::abs(y1 - y0)))) + 1;
  for (int i = 0; i <= n; ++i) {
    const double t = double(i) / n;
    put(img, int(std::lround(x0 + t * (x1 - x0))), int(std::lround(y0 + t * (y1 - y0))), c);
  }
}

constexpr std::array<float, 3> kWhite{{1, 1, 1}}, kGray{{0.55f, 0.55f, 0.55f}}, kGreen{{0.2f, 0.8f, 0.3f}},
    kBlue{{0.3f, 0.5f, 0.95f}}, kRed{{0.9f, 0.25f, 0.2f}}, kYellow{{0.95f, 0.8f, 0.2f}};

}  // namespace pictures_detail

// Rows = sequences (e.g. R0, R1), columns = 0, 30, ..., 330 degrees along the orbit.
// `frame(row, view)` returns that row's image of canonical view `view`, or an empty
// image when not rendered (the nearest rendered view is the caller's business).
// Cells are cell_width x cell_height: give them the frames' aspect, so that
// non-square frames fill their cells.
inline Image<float> contact_sheet(int rows, int views, int cell_width, int cell_height,
                                  const std::function<Image<float>(int, int)>& frame) {
  ensure(rows >= 1 && views >= 2 && cell_width >= 1 && cell_height >= 1, "contact_sheet: ", rows, " rows, ", views,
         " views, cells ", cell_width, "x", cell_height);
  const int cols = 12, pad = 2;
  Image<float> sheet(cols * (cell_width + pad) + pad, rows * (cell_height + pad) + pad, 3, 0.1f);
  for (int r = 0; r < rows; ++r) {
    for (int c = 0; c < cols; ++c) {
      const int view = int(std::lround(double(c) * 30.0 / 360.0 * double(views - 1)));
      Image<float> img = frame(r, view);
      if (img.empty()) continue;
      img = resize_image(to_rgb(img), cell_width, cell_height, ResizeFilter::area);
      const int x0 = pad + c * (cell_width + pad), y0 = pad + r * (cell_height + pad);
      for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x)
          for (int k = 0; k < 3; ++k) sheet(x0 + x, y0 + y, k) = std::min(1.0f, std::max(0.0f, img(x, y, k)));
    }
  }
  return sheet;
}

// The canonical views on a circle (view 0 at the top, in the orbit's direction,
// clockwise on screen): green = observed by a source camera (S_obs), blue = in
// the first reconstruction's arc S_arc only, red = the completion gap U_gap.
inline Image<float> support_mask_picture(const SupportBins& s, int size = 320) {
  using namespace pictures_detail;
  Image<float> img(size, size, 3, 0.08f);
  std::vector<char> obs(std::size_t(s.views), 0);
  for (int b : s.observed) obs[std::size_t(b)] = 1;
  const double c = size / 2.0, R = size * 0.4;
  const double dot = std::max(1.5, std::min(6.0, 2.8 * R / std::max(1, s.views - 1)));
  for (int v = 0; v < s.views - 1; ++v) {
    const double a = 2 * 3.14159265358979 * v / double(s.views - 1);
    const auto& col = obs[std::size_t(v)] ? kGreen : (s.in_arc(v) ? kBlue : kRed);
    disk(img, c + R * std::sin(a), c - R * std::cos(a), dot, col);
  }
  line(img, c, c - R - 3 * dot, c, c - R + 3 * dot, kWhite);  // view 0
  return img;
}

// Top view in the orbit plane's (e1, e2) frame: the fitted circle (gray), canonical
// view 0 (white tick), the look-at point (white cross), the source camera centres
// (yellow, with their viewing direction) and the other recorded cameras (blue).
template <class Scalar>
Image<float> top_view_picture(const OrbitFit<Scalar>& fit, const std::vector<Camera<Scalar>>& source,
                              const std::vector<Camera<Scalar>>& others, int size = 480) {
  using namespace pictures_detail;
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  const auto& g = fit.orbit;
  auto uv = [&](const Vec3& p) {
    const Vec3 d = p - g.center;
    return std::array<double, 2>{{double(d.dot(g.e1)), double(d.dot(g.e2))}};
  };
  double extent = double(g.radius);
  for (const auto* list : {&source, &others})
    for (const auto& c : *list) {
      const auto q = uv(c.center());
      extent = std::max({extent, std::abs(q[0]), std::abs(q[1])});
    }
  ensure(extent > 0 && std::isfinite(extent), "top_view_picture: degenerate orbit");
  const double scale = size * 0.44 / extent, c0 = size / 2.0;
  auto px = [&](const std::array<double, 2>& q) {
    return std::array<double, 2>{{c0 + q[0] * scale, c0 - q[1] * scale}};
  };
  Image<float> img(size, size, 3, 0.08f);
  for (int i = 0; i < 720; ++i) {
    const double a = 2 * 3.14159265358979 * i / 720.0;
    const auto p = px({{double(g.radius) * std::cos(a), double(g.radius) * std::sin(a)}});
    put(img, int(std::lround(p[0])), int(std::lround(p[1])), kGray);
  }
  if (!fit.cameras.empty()) {
    const auto p = px(uv(fit.cameras.front().center()));
    disk(img, p[0], p[1], 5, kWhite);
  }
  const auto la = px(uv(g.look_at));
  line(img, la[0] - 6, la[1], la[0] + 6, la[1], kWhite);
  line(img, la[0], la[1] - 6, la[0], la[1] + 6, kWhite);
  auto draw_cam = [&](const Camera<Scalar>& c, const std::array<float, 3>& col) {
    const auto p = px(uv(c.center()));
    const Vec3 f = c.R.row(2).transpose();  // OpenCV forward axis in world coordinates
    const double fu = double(f.dot(g.e1)), fv = double(f.dot(g.e2));
    line(img, p[0], p[1], p[0] + 14 * fu, p[1] - 14 * fv, col);
    disk(img, p[0], p[1], 2.5, col);
  };
  for (const auto& c : others) draw_cam(c, kBlue);
  for (const auto& c : source) draw_cam(c, kYellow);
  return img;
}

}  // namespace orbitforge

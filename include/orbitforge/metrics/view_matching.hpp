#pragma once
// Which reference view each frame of a video shows, from the pixels alone.
//
// A video model asked for a turn around the scene may stall, turn back or skip
// ahead; the cameras it was asked for cannot say so. Each frame and each
// reference (R0's render at a canonical view) is reduced to a grid x grid
// thumbnail (box averages, so small misalignments and noise matter little), and
// the frame takes the position of the reference with the least mean absolute
// difference. temporal_trace() of those positions then reports the turns,
// stalls and reversals the frames actually show.
#include <algorithm>
#include <cmath>
#include <limits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"

namespace orbitforge {

// Box-averaged grid x grid thumbnail of an RGB(A) image (first three channels).
template <class T>
std::vector<double> thumbnail(const Image<T>& img, int grid) {
  ensure(grid >= 1, "thumbnail: grid must be >= 1, got ", grid);
  ensure(img.width >= 1 && img.height >= 1 && img.channels >= 3, "thumbnail: need an RGB image, got ", img.width,
         "x", img.height, "x", img.channels);
  std::vector<double> sum(std::size_t(grid) * grid * 3, 0.0), count(std::size_t(grid) * grid, 0.0);
  for (int y = 0; y < img.height; ++y) {
    const int gy = int(std::int64_t(y) * grid / img.height);
    for (int x = 0; x < img.width; ++x) {
      const int gx = int(std::int64_t(x) * grid / img.width);
      const std::size_t cell = std::size_t(gy) * grid + gx;
      const T* px = &img.data[(std::size_t(y) * img.width + x) * img.channels];
      for (int c = 0; c < 3; ++c) sum[cell * 3 + c] += double(px[c]);
      count[cell] += 1;
    }
  }
  for (std::size_t cell = 0; cell < count.size(); ++cell)
    for (int c = 0; c < 3; ++c) sum[cell * 3 + c] /= std::max(1.0, count[cell]);
  return sum;
}

// The largest centred crop of `img` with aspect ratio `aspect` (width / height).
// Two views from one place whose focal lengths (in pixels) are in proportion to
// their heights, as the canonical views' are to the source frames', show the
// same field of view once both are cropped to the narrower aspect.
template <class T>
Image<T> centre_crop_to_aspect(const Image<T>& img, double aspect) {
  ensure(aspect > 0 && std::isfinite(aspect), "centre_crop_to_aspect: aspect must be positive, got ", aspect);
  ensure(img.width >= 1 && img.height >= 1, "centre_crop_to_aspect: empty image");
  const int w = std::max(1, std::min(img.width, int(std::lround(img.height * aspect))));
  const int h = std::max(1, std::min(img.height, int(std::lround(img.width / aspect))));
  if (w == img.width && h == img.height) return img;
  Image<T> out(w, h, img.channels);
  const int x0 = (img.width - w) / 2, y0 = (img.height - h) / 2;
  const std::size_t row = std::size_t(w) * std::size_t(img.channels);
  for (int y = 0; y < h; ++y)
    std::copy_n(&img.data[(std::size_t(y0 + y) * img.width + x0) * img.channels], row,
                &out.data[std::size_t(y) * row]);
  return out;
}

struct ViewMatch {
  std::vector<double> positions;   // per frame: the best reference's position
  std::vector<double> distances;   // per frame: its mean absolute thumbnail difference
};

// For every frame thumbnail, the position of the reference thumbnail it matches best.
inline ViewMatch match_views(const std::vector<std::vector<double>>& frames,
                             const std::vector<std::vector<double>>& references,
                             const std::vector<double>& reference_positions) {
  ensure(references.size() == reference_positions.size(), "match_views: ", references.size(), " references but ",
         reference_positions.size(), " positions");
  ensure(!references.empty() || frames.empty(), "match_views: no references to match ", frames.size(), " frames to");
  ViewMatch m;
  for (const auto& t : frames) {
    double best = std::numeric_limits<double>::infinity();
    std::size_t best_k = 0;
    for (std::size_t k = 0; k < references.size(); ++k) {
      ensure(references[k].size() == t.size(), "match_views: thumbnails of different sizes");
      double d = 0;
      for (std::size_t i = 0; i < t.size(); ++i) d += std::abs(t[i] - references[k][i]);
      if (d < best) {
        best = d;
        best_k = k;
      }
    }
    m.positions.push_back(reference_positions[best_k]);
    m.distances.push_back(best / double(std::max<std::size_t>(1, t.size())));
  }
  return m;
}

// The same from images (thumbnails of grid x grid cells).
template <class T>
ViewMatch match_views(const std::vector<Image<T>>& frames, const std::vector<Image<T>>& references,
                      const std::vector<double>& reference_positions, int grid = 24) {
  std::vector<std::vector<double>> f, r;
  for (const auto& x : frames) f.push_back(thumbnail(x, grid));
  for (const auto& x : references) r.push_back(thumbnail(x, grid));
  return match_views(f, r, reference_positions);
}

}  // namespace orbitforge

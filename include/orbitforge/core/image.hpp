#pragma once
// A plain interleaved image (row-major, channels fastest): pixel (x, y), channel c
// lives at data[(y * width + x) * channels + c]. Row 0 is the top row. data starts
// on a cache line (core/aligned_allocator.hpp): threads write neighbouring tiles.
#include <cstddef>
#include <cstdint>
#include <vector>

#include "orbitforge/core/aligned_allocator.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"

namespace orbitforge {

template <class T>
struct Image {
  int width = 0, height = 0, channels = 0;
  cache_aligned_vector<T> data;

  Image() = default;
  Image(int w, int h, int c, T fill = T(0)) : width(w), height(h), channels(c) {
    ensure(w >= 0 && h >= 0 && c >= 0, "Image: negative size ", w, "x", h, "x", c);
    check_image_size(std::uint64_t(w), std::uint64_t(h), "Image");
    data.assign(std::size_t(w) * std::size_t(h) * std::size_t(c), fill);
  }
  std::size_t pixel_count() const { return std::size_t(width) * std::size_t(height); }
  bool empty() const { return data.empty(); }
  T& operator()(int x, int y, int c = 0) { return data[(std::size_t(y) * width + x) * channels + c]; }
  const T& operator()(int x, int y, int c = 0) const { return data[(std::size_t(y) * width + x) * channels + c]; }
  bool same_shape(const Image& o) const {
    return width == o.width && height == o.height && channels == o.channels;
  }
};

using Imagef = Image<float>;
using Imaged = Image<double>;

}  // namespace orbitforge

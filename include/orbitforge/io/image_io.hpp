#pragma once
// Image files: PNG / JPEG (and the other formats stb_image decodes) read through
// stb_image, PNG written by io/png_encode.hpp, and PFM read and written exactly
// as the format defines it, so float output is lossless.
//
// Pixel values are in [0, 1]; readers return 3-channel (RGB) images: grey is
// replicated, an alpha channel is dropped (not composited). 16-bit PNGs keep their
// 16 bits. Writers take 1, 3 (PFM) or 1..4 (PNG) channels; PNG clamps to [0, 1] and
// rounds to 8 bits. Every write goes to a temporary name and is renamed.
//
// PFM ("Portable Float Map"): the text header "PF\n<width> <height>\n<scale>\n" ("Pf"
// for one channel), then float32 pixels, rows stored BOTTOM row first, little endian
// when scale < 0 and big endian when scale > 0. We write scale -1.0; the |scale| is
// not applied to values when reading.
//
// stb: this header compiles the stb_image implementation as static functions
// (STB_IMAGE_STATIC) so the library stays header-only. A program that already
// links its own stb_image implementation defines ORBITFORGE_NO_STB_IMPLEMENTATION
// before including this header.
#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <string>
#include <system_error>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/endian.hpp"
#include "orbitforge/io/png_encode.hpp"

#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-but-set-variable"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#pragma GCC diagnostic ignored "-Wtype-limits"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wcast-qual"
#pragma GCC diagnostic ignored "-Wold-style-cast"
#endif
#ifndef ORBITFORGE_NO_STB_IMPLEMENTATION
#ifndef STB_IMAGE_STATIC
#define STB_IMAGE_STATIC
#endif
#define STB_IMAGE_IMPLEMENTATION
#endif
// Debian installs stb under <stb/...>; other layouts put the headers on the
// include path directly. Either works without extra include flags.
#if __has_include(<stb_image.h>)
#include <stb_image.h>
#elif __has_include(<stb/stb_image.h>)
#include <stb/stb_image.h>
#else
#error "orbitforge/io/image_io.hpp needs stb_image.h (Debian: libstb-dev)"
#endif
#ifndef ORBITFORGE_NO_STB_IMPLEMENTATION
#undef STB_IMAGE_IMPLEMENTATION
#endif
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

namespace orbitforge {

namespace image_io_detail {

inline std::string lower_extension(const std::string& path) {
  const auto slash = path.find_last_of("/\\");
  const auto dot = path.find_last_of('.');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) return "";
  std::string e = path.substr(dot + 1);
  for (char& c : e) c = char(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

}  // namespace image_io_detail

// RGB view of an image with 1 (grey), 2 (grey + alpha), 3 or 4 (RGBA) channels.
template <class T>
Image<T> to_rgb(const Image<T>& in) {
  ensure(in.channels >= 1 && in.channels <= 4, "to_rgb: unsupported channel count ", in.channels);
  if (in.channels == 3) return in;
  Image<T> out(in.width, in.height, 3);
  const std::size_t n = in.pixel_count();
  const int c_in = in.channels;
  for (std::size_t i = 0; i < n; ++i)
    for (int c = 0; c < 3; ++c) out.data[3 * i + c] = in.data[i * c_in + (c_in >= 3 ? c : 0)];
  return out;
}

// ---------------------------------------------------------------------------- PFM

// Decodes PFM bytes (1 or 3 channels, rows returned top row first).
template <class T = float>
Image<T> decode_pfm(const std::string& bytes, const std::string& name) {
  static_assert(std::is_floating_point<T>::value, "decode_pfm: floating-point images only");
  std::size_t pos = 0;
  auto is_space = [](char c) { return c == ' ' || c == '\n' || c == '\r' || c == '\t'; };
  auto token = [&](const char* what) {
    while (pos < bytes.size() && is_space(bytes[pos])) ++pos;
    const std::size_t b = pos;
    while (pos < bytes.size() && !is_space(bytes[pos]) && pos - b < 64) ++pos;
    ensure(pos > b && pos < bytes.size(), name, ": PFM header: missing ", what);
    return bytes.substr(b, pos - b);
  };
  ensure(bytes.size() >= 2 && bytes[0] == 'P' && (bytes[1] == 'F' || bytes[1] == 'f'), name,
         ": not a PFM file (must start with 'PF' or 'Pf')");
  const int channels = bytes[1] == 'F' ? 3 : 1;
  pos = 2;
  ensure(pos < bytes.size() && is_space(bytes[pos]), name, ": PFM header: expected whitespace after '",
         bytes.substr(0, 2), "'");
  auto parse_int = [&](const std::string& s, const char* what) {
    long long v = 0;
    const auto r = std::from_chars(s.data(), s.data() + s.size(), v);
    ensure(r.ec == std::errc() && r.ptr == s.data() + s.size() && v > 0 && v <= (1 << 24), name,
           ": PFM header: bad ", what, " '", s, "'");
    return int(v);
  };
  const int w = parse_int(token("width"), "width");
  const int h = parse_int(token("height"), "height");
  const std::string scale_text = token("scale");
  double scale = 0;
  {
    const auto r = std::from_chars(scale_text.data(), scale_text.data() + scale_text.size(), scale);
    ensure(r.ec == std::errc() && r.ptr == scale_text.data() + scale_text.size() && scale != 0 &&
               std::isfinite(scale),
           name, ": PFM header: bad scale '", scale_text, "' (must be a non-zero number)");
  }
  ++pos;  // exactly one whitespace character ends the header
  const bool little = scale < 0;
  const std::uint64_t need = std::uint64_t(w) * std::uint64_t(h) * std::uint64_t(channels) * 4;
  ensure(bytes.size() - pos >= need, name, ": PFM truncated: ", w, "x", h, "x", channels, " needs ", need,
         " bytes of data after the header (byte offset ", pos, "), found ", bytes.size() - pos);
  const bool swap = little != host_is_little_endian();
  Image<T> img(w, h, channels);
  const auto* data = reinterpret_cast<const unsigned char*>(bytes.data() + pos);
  const std::size_t row = std::size_t(w) * std::size_t(channels);
  for (int y = 0; y < h; ++y) {
    const unsigned char* src = data + std::size_t(h - 1 - y) * row * 4;  // bottom row first
    T* dst = img.data.data() + std::size_t(y) * row;
    for (std::size_t i = 0; i < row; ++i) {
      unsigned char b[4] = {src[4 * i], src[4 * i + 1], src[4 * i + 2], src[4 * i + 3]};
      if (swap) {
        std::swap(b[0], b[3]);
        std::swap(b[1], b[2]);
      }
      float v;
      std::memcpy(&v, b, 4);
      dst[i] = T(v);
    }
  }
  return img;
}

template <class T = float>
Image<T> read_pfm(const std::string& path) {
  return decode_pfm<T>(read_file_bytes(path), path);
}

// PFM bytes, little endian (scale -1), bottom row first; 1 or 3 channels.
template <class T>
std::string pfm_bytes(const Image<T>& img) {
  ensure(img.channels == 1 || img.channels == 3, "pfm_bytes: PFM holds 1 or 3 channels, got ", img.channels);
  ensure(img.width > 0 && img.height > 0, "pfm_bytes: empty image ", img.width, "x", img.height);
  std::string out = std::string(img.channels == 3 ? "PF" : "Pf") + "\n" + std::to_string(img.width) + " " +
                    std::to_string(img.height) + "\n-1.0\n";
  const std::size_t header = out.size();
  const std::size_t row = std::size_t(img.width) * std::size_t(img.channels);
  out.resize(header + row * std::size_t(img.height) * 4);
  auto* data = reinterpret_cast<unsigned char*>(&out[header]);
  const bool swap = !host_is_little_endian();
  for (int y = 0; y < img.height; ++y) {
    const T* src = img.data.data() + std::size_t(img.height - 1 - y) * row;
    unsigned char* dst = data + std::size_t(y) * row * 4;
    for (std::size_t i = 0; i < row; ++i) {
      const float v = float(src[i]);
      std::memcpy(dst + 4 * i, &v, 4);
      if (swap) {
        std::swap(dst[4 * i], dst[4 * i + 3]);
        std::swap(dst[4 * i + 1], dst[4 * i + 2]);
      }
    }
  }
  return out;
}

template <class T>
void write_pfm(const std::string& path, const Image<T>& img) {
  std::string bytes;
  try {
    bytes = pfm_bytes(img);
  } catch (const Error& e) {
    fail(path, ": ", e.what());
  }
  write_file_atomic(path, bytes);
}

// ------------------------------------------------------------------ PNG / JPEG (stb)

// Decodes PNG, JPEG, BMP, TGA, ... bytes to RGB values in [0, 1].
template <class T = float>
Image<T> decode_image(const std::string& bytes, const std::string& name) {
  static_assert(std::is_floating_point<T>::value, "decode_image: floating-point images only");
  if (bytes.size() >= 2 && bytes[0] == 'P' && (bytes[1] == 'F' || bytes[1] == 'f'))
    return to_rgb(decode_pfm<T>(bytes, name));
  ensure(bytes.size() <= std::size_t(INT32_MAX), name, ": image file too large for stb_image");
  const auto* buf = reinterpret_cast<const stbi_uc*>(bytes.data());
  const int len = int(bytes.size());
  int w = 0, h = 0, c = 0;
  Image<T> img;
  if (stbi_is_16_bit_from_memory(buf, len)) {
    stbi_us* px = stbi_load_16_from_memory(buf, len, &w, &h, &c, 0);
    ensure(px != nullptr, name, ": cannot decode image: ", stbi_failure_reason());
    img = Image<T>(w, h, c);
    for (std::size_t i = 0; i < img.data.size(); ++i) img.data[i] = T(px[i]) / T(65535);
    stbi_image_free(px);
  } else {
    stbi_uc* px = stbi_load_from_memory(buf, len, &w, &h, &c, 0);
    ensure(px != nullptr, name, ": cannot decode image: ", stbi_failure_reason());
    img = Image<T>(w, h, c);
    for (std::size_t i = 0; i < img.data.size(); ++i) img.data[i] = T(px[i]) / T(255);
    stbi_image_free(px);
  }
  ensure(c >= 1 && c <= 4, name, ": unsupported channel count ", c);
  return to_rgb(img);
}

// Reads any image stb_image decodes, or a PFM (by its magic bytes), as RGB in [0, 1].
template <class T = float>
Image<T> read_image(const std::string& path) {
  return decode_image<T>(read_file_bytes(path), path);
}

// PNG bytes of an image with 1..4 channels; values clamped to [0, 1], rounded to 8 bits
// (NaN writes 0). Image<unsigned char> is written as is.
template <class T>
std::string png_bytes(const Image<T>& img) {
  // png_encode checks the shape (1..4 channels, not empty).
  if constexpr (std::is_same<T, unsigned char>::value) {
    return png_encode(img.data.data(), img.width, img.height, img.channels);
  } else {
    std::vector<unsigned char> px(img.data.size());
    for (std::size_t i = 0; i < px.size(); ++i) {
      const T v = img.data[i];
      // v * 255 + 0.5 truncated: std::lround(v * 255) without its call, the
      // same wherever the sum is exact in double (every float v in (0, 1)).
      px[i] = v > T(0) ? (v < T(1) ? static_cast<unsigned char>(double(v) * 255.0 + 0.5) : 255) : 0;
    }
    return png_encode(px.data(), img.width, img.height, img.channels);
  }
}

template <class T>
void write_png(const std::string& path, const Image<T>& img) {
  std::string bytes;
  try {
    bytes = png_bytes(img);
  } catch (const Error& e) {
    fail(path, ": ", e.what());
  }
  write_file_atomic(path, bytes);
}

// Writes by extension: .png or .pfm.
template <class T>
void write_image(const std::string& path, const Image<T>& img) {
  const std::string ext = image_io_detail::lower_extension(path);
  if (ext == "png") return write_png(path, img);
  if constexpr (std::is_floating_point<T>::value) {
    if (ext == "pfm") return write_pfm(path, img);
  }
  fail(path, ": unsupported output image format '", ext, "' (use .png or .pfm)");
}

// ------------------------------------------------------------------------ resize

enum class ResizeFilter {
  area,      // average over each output pixel's footprint (fractional overlaps
             // weighted): right for shrinking, blocky when enlarging
  bilinear,  // pixel-centre aligned bilinear interpolation, edges clamped
};

namespace image_io_detail {

struct Tap {
  int index;
  double weight;
};

// Per output coordinate, the input samples and weights along one axis.
inline std::vector<std::vector<Tap>> resize_taps(int in, int out, ResizeFilter filter) {
  std::vector<std::vector<Tap>> taps(static_cast<std::size_t>(out));
  const double s = double(in) / double(out);
  for (int o = 0; o < out; ++o) {
    auto& t = taps[std::size_t(o)];
    if (filter == ResizeFilter::area) {
      const double a = o * s, b = (o + 1) * s;
      const int i0 = std::max(0, int(std::floor(a))), i1 = std::min(in - 1, int(std::ceil(b)) - 1);
      double total = 0;
      for (int i = i0; i <= i1; ++i) {
        const double w = std::min(b, double(i + 1)) - std::max(a, double(i));
        if (w > 0) {
          t.push_back({i, w});
          total += w;
        }
      }
      for (auto& tap : t) tap.weight /= total;
    } else {
      const double x = std::clamp((o + 0.5) * s - 0.5, 0.0, double(in - 1));
      const int i0 = int(std::floor(x));
      const int i1 = std::min(in - 1, i0 + 1);
      const double f = x - i0;
      t.push_back({i0, 1 - f});
      if (i1 != i0 && f > 0) t.push_back({i1, f});
    }
  }
  return taps;
}

}  // namespace image_io_detail

// Resamples to width x height (separable: rows, then columns).
template <class T>
Image<T> resize_image(const Image<T>& in, int width, int height, ResizeFilter filter = ResizeFilter::area) {
  static_assert(std::is_floating_point<T>::value, "resize_image: floating-point images only");
  ensure(width > 0 && height > 0, "resize_image: bad target size ", width, "x", height);
  ensure(in.width > 0 && in.height > 0 && in.channels > 0, "resize_image: empty input ", in.width, "x",
         in.height, "x", in.channels);
  if (in.width == width && in.height == height) return in;
  const int C = in.channels;
  const auto tx = image_io_detail::resize_taps(in.width, width, filter);
  const auto ty = image_io_detail::resize_taps(in.height, height, filter);
  Image<T> mid(width, in.height, C);
  for (int y = 0; y < in.height; ++y)
    for (int x = 0; x < width; ++x)
      for (int c = 0; c < C; ++c) {
        double v = 0;
        for (const auto& t : tx[std::size_t(x)]) v += t.weight * double(in(t.index, y, c));
        mid(x, y, c) = T(v);
      }
  Image<T> out(width, height, C);
  for (int y = 0; y < height; ++y)
    for (int x = 0; x < width; ++x)
      for (int c = 0; c < C; ++c) {
        double v = 0;
        for (const auto& t : ty[std::size_t(y)]) v += t.weight * double(mid(x, t.index, c));
        out(x, y, c) = T(v);
      }
  return out;
}

}  // namespace orbitforge

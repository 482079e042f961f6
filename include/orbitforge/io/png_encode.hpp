#pragma once
// PNG encoding of 8-bit images, 1 to 4 channels (grey, grey + alpha, RGB, RGBA):
// every row Paeth-filtered, the filtered rows deflated by zlib with its
// run-length strategy, in one IDAT chunk.
//
// Why not a general encoder's adaptive choice: the pipeline writes every
// orbit view it renders (two folders of 361 views a run), and on its renders
// and on photographs this fixed choice is both the fastest and the smallest
// measured (docs/benchmarks.md, "PNG output"): Paeth predicts the smooth
// shading and flat backdrops of a render well, and after it the residuals
// are mostly runs of small values, which run-length matching finds at a
// fraction of the cost of a full LZ77 search.
//
// File layout (the PNG specification): the 8-byte signature, then chunks of
// length (4 bytes, big endian), type (4), data, CRC-32 of type and data (4):
// IHDR (width, height, bit depth 8, colour type, deflate, adaptive filtering,
// no interlace), IDAT (the zlib stream of the filtered rows, each row
// prefixed with its filter type byte) and an empty IEND.
#include <zlib.h>

#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"

namespace orbitforge {

namespace png_detail {

inline void put_u32(std::string& out, std::uint32_t v) {
  const char b[4] = {char(v >> 24), char(v >> 16), char(v >> 8), char(v)};
  out.append(b, 4);
}

// Appends chunk `type` with `size` bytes of `data`.
inline void put_chunk(std::string& out, const char* type, const unsigned char* data, std::size_t size) {
  ensure(size < (std::size_t(1) << 31), "png_encode: a chunk of ", size, " bytes is over PNG's 2^31 - 1");
  put_u32(out, std::uint32_t(size));
  const std::size_t at = out.size();
  out.append(type, 4);
  if (size > 0) out.append(reinterpret_cast<const char*>(data), size);
  uLong crc = crc32(0L, Z_NULL, 0);
  crc = crc32_z(crc, reinterpret_cast<const Bytef*>(out.data() + at), z_size_t(size + 4));
  put_u32(out, std::uint32_t(crc));
}

// The Paeth predictor: whichever of left (a), up (b) and upper left (c) is
// closest to a + b - c, ties to a, then b.
inline int paeth(int a, int b, int c) {
  const int pa = std::abs(b - c), pb = std::abs(a - c), pc = std::abs(a + b - 2 * c);
  return pa <= pb && pa <= pc ? a : (pb <= pc ? b : c);
}

// out[0] = 4 (Paeth), then the row's residuals; up = nullptr for the first row.
inline void paeth_row(const unsigned char* row, const unsigned char* up, std::size_t bytes, int channels,
                      unsigned char* out) {
  *out++ = 4;
  const std::size_t c = std::size_t(channels);
  if (!up) {  // above the image is zero: Paeth predicts the left neighbour
    for (std::size_t i = 0; i < bytes; ++i) out[i] = static_cast<unsigned char>(row[i] - (i >= c ? row[i - c] : 0));
    return;
  }
  for (std::size_t i = 0; i < c && i < bytes; ++i) out[i] = static_cast<unsigned char>(row[i] - up[i]);
  for (std::size_t i = c; i < bytes; ++i)
    out[i] = static_cast<unsigned char>(row[i] - paeth(row[i - c], up[i], up[i - c]));
}

}  // namespace png_detail

// The PNG file of a width x height image of `channels` interleaved 8-bit
// samples per pixel, rows top to bottom.
inline std::string png_encode(const unsigned char* pixels, int width, int height, int channels) {
  using namespace png_detail;
  ensure(channels >= 1 && channels <= 4, "png_encode: PNG holds 1..4 channels, got ", channels);
  ensure(width > 0 && height > 0, "png_encode: empty image ", width, "x", height);
  ensure(std::uint64_t(width) * std::uint64_t(channels) < (std::uint64_t(1) << 31) &&
             std::uint64_t(height) < (std::uint64_t(1) << 31),
         "png_encode: ", width, "x", height, " is over PNG's size limit");
  const std::size_t row = std::size_t(width) * std::size_t(channels), stride = row + 1;
  ensure(stride * std::size_t(height) < (std::size_t(1) << 31), "png_encode: a ", width, "x", height, "x", channels,
         " image is over the 2 GB this encoder deflates in one call");
  std::vector<unsigned char> filtered(stride * std::size_t(height));
  for (std::size_t y = 0; y < std::size_t(height); ++y)
    paeth_row(pixels + y * row, y > 0 ? pixels + (y - 1) * row : nullptr, row, channels, filtered.data() + y * stride);

  z_stream zs{};
  ensure(deflateInit2(&zs, 1, Z_DEFLATED, 15, 8, Z_RLE) == Z_OK, "png_encode: zlib's deflateInit2 failed");
  std::vector<unsigned char> idat(deflateBound(&zs, uLong(filtered.size())));
  zs.next_in = filtered.data();
  zs.avail_in = uInt(filtered.size());
  zs.next_out = idat.data();
  zs.avail_out = uInt(idat.size());
  const int status = deflate(&zs, Z_FINISH);
  const std::size_t idat_size = std::size_t(zs.total_out);
  deflateEnd(&zs);
  ensure(status == Z_STREAM_END, "png_encode: zlib's deflate failed on a ", width, "x", height, " image (status ",
         status, ")");

  static const int kColourType[5] = {0, 0, 4, 2, 6};  // by channel count: grey, grey + alpha, RGB, RGBA
  unsigned char ihdr[13] = {};
  for (int k = 0; k < 4; ++k) {
    ihdr[k] = static_cast<unsigned char>(std::uint32_t(width) >> (24 - 8 * k));
    ihdr[4 + k] = static_cast<unsigned char>(std::uint32_t(height) >> (24 - 8 * k));
  }
  ihdr[8] = 8;  // bits per sample
  ihdr[9] = static_cast<unsigned char>(kColourType[channels]);
  // ihdr[10..12] = 0: deflate, adaptive filtering (per-row filter bytes), no interlace

  std::string out;
  out.reserve(8 + 25 + idat_size + 12 + 12);
  out.append("\x89PNG\r\n\x1a\n", 8);
  put_chunk(out, "IHDR", ihdr, sizeof(ihdr));
  put_chunk(out, "IDAT", idat.data(), idat_size);
  put_chunk(out, "IEND", nullptr, 0);
  return out;
}

}  // namespace orbitforge

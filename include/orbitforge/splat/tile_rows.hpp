#pragma once
// Which tiles of its tile box list a Gaussian: per row of tiles, the span its
// alpha >= 1/255 ellipse reaches (TileRowSpans), and the trims the binning keeps
// per Gaussian so that its later passes need not compute them again.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <utility>

#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/splat_record.hpp"

namespace orbitforge {

namespace detail {

// The tiles of each row of a Gaussian's tile box that its p2 >= min_power
// ellipse reaches. The kernels skip every pixel outside it (alpha < 1/255
// there, see alpha_power_floor), so a tile it misses need not list the
// Gaussian: the box's corners, where a tilted or elongated ellipse leaves
// whole tiles. Exact for the continuous band of pixel centres of the row, in
// double, so never tighter than the pixels the kernels evaluate.
// With p2 = -(a dx^2 + 2 h dx dy + c dy^2) the ellipse is a dx^2 + 2 h dx dy +
// c dy^2 <= mu, mu = -min_power. At height dy its chord is
// dx = (-h dy +- sqrt(a mu - det dy^2)) / a, det = a c - h^2; the right end is
// concave in dy with its maximum sqrt(mu c / det) at dy = -h sqrt(mu c / det) / c
// (the left end mirrors it), so over a band the extreme is at that height
// clamped to the band.
class TileRowSpans {
 public:
  template <class Scalar>
  TileRowSpans(const SplatRecord<Scalar>& rec, int tile_size)
      : ts_(tile_size), x_lo_(int(rec.x_lo)), x_last_(int(rec.x_hi) - 1), y_lo_(int(rec.y_lo)),
        y_last_(int(rec.y_hi) - 1), mx_(double(rec.mean_x)), my_(double(rec.mean_y)) {
    const double a = -double(rec.pxx), h = -0.5 * double(rec.pxy), c = -double(rec.pyy);
    const double mu = -double(rec.min_power), det = a * c - h * h;
    if (!(a > 0 && c > 0 && det > 0 && std::isfinite(mu) && std::isfinite(det))) {
      whole_ = true;  // not an ellipse in floating point: the whole box
      return;
    }
    if (mu < 0) {
      none_ = true;  // min_power > 0 >= p2: alpha < 1/255 everywhere
      return;
    }
    inv_a_ = 1 / a; h_ = h; amu_ = a * mu; det_ = det;
    dx_max_ = std::sqrt(mu * c / det);
    dy_max_ = std::sqrt(mu * a / det);
    dy_right_ = -h * dx_max_ / c;
  }

  // Tile columns [first, second] of tile row ty that list the Gaussian, within
  // the box's columns [bx0, bx1]; first > second when none does.
  std::pair<int, int> row(int ty, int bx0, int bx1) const {
    if (whole_) return {bx0, bx1};
    if (none_) return {1, 0};
    const double d0 = double(std::max(ty * ts_, y_lo_)) + 0.5 - my_;
    const double d1 = double(std::min(ty * ts_ + ts_ - 1, y_last_)) + 0.5 - my_;
    const double lo = std::max(d0, -dy_max_), hi = std::min(d1, dy_max_);
    if (lo > hi) return {1, 0};
    // Without branches: the extreme's height clamped to the band (at the
    // extreme itself the chord's end is +-dx_max).
    auto chord = [&](double dy) { return std::sqrt(std::max(0.0, amu_ - det_ * dy * dy)); };
    const double dr = std::min(hi, std::max(lo, dy_right_)), dl = std::min(hi, std::max(lo, -dy_right_));
    const double xr = (chord(dr) - h_ * dr) * inv_a_, xl = (-chord(dl) - h_ * dl) * inv_a_;
    // Pixels x with x + 0.5 - mean_x in [xl, xr], a thousandth of a pixel wider.
    const int xa = int(std::ceil(std::max(double(x_lo_), mx_ + xl - 0.5 - 1e-3)));
    const int xb = int(std::floor(std::min(double(x_last_), mx_ + xr - 0.5 + 1e-3)));
    if (xa > xb) return {1, 0};
    return {std::max(bx0, xa / ts_), std::min(bx1, xb / ts_)};
  }

 private:
  int ts_, x_lo_, x_last_, y_lo_, y_last_;
  double mx_, my_;
  bool whole_ = false, none_ = false;
  double inv_a_ = 0, h_ = 0, amu_ = 0, det_ = 0, dx_max_ = 0, dy_max_ = 0, dy_right_ = 0;
};

// A rank's listed tiles, row by row, for boxes of up to kTrimRows rows and
// kTrimCols columns: per row, the tiles trimmed off the box's left and right
// ends in 4 bits each (row i in bits 8i..8i+7). The binning computes them once;
// the fill pass and the backward's per-Gaussian sum read them. Larger boxes
// store kTrimsRecompute and their users compute TileRowSpans again (the same
// arithmetic, so the same tiles).
inline constexpr int kTrimRows = 8, kTrimCols = 16;
inline constexpr std::uint64_t kTrimsRecompute = ~std::uint64_t(0);

// The trims of a record's box rows (0: the whole box, as for a box of one row
// or one column, whose rect is already the ellipse's extent up to clipping).
template <class Scalar>
inline std::uint64_t encode_row_trims(const SplatRecord<Scalar>& rec, int tile_size) {
  const std::array<int, 4> box = record_tile_box(rec, tile_size);
  const int rows = box[3] - box[1] + 1, cols = box[2] - box[0] + 1;
  if (rows == 1 || cols == 1) return 0;
  if (rows > kTrimRows || cols > kTrimCols) return kTrimsRecompute;
  const TileRowSpans spans(rec, tile_size);
  std::uint64_t t = 0;
  for (int i = 0; i < rows; ++i) {
    const auto [tx0, tx1] = spans.row(box[1] + i, box[0], box[2]);
    // An empty row: 15 + 14 trimmed tiles, more than the box has (and never
    // the pattern kTrimsRecompute).
    const std::uint64_t left = tx0 > tx1 ? 15u : std::uint64_t(tx0 - box[0]);
    const std::uint64_t right = tx0 > tx1 ? 14u : std::uint64_t(box[2] - tx1);
    t |= (left | (right << 4)) << (8 * i);
  }
  return t;
}

// encode_row_trims for records [0, count) at once, B::size records per batch
// (the records' 16 fields transposed into lanes), into trims[0, count). The
// lanes compute in Scalar: the conic's determinant by Kahan's 2x2 method (a
// long, thin ellipse's a c and h^2 nearly cancel) and the ellipse 0.1 % larger
// in mu, which covers the rounding of the chords near the band's ends; the x
// ends move out by 0.02 pixel plus 2^-20 of the mean's coordinate. Never
// tighter than TileRowSpans in double beyond those margins.
//
// encode_row_trims_fields: the same for B::size records given as their fields
// in lanes, f[i * B::size + lane] the lane's record field i (SplatRecord's
// order), into trims[0, B::size).
template <class B, class Scalar>
void encode_row_trims_fields(const Scalar* f, int tile_size, std::uint64_t* trims) {
  constexpr std::size_t N = B::size;
  alignas(64) Scalar code[4 * N];  // per lane: the trims' four 16-bit parts
  const B ts = B(Scalar(tile_size)), inv_ts = B(Scalar(1) / Scalar(tile_size));
  const B half = B(Scalar(0.5)), zero = B(Scalar(0)), one = B(Scalar(1));
  auto field = [&](int i) { return B::load_unaligned(f + std::size_t(i) * N); };
  const B mx = field(0), my = field(1);
  const B a = -field(2), h = Scalar(-0.5) * field(3), c = -field(4);
  const B mu = -field(14) * B(Scalar(1.001));
  const B x_lo = field(10), x_last = field(11) - one, y_lo = field(12), y_last = field(13) - one;
  const B w = h * h;
  const B det = simd::fma(a, c, -w) + simd::fma(-h, h, w);
  const auto usable = (a > zero) & (c > zero) & (det > zero) & (mu >= zero);
  // Unusable lanes compute on harmless values and are replaced below.
  const B sa = simd::select(usable, a, one), sc = simd::select(usable, c, one);
  const B sdet = simd::select(usable, det, one), smu = simd::select(usable, mu, zero);
  const B dx_max = simd::sqrt(smu * sc / sdet), dy_max = simd::sqrt(smu * sa / sdet);
  const B dy_right = -h * dx_max / sc, inv_a = one / sa, amu = sa * smu;
  const B margin = B(Scalar(0.02)) + simd::abs(mx) * B(Scalar(1.0 / 1048576));
  const B bx0 = simd::floor((x_lo + half) * inv_ts), bx1 = simd::floor((x_last + half) * inv_ts);
  const B by0 = simd::floor((y_lo + half) * inv_ts), by1 = simd::floor((y_last + half) * inv_ts);
  const B rows = by1 - by0 + one, cols = bx1 - bx0 + one;
  B part[4] = {zero, zero, zero, zero};  // code_i = left + 16 right, two rows per 16-bit part
  for (int i = 0; i < kTrimRows && simd::any(B(Scalar(i)) < rows); ++i) {
    const B ty0 = (by0 + B(Scalar(i))) * ts;
    const B d0 = simd::max(ty0, y_lo) + half - my, d1 = simd::min(ty0 + ts - one, y_last) + half - my;
    const B lo = simd::max(d0, -dy_max), hi = simd::min(d1, dy_max);
    const B dr = simd::min(hi, simd::max(lo, dy_right)), dl = simd::min(hi, simd::max(lo, -dy_right));
    const B xr = (simd::sqrt(simd::max(zero, amu - sdet * dr * dr)) - h * dr) * inv_a;
    const B xl = (-simd::sqrt(simd::max(zero, amu - sdet * dl * dl)) - h * dl) * inv_a;
    const B xa = simd::ceil(simd::max(x_lo, mx + xl - half - margin));
    const B xb = simd::floor(simd::min(x_last, mx + xr - half + margin));
    const B left = simd::floor((xa + half) * inv_ts) - bx0, right = bx1 - simd::floor((xb + half) * inv_ts);
    const auto empty = (lo > hi) | (xa > xb);
    B code = simd::select(empty, B(Scalar(15 + 16 * 14)), left + B(Scalar(16)) * right);
    code = simd::select(B(Scalar(i)) < rows, code, zero);  // rows past the box: no trim
    part[i / 2] = part[i / 2] + code * B(Scalar(i % 2 ? 256 : 1));
  }
  // Without a branch per lane: a box of one row or column keeps the whole box
  // (0), one too large for the codes or not an ellipse recomputes (all ones).
  const auto whole = (rows == one) | (cols == one);
  const auto partial = !whole;
  const auto too_large = (rows > B(Scalar(kTrimRows))) | (cols > B(Scalar(kTrimCols)));
  const auto not_ellipse = !usable;
  const auto recompute = partial & (too_large | not_ellipse);
  const B all_ones = B(Scalar(65535));
  for (int j = 0; j < 4; ++j)
    simd::select(recompute, all_ones, simd::select(whole, zero, part[j])).store_unaligned(code + std::size_t(j) * N);
  for (std::size_t l = 0; l < N; ++l)
    trims[l] = std::uint64_t(code[l]) | (std::uint64_t(code[N + l]) << 16) | (std::uint64_t(code[2 * N + l]) << 32) |
               (std::uint64_t(code[3 * N + l]) << 48);
}

template <class B, class Scalar>
void encode_row_trims_lanes(const SplatRecord<Scalar>* recs, std::size_t count, int tile_size, std::uint64_t* trims) {
  constexpr std::size_t N = B::size;
  static_assert(16 % N == 0, "a record's 16 fields split into whole blocks of lanes");
  alignas(64) Scalar f[16 * N];
  std::size_t k0 = 0;
  for (; k0 + N <= count; k0 += N) {
    const Scalar* in = &recs[k0].mean_x;
    for (std::size_t f0 = 0; f0 < 16; f0 += N) simd::transpose_block<B>(in + f0, 16, f + f0 * N, N);
    encode_row_trims_fields<B>(f, tile_size, trims + k0);
  }
  for (; k0 < count; ++k0) trims[k0] = encode_row_trims(recs[k0], tile_size);
}

}  // namespace detail

}  // namespace orbitforge

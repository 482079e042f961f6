#pragma once
// The record of one visible Gaussian that the rasterizer and its backward read
// (bin_splats packs them, bin.hpp), with the helpers that read and fill it.
#include <array>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>

#include "orbitforge/core/simd.hpp"

namespace orbitforge {

// One visible Gaussian as the rasterizer reads it. The rect is kept as
// pixel-centre bounds: pixel x is inside iff x_lo < x + 0.5 < x_hi, i.e.
// x_lo = rect_x0, x_hi = rect_x1 + 1 (exact in float for any image size).
template <class Scalar>
struct alignas(sizeof(Scalar) * 16) SplatRecord {
  Scalar mean_x, mean_y;
  // The Gaussian's power in base 2, p2 = pxx dx^2 + pxy dx dy + pyy dy^2 with
  // opacity 2^p2 = opacity exp(power): the conic (a, b, c) times -log2(e) / 2,
  // -log2(e), -log2(e) / 2. Base 2 saves the exp's range reduction.
  Scalar pxx, pxy, pyy;
  Scalar opacity;
  Scalar color_r, color_g, color_b;
  Scalar depth;
  Scalar x_lo, x_hi, y_lo, y_hi;
  // Below this p2, opacity 2^p2 < 1/255 for certain (a lower bound of
  // log2(1 / (255 opacity)), see detail::alpha_power_floor):
  // the backward pass skips a chunk's exp when no lane reaches it (in the
  // forward the extra test cost more than it saved).
  Scalar min_power;
  // The Gaussian's index as an int32 bit pattern in the slot's first bytes
  // (record_index), so that the binning reads one record per Gaussian, not a
  // record and a side array.
  Scalar index_bits;
};

namespace detail {

template <class Scalar>
inline void set_record_index(SplatRecord<Scalar>& rec, std::int32_t i) {
  static_assert(sizeof(Scalar) >= sizeof(std::int32_t), "the index must fit in a Scalar slot");
  rec.index_bits = Scalar(0);
  std::memcpy(&rec.index_bits, &i, sizeof(i));
}

template <class Scalar>
inline std::int32_t record_index(const SplatRecord<Scalar>& rec) {
  std::int32_t i;
  std::memcpy(&i, &rec.index_bits, sizeof(i));
  return i;
}

// The record's tile box from its pixel-centre bounds (exact integers): tile
// columns [0] .. [2] and rows [1] .. [3], inclusive.
template <class Scalar>
inline std::array<int, 4> record_tile_box(const SplatRecord<Scalar>& rec, int tile_size) {
  return {{int(rec.x_lo) / tile_size, int(rec.y_lo) / tile_size, (int(rec.x_hi) - 1) / tile_size,
           (int(rec.y_hi) - 1) / tile_size}};
}

// log2 of a power-of-two tile size, else -1.
inline int tile_size_shift(int tile_size) {
  if (tile_size <= 0 || (tile_size & (tile_size - 1)) != 0) return -1;
  int shift = 0;
  while ((1 << shift) < tile_size) ++shift;
  return shift;
}

// record_tile_box with tile_size = 1 << shift: the bounds are >= 0, so the shift
// gives the same quotients as the divisions, which would otherwise run four
// times per Gaussian in the binning pass.
template <class Scalar>
inline std::array<int, 4> record_tile_box(const SplatRecord<Scalar>& rec, int tile_size, int shift) {
  if (shift < 0) return record_tile_box(rec, tile_size);
  return {{int(rec.x_lo) >> shift, int(rec.y_lo) >> shift, (int(rec.x_hi) - 1) >> shift,
           (int(rec.y_hi) - 1) >> shift}};
}

// The unsigned integer as wide as Scalar (float: 32 bits, double: 64), for
// reading a value's bits.
template <class Scalar>
using scalar_bits_t = std::conditional_t<sizeof(Scalar) == 4, std::uint32_t, std::uint64_t>;

// An IEEE Scalar's fields: significand bits, the exponent field's mask (after
// shifting it down by mant) and the exponent bias.
template <class Scalar>
struct FloatFields {
  using Bits = scalar_bits_t<Scalar>;
  static constexpr int mant = std::numeric_limits<Scalar>::digits - 1;
  static constexpr Bits exp_mask = Bits((Bits(1) << (8 * sizeof(Scalar) - 1 - mant)) - 1);
  static constexpr Bits bias = exp_mask >> 1;
};

// A lower bound of log2(1 / (255 opacity)): base-2 powers below it give
// opacity 2^p2 < 1/255. Without a log per Gaussian (it cost ~1 ms per 300k): with
// x = 255 opacity = m 2^e, m in [1, 2), log2 x <= e + (m - 1) + 0.0861 (the
// largest gap between log2 m and its chord); 1e-4 more covers rounding.
// For a normal x, e and m come from its bits (the exponent field and the
// significand with the exponent of 1); frexp, a library call, handles the rest.
template <class Scalar>
inline Scalar alpha_power_floor(Scalar opacity) {
  static_assert(std::numeric_limits<Scalar>::is_iec559, "alpha_power_floor: IEEE float or double");
  if (!(opacity > Scalar(0))) return std::numeric_limits<Scalar>::infinity();
  using Bits = scalar_bits_t<Scalar>;
  using Fields = FloatFields<Scalar>;
  constexpr int mant = Fields::mant;
  constexpr Bits exp_mask = Fields::exp_mask;
  constexpr int bias = int(Fields::bias);
  const Scalar x = Scalar(255) * opacity;
  Scalar m;
  int e_minus_1;  // x = m 2^(e_minus_1), m in [1, 2)
  if (x >= std::numeric_limits<Scalar>::min() && x <= std::numeric_limits<Scalar>::max()) {
    Bits bits;
    std::memcpy(&bits, &x, sizeof(Bits));
    e_minus_1 = int((bits >> mant) & exp_mask) - bias;
    bits = (bits & ((Bits(1) << mant) - 1)) | (Bits(bias) << mant);
    std::memcpy(&m, &bits, sizeof(Bits));
  } else {
    int e = 0;
    m = Scalar(2) * std::frexp(x, &e);
    e_minus_1 = e - 1;
  }
  const Scalar log2_upper = Scalar(e_minus_1) + (m - Scalar(1)) + Scalar(0.0861);
  return -log2_upper - Scalar(1e-4);
}

// alpha_power_floor of each lane, for lanes whose 255 opacity is a normal
// number (the caller checks): the same operations on the same bits, so the same
// values. The exponent becomes a Scalar without an integer conversion: its
// field, or-ed into the significand of 2^digits, is that number plus the field.
template <class B>
inline B alpha_power_floor_lanes(const B& opacity) {
#if ORBITFORGE_SIMD_ENABLED
  if constexpr (!std::is_same<B, simd::scalar_batch<typename B::value_type>>::value) {
    using Scalar = typename B::value_type;
    const B x = B(Scalar(255)) * opacity;
    using Bits = scalar_bits_t<Scalar>;
    using BI = xsimd::batch<Bits, typename B::arch_type>;
    using Fields = FloatFields<Scalar>;
    constexpr int mant = Fields::mant;
    constexpr Bits exp_mask = Fields::exp_mask;
    constexpr Bits bias = Fields::bias;
    const BI bits = xsimd::bitwise_cast<BI>(x);
    const B m = xsimd::bitwise_cast<B>((bits & BI(Bits((Bits(1) << mant) - 1))) | BI(Bits(bias << mant)));
    const B two_mant = B(Scalar(Bits(1) << mant));
    const BI field_bits = ((bits >> mant) & BI(exp_mask)) | xsimd::bitwise_cast<BI>(two_mant);
    const B field = xsimd::bitwise_cast<B>(field_bits) - two_mant;
    const B log2_upper = (field - B(Scalar(bias))) + (m - B(Scalar(1))) + B(Scalar(0.0861));
    return -log2_upper - B(Scalar(1e-4));
  } else
#endif
  {
    static_assert(B::size == 1, "alpha_power_floor_lanes: one lane without SIMD");
    return B(alpha_power_floor(opacity.get(0)));
  }
}

// exp(power) = 2^(power log2(e)): the conic's coefficients in base 2.
template <class Scalar>
constexpr Scalar kHalfLog2e = Scalar(0.72134752044448170368);
// The record's power coefficients from the conic (a, b, c): pxx = diag a,
// pxy = cross b, pyy = diag c, so that p2 = pxx dx^2 + pxy dx dy + pyy dy^2.
template <class Scalar>
constexpr Scalar kConicDiagToPower = -kHalfLog2e<Scalar>;
template <class Scalar>
constexpr Scalar kConicCrossToPower = Scalar(-2) * kHalfLog2e<Scalar>;

}  // namespace detail

}  // namespace orbitforge

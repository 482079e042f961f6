#pragma once
// A thin SIMD shim: kernels are written once against the small vocabulary below
// and instantiated for
//   simd::native_batch<T>  xsimd::batch<T> of the compiler's best architecture,
//                          or scalar_batch<T> when there is none (xsimd 8.1
//                          declares no batch at all then) or ORBITFORGE_NO_SIMD
//                          is defined;
//   simd::scalar_batch<T>  one lane, always available (the scalar build and a
//                          cross-check for the vector kernels).
//
// Vocabulary (B a batch type, M = mask_t<B>):
//   B::size, B(value) broadcast, B::load_unaligned(p), b.store_unaligned(p),
//   + - * / (and += -= *= /=), unary + and -, comparisons < <= > >= == != giving M,
//   masks combine with & | ^ ~ (and && || !, == !=) as xsimd::batch_bool does (not
//   &= |= ^=: xsimd 8.1 declares them const and they do not compile),
//   fma(x, y, z) = x*y+z, exp, log, exp2_nonpositive, sin, cos, min, max, abs, sqrt, ceil, floor,
//   select(m, a, b),
//   hadd(b) (sum of lanes; xsimd 8.1 has hadd, not reduce_add), any(m), all(m),
//   mask_bits(m) (lane i's flag at bit i, up to 64 lanes),
//   hadd_rows(rows, count, out): out[i] = hadd(rows[i]) for many rows at once.
//   transpose_block<B>(in, in_stride, out, out_stride): a B::size x B::size block,
//   out[c * out_stride + r] = in[r * in_stride + c] (row-major blocks of scalars).
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <type_traits>

#include "orbitforge/core/config.hpp"

#ifndef ORBITFORGE_NO_SIMD
#include <xsimd/xsimd.hpp>
#if defined(XSIMD_NO_SUPPORTED_ARCHITECTURE)
#define ORBITFORGE_SIMD_ENABLED 0
#else
#define ORBITFORGE_SIMD_ENABLED 1
#endif
#else
#define ORBITFORGE_SIMD_ENABLED 0
#endif

namespace orbitforge {
namespace simd {

// Number of set bits (of a mask_bits result).
inline int popcount(std::uint64_t bits) {
#if defined(__GNUC__) || defined(__clang__)
  return __builtin_popcountll(bits);
#else
  int n = 0;
  for (; bits != 0; bits &= bits - 1) ++n;
  return n;
#endif
}

// ---------------------------------------------------------------- scalar path
template <class T>
struct scalar_mask {
  bool v = false;
  scalar_mask() = default;
  scalar_mask(bool b) : v(b) {}
  friend scalar_mask operator&(scalar_mask a, scalar_mask b) { return a.v && b.v; }
  friend scalar_mask operator|(scalar_mask a, scalar_mask b) { return a.v || b.v; }
  friend scalar_mask operator^(scalar_mask a, scalar_mask b) { return a.v != b.v; }
  friend scalar_mask operator~(scalar_mask a) { return !a.v; }
  friend scalar_mask operator!(scalar_mask a) { return !a.v; }
  friend scalar_mask operator&&(scalar_mask a, scalar_mask b) { return a.v && b.v; }
  friend scalar_mask operator||(scalar_mask a, scalar_mask b) { return a.v || b.v; }
  friend scalar_mask operator==(scalar_mask a, scalar_mask b) { return a.v == b.v; }
  friend scalar_mask operator!=(scalar_mask a, scalar_mask b) { return a.v != b.v; }
};

template <class T>
struct scalar_batch {
  using value_type = T;
  static constexpr std::size_t size = 1;
  T v = T(0);
  scalar_batch() = default;
  scalar_batch(T x) : v(x) {}
  static scalar_batch load_unaligned(const T* p) { return *p; }
  void store_unaligned(T* p) const { *p = v; }
  T get(std::size_t) const { return v; }
  friend scalar_batch operator+(scalar_batch a, scalar_batch b) { return a.v + b.v; }
  friend scalar_batch operator-(scalar_batch a, scalar_batch b) { return a.v - b.v; }
  friend scalar_batch operator*(scalar_batch a, scalar_batch b) { return a.v * b.v; }
  friend scalar_batch operator/(scalar_batch a, scalar_batch b) { return a.v / b.v; }
  friend scalar_batch operator-(scalar_batch a) { return -a.v; }
  friend scalar_batch operator+(scalar_batch a) { return a; }
  friend scalar_mask<T> operator<(scalar_batch a, scalar_batch b) { return a.v < b.v; }
  friend scalar_mask<T> operator<=(scalar_batch a, scalar_batch b) { return a.v <= b.v; }
  friend scalar_mask<T> operator>(scalar_batch a, scalar_batch b) { return a.v > b.v; }
  friend scalar_mask<T> operator>=(scalar_batch a, scalar_batch b) { return a.v >= b.v; }
  friend scalar_mask<T> operator==(scalar_batch a, scalar_batch b) { return a.v == b.v; }
  friend scalar_mask<T> operator!=(scalar_batch a, scalar_batch b) { return a.v != b.v; }
  scalar_batch& operator+=(scalar_batch b) { v += b.v; return *this; }
  scalar_batch& operator-=(scalar_batch b) { v -= b.v; return *this; }
  scalar_batch& operator*=(scalar_batch b) { v *= b.v; return *this; }
  scalar_batch& operator/=(scalar_batch b) { v /= b.v; return *this; }
};

template <class T> inline scalar_batch<T> fma(scalar_batch<T> x, scalar_batch<T> y, scalar_batch<T> z) { return std::fma(x.v, y.v, z.v); }
template <class T> inline scalar_batch<T> exp(scalar_batch<T> x) { return std::exp(x.v); }
template <class T> inline scalar_batch<T> log(scalar_batch<T> x) { return std::log(x.v); }
template <class T> inline scalar_batch<T> sin(scalar_batch<T> x) { return std::sin(x.v); }
template <class T> inline scalar_batch<T> cos(scalar_batch<T> x) { return std::cos(x.v); }
template <class T> inline scalar_batch<T> ceil(scalar_batch<T> x) { return std::ceil(x.v); }
template <class T> inline scalar_batch<T> floor(scalar_batch<T> x) { return std::floor(x.v); }
template <class T> inline scalar_batch<T> min(scalar_batch<T> x, scalar_batch<T> y) { return y.v < x.v ? y.v : x.v; }
template <class T> inline scalar_batch<T> max(scalar_batch<T> x, scalar_batch<T> y) { return x.v < y.v ? y.v : x.v; }
template <class T> inline scalar_batch<T> abs(scalar_batch<T> x) { return std::abs(x.v); }
template <class T> inline scalar_batch<T> sqrt(scalar_batch<T> x) { return std::sqrt(x.v); }
template <class T> inline scalar_batch<T> select(scalar_mask<T> m, scalar_batch<T> a, scalar_batch<T> b) { return m.v ? a : b; }
template <class T> inline T hadd(scalar_batch<T> x) { return x.v; }
template <class T> inline bool any(scalar_mask<T> m) { return m.v; }
template <class T> inline bool all(scalar_mask<T> m) { return m.v; }
template <class T> inline std::uint64_t mask_bits(scalar_mask<T> m) { return m.v ? 1u : 0u; }
template <class T> inline scalar_batch<T> ldexp_int(scalar_batch<T> x, scalar_batch<T> n) { return std::ldexp(x.v, int(n.v)); }
template <class T> inline scalar_batch<T> round_nearest(scalar_batch<T> x) { return std::nearbyint(x.v); }

template <class B> struct mask_of;
template <class T> struct mask_of<scalar_batch<T>> { using type = scalar_mask<T>; };

// ---------------------------------------------------------------- xsimd path
#if ORBITFORGE_SIMD_ENABLED
// xsimd 8.1 has no AVX-512 fma kernel: its generic x * y + z is fused only where
// the compiler contracts it (GCC at -O2 and above), so -O1 builds rounded twice
// and disagreed with std::fma on the scalar path. Fused explicitly here.
template <class T, class A> inline xsimd::batch<T, A> fma(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y, const xsimd::batch<T, A>& z) {
#if defined(__AVX512F__)
  if constexpr (std::is_base_of<xsimd::avx512f, A>::value && std::is_same<T, float>::value) return _mm512_fmadd_ps(x, y, z);
  if constexpr (std::is_base_of<xsimd::avx512f, A>::value && std::is_same<T, double>::value) return _mm512_fmadd_pd(x, y, z);
#endif
  return xsimd::fma(x, y, z);
}
template <class T, class A> inline xsimd::batch<T, A> exp(const xsimd::batch<T, A>& x) { return xsimd::exp(x); }
template <class T, class A> inline xsimd::batch<T, A> log(const xsimd::batch<T, A>& x) { return xsimd::log(x); }
template <class T, class A> inline xsimd::batch<T, A> sin(const xsimd::batch<T, A>& x) { return xsimd::sin(x); }
template <class T, class A> inline xsimd::batch<T, A> cos(const xsimd::batch<T, A>& x) { return xsimd::cos(x); }
template <class T, class A> inline xsimd::batch<T, A> ceil(const xsimd::batch<T, A>& x) { return xsimd::ceil(x); }
template <class T, class A> inline xsimd::batch<T, A> floor(const xsimd::batch<T, A>& x) { return xsimd::floor(x); }
template <class T, class A> inline xsimd::batch<T, A> min(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y) { return xsimd::min(x, y); }
template <class T, class A> inline xsimd::batch<T, A> max(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y) { return xsimd::max(x, y); }
template <class T, class A> inline xsimd::batch<T, A> abs(const xsimd::batch<T, A>& x) { return xsimd::abs(x); }
template <class T, class A> inline xsimd::batch<T, A> sqrt(const xsimd::batch<T, A>& x) { return xsimd::sqrt(x); }
template <class T, class A> inline xsimd::batch<T, A> select(const xsimd::batch_bool<T, A>& m, const xsimd::batch<T, A>& a, const xsimd::batch<T, A>& b) { return xsimd::select(m, a, b); }
template <class T, class A> inline T hadd(const xsimd::batch<T, A>& x) { return xsimd::hadd(x); }
template <class T, class A> inline bool any(const xsimd::batch_bool<T, A>& m) { return xsimd::any(m); }
template <class T, class A> inline bool all(const xsimd::batch_bool<T, A>& m) { return xsimd::all(m); }
template <class T, class A> inline std::uint64_t mask_bits(const xsimd::batch_bool<T, A>& m) {
  using R = typename xsimd::batch_bool<T, A>::register_type;
  constexpr std::size_t n = xsimd::batch_bool<T, A>::size;
  static_assert(n <= 64, "mask_bits: more than 64 lanes");
  if constexpr (std::is_integral<R>::value) {  // AVX-512: the mask register is the bits
    return std::uint64_t(R(m)) & (n == 64 ? ~std::uint64_t(0) : (std::uint64_t(1) << n) - 1);
  } else {
    // AVX and SSE float masks are float registers (__m256, __m128d, ...).
    constexpr bool f32 = std::is_same<T, float>::value, f64 = std::is_same<T, double>::value;
#if defined(__AVX__)
    if constexpr (sizeof(R) == 32 && f32) return std::uint64_t(unsigned(_mm256_movemask_ps(R(m))));
    if constexpr (sizeof(R) == 32 && f64) return std::uint64_t(unsigned(_mm256_movemask_pd(R(m))));
#endif
#if defined(__SSE2__)
    if constexpr (sizeof(R) == 16 && f32) return std::uint64_t(unsigned(_mm_movemask_ps(R(m))));
    if constexpr (sizeof(R) == 16 && f64) return std::uint64_t(unsigned(_mm_movemask_pd(R(m))));
#endif
    bool b[n];
    m.store_unaligned(b);
    std::uint64_t bits = 0;
    for (std::size_t i = 0; i < n; ++i) bits |= std::uint64_t(b[i]) << i;
    return bits;
  }
}
template <class T, class A> inline xsimd::batch<T, A> round_nearest(const xsimd::batch<T, A>& x) { return xsimd::nearbyint(x); }
// x * 2^n for n holding small integral values.
template <class T, class A> inline xsimd::batch<T, A> ldexp_int(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& n) {
  return xsimd::ldexp(x, xsimd::to_int(n));
}
template <class T, class A> struct mask_of<xsimd::batch<T, A>> { using type = xsimd::batch_bool<T, A>; };

template <class T> using native_batch = xsimd::batch<T>;
#else
template <class T> using native_batch = scalar_batch<T>;
#endif

template <class B> using mask_t = typename mask_of<B>::type;

// The target's vector registers (AVX-512 and AArch64 have 32, AVX2 and SSE 16):
// a kernel that keeps many batches live picks its blocking by it, since a
// blocking that spills runs slower than the unfused passes it replaces.
#if defined(__AVX512F__) || defined(__aarch64__)
inline constexpr int vector_registers = 32;
#else
inline constexpr int vector_registers = 16;
#endif

// out[i] = hadd(rows[i]), i < count. One reduction per row costs a chain of
// shuffles each; for 16-lane float, blocks of 16 rows are instead reduced
// together by a transposing add tree (about 2 operations per row instead of 8).
// xsimd 8.1's haddp would do this but returns rows 2-5 and 10-13 permuted on
// AVX-512, so it is not used.
template <class T>
inline void hadd_rows(const scalar_batch<T>* rows, int count, T* out) {
  for (int i = 0; i < count; ++i) out[i] = rows[i].v;
}
#if ORBITFORGE_SIMD_ENABLED
namespace detail {
#if defined(__AVX512F__)
// Sums of 16 rows of 16 floats, in row order.
inline __m512 hadd16_avx512(const __m512* r) {
  // 16 -> 8 lanes per row: s[i] = [row 2i folded | row 2i+1 folded].
  __m512 s[8];
  for (int i = 0; i < 8; ++i)
    s[i] = _mm512_add_ps(_mm512_shuffle_f32x4(r[2 * i], r[2 * i + 1], _MM_SHUFFLE(1, 0, 1, 0)),
                         _mm512_shuffle_f32x4(r[2 * i], r[2 * i + 1], _MM_SHUFFLE(3, 2, 3, 2)));
  // 8 -> 4 lanes: 128-bit lane q of u[k] holds row 4k + q.
  __m512 u[4];
  for (int k = 0; k < 4; ++k)
    u[k] = _mm512_add_ps(_mm512_shuffle_f32x4(s[2 * k], s[2 * k + 1], _MM_SHUFFLE(2, 0, 2, 0)),
                         _mm512_shuffle_f32x4(s[2 * k], s[2 * k + 1], _MM_SHUFFLE(3, 1, 3, 1)));
  // 4 -> 2 -> 1 within each 128-bit lane: position p of lane q ends as row 4p + q.
  const __m512 v01 = _mm512_add_ps(_mm512_unpacklo_ps(u[0], u[1]), _mm512_unpackhi_ps(u[0], u[1]));
  const __m512 v23 = _mm512_add_ps(_mm512_unpacklo_ps(u[2], u[3]), _mm512_unpackhi_ps(u[2], u[3]));
  const __m512d a = _mm512_castps_pd(v01), b = _mm512_castps_pd(v23);
  const __m512 w = _mm512_add_ps(_mm512_castpd_ps(_mm512_unpacklo_pd(a, b)), _mm512_castpd_ps(_mm512_unpackhi_pd(a, b)));
  // Element 4q + p holds row 4p + q: transpose the 4 x 4 index.
  const __m512i idx = _mm512_set_epi32(15, 11, 7, 3, 14, 10, 6, 2, 13, 9, 5, 1, 12, 8, 4, 0);
  return _mm512_permutexvar_ps(idx, w);
}
#endif
}  // namespace detail

template <class T, class A>
inline void hadd_rows(const xsimd::batch<T, A>* rows, int count, T* out) {
#if defined(__AVX512F__)
  if constexpr (std::is_same<T, float>::value && std::is_base_of<xsimd::avx512f, A>::value) {
    for (int i0 = 0; i0 < count; i0 += 16) {
      __m512 block[16];
      for (int i = 0; i < 16; ++i) block[i] = i0 + i < count ? __m512(rows[i0 + i]) : _mm512_setzero_ps();
      alignas(64) float sums[16];
      _mm512_store_ps(sums, detail::hadd16_avx512(block));
      for (int i = 0; i < 16 && i0 + i < count; ++i) out[i0 + i] = sums[i];
    }
    return;
  }
#endif
  for (int i = 0; i < count; ++i) out[i] = xsimd::hadd(rows[i]);
}
#endif

// Transposes a B::size x B::size block of scalars (strides in elements). 16 x 16
// floats by a 4-step shuffle network on AVX-512 (64 shuffles instead of 256
// scalar moves), 8 x 8 floats and 4 x 4 doubles by shuffles on AVX; a plain
// loop otherwise.
template <class B>
inline void transpose_block(const typename B::value_type* in, std::size_t in_stride, typename B::value_type* out,
                            std::size_t out_stride) {
#if ORBITFORGE_SIMD_ENABLED && defined(__AVX512F__)
  if constexpr (std::is_same<typename B::value_type, float>::value && B::size == 16) {
    __m512 r[16], t[16];
    for (int i = 0; i < 16; ++i) r[i] = _mm512_loadu_ps(in + std::size_t(i) * in_stride);
    for (int i = 0; i < 8; ++i) {  // 32-bit interleave of row pairs
      t[2 * i] = _mm512_unpacklo_ps(r[2 * i], r[2 * i + 1]);
      t[2 * i + 1] = _mm512_unpackhi_ps(r[2 * i], r[2 * i + 1]);
    }
    for (int i = 0; i < 4; ++i) {  // 64-bit interleave
      const __m512d a = _mm512_castps_pd(t[4 * i]), b = _mm512_castps_pd(t[4 * i + 1]);
      const __m512d c = _mm512_castps_pd(t[4 * i + 2]), d = _mm512_castps_pd(t[4 * i + 3]);
      r[4 * i + 0] = _mm512_castpd_ps(_mm512_unpacklo_pd(a, c));
      r[4 * i + 1] = _mm512_castpd_ps(_mm512_unpackhi_pd(a, c));
      r[4 * i + 2] = _mm512_castpd_ps(_mm512_unpacklo_pd(b, d));
      r[4 * i + 3] = _mm512_castpd_ps(_mm512_unpackhi_pd(b, d));
    }
    for (int i = 0; i < 2; ++i)  // 128-bit lanes, two steps
      for (int j = 0; j < 4; ++j) {
        t[8 * i + j] = _mm512_shuffle_f32x4(r[8 * i + j], r[8 * i + j + 4], 0x88);
        t[8 * i + j + 4] = _mm512_shuffle_f32x4(r[8 * i + j], r[8 * i + j + 4], 0xdd);
      }
    for (int j = 0; j < 8; ++j) {
      r[j] = _mm512_shuffle_f32x4(t[j], t[j + 8], 0x88);
      r[j + 8] = _mm512_shuffle_f32x4(t[j], t[j + 8], 0xdd);
    }
    for (int i = 0; i < 16; ++i) _mm512_storeu_ps(out + std::size_t(i) * out_stride, r[i]);
    return;
  }
#endif
#if ORBITFORGE_SIMD_ENABLED && defined(__AVX__)
  // 8 x 8 floats and 4 x 4 doubles on AVX: the plain loop's 2 B::size^2 scalar
  // loads and stores were a third of the projection's time on an AVX2 machine.
  if constexpr (std::is_same<typename B::value_type, float>::value && B::size == 8) {
    __m256 r[8], t[8];
    for (int i = 0; i < 8; ++i) r[i] = _mm256_loadu_ps(in + std::size_t(i) * in_stride);
    for (int i = 0; i < 4; ++i) {  // row pairs interleaved: (a0 b0 a1 b1 | a4 b4 a5 b5), (a2 b2 a3 b3 | a6 ...)
      t[2 * i] = _mm256_unpacklo_ps(r[2 * i], r[2 * i + 1]);
      t[2 * i + 1] = _mm256_unpackhi_ps(r[2 * i], r[2 * i + 1]);
    }
    for (int i = 0; i < 2; ++i) {  // four rows' column j in each 128-bit half: (a_j b_j c_j d_j | a_j+4 ...)
      r[4 * i + 0] = _mm256_shuffle_ps(t[4 * i], t[4 * i + 2], 0x44);
      r[4 * i + 1] = _mm256_shuffle_ps(t[4 * i], t[4 * i + 2], 0xee);
      r[4 * i + 2] = _mm256_shuffle_ps(t[4 * i + 1], t[4 * i + 3], 0x44);
      r[4 * i + 3] = _mm256_shuffle_ps(t[4 * i + 1], t[4 * i + 3], 0xee);
    }
    for (int j = 0; j < 4; ++j) {  // the halves of rows a-d and e-h joined
      _mm256_storeu_ps(out + std::size_t(j) * out_stride, _mm256_permute2f128_ps(r[j], r[j + 4], 0x20));
      _mm256_storeu_ps(out + std::size_t(j + 4) * out_stride, _mm256_permute2f128_ps(r[j], r[j + 4], 0x31));
    }
    return;
  }
  if constexpr (std::is_same<typename B::value_type, double>::value && B::size == 4) {
    __m256d r[4];
    for (int i = 0; i < 4; ++i) r[i] = _mm256_loadu_pd(in + std::size_t(i) * in_stride);
    const __m256d t0 = _mm256_unpacklo_pd(r[0], r[1]), t1 = _mm256_unpackhi_pd(r[0], r[1]);  // (a0 b0 | a2 b2), (a1 b1 | a3 b3)
    const __m256d t2 = _mm256_unpacklo_pd(r[2], r[3]), t3 = _mm256_unpackhi_pd(r[2], r[3]);
    _mm256_storeu_pd(out, _mm256_permute2f128_pd(t0, t2, 0x20));
    _mm256_storeu_pd(out + out_stride, _mm256_permute2f128_pd(t1, t3, 0x20));
    _mm256_storeu_pd(out + 2 * out_stride, _mm256_permute2f128_pd(t0, t2, 0x31));
    _mm256_storeu_pd(out + 3 * out_stride, _mm256_permute2f128_pd(t1, t3, 0x31));
    return;
  }
#endif
  for (std::size_t r = 0; r < B::size; ++r)
    for (std::size_t c = 0; c < B::size; ++c) out[c * out_stride + r] = in[r * in_stride + c];
}

// 2^x for x <= 0 (values below the floor give 2^floor, which no caller can tell
// from 0: 2^-125 in float). 2^x = 2^n 2^f, n = round(x), f = x - n in
// [-1/2, 1/2] exactly; 2^f by a minimax polynomial (Remez on the relative
// error, fitted for this library): degree 6 for float, 11 for double, relative
// error 1.3 and 1.4 units in the last place, as close as exp() itself. Cheaper
// than exp(): no range reduction by ln 2 and no special-value selects. Lanes
// with x > 0 give 2^x only while it stays finite (the rasterizer masks them).
namespace detail {
template <class T> struct Exp2Poly;
template <> struct Exp2Poly<float> {
  static constexpr int degree = 6;
  static constexpr float floor = -125.0f;
  static constexpr float c[degree + 1] = {1.0000000005541665f,    0.69314720573726808f,   0.24022646890634097f,
                                          0.055503287769647345f,  0.0096184889571141198f, 0.0013399931219338504f,
                                          0.0001534581200314986f};
};
template <> struct Exp2Poly<double> {
  static constexpr int degree = 11;
  static constexpr double floor = -1021.0;
  static constexpr double c[degree + 1] = {
      0.999999999999999997018,     0.693147180559945331275,     0.24022650695910157256,
      0.0555041086648198804946,    0.00961812910758797953049,   0.00133335581467958354415,
      0.000154035304629216990711,  1.52527334864696353823e-05,  1.3215432901575225204e-06,
      1.01781989117590793696e-07,  7.07413586534218884698e-09,  4.43520817790843743792e-10};
};
}  // namespace detail

template <class B>
inline B exp2_nonpositive(const B& x) {
  using T = typename B::value_type;
  using P = detail::Exp2Poly<T>;
  const B y = simd::max(x, B(P::floor));
  const B n = simd::round_nearest(y);
  const B f = y - n;
  B p(P::c[P::degree]);
  for (int k = P::degree - 1; k >= 0; --k) p = simd::fma(p, f, B(P::c[k]));
  return simd::ldexp_int(p, n);
}

}  // namespace simd
}  // namespace orbitforge

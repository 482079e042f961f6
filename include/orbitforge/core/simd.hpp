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
//   + - * / and unary -, comparisons < <= > >= giving M, masks combine with & | ~,
//   fma(x, y, z) = x*y+z, exp, fast_exp, min, max, abs, sqrt, select(m, a, b),
//   hadd(b) (sum of lanes; xsimd 8.1 has hadd, not reduce_add), any(m), all(m).
#include <cmath>
#include <cstddef>
#include <cstdint>

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

// ---------------------------------------------------------------- scalar path
template <class T>
struct scalar_mask {
  bool v = false;
  scalar_mask() = default;
  scalar_mask(bool b) : v(b) {}
  friend scalar_mask operator&(scalar_mask a, scalar_mask b) { return a.v && b.v; }
  friend scalar_mask operator|(scalar_mask a, scalar_mask b) { return a.v || b.v; }
  friend scalar_mask operator~(scalar_mask a) { return !a.v; }
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
  friend scalar_mask<T> operator<(scalar_batch a, scalar_batch b) { return a.v < b.v; }
  friend scalar_mask<T> operator<=(scalar_batch a, scalar_batch b) { return a.v <= b.v; }
  friend scalar_mask<T> operator>(scalar_batch a, scalar_batch b) { return a.v > b.v; }
  friend scalar_mask<T> operator>=(scalar_batch a, scalar_batch b) { return a.v >= b.v; }
  scalar_batch& operator+=(scalar_batch b) { v += b.v; return *this; }
  scalar_batch& operator*=(scalar_batch b) { v *= b.v; return *this; }
};

template <class T> inline scalar_batch<T> fma(scalar_batch<T> x, scalar_batch<T> y, scalar_batch<T> z) { return std::fma(x.v, y.v, z.v); }
template <class T> inline scalar_batch<T> exp(scalar_batch<T> x) { return std::exp(x.v); }
template <class T> inline scalar_batch<T> min(scalar_batch<T> x, scalar_batch<T> y) { return y.v < x.v ? y.v : x.v; }
template <class T> inline scalar_batch<T> max(scalar_batch<T> x, scalar_batch<T> y) { return x.v < y.v ? y.v : x.v; }
template <class T> inline scalar_batch<T> abs(scalar_batch<T> x) { return std::abs(x.v); }
template <class T> inline scalar_batch<T> sqrt(scalar_batch<T> x) { return std::sqrt(x.v); }
template <class T> inline scalar_batch<T> select(scalar_mask<T> m, scalar_batch<T> a, scalar_batch<T> b) { return m.v ? a : b; }
template <class T> inline T hadd(scalar_batch<T> x) { return x.v; }
template <class T> inline bool any(scalar_mask<T> m) { return m.v; }
template <class T> inline bool all(scalar_mask<T> m) { return m.v; }
template <class T> inline scalar_batch<T> ldexp_int(scalar_batch<T> x, scalar_batch<T> n) { return std::ldexp(x.v, int(n.v)); }
template <class T> inline scalar_batch<T> round_nearest(scalar_batch<T> x) { return std::nearbyint(x.v); }

template <class B> struct mask_of;
template <class T> struct mask_of<scalar_batch<T>> { using type = scalar_mask<T>; };

// ---------------------------------------------------------------- xsimd path
#if ORBITFORGE_SIMD_ENABLED
template <class T, class A> inline xsimd::batch<T, A> fma(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y, const xsimd::batch<T, A>& z) { return xsimd::fma(x, y, z); }
template <class T, class A> inline xsimd::batch<T, A> exp(const xsimd::batch<T, A>& x) { return xsimd::exp(x); }
template <class T, class A> inline xsimd::batch<T, A> min(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y) { return xsimd::min(x, y); }
template <class T, class A> inline xsimd::batch<T, A> max(const xsimd::batch<T, A>& x, const xsimd::batch<T, A>& y) { return xsimd::max(x, y); }
template <class T, class A> inline xsimd::batch<T, A> abs(const xsimd::batch<T, A>& x) { return xsimd::abs(x); }
template <class T, class A> inline xsimd::batch<T, A> sqrt(const xsimd::batch<T, A>& x) { return xsimd::sqrt(x); }
template <class T, class A> inline xsimd::batch<T, A> select(const xsimd::batch_bool<T, A>& m, const xsimd::batch<T, A>& a, const xsimd::batch<T, A>& b) { return xsimd::select(m, a, b); }
template <class T, class A> inline T hadd(const xsimd::batch<T, A>& x) { return xsimd::hadd(x); }
template <class T, class A> inline bool any(const xsimd::batch_bool<T, A>& m) { return xsimd::any(m); }
template <class T, class A> inline bool all(const xsimd::batch_bool<T, A>& m) { return xsimd::all(m); }
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

// exp(x) for x <= 0 by 2^(x log2 e) = 2^n 2^f, |f| <= 1/2, with a degree-4
// Taylor polynomial for 2^f: relative error below 5e-5, no special-value
// handling (inputs are clamped to where 2^n stays normal). A speed setting;
// the exact path uses exp().
template <class B>
inline B fast_exp(const B& x) {
  using T = typename B::value_type;
  const B y = simd::max(x * B(T(1.4426950408889634)), B(T(-120)));
  const B n = simd::round_nearest(y);
  const B t = (y - n) * B(T(0.6931471805599453));  // |t| <= ln2 / 2
  B p = simd::fma(B(T(1.0 / 24)), t, B(T(1.0 / 6)));
  p = simd::fma(p, t, B(T(0.5)));
  p = simd::fma(p, t, B(T(1)));
  p = simd::fma(p, t, B(T(1)));
  return simd::ldexp_int(p, n);
}

}  // namespace simd
}  // namespace orbitforge

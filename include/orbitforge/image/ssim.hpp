#pragma once
// Structural similarity (SSIM) of two interleaved images (core/image.hpp), values
// in [0, 1], and its vector-Jacobian product with respect to the first image.
// Both the training loss (train/losses.hpp) and the quality metrics
// (metrics/image.hpp) use it, so it sits below both.
//
// SSIM follows the usual PyTorch 3DGS implementation exactly: an 11x11 Gaussian window
// (sigma 1.5, the outer product of a normalised 1D Gaussian, so it sums to 1),
// C1 = 0.01^2, C2 = 0.03^2, each channel separately, and conv2d with padding = 5:
// pixels outside the image count as zero in every windowed sum (of x, y, x^2, y^2, xy)
// and the window weights are NOT renormalised near the border. So SSIM near the border
// differs from a "valid-window" SSIM; this is deliberate, to match the published losses.
//
//   mu_x = G*x, mu_y = G*y, s_xx = G*(x^2) - mu_x^2, s_yy = G*(y^2) - mu_y^2,
//   s_xy = G*(xy) - mu_x mu_y,
//   ssim = (2 mu_x mu_y + C1)(2 s_xy + C2) / ((mu_x^2 + mu_y^2 + C1)(s_xx + s_yy + C2)).
//
// The 2D filter runs as two 1D passes (rows, then columns), which is exact for a
// separable window under zero padding. The backward pass filters three per-pixel
// derivative maps with the same window: zero-padded convolution with a symmetric
// window is its own adjoint. Rows of the intermediate maps are planar ([map][x]), so
// the per-pixel SSIM arithmetic runs on contiguous arrays and vectorises (the
// interleaved [x][map] layout left it scalar, most of the loss's time).
// A loss, whose weight on SSIM is known before the pass, takes the value and the
// gradient in one pass (ssim_and_vjp_with): each band's derivative rows go
// straight from the forward filter into the backward one instead of through a
// whole-image map, which left the loss waiting on memory in training.
// All work is split over rows with parallel_for; partial
// sums are kept per row and added in row order, so results do not depend on the thread
// count. A caller-owned SsimWorkspace holds every buffer: after the first call at a
// given size nothing allocates.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"

#if ORBITFORGE_SIMD_ENABLED && defined(__AVX512F__)
#include <immintrin.h>
#endif

namespace orbitforge {

struct SsimParams {
  int window = 11;      // window side in pixels (odd)
  double sigma = 1.5;   // Gaussian standard deviation in pixels
  double c1 = 0.01 * 0.01;
  double c2 = 0.03 * 0.03;
};

// Buffers reused across calls. One workspace serves one forward/backward pair at a
// time; ssim_vjp reads what the preceding ssim call on the same images left here.
template <class Scalar>
struct SsimWorkspace {
  int width = 0, height = 0, channels = 0;  // shape of the last forward pass
  bool forward_done = false;
  SsimParams params;                        // params of the last forward pass
  std::vector<Scalar> window;               // [window] normalised 1D weights
  std::vector<Scalar> dmaps;                // [H][3C][r zeros, W, r zeros] d mean-SSIM / d(mu_x, G*x^2, G*xy)
  std::vector<std::vector<Scalar>> rows;    // [worker] its band filters' rows (BandFilter2D::memory_values)
  std::vector<double> row_sums;             // [H] per-row partial sums
  std::vector<double> abs_rows, sq_rows;    // [H] combined_loss: per-row sums of |d| and d^2
  // How the window-11 forward runs, not what it gives (the same bits either
  // way): map four rows straight from the column pass (20 batches live), or
  // store the filtered planes and map them. Fused by default where the 20
  // batches fit in registers; on AVX2 they spill, and the fused loss took
  // 1.14-1.37x the separate passes' time.
  bool fuse_map = simd::vector_registers >= 32;
};

namespace ssim_detail {

inline void check_pair(const char* who, int pw, int ph, int pc, int tw, int th, int tc) {
  ensure(pw == tw && ph == th && pc == tc, who, ": prediction is ", pw, "x", ph, "x", pc,
         " but target is ", tw, "x", th, "x", tc);
  ensure(pw > 0 && ph > 0 && pc > 0, who, ": empty image ", pw, "x", ph, "x", pc);
}

template <class Scalar>
void check_images(const char* who, const Image<Scalar>& pred, const Image<Scalar>& target) {
  check_pair(who, pred.width, pred.height, pred.channels, target.width, target.height, target.channels);
  ensure(pred.data.size() == pred.pixel_count() * std::size_t(pred.channels) &&
             target.data.size() == target.pixel_count() * std::size_t(target.channels),
         who, ": image data size does not match its width x height x channels");
}

// Normalised 1D Gaussian of `size` taps centred on size/2.
template <class Scalar>
void gaussian_window(const SsimParams& p, std::vector<Scalar>& w) {
  ensure(p.window >= 1 && p.window % 2 == 1, "ssim: window size must be odd and positive, got ", p.window);
  ensure(p.sigma > 0 && std::isfinite(p.sigma), "ssim: sigma must be positive, got ", p.sigma);
  w.resize(std::size_t(p.window));
  const int r = p.window / 2;
  double sum = 0;
  std::vector<double> g(std::size_t(p.window));
  for (int k = 0; k < p.window; ++k) {
    const double d = k - r;
    g[std::size_t(k)] = std::exp(-d * d / (2 * p.sigma * p.sigma));
    sum += g[std::size_t(k)];
  }
  for (int k = 0; k < p.window; ++k) w[std::size_t(k)] = Scalar(g[std::size_t(k)] / sum);
}

#if ORBITFORGE_SIMD_ENABLED && defined(__AVX512F__)
namespace detail_sliding {
// acc = fma(w[R + d], at(R - d) + at(R + d), acc) for d = D .. R, in that order.
template <int R, int D, class At>
inline void add_pairs(__m512& acc, const __m512* wd, const At& at) {
  if constexpr (D <= R) {
    acc = _mm512_fmadd_ps(wd[D], _mm512_add_ps(at(std::integral_constant<int, R - D>()),
                                               at(std::integral_constant<int, R + D>())),
                          acc);
    add_pairs<R, D + 1>(acc, wd, at);
  }
}
}  // namespace detail_sliding

// row_taps for 16 float lanes and a radius of at most 8: the 2R + 1 shifted
// inputs of an output vector are lanes of two neighbouring registers
// (valignd), so each output vector loads one register instead of 2R + 1
// unaligned ones, most of which straddle two cache lines. The taps are added
// in row_taps' order, so the sums are the same bits. The input must hold R
// readable values before in[0] and after in[n - 1] (filter_row's padding);
// the last load is masked to them. Returns how many outputs it wrote (whole
// vectors).
template <int R>
std::size_t row_taps_sliding16(const float* in, float* out, std::size_t n, const float* w) {
  static_assert(R >= 1 && 2 * R <= 16, "the window must fit in two registers");
  if (n < 16) return 0;
  __m512 wd[R + 1];
  for (int d = 0; d <= R; ++d) wd[d] = _mm512_set1_ps(w[R + d]);
  __m512 lo = _mm512_loadu_ps(in - R);  // in[i - R .. i - R + 15]
  std::size_t i = 0;
  for (; i + 16 <= n; i += 16) {
    const float* next = in + i - R + 16;  // in[i - R + 16 ..], of which in[.. i + R + 15] is read
    const std::size_t readable = n + 2 * std::size_t(R) - i - 16;  // values up to in[n + R - 1]
    const __m512 hi = readable >= 16 ? _mm512_loadu_ps(next)
                                     : _mm512_maskz_loadu_ps(__mmask16((1u << readable) - 1u), next);
    const auto at = [&](auto k) {  // in[i - R + k .. i - R + k + 15]
      constexpr int shift = decltype(k)::value;
      if constexpr (shift == 16) {
        return hi;  // valignd takes shifts up to 15
      } else {
        return _mm512_castsi512_ps(_mm512_alignr_epi32(_mm512_castps_si512(hi), _mm512_castps_si512(lo), shift));
      }
    };
    __m512 acc = _mm512_mul_ps(wd[0], at(std::integral_constant<int, R>()));
    detail_sliding::add_pairs<R, 1>(acc, wd, at);
    _mm512_storeu_ps(out + i, acc);
    lo = hi;
  }
  return i;
}
#endif

// out[i] = w[r] in[i] + sum_{d = 1..r} w[r + d] (in[i - d] + in[i + d]) for i
// in [0, n), every tap inside the row (the window is symmetric, so taps are
// added in pairs, d = 1 .. r in order). R > 0 fixes the radius at compile time
// so that the taps unroll (a runtime tap loop was most of the row pass). Each
// output vector sums all its taps in a register.
template <int R, class Scalar>
void row_taps(const Scalar* in, Scalar* out, std::size_t n, const Scalar* w, int r_runtime) {
  using B = simd::native_batch<Scalar>;
  const int r = R > 0 ? R : r_runtime;
  const Scalar wc = w[r];
  std::size_t i = 0;
#if ORBITFORGE_SIMD_ENABLED && defined(__AVX512F__)
  if constexpr (R > 0 && 2 * R <= 16 && std::is_same<Scalar, float>::value && B::size == 16)
    i = row_taps_sliding16<R>(in, out, n, w);
#endif
  for (; i + B::size <= n; i += B::size) {
    B acc = B(wc) * B::load_unaligned(in + i);
    for (int d = 1; d <= r; ++d)
      acc = simd::fma(B(w[r + d]), B::load_unaligned(in + i - d) + B::load_unaligned(in + i + d), acc);
    acc.store_unaligned(out + i);
  }
  for (; i < n; ++i) {
    Scalar acc = wc * in[i];
    for (int d = 1; d <= r; ++d) acc = std::fma(w[r + d], in[i - d] + in[i + d], acc);
    out[i] = acc;
  }
}

// out[x] = sum_d w[r + d] in[x + d] over |d| <= r, in[] zero outside [0, width),
// for each of `planes` rows of `width` values. The rows lie `width + 2r` apart
// with r zeros on each side (padded_row_stride), so that every output runs the
// unrolled taps, where the 2r outputs at a row's ends had been summed one tap
// at a time behind bounds tests (docs/benchmarks.md measures it). A zero tap adds
// exactly nothing, so the sums are those of the taps cut at the row's ends.
// (The source rows are written padded where they are made: copying each row
// between zeros just before filtering it was slower than the bounds tests, its
// loads waiting on the copy's stores.)
template <class Scalar>
void filter_row(const Scalar* __restrict in, Scalar* __restrict out, int width, int planes, const Scalar* w, int r) {
  const std::size_t n = std::size_t(width), stride = n + 2 * std::size_t(r);
  for (int p = 0; p < planes; ++p, in += stride, out += width) {
    if (r == 5) row_taps<5>(in + r, out, n, w, r);  // the default 11-tap window
    else row_taps<0>(in + r, out, n, w, r);
  }
}

// Values from one padded plane to the next: the plane's width and r zeros on each side.
inline std::size_t padded_row_stride(int width, int r) { return std::size_t(width) + 2 * std::size_t(r); }

// The column pass: out[k][i] = w[r] in[k + r][i] + sum_{d = 1..r} w[r + d]
// (in[k + r - d][i] + in[k + r + d][i]) for four consecutive output rows (k =
// 0 .. 3), i in [0, n); in: 2r + 4 row pointers. The taps are added as row_taps
// adds them (pairs, d = 1 .. r in order), so every output is the same sum
// whatever the grouping. Four rows at a time read each input row from L2 once
// and the repeats from L1: reading every tap of every row from the ring (in L2)
// made the column pass bandwidth bound. column_sums4 sums lanes i .. i +
// B::size of the four rows into a[0..3], column_sum1 value i of row k.
template <int R, class B, class Scalar>
inline void column_sums4(const Scalar* const* row, std::size_t i, const Scalar* w, B (&a)[4]) {
  const B wc(w[R]);
  B a0 = wc * B::load_unaligned(row[R] + i), a1 = wc * B::load_unaligned(row[R + 1] + i);
  B a2 = wc * B::load_unaligned(row[R + 2] + i), a3 = wc * B::load_unaligned(row[R + 3] + i);
  for (int d = 1; d <= R; ++d) {
    const B wd(w[R + d]);
    a0 = simd::fma(wd, B::load_unaligned(row[R - d] + i) + B::load_unaligned(row[R + d] + i), a0);
    a1 = simd::fma(wd, B::load_unaligned(row[R + 1 - d] + i) + B::load_unaligned(row[R + 1 + d] + i), a1);
    a2 = simd::fma(wd, B::load_unaligned(row[R + 2 - d] + i) + B::load_unaligned(row[R + 2 + d] + i), a2);
    a3 = simd::fma(wd, B::load_unaligned(row[R + 3 - d] + i) + B::load_unaligned(row[R + 3 + d] + i), a3);
  }
  a[0] = a0;
  a[1] = a1;
  a[2] = a2;
  a[3] = a3;
}

template <int R, class Scalar>
inline Scalar column_sum1(const Scalar* const* row, int k, std::size_t i, const Scalar* w) {
  Scalar acc = w[R] * row[k + R][i];
  for (int d = 1; d <= R; ++d) acc = std::fma(w[R + d], row[k + R - d][i] + row[k + R + d][i], acc);
  return acc;
}

template <int R, class Scalar>
void column_taps4(const Scalar* const* in, Scalar* const* out, std::size_t n, const Scalar* w) {
  using B = simd::native_batch<Scalar>;
  const Scalar* row[2 * R + 4];
  for (int j = 0; j < 2 * R + 4; ++j) row[j] = in[j];
  std::size_t i = 0;
  for (; i + B::size <= n; i += B::size) {
    B a[4];
    column_sums4<R>(row, i, w, a);
    for (int k = 0; k < 4; ++k) a[k].store_unaligned(out[k] + i);
  }
  for (; i < n; ++i)
    for (int k = 0; k < 4; ++k) out[k][i] = column_sum1<R>(row, k, i, w);
}

// One output row of the column pass, any radius: the same sum as column_taps4.
template <class Scalar>
void column_taps1(const Scalar* const* in, Scalar* out, std::size_t n, const Scalar* w, int r) {
  using B = simd::native_batch<Scalar>;
  std::size_t i = 0;
  for (; i + B::size <= n; i += B::size) {
    B acc = B(w[r]) * B::load_unaligned(in[r] + i);
    for (int d = 1; d <= r; ++d)
      acc = simd::fma(B(w[r + d]), B::load_unaligned(in[r - d] + i) + B::load_unaligned(in[r + d] + i), acc);
    acc.store_unaligned(out + i);
  }
  for (; i < n; ++i) {
    Scalar acc = w[r] * in[r][i];
    for (int d = 1; d <= r; ++d) acc = std::fma(w[r + d], in[r - d][i] + in[r + d][i], acc);
    out[i] = acc;
  }
}

// p advanced to the next cache line (p itself when it starts one).
template <class Scalar>
Scalar* align_to_line(Scalar* p) {
  constexpr std::size_t kLine = 64 / sizeof(Scalar);
  return p + (kLine - reinterpret_cast<std::uintptr_t>(p) / sizeof(Scalar) % kLine) % kLine;
}

// The 2D filter over one band of output rows [y0, y1), without materialising
// the row-filtered image: it keeps the last 2r + 4 row-filtered rows in a ring
// (about 1 MB for the forward at 896 wide) and filters along columns from
// there, four output rows at a time (column_taps4). A full-image intermediate
// made the loss memory bound (it scaled 1.3x on two cores). A band reads the
// r source rows on each side of it, which the neighbouring bands filter too.
//   source(y, scratch) -> pointer to row y's `planes` planes of W values, each
//     between r zeros (padded_row_stride apart); it may fill scratch, which
//     has that layout with its zeros in place. Rows are pulled once each, in
//     increasing order, from max(0, y0 - r) to min(H, y1 + r) - 1.
// next() makes the following rows; each output row is the same sum in the same
// order whatever the banding, so results do not depend on the thread count.
template <class Scalar>
class BandFilter2D {
 public:
  static constexpr int K = 4;  // output rows per column pass

  // Scalars of working memory one band filter needs, a cache line of slack included.
  static std::size_t memory_values(int W, int planes, int r) {
    const std::size_t len = std::size_t(planes) * std::size_t(W);
    return std::size_t(2 * r + K + K + 1) * len + std::size_t(planes) * padded_row_stride(W, r) + kLine;
  }

  BandFilter2D(Scalar* memory, int W, int H, int planes, const Scalar* w, int r, int y0, int y1)
      : W_(W), H_(H), planes_(planes), r_(r), y_(y0), y1_(y1), next_(std::max(0, y0 - r)), w_(w) {
    // The ring starts on a cache line: with len a multiple of 16 values every
    // ring row is then aligned, and the column pass's loads and the row pass's
    // stores do not straddle lines (docs/benchmarks.md).
    memory = align_to_line(memory);
    len_ = std::size_t(planes) * std::size_t(W);
    ring_rows_ = 2 * r + K;
    ring_ = memory;
    raw_ = ring_ + std::size_t(ring_rows_) * len_;
    const std::size_t padded_len = std::size_t(planes) * padded_row_stride(W, r);
    Scalar* cols = raw_ + padded_len;
    zeros_ = cols + std::size_t(K) * len_;
    std::fill(zeros_, zeros_ + len_, Scalar(0));
    std::fill(raw_, raw_ + padded_len, Scalar(0));
    for (int k = 0; k < K; ++k) out_[k] = cols + std::size_t(k) * len_;
    if (2 * r + K > int(in_fixed_.size())) {
      in_more_.resize(std::size_t(2 * r + K));
      in_ = in_more_.data();
    }
  }
  BandFilter2D(const BandFilter2D&) = delete;  // in_ may point into the object
  BandFilter2D& operator=(const BandFilter2D&) = delete;

  bool done() const { return y_ >= y1_; }
  int row() const { return y_; }  // the first row the next call makes

  // Filters the rows [row(), row() + n) with n = min(K, y1 - row()) and returns n;
  // output(k) is row row() + k until the next call.
  template <class Source>
  int next(Source&& source) {
    return next_with(source, [this](const Scalar* const* in, int rows) { column_pass(in, rows); });
  }

  // As next(), with the caller's column pass: columns(in, n) gets the 2r + n
  // row-filtered rows that output rows row() .. row() + n - 1 are summed from
  // (row k from in[k .. k + 2r]); column_pass(in, n) is the filter's own, into
  // output().
  template <class Source, class Columns>
  int next_with(Source&& source, Columns&& columns) {
    const int rows = std::min(K, y1_ - y_), win = 2 * r_ + 1;
    for (; next_ <= std::min(H_ - 1, y_ + rows - 1 + r_); ++next_)
      filter_row(source(next_, raw_), ring_ + std::size_t(next_ % ring_rows_) * len_, W_, planes_, w_, r_);
    // Rows missing at the image's top or bottom read a zero row.
    for (int j = 0; j < rows + win - 1; ++j) {
      const int yy = y_ - r_ + j;
      in_[j] = yy < 0 || yy >= H_ ? zeros_ : ring_ + std::size_t(yy % ring_rows_) * len_;
    }
    columns(static_cast<const Scalar* const*>(in_), rows);
    y_ += rows;
    return rows;
  }
  void column_pass(const Scalar* const* in, int rows) {
    if (rows == K && r_ == 5) {  // the default 11-tap window
      column_taps4<5>(in, out_, len_, w_);
    } else {
      for (int k = 0; k < rows; ++k) column_taps1(in + k, out_[k], len_, w_, r_);
    }
  }
  Scalar* output(int k) const { return out_[k]; }

 private:
  static constexpr std::size_t kLine = 64 / sizeof(Scalar);
  int W_, H_, planes_, r_, y_, y1_, next_, ring_rows_ = 0;
  const Scalar* w_;
  std::size_t len_ = 0;
  Scalar *ring_ = nullptr, *raw_ = nullptr, *zeros_ = nullptr;
  Scalar* out_[K];
  // The column pass's 2r + K input rows: in the object up to a 17-tap window,
  // so that a band allocates nothing.
  std::array<const Scalar*, 2 * 8 + K> in_fixed_{};
  std::vector<const Scalar*> in_more_;
  const Scalar** in_ = in_fixed_.data();
};

// Bands of at least 64 rows keep the overlap small; 4 per thread balance the load.
inline int filter_bands(int H, int threads) { return std::max(1, std::min(4 * threads, H / 64)); }

// Each worker's working memory: `values` scalars.
template <class Scalar>
Scalar* worker_memory(SsimWorkspace<Scalar>& ws, int worker, std::size_t values) {
  std::vector<Scalar>& b = ws.rows[std::size_t(worker)];
  if (b.size() < values) b.resize(values);
  return b.data();
}

// The 2D filter of the whole image in bands of rows on `threads` threads:
// band_body(f) runs each band's filter f (`planes` planes, weights w, radius
// r) to its end, calling f.next() or f.next_with() until f.done().
template <class Scalar, class Band>
void filter_2d_bands(SsimWorkspace<Scalar>& ws, int W, int H, int planes, const Scalar* w, int r, int threads,
                     Band&& band_body) {
  if (ws.rows.size() < std::size_t(threads)) ws.rows.resize(std::size_t(threads));
  const int bands = filter_bands(H, threads);
  parallel_for(std::size_t(bands), threads, [&](std::size_t band, int worker) {
    const int y0 = int(std::size_t(H) * band / std::size_t(bands));
    const int y1 = int(std::size_t(H) * (band + 1) / std::size_t(bands));
    BandFilter2D<Scalar> f(worker_memory(ws, worker, BandFilter2D<Scalar>::memory_values(W, planes, r)), W, H, planes,
                           w, r, y0, y1);
    band_body(f);
  });
}

// The five planar products of one interleaved row (planes x, y, x^2, y^2, xy,
// each C channels, `stride` apart). CC > 0 fixes the channel count at compile
// time, which lets the compiler vectorise the stride-C loads.
template <int CC, class Scalar>
void products_row(const Scalar* __restrict x, const Scalar* __restrict t, Scalar* __restrict prod, std::size_t W,
                  std::size_t stride, int channels) {
  const std::size_t C = CC > 0 ? std::size_t(CC) : std::size_t(channels);
  for (std::size_t c = 0; c < C; ++c) {
    Scalar* __restrict px_ = prod + c * stride;
    Scalar* __restrict py_ = prod + (C + c) * stride;
    Scalar* __restrict pxx = prod + (2 * C + c) * stride;
    Scalar* __restrict pyy = prod + (3 * C + c) * stride;
    Scalar* __restrict pxy = prod + (4 * C + c) * stride;
    for (std::size_t px = 0; px < W; ++px) {
      const Scalar a = x[px * C + c], b = t[px * C + c];
      px_[px] = a;
      py_[px] = b;
      pxx[px] = a * a;
      pyy[px] = b * b;
      pxy[px] = a * b;
    }
  }
}

// v (interleaved row) = v_ssim (f0 + 2 x f1 + t f2) per channel from planar f
// (planes f0, f1, f2, each C channels); added to v when accumulate.
template <int CC, class Scalar>
void ssim_gradient_row(const Scalar* __restrict f, const Scalar* __restrict x, const Scalar* __restrict t,
                       Scalar* __restrict v, std::size_t W, int channels, Scalar v_ssim, bool accumulate) {
  const std::size_t C = CC > 0 ? std::size_t(CC) : std::size_t(channels);
  for (std::size_t c = 0; c < C; ++c) {
    const Scalar* __restrict f0 = f + c * W;
    const Scalar* __restrict f1 = f + (C + c) * W;
    const Scalar* __restrict f2 = f + (2 * C + c) * W;
    for (std::size_t px = 0; px < W; ++px) {
      const std::size_t i = px * C + c;
      const Scalar g = v_ssim * (f0[px] + 2 * x[i] * f1[px] + t[i] * f2[px]);
      v[i] = accumulate ? v[i] + g : g;
    }
  }
}

inline double sum_in_order(const std::vector<double>& v, std::size_t n) {
  double s = 0;
  for (std::size_t i = 0; i < n; ++i) s += v[i];
  return s;
}

}  // namespace ssim_detail

// ---------------------------------------------------------------- SSIM

namespace ssim_detail {

// One forward pass's shape and constants, and the rows it works on.
template <class Scalar>
struct SsimPass {
  const Image<Scalar>& pred;
  const Image<Scalar>& target;
  int W, H, C, r;
  std::size_t stride;  // padded_row_stride
  Scalar c1, c2, scale;

  bool fuse_map;       // SsimWorkspace::fuse_map

  SsimPass(const Image<Scalar>& p, const Image<Scalar>& t, const SsimParams& params, bool fuse_map_)
      : pred(p), target(t), W(p.width), H(p.height), C(p.channels), r(params.window / 2),
        stride(padded_row_stride(p.width, params.window / 2)), c1(Scalar(params.c1)), c2(Scalar(params.c2)),
        scale(Scalar(1.0 / (double(p.width) * double(p.height) * double(p.channels)))), fuse_map(fuse_map_) {}

  std::size_t at(int y) const { return std::size_t(y) * std::size_t(W) * std::size_t(C); }

  // Row y's five per-pixel products (planes x, y, x^2, y^2, xy, each C
  // channels), written between prod's zeros.
  const Scalar* products(int y, Scalar* prod) const {
    const Scalar* x = pred.data.data() + at(y);
    const Scalar* t = target.data.data() + at(y);
    if (C == 3) products_row<3>(x, t, prod + r, std::size_t(W), stride, C);
    else products_row<0>(x, t, prod + r, std::size_t(W), stride, C);
    return prod;
  }

  // The SSIM values of lanes from their five filtered values (G*x, G*y,
  // G*x^2, G*y^2, G*xy), returned, and their derivatives with respect to G*x,
  // G*x^2 and G*xy (already divided by the pixel-channel count) stored at d0,
  // d1, d2. Explicit SIMD: GCC leaves the per-pixel loop scalar ("no vectype").
  template <class B>
  B ssim_lanes(B mx, B my, B gxx, B gyy, B gxy, Scalar* d0, Scalar* d1, Scalar* d2) const {
    const B sxx = gxx - mx * mx, syy = gyy - my * my, sxy = gxy - mx * my;
    const B two(Scalar(2));
    const B a1 = two * mx * my + B(c1), a2 = two * sxy + B(c2);
    const B b1 = mx * mx + my * my + B(c1), b2 = sxx + syy + B(c2);
    const B inv = B(Scalar(1)) / (b1 * b2);
    const B val = a1 * a2 * inv;
    // d val / d mu_x holding G*x^2 and G*xy fixed (they carry their own terms).
    (B(scale) * (two * my * (a2 - a1) * inv - val * (two * mx / b1 - two * mx / b2))).store_unaligned(d0);
    (B(scale) * (-val / b2)).store_unaligned(d1);       // d val / d (G*x^2)
    (B(scale) * (two * a1 * inv)).store_unaligned(d2);  // d val / d (G*xy)
    return val;
  }

  // A row's SSIM values are summed per lane, then across lanes, channel by
  // channel: a sum in pixel order is a chain of dependent additions, one per
  // pixel, which took most of the map's time.
  static double channel_sum(simd::native_batch<Scalar> lane_sums, Scalar tail) {
    return double(simd::hadd(lane_sums) + tail);
  }

  // The SSIM map of a row from its five filtered planes m (W apart), and its
  // derivatives (ssim_lanes) into dm: the row's 3C padded planes, at their
  // first zero. Returns the row's sum of SSIM values.
  double map_row(const Scalar* m, Scalar* dm) const {
    using VB = simd::native_batch<Scalar>;
    using S1 = simd::scalar_batch<Scalar>;
    const std::size_t Wz = std::size_t(W);
    dm += r;
    double row_sum = 0;
    for (int c = 0; c < C; ++c) {
      const Scalar* __restrict g[5];
      for (int p = 0; p < 5; ++p) g[p] = m + std::size_t(p * C + c) * Wz;
      Scalar* __restrict d0 = dm + std::size_t(c) * stride;
      Scalar* __restrict d1 = dm + std::size_t(C + c) * stride;
      Scalar* __restrict d2 = dm + std::size_t(2 * C + c) * stride;
      VB lane_sums(Scalar(0));
      std::size_t px = 0;
      for (; px + VB::size <= Wz; px += VB::size)
        lane_sums += ssim_lanes(VB::load_unaligned(g[0] + px), VB::load_unaligned(g[1] + px),
                                VB::load_unaligned(g[2] + px), VB::load_unaligned(g[3] + px),
                                VB::load_unaligned(g[4] + px), d0 + px, d1 + px, d2 + px);
      Scalar tail = 0;
      for (; px < Wz; ++px)
        tail += ssim_lanes(S1(g[0][px]), S1(g[1][px]), S1(g[2][px]), S1(g[3][px]), S1(g[4][px]), d0 + px, d1 + px,
                           d2 + px)
                    .v;
      row_sum += channel_sum(lane_sums, tail);
    }
    return row_sum;
  }

  // map_row of four consecutive rows straight from the column pass's 2r + 4
  // input rows (in, planes W apart; the default window, r = 5, weights w):
  // each lane's five filtered values are summed as column_taps4 sums them and
  // mapped while in registers, so the 5C filtered planes are never stored (the
  // column pass was bound by those stores). The same values, derivatives and
  // sums as column_taps4 then map_row. dm: row k's planes at dm + k dm_step.
  void map_rows4(const Scalar* const* in, const Scalar* w, Scalar* dm, std::size_t dm_step, double* sums) const {
    constexpr int R = 5, K = 4;
    using B = simd::native_batch<Scalar>;
    using S1 = simd::scalar_batch<Scalar>;
    const std::size_t Wz = std::size_t(W);
    const Scalar* row[2 * R + K];
    for (int j = 0; j < 2 * R + K; ++j) row[j] = in[j];
    for (int k = 0; k < K; ++k) sums[k] = 0;
    for (int c = 0; c < C; ++c) {
      std::size_t plane[5];
      for (int p = 0; p < 5; ++p) plane[p] = std::size_t(p * C + c) * Wz;
      Scalar* d[K][3];
      for (int k = 0; k < K; ++k)
        for (int q = 0; q < 3; ++q)
          d[k][q] = dm + std::size_t(k) * dm_step + std::size_t(r) + std::size_t(q * C + c) * stride;
      B lane_sums[K] = {B(Scalar(0)), B(Scalar(0)), B(Scalar(0)), B(Scalar(0))};
      std::size_t px = 0;
      for (; px + B::size <= Wz; px += B::size) {
        B g[5][K];
        for (int p = 0; p < 5; ++p) column_sums4<R>(row, plane[p] + px, w, g[p]);
        for (int k = 0; k < K; ++k)
          lane_sums[k] += ssim_lanes(g[0][k], g[1][k], g[2][k], g[3][k], g[4][k], d[k][0] + px, d[k][1] + px,
                                     d[k][2] + px);
      }
      Scalar tails[K] = {};
      for (; px < Wz; ++px)
        for (int k = 0; k < K; ++k) {
          S1 g[5];
          for (int p = 0; p < 5; ++p) g[p] = S1(column_sum1<R>(row, k, plane[p] + px, w));
          tails[k] += ssim_lanes(g[0], g[1], g[2], g[3], g[4], d[k][0] + px, d[k][1] + px, d[k][2] + px).v;
        }
      for (int k = 0; k < K; ++k) sums[k] += channel_sum(lane_sums[k], tails[k]);
    }
  }

  // The filter's next rows (f over this pass's 5C product planes, weights w)
  // mapped: their derivatives into dm + k dm_step (as map_row's dm), their sums
  // into sums[k]; returns how many rows. Four rows of the default window go
  // through map_rows4 when fuse_map is set, others through the filter's column
  // pass and map_row.
  template <class Source>
  int next_mapped(BandFilter2D<Scalar>& f, Source&& source, const Scalar* w, Scalar* dm, std::size_t dm_step,
                  double* sums) const {
    return f.next_with(source, [&](const Scalar* const* in, int rows) {
      if (fuse_map && rows == BandFilter2D<Scalar>::K && r == 5) {
        map_rows4(in, w, dm, dm_step, sums);
        return;
      }
      f.column_pass(in, rows);
      for (int k = 0; k < rows; ++k) sums[k] = map_row(f.output(k), dm + std::size_t(k) * dm_step);
    });
  }

  // Row y of v_pred from its three filtered derivative planes f (W apart).
  void gradient_row(int y, const Scalar* f, Scalar v_ssim, Image<Scalar>& v_pred, bool accumulate) const {
    const Scalar* x = pred.data.data() + at(y);
    const Scalar* t = target.data.data() + at(y);
    Scalar* v = v_pred.data.data() + at(y);
    if (C == 3) ssim_gradient_row<3>(f, x, t, v, std::size_t(W), C, v_ssim, accumulate);
    else ssim_gradient_row<0>(f, x, t, v, std::size_t(W), C, v_ssim, accumulate);
  }
};

// The workspace's record of a forward pass on these images (shape, window and
// the per-row sums); dmaps: whether the pass keeps the whole image's
// derivative maps for ssim_vjp (their zeros written once per shape).
template <class Scalar>
void begin_forward(SsimWorkspace<Scalar>& ws, const SsimPass<Scalar>& pass, const SsimParams& params, bool dmaps) {
  gaussian_window<Scalar>(params, ws.window);
  const std::size_t size = pass.stride * std::size_t(3 * pass.C) * std::size_t(pass.H);
  if (dmaps && (ws.width != pass.W || ws.height != pass.H || ws.channels != pass.C ||
                ws.params.window != params.window || ws.dmaps.size() != size))
    ws.dmaps.assign(size, Scalar(0));
  ws.row_sums.resize(std::size_t(pass.H));
  ws.width = pass.W;
  ws.height = pass.H;
  ws.channels = pass.C;
  ws.params = params;
  ws.forward_done = false;
}

template <class Scalar>
void check_gradient_image(const char* who, const Image<Scalar>& pred, Image<Scalar>& v_pred, bool accumulate) {
  if (accumulate) {
    ensure(v_pred.same_shape(pred) && v_pred.data.size() == pred.data.size(), who,
           ": accumulate into a gradient image of a different shape");
  } else if (!v_pred.same_shape(pred) || v_pred.data.size() != pred.data.size()) {
    v_pred = Image<Scalar>(pred.width, pred.height, pred.channels);
  }
}

}  // namespace ssim_detail

// inputs: pred, target [H][W][C] (values nominally in [0, 1]; C1, C2 assume range 1).
// Returns mean SSIM over pixels and channels. Leaves in `ws` what ssim_vjp needs.
// threads: 0 = default (see parallel_for).
template <class Scalar>
Scalar ssim(const Image<Scalar>& pred, const Image<Scalar>& target, SsimWorkspace<Scalar>& ws,
            const SsimParams& params = {}, int threads = 0) {
  using namespace ssim_detail;
  check_images("ssim", pred, target);
  threads = resolve_threads(threads);
  const SsimPass<Scalar> pass(pred, target, params, ws.fuse_map);
  begin_forward(ws, pass, params, true);
  const std::size_t row3 = pass.stride * std::size_t(3 * pass.C);
  const Scalar* w = ws.window.data();
  filter_2d_bands(ws, pass.W, pass.H, 5 * pass.C, w, pass.r, threads, [&](BandFilter2D<Scalar>& f) {
    const auto products = [&](int y, Scalar* prod) { return pass.products(y, prod); };
    while (!f.done()) {
      const std::size_t y = std::size_t(f.row());
      pass.next_mapped(f, products, w, ws.dmaps.data() + y * row3, row3, ws.row_sums.data() + y);
    }
  });
  const double total = sum_in_order(ws.row_sums, std::size_t(pass.H));
  ws.forward_done = true;
  return Scalar(total * double(pass.scale));
}

// inputs:      pred, target [H][W][C], exactly as passed to the preceding ssim() call
//              that filled `ws` (same params)
// grad output: v_ssim (scalar)
// grad input:  v_pred [H][W][C] (resized; overwritten, or added to when accumulate)
template <class Scalar>
void ssim_vjp(const Image<Scalar>& pred, const Image<Scalar>& target, Scalar v_ssim, SsimWorkspace<Scalar>& ws,
              Image<Scalar>& v_pred, bool accumulate = false, int threads = 0) {
  using namespace ssim_detail;
  check_images("ssim_vjp", pred, target);
  ensure(ws.forward_done && ws.width == pred.width && ws.height == pred.height && ws.channels == pred.channels,
         "ssim_vjp: the workspace holds no forward pass for a ", pred.width, "x", pred.height, "x",
         pred.channels, " image (call ssim() first with the same images and workspace)");
  check_gradient_image("ssim_vjp", pred, v_pred, accumulate);
  threads = resolve_threads(threads);
  const SsimPass<Scalar> pass(pred, target, ws.params, ws.fuse_map);
  const std::size_t row3 = pass.stride * std::size_t(3 * pass.C);
  // The forward maps are windowed sums, so the adjoint filters the derivative maps with
  // the same (symmetric, zero-padded) window.
  filter_2d_bands(ws, pass.W, pass.H, 3 * pass.C, ws.window.data(), pass.r, threads, [&](BandFilter2D<Scalar>& f) {
    const auto dmaps = [&](int y, Scalar*) -> const Scalar* { return ws.dmaps.data() + std::size_t(y) * row3; };
    while (!f.done()) {
      const int y = f.row(), rows = f.next(dmaps);
      for (int k = 0; k < rows; ++k) pass.gradient_row(y + k, f.output(k), v_ssim, v_pred, accumulate);
    }
  });
}

// SSIM and its vector-Jacobian product in one pass: the same value and the
// same v_pred (overwritten) as ssim() then ssim_vjp(..., accumulate = false),
// bit for bit, without the whole image's derivative maps. Each band of rows
// runs the forward filter r rows beyond its ends and feeds the derivative rows
// it makes straight into the backward filter, so they never leave the cache
// (the forward work of those 2r rows per band is done twice). v_ssim must be
// known before the pass (a loss's weight). after_forward_row(y) is called once
// per image row y when its SSIM values are summed, after_backward_row(y) once
// when its row of v_pred is written, each on the thread that did it and in no
// fixed order, so that a caller can do its own per-row work over the same
// images while their rows are in cache. The workspace keeps no forward pass
// for ssim_vjp.
template <class Scalar, class AfterForwardRow, class AfterBackwardRow>
Scalar ssim_and_vjp_with(const Image<Scalar>& pred, const Image<Scalar>& target, Scalar v_ssim,
                         SsimWorkspace<Scalar>& ws, Image<Scalar>& v_pred, const SsimParams& params, int threads,
                         AfterForwardRow&& after_forward_row, AfterBackwardRow&& after_backward_row) {
  using namespace ssim_detail;
  check_images("ssim", pred, target);
  check_gradient_image("ssim_vjp", pred, v_pred, false);
  threads = resolve_threads(threads);
  const SsimPass<Scalar> pass(pred, target, params, ws.fuse_map);
  begin_forward(ws, pass, params, false);
  const int W = pass.W, H = pass.H, S5 = 5 * pass.C, S3 = 3 * pass.C, r = pass.r;
  const Scalar* w = ws.window.data();
  using Filter = BandFilter2D<Scalar>;
  constexpr int K = Filter::K;
  constexpr std::size_t kLine = 64 / sizeof(Scalar);
  const std::size_t forward_values = Filter::memory_values(W, S5, r);
  const std::size_t row3 = pass.stride * std::size_t(S3);
  const std::size_t need = forward_values + Filter::memory_values(W, S3, r) + std::size_t(K) * row3 + kLine;
  if (ws.rows.size() < std::size_t(threads)) ws.rows.resize(std::size_t(threads));
  // Fewer, longer bands than the separate passes': each band's forward overlap is 2r rows.
  const int bands = std::max(1, std::min(2 * threads, H / 128));
  parallel_for(std::size_t(bands), threads, [&](std::size_t band, int worker) {
    const int y0 = int(std::size_t(H) * band / std::size_t(bands));
    const int y1 = int(std::size_t(H) * (band + 1) / std::size_t(bands));
    Scalar* memory = worker_memory(ws, worker, need);
    Filter forward(memory, W, H, S5, w, r, std::max(0, y0 - r), std::min(H, y1 + r));
    Filter backward(memory + forward_values, W, H, S3, w, r, y0, y1);
    // The derivative rows of the forward's last K rows, padded as the backward reads them.
    Scalar* dmaps = align_to_line(memory + forward_values + Filter::memory_values(W, S3, r));
    std::fill(dmaps, dmaps + std::size_t(K) * row3, Scalar(0));
    int made = forward.row();  // the first derivative row the buffer holds
    const auto derivative_row = [&](int y, Scalar*) -> const Scalar* {
      while (forward.row() <= y) {
        made = forward.row();
        double sums[K];
        const int rows = pass.next_mapped(
            forward, [&](int z, Scalar* prod) { return pass.products(z, prod); }, w, dmaps, row3, sums);
        for (int k = 0; k < rows; ++k) {
          const int z = made + k;
          if (z >= y0 && z < y1) {  // each row's sum and call once, in its own band
            ws.row_sums[std::size_t(z)] = sums[k];
            after_forward_row(z);
          }
        }
      }
      return dmaps + std::size_t(y - made) * row3;
    };
    while (!backward.done()) {
      const int y = backward.row(), rows = backward.next(derivative_row);
      for (int k = 0; k < rows; ++k) {
        pass.gradient_row(y + k, backward.output(k), v_ssim, v_pred, false);
        after_backward_row(y + k);
      }
    }
  });
  return Scalar(sum_in_order(ws.row_sums, std::size_t(H)) * double(pass.scale));
}

// Convenience for one-off evaluation (metrics): allocates its own workspace.
template <class Scalar>
Scalar ssim(const Image<Scalar>& pred, const Image<Scalar>& target, const SsimParams& params = {},
            int threads = 0) {
  SsimWorkspace<Scalar> ws;
  return ssim(pred, target, ws, params, threads);
}

}  // namespace orbitforge

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
// All work is split over rows with parallel_for; partial
// sums are kept per row and added in row order, so results do not depend on the thread
// count. A caller-owned SsimWorkspace holds every buffer: after the first call at a
// given size nothing allocates.
#include <algorithm>
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
  std::vector<std::vector<Scalar>> rows;    // [worker] ring of 2r + 1 filtered rows + scratch rows
  std::vector<double> row_sums;             // [H] per-row partial sums
  std::vector<double> abs_rows, sq_rows;    // [H] combined_loss: per-row sums of |d| and d^2
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
// made the column pass bandwidth bound.
template <int R, class Scalar>
void column_taps4(const Scalar* const* in, Scalar* const* out, std::size_t n, const Scalar* w) {
  using B = simd::native_batch<Scalar>;
  const Scalar* row[2 * R + 4];
  for (int j = 0; j < 2 * R + 4; ++j) row[j] = in[j];
  Scalar* o0 = out[0];
  Scalar* o1 = out[1];
  Scalar* o2 = out[2];
  Scalar* o3 = out[3];
  const B wc(w[R]);
  std::size_t i = 0;
  for (; i + B::size <= n; i += B::size) {
    B a0 = wc * B::load_unaligned(row[R] + i), a1 = wc * B::load_unaligned(row[R + 1] + i);
    B a2 = wc * B::load_unaligned(row[R + 2] + i), a3 = wc * B::load_unaligned(row[R + 3] + i);
    for (int d = 1; d <= R; ++d) {
      const B wd(w[R + d]);
      a0 = simd::fma(wd, B::load_unaligned(row[R - d] + i) + B::load_unaligned(row[R + d] + i), a0);
      a1 = simd::fma(wd, B::load_unaligned(row[R + 1 - d] + i) + B::load_unaligned(row[R + 1 + d] + i), a1);
      a2 = simd::fma(wd, B::load_unaligned(row[R + 2 - d] + i) + B::load_unaligned(row[R + 2 + d] + i), a2);
      a3 = simd::fma(wd, B::load_unaligned(row[R + 3 - d] + i) + B::load_unaligned(row[R + 3 + d] + i), a3);
    }
    a0.store_unaligned(o0 + i);
    a1.store_unaligned(o1 + i);
    a2.store_unaligned(o2 + i);
    a3.store_unaligned(o3 + i);
  }
  for (; i < n; ++i)
    for (int k = 0; k < 4; ++k) {
      Scalar acc = w[R] * row[k + R][i];
      for (int d = 1; d <= R; ++d) acc = std::fma(w[R + d], row[k + R - d][i] + row[k + R + d][i], acc);
      out[k][i] = acc;
    }
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

// The 2D filter over bands of rows, without materialising the row-filtered
// image: each worker keeps the last 2r + 4 row-filtered rows of its band in a
// ring (about 1 MB for the forward at 896 wide) and filters along columns from there, four output
// rows at a time (column_taps4). A full-image intermediate made the loss memory
// bound (it scaled 1.3x on two cores). Bands overlap by r rows on each side,
// which are filtered twice.
//   source(y, scratch) -> pointer to row y's `planes` planes of W values, each
//     between r zeros (padded_row_stride apart); it may fill scratch, which
//     has that layout with its zeros in place
//   sink(y, filtered, scratch) gets row y filtered in 2D (planes W apart) and a W-value scratch.
// Each output row is the same sum in the same order whatever the banding, so the
// results do not depend on the thread count.
template <class Scalar, class Source, class Sink>
void filter_2d_rows(SsimWorkspace<Scalar>& ws, int W, int H, int planes, const Scalar* w, int r, int threads,
                    Source&& source, Sink&& sink) {
  constexpr int K = 4;  // output rows per column pass
  const std::size_t len = std::size_t(planes) * std::size_t(W);
  const int win = 2 * r + 1, ring_rows = win + K - 1;
  const std::size_t padded_len = std::size_t(planes) * padded_row_stride(W, r);
  // + one cache line, to start the ring on one: with len a multiple of 16
  // values every ring row is then aligned, and the column pass's loads and the
  // row pass's stores do not straddle lines (docs/benchmarks.md).
  constexpr std::size_t kLine = 64 / sizeof(Scalar);
  const std::size_t need = std::size_t(ring_rows + K + 1) * len + padded_len + std::size_t(W) + kLine;
  if (ws.rows.size() < std::size_t(threads)) ws.rows.resize(std::size_t(threads));
  for (auto& b : ws.rows)
    if (b.size() < need) b.resize(need);
  // Bands of at least 64 rows keep the overlap small; 4 per thread balance the load.
  const int bands = std::max(1, std::min(4 * threads, H / 64));
  parallel_for(std::size_t(bands), threads, [&](std::size_t band, int worker) {
    Scalar* ring = ws.rows[std::size_t(worker)].data();
    ring += (kLine - reinterpret_cast<std::uintptr_t>(ring) / sizeof(Scalar) % kLine) % kLine;
    Scalar* raw = ring + std::size_t(ring_rows) * len;  // one padded source row
    Scalar* cols = raw + padded_len;                     // K filtered output rows
    Scalar* zeros = cols + std::size_t(K) * len;
    Scalar* scratch = zeros + len;
    std::fill(zeros, zeros + len, Scalar(0));
    std::fill(raw, raw + padded_len, Scalar(0));
    std::vector<const Scalar*> in(std::size_t(K + win - 1));
    Scalar* out[K];
    for (int k = 0; k < K; ++k) out[k] = cols + std::size_t(k) * len;
    const int y0 = int(std::size_t(H) * band / std::size_t(bands));
    const int y1 = int(std::size_t(H) * (band + 1) / std::size_t(bands));
    auto ring_row = [&](int y) -> const Scalar* {
      return y < 0 || y >= H ? zeros : ring + std::size_t(y % ring_rows) * len;
    };
    int next = std::max(0, y0 - r);  // next source row to filter into the ring
    for (int y = y0; y < y1; y += K) {
      const int rows = std::min(K, y1 - y);
      for (; next <= std::min(H - 1, y + rows - 1 + r); ++next)
        filter_row(source(next, raw), ring + std::size_t(next % ring_rows) * len, W, planes, w, r);
      // Rows missing at the image's top or bottom read a zero row.
      for (int j = 0; j < rows + win - 1; ++j) in[std::size_t(j)] = ring_row(y - r + j);
      if (rows == K && r == 5) {  // the default 11-tap window
        column_taps4<5>(in.data(), out, len, w);
      } else {
        for (int k = 0; k < rows; ++k) column_taps1(in.data() + k, out[k], len, w, r);
      }
      for (int k = 0; k < rows; ++k) sink(y + k, out[k], scratch);
    }
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

// inputs: pred, target [H][W][C] (values nominally in [0, 1]; C1, C2 assume range 1).
// Returns mean SSIM over pixels and channels. Leaves in `ws` what ssim_vjp needs.
// threads: 0 = default (see parallel_for).
template <class Scalar>
Scalar ssim(const Image<Scalar>& pred, const Image<Scalar>& target, SsimWorkspace<Scalar>& ws,
            const SsimParams& params = {}, int threads = 0) {
  using namespace ssim_detail;
  check_images("ssim", pred, target);
  const int W = pred.width, H = pred.height, C = pred.channels;
  const int S5 = 5 * C, S3 = 3 * C;
  threads = resolve_threads(threads);

  gaussian_window<Scalar>(params, ws.window);
  const int r = params.window / 2;
  const std::size_t stride = padded_row_stride(W, r);
  // The derivative maps are the backward's source rows: padded, their zeros
  // written here once per shape.
  if (ws.width != W || ws.height != H || ws.channels != C || ws.params.window != params.window ||
      ws.dmaps.size() != stride * std::size_t(S3) * std::size_t(H))
    ws.dmaps.assign(stride * std::size_t(S3) * std::size_t(H), Scalar(0));
  ws.row_sums.resize(std::size_t(H));
  ws.width = W;
  ws.height = H;
  ws.channels = C;
  ws.params = params;
  ws.forward_done = false;

  const Scalar* w = ws.window.data();
  const Scalar c1 = Scalar(params.c1), c2 = Scalar(params.c2);
  const Scalar scale = Scalar(1.0 / (double(W) * double(H) * double(C)));

  // Per row: the five per-pixel products (planes x, y, x^2, y^2, xy, each C
  // channels), filtered in 2D, then the SSIM map and its derivatives with respect
  // to mu_x, G*x^2 and G*xy (already divided by the pixel-channel count).
  const std::size_t Wz = std::size_t(W);
  auto products = [&](int y, Scalar* prod) -> const Scalar* {
    const Scalar* x = pred.data.data() + std::size_t(y) * Wz * std::size_t(C);
    const Scalar* t = target.data.data() + std::size_t(y) * Wz * std::size_t(C);
    if (C == 3) products_row<3>(x, t, prod + r, Wz, stride, C);
    else products_row<0>(x, t, prod + r, Wz, stride, C);
    return prod;
  };
  auto ssim_row = [&](int yi, const Scalar* m, Scalar* vals) {
    const std::size_t y = std::size_t(yi);
    Scalar* dm = ws.dmaps.data() + y * stride * std::size_t(S3) + std::size_t(r);
    double row_sum = 0;
    for (int c = 0; c < C; ++c) {
      const Scalar* __restrict mmx = m + std::size_t(c) * Wz;
      const Scalar* __restrict mmy = m + std::size_t(C + c) * Wz;
      const Scalar* __restrict mxx = m + std::size_t(2 * C + c) * Wz;
      const Scalar* __restrict myy = m + std::size_t(3 * C + c) * Wz;
      const Scalar* __restrict mxy = m + std::size_t(4 * C + c) * Wz;
      Scalar* __restrict d0 = dm + std::size_t(c) * stride;
      Scalar* __restrict d1 = dm + std::size_t(C + c) * stride;
      Scalar* __restrict d2 = dm + std::size_t(2 * C + c) * stride;
      // Explicit SIMD: GCC leaves this loop scalar ("no vectype"), and it was
      // most of the loss's time.
      auto ssim_at = [&](auto lanes, std::size_t px) {
        using B = decltype(lanes);
        const B mx = B::load_unaligned(mmx + px), my = B::load_unaligned(mmy + px);
        const B sxx = B::load_unaligned(mxx + px) - mx * mx;
        const B syy = B::load_unaligned(myy + px) - my * my;
        const B sxy = B::load_unaligned(mxy + px) - mx * my;
        const B two(Scalar(2));
        const B a1 = two * mx * my + B(c1), a2 = two * sxy + B(c2);
        const B b1 = mx * mx + my * my + B(c1), b2 = sxx + syy + B(c2);
        const B inv = B(Scalar(1)) / (b1 * b2);
        const B val = a1 * a2 * inv;
        val.store_unaligned(vals + px);
        // d val / d mu_x holding G*x^2 and G*xy fixed (they carry their own terms).
        (B(scale) * (two * my * (a2 - a1) * inv - val * (two * mx / b1 - two * mx / b2))).store_unaligned(d0 + px);
        (B(scale) * (-val / b2)).store_unaligned(d1 + px);       // d val / d (G*x^2)
        (B(scale) * (two * a1 * inv)).store_unaligned(d2 + px);  // d val / d (G*xy)
      };
      using VB = simd::native_batch<Scalar>;
      std::size_t px = 0;
      for (; px + VB::size <= Wz; px += VB::size) ssim_at(VB(), px);
      for (; px < Wz; ++px) ssim_at(simd::scalar_batch<Scalar>(), px);
      // A separate sum keeps the loop above free of a float reduction, which
      // compilers do not vectorise without reassociating.
      Scalar plane_sum = 0;
      for (std::size_t px = 0; px < Wz; ++px) plane_sum += vals[px];
      row_sum += double(plane_sum);
    }
    ws.row_sums[y] = row_sum;
  };
  filter_2d_rows(ws, W, H, S5, w, r, threads, products, ssim_row);

  const double total = sum_in_order(ws.row_sums, std::size_t(H));
  ws.forward_done = true;
  return Scalar(total * double(scale));
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
  if (accumulate) {
    ensure(v_pred.same_shape(pred) && v_pred.data.size() == pred.data.size(),
           "ssim_vjp: accumulate into a gradient image of a different shape");
  } else if (!v_pred.same_shape(pred) || v_pred.data.size() != pred.data.size()) {
    v_pred = Image<Scalar>(pred.width, pred.height, pred.channels);
  }
  const int W = pred.width, H = pred.height, C = pred.channels;
  const int S3 = 3 * C;
  const std::size_t row3 = padded_row_stride(W, ws.params.window / 2) * std::size_t(S3);
  threads = resolve_threads(threads);
  const Scalar* w = ws.window.data();
  const int r = ws.params.window / 2;

  // The forward maps are windowed sums, so the adjoint filters the derivative maps with
  // the same (symmetric, zero-padded) window.
  auto dmap_row = [&](int y, Scalar*) -> const Scalar* { return ws.dmaps.data() + std::size_t(y) * row3; };
  auto gradient_row = [&](int yi, const Scalar* f, Scalar*) {
    const std::size_t at = std::size_t(yi) * std::size_t(W) * std::size_t(C);
    const Scalar* x = pred.data.data() + at;
    const Scalar* t = target.data.data() + at;
    Scalar* v = v_pred.data.data() + at;
    if (C == 3) ssim_gradient_row<3>(f, x, t, v, std::size_t(W), C, v_ssim, accumulate);
    else ssim_gradient_row<0>(f, x, t, v, std::size_t(W), C, v_ssim, accumulate);
  };
  filter_2d_rows(ws, W, H, S3, w, r, threads, dmap_row, gradient_row);
}

// Convenience for one-off evaluation (metrics): allocates its own workspace.
template <class Scalar>
Scalar ssim(const Image<Scalar>& pred, const Image<Scalar>& target, const SsimParams& params = {},
            int threads = 0) {
  SsimWorkspace<Scalar> ws;
  return ssim(pred, target, ws, params, threads);
}

}  // namespace orbitforge

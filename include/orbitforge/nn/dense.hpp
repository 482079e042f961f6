#pragma once
// The two dense products of an MLP layer over a batch of points stored as
// columns (mlp.hpp), for layers of up to about 64 units and chunks of about a
// thousand points (wider layers reuse each weight over too few points here;
// mlp.hpp gives those to Eigen's GEMM):
//
//   dense_forward           Z = act(W1 X1 + W2 X2 + b)   W R x K, X K x m, Z R x m
//                           (act: none or ReLU; optionally Z zero where a gate <= 0)
//   dense_accumulate_outer  G += D H^T, s += D 1          G R x K, D R x m, H K x m
//
// All column-major. A block of W's rows stays in registers while the columns of
// X stream by: no packed copy of X and no zero fill of Z, which a general GEMM
// makes on every call and which were about a third of the field's time at
// these sizes (bench_mlp). dense_forward's columns are independent sums in a
// fixed order, so they do not depend on how the columns are split between
// calls; dense_accumulate_outer adds its columns in order, 128 at a time.
// The gate and the row sums are the backward's ReLU mask and bias gradient,
// done while the values are in registers: as separate passes over the chunk
// they had cost as much as a tenth of the field's backward.
#include <Eigen/Core>
#include <algorithm>
#include <cstddef>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/simd.hpp"

namespace orbitforge {

// A weight matrix laid out for dense_forward: R x K column-major, its leading
// dimension rounded up to whole batches of B (rows past R hold zeros), so that
// every column's rows load as whole batches; the bias (optional) padded alike.
template <class Scalar>
struct DenseWeights {
  std::vector<Scalar> w, b;
  Eigen::Index rows = 0, cols = 0, ld = 0;

  // From R x K src with leading dimension ld_src (transpose: from src^T, src
  // then K x R); bias: R values or nullptr.
  template <class B>
  void assign(const Scalar* src, Eigen::Index ld_src, Eigen::Index r, Eigen::Index k, bool transpose,
              const Scalar* bias) {
    constexpr Eigen::Index L = Eigen::Index(B::size);
    rows = r;
    cols = k;
    ld = (r + L - 1) / L * L;
    w.assign(std::size_t(ld * k), Scalar(0));
    for (Eigen::Index c = 0; c < k; ++c)
      for (Eigen::Index i = 0; i < r; ++i) w[std::size_t(c * ld + i)] = transpose ? src[i * ld_src + c] : src[c * ld_src + i];
    b.assign(bias ? std::size_t(ld) : 0, Scalar(0));
    if (bias) std::copy_n(bias, r, b.begin());
  }
  // The weights from column c0 on (a DenseTerm's).
  const Scalar* column(Eigen::Index c0) const { return w.data() + c0 * ld; }
};

// One term W X of dense_forward: cols columns of weights (leading dimension
// ld, rows padded as in DenseWeights), X with cols rows and leading dimension ldx.
template <class Scalar>
struct DenseTerm {
  const Scalar* w;
  Eigen::Index ld, cols;
  const Scalar* x;
  Eigen::Index ldx;
};

namespace detail {

// Accumulators: NB batches of rows x NC columns. 32 vector registers
// (AVX-512) hold 4 x 4 with room for the weights; 16 registers hold 2 x 6
// (12 accumulators, 2 weights, 1 broadcast).
template <class B>
constexpr int dense_column_group() {
  return B::size == 1 ? 2 : simd::vector_registers >= 32 ? 4 : 6;
}
template <class B>
constexpr int dense_row_group() {
  return B::size == 1 || simd::vector_registers >= 32 ? 4 : 2;
}

// f(std::integral_constant<int, rem>) for 0 < rem < N, nothing for rem 0: the
// rows or columns left after the whole groups of N get one block as large as
// they are. (Columns one block each had left NB accumulators per block, too few
// to hide the multiply-add latency.)
template <int N, class F>
inline void with_remainder(int rem, F&& f) {
  if constexpr (N > 1) {
    if (rem == N - 1) {
      f(std::integral_constant<int, N - 1>{});
      return;
    }
    with_remainder<N - 1>(rem, f);
  }
}

// Rows [row0, row0 + NB L) of columns [j, j + NC) over the weight columns
// [k0, k1) of one term: the first panel starts from the bias, the others from
// the partial sums in z; the last applies the activation. Not inlined: where
// GCC inlined it into the backward's gradient through a layer (Mlp::back_through)
// it kept the NB x NC accumulators on the stack, a load and a store around
// every multiply-add.
template <class B, int NB, int NC>
[[gnu::noinline]] void dense_forward_block(Eigen::Index rows, Eigen::Index row0, const DenseTerm<typename B::value_type>& term,
                                Eigen::Index k0, Eigen::Index k1, bool first, bool last,
                                const typename B::value_type* bias, Eigen::Index j, typename B::value_type* z,
                                Eigen::Index ldz, bool relu, const typename B::value_type* gate, Eigen::Index ldgate) {
  using S = typename B::value_type;
  constexpr Eigen::Index L = Eigen::Index(B::size);
  B acc[NB][NC];
  for (int c = 0; c < NC; ++c)
    for (int b = 0; b < NB; ++b) {
      const Eigen::Index r = row0 + b * L;
      const S* src = z + (j + c) * ldz + r;
      if (first) {
        acc[b][c] = bias ? B::load_unaligned(bias + r) : B(S(0));
      } else if (r + L <= rows) {
        acc[b][c] = B::load_unaligned(src);
      } else {
        S lanes[L] = {};
        std::copy_n(src, rows - r, lanes);
        acc[b][c] = B::load_unaligned(lanes);
      }
    }
  const S* x = term.x + j * term.ldx;
  for (Eigen::Index k = k0; k < k1; ++k) {
    const S* wk = term.w + k * term.ld + row0;
    B wv[NB];
    for (int b = 0; b < NB; ++b) wv[b] = B::load_unaligned(wk + b * L);
    for (int c = 0; c < NC; ++c) {
      const B s(x[c * term.ldx + k]);
      for (int b = 0; b < NB; ++b) acc[b][c] = simd::fma(wv[b], s, acc[b][c]);
    }
  }
  for (int c = 0; c < NC; ++c)
    for (int b = 0; b < NB; ++b) {
      const Eigen::Index r = row0 + b * L;
      B v = last && relu ? simd::max(acc[b][c], B(S(0))) : acc[b][c];
      if (last && gate) {
        const S* gsrc = gate + (j + c) * ldgate + r;
        B gv;
        if (r + L <= rows) {
          gv = B::load_unaligned(gsrc);
        } else {
          S lanes[L] = {};
          std::copy_n(gsrc, rows - r, lanes);
          gv = B::load_unaligned(lanes);
        }
        v = simd::select(gv > B(S(0)), v, B(S(0)));
      }
      S* dst = z + (j + c) * ldz + r;
      if (r + L <= rows) {
        v.store_unaligned(dst);
      } else {
        S lanes[L];
        v.store_unaligned(lanes);
        std::copy_n(lanes, rows - r, dst);
      }
    }
}

// Panels of weight columns small enough that a row block's weights stay in L1
// (16 KB) while every column goes by: wide layers (256 units) otherwise stream
// their weights from L2 once per column group.
template <class B, int NB>
inline void dense_forward_rows(Eigen::Index rows, Eigen::Index row0, const DenseTerm<typename B::value_type>* terms,
                               int n_terms, const typename B::value_type* bias, Eigen::Index m,
                               typename B::value_type* z, Eigen::Index ldz, bool relu,
                               const typename B::value_type* gate, Eigen::Index ldgate) {
  constexpr int NC = dense_column_group<B>();
  constexpr Eigen::Index panel =
      std::max<Eigen::Index>(8, 16384 / Eigen::Index(NB * B::size * sizeof(typename B::value_type)));
  int last_term = n_terms - 1;
  while (last_term > 0 && terms[last_term].cols == 0) --last_term;
  bool first = true;
  for (int t = 0; t <= last_term; ++t) {
    Eigen::Index k0 = 0;
    do {  // at least once, so that a term without columns still writes bias and activation
      const Eigen::Index k1 = std::min(terms[t].cols, k0 + panel);
      const bool last = t == last_term && k1 == terms[t].cols;
      Eigen::Index j = 0;
      for (; j + NC <= m; j += NC)
        dense_forward_block<B, NB, NC>(rows, row0, terms[t], k0, k1, first, last, bias, j, z, ldz, relu, gate, ldgate);
      with_remainder<NC>(int(m - j), [&](auto rem) {
        dense_forward_block<B, NB, decltype(rem)::value>(rows, row0, terms[t], k0, k1, first, last, bias, j, z, ldz,
                                                         relu, gate, ldgate);
      });
      first = false;
      k0 = k1;
    } while (k0 < terms[t].cols);
  }
}

// G (rows [row0, row0 + NB L), columns [k0, k0 + NC)) += D H^T over columns
// [0, m) of D and H; D's rows must be whole batches there. Sums: the same rows
// of s += D 1 as well (the first column group's call; D's rows are loaded anyway).
template <class B, int NB, int NC, bool Sums>
inline void dense_outer_block(typename B::value_type* g, Eigen::Index ldg, Eigen::Index row0, Eigen::Index k0,
                              const typename B::value_type* d, Eigen::Index ldd, const typename B::value_type* h,
                              Eigen::Index ldh, Eigen::Index m, typename B::value_type* sums) {
  using S = typename B::value_type;
  constexpr Eigen::Index L = Eigen::Index(B::size);
  B acc[NB][NC], sum[NB];
  for (int b = 0; b < NB; ++b) {
    sum[b] = B(S(0));
    for (int c = 0; c < NC; ++c) acc[b][c] = B(S(0));
  }
  for (Eigen::Index j = 0; j < m; ++j) {
    const S* dj = d + j * ldd + row0;
    const S* hj = h + j * ldh + k0;
    B dv[NB];
    for (int b = 0; b < NB; ++b) dv[b] = B::load_unaligned(dj + b * L);
    if constexpr (Sums)
      for (int b = 0; b < NB; ++b) sum[b] = sum[b] + dv[b];
    for (int c = 0; c < NC; ++c) {
      const B s(hj[c]);
      for (int b = 0; b < NB; ++b) acc[b][c] = simd::fma(dv[b], s, acc[b][c]);
    }
  }
  for (int c = 0; c < NC; ++c)
    for (int b = 0; b < NB; ++b) {
      S* dst = g + (k0 + c) * ldg + row0 + b * L;
      (B::load_unaligned(dst) + acc[b][c]).store_unaligned(dst);
    }
  if constexpr (Sums)
    for (int b = 0; b < NB; ++b) {
      S* dst = sums + row0 + b * L;
      (B::load_unaligned(dst) + sum[b]).store_unaligned(dst);
    }
}

template <class B, int NB>
inline void dense_outer_rows(typename B::value_type* g, Eigen::Index ldg, Eigen::Index row0, Eigen::Index cols,
                             const typename B::value_type* d, Eigen::Index ldd, const typename B::value_type* h,
                             Eigen::Index ldh, Eigen::Index m, typename B::value_type* sums) {
  constexpr int NC = dense_column_group<B>();
  Eigen::Index k = 0;
  if (sums && cols >= NC) {
    dense_outer_block<B, NB, NC, true>(g, ldg, row0, 0, d, ldd, h, ldh, m, sums);
    k = NC;
  } else if (sums) {
    with_remainder<NC>(int(cols), [&](auto rem) {
      dense_outer_block<B, NB, decltype(rem)::value, true>(g, ldg, row0, 0, d, ldd, h, ldh, m, sums);
    });
    k = cols;
  }
  for (; k + NC <= cols; k += NC) dense_outer_block<B, NB, NC, false>(g, ldg, row0, k, d, ldd, h, ldh, m, nullptr);
  with_remainder<NC>(int(cols - k), [&](auto rem) {
    dense_outer_block<B, NB, decltype(rem)::value, false>(g, ldg, row0, k, d, ldd, h, ldh, m, nullptr);
  });
}

// G += D H^T (and sums += D 1 unless null) with rows a multiple of B::size; cols >= 1.
template <class B>
void dense_outer_whole_batches(typename B::value_type* g, Eigen::Index ldg, Eigen::Index rows, Eigen::Index cols,
                               const typename B::value_type* d, Eigen::Index ldd, const typename B::value_type* h,
                               Eigen::Index ldh, Eigen::Index m, typename B::value_type* sums) {
  constexpr Eigen::Index L = Eigen::Index(B::size);
  // Column tiles that keep D's and H's columns in L1 across the column groups.
  constexpr Eigen::Index tile = 128;
  for (Eigen::Index j0 = 0; j0 < m; j0 += tile) {
    const Eigen::Index mj = std::min(tile, m - j0);
    const auto* dj = d + j0 * ldd;
    const auto* hj = h + j0 * ldh;
    constexpr int NR = dense_row_group<B>();
    Eigen::Index r = 0;
    for (; r + NR * L <= rows; r += NR * L) dense_outer_rows<B, NR>(g, ldg, r, cols, dj, ldd, hj, ldh, mj, sums);
    with_remainder<NR>(int((rows - r) / L), [&](auto nb) {
      dense_outer_rows<B, decltype(nb)::value>(g, ldg, r, cols, dj, ldd, hj, ldh, mj, sums);
    });
  }
}

}  // namespace detail

// z[:, j] = act(sum over terms of W_t x_t[:, j] + bias) for j < m, rows outputs
// (leading dimension ldz). Every term's weights (and the bias, or nullptr) are
// padded to whole batches of B as DenseWeights lays them out. act: ReLU or
// none; then, where gate is given (rows x m, leading dimension ldgate), z is 0
// wherever gate <= 0.
template <class B>
void dense_forward(Eigen::Index rows, const DenseTerm<typename B::value_type>* terms, int n_terms,
                   const typename B::value_type* bias, Eigen::Index m, typename B::value_type* z, Eigen::Index ldz,
                   bool relu, const typename B::value_type* gate = nullptr, Eigen::Index ldgate = 0) {
  using S = typename B::value_type;
  constexpr Eigen::Index L = Eigen::Index(B::size);
  // Column tiles whose inputs (about 32 KB) stay in L1 across the row blocks and panels.
  Eigen::Index k_total = 0;
  for (int t = 0; t < n_terms; ++t) k_total += terms[t].cols;
  const Eigen::Index tile = std::max<Eigen::Index>(16, 32768 / std::max<Eigen::Index>(1, k_total * Eigen::Index(sizeof(S))));
  DenseTerm<S> shifted[2];
  ensure(n_terms >= 1 && n_terms <= 2, "dense_forward: 1 or 2 terms, got ", n_terms);
  for (Eigen::Index j0 = 0; j0 < m; j0 += tile) {
    const Eigen::Index mj = std::min(tile, m - j0);
    for (int t = 0; t < n_terms; ++t) {
      shifted[t] = terms[t];
      shifted[t].x += j0 * terms[t].ldx;
    }
    S* zj = z + j0 * ldz;
    const S* gj = gate ? gate + j0 * ldgate : nullptr;
    // Row blocks over whole batches, the last one partial (its weights are
    // padded with zeros; the block stores only the rows below `rows`).
    constexpr int NR = detail::dense_row_group<B>();
    const Eigen::Index padded = (rows + L - 1) / L * L;
    Eigen::Index r = 0;
    for (; r + NR * L <= padded; r += NR * L)
      detail::dense_forward_rows<B, NR>(rows, r, shifted, n_terms, bias, mj, zj, ldz, relu, gj, ldgate);
    detail::with_remainder<NR>(int((padded - r) / L), [&](auto nb) {
      detail::dense_forward_rows<B, decltype(nb)::value>(rows, r, shifted, n_terms, bias, mj, zj, ldz, relu, gj,
                                                         ldgate);
    });
  }
}

// g (rows x cols, leading dimension ldg) += d h^T over m columns: d rows x m
// (ldd), h cols x m (ldh); row_sums (rows values, or nullptr) += the sum of d's
// columns. scratch: reused when neither rows nor cols is a whole number of
// batches of B and the sum runs transposed.
template <class B>
void dense_accumulate_outer(typename B::value_type* g, Eigen::Index ldg, Eigen::Index rows, Eigen::Index cols,
                            const typename B::value_type* d, Eigen::Index ldd, const typename B::value_type* h,
                            Eigen::Index ldh, Eigen::Index m, std::vector<typename B::value_type>& scratch,
                            typename B::value_type* row_sums = nullptr) {
  using S = typename B::value_type;
  constexpr Eigen::Index L = Eigen::Index(B::size);
  if (rows % L == 0 && cols > 0) {
    detail::dense_outer_whole_batches<B>(g, ldg, rows, cols, d, ldd, h, ldh, m, row_sums);
    return;
  }
  if (rows % L == 0) {
    // no columns: only the sums
  } else if (cols % L == 0) {
    // G^T += H D^T, then added back transposed (the output heads: a few rows).
    scratch.assign(std::size_t(cols * rows), S(0));
    detail::dense_outer_whole_batches<B>(scratch.data(), cols, cols, rows, h, ldh, d, ldd, m, nullptr);
    for (Eigen::Index c = 0; c < cols; ++c)
      for (Eigen::Index r = 0; r < rows; ++r) g[c * ldg + r] += scratch[std::size_t(r * cols + c)];
  } else {
    detail::dense_outer_whole_batches<simd::scalar_batch<S>>(g, ldg, rows, cols, d, ldd, h, ldh, m, row_sums);
    return;
  }
  if (row_sums)
    for (Eigen::Index j = 0; j < m; ++j)
      for (Eigen::Index r = 0; r < rows; ++r) row_sums[r] += d[j * ldd + r];
}

}  // namespace orbitforge

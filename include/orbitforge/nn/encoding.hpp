#pragma once
// Frequency (positional) encoding, batched over points stored as columns:
//
//   gamma(p) = ( p, sin(2^0 p), cos(2^0 p), sin(2^1 p), cos(2^1 p), ...,
//                   sin(2^(L-1) p), cos(2^(L-1) p) )
//
// applied to every coordinate of p. Row layout of the output (d = input rows):
//   rows [0, d)                          p            (when include_input)
//   rows [o + 2kd, o + 2kd + d)          sin(2^k p)   (o = d or 0)
//   rows [o + 2kd + d, o + 2kd + 2d)     cos(2^k p)
// This is the order of the NeRF embedder that Deformable 3D Gaussians (Yang et al.
// 2023) uses, so its weights would map one to one. That embedder includes the input
// and multiplies by 2^k WITHOUT pi (frequencies 1, 2, 4, ...), which is the default
// here; `use_pi` gives the NeRF-paper form sin(2^k pi p).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/simd.hpp"

namespace orbitforge {

struct FrequencyEncodingParams {
  int input_dims = 3;
  int frequencies = 10;        // L
  bool include_input = true;   // Deformable 3DGS: true
  bool use_pi = false;         // Deformable 3DGS: false (sin(2^k p))
};

template <class Scalar>
class FrequencyEncoding {
 public:
  using Matrix = Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic>;  // features x points

  explicit FrequencyEncoding(const FrequencyEncodingParams& p = {}) : p_(p) {
    ensure(p.input_dims > 0, "FrequencyEncoding: input_dims must be positive, got ", p.input_dims);
    ensure(p.frequencies >= 0 && p.frequencies <= 30, "FrequencyEncoding: frequencies must be 0..30, got ",
           p.frequencies);
    ensure(p.include_input || p.frequencies > 0, "FrequencyEncoding: empty encoding");
  }

  const FrequencyEncodingParams& params() const { return p_; }
  int input_dims() const { return p_.input_dims; }
  int output_dims() const { return p_.input_dims * ((p_.include_input ? 1 : 0) + 2 * p_.frequencies); }
  Scalar frequency(int k) const {
    const Scalar f = std::ldexp(Scalar(1), k);
    return p_.use_pi ? f * Constants<Scalar>::pi() : f;
  }

  // in:  p   [input_dims x N]
  // out: enc [output_dims x N] written into out.middleRows(row0, output_dims) so that
  //      several encodings can be stacked into one network input without copies.
  // (out is taken by const reference so that blocks can be passed; Eigen's documented idiom.)
  template <class InDerived, class OutDerived>
  void encode(const Eigen::MatrixBase<InDerived>& p, const Eigen::MatrixBase<OutDerived>& out_,
              int row0 = 0) const {
    auto& out = const_cast<Eigen::MatrixBase<OutDerived>&>(out_);
    const int d = p_.input_dims;
    ensure(p.rows() == d, "FrequencyEncoding::encode: input has ", p.rows(), " rows, expected ", d);
    ensure(out.cols() == p.cols() && out.rows() >= row0 + output_dims(),
           "FrequencyEncoding::encode: output is ", out.rows(), "x", out.cols(), ", needs rows [", row0, ", ",
           row0 + output_dims(), ") and ", p.cols(), " columns");
    int r = row0;
    if (p_.include_input) {
      out.middleRows(r, d) = p;
      r += d;
    }
    if (p_.frequencies == 0) return;
    // One sin/cos per coordinate, then the double-angle recurrence
    //   sin 2a = 2 sin a cos a,  cos 2a = 1 - 2 sin^2 a
    // in double: errors grow by ~2 per doubling, so after 2^(L-1) = 512 they are
    // ~1e-13, below float rounding and near double's. About 8x faster than a
    // sin/cos call per output value (measured in bench_mlp). Points go through
    // in lanes of doubles, the last ones padded, so that every point gets the
    // same sin/cos (the vector one) wherever a caller splits the columns.
    using BD = simd::native_batch<double>;
    constexpr Eigen::Index N = Eigen::Index(BD::size);
    const double base = p_.use_pi ? double(Constants<Scalar>::pi()) : 1.0;
    alignas(64) double a[N], sn_d[N], cs_d[N];
    Scalar sn_l[N], cs_l[N];
    for (Eigen::Index j0 = 0; j0 < p.cols(); j0 += N) {
      const Eigen::Index lanes = std::min(N, p.cols() - j0);
      for (int i = 0; i < d; ++i) {
        for (Eigen::Index l = 0; l < N; ++l) a[l] = l < lanes ? base * double(p(i, j0 + l)) : 0.0;
        const BD x = BD::load_unaligned(a);
        BD sn = simd::sin(x), cs = simd::cos(x);
        int rr = r;
        for (int k = 0; k < p_.frequencies; ++k, rr += 2 * d) {
          sn.store_unaligned(sn_d);
          cs.store_unaligned(cs_d);
          for (Eigen::Index l = 0; l < N; ++l) sn_l[l] = Scalar(sn_d[l]), cs_l[l] = Scalar(cs_d[l]);
          auto store = [&](Eigen::Index count) {
            for (Eigen::Index l = 0; l < count; ++l) {
              out(rr + i, j0 + l) = sn_l[l];
              out(rr + d + i, j0 + l) = cs_l[l];
            }
          };
          if (lanes == N) store(N);  // a constant count: unrolled, no lane tests
          else store(lanes);
          const BD s2 = BD(2.0) * sn * cs;
          cs = BD(1.0) - BD(2.0) * sn * sn;
          sn = s2;
        }
      }
    }
  }

  // The vjp reuses the forward's sin/cos values instead of recomputing them.
  // in:  enc   [* x N]            the encoding written by encode(), rows [row0, row0 + output_dims)
  //      v_enc [* x N]            gradient of the loss w.r.t. the encoding, same rows
  // out: v_p   [input_dims x N]   gradient w.r.t. p (overwritten)
  template <class EncDerived, class VEncDerived, class VPDerived>
  void encode_vjp(const Eigen::MatrixBase<EncDerived>& enc, const Eigen::MatrixBase<VEncDerived>& v_enc,
                  const Eigen::MatrixBase<VPDerived>& v_p_, int row0 = 0) const {
    auto& v_p = const_cast<Eigen::MatrixBase<VPDerived>&>(v_p_);
    const int d = p_.input_dims;
    ensure(v_p.rows() == d && v_p.cols() == enc.cols() && v_enc.cols() == enc.cols() &&
               v_enc.rows() >= row0 + output_dims() && enc.rows() >= row0 + output_dims(),
           "FrequencyEncoding::encode_vjp: shape mismatch (v_p ", v_p.rows(), "x", v_p.cols(), ", enc ", enc.rows(),
           "x", enc.cols(), ", v_enc ", v_enc.rows(), "x", v_enc.cols(), ")");
    int r = row0;
    if (p_.include_input) {
      v_p = v_enc.middleRows(r, d);
      r += d;
    } else {
      v_p.setZero();
    }
    for (int k = 0; k < p_.frequencies; ++k, r += 2 * d) {
      const Scalar f = frequency(k);
      // d sin(f p)/dp = f cos(f p);  d cos(f p)/dp = -f sin(f p)
      v_p.array() += f * (enc.middleRows(r + d, d).array() * v_enc.middleRows(r, d).array() -
                          enc.middleRows(r, d).array() * v_enc.middleRows(r + d, d).array());
    }
  }

 private:
  FrequencyEncodingParams p_;
};

}  // namespace orbitforge

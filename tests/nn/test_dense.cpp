#include <catch2/catch.hpp>

#include <random>
#include <vector>

#include "orbitforge/nn/dense.hpp"

using namespace orbitforge;

namespace {

template <class S>
std::vector<S> random_values(std::size_t n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  std::vector<S> v(n);
  for (auto& x : v) x = S(u(rng));
  return v;
}

}  // namespace

// Shapes cover whole batches, a partial last batch, fewer rows than one batch,
// a row block whose last batch is partial (2L - 1, 4L - 1), more than four
// batches (two row blocks), column counts with a tail, weights
// over several panels (150 columns), an empty second term, and 2L weight
// columns with a partial row batch (the outer product then runs transposed).
TEMPLATE_TEST_CASE("dense kernels: forward and outer product against loops in double", "[nn][dense]", float, double) {
  using S = TestType;
  using B = simd::native_batch<S>;
  const int L = int(B::size);
  const double tol = std::is_same<S, float>::value ? 2e-5 : 1e-13;
  std::mt19937 rng(7);
  for (int rows : {1, 3, L, L + 3, 2 * L - 1, 4 * L - 1, 4 * L, 5 * L + 1, 64})
    for (int k1 : {1, 7, L + 1, 2 * L, 150})
      for (int k2 : {0, 5})
        for (int m : {1, 6, 131}) {
          INFO("rows " << rows << " k1 " << k1 << " k2 " << k2 << " m " << m);
          const int ldx1 = k1 + 2, ldx2 = k2 + 1, ldz = rows + 3;  // leading dimensions larger than the data
          const auto w1 = random_values<S>(std::size_t(rows * k1), rng);
          const auto w2 = random_values<S>(std::size_t(rows * k2), rng);
          const auto bias = random_values<S>(std::size_t(rows), rng);
          const auto x1 = random_values<S>(std::size_t(ldx1 * m), rng);
          const auto x2 = random_values<S>(std::size_t(ldx2 * m), rng);
          // W = [W1 W2] laid out as the kernels want it.
          std::vector<S> w(std::size_t(rows * (k1 + k2)));
          std::copy(w1.begin(), w1.end(), w.begin());
          std::copy(w2.begin(), w2.end(), w.begin() + rows * k1);
          DenseWeights<S> dw;
          dw.template assign<B>(w.data(), rows, rows, k1 + k2, false, bias.data());
          REQUIRE(dw.ld % L == 0);
          const DenseTerm<S> terms[2] = {{dw.column(0), dw.ld, k1, x1.data(), ldx1},
                                         {dw.column(k1), dw.ld, k2, x2.data(), ldx2}};
          // A gate with zeros, negatives and positives, leading dimension larger than rows.
          const int ldgate = rows + 1;
          auto gate = random_values<S>(std::size_t(ldgate * m), rng);
          for (std::size_t q = 0; q < gate.size(); q += 5) gate[q] = S(0);
          for (bool relu : {false, true})
            for (bool gated : {false, true}) {
            std::vector<S> z(std::size_t(ldz * m), S(-7));
            // k2 0: an empty last term
            dense_forward<B>(rows, terms, 2, dw.b.data(), m, z.data(), ldz, relu, gated ? gate.data() : nullptr, ldgate);
            double err = 0;
            bool untouched = true, gated_zero = true;
            for (int j = 0; j < m; ++j) {
              for (int r = 0; r < rows; ++r) {
                double s = double(bias[std::size_t(r)]);
                for (int k = 0; k < k1; ++k) s += double(w1[std::size_t(k * rows + r)]) * double(x1[std::size_t(j * ldx1 + k)]);
                for (int k = 0; k < k2; ++k) s += double(w2[std::size_t(k * rows + r)]) * double(x2[std::size_t(j * ldx2 + k)]);
                if (relu) s = std::max(s, 0.0);
                const bool shut = gated && !(gate[std::size_t(j * ldgate + r)] > S(0));
                if (shut) {
                  gated_zero = gated_zero && z[std::size_t(j * ldz + r)] == S(0);
                  s = 0;
                }
                err = std::max(err, std::abs(s - double(z[std::size_t(j * ldz + r)])) / (1 + std::abs(s)));
              }
              for (int r = rows; r < ldz; ++r) untouched = untouched && z[std::size_t(j * ldz + r)] == S(-7);
            }
            CHECK(err <= tol * (k1 + k2 + 1));
            CHECK(untouched);  // rows past `rows` are not written
            CHECK(gated_zero);  // exactly 0 where the gate is shut
          }
          // G (rows x k1) += D H^T over m columns; G's leading dimension larger than rows.
          const int ldg = rows + 1, ldd = rows + 2;
          const auto d = random_values<S>(std::size_t(ldd * m), rng);
          auto g = random_values<S>(std::size_t(ldg * k1), rng);
          const auto g0 = g;
          std::vector<S> scratch;
          auto sums = random_values<S>(std::size_t(rows), rng);
          const auto sums0 = sums;
          dense_accumulate_outer<B>(g.data(), ldg, rows, k1, d.data(), ldd, x1.data(), ldx1, m, scratch, sums.data());
          double err = 0, sum_err = 0;
          for (int r = 0; r < rows; ++r) {
            double s = double(sums0[std::size_t(r)]);
            for (int j = 0; j < m; ++j) s += double(d[std::size_t(j * ldd + r)]);
            sum_err = std::max(sum_err, std::abs(s - double(sums[std::size_t(r)])) / (1 + std::abs(s)));
          }
          CHECK(sum_err <= tol * (m + 1));
          // Without sums the products are the same.
          auto g2 = g0;
          dense_accumulate_outer<B>(g2.data(), ldg, rows, k1, d.data(), ldd, x1.data(), ldx1, m, scratch);
          CHECK(g2 == g);
          bool untouched = true;
          for (int c = 0; c < k1; ++c) {
            for (int r = 0; r < rows; ++r) {
              double s = double(g0[std::size_t(c * ldg + r)]);
              for (int j = 0; j < m; ++j) s += double(d[std::size_t(j * ldd + r)]) * double(x1[std::size_t(j * ldx1 + c)]);
              err = std::max(err, std::abs(s - double(g[std::size_t(c * ldg + r)])) / (1 + std::abs(s)));
            }
            untouched = untouched && g[std::size_t(c * ldg + rows)] == g0[std::size_t(c * ldg + rows)];
          }
          CHECK(err <= tol * (m + 1));
          CHECK(untouched);
        }
}

TEST_CASE("dense kernels: weights transposed for the backward", "[nn][dense]") {
  using B = simd::native_batch<double>;
  // src 3 x 5 (ld 4); its transpose 5 x 3.
  std::vector<double> src(4 * 5);
  for (int c = 0; c < 5; ++c)
    for (int r = 0; r < 4; ++r) src[std::size_t(c * 4 + r)] = 10 * r + c;
  DenseWeights<double> t;
  t.assign<B>(src.data(), 4, 5, 3, true, nullptr);
  CHECK(t.rows == 5);
  CHECK(t.cols == 3);
  CHECK(t.b.empty());
  for (int c = 0; c < 3; ++c)
    for (int r = 0; r < int(t.ld); ++r) CHECK(t.w[std::size_t(c * t.ld + r)] == (r < 5 ? 10.0 * c + r : 0.0));
}

#include <catch2/catch.hpp>

#include <cmath>
#include <random>

#include "orbitforge/nn/encoding.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("frequency encoding: values and row layout", "[nn][encoding]", float, double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  FrequencyEncoding<S> enc({3, 4, true, false});
  REQUIRE(enc.output_dims() == 3 + 3 * 2 * 4);
  M p(3, 2);
  p << 0.1, -0.7, 0.25, 1.3, -0.4, 0.05;
  M out(enc.output_dims(), 2);
  enc.encode(p, out);
  const S tol = std::is_same<S, float>::value ? S(2e-6) : S(1e-14);
  for (int j = 0; j < 2; ++j)
    for (int i = 0; i < 3; ++i) {
      CHECK(out(i, j) == p(i, j));
      for (int k = 0; k < 4; ++k) {
        const double a = std::ldexp(1.0, k) * double(p(i, j));  // no pi
        CHECK(std::abs(out(3 + 6 * k + i, j) - S(std::sin(a))) <= tol);
        CHECK(std::abs(out(3 + 6 * k + 3 + i, j) - S(std::cos(a))) <= tol);
      }
    }

  FrequencyEncoding<S> enc_pi({3, 2, false, true});
  REQUIRE(enc_pi.output_dims() == 12);
  M out_pi(12, 2);
  enc_pi.encode(p, out_pi);
  const double pi = 3.14159265358979323846;
  for (int i = 0; i < 3; ++i) {
    CHECK(std::abs(out_pi(i, 1) - S(std::sin(pi * double(p(i, 1))))) <= tol);
    CHECK(std::abs(out_pi(6 + 3 + i, 1) - S(std::cos(2 * pi * double(p(i, 1))))) <= tol);
  }

  // Written at a row offset, leaving other rows alone.
  M big = M::Constant(enc.output_dims() + 5, 2, S(7));
  enc.encode(p, big, 2);
  CHECK(big(0, 0) == S(7));
  CHECK(big(1, 1) == S(7));
  CHECK(big(2, 0) == p(0, 0));
  CHECK((big.middleRows(2, enc.output_dims()) - out).cwiseAbs().maxCoeff() == S(0));
  CHECK(big(enc.output_dims() + 2, 1) == S(7));

  M wrong(3, 3);
  CHECK_THROWS_AS(enc.encode(p, wrong), Error);
}

TEST_CASE("frequency encoding: vjp matches central differences", "[nn][encoding]") {
  using M = Eigen::MatrixXd;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  for (bool include : {true, false})
    for (bool use_pi : {false, true}) {
      FrequencyEncoding<double> enc({2, 6, include, use_pi});
      M p(2, 5), v(enc.output_dims(), 5);
      for (int i = 0; i < p.size(); ++i) p(i) = u(rng);
      for (int i = 0; i < v.size(); ++i) v(i) = u(rng);
      M e(enc.output_dims(), 5);
      enc.encode(p, e);
      M v_p(2, 5);
      enc.encode_vjp(e, v, v_p);
      const double h = 1e-6;
      for (int i = 0; i < p.size(); ++i) {
        M pp = p, pm = p, ep(enc.output_dims(), 5), em(enc.output_dims(), 5);
        pp(i) += h;
        pm(i) -= h;
        enc.encode(pp, ep);
        enc.encode(pm, em);
        const double fd = (v.cwiseProduct(ep).sum() - v.cwiseProduct(em).sum()) / (2 * h);
        INFO("include " << include << " pi " << use_pi << " i " << i << " fd " << fd << " vjp " << v_p(i));
        CHECK(std::abs(fd - v_p(i)) <= 1e-6 * std::max({std::abs(fd), std::abs(v_p(i)), 1.0}));
      }
    }
}

TEMPLATE_TEST_CASE("frequency encoding: many points, ten frequencies, any split of the columns", "[nn][encoding]", float,
                   double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  FrequencyEncoding<S> enc({3, 10, true, false});
  std::mt19937 rng(21);
  std::uniform_real_distribution<double> u(-3, 3);
  M p(3, 37);
  for (Eigen::Index i = 0; i < p.size(); ++i) p(i) = S(u(rng));
  M out(enc.output_dims(), p.cols());
  enc.encode(p, out);
  // Against a sin and cos per value in double (2^9 p is exact): the recurrence's
  // error grows ~2x per doubling.
  const double tol = std::is_same<S, float>::value ? 2e-6 : 1e-12;
  double worst = 0;
  for (Eigen::Index j = 0; j < p.cols(); ++j)
    for (int i = 0; i < 3; ++i)
      for (int k = 0; k < 10; ++k) {
        const double a = std::ldexp(1.0, k) * double(p(i, j));
        worst = std::max({worst, std::abs(double(out(3 + 6 * k + i, j)) - std::sin(a)),
                          std::abs(double(out(3 + 6 * k + 3 + i, j)) - std::cos(a))});
      }
  CHECK(worst <= tol);
  // Columns encoded in two calls (as threads split them) give the same bits.
  for (Eigen::Index cut : {1, 5, 8, 16, 36}) {
    M parts(enc.output_dims(), p.cols());
    enc.encode(p.leftCols(cut), parts.leftCols(cut));
    enc.encode(p.rightCols(p.cols() - cut), parts.rightCols(p.cols() - cut));
    INFO("cut " << cut);
    CHECK(parts == out);
  }
}

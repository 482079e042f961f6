#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <sstream>
#include <vector>

#include "orbitforge/nn/adam.hpp"

using namespace orbitforge;

TEMPLATE_TEST_CASE("adam minimises a small anisotropic quadratic", "[nn][adam]", float, double) {
  using S = TestType;
  // f(p) = sum_i a_i (p_i - c_i)^2, minimum at c.
  const std::vector<S> a = {1, 10, 0.1f, 3}, c = {1, -2, 0.5f, 3};
  std::vector<S> p(4, S(0)), g(4);
  Adam<S> opt(AdamParams{0.9, 0.999, 1e-8});
  const int id = opt.add_group("p", 4, 1, S(0.05));
  ExponentialLr lr{0.05, 0.0005, 3000};
  for (int it = 0; it < 3000; ++it) {
    for (int i = 0; i < 4; ++i) g[std::size_t(i)] = 2 * a[std::size_t(i)] * (p[std::size_t(i)] - c[std::size_t(i)]);
    opt.set_lr(id, S(lr(it)));
    opt.step(id, p.data(), g.data());
  }
  for (int i = 0; i < 4; ++i) CHECK(std::abs(p[std::size_t(i)] - c[std::size_t(i)]) < 1e-2);
  CHECK(opt.group(id).step == 3000);
}

TEST_CASE("adam: first step moves every parameter by lr against the gradient sign", "[nn][adam]") {
  // After one step m^ = g and v^ = g^2, so the update is lr * g / (|g| + eps).
  Adam<double> opt;
  std::vector<double> p = {0, 0, 0}, g = {3, -0.5, 1e-3};
  const int id = opt.add_group("x", 1, 3, 0.1);
  opt.step(id, p.data(), g.data());
  CHECK(p[0] == Approx(-0.1).epsilon(1e-12));
  CHECK(p[1] == Approx(0.1).epsilon(1e-12));
  CHECK(p[2] == Approx(-0.1).epsilon(1e-9));
  // Second step, zero gradient: m = 0.9 * 0.1 g, v = 0.999 * 0.001 g^2; bias-corrected
  // update lr * (m / (1 - 0.9^2)) / sqrt(v / (1 - 0.999^2))
  std::vector<double> z = {0, 0, 0};
  const double before = p[0];
  opt.step(id, p.data(), z.data());
  const double expect = 0.1 * (0.09 * 3 / 0.19) / std::sqrt(0.999 * 0.001 * 9 / (1 - 0.999 * 0.999));
  CHECK(before - p[0] == Approx(expect).epsilon(1e-10));
}

TEMPLATE_TEST_CASE("adam: the SIMD update matches the formula, tails included, for any thread count",
                   "[nn][adam]", float, double) {
  using S = TestType;
  std::mt19937 rng(7);
  std::normal_distribution<double> nd(0.0, 1.0);
  // Counts around SIMD widths and past one parallel block (kAdamBlock).
  for (std::size_t count : {std::size_t(1), std::size_t(3), std::size_t(17), std::size_t(45), kAdamBlock + 13,
                            2 * kAdamBlock + 5}) {
    INFO("count " << count);
    std::vector<S> p0(count), g1(count), g2(count);
    for (std::size_t i = 0; i < count; ++i) {
      p0[i] = S(nd(rng));
      g1[i] = S(nd(rng));
      g2[i] = S(0.1 * nd(rng));
    }
    // Reference: the formula in double, two steps.
    std::vector<double> rp(p0.begin(), p0.end()), rm(count, 0.0), rv(count, 0.0);
    const AdamParams ap;
    const double lr = 0.01;
    for (int t = 1; t <= 2; ++t) {
      const auto& g = t == 1 ? g1 : g2;
      for (std::size_t i = 0; i < count; ++i) {
        rm[i] = 0.9 * rm[i] + 0.1 * double(g[i]);
        rv[i] = 0.999 * rv[i] + 0.001 * double(g[i]) * double(g[i]);
        const double mh = rm[i] / (1 - std::pow(0.9, t)), vh = rv[i] / (1 - std::pow(0.999, t));
        rp[i] -= lr * mh / (std::sqrt(vh) + ap.eps);
      }
    }
    std::vector<std::vector<S>> results;
    for (int threads : {1, 2, 3}) {
      Adam<S> opt(ap);
      const int id = opt.add_group("p", count, 1, S(lr));
      std::vector<S> p = p0;
      Adam<S>::update(opt.group(id), ap, p.data(), g1.data(), count, threads);
      Adam<S>::update(opt.group(id), ap, p.data(), g2.data(), count, threads);
      double worst = 0;
      for (std::size_t i = 0; i < count; ++i) worst = std::max(worst, std::abs(double(p[i]) - rp[i]));
      CHECK(worst < (sizeof(S) == 4 ? 2e-6 : 1e-12));
      results.push_back(p);
    }
    CHECK(results[1] == results[0]);  // bit for bit
    CHECK(results[2] == results[0]);
  }
}

TEST_CASE("adam: keep, append, gather and save/load", "[nn][adam]") {
  Adam<float> opt;
  const int a = opt.add_group("means", 4, 3, 1e-3f);
  opt.add_group("opacity", 4, 1, 5e-2f);
  std::vector<float> p(12, 0.f), g(12);
  for (int i = 0; i < 12; ++i) g[std::size_t(i)] = float(i + 1);
  opt.step(a, p.data(), g.data());
  const auto m0 = opt.group(a).m;  // m = 0.1 g
  CHECK(m0[5] == Approx(0.6f));

  opt.keep(a, {true, false, true, true});
  REQUIRE(opt.group(a).rows == 3);
  CHECK(opt.group(a).m[3] == m0[6]);  // old row 2 is new row 1
  CHECK(opt.group(a).m[8] == m0[11]);
  opt.append(a, 2);
  REQUIRE(opt.group(a).rows == 5);
  CHECK(opt.group(a).m.size() == 15);
  CHECK(opt.group(a).m[14] == 0.f);
  CHECK(opt.group(a).v[9] == 0.f);
  opt.gather(a, {4, 0, -1});
  REQUIRE(opt.group(a).rows == 3);
  CHECK(opt.group(a).m[0] == 0.f);
  CHECK(opt.group(a).m[3] == m0[0]);
  CHECK(opt.group(a).m[7] == 0.f);
  CHECK_THROWS_AS(opt.gather(a, {7}), Error);
  CHECK_THROWS_AS(opt.keep(a, {true}), Error);
  CHECK_THROWS_AS(opt.add_group("means", 1, 1, 1.f), Error);

  std::stringstream ss;
  opt.save(ss);
  Adam<float> loaded;
  loaded.load(ss);
  REQUIRE(loaded.group_count() == 2);
  CHECK(loaded.group(0).name == "means");
  CHECK(loaded.group(0).m == opt.group(0).m);
  CHECK(loaded.group(0).v == opt.group(0).v);
  CHECK(loaded.group(0).step == 1);
  CHECK(loaded.group(1).lr == 5e-2f);
  CHECK(loaded.find("opacity") == 1);

  std::stringstream truncated(ss.str().substr(0, 40));
  CHECK_THROWS_AS(loaded.load(truncated), Error);
  std::stringstream wrong_precision;
  opt.save(wrong_precision);
  Adam<double> other;
  CHECK_THROWS_AS(other.load(wrong_precision), Error);
}

TEST_CASE("exponential learning-rate schedule as 3DGS's get_expon_lr_func", "[nn][adam]") {
  ExponentialLr s{1.6e-4, 1.6e-6, 30000};
  CHECK(s(0) == Approx(1.6e-4));
  CHECK(s(30000) == Approx(1.6e-6));
  CHECK(s(60000) == Approx(1.6e-6));
  CHECK(s(15000) == Approx(1.6e-5));  // geometric midpoint
  CHECK(s(-1) == 0.0);
  ExponentialLr d{1e-2, 1e-4, 100, 10, 0.01};
  CHECK(d(0) == Approx(1e-4));                // delay_mult * lr_init
  CHECK(d(10) == Approx(1e-2 * std::pow(1e-2, 0.1)));  // delay over
  CHECK(d(5) < d(10));
}

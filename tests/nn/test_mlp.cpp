#include <catch2/catch.hpp>

#include <cmath>
#include <random>
#include <vector>

#include "orbitforge/nn/mlp.hpp"

using namespace orbitforge;

namespace {

// An independent scalar-loop reference forward; also reports the smallest
// |pre-activation| so finite-difference tests can prove they stay off ReLU kinks.
template <class S>
Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic> reference_forward(const Mlp<S>& net,
                                                                   const Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>& x,
                                                                   double* min_abs_pre = nullptr) {
  const MlpParams& p = net.params();
  const auto& w = net.parameters();
  const auto& layers = net.layers();
  Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic> y(net.output_dims(), x.cols());
  double margin = 1e300;
  for (Eigen::Index j = 0; j < x.cols(); ++j) {
    std::vector<double> in(x.data() + j * x.rows(), x.data() + (j + 1) * x.rows());
    std::vector<double> h;
    for (int i = 0; i <= p.depth; ++i) {
      const auto& l = layers[std::size_t(i)];
      std::vector<double> a;  // layer input
      if (i == 0) a = in;
      else if (p.skip_layer >= 0 && i == p.skip_layer + 1) {
        a = in;
        a.insert(a.end(), h.begin(), h.end());
      } else a = h;
      REQUIRE(int(a.size()) == l.cols);
      std::vector<double> z(std::size_t(l.rows));
      for (int r = 0; r < l.rows; ++r) {
        double s = double(w[l.b + std::size_t(r)]);
        for (int c = 0; c < l.cols; ++c) s += double(w[l.w + std::size_t(c) * l.rows + std::size_t(r)]) * a[std::size_t(c)];
        z[std::size_t(r)] = s;
      }
      if (i == p.depth) {
        for (int r = 0; r < l.rows; ++r) y(r, j) = S(z[std::size_t(r)]);
      } else {
        for (auto& v : z) {
          margin = std::min(margin, std::abs(v));
          v = std::max(v, 0.0);
        }
        h = z;
      }
    }
  }
  if (min_abs_pre) *min_abs_pre = margin;
  return y;
}

// A network with three heads (3, 4 and 3 outputs, as the deformation field's).
MlpParams three_head_params(int input_dims, int depth, int width, int skip) {
  MlpParams p;
  p.input_dims = input_dims;
  p.depth = depth;
  p.width = width;
  p.skip_layer = skip;
  p.head_dims = {3, 4, 3};
  return p;
}

template <class S>
Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic> uniform_matrix(int rows, int cols, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic> m(rows, cols);
  for (int i = 0; i < m.size(); ++i) m(i) = S(u(rng));
  return m;
}

MlpParams small_params(int skip) {
  MlpParams p;
  p.input_dims = 5;
  p.depth = 4;
  p.width = 9;
  p.skip_layer = skip;
  p.head_dims = {3, 4, 2};
  return p;
}

}  // namespace

TEMPLATE_TEST_CASE("mlp: layout, init bounds and forward against a reference", "[nn][mlp]", float, double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  for (int skip : {-1, 1}) {
    Mlp<S> net(small_params(skip));
    // Parameter count: 5->9, 9->9 (or 14->9 after the skip), 9->9, 9->9, 9->9 heads.
    const std::size_t expect = (5 * 9 + 9) + (skip == 1 ? 0 : 1) * (9 * 9 + 9) + (9 * 9 + 9) + (skip == 1 ? 1 : 0) *
                               (14 * 9 + 9) + (9 * 9 + 9) + (9 * 9 + 9);
    CHECK(net.parameter_count() == expect);
    CHECK(net.output_dims() == 9);
    CHECK(net.head_offset(2) == 7);
    net.init(123, S(0.5));
    for (std::size_t li = 0; li < net.layers().size(); ++li) {
      const auto& l = net.layers()[li];
      const double bound = (li + 1 == net.layers().size() ? 0.5 : 1.0) / std::sqrt(double(l.cols));
      double maxabs = 0, sumsq = 0;
      for (std::size_t k = l.w; k < l.b + std::size_t(l.rows); ++k) {
        maxabs = std::max(maxabs, std::abs(double(net.parameters()[k])));
        sumsq += double(net.parameters()[k]) * double(net.parameters()[k]);
      }
      const double count = double(l.b + std::size_t(l.rows) - l.w);
      CHECK(maxabs <= bound);
      // Uniform(-b, b) has rms b / sqrt(3); loose bounds for these small layers.
      CHECK(std::sqrt(sumsq / count) > 0.35 * bound);
      CHECK(std::sqrt(sumsq / count) < 0.8 * bound);
    }
    std::mt19937 rng(5);
    std::uniform_real_distribution<double> u(-1, 1);
    M x(5, 37);
    for (int i = 0; i < x.size(); ++i) x(i) = S(u(rng));
    typename Mlp<S>::Workspace ws;
    M y;
    net.chunk_columns = 8;  // several chunks and ranges
    for (int threads : {1, 2})
    for (int dense_max_width : {64, 0}) {  // dense.hpp's kernels, Eigen's GEMM
      net.dense_max_width = dense_max_width;
      net.forward(x, ws, y, threads);
      const M ref = reference_forward(net, x);
      const S tol = std::is_same<S, float>::value ? S(1e-5) : S(1e-13);
      CHECK((y - ref).cwiseAbs().maxCoeff() <= tol * (S(1) + ref.cwiseAbs().maxCoeff()));
    }
    // Same seed, same parameters.
    Mlp<S> again(small_params(skip));
    again.init(123, S(0.5));
    CHECK(again.parameters() == net.parameters());
    M bad(4, 3);
    CHECK_THROWS_AS(net.forward(bad, ws, y), Error);
  }
}

TEST_CASE("mlp: backward matches central differences for every parameter and input", "[nn][mlp]") {
  using M = Eigen::MatrixXd;
  for (int skip : {-1, 1, 0}) {
    for (int threads : {1, 2})
    for (int dense_max_width : {64, 0}) {  // dense.hpp's kernels, Eigen's GEMM
      Mlp<double> net(small_params(skip));
      net.init(99, 1.0);
      net.chunk_columns = 3;
      net.dense_max_width = dense_max_width;
      std::mt19937 rng(11);
      std::uniform_real_distribution<double> u(-1, 1);
      M x(5, 7), v(net.output_dims(), 7);
      for (int i = 0; i < x.size(); ++i) x(i) = u(rng);
      for (int i = 0; i < v.size(); ++i) v(i) = u(rng);
      double margin = 0;
      reference_forward(net, x, &margin);
      const double h = 1e-7;
      // Perturbations move pre-activations by at most ~h * (sum |w| |a|) << margin.
      INFO("smallest |pre-activation| " << margin);
      REQUIRE(margin > 1e-4);

      typename Mlp<double>::Workspace ws;
      M y;
      net.forward(x, ws, y, threads);
      std::vector<double> g(net.parameter_count(), 0.0);
      g[0] = 1.5;  // accumulation: backward adds
      M v_x;
      net.backward(x, ws, v, g.data(), &v_x, threads);
      g[0] -= 1.5;
      auto loss = [&](const Mlp<double>& n, const M& in) {
        typename Mlp<double>::Workspace w2;
        M out;
        n.forward(in, w2, out, 1);
        return v.cwiseProduct(out).sum();
      };
      int bad = 0;
      for (std::size_t k = 0; k < net.parameter_count(); ++k) {
        Mlp<double> np = net, nm = net;
        np.parameters()[k] += h;
        nm.parameters()[k] -= h;
        const double fd = (loss(np, x) - loss(nm, x)) / (2 * h);
        if (std::abs(fd - g[k]) > 1e-6 * std::max({std::abs(fd), std::abs(g[k]), 1e-2})) {
          ++bad;
          UNSCOPED_INFO("param " << k << " fd " << fd << " analytic " << g[k]);
        }
      }
      for (int i = 0; i < x.size(); ++i) {
        M xp = x, xm = x;
        xp(i) += h;
        xm(i) -= h;
        const double fd = (loss(net, xp) - loss(net, xm)) / (2 * h);
        if (std::abs(fd - v_x(i)) > 1e-6 * std::max({std::abs(fd), std::abs(v_x(i)), 1e-2})) {
          ++bad;
          UNSCOPED_INFO("input " << i << " fd " << fd << " analytic " << v_x(i));
        }
      }
      INFO("skip " << skip << " threads " << threads << " dense_max_width " << dense_max_width);
      CHECK(bad == 0);
    }
  }
}

TEST_CASE("mlp: multi-threaded results are reproducible and match one thread", "[nn][mlp]") {
  using M = Eigen::MatrixXf;
  Mlp<float> net(three_head_params(13, 3, 32, 1));
  net.init(1);
  net.chunk_columns = 64;
  std::mt19937 rng(3);
  const M x = uniform_matrix<float>(13, 1000, rng), v = uniform_matrix<float>(10, 1000, rng);
  auto run = [&](int threads) {
    typename Mlp<float>::Workspace ws;
    M y;
    net.forward(x, ws, y, threads);
    std::vector<float> g(net.parameter_count(), 0.f);
    net.backward(x, ws, v, g.data(), nullptr, threads);
    return g;
  };
  const auto a = run(2), b = run(2), c = run(1);
  CHECK(a == b);
  double maxdiff = 0, maxabs = 0;
  for (std::size_t k = 0; k < a.size(); ++k) {
    maxdiff = std::max(maxdiff, double(std::abs(a[k] - c[k])));
    maxabs = std::max(maxabs, double(std::abs(c[k])));
  }
  CHECK(maxdiff <= 1e-4 * maxabs);
}

TEMPLATE_TEST_CASE("mlp: dense kernels and the GEMM path give the same outputs and gradients", "[nn][mlp]", float, double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  Mlp<S> net(three_head_params(21, 3, 40, 0));
  net.init(4);
  net.chunk_columns = 100;
  std::mt19937 rng(9);
  const M x = uniform_matrix<S>(21, 333, rng), v = uniform_matrix<S>(10, 333, rng);
  auto run = [&](int dense_max_width, M& y, M& v_x) {
    net.dense_max_width = dense_max_width;
    typename Mlp<S>::Workspace ws;
    net.forward(x, ws, y, 2);
    std::vector<S> g(net.parameter_count(), S(0));
    net.backward(x, ws, v, g.data(), &v_x, 2);
    return g;
  };
  M y_dense, y_gemm, vx_dense, vx_gemm;
  const auto g_dense = run(64, y_dense, vx_dense), g_gemm = run(0, y_gemm, vx_gemm);
  const double tol = std::is_same<S, float>::value ? 1e-5 : 1e-12;
  CHECK((y_dense - y_gemm).cwiseAbs().maxCoeff() <= tol * (1 + y_gemm.cwiseAbs().maxCoeff()));
  CHECK((vx_dense - vx_gemm).cwiseAbs().maxCoeff() <= tol * (1 + vx_gemm.cwiseAbs().maxCoeff()));
  double maxdiff = 0, maxabs = 0;
  for (std::size_t k = 0; k < g_gemm.size(); ++k) {
    maxdiff = std::max(maxdiff, double(std::abs(g_dense[k] - g_gemm[k])));
    maxabs = std::max(maxabs, double(std::abs(g_gemm[k])));
  }
  CHECK(maxdiff <= 10 * tol * maxabs);
}

TEMPLATE_TEST_CASE("mlp: forward rejects a non-finite input and names its points", "[nn][mlp]", float, double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  Mlp<S> net(three_head_params(21, 2, 16, -1));
  net.init(2);
  net.chunk_columns = 40;
  std::mt19937 rng(5);
  const M x = uniform_matrix<S>(21, 100, rng);
  typename Mlp<S>::Workspace ws;
  M y;
  REQUIRE_NOTHROW(net.forward(M(x * S(1e30)), ws, y, 2));  // large but finite
  for (const S bad : {std::numeric_limits<S>::quiet_NaN(), std::numeric_limits<S>::infinity(),
                      -std::numeric_limits<S>::infinity()}) {
    M xb = x;
    xb(20, 57) = bad;
    CHECK_THROWS_WITH(net.forward(xb, ws, y, 1), Catch::Contains("non-finite values (points 40 to 79)"));
    CHECK_THROWS_WITH(net.forward(xb, ws, y, 2), Catch::Contains("non-finite values (points 50 to 89)"));
  }
}

// The shared rows given once must act as the same rows in every column: equal
// outputs and gradients (the shared weights' gradient included) to the network
// fed the whole input, with and without the skip, dense kernels and the GEMM
// path, one and two threads.
TEMPLATE_TEST_CASE("mlp: shared input rows act as the same rows in every column", "[nn][mlp]", float, double) {
  using S = TestType;
  using M = Eigen::Matrix<S, Eigen::Dynamic, Eigen::Dynamic>;
  constexpr int kIn = 21, kShared = 5, kPoints = 333;
  std::mt19937 rng(13);
  const M x_points = uniform_matrix<S>(kIn - kShared, kPoints, rng), v = uniform_matrix<S>(10, kPoints, rng);
  const M shared = uniform_matrix<S>(kShared, 1, rng);
  M x_whole(kIn, kPoints);
  x_whole << x_points, shared.replicate(1, kPoints);
  const double tol = std::is_same<S, float>::value ? 1e-5 : 1e-12;
  for (int skip : {-1, 1})
    for (int dense_max_width : {64, 0})
      for (int threads : {1, 2}) {
        INFO("skip " << skip << ", dense_max_width " << dense_max_width << ", threads " << threads);
        MlpParams pw = three_head_params(kIn, 3, 40, skip), ps = pw;
        ps.shared_input_dims = kShared;
        Mlp<S> whole(pw), split(ps);
        whole.init(4);
        split.parameters() = whole.parameters();
        REQUIRE(split.point_input_dims() == kIn - kShared);
        for (Mlp<S>* net : {&whole, &split}) {
          net->chunk_columns = 100;
          net->dense_max_width = dense_max_width;
        }
        typename Mlp<S>::Workspace ws_w, ws_s;
        M y_w, y_s, vx_w, vx_s;
        whole.forward(x_whole, ws_w, y_w, threads);
        split.forward(x_points, ws_s, y_s, threads, shared.data());
        CHECK((y_w - y_s).cwiseAbs().maxCoeff() <= tol * (1 + y_w.cwiseAbs().maxCoeff()));
        std::vector<S> g_w(whole.parameter_count(), S(0)), g_s(split.parameter_count(), S(0));
        whole.backward(x_whole, ws_w, v, g_w.data(), &vx_w, threads);
        split.backward(x_points, ws_s, v, g_s.data(), &vx_s, threads);
        REQUIRE(vx_s.rows() == kIn - kShared);
        CHECK((vx_w.topRows(kIn - kShared) - vx_s).cwiseAbs().maxCoeff() <= tol * (1 + vx_w.cwiseAbs().maxCoeff()));
        double maxdiff = 0, maxabs = 0;
        for (std::size_t k = 0; k < g_w.size(); ++k) {
          maxdiff = std::max(maxdiff, double(std::abs(g_w[k] - g_s[k])));
          maxabs = std::max(maxabs, double(std::abs(g_w[k])));
        }
        CHECK(maxabs > 0);
        CHECK(maxdiff <= 10 * tol * maxabs);
      }
  // The shared rows are required exactly when the network has them, and finite.
  MlpParams ps = three_head_params(kIn, 2, 16, -1);
  ps.shared_input_dims = kShared;
  Mlp<S> net(ps);
  net.init(1);
  typename Mlp<S>::Workspace ws;
  M y;
  CHECK_THROWS_WITH(net.forward(x_points, ws, y, 1), Catch::Contains("5 shared input rows, and they were not given"));
  M bad = shared;
  bad(2) = std::numeric_limits<S>::quiet_NaN();
  CHECK_THROWS_WITH(net.forward(x_points, ws, y, 1, bad.data()), Catch::Contains("shared input contains non-finite"));
  CHECK_THROWS_WITH(net.forward(x_whole, ws, y, 1, shared.data()), Catch::Contains("input has 21 rows, expected 16"));
  ps.shared_input_dims = kIn;
  CHECK_THROWS_WITH(Mlp<S>(ps), Catch::Contains("shared_input_dims 21 must be in [0, input_dims)"));
}

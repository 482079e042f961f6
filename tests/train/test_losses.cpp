// L1, SSIM and the combined 3DGS loss: values against a direct reference, gradients
// against central finite differences, invariances, and float/double agreement.
#include <catch2/catch.hpp>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <random>

#include "orbitforge/train/losses.hpp"

using namespace orbitforge;

namespace {

template <class S>
Image<S> random_image(int w, int h, int c, std::mt19937& rng, double lo = 0.0, double hi = 1.0) {
  std::uniform_real_distribution<double> u(lo, hi);
  Image<S> img(w, h, c);
  for (auto& v : img.data) v = S(u(rng));
  return img;
}

// A target correlated with the prediction (so SSIM is far from 0 and every term of the
// gradient matters), with no pixel equal to the prediction.
template <class S>
Image<S> related_image(const Image<S>& base, std::mt19937& rng, double noise) {
  std::uniform_real_distribution<double> u(-noise, noise);
  Image<S> img = base;
  for (auto& v : img.data) {
    double d = u(rng);
    if (std::abs(d) < 1e-3) d = d < 0 ? -1e-3 : 1e-3;  // keep away from L1 ties
    v = S(std::min(1.0, std::max(0.0, double(v) + d)));
  }
  for (std::size_t i = 0; i < img.data.size(); ++i)
    if (std::abs(double(img.data[i]) - double(base.data[i])) < 1e-3) img.data[i] = S(double(base.data[i]) + 2e-3);
  return img;
}

// The obviously-correct SSIM: the full 11x11 window at every pixel, 2D Gaussian weights
// normalised over the full window, out-of-image pixels contributing zero.
double reference_ssim(const Image<double>& x, const Image<double>& y, const SsimParams& p = {}) {
  const int r = p.window / 2, side = p.window;
  const double sigma = p.sigma, c1 = p.c1, c2 = p.c2;
  double wsum = 0;
  std::vector<double> w2(std::size_t(side * side));
  auto at = [&](int dx, int dy) -> double& { return w2[std::size_t((dy + r) * side + dx + r)]; };
  for (int dy = -r; dy <= r; ++dy)
    for (int dx = -r; dx <= r; ++dx) {
      at(dx, dy) = std::exp(-(dx * dx + dy * dy) / (2 * sigma * sigma));
      wsum += at(dx, dy);
    }
  double total = 0;
  for (int c = 0; c < x.channels; ++c)
    for (int py = 0; py < x.height; ++py)
      for (int px = 0; px < x.width; ++px) {
        double mx = 0, my = 0, exx = 0, eyy = 0, exy = 0;
        for (int dy = -r; dy <= r; ++dy)
          for (int dx = -r; dx <= r; ++dx) {
            const int qx = px + dx, qy = py + dy;
            if (qx < 0 || qy < 0 || qx >= x.width || qy >= x.height) continue;  // zero padding
            const double w = at(dx, dy) / wsum;
            const double a = x(qx, qy, c), b = y(qx, qy, c);
            mx += w * a;
            my += w * b;
            exx += w * a * a;
            eyy += w * b * b;
            exy += w * a * b;
          }
        const double sxx = exx - mx * mx, syy = eyy - my * my, sxy = exy - mx * my;
        total += (2 * mx * my + c1) * (2 * sxy + c2) / ((mx * mx + my * my + c1) * (sxx + syy + c2));
      }
  return total / double(x.width * x.height * x.channels);
}

// Checks an analytic gradient against central differences of f at every pixel, using
// the five-point central stencil (error O(h^4)) so that a step of 1e-3 keeps both
// truncation and rounding far below the tolerance. Error per element is relative to
// max(|fd|, |analytic|, 1e-3 * max |fd|).
void check_gradient(Image<double> x, const Image<double>& analytic, const std::function<double(const Image<double>&)>& f,
                    double h = 1e-3, double tol = 1e-6) {
  double gmax = 0;
  std::vector<double> fd(x.data.size());
  for (std::size_t i = 0; i < x.data.size(); ++i) {
    const double v = x.data[i];
    double fv[4];
    const double steps[4] = {2 * h, h, -h, -2 * h};
    for (int k = 0; k < 4; ++k) {
      x.data[i] = v + steps[k];
      fv[k] = f(x);
    }
    x.data[i] = v;
    fd[i] = (-fv[0] + 8 * fv[1] - 8 * fv[2] + fv[3]) / (12 * h);
    gmax = std::max(gmax, std::abs(fd[i]));
  }
  REQUIRE(gmax > 0);
  double worst = 0;
  for (std::size_t i = 0; i < x.data.size(); ++i) {
    const double denom = std::max({std::abs(fd[i]), std::abs(analytic.data[i]), 1e-3 * gmax});
    worst = std::max(worst, std::abs(fd[i] - analytic.data[i]) / denom);
  }
  INFO("worst relative gradient error " << worst << " (max |grad| " << gmax << ")");
  CHECK(worst < tol);
}

struct Size {
  int w, h, c;
};
// Small, larger than the window in both directions, smaller than the window, and
// tall enough that the 2D filter runs in more than one band of rows (64 or more each).
const Size kSizes[] = {{13, 9, 3}, {17, 14, 3}, {6, 4, 3}, {12, 12, 1}, {6, 130, 2}};

}  // namespace

TEST_CASE("ssim matches a direct full-window implementation", "[train][losses]") {
  std::mt19937 rng(1234);
  for (const Size s : kSizes) {
    const auto x = random_image<double>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.3);
    const auto z = random_image<double>(s.w, s.h, s.c, rng);
    SsimWorkspace<double> ws;
    INFO(s.w << "x" << s.h << "x" << s.c);
    CHECK(ssim(x, y, ws) == Approx(reference_ssim(x, y)).epsilon(1e-12));
    CHECK(ssim(x, z, ws) == Approx(reference_ssim(x, z)).epsilon(1e-12));
    // With threads (the result must not depend on the thread count).
    CHECK(ssim(x, z, ws, SsimParams{}, 2) == ssim(x, z, ws, SsimParams{}, 1));
  }
}

namespace {
// row_taps<R> (taps unrolled; on AVX-512 floats, the shifted inputs taken from
// two registers) against the runtime-radius path and a scalar sum in the same
// order: every output the same bits, for rows shorter and longer than a vector,
// with R padding values on each side of the row and none beyond.
template <int R, class S>
void check_row_taps(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  std::vector<S> w(2 * R + 1);
  for (auto& v : w) v = S(u(rng));
  for (std::size_t n = 1; n <= 70; ++n) {
    std::vector<S> row(n + 2 * R);
    for (auto& v : row) v = S(u(rng));
    std::vector<S> fixed(n), runtime(n);
    ssim_detail::row_taps<R>(row.data() + R, fixed.data(), n, w.data(), R);
    ssim_detail::row_taps<0>(row.data() + R, runtime.data(), n, w.data(), R);
    INFO("R " << R << ", n " << n << ", " << sizeof(S) * 8 << "-bit");
    for (std::size_t i = 0; i < n; ++i) {
      const S* c = row.data() + R + i;
      S expect = w[R] * c[0];
      for (int d = 1; d <= R; ++d) expect = std::fma(w[R + d], c[-d] + c[d], expect);
      REQUIRE(fixed[i] == expect);
      REQUIRE(runtime[i] == expect);
    }
  }
}
}  // namespace

TEMPLATE_TEST_CASE("ssim's row pass sums each output in one order on every path", "[train][losses]", float,
                   double) {
  std::mt19937 rng(99);
  check_row_taps<5, TestType>(rng);  // the default 11-tap window
  check_row_taps<1, TestType>(rng);
  check_row_taps<8, TestType>(rng);
}

TEST_CASE("ssim with other windows, and the same value whatever the rows' banding", "[train][losses]") {
  std::mt19937 rng(77);
  // Windows other than the default 11 taps take the generic filter paths.
  for (const int window : {1, 3, 7, 13}) {
    SsimParams p;
    p.window = window;
    p.sigma = 0.4 + 0.2 * window;
    for (const Size s : kSizes) {
      const auto x = random_image<double>(s.w, s.h, s.c, rng);
      const auto y = related_image(x, rng, 0.3);
      SsimWorkspace<double> ws;
      INFO("window " << window << ", " << s.w << "x" << s.h << "x" << s.c);
      CHECK(ssim(x, y, ws, p) == Approx(reference_ssim(x, y, p)).epsilon(1e-12));
    }
  }
  // 520 rows: one thread filters them in 4 bands of 130, two or three threads in
  // 8 of 65, so rows meet the four-row column pass in different groups.
  const auto x = random_image<float>(37, 520, 3, rng);
  const auto y = related_image(x, rng, 0.2);
  SsimWorkspace<float> ws;
  const float one = ssim(x, y, ws, SsimParams{}, 1);
  Image<float> v1, v2;
  ssim_vjp(x, y, 1.0f, ws, v1, false, 1);
  for (const int threads : {2, 3}) {
    INFO(threads << " threads");
    CHECK(ssim(x, y, ws, SsimParams{}, threads) == one);
    ssim_vjp(x, y, 1.0f, ws, v2, false, threads);
    CHECK(v2.data == v1.data);
  }
}

TEST_CASE("ssim: one workspace across shapes and windows gives what a fresh one gives", "[train][losses]") {
  // The backward's derivative rows are kept between zero margins written once
  // per shape: a margin left from another shape or window would show here.
  std::mt19937 rng(5);
  SsimWorkspace<double> reused;
  for (const int window : {11, 3, 11})
    for (const Size s : kSizes) {
      SsimParams p;
      p.window = window;
      const auto x = random_image<double>(s.w, s.h, s.c, rng);
      const auto y = related_image(x, rng, 0.3);
      SsimWorkspace<double> fresh;
      Image<double> v_fresh, v_reused;
      INFO("window " << window << ", " << s.w << "x" << s.h << "x" << s.c);
      CHECK(ssim(x, y, reused, p) == ssim(x, y, fresh, p));
      ssim_vjp(x, y, 1.0, fresh, v_fresh);
      ssim_vjp(x, y, 1.0, reused, v_reused);
      CHECK(v_reused.data == v_fresh.data);
    }
}

TEST_CASE("zero padding: a constant image is not perfectly similar to a scaled copy near borders",
          "[train][losses]") {
  // Inside, mu_x = 0.5 and mu_y = 0.25 everywhere; at the border both shrink with the
  // un-renormalised window, which the reference also does.
  Image<double> x(20, 20, 1, 0.5), y(20, 20, 1, 0.25);
  CHECK(ssim(x, y) == Approx(reference_ssim(x, y)).epsilon(1e-12));
  // Interior pixel value: luminance term (2*0.125 + C1)/(0.3125 + C1), contrast term 1.
  const double c1 = 1e-4;
  const double interior = (2 * 0.5 * 0.25 + c1) / (0.25 + 0.0625 + c1);
  CHECK(ssim(x, y) != Approx(interior).epsilon(1e-6));  // borders matter
}

TEMPLATE_TEST_CASE("ssim of an image with itself is 1, symmetric, and in [-1, 1]", "[train][losses]", float,
                   double) {
  std::mt19937 rng(99);
  const double tol = std::is_same<TestType, float>::value ? 1e-5 : 1e-12;
  for (const Size s : kSizes) {
    const auto x = random_image<TestType>(s.w, s.h, s.c, rng);
    const auto y = random_image<TestType>(s.w, s.h, s.c, rng);
    SsimWorkspace<TestType> ws;
    CHECK(double(ssim(x, x, ws)) == Approx(1.0).margin(tol));
    const double xy = double(ssim(x, y, ws)), yx = double(ssim(y, x, ws));
    CHECK(xy == Approx(yx).margin(tol));
    CHECK(xy < 0.9);
    CHECK(xy > -1.0);
  }
  // Also a constant black image (every variance is zero: C1, C2 keep it finite).
  Image<TestType> black(8, 8, 3, TestType(0));
  CHECK(double(ssim(black, black)) == Approx(1.0).margin(tol));
}

TEST_CASE("l1 value and gradient", "[train][losses]") {
  std::mt19937 rng(7);
  for (const Size s : kSizes) {
    const auto x = random_image<double>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.2);
    double direct = 0;
    for (std::size_t i = 0; i < x.data.size(); ++i) direct += std::abs(x.data[i] - y.data[i]);
    direct /= double(x.data.size());
    CHECK(l1_loss(x, y) == Approx(direct).epsilon(1e-13));
    CHECK(l1_loss(y, x) == Approx(direct).epsilon(1e-13));
    Image<double> v;
    l1_loss_vjp(x, y, 1.0, v);
    check_gradient(x, v, [&](const Image<double>& p) { return l1_loss(p, y); }, 2e-4);
  }
  // Ties: gradient is defined as 0 there.
  Image<double> a(3, 2, 3, 0.5), v;
  l1_loss_vjp(a, a, 1.0, v);
  for (double g : v.data) CHECK(g == 0.0);
}

TEST_CASE("ssim gradient matches central differences at every pixel", "[train][losses]") {
  std::mt19937 rng(2024);
  for (const Size s : kSizes) {
    INFO(s.w << "x" << s.h << "x" << s.c);
    const auto x = random_image<double>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.25);
    SsimWorkspace<double> ws;
    ssim(x, y, ws);
    Image<double> v;
    ssim_vjp(x, y, 1.0, ws, v);
    SsimWorkspace<double> ws_fd;
    check_gradient(x, v, [&](const Image<double>& p) { return ssim(p, y, ws_fd); });
    // Upstream scaling and accumulation.
    Image<double> v2 = v;
    ssim(x, y, ws, SsimParams{}, 2);
    ssim_vjp(x, y, -2.5, ws, v2, true, 2);
    for (std::size_t i = 0; i < v.data.size(); ++i) CHECK(v2.data[i] == Approx(-1.5 * v.data[i]).margin(1e-15));
  }
}

TEST_CASE("combined loss value and gradient", "[train][losses]") {
  std::mt19937 rng(31);
  for (const Size s : kSizes) {
    INFO(s.w << "x" << s.h << "x" << s.c);
    const auto x = random_image<double>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.3);
    SsimWorkspace<double> ws;
    Image<double> v;
    const auto terms = combined_loss(x, y, v, ws);
    const double expect = 0.8 * l1_loss(x, y) + 0.2 * (1 - reference_ssim(x, y));
    CHECK(terms.total == Approx(expect).epsilon(1e-12));
    CHECK(terms.l1 == Approx(l1_loss(x, y)).epsilon(1e-14));
    CHECK(terms.ssim == Approx(reference_ssim(x, y)).epsilon(1e-12));
    double sq = 0;
    for (std::size_t i = 0; i < x.data.size(); ++i) sq += (x.data[i] - y.data[i]) * (x.data[i] - y.data[i]);
    CHECK(terms.mse == Approx(sq / double(x.data.size())).epsilon(1e-12));
    // Rows are split over threads; the sums must not depend on it.
    Image<double> v2;
    SsimWorkspace<double> ws2;
    const auto t2 = combined_loss(x, y, v2, ws2, 0.2, 3);
    CHECK(t2.total == terms.total);
    CHECK(t2.mse == terms.mse);
    CHECK(v2.data == v.data);
    SsimWorkspace<double> ws_fd;
    Image<double> v_fd;
    check_gradient(x, v, [&](const Image<double>& p) { return combined_loss(p, y, v_fd, ws_fd).total; }, 2e-4);
    // Other lambda.
    const auto t5 = combined_loss(x, y, v, ws, 0.5);
    CHECK(t5.total == Approx(0.5 * terms.l1 + 0.5 * (1 - terms.ssim)).epsilon(1e-13));
  }
}

TEMPLATE_TEST_CASE("combined loss: its L1 parts, done as SSIM finishes each row, give the separate passes' bits",
                   "[train][losses]", float, double) {
  using S = TestType;
  std::mt19937 rng(37);
  // Wide enough for whole SIMD vectors, tall enough for several bands of rows.
  for (const Size s : {Size{150, 300, 3}, Size{33, 520, 3}, Size{21, 70, 1}}) {
    INFO(s.w << "x" << s.h << "x" << s.c);
    const auto x = random_image<S>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.3);
    const S lambda = S(0.2);
    for (int threads = 1; threads <= 3; ++threads) {
      INFO(threads << " threads");
      SsimWorkspace<S> ws_ref;
      Image<S> v_ref;
      const S ssim_ref = ssim(x, y, ws_ref, SsimParams{}, threads);
      ssim_vjp(x, y, -lambda, ws_ref, v_ref, false, threads);
      l1_loss_vjp(x, y, S(1) - lambda, v_ref, true);
      double sq = 0;
      for (std::size_t i = 0; i < x.data.size(); ++i) sq += double(x.data[i] - y.data[i]) * double(x.data[i] - y.data[i]);

      SsimWorkspace<S> ws;
      Image<S> v;
      const auto terms = combined_loss(x, y, v, ws, 0.2, threads);
      CHECK(terms.ssim == ssim_ref);
      CHECK(v.data == v_ref.data);
      CHECK(double(terms.l1) == Approx(double(l1_loss(x, y))).epsilon(1e-6));
      CHECK(terms.mse == Approx(sq / double(x.data.size())).epsilon(1e-6));
    }
  }
}

TEST_CASE("ssim in one pass calls each row's hooks once, the backward's after its row is written",
          "[train][losses]") {
  std::mt19937 rng(41);
  // 520 rows: two to four bands of rows at one to three threads.
  constexpr int H = 520;
  const auto x = random_image<float>(40, H, 3, rng);
  const auto y = related_image(x, rng, 0.3);
  for (int threads = 1; threads <= 3; ++threads) {
    INFO(threads << " threads");
    // Each band's forward runs beyond its rows, but calls for its own rows only.
    std::vector<std::atomic<int>> forward(H), backward(H);
    Image<float> v(40, H, 3);
    std::fill(v.data.begin(), v.data.end(), std::numeric_limits<float>::quiet_NaN());  // overwritten row by row
    SsimWorkspace<float> ws;
    const float one_pass = ssim_and_vjp_with(
        x, y, 1.0f, ws, v, SsimParams{}, threads, [&](int row) { ++forward[std::size_t(row)]; },
        [&](int row) {
          for (int px = 0; px < v.width; ++px)
            for (int c = 0; c < v.channels; ++c) CHECK(std::isfinite(v(px, row, c)));
          ++backward[std::size_t(row)];
        });
    SsimWorkspace<float> ws_plain;
    CHECK(one_pass == ssim(x, y, ws_plain, SsimParams{}, threads));
    int once = 0;
    for (std::size_t r = 0; r < forward.size(); ++r) once += forward[r] == 1 && backward[r] == 1 ? 1 : 0;
    CHECK(once == H);
  }
}

TEMPLATE_TEST_CASE("ssim in one pass with its gradient: the separate passes' bits at every window and size",
                   "[train][losses]", float, double) {
  using T = TestType;
  std::mt19937 rng(43);
  for (const int window : {1, 3, 7, 11, 13}) {
    SsimParams p;
    p.window = window;
    p.sigma = window == 11 ? 1.5 : 0.4 + 0.2 * window;
    // Small, narrower and shorter than the window, and tall enough for several bands.
    for (const Size s : {Size{13, 9, 3}, Size{6, 4, 3}, Size{12, 12, 1}, Size{19, 300, 3}, Size{70, 520, 2}}) {
      const auto x = random_image<T>(s.w, s.h, s.c, rng);
      const auto y = related_image(x, rng, 0.3);
      for (const int threads : {1, 2, 3}) {
        INFO("window " << window << ", " << s.w << "x" << s.h << "x" << s.c << ", " << threads << " threads");
        SsimWorkspace<T> ws, ws1;
        Image<T> v, v1;
        const T value = ssim(x, y, ws, p, threads);
        ssim_vjp(x, y, T(0.7), ws, v, false, threads);
        const T one_pass = ssim_and_vjp_with(x, y, T(0.7), ws1, v1, p, threads, [](int) {}, [](int) {});
        CHECK(one_pass == value);
        CHECK(v1.data == v.data);
        // The one pass keeps no forward for ssim_vjp.
        Image<T> v2;
        CHECK_THROWS_WITH(ssim_vjp(x, y, T(0.7), ws1, v2), Catch::Contains("holds no forward pass"));
      }
    }
  }
}

TEMPLATE_TEST_CASE("ssim: the fused map and the separate passes give the same bits", "[train][losses]", float,
                   double) {
  using T = TestType;
  std::mt19937 rng(47);
  // Widths around the batch sizes (tails), heights with several four-row steps and a remainder.
  for (const Size s : {Size{29, 23, 3}, Size{64, 37, 3}, Size{45, 70, 1}}) {
    const auto x = random_image<T>(s.w, s.h, s.c, rng);
    const auto y = related_image(x, rng, 0.3);
    for (const int threads : {1, 2}) {
      INFO(s.w << "x" << s.h << "x" << s.c << ", " << threads << " threads");
      SsimWorkspace<T> fused, separate;
      fused.fuse_map = true;
      separate.fuse_map = false;
      Image<T> v_fused, v_separate;
      const T value_fused = ssim(x, y, fused, SsimParams{}, threads);
      const T value_separate = ssim(x, y, separate, SsimParams{}, threads);
      CHECK(value_fused == value_separate);
      CHECK(fused.dmaps == separate.dmaps);
      ssim_vjp(x, y, T(0.7), fused, v_fused, false, threads);
      ssim_vjp(x, y, T(0.7), separate, v_separate, false, threads);
      CHECK(v_fused.data == v_separate.data);
      const auto one_pass = [&](SsimWorkspace<T>& ws, Image<T>& v) {
        return ssim_and_vjp_with(x, y, T(0.7), ws, v, SsimParams{}, threads, [](int) {}, [](int) {});
      };
      CHECK(one_pass(fused, v_fused) == one_pass(separate, v_separate));
      CHECK(v_fused.data == v_separate.data);
      CHECK(value_fused != T(1));  // related, not equal, images
    }
  }
}

TEST_CASE("float and double agree", "[train][losses]") {
  std::mt19937 rng(5);
  const auto xd = random_image<double>(40, 31, 3, rng);
  const auto yd = related_image(xd, rng, 0.3);
  Image<float> xf(40, 31, 3), yf(40, 31, 3);
  for (std::size_t i = 0; i < xd.data.size(); ++i) {
    xf.data[i] = float(xd.data[i]);
    yf.data[i] = float(yd.data[i]);
  }
  // Evaluate double on the float-rounded values so only arithmetic precision differs.
  Image<double> xr = xd, yr = yd;
  for (std::size_t i = 0; i < xd.data.size(); ++i) {
    xr.data[i] = double(xf.data[i]);
    yr.data[i] = double(yf.data[i]);
  }
  SsimWorkspace<float> wf;
  SsimWorkspace<double> wd;
  Image<float> vf;
  Image<double> vd;
  const auto tf = combined_loss(xf, yf, vf, wf, 0.2, 2);
  const auto td = combined_loss(xr, yr, vd, wd, 0.2, 1);
  CHECK(double(tf.total) == Approx(td.total).epsilon(1e-5));
  CHECK(double(tf.ssim) == Approx(td.ssim).epsilon(1e-5));
  double gmax = 0, err = 0;
  for (std::size_t i = 0; i < vd.data.size(); ++i) {
    gmax = std::max(gmax, std::abs(vd.data[i]));
    err = std::max(err, std::abs(double(vf.data[i]) - vd.data[i]));
  }
  CHECK(err < 1e-4 * gmax);
}

TEST_CASE("losses reject bad input", "[train][losses]") {
  Image<double> a(4, 4, 3), b(4, 5, 3), v;
  SsimWorkspace<double> ws;
  CHECK_THROWS_AS(l1_loss(a, b), Error);
  CHECK_THROWS_AS(ssim(a, b, ws), Error);
  CHECK_THROWS_AS(combined_loss(a, b, v, ws), Error);
  // Backward without a forward pass on this shape.
  SsimWorkspace<double> fresh;
  CHECK_THROWS_AS(ssim_vjp(a, a, 1.0, fresh, v), Error);
  // NaN in the prediction is reported, not returned.
  Image<double> n(4, 4, 3, 0.5);
  n(1, 2, 0) = std::nan("");
  CHECK_THROWS_AS(combined_loss(n, a, v, ws), Error);
  SsimParams even;
  even.window = 10;
  CHECK_THROWS_AS(ssim(a, a, ws, even), Error);
}

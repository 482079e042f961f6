// PSNR, SSIM, MAE (0-255) and compare_images.
#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <random>

#include "orbitforge/metrics/image.hpp"

using namespace orbitforge;

namespace {
template <class S>
Image<S> random_image(int w, int h, int c, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0.0, 1.0);
  Image<S> img(w, h, c);
  for (auto& v : img.data) v = S(u(rng));
  return img;
}
}  // namespace

TEMPLATE_TEST_CASE("psnr of a known mean squared error", "[metrics][image]", float, double) {
  // Every value differs by exactly 0.1 (representable offsets chosen in double, then
  // the MSE is computed from the stored values): MSE = 0.01 -> 20 dB.
  Image<TestType> a(7, 5, 3, TestType(0.25)), b(7, 5, 3, TestType(0.25));
  for (std::size_t i = 0; i < b.data.size(); ++i) b.data[i] = TestType(i % 2 ? 0.35 : 0.15);
  const double d = double(TestType(0.35)) - double(TestType(0.25));
  const double d2 = double(TestType(0.25)) - double(TestType(0.15));
  const std::size_t n = a.data.size();
  const double expected_mse = (d * d * double(n / 2) + d2 * d2 * double(n - n / 2)) / double(n);
  CHECK(mse(a, b) == Approx(expected_mse).epsilon(1e-12));
  CHECK(psnr(a, b) == Approx(-10 * std::log10(expected_mse)).epsilon(1e-12));
  CHECK(psnr(a, b) == Approx(20.0).margin(1e-4));
  CHECK(psnr(a, b) == Approx(psnr(b, a)).epsilon(1e-15));
  // 0-255 scale: mean |diff| = 0.1 -> 25.5.
  CHECK(mae_255(a, b) == Approx(25.5).margin(1e-4));
  CHECK(mae_255(a, b) == Approx(mae_255(b, a)).epsilon(1e-15));
}

TEST_CASE("psnr of identical images is +infinity, and known values", "[metrics][image]") {
  Image<double> a(4, 4, 3, 0.3);
  CHECK(std::isinf(psnr(a, a)));
  CHECK(psnr(a, a) > 0);
  CHECK(psnr_from_mse(1.0) == Approx(0.0).margin(1e-15));
  CHECK(psnr_from_mse(1e-3) == Approx(30.0).epsilon(1e-14));
  CHECK_THROWS_AS(psnr_from_mse(-1.0), Error);
  CHECK_THROWS_AS(psnr_from_mse(std::nan("")), Error);
  // Black vs white: MSE 1 -> 0 dB, MAE 255.
  Image<double> k(3, 3, 3, 0.0), w(3, 3, 3, 1.0);
  CHECK(psnr(k, w) == Approx(0.0).margin(1e-15));
  CHECK(mae_255(k, w) == Approx(255.0).epsilon(1e-15));
}

TEMPLATE_TEST_CASE("ssim metric is the loss's SSIM, symmetric, 1 on identical images", "[metrics][image]",
                   float, double) {
  std::mt19937 rng(42);
  const auto a = random_image<TestType>(23, 17, 3, rng);
  auto b = a;
  std::normal_distribution<double> n(0, 0.05);
  for (auto& v : b.data) v = TestType(std::min(1.0, std::max(0.0, double(v) + n(rng))));
  CHECK(ssim_metric(a, a) == Approx(1.0).margin(1e-12));
  CHECK(ssim_metric(a, b) == Approx(ssim_metric(b, a)).epsilon(1e-12));
  CHECK(ssim_metric(a, b) == Approx(double(ssim(a, b))).epsilon(1e-4));
  CHECK(ssim_metric(a, b) < 0.99);
  CHECK(ssim_metric(a, b) > 0.5);
}

TEST_CASE("compare_images bundles the metrics and names the pair in errors", "[metrics][image]") {
  std::mt19937 rng(3);
  auto a = random_image<float>(16, 12, 3, rng);
  auto b = random_image<float>(16, 12, 3, rng);
  const auto q = compare_images(a, b, "frame_0001.png");
  CHECK(q.psnr == Approx(psnr(a, b)).epsilon(1e-12));
  CHECK(q.ssim == Approx(ssim_metric(a, b)).epsilon(1e-12));
  CHECK(q.mae_255 == Approx(mae_255(a, b)).epsilon(1e-12));
  CHECK(std::isinf(compare_images(a, a).psnr));
  CHECK(compare_images(a, a).ssim == Approx(1.0).margin(1e-12));

  // Out-of-range render values are clamped (as when saved to 8 bits).
  auto bright = a;
  for (auto& v : bright.data) v = v + 2.0f;
  Image<float> white(16, 12, 3, 1.0f);
  CHECK(compare_images(bright, white).mse == Approx(0.0).margin(1e-15));

  Image<float> wrong(16, 13, 3);
  try {
    compare_images(a, wrong, "frame_0007.png");
    FAIL("expected an error");
  } catch (const Error& e) {
    CHECK(std::string(e.what()).find("frame_0007.png") != std::string::npos);
  }
  auto bad = a;
  bad(5, 4, 1) = std::numeric_limits<float>::quiet_NaN();
  try {
    compare_images(bad, b, "view 3");
    FAIL("expected an error");
  } catch (const Error& e) {
    const std::string m = e.what();
    CHECK(m.find("view 3") != std::string::npos);
    CHECK(m.find("(5, 4)") != std::string::npos);
  }
}

TEST_CASE("keep_channels, mean_quality and percentile", "[metrics][image]") {
  Image<float> rgba(2, 2, 4);
  for (std::size_t i = 0; i < rgba.data.size(); ++i) rgba.data[i] = float(i);
  const auto rgb = keep_channels(rgba, 3);
  REQUIRE(rgb.channels == 3);
  CHECK(rgb(1, 1, 2) == rgba(1, 1, 2));
  CHECK(rgb(0, 1, 0) == rgba(0, 1, 0));
  CHECK_THROWS_AS(keep_channels(rgba, 5), Error);

  std::vector<ImageQuality> qs(2);
  qs[0].psnr = 20;
  qs[0].ssim = 0.5;
  qs[1].psnr = 30;
  qs[1].ssim = 0.7;
  const auto m = mean_quality(qs);
  CHECK(m.views == 2);
  CHECK(m.psnr == Approx(25));
  CHECK(m.ssim == Approx(0.6));

  CHECK(percentile({1, 2, 3, 4, 5}, 50) == Approx(3));
  CHECK(percentile({1, 2, 3, 4, 5}, 95) == Approx(4.8));
  CHECK(percentile({10, 0}, 100) == Approx(10));
  CHECK_THROWS_AS(percentile({}, 50), Error);
}

TEMPLATE_TEST_CASE("sequence stability of frames with known differences", "[metrics][image]", float, double) {
  using S = TestType;
  // Frame k is a constant grey level g_k: every pair's L1 is |g_a - g_b| * 255.
  const std::vector<double> grey = {0.1, 0.3, 0.35, 0.95, 0.5};
  SequenceStabilityMeter<S> m;
  for (double g : grey) m.add(Image<S>(7, 5, 3, S(g)));
  const SequenceStability r = m.result();
  std::vector<double> pairs;
  for (std::size_t k = 1; k < grey.size(); ++k) pairs.push_back(std::abs(grey[k] - grey[k - 1]) * 255);
  double mean = 0;
  for (double v : pairs) mean += v / double(pairs.size());
  const double tol = sizeof(S) == 4 ? 1e-4 : 1e-9;
  CHECK(r.frames == 5);
  CHECK(r.adjacent_l1 == Approx(mean).margin(tol));
  // 95th percentile of {51, 12.75, 153, 114.75}: sorted, position 0.95 * 3 = 2.85.
  CHECK(r.adjacent_l1_p95 == Approx(114.75 + 0.85 * (153 - 114.75)).margin(tol));
  CHECK(r.loop_l1 == Approx(0.4 * 255).margin(tol));
  // Values outside [0, 1] are clamped before differencing (like saved frames).
  SequenceStabilityMeter<S> c;
  c.add(Image<S>(2, 2, 3, S(-1)));
  c.add(Image<S>(2, 2, 3, S(2)));
  CHECK(c.result().adjacent_l1 == Approx(255).margin(tol));
  SequenceStabilityMeter<S> one;
  one.add(Image<S>(2, 2, 3, S(0)));
  CHECK_THROWS_AS(one.result(), Error);
  CHECK_THROWS_AS(one.add(Image<S>(3, 2, 3, S(0))), Error);
}

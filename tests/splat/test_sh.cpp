#include <catch2/catch.hpp>

#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "orbitforge/splat/sh.hpp"

using namespace orbitforge;

namespace {

// Spec values of the 3DGS basis written out independently of sh.hpp.
const double kC0 = 0.28209479177387814, kC1 = 0.4886025119029199;
const double kC2[5] = {1.0925484305920792, -1.0925484305920792, 0.31539156525252005, -1.0925484305920792,
                       0.5462742152960396};
const double kC3[7] = {-0.5900435899266435, 2.890611442640554, -0.4570457994644658, 0.3731763325901154,
                       -0.4570457994644658, 1.445305721320277, -0.5900435899266435};

double spec_basis(int k, double x, double y, double z) {
  switch (k) {
    case 0: return kC0;
    case 1: return -kC1 * y;
    case 2: return kC1 * z;
    case 3: return -kC1 * x;
    case 4: return kC2[0] * x * y;
    case 5: return kC2[1] * y * z;
    case 6: return kC2[2] * (2 * z * z - x * x - y * y);
    case 7: return kC2[3] * x * z;
    case 8: return kC2[4] * (x * x - y * y);
    case 9: return kC3[0] * y * (3 * x * x - y * y);
    case 10: return kC3[1] * x * y * z;
    case 11: return kC3[2] * y * (4 * z * z - x * x - y * y);
    case 12: return kC3[3] * z * (2 * z * z - 3 * x * x - 3 * y * y);
    case 13: return kC3[4] * x * (4 * z * z - x * x - y * y);
    case 14: return kC3[5] * z * (x * x - y * y);
    case 15: return kC3[6] * x * (x * x - 3 * y * y);
  }
  return 0;
}

std::vector<double> random_sh(std::mt19937& rng, int degree, double dc_bias) {
  std::uniform_real_distribution<double> u(-0.5, 0.5);
  std::vector<double> sh(3 * sh_coefficient_count(degree));
  for (auto& v : sh) v = u(rng);
  for (int c = 0; c < 3; ++c) sh[c] += dc_bias;
  return sh;
}

}  // namespace

TEST_CASE("SH basis matches the 3DGS constants and sign pattern", "[splat][sh]") {
  const double dirs[][3] = {{1, 0, 0}, {0, 1, 0}, {0, 0, 1}, {0.3, -0.5, 0.8}, {-0.7, 0.1, -0.2}};
  for (const auto& d : dirs) {
    const double n = std::sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2]);
    const double x = d[0] / n, y = d[1] / n, z = d[2] / n;
    double b[16];
    sh_basis(3, x, y, z, b);
    for (int k = 0; k < 16; ++k) REQUIRE(b[k] == Approx(spec_basis(k, x, y, z)).margin(1e-15));
  }
  // A few values worked out by hand: deg-1 at +y is -C1; deg-3 at +x: C3[6].
  double b[16];
  sh_basis(3, 0.0, 1.0, 0.0, b);
  REQUIRE(b[1] == Approx(-0.4886025119029199));
  REQUIRE(b[9] == Approx(0.5900435899266435));
  sh_basis(3, 1.0, 0.0, 0.0, b);
  REQUIRE(b[15] == Approx(-0.5900435899266435));
  REQUIRE(b[13] == Approx(0.4570457994644658));
  sh_basis(3, 0.0, 0.0, 1.0, b);
  REQUIRE(b[12] == Approx(2 * 0.3731763325901154));
}

TEST_CASE("SH basis is orthonormal on the sphere", "[splat][sh]") {
  // Integrate b_i b_j over the sphere: trapezoid in phi (exact for these trig
  // polynomials) times composite Simpson in z = cos(theta) (polynomial integrands).
  const int nphi = 32, nz = 400;
  double gram[16][16] = {};
  for (int iz = 0; iz <= nz; ++iz) {
    const double z = -1 + 2.0 * iz / nz;
    const double wz = (iz == 0 || iz == nz) ? 1 : (iz % 2 ? 4 : 2);
    const double rho = std::sqrt(std::max(0.0, 1 - z * z));
    for (int ip = 0; ip < nphi; ++ip) {
      const double phi = 2 * M_PI * ip / nphi;
      double b[16];
      sh_basis(3, rho * std::cos(phi), rho * std::sin(phi), z, b);
      const double w = wz * (2.0 / nz / 3.0) * (2 * M_PI / nphi);
      for (int i = 0; i < 16; ++i)
        for (int j = 0; j < 16; ++j) gram[i][j] += w * b[i] * b[j];
    }
  }
  for (int i = 0; i < 16; ++i)
    for (int j = 0; j < 16; ++j) REQUIRE(gram[i][j] == Approx(i == j ? 1.0 : 0.0).margin(1e-9));
}

TEMPLATE_TEST_CASE("sh_to_color: DC term, +0.5 offset, clamp at zero", "[splat][sh]", float, double) {
  using S = TestType;
  const S dir[3] = {S(0.2), S(-0.3), S(1)};
  S sh[3] = {S(1), S(-3), S(0)};
  S rgb[3];
  sh_to_color(0, sh, dir, rgb);
  REQUIRE(rgb[0] == Approx(0.28209479177387814 + 0.5).epsilon(1e-6));
  REQUIRE(rgb[1] == S(0));  // 0.5 - 3 C0 < 0
  REQUIRE(rgb[2] == Approx(0.5).epsilon(1e-6));
}

TEMPLATE_TEST_CASE("sh_to_color reads nothing beyond the degree present", "[splat][sh]", float, double) {
  using S = TestType;
  std::mt19937 rng(7);
  for (int degree = 0; degree <= 3; ++degree) {
    const int k = sh_coefficient_count(degree);
    std::vector<S> sh(48, std::numeric_limits<S>::quiet_NaN());
    const auto ref = random_sh(rng, degree, 1.0);
    for (int j = 0; j < 3 * k; ++j) sh[j] = S(ref[j]);
    const S dir[3] = {S(0.4), S(0.1), S(-0.9)};
    S rgb[3];
    sh_to_color(degree, sh.data(), dir, rgb);
    for (int c = 0; c < 3; ++c) REQUIRE(std::isfinite(rgb[c]));
    std::vector<S> v_sh(48, S(-7));
    S v_dir[3];
    const S v_rgb[3] = {S(1), S(2), S(3)};
    sh_to_color_vjp(degree, sh.data(), dir, v_rgb, v_sh.data(), v_dir);
    for (int j = 0; j < 48; ++j) {
      if (j < 3 * k)
        REQUIRE(std::isfinite(v_sh[j]));
      else
        REQUIRE(v_sh[j] == S(-7));  // untouched
    }
    for (int c = 0; c < 3; ++c) REQUIRE(std::isfinite(v_dir[c]));
  }
}

TEST_CASE("sh_to_color: float forward matches double", "[splat][sh]") {
  std::mt19937 rng(11);
  for (int degree = 0; degree <= 3; ++degree) {
    for (int trial = 0; trial < 20; ++trial) {
      const auto sh = random_sh(rng, degree, 0.5);
      std::vector<float> shf(sh.begin(), sh.end());
      std::normal_distribution<double> nd;
      const double dir[3] = {nd(rng), nd(rng), nd(rng)};
      const float dirf[3] = {float(dir[0]), float(dir[1]), float(dir[2])};
      double rgb[3];
      float rgbf[3];
      sh_to_color(degree, sh.data(), dir, rgb);
      sh_to_color(degree, shf.data(), dirf, rgbf);
      for (int c = 0; c < 3; ++c) REQUIRE(std::abs(rgbf[c] - rgb[c]) < 2e-6);
    }
  }
}

TEST_CASE("sh_to_color_vjp matches central finite differences", "[splat][sh][grad]") {
  std::mt19937 rng(1234);
  std::uniform_real_distribution<double> w(-1, 1);
  for (int degree = 0; degree <= 3; ++degree) {
    for (int trial = 0; trial < 5; ++trial) {
      auto sh = random_sh(rng, degree, 2.0);  // bias keeps every channel unclamped
      std::normal_distribution<double> nd;
      double dir[3] = {nd(rng), nd(rng), nd(rng) + 2.0};
      const double v_rgb[3] = {w(rng), w(rng), w(rng)};
      auto loss = [&]() {
        double rgb[3];
        sh_to_color(degree, sh.data(), dir, rgb);
        for (int c = 0; c < 3; ++c) REQUIRE(rgb[c] > 0.1);
        return v_rgb[0] * rgb[0] + v_rgb[1] * rgb[1] + v_rgb[2] * rgb[2];
      };
      std::vector<double> v_sh(sh.size());
      double v_dir[3];
      sh_to_color_vjp(degree, sh.data(), dir, v_rgb, v_sh.data(), v_dir);
      const double h = 1e-6;
      for (std::size_t j = 0; j < sh.size(); ++j) {
        const double keep = sh[j];
        sh[j] = keep + h;
        const double lp = loss();
        sh[j] = keep - h;
        const double lm = loss();
        sh[j] = keep;
        const double fd = (lp - lm) / (2 * h);
        REQUIRE(std::abs(v_sh[j] - fd) <= 1e-6 * std::max(std::abs(fd), 1e-3));
      }
      for (int a = 0; a < 3; ++a) {
        const double keep = dir[a];
        dir[a] = keep + h;
        const double lp = loss();
        dir[a] = keep - h;
        const double lm = loss();
        dir[a] = keep;
        const double fd = (lp - lm) / (2 * h);
        if (degree == 0) REQUIRE(v_dir[a] == 0.0);
        REQUIRE(std::abs(v_dir[a] - fd) <= 1e-6 * std::max(std::abs(fd), 1e-3));
      }
    }
  }
}

TEST_CASE("sh_to_color_vjp passes no gradient through a clamped channel", "[splat][sh][grad]") {
  const double dir[3] = {0.3, 0.2, 1.0};
  std::vector<double> sh(12, 0.0);
  sh[0] = -5;  // red clamped
  sh[1] = 1;   // green not
  sh[3 * 1 + 0] = 0.2;
  sh[3 * 1 + 1] = 0.3;
  const double v_rgb[3] = {1, 1, 0};
  std::vector<double> v_sh(12);
  double v_dir[3];
  sh_to_color_vjp(1, sh.data(), dir, v_rgb, v_sh.data(), v_dir);
  for (int k = 0; k < 4; ++k) {
    REQUIRE(v_sh[3 * k + 0] == 0.0);
    REQUIRE(v_sh[3 * k + 2] == 0.0);
  }
  REQUIRE(v_sh[1] != 0.0);
  // v_dir comes only from green.
  std::vector<double> sh_g = sh;
  for (int k = 0; k < 4; ++k) sh_g[3 * k] = 0;
  const double v_g[3] = {0, 1, 0};
  double v_dir_g[3];
  sh_to_color_vjp(1, sh_g.data(), dir, v_g, nullptr, v_dir_g);
  for (int a = 0; a < 3; ++a) REQUIRE(v_dir[a] == Approx(v_dir_g[a]).margin(1e-15));
}

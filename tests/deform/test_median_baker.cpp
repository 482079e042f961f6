#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "orbitforge/deform/median_baker.hpp"

using namespace orbitforge;

namespace {

template <class S>
GaussianScene<S> random_scene(std::size_t n, std::uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  GaussianScene<S> s;
  s.resize(n, 1);
  for (auto& v : s.means) v = S(u(rng));
  for (auto& v : s.rotations) v = S(u(rng));
  for (auto& v : s.log_scales) v = S(-2 + u(rng));
  for (auto& v : s.opacity_logits) v = S(3 * u(rng));
  for (auto& v : s.sh) v = S(u(rng));
  return s;
}

// Offsets as a function of (Gaussian column values, t): a synthetic deformation.
template <class S, class F>
auto synthetic(F f) {
  return [f](const Eigen::Ref<const Matrix3X<S>>& means, S t, DeformationOffsets<S>& out) {
    out.resize(means.cols());
    for (Eigen::Index j = 0; j < means.cols(); ++j) {
      S o[10];
      f(means.col(j), t, o);
      for (int c = 0; c < 3; ++c) out.dx(c, j) = o[c];
      for (int c = 0; c < 4; ++c) out.dq(c, j) = o[3 + c];
      for (int c = 0; c < 3; ++c) out.ds(c, j) = o[7 + c];
    }
  };
}

// The static state the paper's formulas give for offsets o[10], in double.
template <class S>
void expected_state(const GaussianScene<S>& c, std::size_t j, const double* o, double eps, double* x, double* q,
                    double* l) {
  for (int a = 0; a < 3; ++a) x[a] = double(c.means[3 * j + a]) + o[a];
  double qn = 0;
  for (int a = 0; a < 4; ++a) qn += double(c.rotations[4 * j + a]) * double(c.rotations[4 * j + a]);
  qn = std::sqrt(qn);
  double r[4], rn = 0;
  for (int a = 0; a < 4; ++a) {
    r[a] = double(c.rotations[4 * j + a]) / qn + o[3 + a];
    rn += r[a] * r[a];
  }
  rn = std::sqrt(rn);
  for (int a = 0; a < 4; ++a) q[a] = r[a] / rn;
  for (int a = 0; a < 3; ++a) l[a] = std::log(std::max(std::abs(std::exp(double(c.log_scales[3 * j + a])) + o[7 + a]), eps));
}

template <class S>
void check_state(const GaussianScene<S>& baked, const GaussianScene<S>& c, std::size_t j, const double* o, double eps) {
  const double tol = std::is_same<S, float>::value ? 2e-6 : 1e-14;
  double x[3], q[4], l[3];
  expected_state(c, j, o, eps, x, q, l);
  for (int a = 0; a < 3; ++a) CHECK(std::abs(double(baked.means[3 * j + a]) - x[a]) <= tol * (1 + std::abs(x[a])));
  for (int a = 0; a < 4; ++a) CHECK(std::abs(double(baked.rotations[4 * j + a]) - q[a]) <= 4 * tol);
  for (int a = 0; a < 3; ++a) CHECK(std::abs(double(baked.log_scales[3 * j + a]) - l[a]) <= 4 * tol * (1 + std::abs(l[a])));
}

}  // namespace

TEMPLATE_TEST_CASE("MedianGS of a constant deformation is the canonical scene plus the offset", "[deform][baker]",
                   float, double) {
  using S = TestType;
  auto scene = random_scene<S>(40, 1);
  // Gaussian 1: ds flips the scale's sign (|.| keeps the magnitude);
  // Gaussian 2: scale ends below eps_s (floored).
  scene.log_scales[3 * 2 + 2] = S(std::log(0.5));
  const double o[10] = {0.1, -0.2, 0.3, 0.05, -0.1, 0.2, 0.01, -1.0, 0.02, -0.5};
  std::vector<S> seen_t;
  auto def = [&](const Eigen::Ref<const Matrix3X<S>>& means, S t, DeformationOffsets<S>& out) {
    seen_t.push_back(t);
    out.resize(means.cols());
    for (Eigen::Index j = 0; j < means.cols(); ++j) {
      for (int c = 0; c < 3; ++c) out.dx(c, j) = S(o[c]);
      for (int c = 0; c < 4; ++c) out.dq(c, j) = S(o[3 + c]);
      for (int c = 0; c < 3; ++c) out.ds(c, j) = S(o[7 + c]);
    }
  };
  MedianBakeParams p;
  p.chunk_gaussians = 1000;
  BakeReport report;
  const auto baked = bake_median(scene, def, p, &report);
  // Time codes k / (T_m - 1), both ends included.
  REQUIRE(seen_t.size() == 128);
  CHECK(seen_t.front() == S(0));
  CHECK(seen_t.back() == S(1));
  CHECK(std::abs(seen_t[64] - S(64.0 / 127.0)) <= S(1e-7));
  REQUIRE(baked.size() == scene.size());
  CHECK(baked.sh_degree == scene.sh_degree);
  CHECK(baked.opacity_logits == scene.opacity_logits);
  CHECK(baked.sh == scene.sh);
  for (std::size_t j = 0; j < scene.size(); ++j) check_state(baked, scene, j, o, 1e-6);
  // The floor: exp(log 0.5) - 0.5 = 0 -> log(eps_s).
  CHECK(std::abs(double(baked.log_scales[8]) - std::log(1e-6)) < 1e-3);
  CHECK(report.nonfinite_samples == 0);
  CHECK(report.rotation_fallbacks == 0);
  // Baked rotations are unit quaternions.
  for (std::size_t j = 0; j < scene.size(); ++j) {
    double n2 = 0;
    for (int a = 0; a < 4; ++a) n2 += double(baked.rotations[4 * j + a]) * double(baked.rotations[4 * j + a]);
    CHECK(std::abs(n2 - 1) < 1e-5);
  }
}

TEMPLATE_TEST_CASE("MedianGS ignores a minority of outlier time samples", "[deform][baker]", float, double) {
  using S = TestType;
  const auto scene = random_scene<S>(300, 2);
  // Base offsets depend on the position; 60 of 128 samples (both signs) are wild.
  auto base = [](const Eigen::Matrix<S, 3, 1>& x, double* o) {
    for (int c = 0; c < 10; ++c) o[c] = 0.1 * std::sin(3.0 * c + double(x(0)) + 2 * double(x(1)) - double(x(2)));
  };
  auto def = [&](const Eigen::Ref<const Matrix3X<S>>& means, S t, DeformationOffsets<S>& out) {
    const int k = int(std::lround(double(t) * 127));
    const bool outlier = (k % 32) < 15;  // 4 x 15 = 60 samples
    const double wild = (k % 2 == 0) ? 1e3 : -1e3;
    out.resize(means.cols());
    for (Eigen::Index j = 0; j < means.cols(); ++j) {
      double o[10];
      base(means.col(j), o);
      if (outlier)
        for (double& v : o) v += wild * (1 + 0.01 * k);
      for (int c = 0; c < 3; ++c) out.dx(c, j) = S(o[c]);
      for (int c = 0; c < 4; ++c) out.dq(c, j) = S(o[3 + c]);
      for (int c = 0; c < 3; ++c) out.ds(c, j) = S(o[7 + c]);
    }
  };
  MedianBakeParams p;
  p.chunk_gaussians = 37;  // several chunks, a ragged last one
  const auto baked = bake_median(scene, def, p);
  for (std::size_t j = 0; j < scene.size(); ++j) {
    const Eigen::Matrix<S, 3, 1> x(&scene.means[3 * j]);
    double o[10];
    base(x, o);
    // The base offsets are computed in double here and rounded once to S in def.
    for (double& v : o) v = double(S(v));
    check_state(baked, scene, j, o, 1e-6);
  }
}

TEMPLATE_TEST_CASE("MedianGS takes the lower middle value of an even count", "[deform][baker]", float, double) {
  using S = TestType;
  const auto scene = random_scene<S>(3, 3);
  // Sample k gets value perm(k) (not monotone in t) on every coordinate, scaled per coordinate.
  for (int T : {4, 5, 8, 128}) {
    auto perm = [T](int k) { return (k * 3 + 1) % T; };  // a permutation for T not divisible by 3
    if (T % 3 == 0) continue;
    auto def = synthetic<S>([T, perm](const auto&, S t, S* o) {
      const int k = int(std::lround(double(t) * (T - 1)));
      for (int c = 0; c < 10; ++c) o[c] = S(0.001 * (c + 1) * perm(k));
    });
    MedianBakeParams p;
    p.samples = T;
    const auto baked = bake_median(scene, def, p);
    const double med = (T % 2 == 0) ? T / 2 - 1 : (T - 1) / 2;  // sorted values are 0 .. T-1
    double o[10];
    for (int c = 0; c < 10; ++c) o[c] = double(S(0.001 * (c + 1) * med));
    INFO("T_m = " << T);
    for (std::size_t j = 0; j < scene.size(); ++j) check_state(baked, scene, j, o, 1e-6);
  }
}

TEMPLATE_TEST_CASE("MedianGS never returns non-finite values", "[deform][baker]", float, double) {
  using S = TestType;
  const S nan = std::numeric_limits<S>::quiet_NaN(), inf = std::numeric_limits<S>::infinity();
  const auto scene = random_scene<S>(20, 4);
  // NaN / inf in some samples (even a majority of them for Gaussian 0): the median
  // is taken over the finite samples only.
  auto def = synthetic<S>([&](const auto& x, S t, S* o) {
    const int k = int(std::lround(double(t) * 127));
    const bool first = std::abs(double(x(0)) - double(scene.means[0])) < 1e-12;
    for (int c = 0; c < 10; ++c) o[c] = S(0.01 * c);
    if (k % 5 == 0) o[k % 10] = (k % 2) ? inf : nan;
    if (first && k < 100) o[3] = nan;  // 100 of 128 samples of dq.w are NaN
  });
  BakeReport report;
  const auto baked = bake_median(scene, def, MedianBakeParams{}, &report);
  CHECK(report.nonfinite_samples > 100 * 1);
  for (auto v : baked.means) CHECK(std::isfinite(v));
  for (auto v : baked.rotations) CHECK(std::isfinite(v));
  for (auto v : baked.log_scales) CHECK(std::isfinite(v));
  double o[10];
  for (int c = 0; c < 10; ++c) o[c] = double(S(0.01 * c));
  for (std::size_t j = 0; j < scene.size(); ++j) check_state(baked, scene, j, o, 1e-6);

  // No finite sample at all for one coordinate: an error, not a NaN.
  auto all_nan = synthetic<S>([&](const auto& x, S, S* o) {
    for (int c = 0; c < 10; ++c) o[c] = 0;
    if (std::abs(double(x(0)) - double(scene.means[3 * 7])) < 1e-12) o[8] = nan;
  });
  CHECK_THROWS_AS(bake_median(scene, all_nan), Error);
  // A single time slice has no majority: a non-finite offset is an error.
  CHECK_THROWS_AS(bake_time_slice(scene, all_nan, S(0.2)), Error);

  // Rotation offset that cancels the rotation: keep normalize(q), count it.
  auto cancel = [&](const Eigen::Ref<const Matrix3X<S>>& means, S, DeformationOffsets<S>& out) {
    out.set_zero(means.cols());
    Eigen::Map<const Eigen::Matrix<S, 4, 1>> q(&scene.rotations[4 * 5]);
    out.dq.col(5) = -q.normalized();  // chunk holds all 20 Gaussians
  };
  BakeReport r2;
  const auto b2 = bake_median(scene, cancel, MedianBakeParams{}, &r2);
  CHECK(r2.rotation_fallbacks == 1);
  Eigen::Map<const Eigen::Matrix<S, 4, 1>> q5(&scene.rotations[20]);
  Eigen::Map<const Eigen::Matrix<S, 4, 1>> b5(&b2.rotations[20]);
  CHECK((b5 - q5.normalized()).cwiseAbs().maxCoeff() < S(1e-6));

  // Overflowing scale: an error naming the Gaussian.
  auto big = scene;
  big.log_scales[3 * 9 + 1] = S(1e4);
  auto zero = [](const Eigen::Ref<const Matrix3X<S>>& means, S, DeformationOffsets<S>& out) {
    out.set_zero(means.cols());
  };
  CHECK_THROWS_WITH(bake_median(big, zero), Catch::Contains("Gaussian 9"));
  // Zero canonical quaternion: bad input.
  auto zq = scene;
  for (int a = 0; a < 4; ++a) zq.rotations[4 * 3 + a] = 0;
  CHECK_THROWS_AS(bake_median(zq, zero), Error);
}

TEMPLATE_TEST_CASE("fixed-slice and frame-varying variants use one time code", "[deform][baker]", float, double) {
  using S = TestType;
  const auto scene = random_scene<S>(25, 5);
  auto f = [](const auto& x, S t, S* o) {
    for (int c = 0; c < 10; ++c) o[c] = S(0.05 * std::cos(double(t) * (c + 1) + double(x(1))));
  };
  auto def = synthetic<S>(f);
  MedianBakeParams p;
  p.chunk_gaussians = 6;
  for (S t : {S(0), S(0.3), S(1)}) {
    const auto baked = bake_time_slice(scene, def, t, p);
    CHECK(baked.opacity_logits == scene.opacity_logits);
    for (std::size_t j = 0; j < scene.size(); ++j) {
      Eigen::Map<const Matrix3X<S>> x(&scene.means[3 * j], 3, 1);
      S os[10];
      f(x.col(0), t, os);
      double o[10];
      for (int c = 0; c < 10; ++c) o[c] = double(os[c]);
      check_state(baked, scene, j, o, 1e-6);
    }
  }
  const auto fixed = bake_fixed_slice(scene, def, p);
  const auto half = bake_time_slice(scene, def, S(0.5), p);
  CHECK(fixed.means == half.means);
  CHECK(fixed.rotations == half.rotations);
  CHECK(fixed.log_scales == half.log_scales);
}

TEMPLATE_TEST_CASE("MedianGS of a DeformationField matches a direct per-Gaussian median", "[deform][baker]", float,
                   double) {
  using S = TestType;
  const auto scene = random_scene<S>(50, 6);
  DeformationFieldParams fp;
  fp.depth = 2;
  fp.width = 16;
  fp.head_init_scale = 1.0;
  fp.seed = 9;
  fp.scale_offset = ScaleOffset::additive;  // the paper's formula (expected_state)
  DeformationField<S> field(fp);
  MedianBakeParams p;
  p.samples = 16;
  p.chunk_gaussians = 20;
  const auto baked = bake_median(scene, FieldDeformation<S>(field), p);
  // Direct: evaluate every sample for all Gaussians, sort, take element T/2 - 1.
  typename DeformationField<S>::Workspace ws;
  std::vector<DeformationOffsets<S>> all(16);
  for (int k = 0; k < 16; ++k) field.evaluate(means_matrix(scene), S(k) / S(15), ws, all[std::size_t(k)]);
  for (std::size_t j = 0; j < scene.size(); ++j) {
    double o[10];
    for (int c = 0; c < 10; ++c) {
      std::vector<S> v;
      for (int k = 0; k < 16; ++k) {
        const auto& a = all[std::size_t(k)];
        v.push_back(c < 3 ? a.dx(c, Eigen::Index(j)) : c < 7 ? a.dq(c - 3, Eigen::Index(j)) : a.ds(c - 7, Eigen::Index(j)));
      }
      std::sort(v.begin(), v.end());
      o[c] = double(v[7]);
    }
    check_state(baked, scene, j, o, 1e-6);
  }
}

TEMPLATE_TEST_CASE("MedianGS with relative scale offsets: the median of s exp(ds)", "[deform][baker]", float, double) {
  using S = TestType;
  const auto scene = random_scene<S>(12, 9);
  // ds_k = 0.1 k - 0.4 over the 9 samples: median 0 at k = 4; a Gaussian-dependent shift on top.
  auto rel = [](const Eigen::Ref<const Matrix3X<S>>& means, S t, DeformationOffsets<S>& out) {
    out.set_zero(means.cols());
    out.scale_offset = ScaleOffset::log;
    for (Eigen::Index j = 0; j < means.cols(); ++j)
      for (int a = 0; a < 3; ++a) out.ds(a, j) = S(0.8) * t - S(0.4) + S(0.01) * S(j % 3);
  };
  MedianBakeParams p;
  p.samples = 9;
  const auto b = bake_median(scene, rel, p);
  for (std::size_t j = 0; j < scene.size(); ++j)
    for (int a = 0; a < 3; ++a) {
      INFO("Gaussian " << j << " axis " << a);
      CHECK(b.log_scales[3 * j + std::size_t(a)] ==
            Approx(scene.log_scales[3 * j + std::size_t(a)] + S(0.01) * S(j % 3)).margin(1e-5));
    }
  // A large negative offset stops at the scale floor instead of flipping sign.
  auto shrink = [](const Eigen::Ref<const Matrix3X<S>>& means, S, DeformationOffsets<S>& out) {
    out.set_zero(means.cols());
    out.scale_offset = ScaleOffset::log;
    out.ds.setConstant(S(-200));
  };
  p.scale_floor = 1e-6;
  const auto f = bake_time_slice(scene, shrink, S(0.5), p);
  CHECK(f.log_scales[4] == Approx(std::log(1e-6)).margin(1e-4));
}

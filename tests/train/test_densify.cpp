// 3DGS densification: gradient units, statistics, clone / split / prune on hand-built
// scenes, the split distribution, determinism, opacity reset, schedule and remapping.
#include <catch2/catch.hpp>

#include <cmath>
#include <random>

#include "orbitforge/train/densify.hpp"

using namespace orbitforge;

namespace {

// One Gaussian with isotropic scale s, opacity o, SH DC = (i, 2i, 3i) to tell them apart.
template <class S>
void set_gaussian(GaussianScene<S>& g, std::size_t i, S x, S scale, S opacity) {
  g.means[3 * i] = x;
  g.means[3 * i + 1] = S(2) * x;
  g.means[3 * i + 2] = S(-1);
  for (int a = 0; a < 3; ++a) g.log_scales[3 * i + a] = std::log(scale);
  g.opacity_logits[i] = logit(opacity);
  const std::size_t k3 = 3 * std::size_t(g.sh_coefficients());
  for (std::size_t k = 0; k < k3; ++k) g.sh[k3 * i + k] = S(i) + S(0.01) * S(k);
}

}  // namespace

TEST_CASE("NDC gradient units: d pixel / d ndc = W / 2", "[train][densify]") {
  // pixel(ndc) = ((ndc + 1) W - 1) / 2; for L = a * pixel_x + b * pixel_y the NDC
  // gradient is (a W / 2, b H / 2).
  const int W = 512, H = 384;
  const double a = 3e-6, b = -1e-6;
  auto loss = [&](double nx, double ny) {
    return a * ((nx + 1) * W - 1) / 2 + b * ((ny + 1) * H - 1) / 2;
  };
  const double h = 1e-3;
  const double gx = (loss(0.1 + h, 0.2) - loss(0.1 - h, 0.2)) / (2 * h);
  const double gy = (loss(0.1, 0.2 + h) - loss(0.1, 0.2 - h)) / (2 * h);
  CHECK(ndc_gradient_norm(a, b, W, H) == Approx(std::hypot(gx, gy)).epsilon(1e-9));
  // The published threshold 0.0002 in NDC is 0.0002 / 256 per pixel at W = 512.
  CHECK(ndc_gradient_norm(0.0002 / 256.0, 0.0, 512, 512) == Approx(0.0002).epsilon(1e-12));
}

TEST_CASE("statistics count only visible views", "[train][densify]") {
  DensifyStats<float> st;
  st.reset(3);
  st.add_view(std::vector<float>{1.0f, 2.0f, 3.0f}, std::vector<int>{1, 0, 5});
  st.add_view(std::vector<float>{3.0f, 2.0f, 1.0f}, std::vector<int>{7, 0, 0});
  CHECK(st.mean_grad(0) == Approx(2.0));
  CHECK(st.mean_grad(1) == 0.0);  // never visible
  CHECK(st.mean_grad(2) == Approx(3.0));
  CHECK(st.count[0] == 2);
  CHECK(st.max_radius[0] == 7.0f);
  CHECK(st.max_radius[2] == 5.0f);
  CHECK_THROWS_AS(st.add_view(std::vector<float>{1.0f}, std::vector<int>{1}), Error);
}

TEMPLATE_TEST_CASE("clone, split and prune on a hand-built scene", "[train][densify]", float, double) {
  using S = TestType;
  const S extent = 10;  // dense limit 0.1, world limit 1.0
  GaussianScene<S> g;
  g.resize(8, 1);
  set_gaussian<S>(g, 0, 0, S(0.05), S(0.5));   // small, high grad   -> clone
  set_gaussian<S>(g, 1, 1, S(0.5), S(0.5));    // large, high grad   -> split
  set_gaussian<S>(g, 2, 2, S(0.05), S(0.5));   // low grad           -> kept as is
  set_gaussian<S>(g, 3, 3, S(0.05), S(0.001)); // transparent        -> pruned
  set_gaussian<S>(g, 4, 4, S(2.0), S(0.5));    // huge in world      -> pruned if size_prune
  set_gaussian<S>(g, 5, 5, S(0.05), S(0.5));   // huge on screen     -> pruned if size_prune
  set_gaussian<S>(g, 6, 6, S(0.05), S(0.5));   // high grad, never visible -> kept as is
  set_gaussian<S>(g, 7, 7, S(0.05), S(0.003)); // high grad, transparent: clone and self pruned
  // Rotate the split one by 90 degrees about z.
  const S c = std::sqrt(S(0.5));
  g.rotations[4 * 1 + 0] = c;
  g.rotations[4 * 1 + 3] = c;

  DensifyStats<S> st;
  st.reset(8);
  std::vector<S> grad = {S(3e-4), S(5e-4), S(1e-4), S(0), S(0), S(0), S(9e-4), S(4e-4)};
  std::vector<int> radius = {3, 4, 3, 3, 3, 30, 0, 3};
  st.add_view(grad, radius);
  st.add_view(grad, radius);

  DensifyParams params;
  params.min_gaussians = 0;  // the prune rules alone (the floor has its own test)
  for (bool size_prune : {false, true}) {
    INFO("size_prune " << size_prune);
    GaussianScene<S> s = g;
    std::mt19937 rng(17);
    const DensifyPlan plan = densify_and_prune(s, st, params, extent, size_prune, rng);
    const std::vector<std::uint8_t> keep_expected =
        size_prune ? std::vector<std::uint8_t>{1, 0, 1, 0, 0, 0, 1, 0} : std::vector<std::uint8_t>{1, 0, 1, 0, 1, 1, 1, 0};
    CHECK(plan.keep == keep_expected);
    // Appended: the clone of 0 (the clone of 7 is transparent), two children of 1.
    CHECK(plan.appended_from == std::vector<std::size_t>{0, 1, 1});
    CHECK(plan.cloned == 2);
    CHECK(plan.split == 1);
    CHECK(plan.pruned == (size_prune ? 4u : 2u));
    CHECK(plan.pruned_by_size == (size_prune ? 2u : 0u));  // gaussians 4 and 5; 3 and 7 go for their opacity
    REQUIRE(s.size() == plan.new_size());
    s.check_consistent();

    const std::size_t kept = s.size() - 3;
    // Kept ones in their old order: 0, 2, (4, 5,) 6.
    CHECK(s.means[0] == g.means[0]);
    CHECK(s.means[3 * 1] == g.means[3 * 2]);
    CHECK(s.means[3 * (kept - 1)] == g.means[3 * 6]);
    // The clone is an exact copy of Gaussian 0.
    for (int a = 0; a < 3; ++a) {
      CHECK(s.means[3 * kept + a] == g.means[a]);
      CHECK(s.log_scales[3 * kept + a] == g.log_scales[a]);
    }
    CHECK(s.opacity_logits[kept] == g.opacity_logits[0]);
    for (int k = 0; k < 12; ++k) CHECK(s.sh[12 * kept + k] == g.sh[k]);
    // Split children: scale / 1.6, same rotation, opacity and colour, near the parent.
    for (std::size_t j = kept + 1; j < kept + 3; ++j) {
      for (int a = 0; a < 3; ++a) {
        CHECK(double(std::exp(s.log_scales[3 * j + a])) == Approx(0.5 / 1.6).epsilon(1e-5));
        CHECK(std::abs(s.means[3 * j + a] - g.means[3 + a]) < S(5 * 0.5));
        CHECK(s.means[3 * j + a] != g.means[3 + a]);
      }
      for (int a = 0; a < 4; ++a) CHECK(s.rotations[4 * j + a] == g.rotations[4 + a]);
      CHECK(s.opacity_logits[j] == g.opacity_logits[1]);
      for (int k = 0; k < 12; ++k) CHECK(s.sh[12 * j + k] == g.sh[12 + k]);
    }
    CHECK(s.means[3 * (kept + 1)] != s.means[3 * (kept + 2)]);
  }
}

TEST_CASE("a gradient exactly at the threshold densifies; below does not", "[train][densify]") {
  GaussianScene<double> g;
  g.resize(2, 0);
  set_gaussian<double>(g, 0, 0, 0.05, 0.5);
  set_gaussian<double>(g, 1, 1, 0.05, 0.5);
  DensifyStats<double> st;
  st.reset(2);
  st.add_view(std::vector<double>{0.0002, 0.0002 * (1 - 1e-9)}, std::vector<int>{1, 1});
  std::mt19937 rng(1);
  const auto plan = densify_and_prune(g, st, DensifyParams{}, 10.0, false, rng);
  CHECK(plan.appended_from == std::vector<std::size_t>{0});
}

TEST_CASE("a Gaussian budget takes the largest gradients first and never overflows", "[train][densify]") {
  // Ten Gaussians: 0..5 small (clone, +1 each), 6..9 large (split into 2, +1 each).
  GaussianScene<double> g;
  g.resize(10, 0);
  for (std::size_t i = 0; i < 10; ++i) set_gaussian<double>(g, i, double(i), i < 6 ? 0.05 : 0.5, 0.5);
  DensifyStats<double> st;
  st.reset(10);
  std::vector<double> grad(10);
  for (std::size_t i = 0; i < 10; ++i) grad[i] = 0.001 * double(1 + (i * 7) % 10);  // all above the threshold
  st.add_view(grad, std::vector<int>(10, 1));
  DensifyParams p;
  p.max_gaussians = 14;  // room for 4 more
  std::mt19937 rng(1);
  GaussianScene<double> a = g;
  const auto plan = densify_and_prune(a, st, p, 10.0, false, rng);
  CHECK(a.size() == 14);
  // The four largest gradients: i with (7 i) % 10 in {9, 8, 7, 6} -> i = 7, 4, 1, 8.
  CHECK(plan.cloned == 2);  // 1 and 4
  CHECK(plan.split == 2);   // 7 and 8
  CHECK(plan.keep[7] == 0);
  CHECK(plan.keep[8] == 0);
  // No budget: every candidate densifies.
  GaussianScene<double> b = g;
  densify_and_prune(b, st, DensifyParams{}, 10.0, false, rng);
  CHECK(b.size() == 20);
  // A full budget adds nothing.
  p.max_gaussians = 10;
  GaussianScene<double> c = g;
  CHECK(densify_and_prune(c, st, p, 10.0, false, rng).new_size() == 10);
}

TEST_CASE("split children follow the parent's rotated, scaled distribution", "[train][densify]") {
  // Many identical parents, all split: children offsets should have mean 0 and
  // covariance R diag(s^2) R^T with s = the parent's scales.
  const std::size_t n = 4000;
  const double s[3] = {0.8, 0.3, 0.15};
  // Unit quaternion: rotation of 0.7 rad about the axis (1, 2, 2) / 3.
  const double ang = 0.7, ax[3] = {1 / 3.0, 2 / 3.0, 2 / 3.0};
  const double q[4] = {std::cos(ang / 2), std::sin(ang / 2) * ax[0], std::sin(ang / 2) * ax[1],
                       std::sin(ang / 2) * ax[2]};
  GaussianScene<double> g;
  g.resize(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    g.means[3 * i] = 1.0;
    g.means[3 * i + 1] = -2.0;
    g.means[3 * i + 2] = 0.5;
    for (int a = 0; a < 3; ++a) g.log_scales[3 * i + a] = std::log(s[a]);
    for (int a = 0; a < 4; ++a) g.rotations[4 * i + a] = 2.0 * q[a];  // not normalised on purpose
    g.opacity_logits[i] = 0.0;
  }
  DensifyStats<double> st;
  st.reset(n);
  st.add_view(std::vector<double>(n, 1e-3), std::vector<int>(n, 2));
  std::mt19937 rng(2025);
  const auto plan = densify_and_prune(g, st, DensifyParams{}, 10.0, false, rng);
  REQUIRE(plan.split == n);
  REQUIRE(g.size() == 2 * n);
  // Rotation matrix columns are the Gaussian's axes in the world.
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  const double R[3][3] = {{1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)},
                          {2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)},
                          {2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)}};
  double mean[3] = {0, 0, 0}, cov[3][3] = {};
  const double parent[3] = {1.0, -2.0, 0.5};
  for (std::size_t i = 0; i < g.size(); ++i) {
    double d[3], local[3];
    for (int a = 0; a < 3; ++a) d[a] = g.means[3 * i + a] - parent[a];
    for (int a = 0; a < 3; ++a) local[a] = R[0][a] * d[0] + R[1][a] * d[1] + R[2][a] * d[2];  // R^T d
    for (int a = 0; a < 3; ++a) {
      mean[a] += local[a] / double(g.size());
      for (int b = 0; b < 3; ++b) cov[a][b] += local[a] * local[b] / double(g.size());
    }
  }
  for (int a = 0; a < 3; ++a) {
    INFO("axis " << a);
    CHECK(std::abs(mean[a]) < 4 * s[a] / std::sqrt(double(g.size())));
    CHECK(std::sqrt(cov[a][a]) == Approx(s[a]).epsilon(0.05));
    for (int b = 0; b < 3; ++b)
      if (a != b) CHECK(std::abs(cov[a][b]) < 0.05 * s[a] * s[b] + 4 * s[a] * s[b] / std::sqrt(double(g.size())));
  }
}

TEMPLATE_TEST_CASE("the pruning floor keeps the most opaque when every Gaussian would go", "[train][densify]", float,
                   double) {
  using S = TestType;
  const std::size_t n = 40;
  GaussianScene<S> g;
  g.resize(n, 0);
  // All under min_opacity (0.005), Gaussian i at opacity 1e-4 * (1 + (7 i) % 40).
  for (std::size_t i = 0; i < n; ++i) set_gaussian<S>(g, i, S(i), S(0.05), S(1e-4 * double(1 + (7 * i) % n)));
  DensifyStats<S> st;
  st.reset(n);
  st.add_view(std::vector<S>(n, S(0)), std::vector<int>(n, 3));
  DensifyParams p;
  p.min_gaussians = 10;
  std::mt19937 rng(3);
  GaussianScene<S> s = g;
  const DensifyPlan plan = densify_and_prune(s, st, p, S(10), false, rng);
  REQUIRE(s.size() == 10);
  CHECK(plan.spared == 10);
  CHECK(plan.pruned == n - 10);
  // The ten kept are the ten most opaque, (7 i) % 40 in 30..39, in their old order.
  for (std::size_t i = 0; i < n; ++i) CHECK(bool(plan.keep[i]) == ((7 * i) % n >= 30));
  S lowest_kept = S(1);
  for (std::size_t k = 0; k < s.size(); ++k) lowest_kept = std::min(lowest_kept, sigmoid(s.opacity_logits[k]));
  CHECK(double(lowest_kept) == Approx(1e-4 * 31).epsilon(1e-3));
  // Above the floor the rules decide alone; min_gaussians 0 lets them empty the scene.
  p.min_gaussians = 0;
  GaussianScene<S> e = g;
  CHECK(densify_and_prune(e, st, p, S(10), false, rng).spared == 0);
  CHECK(e.size() == 0);
}

TEST_CASE("seeded densification is deterministic", "[train][densify]") {
  GaussianScene<float> g;
  g.resize(50, 0);
  std::mt19937 init(5);
  std::uniform_real_distribution<float> u(-1, 1);
  for (auto& v : g.means) v = u(init);
  for (auto& v : g.log_scales) v = std::log(0.3f) + 2 * u(init);
  for (auto& v : g.rotations) v = u(init);
  for (auto& v : g.opacity_logits) v = 4 * u(init);
  DensifyStats<float> st;
  st.reset(50);
  std::vector<float> grad(50);
  for (auto& v : grad) v = 4e-4f * (u(init) + 1);
  st.add_view(grad, std::vector<int>(50, 3));
  auto run = [&](unsigned seed) {
    GaussianScene<float> s = g;
    std::mt19937 rng(seed);
    densify_and_prune(s, st, DensifyParams{}, 5.0f, true, rng);
    return s;
  };
  const auto a = run(9), b = run(9), c = run(10);
  CHECK(a.means == b.means);
  CHECK(a.log_scales == b.log_scales);
  CHECK(a.opacity_logits == b.opacity_logits);
  REQUIRE(a.size() == c.size());
  CHECK(a.means != c.means);
}

TEST_CASE("opacity reset caps opacity at 0.01 through the logit", "[train][densify]") {
  GaussianScene<double> g;
  g.resize(3, 0);
  g.opacity_logits = {logit(0.5), logit(0.001), logit(0.0100001)};
  reset_opacity(g);
  CHECK(sigmoid(g.opacity_logits[0]) == Approx(0.01).epsilon(1e-12));
  CHECK(sigmoid(g.opacity_logits[1]) == Approx(0.001).epsilon(1e-12));
  CHECK(sigmoid(g.opacity_logits[2]) == Approx(0.01).epsilon(1e-12));
}

TEST_CASE("schedule: published defaults and scaling to a budget", "[train][densify]") {
  const DensifySchedule s;
  CHECK(s.collects_stats(14999));
  CHECK_FALSE(s.collects_stats(15000));
  CHECK_FALSE(s.densifies_at(500));  // strictly after densify_from
  CHECK(s.densifies_at(600));
  CHECK_FALSE(s.densifies_at(650));
  CHECK(s.densifies_at(14900));
  CHECK_FALSE(s.densifies_at(15000));
  CHECK(s.resets_opacity_at(3000));
  CHECK(s.resets_opacity_at(12000));
  CHECK_FALSE(s.resets_opacity_at(15000));
  CHECK_FALSE(s.resets_opacity_at(500));
  CHECK(s.resets_opacity_at(500, true));
  CHECK_FALSE(s.size_prune_at(3000));
  CHECK(s.size_prune_at(3001));

  const auto t = scale_schedule(3000);
  CHECK(t.densify_from == 50);
  CHECK(t.densify_until == 1500);
  CHECK(t.densify_interval == 10);
  CHECK(t.opacity_reset_interval == 300);
  const auto u = scale_schedule(3000, DensifySchedule{}, 30000, 25);
  CHECK(u.densify_interval == 25);
  CHECK(scale_schedule(30000).densify_until == 15000);
  CHECK_THROWS_AS(scale_schedule(0), Error);
}

TEST_CASE("schedule: floors in passes over the training frames", "[train][densify]") {
  const DensifySchedule budget = scale_schedule(3000, DensifySchedule{}, 30000, 50);  // every 50, reset every 300
  // Up to 100 draws per pass the budget's intervals stand (half a pass <= 50, three passes <= 300).
  for (std::size_t draws : {0u, 8u, 29u, 100u}) {
    INFO(draws);
    const DensifySchedule s = schedule_floors_for_frames(budget, draws, 0.5, 3);
    CHECK(s.densify_interval == 50);
    CHECK(s.opacity_reset_interval == 300);
  }
  const DensifySchedule long_input = schedule_floors_for_frames(budget, 301, 0.5, 3);
  CHECK(long_input.densify_interval == 151);        // ceil(150.5)
  CHECK(long_input.opacity_reset_interval == 903);  // three passes
  CHECK(long_input.densify_from == budget.densify_from);
  CHECK(long_input.densify_until == budget.densify_until);
  const DensifySchedule off = schedule_floors_for_frames(budget, 301, 0, 0);
  CHECK(off.densify_interval == 50);
  CHECK(off.opacity_reset_interval == 300);
  CHECK_THROWS_WITH(schedule_floors_for_frames(budget, 10, -1, 3), Catch::Contains("passes"));
  CHECK_THROWS_WITH(schedule_floors_for_frames(budget, 10, 0.5, std::nan("")), Catch::Contains("passes"));
}

TEST_CASE("remap_per_gaussian follows the plan", "[train][densify]") {
  DensifyPlan plan;
  plan.keep = {1, 0, 1};
  plan.appended_from = {2, 1};
  std::vector<float> m = {1, 1, 2, 2, 3, 3};
  auto z = m;
  remap_per_gaussian(z, 2, plan);
  CHECK(z == std::vector<float>{1, 1, 3, 3, 0, 0, 0, 0});
  remap_per_gaussian(m, 2, plan, AppendFill::copy_source);
  CHECK(m == std::vector<float>{1, 1, 3, 3, 3, 3, 2, 2});
  std::vector<float> wrong(5);
  CHECK_THROWS_AS(remap_per_gaussian(wrong, 2, plan), Error);
}

TEST_CASE("camera extent and bad input", "[train][densify]") {
  std::vector<Camera<double>> cams(2);
  cams[0].t = Eigen::Vector3d(-1, 0, 0);  // centre = -R^T t = (1, 0, 0)
  cams[1].t = Eigen::Vector3d(1, 0, 0);
  CHECK(camera_extent(cams) == Approx(1.1));

  GaussianScene<double> g;
  g.resize(2, 0);
  DensifyStats<double> st;
  st.reset(3);
  std::mt19937 rng(1);
  CHECK_THROWS_AS(densify_and_prune(g, st, DensifyParams{}, 1.0, false, rng), Error);
  st.reset(2);
  CHECK_THROWS_AS(densify_and_prune(g, st, DensifyParams{}, 0.0, false, rng), Error);
}

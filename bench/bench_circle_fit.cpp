// Kasa (the paper's linear fit) vs the geometric (orthogonal-distance) circle fit:
// centre and radius error as the arc shortens (10..360 degrees) and noise grows,
// plus the time per fit. The accuracy table is printed before the timings and
// also attached to each benchmark as counters (center_err, radius_err, relative
// to the radius; mean over 200 noisy trials of 40 points on a unit circle).
#include <benchmark/benchmark.h>

#include <cstdio>
#include <random>
#include <vector>

#include "orbitforge/geometry/circle_fit.hpp"

using namespace orbitforge;
using V2 = Eigen::Vector2d;

static std::vector<V2> noisy_arc(double arc_deg, double noise, std::mt19937& rng, int n = 40) {
  std::normal_distribution<double> g(0, 1);
  std::vector<V2> p;
  for (int i = 0; i < n; ++i) {
    const double a = (15 + arc_deg * i / (arc_deg >= 360 ? n : n - 1)) * M_PI / 180;
    p.push_back(V2(std::cos(a) + noise * g(rng), std::sin(a) + noise * g(rng)));
  }
  return p;
}

struct Accuracy {
  double center = 0, radius = 0;
  int failures = 0;
};

static Accuracy accuracy(CircleFitMethod m, double arc, double noise) {
  std::mt19937 rng(1234);
  CircleFitParams p;
  p.method = m;
  Accuracy a;
  const int trials = 200;
  int ok = 0;
  for (int t = 0; t < trials; ++t) {
    const auto pts = noisy_arc(arc, noise, rng);
    try {
      const auto c = fit_circle(pts, p);
      a.center += c.center.norm();
      a.radius += std::abs(c.radius - 1);
      ++ok;
    } catch (const Error&) {
      ++a.failures;
    }
  }
  a.center /= std::max(ok, 1);
  a.radius /= std::max(ok, 1);
  return a;
}

static const double kArcs[] = {10, 20, 45, 90, 128, 180, 270, 360};
static const double kNoise[] = {0.001, 0.01, 0.03};

static void BM_CircleFit(benchmark::State& state) {
  const auto m = state.range(0) == 0 ? CircleFitMethod::kasa : CircleFitMethod::geometric;
  const double arc = double(state.range(1)), noise = double(state.range(2)) * 1e-3;
  std::mt19937 rng(99);
  const auto pts = noisy_arc(arc, noise, rng);
  CircleFitParams p;
  p.method = m;
  for (auto _ : state) benchmark::DoNotOptimize(fit_circle(pts, p));
  const auto a = accuracy(m, arc, noise);
  state.counters["center_err"] = a.center;
  state.counters["radius_err"] = a.radius;
  state.SetLabel(circle_fit_method_name(m));
}

static void register_all() {
  for (int m = 0; m < 2; ++m)
    for (double arc : kArcs)
      for (double n : kNoise)
        benchmark::RegisterBenchmark("BM_CircleFit", BM_CircleFit)->Args({m, int64_t(arc), int64_t(n * 1e3)});
}

int main(int argc, char** argv) {
  std::printf("Circle fit accuracy, unit radius, 40 points, mean over 200 trials (errors relative to r)\n");
  std::printf("%6s %7s | %12s %12s | %12s %12s\n", "arc", "noise", "kasa centre", "kasa radius", "geo centre",
              "geo radius");
  for (double n : kNoise)
    for (double arc : kArcs) {
      const auto k = accuracy(CircleFitMethod::kasa, arc, n), g = accuracy(CircleFitMethod::geometric, arc, n);
      std::printf("%6.0f %7.3f | %12.5f %12.5f | %12.5f %12.5f\n", arc, n, k.center, k.radius, g.center, g.radius);
    }
  std::fflush(stdout);
  register_all();
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}

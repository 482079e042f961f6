// Per-Gaussian stages: projection + SH colour (forward) and their VJP, for 10k,
// 100k and 300k Gaussians, SH degree 0 and 3, 1 and 2 threads, float; and the
// effect of opacity-aware (tight) rectangles on the pixels splats cover.
//
//   build-project/bench/bench_project --benchmark_min_time=0.3
#include <benchmark/benchmark.h>

#include <map>
#include <random>

#include "orbitforge/splat/project.hpp"

using namespace orbitforge;

namespace {

// A synthetic scene in front of a 512x512 camera: positions in a ball, random
// rotations, scales so that splats cover from below a pixel to ~100 pixels, and a
// wide opacity spread (trained scenes have many faint Gaussians).
template <class S>
const GaussianScene<S>& bench_scene(std::size_t n, int degree) {
  static std::map<std::pair<std::size_t, int>, GaussianScene<S>> cache;
  auto it = cache.find({n, degree});
  if (it != cache.end()) return it->second;
  GaussianScene<S> s;
  s.resize(n, degree);
  std::mt19937 rng(2024);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = S(1.2 * u(rng));
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = S(nd(rng));
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = S(-4.5 + 0.8 * nd(rng));
    s.opacity_logits[i] = S(4 * u(rng));
  }
  for (auto& v : s.sh) v = S(0.2 * u(rng));
  return cache.emplace(std::make_pair(n, degree), std::move(s)).first->second;
}

template <class S>
Camera<S> bench_camera() {
  Intrinsics<S> k{S(450), S(450), S(256), S(256), 512, 512};
  return Camera<S>::look_at({S(0), S(-0.5), S(-3.5)}, {S(0), S(0), S(0)}, {S(0), S(-1), S(0)}, k);
}

void BM_Project(benchmark::State& state) {
  using S = float;
  const std::size_t n = std::size_t(state.range(0));
  const int degree = int(state.range(1)), threads = int(state.range(2));
  const auto& scene = bench_scene<S>(n, degree);
  const auto cam = bench_camera<S>();
  ProjectedSplats<S> out;
  ProjectionStats st;
  project_scene(SceneView<S>(scene), cam, ProjectionParams{}, out, &st, threads);  // first touch of out
  for (auto _ : state) {
    project_scene(SceneView<S>(scene), cam, ProjectionParams{}, out, &st, threads);
    benchmark::DoNotOptimize(out.radius.data());
  }
  state.counters["visible"] = double(st.visible);
  state.counters["time_per_gaussian"] = benchmark::Counter(double(n),
      benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

void BM_ProjectBackward(benchmark::State& state) {
  using S = float;
  const std::size_t n = std::size_t(state.range(0));
  const int degree = int(state.range(1)), threads = int(state.range(2));
  const auto& scene = bench_scene<S>(n, degree);
  const auto cam = bench_camera<S>();
  ProjectedSplats<S> fwd;
  project_scene(SceneView<S>(scene), cam, ProjectionParams{}, fwd, nullptr, threads);
  ProjectedSplatsGrad<S> v;
  v.assign_zero(n);
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1, 1);
  for (auto* a : {&v.v_mean_x, &v.v_mean_y, &v.v_conic_a, &v.v_conic_b, &v.v_conic_c, &v.v_opacity, &v.v_color_r,
                  &v.v_color_g, &v.v_color_b, &v.v_depth})
    for (auto& x : *a) x = u(rng);
  GaussianSceneGrad<S> g;
  project_scene_vjp(SceneView<S>(scene), cam, ProjectionParams{}, fwd, v, g, Freeze{}, threads);  // first touch
  for (auto _ : state) {
    project_scene_vjp(SceneView<S>(scene), cam, ProjectionParams{}, fwd, v, g, Freeze{}, threads);
    benchmark::DoNotOptimize(g.means.data());
  }
  state.counters["time_per_gaussian"] = benchmark::Counter(double(n),
      benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

// Pixel-Gaussian pairs inside the rectangles (what the rasterizer must at least
// look at), with and without tight extents; time is the tight projection.
void BM_TightExtents(benchmark::State& state) {
  using S = float;
  const std::size_t n = std::size_t(state.range(0));
  const auto& scene = bench_scene<S>(n, 0);
  const auto cam = bench_camera<S>();
  ProjectionParams loose, tight;
  loose.tight_extents = false;
  ProjectedSplats<S> a, b;
  ProjectionStats sa, sb;
  project_scene(SceneView<S>(scene), cam, loose, a, &sa, 1);
  for (auto _ : state) {
    project_scene(SceneView<S>(scene), cam, tight, b, &sb, 1);
    benchmark::DoNotOptimize(b.radius.data());
  }
  auto pairs = [](const ProjectedSplats<S>& p) {
    double total = 0;
    for (std::size_t i = 0; i < p.size(); ++i)
      if (p.radius[i] > 0) total += double(p.rect_x1[i] - p.rect_x0[i] + 1) * double(p.rect_y1[i] - p.rect_y0[i] + 1);
    return total;
  };
  const double pl = pairs(a), pt = pairs(b);
  state.counters["pairs_3sigma"] = pl;
  state.counters["pairs_tight"] = pt;
  state.counters["tight_over_3sigma"] = pt / pl;
  state.counters["visible_3sigma"] = double(sa.visible);
  state.counters["visible_tight"] = double(sb.visible);
}

}  // namespace

BENCHMARK(BM_Project)
    ->ArgNames({"n", "deg", "threads"})
    ->ArgsProduct({{10000, 100000, 300000}, {0, 3}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_ProjectBackward)
    ->ArgNames({"n", "deg", "threads"})
    ->ArgsProduct({{10000, 100000, 300000}, {0, 3}, {1, 2}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(BM_TightExtents)->ArgNames({"n"})->Arg(100000)->Unit(benchmark::kMillisecond);

BENCHMARK_MAIN();

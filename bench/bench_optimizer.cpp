// The Gaussians' Adam step (train/gaussian_adam.hpp) over every parameter array,
// as a training step runs it: SH degree 3 (59 values per Gaussian), random
// gradients. Args: Gaussians, threads. Counter ns_g: wall ns per Gaussian.
#include <benchmark/benchmark.h>

#include <chrono>
#include <random>

#include "orbitforge/train/gaussian_adam.hpp"

using namespace orbitforge;

static void BM_GaussianAdam(benchmark::State& state) {
  const std::size_t n = std::size_t(state.range(0));
  const int threads = int(state.range(1));
  TrainParams p;
  GaussianScene<float> scene;
  scene.resize(n, p.max_sh_degree);
  GaussianSceneGrad<float> grad;
  grad.assign_zero(n, p.max_sh_degree);
  std::mt19937 rng(5);
  std::normal_distribution<float> g(0.0f, 1e-3f);
  for (auto* v : {&grad.means, &grad.rotations, &grad.scales, &grad.opacity_logits, &grad.sh})
    for (auto& x : *v) x = g(rng);
  Adam<float> adam = make_gaussian_adam<float>(p, n);
  adam.set_lr(kMeansGroup, 1e-4f);
  step_gaussians(adam, scene, grad, threads);  // first touch of the moments
  const auto t0 = std::chrono::steady_clock::now();
  for (auto _ : state) {
    step_gaussians(adam, scene, grad, threads);
    benchmark::DoNotOptimize(scene.sh.data());
  }
  const double ns = std::chrono::duration<double, std::nano>(std::chrono::steady_clock::now() - t0).count();
  state.counters["ns_g"] = ns / (double(state.iterations()) * double(n));
}
BENCHMARK(BM_GaussianAdam)
    ->Args({66000, 1})
    ->Args({66000, 2})
    ->Args({300000, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();

// Combined 3DGS loss (0.8 L1 + 0.2 (1 - SSIM)), forward + backward, on a 512x512 RGB
// float image: the per-step loss cost of training. Arg: thread count.
#include <benchmark/benchmark.h>

#include <random>

#include "orbitforge/train/losses.hpp"

using namespace orbitforge;

static void BM_CombinedLoss512(benchmark::State& state) {
  const int threads = int(state.range(0));
  const int W = 512, H = 512, C = 3;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Image<float> pred(W, H, C), target(W, H, C), v_pred;
  for (auto& v : pred.data) v = u(rng);
  for (std::size_t i = 0; i < target.data.size(); ++i) target.data[i] = 0.7f * pred.data[i] + 0.3f * u(rng);
  SsimWorkspace<float> ws;
  combined_loss(pred, target, v_pred, ws, 0.2, threads);  // first call allocates
  for (auto _ : state) {
    const auto t = combined_loss(pred, target, v_pred, ws, 0.2, threads);
    benchmark::DoNotOptimize(t.total);
    benchmark::DoNotOptimize(v_pred.data.data());
  }
  state.SetItemsProcessed(state.iterations() * W * H);
}
BENCHMARK(BM_CombinedLoss512)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

static void BM_SsimForward512(benchmark::State& state) {
  const int threads = int(state.range(0));
  std::mt19937 rng(12);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Image<float> pred(512, 512, 3), target(512, 512, 3);
  for (auto& v : pred.data) v = u(rng);
  for (auto& v : target.data) v = u(rng);
  SsimWorkspace<float> ws;
  ssim(pred, target, ws, SsimParams{}, threads);
  for (auto _ : state) benchmark::DoNotOptimize(ssim(pred, target, ws, SsimParams{}, threads));
}
BENCHMARK(BM_SsimForward512)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

BENCHMARK_MAIN();

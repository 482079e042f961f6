// Combined 3DGS loss (0.8 L1 + 0.2 (1 - SSIM)), forward + backward, on an RGB float
// image: the per-step loss cost of training; and the SSIM forward alone.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "orbitforge/train/losses.hpp"

using namespace orbitforge;

// Args: width, height, thread count, cold. Cold empties the caches before each
// call (a 64 MB sweep, not timed), as in training, where the render and its
// backward pass run between two losses.
static void BM_CombinedLoss(benchmark::State& state) {
  const int W = int(state.range(0)), H = int(state.range(1)), threads = int(state.range(2)), C = 3;
  const bool cold = state.range(3) != 0;
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Image<float> pred(W, H, C), target(W, H, C), v_pred;
  for (auto& v : pred.data) v = u(rng);
  for (std::size_t i = 0; i < target.data.size(); ++i) target.data[i] = 0.7f * pred.data[i] + 0.3f * u(rng);
  SsimWorkspace<float> ws;
  combined_loss(pred, target, v_pred, ws, 0.2, threads);  // first call allocates
  std::vector<float> sweep(cold ? std::size_t(16) << 20 : 0, 1.0f);
  for (auto _ : state) {
    if (cold) {
      state.PauseTiming();
      for (std::size_t i = 0; i < sweep.size(); i += 16) sweep[i] += 1.0f;
      benchmark::DoNotOptimize(sweep.data());
      state.ResumeTiming();
    }
    const auto t = combined_loss(pred, target, v_pred, ws, 0.2, threads);
    benchmark::DoNotOptimize(t.total);
    benchmark::DoNotOptimize(v_pred.data.data());
  }
  state.SetItemsProcessed(state.iterations() * W * H);
}
// The default training size and the paper's.
BENCHMARK(BM_CombinedLoss)
    ->ArgNames({"w", "h", "threads", "cold"})
    ->Args({512, 512, 1, 0})
    ->Args({512, 512, 2, 0})
    ->Args({896, 512, 1, 0})
    ->Args({896, 512, 2, 0})
    ->Args({512, 512, 2, 1})
    ->Args({896, 512, 2, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

// Args: thread count, fused (SsimWorkspace::fuse_map): the two ways the
// forward runs, for choosing the default on a machine.
static void BM_SsimForward512(benchmark::State& state) {
  const int threads = int(state.range(0));
  std::mt19937 rng(12);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Image<float> pred(512, 512, 3), target(512, 512, 3);
  for (auto& v : pred.data) v = u(rng);
  for (auto& v : target.data) v = u(rng);
  SsimWorkspace<float> ws;
  ws.fuse_map = state.range(1) != 0;
  ssim(pred, target, ws, SsimParams{}, threads);
  for (auto _ : state) benchmark::DoNotOptimize(ssim(pred, target, ws, SsimParams{}, threads));
}
BENCHMARK(BM_SsimForward512)
    ->ArgNames({"threads", "fused"})
    ->ArgsProduct({{1, 2}, {0, 1}})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

BENCHMARK_MAIN();

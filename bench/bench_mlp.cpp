// Speed of the deformation field on 50k Gaussians (float): forward (encoding + MLP)
// and forward + backward (parameter gradients, as in a training step), for the
// original 8 x 256 network and smaller candidates; the thread count and GEMM
// chunk; the activation layout (points as columns vs rows); and the MedianGS bake.
//
//   build-nn/bench/bench_mlp --benchmark_filter=Deform
//
// The field benchmarks report the CPU time of the whole process (all threads):
// on a shared, loaded 2-core machine CPU / threads predicts the unloaded wall
// time better than the wall time does.
#include <benchmark/benchmark.h>

#include <random>
#include <vector>

#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/deform/median_baker.hpp"

using namespace orbitforge;

namespace {

constexpr Eigen::Index kPoints = 50000;

Matrix3X<float> random_means(Eigen::Index n) {
  std::mt19937 rng(1);
  std::uniform_real_distribution<float> u(-1, 1);
  Matrix3X<float> m(3, n);
  for (Eigen::Index i = 0; i < m.size(); ++i) m(i) = u(rng);
  return m;
}

DeformationFieldParams field_params(int depth, int width, int skip) {
  DeformationFieldParams p;
  p.depth = depth;
  p.width = width;
  p.skip_layer = skip;
  return p;
}

// Args: depth, width, skip (-1 none), threads, chunk columns
void BM_DeformForward(benchmark::State& state) {
  DeformationField<float> f(field_params(int(state.range(0)), int(state.range(1)), int(state.range(2))));
  f.mlp().chunk_columns = state.range(4);
  const auto x = random_means(kPoints);
  typename DeformationField<float>::Workspace ws;
  DeformationOffsets<float> off;
  f.evaluate(x, 0.4f, ws, off, int(state.range(3)));  // warm-up: workspace allocation and first touch
  for (auto _ : state) {
    f.evaluate(x, 0.4f, ws, off, int(state.range(3)));
    benchmark::DoNotOptimize(off.dx.data());
  }
}

void BM_DeformForwardBackward(benchmark::State& state) {
  DeformationField<float> f(field_params(int(state.range(0)), int(state.range(1)), int(state.range(2))));
  f.mlp().chunk_columns = state.range(4);
  const auto x = random_means(kPoints);
  typename DeformationField<float>::Workspace ws;
  DeformationOffsets<float> off, v;
  v.resize(kPoints);
  v.dx.setConstant(1e-3f);
  v.dq.setConstant(-1e-3f);
  v.ds.setConstant(2e-3f);
  std::vector<float> g(f.parameter_count());
  f.evaluate(x, 0.4f, ws, off, int(state.range(3)));  // warm-up
  f.evaluate_vjp(ws, v, g.data(), nullptr, int(state.range(3)));
  for (auto _ : state) {
    f.evaluate(x, 0.4f, ws, off, int(state.range(3)));
    std::fill(g.begin(), g.end(), 0.f);
    f.evaluate_vjp(ws, v, g.data(), nullptr, int(state.range(3)));
    benchmark::DoNotOptimize(g.data());
  }
}

void field_args(benchmark::internal::Benchmark* b) {
  b->ArgNames({"depth", "width", "skip", "threads", "chunk"});
  // The published network, then candidates for the CPU default.
  for (int threads : {1, 2}) b->Args({8, 256, 4, threads, 1024});
  for (int threads : {1, 2}) {
    b->Args({6, 128, 3, threads, 1024});
    b->Args({4, 128, -1, threads, 1024});
    b->Args({4, 64, -1, threads, 1024});
    b->Args({4, 64, 1, threads, 1024});
    b->Args({3, 64, -1, threads, 1024});
    b->Args({2, 64, -1, threads, 1024});
    b->Args({3, 32, -1, threads, 1024});
  }
  // GEMM chunk size for the default.
  for (int chunk : {256, 4096, 50000}) b->Args({4, 64, -1, 2, chunk});
  // CPU time of all threads: on a loaded 2-core machine, CPU / threads estimates the
  // unloaded wall time better than the wall time does.
  b->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime()->UseRealTime();
}

// One 256 -> 256 layer over 50k points: points as columns (W A, column-major A)
// against points as rows (A W^T, row-major A).
void BM_LayoutColumns(benchmark::State& state) {
  const Eigen::Index w = state.range(0), chunk = 1024;
  Eigen::MatrixXf W = Eigen::MatrixXf::Random(w, w), A = Eigen::MatrixXf::Random(w, kPoints), Z(w, kPoints);
  for (auto _ : state) {
    for (Eigen::Index c = 0; c < kPoints; c += chunk) {
      const Eigen::Index m = std::min(chunk, kPoints - c);
      Z.middleCols(c, m).noalias() = W * A.middleCols(c, m);
    }
    benchmark::DoNotOptimize(Z.data());
  }
}
void BM_LayoutRows(benchmark::State& state) {
  using RowM = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;
  const Eigen::Index w = state.range(0), chunk = 1024;
  Eigen::MatrixXf W = Eigen::MatrixXf::Random(w, w);
  RowM A = RowM::Random(kPoints, w), Z(kPoints, w);
  for (auto _ : state) {
    for (Eigen::Index c = 0; c < kPoints; c += chunk) {
      const Eigen::Index m = std::min(chunk, kPoints - c);
      Z.middleRows(c, m).noalias() = A.middleRows(c, m) * W.transpose();
    }
    benchmark::DoNotOptimize(Z.data());
  }
}

// MedianGS: 128 time samples of the default field over 50k Gaussians.
void BM_MedianBake(benchmark::State& state) {
  DeformationField<float> f(field_params(int(state.range(0)), int(state.range(1)), int(state.range(2))));
  GaussianScene<float> scene;
  scene.resize(std::size_t(kPoints), 0);
  const auto x = random_means(kPoints);
  std::copy(x.data(), x.data() + x.size(), scene.means.begin());
  for (auto _ : state) {
    auto baked = bake_median(scene, FieldDeformation<float>(f, 2), MedianBakeParams{});
    benchmark::DoNotOptimize(baked.means.data());
  }
}

}  // namespace

BENCHMARK(BM_DeformForward)->Apply(field_args);
BENCHMARK(BM_DeformForwardBackward)->Apply(field_args);
BENCHMARK(BM_LayoutColumns)->Arg(64)->Arg(256)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_LayoutRows)->Arg(64)->Arg(256)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_MedianBake)->Args({4, 64, -1})->Unit(benchmark::kMillisecond)->Iterations(1)->MeasureProcessCPUTime()->UseRealTime();

BENCHMARK_MAIN();

// Whole orbit fit on 121 synthetic source cameras (the paper's median source
// length), and binning + endpoint-window layout on its result.
#include <benchmark/benchmark.h>

#include "../tests/geometry/synthetic_orbit.hpp"
#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"

using namespace orbitforge;

template <class S>
static std::vector<FrameCamera<S>> source121() {
  orbitforge_test::SyntheticOrbit<S> o;
  o.count = 121;
  o.step_deg = 1.07;
  o.noise = 0.005;
  o.angle_noise_deg = 0.3;
  std::mt19937 rng(5);
  o.world_R_orbit = orbitforge_test::random_rotation<S>(rng);
  return o.cameras();
}

template <class S>
static void BM_FitOrbit121(benchmark::State& state) {
  const auto src = source121<S>();
  for (auto _ : state) benchmark::DoNotOptimize(fit_orbit(src));
  state.SetItemsProcessed(state.iterations() * 121);
}
BENCHMARK_TEMPLATE(BM_FitOrbit121, float);
BENCHMARK_TEMPLATE(BM_FitOrbit121, double);

static void BM_BinningAndLayout(benchmark::State& state) {
  const auto fit = fit_orbit(source121<double>());
  std::vector<double> az;
  std::vector<std::string> names;
  for (const auto& s : fit.source) {
    az.push_back(s.azimuth_deg);
    names.push_back(s.name);
  }
  for (auto _ : state) {
    const auto sup = bin_sources(az, fit.orbit.theta0_deg, fit.orbit.direction, 361);
    const auto L = endpoint_window_layout(sup, names);
    benchmark::DoNotOptimize(assembly_plan(L));
  }
}
BENCHMARK(BM_BinningAndLayout);

BENCHMARK_MAIN();

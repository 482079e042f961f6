// Renderer speed: forward and backward at 256x256, 512x512 and 896x512 with 10k,
// 100k and 300k Gaussians, 1 and 2 threads, float; plus 3-sigma rects against the
// opacity-aware ones.
//
// Scenes are random but shaped like real ones: Gaussians in a box in front of the
// camera, anisotropic, opacities spread over (0, 1), SH degree 3, sized so that
// 512x512 with 100k Gaussians blends about 35 Gaussians per pixel.
// BM_ForwardBall / BM_BackwardBall: a sparser scene that weighs the per-Gaussian
// stages more: means uniform in a unit ball, scales log-normal around 0.03
// (sigma 0.4), opacity logits uniform in [-3, 4], SH degree 3, seen from radius 3
// at 20 degrees elevation with fx = fy = 440 (about 21 contributions per pixel at
// 512x512 with 100k Gaussians).
//
// Counters (per frame): contrib_px (contributions per pixel), fwd_ns_contrib and
// bwd_ns_contrib (rasterizer forward / backward time per contribution, ns),
// project_ms, sort_ms, bin_ms, raster_ms, and for backward the split between the
// per-pixel and per-Gaussian stages. Whole passes: pass_ns_contrib (the whole
// forward or backward, wall, per contribution) and, per Gaussian of the scene
// (ns): project_ns_g, sort_ns_g, bin_ns_g and their sum gauss_ns_g (forward),
// bwd_project_ns_g (backward). BM_RasterKernels also reports the kernels'
// time per evaluated pixel-Gaussian pair (fwd_ns_eval, bwd_ns_eval), to set
// against BM_ExpBlendLoop: the same evaluation (conic power, exp, alpha, colour
// and transmittance blend) in a plain SIMD loop with every operand in registers
// or L1, the speed one core sustains without tiles, lists or early stops.
// BM_PerGaussianMemory: the memory traffic of the per-Gaussian stages without
// their arithmetic (the floor under gauss_ns_g; see the function).
// BM_EmptyFrame: the forward pass of a frame with one Gaussian in one tile, so
// nearly every tile only writes its outputs (colour, transmittance, depth, count,
// replay); empty_ns_px is the whole pass per pixel. A trained scene's backdrop
// is such tiles, and threads write neighbouring ones.
// BM_RasterKernelsScene: the same kernels on a scene of your own, e.g. one that
// full_pipeline trained, at every K-th camera of a camera or orbit file; it is
// registered only when the environment names them:
//   ORBITFORGE_BENCH_PLY=out/doll/final.ply ORBITFORGE_BENCH_CAMERAS=out/doll/orbit.json
//   [ORBITFORGE_BENCH_EVERY=24] bench_render --benchmark_filter=Scene   (one command line)
//
//   build-raster/bench/bench_render --benchmark_filter=Forward/512/512/100000
#include <benchmark/benchmark.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <map>
#include <memory>
#include <random>
#include <cstdlib>
#include <ctime>
#include <string>

#include "orbitforge/io/ply.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/train_params.hpp"

using namespace orbitforge;

namespace {

GaussianScenef make_scene(std::size_t n) {
  std::mt19937 rng(1234);
  std::uniform_real_distribution<float> u(-1.f, 1.f), u01(0.f, 1.f);
  std::normal_distribution<float> nd;
  GaussianScenef s;
  s.resize(n, 3);
  // Scale with density so that the depth complexity per pixel stays realistic.
  const float base = std::log(0.03f * std::sqrt(100000.f / float(n)));
  for (std::size_t i = 0; i < n; ++i) {
    s.means[3 * i + 0] = 1.1f * u(rng);
    s.means[3 * i + 1] = 1.1f * u(rng);
    s.means[3 * i + 2] = 0.8f * u(rng);
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = nd(rng);
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = base + 0.5f * u(rng);
    s.opacity_logits[i] = 4.f + 2.f * nd(rng);
  }
  for (std::size_t j = 0; j < s.sh.size(); ++j) s.sh[j] = (j % 48 < 3 ? 0.8f : 0.15f) * u(rng);
  return s;
}

GaussianScenef make_ball_scene(std::size_t n) {
  std::mt19937 rng(4321);
  std::uniform_real_distribution<float> u(-1.f, 1.f), logit(-3.f, 4.f);
  std::normal_distribution<float> nd;
  GaussianScenef s;
  s.resize(n, 3);
  for (std::size_t i = 0; i < n; ++i) {
    Eigen::Vector3f x;
    do x = Eigen::Vector3f(u(rng), u(rng), u(rng));
    while (x.squaredNorm() > 1.f);  // rejection: uniform in the ball
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = x[a];
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = nd(rng);
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = std::log(0.03f) + 0.4f * nd(rng);
    s.opacity_logits[i] = logit(rng);
  }
  for (std::size_t j = 0; j < s.sh.size(); ++j) s.sh[j] = (j % 48 < 3 ? 0.8f : 0.15f) * u(rng);
  return s;
}

const GaussianScenef& scene(std::size_t n, bool ball = false) {
  static std::map<std::pair<std::size_t, bool>, std::unique_ptr<GaussianScenef>> cache;
  auto& p = cache[{n, ball}];
  if (!p) p = std::make_unique<GaussianScenef>(ball ? make_ball_scene(n) : make_scene(n));
  return *p;
}

Cameraf camera(int w, int h) {
  Cameraf c;
  const float f = 1.1f * float(h);  // vertical fov ~ 49 degrees
  c.intrinsics = {f, f, 0.5f * float(w), 0.5f * float(h), w, h};
  c.t = Eigen::Vector3f(0, 0, 3.2f);
  return c;
}

// The ball scene's camera: radius 3, elevation 20 degrees, looking at the origin
// (world z up), fx = fy = 440.
Cameraf ball_camera(int w, int h) {
  const float el = 20.f * float(M_PI) / 180.f;
  const Eigen::Vector3f centre(3.f * std::cos(el), 0.f, 3.f * std::sin(el));
  const Eigen::Vector3f forward = -centre.normalized();
  const Eigen::Vector3f right = forward.cross(Eigen::Vector3f::UnitZ()).normalized();
  const Eigen::Vector3f down = forward.cross(right);
  Cameraf c;
  c.intrinsics = {440.f, 440.f, 0.5f * float(w), 0.5f * float(h), w, h};
  c.R.row(0) = right.transpose();
  c.R.row(1) = down.transpose();
  c.R.row(2) = forward.transpose();
  c.t = -c.R * centre;
  return c;
}

// CPU time of the calling thread: on a shared machine wall time also counts other
// people's work; with threads = 1 every stage runs on this thread.
double thread_cpu_ms() {
  timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return double(ts.tv_sec) * 1e3 + double(ts.tv_nsec) * 1e-6;
}

void set_counters(benchmark::State& state, const RenderStats& st, int w, int h) {
  state.counters["contrib_px"] = double(st.contributions) / (double(w) * h);
  state.counters["evaluated_px"] = double(st.pairs_evaluated) / (double(w) * h);
  state.counters["visible"] = double(st.gaussians_visible);
  state.counters["project_ms"] = st.project_ms;
  state.counters["sort_ms"] = st.sort_ms;
  state.counters["bin_ms"] = st.bin_ms;
  state.counters["raster_ms"] = st.raster_ms;
  state.counters["fwd_ns_contrib"] = st.raster_ms * 1e6 / double(std::max<std::uint64_t>(1, st.contributions));
}

// Args: width, height, gaussians, threads, tight_extents
void forward_pass(benchmark::State& state, bool ball) {
  const int w = int(state.range(0)), h = int(state.range(1));
  const std::size_t n = std::size_t(state.range(2));
  const auto& s = scene(n, ball);
  RenderParams<float> p;
  p.threads = int(state.range(3));
  p.tight_extents = state.range(4) != 0;
  Renderer<float> r(p);
  const auto cam = ball ? ball_camera(w, h) : camera(w, h);
  r.render(SceneView<float>(s), cam);  // first frame allocates
  RenderStats sum;
  double cpu = 0;
  for (auto _ : state) {
    const double c0 = thread_cpu_ms();
    const auto& out = r.render(SceneView<float>(s), cam);
    cpu += thread_cpu_ms() - c0;
    benchmark::DoNotOptimize(out.color.data.data());
    sum.project_ms += out.frame.project_ms;
    sum.sort_ms += out.frame.sort_ms;
    sum.bin_ms += out.frame.bin_ms;
    sum.raster_ms += out.frame.raster_ms;
    sum.total_ms += out.frame.total_ms;
    sum.contributions = out.frame.contributions;
    sum.pairs_evaluated = out.frame.pairs_evaluated;
    sum.gaussians_visible = out.frame.gaussians_visible;
    sum.tile_entries = out.frame.tile_entries;
  }
  const double k = 1.0 / double(state.iterations());
  sum.project_ms *= k; sum.sort_ms *= k; sum.bin_ms *= k; sum.raster_ms *= k; sum.total_ms *= k;
  set_counters(state, sum, w, h);
  state.counters["main_thread_cpu_ms"] = cpu * k;
  state.counters["tile_entries"] = double(sum.tile_entries);
  state.counters["pass_ns_contrib"] = sum.total_ms * 1e6 / double(std::max<std::uint64_t>(1, sum.contributions));
  const double per_g = 1e6 / double(std::max<std::size_t>(1, n));
  state.counters["project_ns_g"] = sum.project_ms * per_g;
  state.counters["sort_ns_g"] = sum.sort_ms * per_g;
  state.counters["bin_ns_g"] = sum.bin_ms * per_g;
  state.counters["gauss_ns_g"] = (sum.project_ms + sum.sort_ms + sum.bin_ms) * per_g;
}
void BM_Forward(benchmark::State& state) { forward_pass(state, false); }
void BM_ForwardBall(benchmark::State& state) { forward_pass(state, true); }

// Args: width, height, gaussians, threads. dL/dcolour = 1 everywhere plus alpha and depth terms.
void backward_pass(benchmark::State& state, bool ball) {
  const int w = int(state.range(0)), h = int(state.range(1));
  const std::size_t n = std::size_t(state.range(2));
  const auto& s = scene(n, ball);
  RenderParams<float> p;
  p.threads = int(state.range(3));
  Renderer<float> r(p);
  const auto cam = ball ? ball_camera(w, h) : camera(w, h);
  const auto& out = r.render(SceneView<float>(s), cam);
  Imagef v_color(w, h, 3, 1.f), v_alpha(w, h, 1, 0.5f), v_depth(w, h, 1, 0.01f);
  r.backward(SceneView<float>(s), cam, v_color, &v_alpha, &v_depth);  // first call allocates
  double raster_ms = 0, project_ms = 0, pass_ms = 0;
  for (auto _ : state) {
    const auto t0 = std::chrono::steady_clock::now();
    const auto& g = r.backward(SceneView<float>(s), cam, v_color, &v_alpha, &v_depth);
    benchmark::DoNotOptimize(g.means.data());
    pass_ms += std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
    raster_ms += r.output().frame.backward_raster_ms;
    project_ms += r.output().frame.backward_project_ms;
  }
  const double k = 1.0 / double(state.iterations());
  state.counters["contrib_px"] = double(out.frame.contributions) / (double(w) * h);
  state.counters["bwd_raster_ms"] = raster_ms * k;
  state.counters["bwd_project_ms"] = project_ms * k;
  const double contributions = double(std::max<std::uint64_t>(1, out.frame.contributions));
  state.counters["bwd_ns_contrib"] = raster_ms * k * 1e6 / contributions;
  state.counters["pass_ns_contrib"] = pass_ms * k * 1e6 / contributions;
  state.counters["bwd_project_ns_g"] = project_ms * k * 1e6 / double(std::max<std::size_t>(1, n));
}
void BM_Backward(benchmark::State& state) { backward_pass(state, false); }
void BM_BackwardBall(benchmark::State& state) { backward_pass(state, true); }

// The per-pixel kernels alone, one thread, timed in thread CPU time.
// Args: width, height, gaussians.
void BM_RasterKernels(benchmark::State& state) {
  const int w = int(state.range(0)), h = int(state.range(1));
  const auto& s = scene(std::size_t(state.range(2)));
  ProjectedSplats<float> splats;
  project_scene(SceneView<float>(s), camera(w, h), ProjectionParams{}, splats, nullptr, 1);
  BinWorkspace<float> bins;
  RasterWorkspace<float> ws;
  RasterOutput<float> out;
  RasterGradOutput<float> grad;
  RasterParams<float> rp;
  rp.threads = 1;
  Imagef v_color(w, h, 3, 1.f), v_alpha(w, h, 1, 0.5f), v_depth(w, h, 1, 0.01f);
  bin_splats(splats, w, h, 16, bins);  // warm-up: the first frame allocates
  rasterize(bins, rp, out, ws);
  rasterize_vjp(bins, rp, out, v_color, &v_alpha, &v_depth, splats.size(), grad, ws);
  double bin = 0, fwd = 0, bwd = 0;
  for (auto _ : state) {
    const double t0 = thread_cpu_ms();
    bin_splats(splats, w, h, 16, bins);
    const double t1 = thread_cpu_ms();
    rasterize(bins, rp, out, ws);
    const double t2 = thread_cpu_ms();
    rasterize_vjp(bins, rp, out, v_color, &v_alpha, &v_depth, splats.size(), grad, ws);
    const double t3 = thread_cpu_ms();
    bin += t1 - t0; fwd += t2 - t1; bwd += t3 - t2;
  }
  const double k = 1.0 / double(state.iterations());
  const double c = double(std::max<std::uint64_t>(1, out.stats.contributions));
  state.counters["contrib_px"] = c / (double(w) * h);
  state.counters["bin_cpu_ms"] = bin * k;
  state.counters["fwd_cpu_ms"] = fwd * k;
  state.counters["bwd_cpu_ms"] = bwd * k;
  state.counters["fwd_ns_contrib"] = fwd * k * 1e6 / c;
  state.counters["bwd_ns_contrib"] = bwd * k * 1e6 / c;
  const double e = double(std::max<std::uint64_t>(1, out.stats.pairs_evaluated));
  state.counters["evaluated_px"] = e / (double(w) * h);
  state.counters["fwd_ns_eval"] = fwd * k * 1e6 / e;
  state.counters["bwd_ns_eval"] = bwd * k * 1e6 / e;
}

// BM_RasterKernels on a given scene and cameras (header comment): each camera's
// bins are made once, then every pass runs the forward and backward kernels at
// all of them, one thread, thread CPU time. The same counters, summed over the
// cameras.
void BM_RasterKernelsScene(benchmark::State& state, const std::string& ply, const std::string& cameras_file,
                           int every) {
  const GaussianScenef s = read_ply<float>(ply);
  const std::vector<Cameraf> all = read_cameras_json<float>(cameras_file);
  struct View {
    BinWorkspace<float> bins;
    RasterOutput<float> out;
    Imagef v_color;
  };
  std::vector<std::unique_ptr<View>> views;
  ProjectionParams pp;
  pp.near_plane = TrainParams{}.near_plane_fraction * double(camera_extent(all));  // as training and render_orbit set it
  ProjectedSplats<float> splats;
  for (std::size_t i = 0; i < all.size(); i += std::size_t(every)) {
    auto v = std::make_unique<View>();
    const int w = all[i].intrinsics.width, h = all[i].intrinsics.height;
    project_scene(SceneView<float>(s), all[i], pp, splats, nullptr, 1);
    bin_splats(splats, w, h, 16, v->bins);
    v->v_color = Imagef(w, h, 3, 1.f);
    views.push_back(std::move(v));
  }
  RasterWorkspace<float> ws;
  RasterGradOutput<float> grad;
  RasterParams<float> rp;
  rp.threads = 1;
  double fwd = 0, bwd = 0, pixels = 0, contributions = 0, evaluated = 0;
  for (auto& v : views) {  // warm-up: the first frame allocates
    rasterize(v->bins, rp, v->out, ws);
    rasterize_vjp(v->bins, rp, v->out, v->v_color, nullptr, nullptr, s.size(), grad, ws);
    pixels += double(v->bins.grid.pixel_count());
    contributions += double(v->out.stats.contributions);
    evaluated += double(v->out.stats.pairs_evaluated);
  }
  for (auto _ : state) {
    for (auto& v : views) {
      const double t0 = thread_cpu_ms();
      rasterize(v->bins, rp, v->out, ws);
      const double t1 = thread_cpu_ms();
      rasterize_vjp(v->bins, rp, v->out, v->v_color, nullptr, nullptr, s.size(), grad, ws);
      const double t2 = thread_cpu_ms();
      fwd += t1 - t0; bwd += t2 - t1;
    }
  }
  const double k = 1.0 / double(state.iterations());
  const double c = std::max(1.0, contributions), e = std::max(1.0, evaluated);
  state.counters["views"] = double(views.size());
  state.counters["contrib_px"] = c / std::max(1.0, pixels);
  state.counters["evaluated_px"] = e / std::max(1.0, pixels);
  state.counters["fwd_cpu_ms"] = fwd * k;
  state.counters["bwd_cpu_ms"] = bwd * k;
  state.counters["fwd_ns_contrib"] = fwd * k * 1e6 / c;
  state.counters["bwd_ns_contrib"] = bwd * k * 1e6 / c;
}

// Registered before main runs, only when the environment names a scene.
const bool scene_registered = [] {
  const char* ply = std::getenv("ORBITFORGE_BENCH_PLY");
  const char* cameras = std::getenv("ORBITFORGE_BENCH_CAMERAS");
  if (!ply || !cameras) return false;
  const char* every = std::getenv("ORBITFORGE_BENCH_EVERY");
  const int k = every ? std::max(1, std::atoi(every)) : 24;
  benchmark::RegisterBenchmark("BM_RasterKernelsScene", BM_RasterKernelsScene, std::string(ply), std::string(cameras), k)
      ->Unit(benchmark::kMillisecond)
      ->MinTime(0.3);
  return true;
}();

// A plain exp-and-blend loop: a 16x16 tile of pixels (in native float batches)
// against a list of Gaussians (mean, conic in base-2 units, opacity, colour),
// front to back, with no rect tests, no early termination and no stores but the
// tile's final colour. Arg: the exponential (0 = xsimd::exp of the natural-log
// power, 1 = the rasterizer's exp2_nonpositive of the base-2 power).
void BM_ExpBlendLoop(benchmark::State& state) {
  using B = simd::native_batch<float>;
  constexpr int kTile = 16, kGaussians = 512;
  constexpr int kBatches = kTile * kTile / int(B::size);
  std::mt19937 rng(7);
  std::uniform_real_distribution<float> u(0.f, 1.f);
  struct G { float mx, my, a, b, c, o, r, g, bl; };
  std::vector<G> gs(kGaussians);
  const float to_base = state.range(0) ? float(-0.5 / std::log(2.0)) : -0.5f;
  for (auto& g : gs) {
    const float s = 0.02f + 0.05f * u(rng);  // inverse variances: a few-pixel footprints
    g = {kTile * u(rng), kTile * u(rng), s * to_base, 0.3f * s * (u(rng) - 0.5f) * to_base, s * to_base,
         0.05f + 0.3f * u(rng), u(rng), u(rng), u(rng)};
  }
  alignas(64) float px[kTile * kTile], py[kTile * kTile];
  for (int i = 0; i < kTile * kTile; ++i) px[i] = float(i % kTile) + 0.5f, py[i] = float(i / kTile) + 0.5f;
  alignas(64) float out[3 * kTile * kTile];
  const double t0 = thread_cpu_ms();
  for (auto _ : state) {
    for (int k = 0; k < kBatches; ++k) {
      const B x = B::load_aligned(px + k * B::size), y = B::load_aligned(py + k * B::size);
      B T(1.f), cr(0.f), cg(0.f), cb(0.f);
      for (const G& g : gs) {
        const B dx = x - B(g.mx), dy = y - B(g.my);
        const B power = simd::fma(B(g.a) * dx, dx, simd::fma(B(2.f * g.b) * dx, dy, B(g.c) * dy * dy));
        const B e = state.range(0) ? simd::exp2_nonpositive(power) : simd::exp(power);
        const B alpha = simd::min(B(0.99f), B(g.o) * e);
        const B wgt = alpha * T;
        cr = simd::fma(wgt, B(g.r), cr);
        cg = simd::fma(wgt, B(g.g), cg);
        cb = simd::fma(wgt, B(g.bl), cb);
        T = T - wgt;
      }
      cr.store_aligned(out + k * B::size);
      cg.store_aligned(out + kTile * kTile + k * B::size);
      cb.store_aligned(out + 2 * kTile * kTile + k * B::size);
    }
    benchmark::DoNotOptimize(out);
    benchmark::ClobberMemory();
  }
  const double evals = double(state.iterations()) * kTile * kTile * kGaussians;
  state.counters["ns_eval"] = (thread_cpu_ms() - t0) * 1e6 / evals;  // thread CPU time, as BM_RasterKernels
}

// The memory traffic the per-Gaussian stages cannot avoid as they are laid out,
// one thread, on the ball scene (Arg: Gaussians), without their arithmetic:
//   scene_ns_g   reading every parameter of the scene once (what projection reads;
//                degree-3 SH is 192 of its 236 bytes per Gaussian)
//   soa_ns_g     writing the projection's 15 output arrays and reading them back
//                (what packing reads)
//   gather_ns_g  copying 64-byte records into depth order through a random
//                permutation, prefetched 40 ahead (binning's permute pass)
// Their sum (floor_ns_g) set against BM_ForwardBall's gauss_ns_g says how much
// of the per-Gaussian stages is memory.
void BM_PerGaussianMemory(benchmark::State& state) {
  using B = simd::native_batch<float>;
  const std::size_t n = std::size_t(state.range(0));
  const auto& s = scene(n, true);
  constexpr std::size_t kSoaArrays = 15;
  std::vector<float> soa(kSoaArrays * n, 1.f);
  std::vector<SplatRecord<float>> packed(n), ranked(n);
  std::vector<std::int32_t> perm(n);
  for (std::size_t i = 0; i < n; ++i) perm[i] = std::int32_t(i);
  std::shuffle(perm.begin(), perm.end(), std::mt19937(99));
  auto sum_of = [](const float* p, std::size_t count) {
    B acc(0.f);
    std::size_t i = 0;
    for (; i + B::size <= count; i += B::size) acc += B::load_unaligned(p + i);
    float r = simd::hadd(acc);
    for (; i < count; ++i) r += p[i];
    return r;
  };
  double scene_ms = 0, soa_ms = 0, gather_ms = 0;
  for (auto _ : state) {
    const double t0 = thread_cpu_ms();
    float sum = 0;
    for (const auto* v : {&s.means, &s.rotations, &s.log_scales, &s.opacity_logits, &s.sh})
      sum += sum_of(v->data(), v->size());
    const double t1 = thread_cpu_ms();
    for (std::size_t a = 0; a < kSoaArrays; ++a) std::fill_n(soa.data() + a * n, n, sum);
    for (std::size_t a = 0; a < kSoaArrays; ++a) sum += sum_of(soa.data() + a * n, n);
    const double t2 = thread_cpu_ms();
    for (std::size_t r = 0; r < n; ++r) {
#if defined(__GNUC__)
      if (r + 40 < n) __builtin_prefetch(&packed[std::size_t(perm[r + 40])]);
#endif
      ranked[r] = packed[std::size_t(perm[r])];
    }
    const double t3 = thread_cpu_ms();
    benchmark::DoNotOptimize(sum);
    benchmark::DoNotOptimize(ranked.data());
    benchmark::ClobberMemory();
    scene_ms += t1 - t0;
    soa_ms += t2 - t1;
    gather_ms += t3 - t2;
  }
  const double per_g = 1e6 / double(state.iterations()) / double(n);
  state.counters["scene_ns_g"] = scene_ms * per_g;
  state.counters["soa_ns_g"] = soa_ms * per_g;
  state.counters["gather_ns_g"] = gather_ms * per_g;
  state.counters["floor_ns_g"] = (scene_ms + soa_ms + gather_ms) * per_g;
}

// Args: width, height, threads.
void BM_EmptyFrame(benchmark::State& state) {
  const int w = int(state.range(0)), h = int(state.range(1));
  GaussianScene<float> s;
  s.resize(1, 0);
  s.log_scales.assign(3, std::log(0.01f));
  s.opacity_logits = {2.f};
  s.sh = {1.5f, 0.f, 0.f};
  RenderParams<float> p;
  p.threads = int(state.range(2));
  Renderer<float> r(p);
  const Intrinsics<float> k{440.f, 440.f, 0.5f * float(w), 0.5f * float(h), w, h};
  const auto cam = Camera<float>::look_at({0.f, -3.f, 0.f}, {0.f, 0.f, 0.f}, {0.f, 0.f, 1.f}, k);
  r.render(SceneView<float>(s), cam);  // first frame allocates
  double total_ms = 0;
  for (auto _ : state) {
    const auto& out = r.render(SceneView<float>(s), cam);
    benchmark::DoNotOptimize(out.color.data.data());
    total_ms += out.frame.total_ms;
  }
  state.counters["empty_ns_px"] = total_ms * 1e6 / (double(state.iterations()) * double(w) * double(h));
}

void sizes(benchmark::internal::Benchmark* b, bool with_extents) {
  for (auto wh : {std::pair<int, int>{256, 256}, {512, 512}, {896, 512}})
    for (int n : {10000, 100000, 300000})
      for (int threads : {1, 2}) {
        if (with_extents) b->Args({wh.first, wh.second, n, threads, 1});
        else b->Args({wh.first, wh.second, n, threads});
      }
  if (with_extents) b->Args({512, 512, 100000, 1, 0});  // 3-sigma rects instead of opacity-aware ones
}

}  // namespace

BENCHMARK(BM_Forward)
    ->ArgNames({"w", "h", "n", "threads", "tight"})
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, true); })
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.3);
BENCHMARK(BM_ForwardBall)
    ->ArgNames({"w", "h", "n", "threads", "tight"})
    ->Args({512, 512, 100000, 1, 1})
    ->Args({512, 512, 100000, 2, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.3);
BENCHMARK(BM_PerGaussianMemory)->ArgName("n")->Arg(100000)->Arg(300000)->Unit(benchmark::kMillisecond)->MinTime(0.3);
BENCHMARK(BM_RasterKernels)
    ->ArgNames({"w", "h", "n"})
    ->Args({256, 256, 10000})
    ->Args({512, 512, 100000})
    ->Args({896, 512, 300000})
    ->Unit(benchmark::kMillisecond)
    ->MinTime(0.3);
BENCHMARK(BM_EmptyFrame)
    ->ArgNames({"w", "h", "threads"})
    ->Args({896, 512, 1})
    ->Args({896, 512, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.3);
BENCHMARK(BM_ExpBlendLoop)->ArgName("exp2")->Arg(0)->Arg(1)->MinTime(0.3);
BENCHMARK(BM_Backward)
    ->ArgNames({"w", "h", "n", "threads"})
    ->Apply([](benchmark::internal::Benchmark* b) { sizes(b, false); })
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.3);

BENCHMARK(BM_BackwardBall)
    ->ArgNames({"w", "h", "n", "threads"})
    ->Args({512, 512, 100000, 1})
    ->Args({512, 512, 100000, 2})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime()
    ->MinTime(0.3);

BENCHMARK_MAIN();

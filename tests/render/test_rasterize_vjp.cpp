// rasterize_vjp against central finite differences (double) of
// L = sum w_c colour + sum w_a alpha + sum w_d depth, w.r.t. every ProjectedSplats field.
#include <catch2/catch.hpp>

#include <random>

#include "orbitforge/splat/bin.hpp"
#include "orbitforge/splat/rasterize.hpp"
#include "orbitforge/splat/rasterize_vjp.hpp"
#include "render/reference_renderer.hpp"

using namespace orbitforge;
using namespace orbitforge_test;

namespace {

struct LossWeights {
  Image<double> wc, wa, wd;
};

LossWeights random_weights(int w, int h, std::uint32_t seed, bool alpha, bool depth) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1, 1);
  LossWeights lw{Image<double>(w, h, 3), Image<double>(w, h, 1), Image<double>(w, h, 1)};
  for (auto& v : lw.wc.data) v = u(rng);
  for (auto& v : lw.wa.data) v = alpha ? u(rng) : 0;
  for (auto& v : lw.wd.data) v = depth ? 0.1 * u(rng) : 0;
  return lw;
}

template <class B = simd::native_batch<double>>
// Accumulated and returned in long double: rounding the sum to double (eps * |L|)
// was the dominant round-off in the finite differences below.
long double loss(const ProjectedSplats<double>& s, int w, int h, int tile, const RasterParams<double>& p,
                 const LossWeights& lw) {
  BinWorkspace<double> bins;
  bin_splats(s, w, h, tile, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize_with<B>(bins, p, out, ws);
  long double L = 0;
  for (std::size_t i = 0; i < out.color.data.size(); ++i) L += (long double)lw.wc.data[i] * out.color.data[i];
  for (std::size_t i = 0; i < out.depth.data.size(); ++i)
    L += (long double)lw.wa.data[i] * (1 - out.transmittance.data[i]) + (long double)lw.wd.data[i] * out.depth.data[i];
  return L;
}

template <class B = simd::native_batch<double>>
RasterGradOutput<double> analytic(const ProjectedSplats<double>& s, int w, int h, int tile, const RasterParams<double>& p,
                                  const LossWeights& lw, bool alpha, bool depth) {
  BinWorkspace<double> bins;
  bin_splats(s, w, h, tile, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize_with<B>(bins, p, out, ws);
  RasterGradOutput<double> g;
  rasterize_vjp_with<B>(bins, p, out, lw.wc, alpha ? &lw.wa : nullptr, depth ? &lw.wd : nullptr, s.size(), g, ws);
  return g;
}

std::vector<double>* field(ProjectedSplats<double>& s, int f) {
  std::vector<double>* v[] = {&s.mean_x, &s.mean_y, &s.conic_a, &s.conic_b, &s.conic_c,
                              &s.opacity, &s.color_r, &s.color_g, &s.color_b, &s.depth};
  return v[f];
}
const std::vector<double>* grad_field(const ProjectedSplatsGrad<double>& g, int f) {
  const std::vector<double>* v[] = {&g.v_mean_x, &g.v_mean_y, &g.v_conic_a, &g.v_conic_b, &g.v_conic_c,
                                    &g.v_opacity, &g.v_color_r, &g.v_color_g, &g.v_color_b, &g.v_depth};
  return v[f];
}
const char* field_names[] = {"mean_x", "mean_y", "conic_a", "conic_b", "conic_c",
                             "opacity", "color_r", "color_g", "color_b", "depth"};

void check_fd_with(ProjectedSplats<double> s, int w, int h, int tile, const LossWeights& lw, bool alpha, bool depth) {
  RasterParams<double> p;
  p.background = {{0.3, 0.6, 0.1}};
  p.threads = 2;
  const auto g = analytic(s, w, h, tile, p, lw, alpha, depth);
  double worst = 0;
  int checked = 0;
  // Steps per field: small enough that no pair crosses a threshold (the scene is
  // kept 1e-3 away from them), large enough to beat round-off; colour and depth
  // enter linearly.
  const double steps[] = {1e-5, 1e-5, 1e-7, 1e-7, 1e-7, 1e-6, 1e-4, 1e-4, 1e-4, 1e-4};
  for (int f = 0; f < 10; ++f) {
    // Relative error, floored at 1% of the field's largest gradient so that
    // round-off on near-zero entries does not count as error.
    double scale = 0;
    for (double x : *grad_field(g.splats, f)) scale = std::max(scale, std::abs(x));
    for (std::size_t i = 0; i < s.size(); ++i) {
      if (s.radius[i] <= 0) continue;
      std::vector<double>& v = *field(s, f);
      const double x0 = v[i];
      const double hstep = steps[f];
      v[i] = x0 + hstep;
      const long double lp = loss(s, w, h, tile, p, lw);
      v[i] = x0 - hstep;
      const long double lm = loss(s, w, h, tile, p, lw);
      v[i] = x0;
      const double fd = double((lp - lm) / (2 * hstep));
      const double an = (*grad_field(g.splats, f))[i];
      const double err = std::abs(fd - an) / std::max({std::abs(fd), 1e-2 * scale, 1e-12});
      INFO(field_names[f] << " of Gaussian " << i << ": analytic " << an << " fd " << fd);
      CHECK(err < 1e-6);
      worst = std::max(worst, err);
      ++checked;
    }
  }
  // Background colour.
  for (int c = 0; c < 3; ++c) {
    RasterParams<double> q = p;
    q.background[std::size_t(c)] += 1e-6;
    const double lp = loss(s, w, h, tile, q, lw);
    q.background[std::size_t(c)] -= 2e-6;
    const double lm = loss(s, w, h, tile, q, lw);
    CHECK(std::abs((lp - lm) / 2e-6 - g.v_background[std::size_t(c)]) < 1e-6 * std::max(1.0, std::abs(g.v_background[std::size_t(c)])));
  }
  CHECK(checked > 0);
  WARN("worst relative FD error " << worst << " over " << checked << " entries");
}

void check_fd(const ProjectedSplats<double>& s, int w, int h, int tile, bool alpha, bool depth, std::uint32_t seed) {
  check_fd_with(s, w, h, tile, random_weights(w, h, seed, alpha, depth), alpha, depth);
}

}  // namespace

TEST_CASE("rasterize_vjp matches finite differences", "[render][grad]") {
  RandomSplatOptions o;
  o.opacity_max = 0.9;  // stay off the 0.99 clamp
  o.sigma_min = 1.5;
  o.sigma_max = 8;
  auto s = random_splats<double>(40, 26, 21, 101, o);
  clear_thresholds(s, 26, 21, 1e-3);
  REQUIRE(threshold_violators(s, 26, 21, 1e-3).empty());
  SECTION("colour only, 8 px tiles") { check_fd(s, 26, 21, 8, false, false, 1); }
  SECTION("colour + alpha + depth, 16 px tiles") { check_fd(s, 26, 21, 16, true, true, 2); }
}

TEST_CASE("rasterize_vjp with early-stopped pixels matches finite differences", "[render][grad]") {
  RandomSplatOptions o;
  o.opacity_min = 0.6;
  o.opacity_max = 0.95;
  o.sigma_min = 4;
  o.sigma_max = 10;
  auto s = random_splats<double>(60, 20, 18, 202, o);
  // Keep raw opacity exp(power) below 0.99 everywhere: opacity <= 0.95.
  clear_thresholds(s, 20, 18, 1e-3);
  REQUIRE(threshold_violators(s, 20, 18, 1e-3).empty());
  BinWorkspace<double> bins;
  bin_splats(s, 20, 18, 16, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize(bins, RasterParams<double>{}, out, ws);
  std::size_t stopped = 0;
  for (double T : out.transmittance.data) stopped += T < 2e-4;
  REQUIRE(stopped > 10);  // the scene exercises the 1e-4 stop
  check_fd(s, 20, 18, 16, true, true, 3);
}

TEST_CASE("rasterize_vjp skips entries past a tile's last replay", "[render][grad]") {
  // Opaque Gaussians stop some tiles early, so a Gaussian can be listed past
  // every replay in one tile (its slot there is never written) and replayed in
  // another: the per-Gaussian sum must skip only the former.
  RandomSplatOptions o;
  o.opacity_min = 0.6;
  o.opacity_max = 0.95;
  o.sigma_min = 2;
  o.sigma_max = 7;
  const int W = 40, H = 24, tile = 8;
  auto s = random_splats<double>(160, W, H, 404, o);
  clear_thresholds(s, W, H, 1e-3);
  REQUIRE(threshold_violators(s, W, H, 1e-3).empty());
  BinWorkspace<double> bins;
  bin_splats(s, W, H, tile, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize(bins, RasterParams<double>{}, out, ws);
  // Some Gaussian is listed past every replay in one tile (its slot there is
  // never written) and replayed in another: the sum must skip only the former.
  const TileGrid& g = bins.grid;
  std::vector<int> tile_max(std::size_t(g.tile_count()), 0);
  for (int y = 0; y < g.height; ++y)
    for (int x = 0; x < g.width; ++x) {
      const std::size_t t = std::size_t((y / g.tile_size) * g.tiles_x + x / g.tile_size);
      tile_max[t] = std::max(tile_max[t], out.replay[std::size_t(y) * std::size_t(g.width) + std::size_t(x)]);
    }
  std::vector<int> live(bins.visible(), 0), dead(bins.visible(), 0);
  for (int t = 0; t < g.tile_count(); ++t)
    for (std::uint32_t e = bins.tile_offsets[std::size_t(t)]; e < bins.tile_offsets[std::size_t(t) + 1]; ++e)
      ++(int(e - bins.tile_offsets[std::size_t(t)]) < tile_max[std::size_t(t)] ? live : dead)[std::size_t(bins.tile_ranks[e])];
  int mixed = 0;
  for (std::size_t r = 0; r < live.size(); ++r) mixed += live[r] > 0 && dead[r] > 0;
  REQUIRE(mixed > 0);
  // A workspace reused from another frame holds that frame's slots (here made
  // conspicuous): none may leak into the sums.
  const LossWeights lw = random_weights(W, H, 4, true, true);
  RasterGradOutput<double> fresh, reused;
  RasterWorkspace<double> ws_fresh;
  rasterize_vjp(bins, RasterParams<double>{}, out, lw.wc, &lw.wa, &lw.wd, s.size(), fresh, ws_fresh);
  REQUIRE(bins.slots() > bins.pairs());  // box tiles that are not listed: their slots must not leak either
  ws.pair_grad.assign(bins.slots() * 10, 1e6);
  rasterize_vjp(bins, RasterParams<double>{}, out, lw.wc, &lw.wa, &lw.wd, s.size(), reused, ws);
  for (int f = 0; f < 10; ++f) CHECK(*grad_field(fresh.splats, f) == *grad_field(reused.splats, f));
  check_fd(s, W, H, tile, true, true, 4);
}

TEST_CASE("gradients are zero where the forward clamps or skips", "[render][grad]") {
  ProjectedSplats<double> s;
  s.resize(3);
  // 0: opacity 1 at the centre -> alpha clamped at 0.99 near the mean.
  // 1: opacity 0 -> always skipped.  2: culled (radius 0).
  for (std::size_t i = 0; i < 3; ++i) {
    s.mean_x[i] = 8; s.mean_y[i] = 8; s.conic_a[i] = 1e-4; s.conic_b[i] = 0; s.conic_c[i] = 1e-4;
    s.color_r[i] = 0.5; s.color_g[i] = 0.5; s.color_b[i] = 0.5; s.depth[i] = 1 + double(i);
    set_rect_from_conic(s, i, 16, 16);
  }
  s.opacity[0] = 1; s.opacity[1] = 0; s.opacity[2] = 0.5;
  s.radius[2] = 0;
  const LossWeights lw = random_weights(16, 16, 7, true, true);
  RasterParams<double> p;
  const auto g = analytic(s, 16, 16, 16, p, lw, true, true);
  // Every pixel of Gaussian 0 is clamped (opacity exp(power) >= 0.99 over the image).
  CHECK(g.splats.v_opacity[0] == 0);
  CHECK(g.splats.v_conic_a[0] == 0);
  CHECK(g.splats.v_mean_x[0] == 0);
  CHECK(g.splats.v_color_r[0] != 0);  // colour still flows (w = 0.99)
  for (int f = 0; f < 10; ++f) {
    CHECK((*grad_field(g.splats, f))[1] == 0);
    CHECK((*grad_field(g.splats, f))[2] == 0);
  }
}

namespace {

// The loss at pixel (x, y) only, and its gradient.
RasterGradOutput<double> one_pixel_gradient(const ProjectedSplats<double>& s, int w, int h, int x, int y) {
  LossWeights lw{Image<double>(w, h, 3), Image<double>(w, h, 1), Image<double>(w, h, 1)};
  lw.wc(x, y, 0) = 1;
  lw.wc(x, y, 1) = -0.5;
  lw.wc(x, y, 2) = 0.25;
  lw.wa(x, y) = 0.7;
  lw.wd(x, y) = 0.1;
  return analytic(s, w, h, 8, RasterParams<double>{}, lw, true, true);
}

bool all_zero(const RasterGradOutput<double>& g, std::size_t i) {
  for (int f = 0; f < 10; ++f)
    if ((*grad_field(g.splats, f))[i] != 0) return false;
  return true;
}

}  // namespace

TEST_CASE("backward agrees with the forward at the 1/255 skip, the 0.99 clamp and the 1e-4 stop", "[render][grad]") {
  const int W = 24, H = 12;
  const double a_min = 1.0 / 255, margin = 2e-3;  // relative distance of the aimed pairs from 1/255
  ProjectedSplats<double> s;
  s.resize(10);
  auto put = [&](std::size_t i, double mx, double my, double a, double b, double c, double o, double z) {
    s.mean_x[i] = mx; s.mean_y[i] = my;
    s.conic_a[i] = a; s.conic_b[i] = b; s.conic_c[i] = c;
    s.opacity[i] = o; s.depth[i] = z;
    s.color_r[i] = 0.2 + 0.1 * double(i); s.color_g[i] = 0.9 - 0.1 * double(i); s.color_b[i] = 0.5;
    set_rect_from_conic(s, i, W, H);
  };
  // 0: mean on a pixel corner, alpha at its four nearest pixel centres
  // (d = (0.5, 0.5), power -0.25) just below 1/255: skipped everywhere.
  put(0, 2.0, 2.0, 1, 0, 1, a_min * (1 - margin) / std::exp(-0.25), 1.0);
  // 1: mean on the centre of pixel (8, 4); 255 o = 2^6 / ln 2, where the backward's
  // cheap lower bound of log2(1 / (255 o)) (bin.hpp alpha_power_floor) is least
  // tight. Pixels (5, 4), (11, 4) (dx = 3) just above 1/255, (8, 1), (8, 7)
  // (dy = 3) just below.
  const double o1 = 64 / std::log(2.0) / 255;
  put(1, 8.5, 4.5, 2 * std::log(255 * o1 / (1 + margin)) / 9, 0, 2 * std::log(255 * o1 / (1 - margin)) / 9, o1, 1.1);
  s.rect_x0[1] = 3; s.rect_x1[1] = 14; s.rect_y0[1] = 0; s.rect_y1[1] = 9;  // room around the 3-sigma square
  // 2: opaque, raw alpha ~0.998 at pixel (19, 3): clamped there, not at (20, 3).
  put(2, 19.55, 3.45, 0.25, 0.05, 0.3, 1.0, 1.5);
  // 3..7: a stack with alpha ~0.967 at pixel (4, 8): T = 0.033, 1.1e-3, then
  // 3.6e-5 < 1e-4, so 5 stops the pixel and 5..7 are not blended there.
  for (std::size_t i = 3; i < 8; ++i) put(i, 4.6, 8.4, 0.3, 0.02, 0.35, 0.97, 2 + double(i));
  // 8: 255 o = 1 / ln 2, just above 1/255 at pixel (14, 9) only (dx = 0.3; every
  // other pixel far below), so the backward's chunk pre-test must let it through.
  const double o8 = 1 / std::log(2.0) / 255;
  put(8, 14.8, 9.5, 2 * std::log(255 * o8 / (1 + margin)) / 0.09, 0, 8.1, o8, 1.2);
  // 9: a backdrop behind everything: every pixel blends something after the
  // aimed pairs, so the backward replays past them.
  put(9, 12, 6, 0.006, 0, 0.01, 0.5, 30);
  // No pair within 1e-3 of a threshold (the aimed ones sit 2e-3 away), so the
  // finite-difference steps (relative changes <= 3e-4) cross none.
  REQUIRE(threshold_violators(s, W, H, 1e-3).empty());

  BinWorkspace<double> bins;
  bin_splats(s, W, H, 8, bins);
  RasterOutput<double> out;
  RasterWorkspace<double> ws;
  rasterize(bins, RasterParams<double>{}, out, ws);
  CHECK(out.count(4, 8) == 2);
  CHECK(out.count(11, 4) == 2);  // 1 and the backdrop
  CHECK(out.count(14, 9) == 2);  // 8 and the backdrop

  // Skipped below 1/255: exactly zero.
  CHECK(all_zero(one_pixel_gradient(s, W, H, 2, 2), 0));
  CHECK(all_zero(one_pixel_gradient(s, W, H, 1, 1), 0));
  for (const auto& xy : {std::array<int, 2>{{8, 1}}, std::array<int, 2>{{8, 7}}}) {
    INFO("pixel " << xy[0] << ", " << xy[1]);
    CHECK(all_zero(one_pixel_gradient(s, W, H, xy[0], xy[1]), 1));
  }
  // Blended just above 1/255: Gaussian 1 gets a gradient (dy = 0 and b = 0 there,
  // so mean_y, conic_b and conic_c get exactly nothing).
  for (const auto& xy : {std::array<int, 2>{{5, 4}}, std::array<int, 2>{{11, 4}}}) {
    INFO("pixel " << xy[0] << ", " << xy[1]);
    const auto g = one_pixel_gradient(s, W, H, xy[0], xy[1]);
    for (int f : {0, 2, 5, 6, 7, 8, 9}) CHECK((*grad_field(g.splats, f))[1] != 0);
  }
  {
    const auto g = one_pixel_gradient(s, W, H, 14, 9);
    for (int f : {0, 2, 5, 6, 7, 8, 9}) CHECK((*grad_field(g.splats, f))[8] != 0);
    CHECK(all_zero(one_pixel_gradient(s, W, H, 15, 9), 8));
  }
  {
    // Clamped at 0.99: colour and depth get w, opacity, conic and mean nothing.
    const auto g = one_pixel_gradient(s, W, H, 19, 3);
    for (int f : {0, 1, 2, 3, 4, 5}) CHECK((*grad_field(g.splats, f))[2] == 0);
    for (int f : {6, 7, 8, 9}) CHECK((*grad_field(g.splats, f))[2] != 0);
    const auto g2 = one_pixel_gradient(s, W, H, 20, 3);
    for (int f = 0; f < 10; ++f) CHECK((*grad_field(g2.splats, f))[2] != 0);
  }
  {
    // The 1e-4 stop: 3 and 4 blended, 5..7 (the stopping one and those behind) not.
    const auto g = one_pixel_gradient(s, W, H, 4, 8);
    for (std::size_t i : {3, 4}) {
      INFO("Gaussian " << i);
      for (int f : {0, 5, 6, 9}) CHECK((*grad_field(g.splats, f))[i] != 0);
    }
    for (std::size_t i : {5, 6, 7}) {
      INFO("Gaussian " << i);
      CHECK(all_zero(g, i));
    }
  }
  // Whole image, and each aimed pixel alone: the gradients are those of the forward.
  check_fd(s, W, H, 8, true, true, 5);
  for (const auto& xy : {std::array<int, 2>{{11, 4}}, std::array<int, 2>{{8, 7}}, std::array<int, 2>{{14, 9}},
                         std::array<int, 2>{{19, 3}}, std::array<int, 2>{{4, 8}}}) {
    INFO("pixel " << xy[0] << ", " << xy[1]);
    LossWeights lw{Image<double>(W, H, 3), Image<double>(W, H, 1), Image<double>(W, H, 1)};
    lw.wc(xy[0], xy[1], 0) = 1;
    lw.wa(xy[0], xy[1]) = 0.7;
    lw.wd(xy[0], xy[1]) = 0.1;
    check_fd_with(s, W, H, 8, lw, true, true);
  }
}

TEST_CASE("backward: scalar kernel, SIMD kernel and thread counts agree", "[render][grad]") {
  auto s = random_splats<double>(300, 45, 38, 303);
  const LossWeights lw = random_weights(45, 38, 9, true, true);
  RasterParams<double> p;
  p.threads = 1;
  const auto a = analytic(s, 45, 38, 16, p, lw, true, true);
  const auto b = analytic<simd::scalar_batch<double>>(s, 45, 38, 16, p, lw, true, true);
  p.threads = 2;
  const auto c = analytic(s, 45, 38, 16, p, lw, true, true);
  for (int f = 0; f < 10; ++f)
    for (std::size_t i = 0; i < s.size(); ++i) {
      const double x = (*grad_field(a.splats, f))[i];
      CHECK(std::abs(x - (*grad_field(b.splats, f))[i]) <= 1e-9 * std::max(1.0, std::abs(x)));
      CHECK(x == (*grad_field(c.splats, f))[i]);  // deterministic whatever the thread count
    }
}

TEST_CASE("backward without the background gradient: the same splat gradients, a zero background's", "[render][grad]") {
  // Few splats, so that some tiles are empty: both tile paths skip the sums.
  RandomSplatOptions o;
  o.sigma_max = 3;
  auto s = random_splats<double>(40, 100, 84, 404, o);
  BinWorkspace<double> bins;
  bin_splats(s, 100, 84, 16, bins);
  int empty = 0;
  for (int t = 0; t < bins.grid.tile_count(); ++t) empty += bins.tile_offsets[std::size_t(t) + 1] == bins.tile_offsets[std::size_t(t)];
  REQUIRE(empty > 0);
  REQUIRE(empty < bins.grid.tile_count());
  const LossWeights lw = random_weights(100, 84, 11, true, true);
  RasterParams<double> p;
  p.background = {{0.3, 0.6, 0.9}};
  for (int threads : {1, 2}) {
    p.threads = threads;
    p.background_gradient = true;
    const auto with = analytic(s, 100, 84, 16, p, lw, true, true);
    p.background_gradient = false;
    const auto without = analytic(s, 100, 84, 16, p, lw, true, true);
    for (int c = 0; c < 3; ++c) {
      CHECK(with.v_background[std::size_t(c)] != 0);
      CHECK(without.v_background[std::size_t(c)] == 0);
    }
    for (int f = 0; f < 10; ++f)
      for (std::size_t i = 0; i < s.size(); ++i) CHECK((*grad_field(with.splats, f))[i] == (*grad_field(without.splats, f))[i]);
  }
}

TEST_CASE("backward in float agrees with double", "[render][grad]") {
  RandomSplatOptions o;
  o.opacity_max = 0.9;
  auto sd = random_splats<double>(200, 40, 30, 404, o);
  clear_thresholds(sd, 40, 30, 1e-3);
  ProjectedSplats<float> sf;
  sf.resize(sd.size());
  for (std::size_t i = 0; i < sd.size(); ++i) {
    sf.mean_x[i] = float(sd.mean_x[i]); sf.mean_y[i] = float(sd.mean_y[i]);
    sf.conic_a[i] = float(sd.conic_a[i]); sf.conic_b[i] = float(sd.conic_b[i]); sf.conic_c[i] = float(sd.conic_c[i]);
    sf.opacity[i] = float(sd.opacity[i]);
    sf.color_r[i] = float(sd.color_r[i]); sf.color_g[i] = float(sd.color_g[i]); sf.color_b[i] = float(sd.color_b[i]);
    sf.depth[i] = float(sd.depth[i]);
    sf.radius[i] = sd.radius[i];
    sf.rect_x0[i] = sd.rect_x0[i]; sf.rect_x1[i] = sd.rect_x1[i]; sf.rect_y0[i] = sd.rect_y0[i]; sf.rect_y1[i] = sd.rect_y1[i];
  }
  clear_thresholds(sf, 40, 30, 1e-3);
  for (std::size_t i = 0; i < sd.size(); ++i) sd.opacity[i] = double(sf.opacity[i]);
  const LossWeights lw = random_weights(40, 30, 5, false, false);
  Image<float> wcf(40, 30, 3);
  for (std::size_t i = 0; i < wcf.data.size(); ++i) wcf.data[i] = float(lw.wc.data[i]);
  RasterParams<double> pd;
  const auto gd = analytic(sd, 40, 30, 16, pd, lw, false, false);
  BinWorkspace<float> bins;
  bin_splats(sf, 40, 30, 16, bins);
  RasterOutput<float> out;
  RasterWorkspace<float> ws;
  RasterParams<float> pf;
  rasterize(bins, pf, out, ws);
  RasterGradOutput<float> gf;
  rasterize_vjp(bins, pf, out, wcf, nullptr, nullptr, sf.size(), gf, ws);
  for (std::size_t i = 0; i < sd.size(); ++i) {
    CHECK(gf.splats.v_opacity[i] == Approx(gd.splats.v_opacity[i]).margin(1e-3).epsilon(1e-3));
    CHECK(gf.splats.v_mean_x[i] == Approx(gd.splats.v_mean_x[i]).margin(1e-3).epsilon(1e-3));
    CHECK(gf.splats.v_color_g[i] == Approx(gd.splats.v_color_g[i]).margin(1e-4).epsilon(1e-4));
  }
}

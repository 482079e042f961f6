// Binning + forward rasterization against the plain per-pixel reference.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <random>

#include "orbitforge/splat/bin.hpp"
#include "orbitforge/splat/rasterize.hpp"
#include "orbitforge/splat/rasterize_vjp.hpp"
#include "render/reference_renderer.hpp"

using namespace orbitforge;
using namespace orbitforge_test;

namespace {

template <class S, class B = simd::native_batch<S>>
RasterOutput<S> render_splats(const ProjectedSplats<S>& s, int w, int h, int tile = 16, int threads = 1,
                              std::array<S, 3> bg = {{0, 0, 0}}) {
  BinWorkspace<S> bins;
  bin_splats(s, w, h, tile, bins);
  RasterParams<S> p;
  p.background = bg;
  p.threads = threads;
  RasterOutput<S> out;
  RasterWorkspace<S> ws;
  rasterize_with<B>(bins, p, out, ws);
  return out;
}

template <class S>
void check_against_reference(const ProjectedSplats<S>& s, int w, int h, std::array<S, 3> bg, double tolerance,
                             int tile = 16, int threads = 1) {
  const auto ref = reference_rasterize(s, w, h, bg);
  const auto out = render_splats(s, w, h, tile, threads, bg);
  CHECK(max_abs_diff(out.color, ref.color) <= tolerance);
  CHECK(max_abs_diff(out.transmittance, ref.transmittance) <= tolerance);
  // Depth is a sum of w z with z up to 20: compare relative to that scale.
  CHECK(max_abs_diff(out.depth, ref.depth) <= tolerance * 20);
  CHECK(max_abs_diff(out.count, ref.count) == 0);
  std::uint64_t n = 0;
  for (auto c : ref.count.data) n += std::uint64_t(c);
  CHECK(out.stats.contributions == n);
  CHECK(out.stats.pairs_evaluated >= out.stats.contributions);
}

}  // namespace

TEMPLATE_TEST_CASE("rasterize matches the reference in the same precision", "[render]", float, double) {
  using S = TestType;
  const std::array<S, 3> bg{{S(0.2), S(0.5), S(0.9)}};
  struct Case { int w, h, n; std::uint32_t seed; };
  for (const Case c : {Case{64, 48, 300, 1}, Case{17, 9, 40, 2}, Case{1, 1, 20, 3}, Case{1000, 3, 200, 4},
                       Case{3, 200, 100, 5}, Case{33, 31, 2000, 6}}) {
    INFO("case " << c.w << "x" << c.h << " n=" << c.n);
    auto s = random_splats<S>(std::size_t(c.n), c.w, c.h, c.seed);
    check_against_reference(s, c.w, c.h, bg, same_precision_tol<S>());
  }
}

TEST_CASE("float rasterizer matches the double reference away from thresholds", "[render]") {
  auto sd = random_splats<double>(400, 70, 50, 11);
  clear_thresholds(sd, 70, 50, 1e-3);
  REQUIRE(threshold_violators(sd, 70, 50, 1e-3).empty());
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
  // Re-check in float inputs (rounding the inputs moves pairs slightly).
  clear_thresholds(sf, 70, 50, 1e-3);
  for (std::size_t i = 0; i < sd.size(); ++i) sd.opacity[i] = double(sf.opacity[i]);
  const auto ref = reference_rasterize(sd, 70, 50, std::array<double, 3>{{0.1, 0.2, 0.3}});
  const auto out = render_splats(sf, 70, 50, 16, 1, std::array<float, 3>{{0.1f, 0.2f, 0.3f}});
  double m = 0;
  for (std::size_t i = 0; i < ref.color.data.size(); ++i) m = std::max(m, std::abs(ref.color.data[i] - double(out.color.data[i])));
  CHECK(m <= 1e-5);
  for (std::size_t i = 0; i < ref.count.data.size(); ++i) REQUIRE(ref.count.data[i] == out.count.data[i]);
}

TEMPLATE_TEST_CASE("image does not depend on tile size or thread count", "[render]", float, double) {
  using S = TestType;
  auto s = random_splats<S>(800, 90, 70, 21);
  const std::array<S, 3> bg{{S(0.3), S(0.3), S(0.3)}};
  const auto base = render_splats(s, 90, 70, 16, 1, bg);
  for (int tile : {1, 5, 8, 16, 32, 64})
    for (int threads : {1, 2, 3}) {
      INFO("tile " << tile << " threads " << threads);
      const auto o = render_splats(s, 90, 70, tile, threads, bg);
      // Identical arithmetic per pixel whatever the tiling: bitwise equal.
      CHECK(max_abs_diff(o.color, base.color) == 0);
      CHECK(max_abs_diff(o.depth, base.depth) == 0);
      CHECK(max_abs_diff(o.count, base.count) == 0);
      CHECK(o.stats.contributions == base.stats.contributions);
    }
}

TEMPLATE_TEST_CASE("scalar kernel matches the SIMD kernel", "[render]", float, double) {
  using S = TestType;
  auto s = random_splats<S>(500, 45, 37, 31);
  const std::array<S, 3> bg{{S(0.1), S(0), S(1)}};
  const auto v = render_splats<S>(s, 45, 37, 16, 2, bg);
  const auto c = render_splats<S, simd::scalar_batch<S>>(s, 45, 37, 16, 2, bg);
  CHECK(max_abs_diff(v.color, c.color) <= same_precision_tol<S>());
  CHECK(max_abs_diff(v.count, c.count) == 0);
}

TEMPLATE_TEST_CASE("hard cases", "[render]", float, double) {
  using S = TestType;
  const std::array<S, 3> bg{{S(0.25), S(0.5), S(0.75)}};
  SECTION("empty scene shows the background") {
    ProjectedSplats<S> s;
    const auto out = render_splats(s, 20, 10, 16, 1, bg);
    for (int y = 0; y < 10; ++y)
      for (int x = 0; x < 20; ++x) {
        CHECK(out.color(x, y, 0) == bg[0]);
        CHECK(out.color(x, y, 2) == bg[2]);
        CHECK(out.transmittance(x, y) == S(1));
        CHECK(out.count(x, y) == 0);
      }
  }
  SECTION("a Gaussian covering the whole image, opacity 1: alpha clamps at 0.99") {
    ProjectedSplats<S> s;
    s.resize(1);
    s.mean_x[0] = 20; s.mean_y[0] = 10;
    s.conic_a[0] = S(1e-6); s.conic_b[0] = 0; s.conic_c[0] = S(1e-6);
    s.opacity[0] = 1; s.color_r[0] = 1; s.color_g[0] = 0; s.color_b[0] = 0; s.depth[0] = 3;
    set_rect_from_conic(s, 0, 40, 20);
    REQUIRE(s.rect_x0[0] == 0);
    REQUIRE(s.rect_x1[0] == 39);
    const auto out = render_splats(s, 40, 20, 16, 2, bg);
    for (int y = 0; y < 20; ++y)
      for (int x = 0; x < 40; ++x) {
        CHECK(out.transmittance(x, y) == Approx(0.01).epsilon(1e-5));
        CHECK(out.color(x, y, 0) == Approx(0.99 + 0.01 * 0.25).epsilon(1e-5));
      }
    check_against_reference(s, 40, 20, bg, same_precision_tol<S>());
  }
  SECTION("opacity 0 and Gaussians far below one pixel") {
    auto s = random_splats<S>(200, 30, 30, 41);
    for (std::size_t i = 0; i < s.size(); ++i) {
      if (i % 2 == 0) s.opacity[i] = 0;
      else { s.conic_a[i] = S(1e6); s.conic_b[i] = 0; s.conic_c[i] = S(1e6); set_rect_from_conic(s, i, 30, 30); }
    }
    check_against_reference(s, 30, 30, bg, same_precision_tol<S>());
  }
  SECTION("flattened Gaussians (huge conic along one axis)") {
    auto s = random_splats<S>(150, 40, 30, 51);
    for (std::size_t i = 0; i < s.size(); ++i) { s.conic_a[i] = S(400); s.conic_b[i] = 0; }
    check_against_reference(s, 40, 30, bg, same_precision_tol<S>());
  }
  SECTION("dense opaque stack stops early (1e-4 rule)") {
    RandomSplatOptions o;
    o.opacity_min = 0.9;
    o.sigma_min = 20; o.sigma_max = 40;
    auto s = random_splats<S>(300, 32, 32, 61, o);
    check_against_reference(s, 32, 32, bg, same_precision_tol<S>());
    const auto out = render_splats(s, 32, 32);
    CHECK(out.stats.pairs_evaluated < 300u * 32u * 32u / 2u);
  }
  SECTION("equal depths are blended in index order") {
    ProjectedSplats<S> s;
    s.resize(2);
    for (std::size_t i = 0; i < 2; ++i) {
      s.mean_x[i] = 4; s.mean_y[i] = 4; s.conic_a[i] = S(0.1); s.conic_b[i] = 0; s.conic_c[i] = S(0.1);
      s.opacity[i] = S(0.5); s.depth[i] = 2;
      set_rect_from_conic(s, i, 8, 8);
    }
    s.color_r[0] = 1; s.color_g[0] = 0; s.color_b[0] = 0;
    s.color_r[1] = 0; s.color_g[1] = 1; s.color_b[1] = 0;
    const auto out = render_splats(s, 8, 8);
    CHECK(out.color(3, 3, 0) > out.color(3, 3, 1));  // Gaussian 0 is in front
    check_against_reference(s, 8, 8, bg, same_precision_tol<S>());
  }
}

TEST_CASE("bin_splats rejects malformed input", "[render]") {
  BinWorkspace<float> bins;
  ProjectedSplats<float> s = random_splats<float>(10, 16, 16, 71);
  s.rect_x1[3] = 40;
  s.radius[3] = 5;
  CHECK_THROWS_AS(bin_splats(s, 16, 16, 16, bins), Error);
  s = random_splats<float>(10, 16, 16, 71);
  s.depth.pop_back();
  CHECK_THROWS_AS(bin_splats(s, 16, 16, 16, bins), Error);
  s = random_splats<float>(10, 16, 16, 71);
  for (std::size_t i = 0; i < s.size(); ++i)
    if (s.radius[i] > 0) { s.mean_x[i] = std::nanf(""); break; }
  CHECK_THROWS_AS(bin_splats(s, 16, 16, 16, bins), Error);
  CHECK_THROWS_AS(bin_splats(s, 0, 16, 16, bins), Error);
}

TEST_CASE("binning on several threads gives the same lists as on one", "[render]") {
  // Enough visible Gaussians for several rank chunks (one per 4096).
  const int w = 96, h = 80;
  const auto s = random_splats<float>(20000, w, h, 11);
  BinWorkspace<float> one, many;
  bin_splats(s, w, h, 16, one, 1);
  for (int threads : {2, 3, 5}) {
    INFO("threads " << threads);
    bin_splats(s, w, h, 16, many, threads);
    REQUIRE(many.visible() == one.visible());
    REQUIRE(many.visible() > 3 * 4096);
    CHECK(many.order == one.order);
    CHECK(many.tile_offsets == one.tile_offsets);
    CHECK(many.tile_ranks == one.tile_ranks);
    CHECK(many.rank_offsets == one.rank_offsets);
    CHECK(many.rank_boxes == one.rank_boxes);
    // The two layouts index the same entries: the slots of the tile lists'
    // entries are a permutation of [0, pairs).
    std::vector<char> seen(many.pairs(), 0);
    const TileGrid& g = many.grid;
    for (int t = 0; t < g.tile_count(); ++t)
      for (std::uint32_t e = many.tile_offsets[std::size_t(t)]; e < many.tile_offsets[std::size_t(t) + 1]; ++e) {
        const std::uint32_t slot = many.entry_slot(t % g.tiles_x, t / g.tiles_x, std::size_t(many.tile_ranks[e]));
        REQUIRE(slot < many.pairs());
        seen[slot] = 1;
      }
    CHECK(std::count(seen.begin(), seen.end(), 1) == std::ptrdiff_t(many.pairs()));
  }
}

TEST_CASE("the tile lists and their rank-major slots are those of a plain enumeration", "[render]") {
  // Every tile lists, front to back, the ranks whose tile box covers it; a
  // rank's slots number its box's tiles in row-major order, ranks in order.
  const int w = 200, h = 72;  // a partial last column and row of tiles
  const auto s = random_splats<float>(9000, w, h, 5);
  for (int threads : {1, 2}) {
    INFO("threads " << threads);
    BinWorkspace<float> bins;
    bin_splats(s, w, h, 16, bins, threads);
    const TileGrid& g = bins.grid;
    REQUIRE(bins.visible() > 4096);  // more than one rank chunk on two threads
    std::vector<std::vector<std::int32_t>> ranks(std::size_t(g.tile_count()));
    std::vector<std::vector<std::uint32_t>> slots(std::size_t(g.tile_count()));
    std::uint32_t k = 0;
    for (std::size_t r = 0; r < bins.visible(); ++r) {
      const auto& b = bins.rank_boxes[r];
      const std::size_t i = std::size_t(b[4]);
      REQUIRE(bins.order[r] == b[4]);
      CHECK(b[0] == s.rect_x0[i] / 16);
      CHECK(b[1] == s.rect_y0[i] / 16);
      CHECK(b[2] == s.rect_x1[i] / 16);
      CHECK(b[3] == s.rect_y1[i] / 16);
      if (r > 0) CHECK(bins.records[r - 1].depth <= bins.records[r].depth);
      CHECK(bins.rank_offsets[r] == k);
      for (int ty = b[1]; ty <= b[3]; ++ty)
        for (int tx = b[0]; tx <= b[2]; ++tx) {
          ranks[std::size_t(ty * g.tiles_x + tx)].push_back(std::int32_t(r));
          slots[std::size_t(ty * g.tiles_x + tx)].push_back(k++);
        }
    }
    CHECK(bins.rank_offsets[bins.visible()] == k);
    REQUIRE(bins.pairs() == k);
    for (int t = 0; t < g.tile_count(); ++t) {
      const std::uint32_t b = bins.tile_offsets[std::size_t(t)], e = bins.tile_offsets[std::size_t(t) + 1];
      REQUIRE(e - b == ranks[std::size_t(t)].size());
      CHECK(std::equal(bins.tile_ranks.begin() + b, bins.tile_ranks.begin() + e, ranks[std::size_t(t)].begin()));
      for (std::uint32_t x = b; x < e; ++x)
        CHECK(bins.entry_slot(t % g.tiles_x, t / g.tiles_x, std::size_t(bins.tile_ranks[x])) == slots[std::size_t(t)][x - b]);
    }
  }
}

TEST_CASE("the depth radix sort is the stable sort", "[render]") {
  // Many equal keys (ties keep index order), negative and
  // positive depths, and keys that differ only in their high bytes.
  std::mt19937 rng(21);
  std::uniform_int_distribution<int> pick(0, 5000);
  const std::size_t n = 70000;
  std::vector<std::uint32_t> keys0(n);
  for (std::size_t i = 0; i < n; ++i) {
    const float depth = (pick(rng) % 7 == 0 ? -1.0f : 1.0f) * float(pick(rng)) * (i % 3 == 0 ? 1e3f : 1e-2f);
    keys0[i] = detail::sortable_key<std::uint32_t>(depth);
  }
  std::vector<std::int32_t> expected(n);
  for (std::size_t i = 0; i < n; ++i) expected[i] = std::int32_t(i);
  std::stable_sort(expected.begin(), expected.end(), [&](std::int32_t a, std::int32_t b) {
    return keys0[std::size_t(a)] < keys0[std::size_t(b)];
  });
  std::vector<std::uint32_t> keys = keys0, keys_tmp;
  std::vector<std::int32_t> idx(n), idx_tmp;
  for (std::size_t i = 0; i < n; ++i) idx[i] = std::int32_t(i);
  detail::radix_sort_stable(keys, idx, keys_tmp, idx_tmp);
  CHECK(idx == expected);
  CHECK(std::is_sorted(keys.begin(), keys.end()));

  // The threaded sort gives the same order for any thread count, including
  // counts that leave an odd run over in a merge round (3) and inputs too short
  // to split (the first 100 keys).
  for (const std::size_t len : {std::size_t(100), n}) {
    std::vector<std::int32_t> want(len);
    for (std::size_t i = 0; i < len; ++i) want[i] = std::int32_t(i);
    std::stable_sort(want.begin(), want.end(), [&](std::int32_t a, std::int32_t b) {
      return keys0[std::size_t(a)] < keys0[std::size_t(b)];
    });
    for (const int threads : {1, 2, 3, 4}) {
      INFO(len << " keys, " << threads << " threads");
      std::vector<std::uint32_t> k(keys0.begin(), keys0.begin() + std::ptrdiff_t(len));
      std::vector<std::int32_t> ix(len);
      for (std::size_t i = 0; i < len; ++i) ix[i] = std::int32_t(i);
      detail::radix_sort_stable_parallel(k, ix, keys_tmp, idx_tmp, threads);
      CHECK(ix == want);
      CHECK(std::is_sorted(k.begin(), k.end()));
    }
  }
  // The merge-path split on ties: the left run's equal keys come first.
  const std::uint32_t a[] = {1, 2, 2, 2, 5}, b[] = {2, 2, 3};
  CHECK(detail::merge_path_split(a, 5, b, 3, 0) == 0);
  CHECK(detail::merge_path_split(a, 5, b, 3, 4) == 4);  // 1 2 2 2 from a
  CHECK(detail::merge_path_split(a, 5, b, 3, 6) == 4);  // then b's 2 2
  CHECK(detail::merge_path_split(a, 5, b, 3, 8) == 5);
}

TEMPLATE_TEST_CASE("alpha_power_floor is a tight lower bound of log2(1 / (255 opacity))", "[render]", float, double) {
  // Base-2 powers below the floor must give opacity 2^p2 < 1/255 (the backward
  // skips them); a loose floor only skips less.
  int checked = 0;
  for (double lo = -30; lo <= 0; lo += 1e-3) {
    const TestType op = TestType(std::exp(lo));
    const double exact = -std::log2(255.0 * double(op));
    const double floor = double(detail::alpha_power_floor(op));
    INFO("opacity " << op);
    REQUIRE(floor < exact);
    REQUIRE(exact - floor < 0.087);
    ++checked;
  }
  CHECK(checked > 20000);
  CHECK(std::isinf(detail::alpha_power_floor(TestType(0))));
}

TEMPLATE_TEST_CASE("tiles without Gaussians: the background, and their share of its gradient", "[render]", float,
                   double) {
  // Gaussians in the top-left 24 x 20 pixels of a 100 x 70 image: most tiles are
  // empty and take the rasterizers' shortcuts.
  using S = TestType;
  const std::array<S, 3> bg{{S(0.2), S(0.7), S(0.4)}};
  const int w = 100, h = 70;
  const auto s = random_splats<S>(60, 24, 20, 11);
  check_against_reference(s, w, h, bg, same_precision_tol<S>());
  const auto out = render_splats(s, w, h, 16, 2, bg);
  for (int y = 40; y < h; ++y)
    for (int x = 60; x < w; ++x) {
      INFO(x << "," << y);
      CHECK(out.color(x, y, 1) == bg[1]);
      CHECK(out.transmittance(x, y) == S(1));
      CHECK(out.depth(x, y) == S(0));
      CHECK(out.replay[std::size_t(y * w + x)] == 0);
    }
  // dL/d(background) = sum over pixels of v_colour T_final, summed here directly.
  BinWorkspace<S> bins;
  bin_splats(s, w, h, 16, bins);
  RasterParams<S> p;
  p.background = bg;
  p.threads = 2;
  RasterWorkspace<S> ws;
  RasterOutput<S> fwd;
  rasterize(bins, p, fwd, ws);
  Image<S> v_color(w, h, 3);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(-1, 1);
  for (auto& v : v_color.data) v = S(u(rng));
  RasterGradOutput<S> grad;
  rasterize_vjp(bins, p, fwd, v_color, nullptr, nullptr, s.size(), grad, ws);
  for (int c = 0; c < 3; ++c) {
    double direct = 0;
    for (int y = 0; y < h; ++y)
      for (int x = 0; x < w; ++x) direct += double(v_color(x, y, c)) * double(fwd.transmittance(x, y));
    CHECK(double(grad.v_background[std::size_t(c)]) == Approx(direct).epsilon(sizeof(S) == 4 ? 1e-4 : 1e-12));
  }
}

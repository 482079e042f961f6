// Binning + forward rasterization against the plain per-pixel reference.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>
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

TEST_CASE("tile lanes: every pixel once, in blocks where the tile size allows", "[render]") {
  struct Case { int tile, lanes, block_w, block_h; };  // block 0 x 0: runs of consecutive pixels
  for (const Case c : {Case{16, 16, 4, 4}, Case{16, 8, 4, 2}, Case{16, 4, 2, 2}, Case{16, 2, 2, 1}, Case{16, 1, 1, 1},
                       Case{12, 16, 4, 4}, Case{8, 8, 4, 2}, Case{5, 16, 0, 0}, Case{6, 16, 0, 0}, Case{1, 8, 0, 0}}) {
    INFO("tile " << c.tile << " lanes " << c.lanes);
    TileLanes<float> L;
    L.build(c.tile, c.lanes);
    const int pixels = c.tile * c.tile;
    REQUIRE(L.chunks == (pixels + c.lanes - 1) / c.lanes);
    std::vector<int> seen(std::size_t(pixels), 0);
    for (int k = 0; k < L.chunks; ++k) {
      float x_lo = 1e30f, x_hi = -1e30f, y_lo = 1e30f, y_hi = -1e30f;
      for (int l = 0; l < c.lanes; ++l) {
        const std::size_t q = std::size_t(k * c.lanes + l);
        const int p = L.pixel[q];
        if (p < 0) {  // padding: only after the last pixel, and below any image
          CHECK(k == L.chunks - 1);
          CHECK(L.oy[q] >= float(1 << 23));
          continue;
        }
        REQUIRE(p < pixels);
        ++seen[std::size_t(p)];
        CHECK(L.ox[q] == float(p % c.tile) + 0.5f);
        CHECK(L.oy[q] == float(p / c.tile) + 0.5f);
        CHECK(L.col[q] == p % c.tile);
        CHECK(L.row[q] == p / c.tile);
        x_lo = std::min(x_lo, L.ox[q]); x_hi = std::max(x_hi, L.ox[q]);
        y_lo = std::min(y_lo, L.oy[q]); y_hi = std::max(y_hi, L.oy[q]);
      }
      // The chunk's bounds are those of its own pixel centres (ChunkBoxes relies on it).
      CHECK(L.cx_lo[std::size_t(k)] == x_lo);
      CHECK(L.cx_hi[std::size_t(k)] == x_hi);
      CHECK(L.cy_lo[std::size_t(k)] == y_lo);
      CHECK(L.cy_hi[std::size_t(k)] == y_hi);
      if (c.block_w > 0) {
        CHECK(x_hi - x_lo == float(c.block_w - 1));
        CHECK(y_hi - y_lo == float(c.block_h - 1));
      } else {
        const int first = L.pixel[std::size_t(k * c.lanes)];
        for (int l = 1; l < c.lanes; ++l) {
          const int p = L.pixel[std::size_t(k * c.lanes + l)];
          if (p >= 0) CHECK(p == first + l);
        }
      }
    }
    CHECK(std::count(seen.begin(), seen.end(), 1) == pixels);
  }
}

namespace {

// ChunkBoxes' bits against one scalar test per chunk: a rect meets chunk k when
// it reaches one of its pixel centres, and holds it when it holds all of them.
template <class S, class B>
void check_chunk_boxes(int tile, std::uint32_t seed) {
  INFO("tile " << tile << ", " << B::size << " lanes");
  TileLanes<S> L;
  L.build(tile, int(B::size));
  std::mt19937 rng(seed);
  std::uniform_int_distribution<int> corner(0, 3), off(-3, tile + 3), len(0, tile + 2);
  const int tiles_x = 5;
  std::vector<std::uint64_t> want_meets, want_within;
  for (int trial = 0; trial < 400; ++trial) {
    const int tx0 = tile * corner(rng), ty0 = tile * corner(rng);
    SplatRecord<S> G{};
    const int x0 = std::max(0, tx0 + off(rng)), y0 = std::max(0, ty0 + off(rng));
    G.x_lo = S(x0);
    G.y_lo = S(y0);
    G.x_hi = S(std::min(tiles_x * tile, x0 + 1 + len(rng)));
    G.y_hi = S(std::min(tiles_x * tile, y0 + 1 + len(rng)));
    const detail::ChunkBoxes<B, S> boxes(L, S(tx0), S(ty0));
    REQUIRE(boxes.words == (L.chunks + 63) / 64);
    for (int w = 0; w < boxes.words; ++w) {
      std::uint64_t meets = 0, within = 0;
      for (int k = 64 * w; k < std::min(L.chunks, 64 * w + 64); ++k) {
        const S cxl = S(tx0) + L.cx_lo[std::size_t(k)], cxh = S(tx0) + L.cx_hi[std::size_t(k)];
        const S cyl = S(ty0) + L.cy_lo[std::size_t(k)], cyh = S(ty0) + L.cy_hi[std::size_t(k)];
        const std::uint64_t bit = std::uint64_t(1) << (k - 64 * w);
        if (!(G.x_lo >= cxh || G.x_hi <= cxl || G.y_lo >= cyh || G.y_hi <= cyl)) meets |= bit;
        if (G.x_lo < cxl && G.x_hi > cxh && G.y_lo < cyl && G.y_hi > cyh) within |= bit;
      }
      INFO("trial " << trial << " word " << w << " rect [" << G.x_lo << ", " << G.x_hi << "] x [" << G.y_lo << ", "
                    << G.y_hi << "] tile at " << tx0 << ", " << ty0);
      CHECK(boxes.meets(G, w) == meets);
      CHECK(boxes.within(G, w) == within);
    }
  }
}

}  // namespace

TEMPLATE_TEST_CASE("chunk bits: each chunk a rect meets or holds, as a test per chunk finds them", "[render]", float,
                   double) {
  using S = TestType;
  for (int tile : {1, 5, 8, 16, 32, 64}) {
    check_chunk_boxes<S, simd::native_batch<S>>(tile, std::uint32_t(tile));
    check_chunk_boxes<S, simd::scalar_batch<S>>(tile, std::uint32_t(tile) + 100);
  }
}

TEMPLATE_TEST_CASE("mask_bits: lane i's flag at bit i", "[render]", float, double) {
  using B = simd::native_batch<TestType>;
  constexpr std::size_t N = B::size;
  alignas(64) TestType v[N];
  for (std::uint32_t pattern : {0u, 1u, 0x5555u, 0xffffu, 0x8001u, 0x1234u}) {
    std::uint64_t want = 0;
    for (std::size_t i = 0; i < N; ++i) {
      const bool on = (pattern >> i) & 1u;
      v[i] = on ? TestType(1) : TestType(0);
      want |= std::uint64_t(on) << i;
    }
    CHECK(simd::mask_bits(B::load_unaligned(v) > B(TestType(0.5))) == want);
    CHECK(simd::mask_bits(simd::scalar_batch<TestType>(v[0]) > simd::scalar_batch<TestType>(TestType(0.5))) ==
          (want & 1u));
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

TEST_CASE("a record's tile box: the shift of a power-of-two tile size gives the division's quotients", "[render]") {
  CHECK(detail::tile_size_shift(1) == 0);
  CHECK(detail::tile_size_shift(16) == 4);
  CHECK(detail::tile_size_shift(256) == 8);
  for (int ts : {0, 3, 5, 12, 24, 255}) CHECK(detail::tile_size_shift(ts) == -1);
  for (int ts : {1, 2, 5, 8, 16, 24, 64}) {
    const int shift = detail::tile_size_shift(ts);
    for (int lo = 0; lo < 300; lo += 7)
      for (int hi = lo + 1; hi < 320; hi += 13) {
        SplatRecord<float> rec{};
        rec.x_lo = float(lo), rec.x_hi = float(hi), rec.y_lo = float(hi - 1), rec.y_hi = float(hi);
        const std::array<int, 4> box = detail::record_tile_box(rec, ts, shift);
        INFO("tile " << ts << " lo " << lo << " hi " << hi);
        CHECK(box == (std::array<int, 4>{{lo / ts, (hi - 1) / ts, (hi - 1) / ts, (hi - 1) / ts}}));
      }
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
    // The tile lists' entries have distinct rank-major slots in [0, slots).
    std::vector<char> seen(many.slots(), 0);
    const TileGrid& g = many.grid;
    for (int t = 0; t < g.tile_count(); ++t)
      for (std::uint32_t e = many.tile_offsets[std::size_t(t)]; e < many.tile_offsets[std::size_t(t) + 1]; ++e) {
        const std::uint32_t slot = many.entry_slot(t % g.tiles_x, t / g.tiles_x, std::size_t(many.tile_ranks[e]));
        REQUIRE(slot < many.slots());
        seen[slot] = 1;
      }
    CHECK(std::count(seen.begin(), seen.end(), 1) == std::ptrdiff_t(many.pairs()));
  }
}

TEMPLATE_TEST_CASE("the tile lists: the tiles each ellipse reaches, with slots over its whole tile box", "[render]",
                   float, double) {
  // A rank's slots number its tile box's tiles in row-major order, ranks in
  // order, listed or not. A tile lists, front to back, the ranks whose
  // p2 >= min_power ellipse reaches it: every tile with a pixel centre (in the
  // rect) inside the ellipse is listed (else the kernels would miss a pixel),
  // and every listed tile has a pixel column whose band of rows in the tile
  // meets the ellipse (the corners of a tilted or long ellipse's box are not
  // listed; a box of one row or column lists all its tiles). Both evaluated
  // here in double, from the records' fields. Boxes of up to 8 x 16 tiles keep
  // their rows' trims, larger ones compute them again: the second scene's
  // large splats have both kinds.
  struct Scene { int w, h, n; double sigma_max; };
  std::vector<std::pair<Scene, int>> runs;  // scene, threads
  for (const Scene sc : {Scene{200, 72, 9000, 12}, Scene{256, 200, 1500, 40}})
    for (int threads : {1, 2}) runs.emplace_back(sc, threads);
  for (const auto& [sc, threads] : runs) {
    INFO("scene " << sc.w << "x" << sc.h << ", threads " << threads);
    const int w = sc.w, h = sc.h;  // the first: a partial last column and row of tiles
    RandomSplatOptions o;
    o.sigma_max = sc.sigma_max;
    const auto s = random_splats<TestType>(std::size_t(sc.n), w, h, 5, o);
    BinWorkspace<TestType> bins;
    bin_splats(s, w, h, 16, bins, threads);
    const TileGrid& g = bins.grid;
    if (sc.n > 4096) REQUIRE(bins.visible() > 4096);  // more than one rank chunk on two threads
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
      k += std::uint32_t((b[2] - b[0] + 1) * (b[3] - b[1] + 1));
    }
    REQUIRE(bins.slots() == k);
    // listed[r] = the tiles listing rank r
    std::vector<std::vector<int>> listed(bins.visible());
    for (int t = 0; t < g.tile_count(); ++t) {
      const int tx = t % g.tiles_x, ty = t / g.tiles_x;
      for (std::uint32_t e = bins.tile_offsets[std::size_t(t)]; e < bins.tile_offsets[std::size_t(t) + 1]; ++e) {
        const std::size_t r = std::size_t(bins.tile_ranks[e]);
        if (e > bins.tile_offsets[std::size_t(t)]) CHECK(bins.tile_ranks[e - 1] < bins.tile_ranks[e]);
        const auto& b = bins.rank_boxes[r];
        REQUIRE((tx >= b[0] && tx <= b[2] && ty >= b[1] && ty <= b[3]));
        CHECK(bins.entry_slot(tx, ty, r) ==
              bins.rank_offsets[r] + std::uint32_t((ty - b[1]) * (b[2] - b[0] + 1) + (tx - b[0])));
        listed[r].push_back(t);
      }
    }
    std::size_t boxes_tiles = 0, reached = 0, wrongly_listed = 0, missed = 0;
    for (std::size_t r = 0; r < bins.visible(); ++r) {
      const auto& rec = bins.records[r];
      const auto& b = bins.rank_boxes[r];
      const double a = -double(rec.pxx), hh = -0.5 * double(rec.pxy), c = -double(rec.pyy), mu = -double(rec.min_power);
      auto q = [&](double dx, double dy) { return a * dx * dx + 2 * hh * dx * dy + c * dy * dy; };
      for (int ty = b[1]; ty <= b[3]; ++ty)
        for (int tx = b[0]; tx <= b[2]; ++tx) {
          ++boxes_tiles;
          const int x0 = std::max(tx * 16, int(rec.x_lo)), x1 = std::min(tx * 16 + 15, int(rec.x_hi) - 1);
          const int y0 = std::max(ty * 16, int(rec.y_lo)), y1 = std::min(ty * 16 + 15, int(rec.y_hi) - 1);
          bool pixel_inside = false, band_meets = false;
          for (int x = x0; x <= x1; ++x) {
            const double dx = x + 0.5 - double(rec.mean_x);
            // The smallest q over the column's continuous band of rows, with
            // the binning's margins: the column moved either way by 0.02 pixel
            // and 2^-20 of the mean's coordinate, and mu 0.1 % larger.
            const double margin = 0.02 + std::abs(double(rec.mean_x)) / 1048576 + 1e-9;
            const double lo = y0 + 0.5 - double(rec.mean_y), hi = y1 + 0.5 - double(rec.mean_y);
            for (const double dxm : {dx - margin, dx, dx + margin}) {
              const double dy_min = std::min(hi, std::max(lo, -hh * dxm / c));
              band_meets = band_meets || q(dxm, dy_min) <= mu * 1.0011 + 1e-9;
            }
            for (int y = y0; y <= y1 && !pixel_inside; ++y) pixel_inside = q(dx, y + 0.5 - double(rec.mean_y)) <= mu;
          }
          const bool is_listed =
              std::find(listed[r].begin(), listed[r].end(), ty * g.tiles_x + tx) != listed[r].end();
          reached += is_listed;
          missed += pixel_inside && !is_listed;
          // A box of one row or one column keeps all its tiles.
          if (b[1] == b[3] || b[0] == b[2]) wrongly_listed += !is_listed;
          else wrongly_listed += is_listed && !band_meets;
        }
    }
    CHECK(missed == 0);
    CHECK(wrongly_listed == 0);
    CHECK(reached == bins.pairs());
    // These random splats have square 3-sigma rects, so many box tiles go.
    CHECK(double(bins.pairs()) < 0.8 * double(boxes_tiles));
    const auto recompute = std::count(bins.rank_trims.begin(), bins.rank_trims.end(), detail::kTrimsRecompute);
    const auto whole = std::count(bins.rank_trims.begin(), bins.rank_trims.end(), std::uint64_t(0));
    if (sc.sigma_max > 12) CHECK(recompute > 0);
    CHECK(std::size_t(recompute + whole) < bins.visible());
  }
}

TEMPLATE_TEST_CASE("tile rows of an ellipse: exact spans of a tilted, a thin and a flat ellipse", "[render]", float,
                   double) {
  // A Gaussian whose ellipse is the unit-free q(dx, dy) = a dx^2 + 2 h dx dy +
  // c dy^2 <= mu, checked against spans counted by hand from the chords.
  using S = TestType;
  SplatRecord<S> rec{};
  auto set = [&](double mx, double my, double a, double hh, double c, double mu, int x0, int x1, int y0, int y1) {
    rec.mean_x = S(mx); rec.mean_y = S(my);
    rec.pxx = S(-a); rec.pxy = S(-2 * hh); rec.pyy = S(-c); rec.min_power = S(-mu);
    rec.x_lo = S(x0); rec.x_hi = S(x1 + 1); rec.y_lo = S(y0); rec.y_hi = S(y1 + 1);
  };
  SECTION("an axis-aligned ellipse 40 wide, 8 tall, in a 64x64 box: one row of tiles") {
    set(32, 32, 1.0 / 400, 0, 1.0 / 16, 1, 0, 63, 0, 63);  // half-widths 20 and 4
    const detail::TileRowSpans spans(rec, 16);
    CHECK(spans.row(0, 0, 3).first > spans.row(0, 0, 3).second);
    CHECK(spans.row(1, 0, 3) == std::pair<int, int>(0, 3));  // x 12.5..51.5 -> tiles 0..3
    CHECK(spans.row(2, 0, 3) == std::pair<int, int>(0, 3));  // rows 32..35 still reach
    CHECK(spans.row(3, 0, 3).first > spans.row(3, 0, 3).second);
  }
  SECTION("a thin ellipse along the diagonal lists 10 of its box's 16 tiles") {
    // Long axis (1,1)/sqrt2 with half length 40 (x and y from about 3.7 to
    // 60.3), short half length 2: about 2.8 pixels either side of x = y. Row 0 (y 4..15.5) spans x 1.2..18.3, row 1 (y 16.5..31.5) x
    // 13.7..34.3, and the lower rows mirror them.
    const double l1 = 1.0 / 1600, l2 = 1.0 / 4;  // 1 / half-lengths^2
    set(32, 32, 0.5 * (l1 + l2), 0.5 * (l1 - l2), 0.5 * (l1 + l2), 1, 0, 63, 0, 63);
    const detail::TileRowSpans spans(rec, 16);
    CHECK(spans.row(0, 0, 3) == std::pair<int, int>(0, 1));
    CHECK(spans.row(1, 0, 3) == std::pair<int, int>(0, 2));
    CHECK(spans.row(2, 0, 3) == std::pair<int, int>(1, 3));
    CHECK(spans.row(3, 0, 3) == std::pair<int, int>(2, 3));
  }
  SECTION("mu < 0 (min_power > 0): listed nowhere; a degenerate form: the whole box row") {
    set(8, 8, 1, 0, 1, -1, 0, 15, 0, 15);
    CHECK(detail::TileRowSpans(rec, 16).row(0, 0, 0).first > 0);
    set(8, 8, 1, 1, 1, 1, 0, 31, 0, 15);  // det = 0
    CHECK(detail::TileRowSpans(rec, 16).row(0, 0, 1) == std::pair<int, int>(0, 1));
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
  // Subnormal 255 opacity (frexp's path): still a lower bound.
  for (const TestType op : {std::numeric_limits<TestType>::denorm_min(), std::numeric_limits<TestType>::min() / 1024}) {
    INFO("opacity " << op);
    CHECK(double(detail::alpha_power_floor(op)) < -std::log2(255.0 * double(op)));
  }
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

TEMPLATE_TEST_CASE("binning packs in lanes the records it packs one at a time", "[render]", float, double) {
  // Whole batches of visible Gaussians go through pack_record_lanes, the rest
  // (culled ones nearby, a subnormal 255 opacity, a chunk's last few) one at a
  // time; every record must be pack_record's, bit for bit, in depth order.
  using S = TestType;
  const int w = 96, h = 80;
  auto s = random_splats<S>(3001, w, h, 12);
  constexpr std::size_t N = simd::native_batch<S>::size;
  s.opacity[5 * N + 1] = std::numeric_limits<S>::min() / 1024;  // 255 opacity subnormal: frexp's path
  s.radius[7 * N + 2] = 0;                                      // a culled Gaussian inside a batch
  for (int threads : {1, 2}) {
    BinWorkspace<S> bins;
    bin_splats(s, w, h, 16, bins, threads);
    std::size_t visible = 0;
    for (std::size_t i = 0; i < s.size(); ++i)
      visible += s.radius[i] > 0 && s.rect_x0[i] <= s.rect_x1[i] && s.rect_y0[i] <= s.rect_y1[i];
    REQUIRE(bins.visible() == visible);
    REQUIRE(visible > 40 * N);
    for (std::size_t r = 0; r < bins.visible(); ++r) {
      const std::size_t i = std::size_t(bins.order[r]);
      SplatRecord<S> expected;
      detail::pack_record(s, i, expected);
      INFO("threads " << threads << ", rank " << r << ", Gaussian " << i);
      REQUIRE(std::memcmp(&bins.records[r], &expected, sizeof(expected)) == 0);
      if (r > 0) {
        const std::size_t p = std::size_t(bins.order[r - 1]);
        REQUIRE((s.depth[p] < s.depth[i] || (s.depth[p] == s.depth[i] && p < i)));
      }
    }
  }
}

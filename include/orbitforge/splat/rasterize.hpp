#pragma once
// Per-tile forward rasterization (front-to-back alpha blending), multi-threaded
// over tiles and SIMD over the pixels of a tile.
//
// Rules (docs/conventions.md): pixel
// (x, y) has its centre at (x + 0.5, y + 0.5); for each Gaussian of the pixel's
// tile in depth order whose rect contains the pixel,
//   power = -0.5 (a dx^2 + c dy^2) - b dx dy        (skip power > 0)
//   alpha = min(0.99, opacity exp(power))           (skip alpha < 1/255)
// (computed in base 2: see SplatRecord and simd::exp2_nonpositive),
//   if T (1 - alpha) < 1e-4 the pixel stops and this Gaussian is NOT blended;
//   else colour += T alpha c, depth += T alpha z, T *= 1 - alpha.
// Outputs: colour + T background, final T, expected depth (unnormalised), the
// number of Gaussians blended, and per pixel how many tile-list entries the
// backward pass must replay (list position of the last blended Gaussian + 1).
//
// A tile of ts x ts pixels is cut into "chunks" of B::size pixels, one per lane:
// square-ish blocks (16 lanes: 4x4, 8: 4x2, 4: 2x2) where ts allows, else runs of
// consecutive pixels in row-major order (TileLanes). Lanes past the image border
// or the tile are dead from the start. Each pixel's arithmetic and order do not
// depend on the layout, so neither does the image.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/bin.hpp"

namespace orbitforge {

template <class Scalar>
struct RasterParams {
  std::array<Scalar, 3> background{{0, 0, 0}};
  int threads = 0;  // 0 = default (all hardware threads)
  // The backward computes dL/d(background) (RasterGradOutput::v_background);
  // false leaves it zero and skips its per-pixel sums, which are serial (pixel
  // order) and, on a frame of mostly empty tiles, most of what those tiles cost.
  bool background_gradient = true;
};

// The blending thresholds, in one place for the forward, backward and reference.
template <class Scalar>
struct RasterRules {
  static constexpr Scalar max_alpha() { return Scalar(0.99); }
  static constexpr Scalar min_alpha() { return Scalar(1) / Scalar(255); }
  static constexpr Scalar min_transmittance() { return Scalar(1e-4); }
};

struct RasterStats {
  std::uint64_t pairs_evaluated = 0;  // (pixel, Gaussian) pairs whose power was evaluated for a live pixel
  std::uint64_t contributions = 0;    // pairs blended
  double ms = 0;
};

template <class Scalar>
struct RasterOutput {
  Image<Scalar> color;                // [H][W][3] sum_i w_i c_i + T background
  Image<Scalar> transmittance;        // [H][W][1] final T; alpha = 1 - T
  Image<Scalar> depth;                // [H][W][1] sum_i w_i z_i (divide by alpha to normalise)
  Image<std::int32_t> count;          // [H][W][1] Gaussians blended
  cache_aligned_vector<std::int32_t> replay;  // [H*W] tile-list entries the backward replays
  RasterStats stats;
};

// Pixel offsets of the lanes of each chunk of a tile, for one tile size and lane
// count, plus each chunk's pixel-centre bounding box in the tile (ChunkBoxes).
// Chunks are blocks of bw x bh pixels, bw the smallest power of two with
// bw^2 >= lanes, in row-major block order. Trained scenes are mostly Gaussians a
// few pixels wide: a 4x4 block wastes fewer lanes on them than a 16-pixel row
// (bench_render's BM_RasterKernelsScene on three trained scenes: the forward
// 0.71-0.79x, the backward 0.66-0.86x the time; docs/benchmarks.md).
// A tile size the blocks do not divide falls back to runs of consecutive pixels.
template <class Scalar>
struct TileLanes {
  int tile_size = 0, lanes = 0, chunks = 0;
  std::vector<Scalar> ox, oy;                      // [chunks * lanes] centre offsets (x + 0.5)
  // [chunks, padded to a multiple of lanes] with bounds no rect meets
  std::vector<Scalar> cx_lo, cx_hi, cy_lo, cy_hi;
  std::vector<std::int32_t> pixel;                 // [chunks * lanes] pixel index in the tile, -1 = padding
  // [chunks * lanes] the pixel's column and row in the tile (padding: 0), so
  // that storing a chunk divides nothing by the tile size.
  std::vector<std::int32_t> col, row;

  // The chunk count rounded up to whole batches of lanes (the bounds' length).
  std::size_t padded_chunks() const { return cx_lo.size(); }

  void build(int ts, int n_lanes) {
    if (ts == tile_size && n_lanes == lanes) return;
    tile_size = ts;
    lanes = n_lanes;
    const int pixels = ts * ts;
    chunks = (pixels + lanes - 1) / lanes;
    const std::size_t total = std::size_t(chunks) * std::size_t(lanes);
    ox.assign(total, Scalar(0.5));
    oy.assign(total, Scalar(1 << 24));  // padding lanes sit far below any image: dead
    pixel.assign(total, -1);
    col.assign(total, 0);
    row.assign(total, 0);
    const std::size_t padded = std::size_t((chunks + lanes - 1) / lanes) * std::size_t(lanes);
    cx_lo.assign(padded, Scalar(1e30)); cx_hi.assign(padded, Scalar(-1e30));
    cy_lo.assign(padded, Scalar(1e30)); cy_hi.assign(padded, Scalar(-1e30));
    int bw = 1;
    while (bw * bw < lanes) bw *= 2;
    const int bh = lanes / bw;
    const bool blocks = bw * bh == lanes && ts % bw == 0 && ts % bh == 0;
    const int blocks_per_row = blocks ? ts / bw : 0;
    for (int q = 0; q < pixels; ++q) {  // lane slot q = chunk k, lane l
      const int k = q / lanes, l = q % lanes;
      const int p = blocks ? ((k / blocks_per_row) * bh + l / bw) * ts + (k % blocks_per_row) * bw + l % bw : q;
      const Scalar x = Scalar(p % ts) + Scalar(0.5), y = Scalar(p / ts) + Scalar(0.5);
      ox[std::size_t(q)] = x;
      oy[std::size_t(q)] = y;
      pixel[std::size_t(q)] = p;
      col[std::size_t(q)] = p % ts;
      row[std::size_t(q)] = p / ts;
      cx_lo[std::size_t(k)] = std::min(cx_lo[std::size_t(k)], x); cx_hi[std::size_t(k)] = std::max(cx_hi[std::size_t(k)], x);
      cy_lo[std::size_t(k)] = std::min(cy_lo[std::size_t(k)], y); cy_hi[std::size_t(k)] = std::max(cy_hi[std::size_t(k)], y);
    }
  }
};

// Caller-owned scratch for rasterize / rasterize_vjp, reused across frames.
template <class Scalar>
struct RasterWorkspace {
  TileLanes<Scalar> lanes;
  struct alignas(64) WorkerStats { std::uint64_t evaluated = 0, contributions = 0; };
  std::vector<WorkerStats> worker_stats;
  std::vector<std::vector<std::uint64_t>> worker_chunk_bits;  // [workers][a tile's entries x ChunkBoxes words] (forward)
  // Backward only.
  std::vector<std::vector<Scalar>> worker_scratch;  // [workers][7 lanes per pixel slot + chunk slots]
  std::vector<Scalar> pair_grad;                    // [slots][10] rank-major (BinWorkspace::entry_slot)
  std::vector<std::int32_t> live_rank_end;          // [tiles] entries of rank >= this were not replayed
  std::vector<Scalar> tile_background;              // [tiles][3] each tile's share of dL/d(background)
};

namespace detail {

// Calls f(first, last) with the pixel indices of the first and last pixel of
// each row of the tile whose top-left pixel is (tx0, ty0).
template <class F>
void tile_row_spans(const TileGrid& g, int tx0, int ty0, F&& f) {
  const int rows = std::min(g.tile_size, g.height - ty0), cols = std::min(g.tile_size, g.width - tx0);
  for (int y = 0; y < rows; ++y) {
    const std::size_t first = std::size_t(ty0 + y) * std::size_t(g.width) + std::size_t(tx0);
    f(first, first + std::size_t(cols - 1));
  }
}

template <class Scalar>
void prepare_raster_output(const TileGrid& g, RasterOutput<Scalar>& out) {
  auto shape = [&](auto& img, int c) {
    if (img.width != g.width || img.height != g.height || img.channels != c)
      img = std::decay_t<decltype(img)>(g.width, g.height, c);
  };
  shape(out.color, 3);
  shape(out.transmittance, 1);
  shape(out.depth, 1);
  shape(out.count, 1);
  out.replay.resize(std::size_t(g.width) * std::size_t(g.height));
}

// Which chunks of a tile a Gaussian's rect meets, as bits: chunk k at bit
// k % 64 of word k / 64. The same comparisons as a scalar test per chunk
// (relative to the tile's corner, exact for the integer and half-integer
// bounds of images under 2^23 pixels a side), for B::size chunks at once. On
// a trained scene a tile lists many Gaussians a few pixels wide, each meeting
// one to four of its 16 chunks: testing every chunk against every entry, one
// unpredictable branch each, had cost more than the blending
// (docs/benchmarks.md).
template <class B, class Scalar>
struct ChunkBoxes {
  const TileLanes<Scalar>* L;
  Scalar fx0, fy0;
  int words;

  ChunkBoxes(const TileLanes<Scalar>& lanes, Scalar x0, Scalar y0)
      : L(&lanes), fx0(x0), fy0(y0), words((lanes.chunks + 63) / 64) {}

  // Chunks of word w that the rect [x_lo, x_hi] x [y_lo, y_hi] reaches a pixel centre of.
  std::uint64_t meets(const SplatRecord<Scalar>& G, int w) const {
    const B xl(G.x_lo - fx0), xh(G.x_hi - fx0), yl(G.y_lo - fy0), yh(G.y_hi - fy0);
    return over_word(w, [&](std::size_t o) {
      return (xl < B::load_unaligned(L->cx_hi.data() + o)) & (xh > B::load_unaligned(L->cx_lo.data() + o)) &
             (yl < B::load_unaligned(L->cy_hi.data() + o)) & (yh > B::load_unaligned(L->cy_lo.data() + o));
    });
  }
  // Chunks of word w wholly inside the rect.
  std::uint64_t within(const SplatRecord<Scalar>& G, int w) const {
    const B xl(G.x_lo - fx0), xh(G.x_hi - fx0), yl(G.y_lo - fy0), yh(G.y_hi - fy0);
    return over_word(w, [&](std::size_t o) {
      return (xl < B::load_unaligned(L->cx_lo.data() + o)) & (xh > B::load_unaligned(L->cx_hi.data() + o)) &
             (yl < B::load_unaligned(L->cy_lo.data() + o)) & (yh > B::load_unaligned(L->cy_hi.data() + o));
    });
  }
  // Bits of word w from test(o), the mask of chunks o .. o + B::size - 1
  // (none past the last chunk).
  template <class Test>
  std::uint64_t over_word(int w, Test&& test) const {
    constexpr std::size_t N = B::size;
    static_assert(64 % N == 0, "ChunkBoxes: the lane count must divide 64");
    const std::size_t first = std::size_t(w) * 64, end = std::min(first + 64, L->padded_chunks());
    std::uint64_t bits = 0;
    for (std::size_t o = first; o < end; o += N) bits |= simd::mask_bits(test(o)) << (o - first);
    const std::size_t chunks = std::size_t(L->chunks) - first;
    return chunks >= 64 ? bits : bits & ((std::uint64_t(1) << chunks) - 1);
  }
};

// One chunk's running state while it walks the tile's list front to back.
template <class B, class Scalar>
struct ChunkBlend {
  using M = simd::mask_t<B>;
  using Rules = RasterRules<Scalar>;
  B px, py;
  M active;
  B T, cr, cg, cb, dep, cnt, last, ev;
  bool live;

  ChunkBlend(int k, const TileLanes<Scalar>& L, Scalar fx0, Scalar fy0, const TileGrid& g) {
    const std::size_t N = B::size;
    px = B::load_unaligned(L.ox.data() + std::size_t(k) * N) + B(fx0);
    py = B::load_unaligned(L.oy.data() + std::size_t(k) * N) + B(fy0);
    active = (px < B(Scalar(g.width))) & (py < B(Scalar(g.height)));
    T = B(Scalar(1));
    cr = cg = cb = dep = cnt = last = ev = B(Scalar(0));
    live = simd::any(active);  // false for a chunk wholly outside the image
  }

  // Blend list entry j (Gaussian G, whose rect meets the chunk: ChunkBoxes)
  // into the chunk's live lanes.
  void blend(const SplatRecord<Scalar>& G, int j) {
    const B zero(Scalar(0)), one(Scalar(1));
    const M inside = active & (px > B(G.x_lo)) & (px < B(G.x_hi)) & (py > B(G.y_lo)) & (py < B(G.y_hi));
    const B dx = px - B(G.mean_x), dy = py - B(G.mean_y);
    // The power in base 2 (SplatRecord): exp(power) = 2^p2.
    const B p2 = simd::fma(B(G.pxx) * dx, dx, simd::fma(B(G.pxy) * dx, dy, B(G.pyy) * dy * dy));
    const B alpha = simd::min(B(Rules::max_alpha()), B(G.opacity) * simd::exp2_nonpositive(p2));
    const M valid = inside & (p2 <= zero) & (alpha >= B(Rules::min_alpha()));
    const B T_next = T * (one - alpha);
    const M blend = valid & (T_next >= B(Rules::min_transmittance()));
    // A valid pair that would push T below 1e-4 stops the pixel unblended.
    active = active & ~(valid & (T_next < B(Rules::min_transmittance())));
    const B w = simd::select(blend, alpha * T, zero);
    cr = simd::fma(w, B(G.color_r), cr);
    cg = simd::fma(w, B(G.color_g), cg);
    cb = simd::fma(w, B(G.color_b), cb);
    dep = simd::fma(w, B(G.depth), dep);
    T = simd::select(blend, T_next, T);
    cnt = cnt + simd::select(blend, one, zero);
    last = simd::select(blend, B(Scalar(j + 1)), last);
    ev = ev + simd::select(inside, one, zero);
    live = simd::any(active);
  }

  // Scatter the chunk's lanes to the images (dead lanes are not written).
  void store(int k, const TileLanes<Scalar>& L, int tx0, int ty0, const TileGrid& g, const RasterParams<Scalar>& params,
             RasterOutput<Scalar>& out, std::uint64_t& evaluated, std::uint64_t& contributions) const {
    constexpr std::size_t N = B::size;
    alignas(64) Scalar s_T[N], s_r[N], s_g[N], s_b[N], s_d[N], s_n[N], s_l[N], s_e[N];
    T.store_unaligned(s_T); cr.store_unaligned(s_r); cg.store_unaligned(s_g); cb.store_unaligned(s_b);
    dep.store_unaligned(s_d); cnt.store_unaligned(s_n); last.store_unaligned(s_l); ev.store_unaligned(s_e);
    for (std::size_t l = 0; l < N; ++l) {
      const std::size_t q = std::size_t(k) * N + l;
      if (L.pixel[q] < 0) continue;
      const int x = tx0 + L.col[q], y = ty0 + L.row[q];
      if (x >= g.width || y >= g.height) continue;
      const std::size_t pi = std::size_t(y) * std::size_t(g.width) + std::size_t(x);
      out.color.data[3 * pi + 0] = s_r[l] + s_T[l] * params.background[0];
      out.color.data[3 * pi + 1] = s_g[l] + s_T[l] * params.background[1];
      out.color.data[3 * pi + 2] = s_b[l] + s_T[l] * params.background[2];
      out.transmittance.data[pi] = s_T[l];
      out.depth.data[pi] = s_d[l];
      out.count.data[pi] = std::int32_t(s_n[l]);
      out.replay[pi] = std::int32_t(s_l[l]);
      contributions += std::uint64_t(s_n[l]);
      evaluated += std::uint64_t(s_e[l]);
    }
  }
};

// Four chunks walk the list together: each chunk's transmittance update is a
// serial dependency (multiply, compare, select) that left one chunk latency
// bound; independent chains fill the gaps (two chunks: 10%, four: another 4%
// on AVX-512). Each chunk's arithmetic and order are unchanged, so the image is
// the same bit for bit.
constexpr int kChunksTogether = 4;
static_assert(64 % kChunksTogether == 0, "a group of chunks must not straddle two words of ChunkBoxes bits");

template <class B, class Scalar>
void rasterize_tile(int t, const BinWorkspace<Scalar>& bins, const TileLanes<Scalar>& L, const RasterParams<Scalar>& params,
                    RasterOutput<Scalar>& out, std::uint64_t& evaluated_out, std::uint64_t& contributions_out,
                    std::vector<std::uint64_t>& chunk_bits) {
  using Chunk = ChunkBlend<B, Scalar>;
  const TileGrid& g = bins.grid;
  const int tx0 = g.tile_x0(t), ty0 = g.tile_y0(t);
  const Scalar fx0 = Scalar(tx0), fy0 = Scalar(ty0);
  const std::int32_t* ranks = bins.tile_ranks.data() + bins.tile_offsets[std::size_t(t)];
  const int n = int(bins.tile_offsets[std::size_t(t) + 1] - bins.tile_offsets[std::size_t(t)]);
  const SplatRecord<Scalar>* rec = bins.records.data();
  if (n == 0) {  // no Gaussian here: what the blend would store, written directly
    tile_row_spans(g, tx0, ty0, [&](std::size_t first, std::size_t last) {
      const std::size_t count = last - first + 1;
      for (std::size_t i = first; i <= last; ++i)
        for (std::size_t c = 0; c < 3; ++c) out.color.data[3 * i + c] = params.background[c];
      std::fill_n(out.transmittance.data.begin() + std::ptrdiff_t(first), count, Scalar(1));
      std::fill_n(out.depth.data.begin() + std::ptrdiff_t(first), count, Scalar(0));
      std::fill_n(out.count.data.begin() + std::ptrdiff_t(first), count, 0);
      std::fill_n(out.replay.begin() + std::ptrdiff_t(first), count, 0);
    });
    return;
  }
  std::uint64_t evaluated = 0, contributions = 0;

  // Each entry's chunks, found once for the tile (entry j's word w at
  // chunk_bits[j * words + w]), in blocks as far down the list as some group
  // of chunks walks: on dense scenes the pixels stop long before the list ends.
  const ChunkBoxes<B, Scalar> boxes(L, fx0, fy0);
  const int words = boxes.words;
  if (chunk_bits.size() < std::size_t(n) * std::size_t(words)) chunk_bits.resize(std::size_t(n) * std::size_t(words));
  int found = 0;  // entries whose bits are in chunk_bits
  auto find_bits = [&] {
    const int end = std::min(n, found + 32);
    for (int j = found; j < end; ++j) {
#if defined(__GNUC__)
      // The tile's records lie scattered over the rank range; this loop is
      // short, so they are asked for well ahead.
      if (j + 24 < n) __builtin_prefetch(&rec[ranks[j + 24]]);
#endif
      for (int w = 0; w < words; ++w)
        chunk_bits[std::size_t(j) * std::size_t(words) + std::size_t(w)] = boxes.meets(rec[ranks[j]], w);
    }
    found = end;
  };

  constexpr int C = kChunksTogether;
  for (int k0 = 0; k0 < L.chunks; k0 += C) {
    // Chunks past the tile's last are clones of it, never live and never stored.
    Chunk c[C] = {Chunk(std::min(k0, L.chunks - 1), L, fx0, fy0, g), Chunk(std::min(k0 + 1, L.chunks - 1), L, fx0, fy0, g),
                  Chunk(std::min(k0 + 2, L.chunks - 1), L, fx0, fy0, g), Chunk(std::min(k0 + 3, L.chunks - 1), L, fx0, fy0, g)};
    static_assert(C == 4, "rasterize_tile: the chunks are listed out below");
    for (int i = 0; i < C; ++i)
      if (k0 + i >= L.chunks) c[i].live = false;
    // The four chunks' bits (C divides 64, so they share a word).
    const int shift = k0 % 64;
    for (int j = 0; j < n; ++j) {
      if (j == found) find_bits();
      const unsigned bits = unsigned(chunk_bits[std::size_t(j) * std::size_t(words) + std::size_t(k0 / 64)] >> shift) & 15u;
      if (bits == 0) continue;
      const SplatRecord<Scalar>& G = rec[ranks[j]];
      // Written out: a loop over the four was measurably slower.
      if ((bits & 1u) && c[0].live) c[0].blend(G, j);
      if ((bits & 2u) && c[1].live) c[1].blend(G, j);
      if ((bits & 4u) && c[2].live) c[2].blend(G, j);
      if ((bits & 8u) && c[3].live) c[3].blend(G, j);
      if (!(c[0].live || c[1].live || c[2].live || c[3].live)) break;
    }
    for (int i = 0; i < C; ++i)
      if (k0 + i < L.chunks) c[i].store(k0 + i, L, tx0, ty0, g, params, out, evaluated, contributions);
  }
  evaluated_out += evaluated;
  contributions_out += contributions;
}

}  // namespace detail

// Forward rasterization with batch type B (simd::native_batch<Scalar> by
// default; simd::scalar_batch<Scalar> for the scalar kernel).
template <class B, class Scalar>
void rasterize_with(const BinWorkspace<Scalar>& bins, const RasterParams<Scalar>& params, RasterOutput<Scalar>& out,
                    RasterWorkspace<Scalar>& ws) {
  static_assert(std::is_same<typename B::value_type, Scalar>::value, "rasterize_with: batch of the wrong precision");
  const auto t0 = std::chrono::steady_clock::now();
  const TileGrid& g = bins.grid;
  ensure(g.tile_count() > 0, "rasterize: the bins are empty (call bin_splats first)");
  ensure(g.width < (1 << 23) && g.height < (1 << 23), "rasterize: image too large");
  detail::prepare_raster_output(g, out);
  ws.lanes.build(g.tile_size, int(B::size));
  const int threads = resolve_threads(params.threads);
  ws.worker_stats.assign(std::size_t(threads), {});
  ws.worker_chunk_bits.resize(std::size_t(threads));
  parallel_for(std::size_t(g.tile_count()), threads, [&](std::size_t t, int w) {
    auto& st = ws.worker_stats[std::size_t(w)];
    detail::rasterize_tile<B>(int(t), bins, ws.lanes, params, out, st.evaluated, st.contributions,
                              ws.worker_chunk_bits[std::size_t(w)]);
  });
  out.stats = {};
  for (const auto& st : ws.worker_stats) {
    out.stats.pairs_evaluated += st.evaluated;
    out.stats.contributions += st.contributions;
  }
  out.stats.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

template <class Scalar>
void rasterize(const BinWorkspace<Scalar>& bins, const RasterParams<Scalar>& params, RasterOutput<Scalar>& out,
               RasterWorkspace<Scalar>& ws) {
  rasterize_with<simd::native_batch<Scalar>>(bins, params, out, ws);
}

}  // namespace orbitforge

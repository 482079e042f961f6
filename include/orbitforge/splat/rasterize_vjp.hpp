#pragma once
// The VJP of rasterize() (its backward pass): from dL/d(colour) [H][W][3] and optionally
// dL/d(alpha) [H][W][1] (alpha = 1 - final T) and dL/d(depth) [H][W][1], the
// gradients w.r.t. every ProjectedSplats field (and the background colour).
//
// Each tile is replayed back to front from the forward's saved final T and
// replay count (3DGS style): T_before = T_after / (1 - alpha), with alpha
// recomputed by exactly the forward's arithmetic (same exp path) and the same
// skip rules. Per pixel two running values suffice:
//   T   transmittance in front of the current Gaussian
//   acc = sum over later Gaussians k of w_k (v_c . c_k + v_d z_k)
//         + T_final (v_c . background) - v_alpha T_final
// so that dL/d(alpha_i) = T_i (v_c . c_i + v_d z_i) - acc / (1 - alpha_i).
// Where the forward clamped alpha at 0.99, d alpha / d(opacity exp(power)) = 0:
// no opacity, conic or mean gradient (colour and depth still get w_i).
//
// Determinism: each tile writes its per-Gaussian sums into its own slots of a
// per-(tile, Gaussian) buffer (laid out Gaussian-major, see BinWorkspace); the
// slots are added up in tile order afterwards.
// Results therefore do not depend on the thread count or scheduling.
// A tile writes only the slots of entries some pixel replays (a prefix of its
// list) and records where that prefix ends as a rank; the sum skips the rest.
// Zeroing the dead entries instead cost a scattered cache-line write each, 13%
// of the backward kernel at 896x512 with 300k Gaussians.
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <limits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/bin.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/rasterize.hpp"

namespace orbitforge {

template <class Scalar>
struct RasterGradOutput {
  ProjectedSplatsGrad<Scalar> splats;       // [N] per input Gaussian (zero for culled)
  std::array<Scalar, 3> v_background{{0, 0, 0}};  // zero unless RasterParams::background_gradient
  double ms = 0;
};

namespace detail {

template <class T> struct identity { using type = T; };
template <class T> using identity_t = typename identity<T>::type;  // blocks deduction (lets callers pass nullptr)

// Asks for the cache lines of a[first .. last] to be read soon (a hint; nothing
// without GCC or Clang). Prefetching the forward's output rows for writing the
// same way made the forward ~10 % slower, so only the backward does this.
template <class T>
inline void prefetch_span(const T* a, std::size_t first, std::size_t last) {
#if defined(__GNUC__)
  constexpr std::size_t step = 64 / sizeof(T) > 0 ? 64 / sizeof(T) : 1;
  for (std::size_t i = first; i < last; i += step) __builtin_prefetch(a + i);
  __builtin_prefetch(a + last);
#else
  (void)a;
  (void)first;
  (void)last;
#endif
}

inline int lowest_bit(std::uint64_t bits) {
#if defined(__GNUC__) || defined(__clang__)
  return __builtin_ctzll(bits);
#else
  int k = 0;
  while (!((bits >> k) & 1u)) ++k;
  return k;
#endif
}

enum : int { kGradOpacity, kGradA, kGradB, kGradC, kGradMx, kGradMy, kGradR, kGradG, kGradBl, kGradZ, kGradFields };

// Depth: v_depth is given (training has no depth term: its loads and sums are skipped).
template <class B, bool Depth, class Scalar>
void rasterize_vjp_tile(int t, const BinWorkspace<Scalar>& bins, const TileLanes<Scalar>& L,
                             const RasterParams<Scalar>& params, const RasterOutput<Scalar>& fwd,
                             const Image<Scalar>& v_color, const Image<Scalar>* v_alpha, const Image<Scalar>* v_depth,
                             Scalar* scratch, Scalar* pair_grad, std::int32_t& live_rank_end,
                             Scalar* v_background) {
  using M = simd::mask_t<B>;
  using Rules = RasterRules<Scalar>;
  constexpr std::size_t N = B::size;
  const TileGrid& g = bins.grid;
  const int tx0 = g.tile_x0(t), ty0 = g.tile_y0(t);
  const Scalar fx0 = Scalar(tx0), fy0 = Scalar(ty0);
  const std::size_t off = bins.tile_offsets[std::size_t(t)];
  const std::int32_t* ranks = bins.tile_ranks.data() + off;
  const int n = int(bins.tile_offsets[std::size_t(t) + 1] - off);
  const SplatRecord<Scalar>* rec = bins.records.data();
  const std::size_t lanes = std::size_t(L.chunks) * N;

  // v_background (3 values): this tile's share of dL/d(background) = sum over
  // its pixels of v_colour T_final, in pixel order.
  Scalar share[3] = {0, 0, 0};
  const bool background = params.background_gradient;
  auto add_background = [&](std::size_t pi, Scalar T) {
    if (background)
      for (std::size_t c = 0; c < 3; ++c) share[c] += v_color.data[3 * pi + c] * T;
  };
  if (n == 0) {  // no Gaussian here: only the background's share
    if (background)
      tile_row_spans(g, tx0, ty0, [&](std::size_t first, std::size_t last) {
        for (std::size_t pi = first; pi <= last; ++pi) add_background(pi, fwd.transmittance.data[pi]);
      });
    std::copy(share, share + 3, v_background);
    live_rank_end = std::numeric_limits<std::int32_t>::max();
    return;
  }

  // Per-lane state, tile-local: T, acc, replay count, v_r, v_g, v_b, v_d.
  Scalar* sT = scratch;
  Scalar* sAcc = sT + lanes;
  Scalar* sRep = sAcc + lanes;
  Scalar* sVr = sRep + lanes;
  Scalar* sVg = sVr + lanes;
  Scalar* sVb = sVg + lanes;
  Scalar* sVd = sVb + lanes;
  Scalar* chunk_max = sVd + lanes;  // [padded_chunks(), 0 past the last] largest replay count of the chunk
  std::fill_n(chunk_max, L.padded_chunks(), Scalar(0));
  const ChunkBoxes<B, Scalar> boxes(L, fx0, fy0);
  // The tile's rows of T, replay count and v_colour lie a frame row apart and
  // miss the cache: asked for all at once, the misses overlap instead of
  // stalling the loop below one by one (about a tenth of this kernel at 896x512).
  tile_row_spans(g, tx0, ty0, [&](std::size_t first, std::size_t last) {
    prefetch_span(fwd.transmittance.data.data(), first, last);
    prefetch_span(fwd.replay.data(), first, last);
    prefetch_span(v_color.data.data(), 3 * first, 3 * last + 2);
  });
  int tile_max = 0;
  for (int k = 0; k < L.chunks; ++k) {
    int cmax = 0;
    for (std::size_t l = 0; l < N; ++l) {
      const std::size_t li = std::size_t(k) * N + l;
      const int p = L.pixel[li];
      const int x = p < 0 ? g.width : tx0 + L.col[li], y = p < 0 ? g.height : ty0 + L.row[li];
      if (p < 0 || x >= g.width || y >= g.height) {
        sT[li] = sAcc[li] = sRep[li] = sVr[li] = sVg[li] = sVb[li] = sVd[li] = Scalar(0);
        continue;
      }
      const std::size_t pi = std::size_t(y) * std::size_t(g.width) + std::size_t(x);
      const Scalar T = fwd.transmittance.data[pi];
      add_background(pi, T);
      const Scalar vr = v_color.data[3 * pi], vg = v_color.data[3 * pi + 1], vb = v_color.data[3 * pi + 2];
      const Scalar va = v_alpha ? v_alpha->data[pi] : Scalar(0);
      sT[li] = T;
      sVr[li] = vr; sVg[li] = vg; sVb[li] = vb;
      sVd[li] = v_depth ? v_depth->data[pi] : Scalar(0);
      // Colour sees T_final * background; alpha = 1 - T_final.
      sAcc[li] = T * (vr * params.background[0] + vg * params.background[1] + vb * params.background[2]) - va * T;
      const int rep = fwd.replay[pi];
      sRep[li] = Scalar(rep);
      cmax = std::max(cmax, rep);
    }
    chunk_max[k] = Scalar(cmax);
    tile_max = std::max(tile_max, cmax);
  }
  std::copy(share, share + 3, v_background);
  // Entries from tile_max on (ranks >= live_rank_end) are never replayed: their
  // slots are left unwritten and skipped by the sum.
  const int tile_col = t % g.tiles_x, tile_row = t / g.tiles_x;
  live_rank_end = tile_max < n ? ranks[tile_max] : std::numeric_limits<std::int32_t>::max();

  const B zero(Scalar(0)), one(Scalar(1));
  for (int j = tile_max - 1; j >= 0; --j) {
#if defined(__GNUC__)
    // The records of a tile are scattered over the whole rank range, and so
    // are their gradient slots: a slot written without its line in cache
    // stalls the stores behind it while the line is read, so its address
    // (from the box and offset fetched 8 entries earlier) is prefetched for
    // writing too.
    if (j >= 8) {
      __builtin_prefetch(&rec[ranks[j - 8]]);
      const Scalar* slot =
          pair_grad + std::size_t(bins.entry_slot(tile_col, tile_row, std::size_t(ranks[j - 8]))) * kGradFields;
      __builtin_prefetch(slot, 1);
      __builtin_prefetch(slot + kGradFields - 1, 1);
    }
    if (j >= 16) {
      __builtin_prefetch(&bins.rank_boxes[std::size_t(ranks[j - 16])]);
      __builtin_prefetch(&bins.rank_offsets[std::size_t(ranks[j - 16])]);
    }
#endif
    const SplatRecord<Scalar>& G = rec[ranks[j]];
    const B jj = B(Scalar(j));
    B g_o = zero, g_a = zero, g_b = zero, g_c = zero, g_mx = zero, g_my = zero;
    B g_r = zero, g_g = zero, g_bl = zero, g_z = zero;
    // Chunk k of the tile, which the rect meets and some lane of which replays
    // entry j; whole: the chunk lies inside the rect.
    auto replay_chunk = [&](int k, bool whole) {
      const std::size_t base = std::size_t(k) * N;
      const B px = B::load_unaligned(L.ox.data() + base) + B(fx0);
      const B py = B::load_unaligned(L.oy.data() + base) + B(fy0);
      const M replayed = jj < B::load_unaligned(sRep + base);
      // Per-lane rect tests only for chunks the rect cuts.
      const M inside = whole ? replayed
                             : replayed & (px > B(G.x_lo)) & (px < B(G.x_hi)) & (py > B(G.y_lo)) & (py < B(G.y_hi));
      // Same arithmetic as the forward, so alpha (and the skip decisions) match bit for bit.
      const B dx = px - B(G.mean_x), dy = py - B(G.mean_y);
      const B p2 = simd::fma(B(G.pxx) * dx, dx, simd::fma(B(G.pxy) * dx, dy, B(G.pyy) * dy * dy));
      if (!simd::any(inside & (p2 >= B(G.min_power)))) return;  // no lane reaches alpha 1/255
      const B e = simd::exp2_nonpositive(p2);
      const B raw = B(G.opacity) * e;
      const B alpha = simd::min(B(Rules::max_alpha()), raw);
      const M m = inside & (p2 <= zero) & (alpha >= B(Rules::min_alpha()));
      if (!simd::any(m)) return;

      const B T_after = B::load_unaligned(sT + base);
      const B acc = B::load_unaligned(sAcc + base);
      const B vr = B::load_unaligned(sVr + base), vg = B::load_unaligned(sVg + base);
      const B vb = B::load_unaligned(sVb + base);
      const B inv_one_minus = one / (one - alpha);
      const B T = T_after * inv_one_minus;  // transmittance in front of this Gaussian
      const B w = alpha * T;
      // v . (colour, depth) of this Gaussian as seen by the pixel
      B vd = zero, vc = vb * B(G.color_b);
      if constexpr (Depth) {
        vd = B::load_unaligned(sVd + base);
        vc = simd::fma(vb, B(G.color_b), vd * B(G.depth));
      }
      vc = simd::fma(vr, B(G.color_r), simd::fma(vg, B(G.color_g), vc));
      const B v_alpha_i = simd::fma(T, vc, -(acc * inv_one_minus));
      simd::select(m, T, T_after).store_unaligned(sT + base);
      simd::select(m, simd::fma(w, vc, acc), acc).store_unaligned(sAcc + base);

      const B wm = simd::select(m, w, zero);
      g_r = simd::fma(wm, vr, g_r);
      g_g = simd::fma(wm, vg, g_g);
      g_bl = simd::fma(wm, vb, g_bl);
      if constexpr (Depth) g_z = simd::fma(wm, vd, g_z);
      // Through alpha = opacity exp(power) where it was not clamped.
      const B va = simd::select(m & (raw <= B(Rules::max_alpha())), v_alpha_i, zero);
      g_o = simd::fma(va, e, g_o);
      const B v_power = va * alpha;  // d alpha / d power = opacity exp(power) = alpha
      g_a = simd::fma(v_power, dx * dx, g_a);
      g_b = simd::fma(v_power, dx * dy, g_b);
      g_c = simd::fma(v_power, dy * dy, g_c);
      // The mean's gradient is linear in (dx, dy) with per-Gaussian
      // coefficients: sum v_power dx and v_power dy, combine after the lane sums.
      g_mx = simd::fma(v_power, dx, g_mx);
      g_my = simd::fma(v_power, dy, g_my);
    };
    // The chunks that the rect meets and that replay entry j (a lane's replay
    // count is above j), in ascending order.
    for (int w = 0; w < boxes.words; ++w) {
      std::uint64_t bits = boxes.meets(G, w) & boxes.over_word(w, [&](std::size_t o) {
        return jj < B::load_unaligned(chunk_max + o);
      });
      if (bits == 0) continue;
      const std::uint64_t within = boxes.within(G, w);
      for (; bits != 0; bits &= bits - 1) {
        const int k = lowest_bit(bits);
        replay_chunk(64 * w + k, (within >> k) & 1u);
      }
    }
    // The conic's power factors (-1/2, -1, -1/2) are applied once per vector.
    const B rows[kGradFields] = {g_o, B(Scalar(-0.5)) * g_a, -g_b, B(Scalar(-0.5)) * g_c, g_mx, g_my, g_r, g_g, g_bl, g_z};
    Scalar* out = pair_grad + std::size_t(bins.entry_slot(tile_col, tile_row, std::size_t(ranks[j]))) * kGradFields;
    simd::hadd_rows(rows, kGradFields, out);
    // d power / d mean = -(d power / d (dx, dy)) = -ln 2 (d p2 / d (dx, dy)),
    // d p2 / d dx = 2 pxx dx + pxy dy, d p2 / d dy = pxy dx + 2 pyy dy.
    const Scalar sx = out[kGradMx], sy = out[kGradMy], neg_ln2 = Scalar(-0.69314718055994530942);
    out[kGradMx] = neg_ln2 * (Scalar(2) * G.pxx * sx + G.pxy * sy);
    out[kGradMy] = neg_ln2 * (G.pxy * sx + Scalar(2) * G.pyy * sy);
  }
}

}  // namespace detail

// bins, params and fwd must be those of the forward pass being differentiated.
// v_alpha and v_depth may be null (no loss term on them).
template <class B, class Scalar>
void rasterize_vjp_with(const BinWorkspace<Scalar>& bins, const RasterParams<Scalar>& params,
                             const RasterOutput<Scalar>& fwd, const Image<Scalar>& v_color,
                             const detail::identity_t<Image<Scalar>>* v_alpha,
                             const detail::identity_t<Image<Scalar>>* v_depth, std::size_t n_splats,
                             RasterGradOutput<Scalar>& out, RasterWorkspace<Scalar>& ws) {
  static_assert(std::is_same<typename B::value_type, Scalar>::value, "rasterize_vjp: batch of the wrong precision");
  const auto t0 = std::chrono::steady_clock::now();
  const TileGrid& g = bins.grid;
  ensure(fwd.color.width == g.width && fwd.color.height == g.height && fwd.replay.size() == g.pixel_count(),
         "rasterize_vjp: the forward output does not match the bins (", fwd.color.width, "x", fwd.color.height,
         " vs ", g.width, "x", g.height, ")");
  ensure(v_color.width == g.width && v_color.height == g.height && v_color.channels == 3,
         "rasterize_vjp: v_color is ", v_color.width, "x", v_color.height, "x", v_color.channels, ", expected ",
         g.width, "x", g.height, "x3");
  for (const Image<Scalar>* v : {v_alpha, v_depth})
    ensure(!v || (v->width == g.width && v->height == g.height && v->channels == 1),
           "rasterize_vjp: v_alpha / v_depth must be ", g.width, "x", g.height, "x1");
  for (std::size_t r = 0; r < bins.order.size(); ++r)
    ensure(std::size_t(bins.order[r]) < n_splats, "rasterize_vjp: n_splats (", n_splats, ") is smaller than the binned set");

  ws.lanes.build(g.tile_size, int(B::size));
  const int threads = resolve_threads(params.threads);
  const std::size_t lanes = std::size_t(ws.lanes.chunks) * B::size;
  ws.worker_scratch.resize(std::size_t(threads));
  for (auto& s : ws.worker_scratch) s.resize(7 * lanes + ws.lanes.padded_chunks());
  check_memory_request(std::uint64_t(bins.slots()) * detail::kGradFields * sizeof(Scalar),
                       "rasterize_vjp: the per-entry gradients of ", bins.slots(), " tile-box slots");
  ws.pair_grad.resize(bins.slots() * detail::kGradFields);
  ws.live_rank_end.resize(std::size_t(g.tile_count()));
  ws.tile_background.resize(3 * std::size_t(g.tile_count()));

  auto run = [&](auto depth) {
    parallel_for(std::size_t(g.tile_count()), threads, [&](std::size_t t, int w) {
      detail::rasterize_vjp_tile<B, decltype(depth)::value>(int(t), bins, ws.lanes, params, fwd, v_color, v_alpha,
                                                                 v_depth, ws.worker_scratch[std::size_t(w)].data(),
                                                                 ws.pair_grad.data(), ws.live_rank_end[t],
                                                                 ws.tile_background.data() + 3 * t);
    });
  };
  if (v_depth) run(std::true_type{});
  else run(std::false_type{});

  // Sum each Gaussian's per-tile slots (stored rank-major, in tile order:
  // deterministic), streaming through pair_grad; ranks split across workers.
  // Rank r's slots are the tiles of its tile box in row-major order (bin_splats);
  // only those of the tiles that list it are written.
  const std::size_t visible = bins.visible();
  constexpr std::size_t F = detail::kGradFields;
  ProjectedSplatsGrad<Scalar>& gr = out.splats;
  gr.assign_zero(n_splats);
  Scalar* fields[F] = {gr.v_opacity.data(), gr.v_conic_a.data(), gr.v_conic_b.data(), gr.v_conic_c.data(),
                       gr.v_mean_x.data(),  gr.v_mean_y.data(),  gr.v_color_r.data(), gr.v_color_g.data(),
                       gr.v_color_b.data(), gr.v_depth.data()};
  const std::size_t blocks = std::min<std::size_t>(std::size_t(threads) * 4, std::max<std::size_t>(1, visible));
  parallel_for(blocks, threads, [&](std::size_t b, int) {
    const std::size_t lo = visible * b / blocks, hi = visible * (b + 1) / blocks;
    const Scalar* pg = ws.pair_grad.data();
    for (std::size_t r = lo; r < hi; ++r) {
      Scalar sum[F] = {};
      bins.for_each_listed_tile(r, [&](int tx, int ty, std::uint32_t k) {
        if (std::int32_t(r) >= ws.live_rank_end[std::size_t(ty) * std::size_t(g.tiles_x) + std::size_t(tx)]) return;
        for (std::size_t f = 0; f < F; ++f) sum[f] += pg[std::size_t(k) * F + f];
      });
      const std::size_t i = std::size_t(bins.order[r]);
      for (std::size_t f = 0; f < F; ++f) fields[f][i] = sum[f];
    }
  });
  // Background: colour = ... + T_final background; the tiles' shares in tile
  // order (this was a serial pass over every pixel).
  out.v_background = {{0, 0, 0}};
  for (std::size_t t = 0; t < std::size_t(g.tile_count()); ++t)
    for (std::size_t c = 0; c < 3; ++c) out.v_background[c] += ws.tile_background[3 * t + c];
  out.ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t0).count();
}

template <class Scalar>
void rasterize_vjp(const BinWorkspace<Scalar>& bins, const RasterParams<Scalar>& params,
                        const RasterOutput<Scalar>& fwd, const Image<Scalar>& v_color,
                        const detail::identity_t<Image<Scalar>>* v_alpha,
                        const detail::identity_t<Image<Scalar>>* v_depth, std::size_t n_splats, RasterGradOutput<Scalar>& out,
                        RasterWorkspace<Scalar>& ws) {
  rasterize_vjp_with<simd::native_batch<Scalar>>(bins, params, fwd, v_color, v_alpha, v_depth, n_splats, out, ws);
}

}  // namespace orbitforge

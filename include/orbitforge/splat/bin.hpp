#pragma once
// Tile binning: one global depth sort of the visible Gaussians per frame, then
// per-tile lists of those Gaussians in depth order.
//
//   visible   radius > 0 and a non-empty rect (ProjectedSplats' inclusive pixel
//             rectangle, already clipped to the image)
//   order     rank -> Gaussian index, sorted by (depth, index): a stable LSD
//             radix sort on the depth bits (parts sorted on their own threads,
//             then merged), so equal depths keep index order and the result is
//             the same for any thread count
//   records   the visible Gaussians packed in rank order, one cache line each
//             (float), so a tile streams through contiguous memory
//   tiles     tile t's list is tile_ranks[tile_offsets[t] .. tile_offsets[t+1]),
//             ascending rank = front to back; a Gaussian is listed in the
//             tiles of its rect that its alpha >= 1/255 ellipse reaches
//             (detail::TileRowSpans: per row of tiles, so a tilted or long
//             ellipse is not listed in its box's corners)
//
// Built with a counting pass and a prefix sum into caller-owned buffers that are
// reused across frames: no allocation once the workspace has grown. The counting
// and filling passes run on `threads` threads (same result for any count).
#include <algorithm>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <limits>
#include <type_traits>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/limits.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/splat_record.hpp"
#include "orbitforge/splat/tile_rows.hpp"

namespace orbitforge {

struct TileGrid {
  int width = 0, height = 0, tile_size = 16;
  int tiles_x = 0, tiles_y = 0;

  TileGrid() = default;
  TileGrid(int w, int h, int ts) : width(w), height(h), tile_size(ts) {
    ensure(w > 0 && h > 0, "TileGrid: image size must be positive, got ", w, "x", h);
    ensure(ts > 0 && ts <= 256, "TileGrid: tile size must be in 1..256, got ", ts);
    tiles_x = (w + ts - 1) / ts;
    tiles_y = (h + ts - 1) / ts;
  }
  int tile_count() const { return tiles_x * tiles_y; }
  std::size_t pixel_count() const { return std::size_t(width) * std::size_t(height); }
  int tile_x0(int t) const { return (t % tiles_x) * tile_size; }
  int tile_y0(int t) const { return (t / tiles_x) * tile_size; }
};

template <class Scalar>
struct BinWorkspace {
  TileGrid grid;
  std::vector<std::int32_t> order;             // [V] rank -> Gaussian index
  std::vector<SplatRecord<Scalar>> records;    // [V] rank order
  std::vector<std::uint32_t> tile_offsets;     // [tiles + 1]
  std::vector<std::int32_t> tile_ranks;        // [pairs] ranks, per tile front to back
  // The same entries in rank-major order (rank r's tiles, ascending tile index):
  // rank r owns slots [rank_offsets[r], rank_offsets[r+1]), the tiles of its
  // tile box in row-major order (entry_slot), whether or not its ellipse
  // reaches them (detail::TileRowSpans says which are listed). The backward
  // pass writes per-entry gradients there so that summing them per Gaussian
  // streams through memory.
  std::vector<std::uint32_t> rank_offsets;     // [visible + 1]
  // [V] rank r's tile box (tile x0, y0, x1, y1; Gaussian index).
  std::vector<std::array<std::int32_t, 5>> rank_boxes;
  // [V] which tiles of rank r's box list it (detail::encode_row_trims).
  std::vector<std::uint64_t> rank_trims;
  // Timings of the last bin_splats call.
  double sort_ms = 0, bin_ms = 0;

  std::size_t visible() const { return order.size(); }
  std::size_t pairs() const { return tile_ranks.size(); }
  // Rank-major slots: every tile of every box, listed or not (>= pairs()).
  std::size_t slots() const { return rank_offsets.empty() ? 0 : std::size_t(rank_offsets.back()); }
  // The rank-major slot of rank r's entry in tile (tx, ty), a tile of its box.
  // Computed where it is needed (the backward) rather than stored per entry: a
  // second per-tile stream of writes made the fill pass of binning slower.
  std::uint32_t entry_slot(int tx, int ty, std::size_t r) const {
    const auto& b = rank_boxes[r];
    return rank_offsets[r] + std::uint32_t((ty - b[1]) * (b[2] - b[0] + 1) + (tx - b[0]));
  }
  // Calls f(ty, tx0, tx1, row_slot) for each row of tiles of rank r's box that
  // lists it in tiles tx0 .. tx1 (inclusive, tx0 <= tx1); row_slot is the slot
  // of the row's first box tile (tile tx's slot: row_slot + tx - box x0).
  template <class F>
  void for_each_listed_row(std::size_t r, F&& f) const {
    const auto& b = rank_boxes[r];
    const std::uint64_t trims = rank_trims[r];
    const std::uint32_t box_w = std::uint32_t(b[2] - b[0] + 1);
    std::uint32_t row_slot = rank_offsets[r];
    if (trims == 0) {
      for (int ty = b[1]; ty <= b[3]; ++ty, row_slot += box_w) f(ty, b[0], b[2], row_slot);
    } else if (trims == detail::kTrimsRecompute) {
      const detail::TileRowSpans spans(records[r], grid.tile_size);
      for (int ty = b[1]; ty <= b[3]; ++ty, row_slot += box_w) {
        const auto [tx0, tx1] = spans.row(ty, b[0], b[2]);
        if (tx0 <= tx1) f(ty, tx0, tx1, row_slot);
      }
    } else {
      for (int ty = b[1], i = 0; ty <= b[3]; ++ty, ++i, row_slot += box_w) {
        const int tx0 = b[0] + int((trims >> (8 * i)) & 15u), tx1 = b[2] - int((trims >> (8 * i + 4)) & 15u);
        if (tx0 <= tx1) f(ty, tx0, tx1, row_slot);
      }
    }
  }
  // Calls f(tx, ty, slot) for each tile that lists rank r, row by row.
  template <class F>
  void for_each_listed_tile(std::size_t r, F&& f) const {
    const int x0 = rank_boxes[r][0];
    for_each_listed_row(r, [&](int ty, int tx0, int tx1, std::uint32_t row_slot) {
      for (int tx = tx0; tx <= tx1; ++tx) f(tx, ty, row_slot + std::uint32_t(tx - x0));
    });
  }

  // Sort scratch (kept so that frames after the first do not allocate).
  using Key = detail::scalar_bits_t<Scalar>;
  std::vector<Key> keys_, keys_tmp_;
  std::vector<std::int32_t> perm_, idx_tmp_;
  std::vector<SplatRecord<Scalar>> packed_;
  std::vector<std::uint64_t> packed_trims_;
  std::vector<std::uint32_t> chunk_counts_;  // [chunks][tiles] counts, then cursors
  std::vector<std::int32_t> chunk_diffs_;    // [chunks][tiles_y][tiles_x + 1] row differences of the counts
  std::vector<std::uint64_t> chunk_entries_; // [chunks + 1] rank-major entry offsets
};

namespace detail {

// Order-preserving map from an IEEE float to an unsigned key (negative values
// flip all bits, positive ones only the sign bit).
template <class Key, class Scalar>
inline Key sortable_key(Scalar v) {
  Key bits;
  std::memcpy(&bits, &v, sizeof(Key));
  const Key sign = Key(1) << (8 * sizeof(Key) - 1);
  return (bits & sign) ? Key(~bits) : Key(bits | sign);
}

// Stable LSD radix sort of idx by key, 8 bits per pass, over n entries of caller
// arrays with n entries of scratch each; passes whose digit is the same for
// every key are skipped (depths of a scene share their high bits). Returns true
// when the sorted result ended in the scratch arrays.
template <class Key>
bool radix_sort_stable(Key* keys, std::int32_t* idx, Key* keys_tmp, std::int32_t* idx_tmp, std::size_t n) {
  constexpr int passes = int(sizeof(Key));
  std::uint32_t hist[passes][256];
  std::memset(hist, 0, sizeof(hist));
  for (std::size_t i = 0; i < n; ++i)
    for (int p = 0; p < passes; ++p) ++hist[p][(keys[i] >> (8 * p)) & 0xFF];
  bool in_scratch = false;
  for (int p = 0; p < passes; ++p) {
    const int shift = 8 * p;
    if (n == 0 || hist[p][(keys[0] >> shift) & 0xFF] == n) continue;  // one bucket: no-op pass
    std::uint32_t sum = 0;
    for (int b = 0; b < 256; ++b) {
      const std::uint32_t c = hist[p][b];
      hist[p][b] = sum;
      sum += c;
    }
    for (std::size_t i = 0; i < n; ++i) {
      const std::uint32_t dst = hist[p][(keys[i] >> shift) & 0xFF]++;
      keys_tmp[dst] = keys[i];
      idx_tmp[dst] = idx[i];
    }
    std::swap(keys, keys_tmp);
    std::swap(idx, idx_tmp);
    in_scratch = !in_scratch;
  }
  return in_scratch;
}

template <class Key>
void radix_sort_stable(std::vector<Key>& keys, std::vector<std::int32_t>& idx, std::vector<Key>& keys_tmp,
                       std::vector<std::int32_t>& idx_tmp) {
  const std::size_t n = keys.size();
  keys_tmp.resize(n);
  idx_tmp.resize(n);
  if (radix_sort_stable(keys.data(), idx.data(), keys_tmp.data(), idx_tmp.data(), n)) {
    keys.swap(keys_tmp);
    idx.swap(idx_tmp);
  }
}

// How many of a's m keys are among the first d of the stable merge of a and b
// (a's entries first on equal keys): the merge-path split, by bisection.
template <class Key>
std::size_t merge_path_split(const Key* a, std::size_t m, const Key* b, std::size_t n, std::size_t d) {
  std::size_t lo = d > n ? d - n : 0, hi = std::min(d, m);
  while (lo < hi) {
    const std::size_t mid = lo + (hi - lo) / 2;
    if (a[mid] <= b[d - 1 - mid]) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

// The same order as radix_sort_stable, on `threads` threads: contiguous parts
// are sorted on their own, then merged pairwise, each merge cut into pieces at
// merge-path splits so that every thread writes its own output range. A stable
// sort of each part followed by stable merges (the left part first on ties) is
// the stable sort of the whole, so the result does not depend on the thread
// count. One synchronisation per merge round, not per digit: a block-parallel
// LSD sort (per-block digit counts each pass) was slower on two cores.
template <class Key>
void radix_sort_stable_parallel(std::vector<Key>& keys, std::vector<std::int32_t>& idx, std::vector<Key>& keys_tmp,
                                std::vector<std::int32_t>& idx_tmp, int threads) {
  constexpr std::size_t min_part = 16384;  // below this a part's sort is too short to pay for a thread
  const std::size_t n = keys.size();
  const std::size_t parts = std::min<std::size_t>(std::size_t(std::max(1, threads)), n / min_part);
  if (parts < 2) {
    radix_sort_stable(keys, idx, keys_tmp, idx_tmp);
    return;
  }
  keys_tmp.resize(n);
  idx_tmp.resize(n);
  std::vector<std::size_t> bounds(parts + 1);
  for (std::size_t p = 0; p <= parts; ++p) bounds[p] = n * p / parts;
  parallel_for(parts, threads, [&](std::size_t p, int) {
    const std::size_t b = bounds[p], len = bounds[p + 1] - b;
    if (radix_sort_stable(keys.data() + b, idx.data() + b, keys_tmp.data() + b, idx_tmp.data() + b, len)) {
      std::copy_n(keys_tmp.data() + b, len, keys.data() + b);
      std::copy_n(idx_tmp.data() + b, len, idx.data() + b);
    }
  });
  while (bounds.size() > 2) {
    const std::size_t runs = bounds.size() - 1, pairs = runs / 2;
    const std::size_t pieces = std::max<std::size_t>(1, std::size_t(std::max(1, threads)) / pairs);
    // Items: pieces of each pair's merge, then (odd run count) the last run copied through.
    const std::size_t items = pairs * pieces + (runs % 2);
    parallel_for(items, threads, [&](std::size_t item, int) {
      if (item == pairs * pieces) {
        const std::size_t b = bounds[runs - 1], len = bounds[runs] - b;
        std::copy_n(keys.data() + b, len, keys_tmp.data() + b);
        std::copy_n(idx.data() + b, len, idx_tmp.data() + b);
        return;
      }
      const std::size_t pair = item / pieces, piece = item % pieces;
      const std::size_t a0 = bounds[2 * pair], b0 = bounds[2 * pair + 1], e = bounds[2 * pair + 2];
      const Key* ka = keys.data() + a0;
      const Key* kb = keys.data() + b0;
      const std::int32_t* ia = idx.data() + a0;
      const std::int32_t* ib = idx.data() + b0;
      const std::size_t m = b0 - a0, len_b = e - b0, total = e - a0;
      const std::size_t d0 = total * piece / pieces, d1 = total * (piece + 1) / pieces;
      std::size_t i = merge_path_split(ka, m, kb, len_b, d0), j = d0 - i;
      Key* ko = keys_tmp.data() + a0;
      std::int32_t* io = idx_tmp.data() + a0;
      for (std::size_t d = d0; d < d1; ++d) {
        if (j >= len_b || (i < m && ka[i] <= kb[j])) {
          ko[d] = ka[i];
          io[d] = ia[i++];
        } else {
          ko[d] = kb[j];
          io[d] = ib[j++];
        }
      }
    });
    keys.swap(keys_tmp);
    idx.swap(idx_tmp);
    std::vector<std::size_t> merged;
    for (std::size_t r = 0; r <= runs; r += 2) merged.push_back(bounds[r]);
    if (merged.back() != n) merged.push_back(n);
    bounds.swap(merged);
  }
}

// Gaussian i of s as the rasterizer's record: its fields, base-2 conic,
// pixel-centre bounds, power floor and index.
template <class Scalar>
inline void pack_record(const ProjectedSplats<Scalar>& s, std::size_t i, SplatRecord<Scalar>& rec) {
  rec.mean_x = s.mean_x[i]; rec.mean_y = s.mean_y[i];
  rec.pxx = kConicDiagToPower<Scalar> * s.conic_a[i];
  rec.pxy = kConicCrossToPower<Scalar> * s.conic_b[i];
  rec.pyy = kConicDiagToPower<Scalar> * s.conic_c[i];
  rec.opacity = s.opacity[i];
  rec.color_r = s.color_r[i]; rec.color_g = s.color_g[i]; rec.color_b = s.color_b[i];
  rec.depth = s.depth[i];
  rec.x_lo = Scalar(s.rect_x0[i]); rec.x_hi = Scalar(s.rect_x1[i] + 1);
  rec.y_lo = Scalar(s.rect_y0[i]); rec.y_hi = Scalar(s.rect_y1[i] + 1);
  rec.min_power = alpha_power_floor(rec.opacity);
  set_record_index(rec, std::int32_t(i));
}

// The records of Gaussians i .. i + B::size - 1 as lanes, rows[f * B::size +
// lane] the lane's field f in SplatRecord's order, when each of them is visible,
// inside the width x height image, finite, and of an opacity whose power floor
// comes from its bits (nearly every batch of a frame); else false, and the
// caller packs them one at a time. The values are pack_record's, bit for bit.
template <class B, class Scalar>
bool pack_record_lanes(const ProjectedSplats<Scalar>& s, std::size_t i, int width, int height, Scalar* rows) {
  constexpr std::size_t N = B::size;
  static_assert(sizeof(SplatRecord<Scalar>) == 16 * sizeof(Scalar), "a record is 16 fields");
  bool ok = true;
  for (std::size_t l = 0; l < N; ++l) {
    const std::size_t g = i + l;
    const int x0 = s.rect_x0[g], y0 = s.rect_y0[g], x1 = s.rect_x1[g], y1 = s.rect_y1[g];
    ok &= s.radius[g] > 0 && x0 >= 0 && y0 >= 0 && x0 <= x1 && y0 <= y1 && x1 < width && y1 < height;
    rows[10 * N + l] = Scalar(x0);
    rows[11 * N + l] = Scalar(x1 + 1);
    rows[12 * N + l] = Scalar(y0);
    rows[13 * N + l] = Scalar(y1 + 1);
  }
  if (!ok) return false;
  const B ld[10] = {B::load_unaligned(&s.mean_x[i]),  B::load_unaligned(&s.mean_y[i]),
                    B::load_unaligned(&s.conic_a[i]), B::load_unaligned(&s.conic_b[i]),
                    B::load_unaligned(&s.conic_c[i]), B::load_unaligned(&s.opacity[i]),
                    B::load_unaligned(&s.color_r[i]), B::load_unaligned(&s.color_g[i]),
                    B::load_unaligned(&s.color_b[i]), B::load_unaligned(&s.depth[i])};
  const B fields[10] = {ld[0], ld[1], B(kConicDiagToPower<Scalar>) * ld[2], B(kConicCrossToPower<Scalar>) * ld[3],
                        B(kConicDiagToPower<Scalar>) * ld[4], ld[5], ld[6], ld[7], ld[8], ld[9]};
  const B zero(Scalar(0));
  B poison = zero;  // x * 0 is 0 for finite x, NaN otherwise (the scaled conic may overflow)
  for (const B& v : fields) poison = poison + v * zero;
  const B x = B(Scalar(255)) * ld[5];
  const auto normal = (x >= B(std::numeric_limits<Scalar>::min())) & (x <= B(std::numeric_limits<Scalar>::max()));
  if (!simd::all((poison == zero) & normal)) return false;
  for (int f = 0; f < 10; ++f) fields[f].store_unaligned(rows + std::size_t(f) * N);
  alpha_power_floor_lanes(ld[5]).store_unaligned(rows + 14 * N);
  for (std::size_t l = 0; l < N; ++l) {
    const std::int32_t index = std::int32_t(i + l);
    Scalar bits = Scalar(0);
    std::memcpy(&bits, &index, sizeof(index));
    rows[15 * N + l] = bits;
  }
  return true;
}

}  // namespace detail

// Fills ws for an image of width x height pixels and tiles of tile_size pixels.
// Throws orbitforge::Error when the splat arrays disagree in length or a visible
// splat has a non-finite field or a rect outside the image.
template <class Scalar>
void bin_splats(const ProjectedSplats<Scalar>& s, int width, int height, int tile_size, BinWorkspace<Scalar>& ws,
                int threads = 1) {
  using clock = std::chrono::steady_clock;
  const auto t0 = clock::now();
  const std::size_t n = s.size();
  for (const auto* v : {&s.mean_x, &s.mean_y, &s.conic_a, &s.conic_b, &s.conic_c, &s.opacity, &s.color_r,
                        &s.color_g, &s.color_b, &s.depth})
    ensure(v->size() == n, "bin_splats: a ProjectedSplats array has ", v->size(), " entries, radius has ", n);
  for (const auto* v : {&s.rect_x0, &s.rect_y0, &s.rect_x1, &s.rect_y1})
    ensure(v->size() == n, "bin_splats: a ProjectedSplats rect array has ", v->size(), " entries, radius has ", n);
  ensure(n < (std::size_t(1) << 31), "bin_splats: too many Gaussians (", n, ")");
  ws.grid = TileGrid(width, height, tile_size);
  const TileGrid& g = ws.grid;

  // Visible Gaussians are packed (in index order) with their sort keys; a
  // record carries its Gaussian's index and pixel bounds (its tile range), and
  // the sort then permutes whole records, so the input arrays are never read in
  // random order. Contiguous index chunks count their visible Gaussians,
  // then pack them at their prefix-sum offsets (same result for any thread count).
  using Key = typename BinWorkspace<Scalar>::Key;
  const int ts = g.tile_size;
  auto visible = [&s](std::size_t i) {
    return s.radius[i] > 0 && s.rect_x0[i] <= s.rect_x1[i] && s.rect_y0[i] <= s.rect_y1[i];
  };
  const std::size_t in_chunks = std::max<std::size_t>(1, std::min<std::size_t>(std::size_t(std::max(1, threads)), n / 8192));
  ws.chunk_entries_.assign(in_chunks + 1, 0u);
  parallel_for(in_chunks, threads, [&](std::size_t c, int) {
    std::uint64_t m = 0;
    for (std::size_t i = n * c / in_chunks, end = n * (c + 1) / in_chunks; i < end; ++i) m += visible(i) ? 1 : 0;
    ws.chunk_entries_[c + 1] = m;
  });
  for (std::size_t c = 0; c < in_chunks; ++c) ws.chunk_entries_[c + 1] += ws.chunk_entries_[c];
  const std::size_t packed = std::size_t(ws.chunk_entries_[in_chunks]);
  ws.keys_.resize(packed);
  ws.perm_.resize(packed);
  ws.packed_.resize(packed);
  ws.packed_trims_.resize(packed);
  parallel_for(in_chunks, threads, [&](std::size_t c, int) {
    using B = simd::native_batch<Scalar>;
    constexpr std::size_t N = B::size;
    alignas(64) Scalar rows[16 * N];
    std::size_t k = std::size_t(ws.chunk_entries_[c]), k_trimmed = k;
    auto trim = [&](std::size_t from, std::size_t to) {
      detail::encode_row_trims_lanes<B>(ws.packed_.data() + from, to - from, ts, ws.packed_trims_.data() + from);
      k_trimmed = to;
    };
    const std::size_t end = n * (c + 1) / in_chunks;
    for (std::size_t i = n * c / in_chunks; i < end;) {
      // A batch of lanes: the records and their trims from the same lanes,
      // then transposed into place.
      if (i + N <= end && detail::pack_record_lanes<B>(s, i, width, height, rows)) {
        if (k_trimmed < k) trim(k_trimmed, k);
        detail::encode_row_trims_fields<B>(rows, ts, ws.packed_trims_.data() + k);
        for (std::size_t f0 = 0; f0 < 16; f0 += N)
          simd::transpose_block<B>(rows + f0 * N, N, &ws.packed_[k].mean_x + f0, 16);
        for (std::size_t l = 0; l < N; ++l) {
          ws.perm_[k + l] = std::int32_t(k + l);
          ws.keys_[k + l] = detail::sortable_key<Key>(s.depth[i + l]);
        }
        k += N;
        k_trimmed = k;
        i += N;
        continue;
      }
      for (const std::size_t stop = std::min(end, i + N); i < stop; ++i) {
        if (!visible(i)) continue;
        const int x0 = s.rect_x0[i], y0 = s.rect_y0[i], x1 = s.rect_x1[i], y1 = s.rect_y1[i];
        ensure(x0 >= 0 && y0 >= 0 && x1 < width && y1 < height, "bin_splats: Gaussian ", i, " has rect [", x0, ",", x1,
               "]x[", y0, ",", y1, "] outside the ", width, "x", height, " image");
        SplatRecord<Scalar>& rec = ws.packed_[k];
        detail::pack_record(s, i, rec);
        bool finite = true;
        for (int f = 0; f < 10; ++f) finite = finite && std::isfinite((&rec.mean_x)[f]);
        ensure(finite, "bin_splats: visible Gaussian ", i, " has a non-finite field");
        ws.perm_[k] = std::int32_t(k);
        ws.keys_[k] = detail::sortable_key<Key>(rec.depth);
        ++k;
        // Which tiles of its box list each record, 64 records at a time while
        // they are in cache.
        if (k - k_trimmed == 64) trim(k_trimmed, k);
      }
    }
    trim(k_trimmed, k);
  });
  detail::radix_sort_stable_parallel(ws.keys_, ws.perm_, ws.keys_tmp_, ws.idx_tmp_, threads);
  const auto t1 = clock::now();

  // Permute into rank order and count tile entries, then fill the lists: each
  // of C contiguous rank chunks counts into its own per-tile array, so chunk c's
  // entries of tile t start after those of chunks < c and the result is the same
  // as one sequential pass, for any thread count.
  const std::size_t v = ws.perm_.size();
  ws.records.resize(v);
  ws.order.resize(v);
  ws.rank_boxes.resize(v);
  ws.rank_trims.resize(v);
  ws.rank_offsets.resize(v + 1);  // read (not yet set) by for_each_listed_tile in the counting pass
  const std::size_t tiles = std::size_t(g.tile_count());
  const int tiles_x = g.tiles_x;
  const int ts_shift = detail::tile_size_shift(ts);
  const std::size_t chunks = std::max<std::size_t>(1, std::min<std::size_t>(std::size_t(std::max(1, threads)), v / 4096));
  // Per chunk, a row's entries are counted as +1 at its first tile and -1 past
  // its last (a row of tiles_x + 1 cells), then summed along the row: two
  // increments per listed row instead of one per listed tile.
  const std::size_t diff_row = std::size_t(tiles_x) + 1, diff_cells = diff_row * std::size_t(g.tiles_y);
  ws.chunk_counts_.resize(chunks * tiles);
  ws.chunk_diffs_.assign(chunks * diff_cells, 0);
  ws.chunk_entries_.assign(chunks + 1, 0u);
  auto chunk_range = [&](std::size_t c) { return std::pair<std::size_t, std::size_t>(v * c / chunks, v * (c + 1) / chunks); };
  parallel_for(chunks, threads, [&](std::size_t c, int) {
    const auto [r0, r1] = chunk_range(c);
    std::int32_t* diffs = ws.chunk_diffs_.data() + c * diff_cells;
    std::uint64_t entries = 0;
    for (std::size_t r = r0; r < r1; ++r) {
      const std::size_t p = std::size_t(ws.perm_[r]);
#if defined(__GNUC__)
      // The permuted reads miss the cache; ask for them well ahead (40 ranks
      // read 4-8 % faster than 16 at 300k records; 24-96 were close).
      constexpr std::size_t ahead = 40;
      if (r + ahead < r1) {
        __builtin_prefetch(&ws.packed_[std::size_t(ws.perm_[r + ahead])]);
        __builtin_prefetch(&ws.packed_trims_[std::size_t(ws.perm_[r + ahead])]);
      }
#endif
      const SplatRecord<Scalar>& rec = ws.packed_[p];
      ws.records[r] = rec;
      const std::array<int, 4> tb = detail::record_tile_box(rec, ts, ts_shift);
      const std::array<std::int32_t, 5> box{{tb[0], tb[1], tb[2], tb[3], detail::record_index(rec)}};
      ws.rank_boxes[r] = box;
      ws.order[r] = box[4];
      ws.rank_trims[r] = ws.packed_trims_[p];
      ws.for_each_listed_row(r, [&](int ty, int tx0, int tx1, std::uint32_t) {
        std::int32_t* row = diffs + std::size_t(ty) * diff_row;
        ++row[tx0];
        --row[tx1 + 1];
      });
      entries += std::uint64_t(box[3] - box[1] + 1) * std::uint64_t(box[2] - box[0] + 1);
    }
    ws.chunk_entries_[c + 1] = entries;
    std::uint32_t* counts = ws.chunk_counts_.data() + c * tiles;
    for (int ty = 0; ty < g.tiles_y; ++ty) {
      const std::int32_t* row = diffs + std::size_t(ty) * diff_row;
      std::int32_t run = 0;
      for (int tx = 0; tx < tiles_x; ++tx) counts[ty * tiles_x + tx] = std::uint32_t(run += row[tx]);
    }
  });
  // Prefix sums: tile offsets over all chunks, then each chunk's start within a tile.
  ws.tile_offsets.assign(tiles + 1, 0u);
  std::uint64_t total = 0;
  for (std::size_t t = 0; t < tiles; ++t) {
    std::uint64_t in_tile = 0;
    for (std::size_t c = 0; c < chunks; ++c) in_tile += ws.chunk_counts_[c * tiles + t];
    // The rasterizer counts list positions in Scalar lanes: keep them exact.
    ensure(in_tile < (1u << 24), "bin_splats: a tile lists ", in_tile, " Gaussians (limit 2^24)");
    total += in_tile;
    ensure(total < (std::uint64_t(1) << 32), "bin_splats: more than 2^32 tile entries");
    ws.tile_offsets[t + 1] = std::uint32_t(total);
  }
  for (std::size_t t = 0; t < tiles; ++t) {
    std::uint32_t start = ws.tile_offsets[t];
    for (std::size_t c = 0; c < chunks; ++c) {
      std::uint32_t& cell = ws.chunk_counts_[c * tiles + t];
      const std::uint32_t n_c = cell;
      cell = start;  // now chunk c's cursor in tile t
      start += n_c;
    }
  }
  for (std::size_t c = 0; c < chunks; ++c) ws.chunk_entries_[c + 1] += ws.chunk_entries_[c];
  const std::uint64_t slots = ws.chunk_entries_[chunks];
  ensure(slots < (std::uint64_t(1) << 32), "bin_splats: more than 2^32 tile-box slots");
  // The lists' length depends on the scene (large splats at a large size list in
  // many tiles): check it against the memory limit now that it is known.
  check_memory_request(total * sizeof(std::int32_t), "bin_splats: the tile lists of a ",
                       width, "x", height, " frame (", total, " entries of ", v, " visible Gaussians)");
  ws.tile_ranks.resize(std::size_t(total));
  parallel_for(chunks, threads, [&](std::size_t c, int) {
    const auto [r0, r1] = chunk_range(c);
    std::uint32_t* cursor = ws.chunk_counts_.data() + c * tiles;
    std::int32_t* out = ws.tile_ranks.data();
    std::uint32_t k = std::uint32_t(ws.chunk_entries_[c]);  // rank-major position of the next entry
    for (std::size_t r = r0; r < r1; ++r) {
      const auto box = ws.rank_boxes[r];
      ws.rank_offsets[r] = k;
      k += std::uint32_t((box[3] - box[1] + 1) * (box[2] - box[0] + 1));
      ws.for_each_listed_tile(r, [&](int tx, int ty, std::uint32_t) { out[cursor[ty * tiles_x + tx]++] = std::int32_t(r); });
    }
  });
  ws.rank_offsets[v] = std::uint32_t(slots);
  const auto t2 = clock::now();
  ws.sort_ms = std::chrono::duration<double, std::milli>(t1 - t0).count();
  ws.bin_ms = std::chrono::duration<double, std::milli>(t2 - t1).count();
}

}  // namespace orbitforge

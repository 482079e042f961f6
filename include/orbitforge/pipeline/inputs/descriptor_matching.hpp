#pragma once
// Exact SIFT matching of the image pairs the cameras stages list, written as
// the "raw" match list COLMAP's matches_importer reads (its geometric
// verification and the mapper then run as before).
//
// Why not COLMAP's own matcher: two runs of its CPU matcher on one database
// (one thread, a fixed seed) gave match tables that differ by a match or two in
// some pairs (its nearest-neighbour search is approximate), and the mapper turns that
// into about 1 % of focal length (docs/cameras.md). Exact matching makes the
// cameras stage give the same cameras on every run, so settings can be
// compared and figures repeated.
//
// The criteria are COLMAP's defaults for SIFT: a descriptor's distance to
// another is the angle between them, acos(dot / 512^2) (COLMAP stores each
// descriptor scaled to an L2 norm of about 512); the nearest must lie within
// max_distance radians and below max_ratio times the second nearest's angle,
// and with cross_check a pair is kept only when each is the other's nearest
// (both directions passing both tests). The dot products of uint8 descriptors
// are integers below 2^24, so float products are exact and the result does not
// depend on the order of the sums. Ties go to the lower index.
#include <Eigen/Core>
#include <array>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/pipeline/inputs/colmap_database.hpp"

namespace orbitforge {

struct DescriptorMatchParams {
  double max_ratio = 0.8;     // nearest angle / second nearest angle, below this
  double max_distance = 0.7;  // radians
  bool cross_check = true;
};

// Pairs (i, j), i < j, of the frames 0..n-1 that COLMAP's sequential_matcher
// matches: each frame with the next overlap - 1, and with those 2^k further
// on for k < overlap (its quadratic overlap, on by default).
inline std::vector<std::pair<int, int>> sequential_match_pairs(int n, int overlap) {
  ensure(overlap >= 1, "sequential matching: overlap ", overlap, " must be at least 1");
  std::vector<std::pair<int, int>> pairs;
  for (int i = 0; i < n; ++i) {
    std::vector<int> with;
    for (int d = 1; d < overlap && i + d < n; ++d) with.push_back(i + d);
    for (int k = 0; k < overlap && k < 31; ++k) {
      const long j = long(i) + (1L << k);
      if (j >= n) break;
      if (j - i >= overlap) with.push_back(int(j));
    }
    for (int j : with) pairs.push_back({i, j});
  }
  return pairs;
}

namespace descriptor_matching_detail {

using DotMatrix = Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor>;

// For each row of `dots`, the column it matches (or -1), by the ratio and
// distance tests.
inline std::vector<int> best_one_way(const DotMatrix& dots, const DescriptorMatchParams& p) {
  constexpr double kDotToCosine = 1.0 / (512.0 * 512.0);
  std::vector<int> match(std::size_t(dots.rows()), -1);
  for (Eigen::Index i = 0; i < dots.rows(); ++i) {
    float best = 0, second = 0;
    Eigen::Index best_j = -1;
    for (Eigen::Index j = 0; j < dots.cols(); ++j) {
      const float d = dots(i, j);
      if (d > best) {
        second = best;
        best = d;
        best_j = j;
      } else if (d > second) {
        second = d;
      }
    }
    if (best_j < 0) continue;
    const double best_angle = std::acos(std::min(kDotToCosine * best, 1.0));
    const double second_angle = std::acos(std::min(kDotToCosine * second, 1.0));
    if (best_angle > p.max_distance || best_angle >= p.max_ratio * second_angle) continue;
    match[std::size_t(i)] = int(best_j);
  }
  return match;
}

}  // namespace descriptor_matching_detail

// The matches (index in a, index in b) between two images' descriptors, in a's order.
inline std::vector<std::array<std::uint32_t, 2>> match_descriptors(const SiftDescriptors& a, const SiftDescriptors& b,
                                                                  const DescriptorMatchParams& p = {}) {
  namespace d = descriptor_matching_detail;
  std::vector<std::array<std::uint32_t, 2>> matches;
  if (a.rows() == 0 || b.rows() == 0) return matches;
  const Eigen::MatrixXf fa = a.cast<float>(), fb = b.cast<float>();
  const d::DotMatrix dots = fa * fb.transpose();
  const std::vector<int> ab = d::best_one_way(dots, p);
  std::vector<int> ba;
  if (p.cross_check) ba = d::best_one_way(dots.transpose(), p);
  for (std::size_t i = 0; i < ab.size(); ++i) {
    const int j = ab[i];
    if (j < 0 || (p.cross_check && ba[std::size_t(j)] != int(i))) continue;
    matches.push_back({std::uint32_t(i), std::uint32_t(j)});
  }
  return matches;
}

struct MatchedPair {
  int first = 0, second = 0;  // indices into the image list
  std::vector<std::array<std::uint32_t, 2>> matches;
};

// Every listed pair matched, on `threads` threads; the result is in the order of
// `pairs` and the same for any thread count.
inline std::vector<MatchedPair> match_image_pairs(const std::vector<ColmapDatabaseImage>& images,
                                                  const std::vector<std::pair<int, int>>& pairs, int threads,
                                                  const DescriptorMatchParams& p = {}) {
  std::vector<MatchedPair> out(pairs.size());
  for (const auto& [i, j] : pairs)
    ensure(i >= 0 && j >= 0 && std::size_t(i) < images.size() && std::size_t(j) < images.size() && i != j,
           "descriptor matching: pair (", i, ", ", j, ") is not two of the ", images.size(), " images");
  parallel_for(pairs.size(), threads, [&](std::size_t k, int) {
    const auto [i, j] = pairs[k];
    out[k] = {i, j, match_descriptors(images[std::size_t(i)].descriptors, images[std::size_t(j)].descriptors, p)};
  });
  return out;
}

// COLMAP's raw match list: "NAME1 NAME2", one "IDX1 IDX2" line per match, a
// blank line after each pair. Pairs without matches are left out.
inline std::string raw_match_list(const std::vector<ColmapDatabaseImage>& images,
                                  const std::vector<MatchedPair>& matched) {
  std::string text;
  for (const MatchedPair& m : matched) {
    if (m.matches.empty()) continue;
    for (const std::string* name : {&images[std::size_t(m.first)].name, &images[std::size_t(m.second)].name})
      ensure(name->find_first_of(" \t\r\n") == std::string::npos, "descriptor matching: image name \"", *name,
             "\" has white space, which COLMAP's match list cannot hold");
    text += images[std::size_t(m.first)].name + ' ' + images[std::size_t(m.second)].name + '\n';
    for (const auto& [a, b] : m.matches) text += std::to_string(a) + ' ' + std::to_string(b) + '\n';
    text += '\n';
  }
  return text;
}

struct ExactMatchSummary {
  std::size_t pairs = 0, pairs_matched = 0, matches = 0;
  double seconds = 0;

  // One progress line: "exact matching: M matches in P of N pairs, S s".
  std::string text() const {
    char b[160];
    std::snprintf(b, sizeof(b), "exact matching: %zu matches in %zu of %zu pairs, %.1f s", matches, pairs_matched,
                  pairs, seconds);
    return b;
  }
};

// Reads the descriptors of `database`, matches the pairs of image names listed
// and writes the raw match list to `list_file` (for
// colmap_raw_matches_importer_command). Every name must be in the database.
inline ExactMatchSummary write_exact_match_list(const std::string& database,
                                                const std::vector<std::pair<std::string, std::string>>& pairs,
                                                const std::string& list_file, int threads,
                                                const DescriptorMatchParams& p = {}) {
  const auto t0 = std::chrono::steady_clock::now();
  const std::vector<ColmapDatabaseImage> images = read_colmap_database_descriptors(database);
  std::map<std::string, int> index;
  for (std::size_t k = 0; k < images.size(); ++k) index[images[k].name] = int(k);
  std::vector<std::pair<int, int>> by_index;
  for (const auto& [a, b] : pairs) {
    const auto ia = index.find(a), ib = index.find(b);
    ensure(ia != index.end() && ib != index.end(), "descriptor matching: ", ia == index.end() ? a : b,
           " is not an image of ", database);
    by_index.push_back({ia->second, ib->second});
  }
  const std::vector<MatchedPair> matched = match_image_pairs(images, by_index, threads, p);
  write_file_atomic(list_file, raw_match_list(images, matched));
  ExactMatchSummary s;
  s.pairs = matched.size();
  for (const MatchedPair& m : matched) {
    s.pairs_matched += !m.matches.empty();
    s.matches += m.matches.size();
  }
  s.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return s;
}

}  // namespace orbitforge

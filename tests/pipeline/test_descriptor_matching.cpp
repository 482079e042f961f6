// Exact SIFT matching (pipeline/inputs/descriptor_matching.hpp) and the
// COLMAP database reader it works from (pipeline/inputs/colmap_database.hpp).
#include <catch2/catch.hpp>

#include <sqlite3.h>

#include <algorithm>
#include <array>
#include <fstream>
#include <cmath>
#include <random>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "orbitforge/pipeline/inputs/descriptor_matching.hpp"
#include "support/temp_dir.hpp"

using namespace orbitforge;

namespace descriptor_matching_test {

// A descriptor before scaling: non-negative, unit L2 norm.
using Unit = std::array<double, 128>;

Unit normalised(Unit v) {
  double n2 = 0;
  for (double x : v) n2 += x * x;
  for (double& x : v) x /= std::sqrt(n2);
  return v;
}

Unit random_unit(std::mt19937& rng) {
  std::uniform_real_distribution<double> u(0, 1);
  Unit v;
  for (double& x : v) x = u(rng) * u(rng);
  return normalised(v);
}

Unit noisy(Unit v, std::normal_distribution<double>& noise, std::mt19937& rng) {
  for (double& x : v) x = std::max(0.0, x + noise(rng));
  return normalised(v);
}

// Scaled to an L2 norm of 512 and rounded, as COLMAP stores SIFT descriptors.
void set_row(SiftDescriptors& d, Eigen::Index row, const Unit& unit) {
  for (int k = 0; k < 128; ++k) d(row, k) = std::uint8_t(std::clamp(std::lround(512.0 * unit[std::size_t(k)]), 0L, 255L));
}

// The criteria written out on their own, in double, from the normalised angle:
// the nearest within max_distance and below max_ratio times the second nearest,
// both ways.
int nearest_passing(const SiftDescriptors& from, Eigen::Index i, const SiftDescriptors& to,
                    const DescriptorMatchParams& p) {
  std::vector<std::pair<double, Eigen::Index>> angles;
  for (Eigen::Index j = 0; j < to.rows(); ++j) {
    double dot = 0;
    for (int k = 0; k < 128; ++k) dot += double(from(i, k)) * double(to(j, k));
    angles.push_back({std::acos(std::min(dot / (512.0 * 512.0), 1.0)), j});
  }
  std::stable_sort(angles.begin(), angles.end(), [](auto& a, auto& b) { return a.first < b.first; });
  const double second = angles.size() > 1 ? angles[1].first : std::acos(0.0);
  if (angles[0].first > p.max_distance || angles[0].first >= p.max_ratio * second) return -1;
  return int(angles[0].second);
}

TEST_CASE("descriptor matching: COLMAP's sequential pairs", "[pipeline][matching]") {
  // 33 frames, overlap 10: each frame with the next 9, and 16 and 32 further on.
  const auto pairs = sequential_match_pairs(33, 10);
  std::set<std::pair<int, int>> expected;
  for (int i = 0; i < 33; ++i)
    for (int j = i + 1; j < 33; ++j) {
      const int d = j - i;
      if (d < 10 || d == 16 || d == 32) expected.insert({i, j});
    }
  CHECK(std::set<std::pair<int, int>>(pairs.begin(), pairs.end()) == expected);
  CHECK(pairs.size() == expected.size());  // no pair twice
  CHECK(pairs.size() == 270);              // what sequential_matcher listed on 33 frames
  CHECK(sequential_match_pairs(1, 10).empty());
  CHECK(sequential_match_pairs(3, 1) == std::vector<std::pair<int, int>>{{0, 1}, {1, 2}});
  CHECK_THROWS_WITH(sequential_match_pairs(5, 0), Catch::Contains("overlap 0"));
}

TEST_CASE("descriptor matching: the nearest descriptor, by ratio, distance and both ways", "[pipeline][matching]") {
  std::mt19937 rng(3);
  const int n = 120;
  SiftDescriptors a(n, 128), b(n + 40, 128);
  std::vector<int> truth(n);
  for (int i = 0; i < n; ++i) truth[std::size_t(i)] = (i * 37) % (n + 40);
  std::vector<bool> used(std::size_t(n + 40), false);
  std::normal_distribution<double> noise(0, 0.02);
  for (int i = 0; i < n; ++i) {
    const Unit v = random_unit(rng);
    set_row(a, i, v);
    set_row(b, truth[std::size_t(i)], noisy(v, noise, rng));
    used[std::size_t(truth[std::size_t(i)])] = true;
  }
  for (int j = 0; j < n + 40; ++j)
    if (!used[std::size_t(j)]) set_row(b, j, random_unit(rng));  // distractors
  // An ambiguous feature: b holds a's row 5's partner twice, so the ratio test drops it.
  {
    int other = 0;
    while (used[std::size_t(other)]) ++other;
    b.row(other) = b.row(truth[5]);
  }

  const DescriptorMatchParams p;
  const auto m = match_descriptors(a, b, p);
  std::set<std::pair<int, int>> got;
  for (const auto& [i, j] : m) got.insert({int(i), int(j)});
  std::set<std::pair<int, int>> expected;
  for (int i = 0; i < n; ++i) {
    const int j = nearest_passing(a, i, b, p);
    if (j >= 0 && nearest_passing(b, j, a, p) == i) expected.insert({i, j});
  }
  CHECK(got == expected);
  CHECK(got.size() >= std::size_t(n - 5));
  CHECK(got.count({5, truth[5]}) == 0);
  for (const auto& [i, j] : got) CHECK(j == truth[std::size_t(i)]);
  // In a's order.
  for (std::size_t k = 1; k < m.size(); ++k) CHECK(m[k - 1][0] < m[k][0]);

  // A far descriptor is no match, however unique: here everything is beyond 0.05 rad.
  DescriptorMatchParams tight = p;
  tight.max_distance = 0.005;
  CHECK(match_descriptors(a, b, tight).empty());
  // Without the cross check, a descriptor of b may be matched twice.
  SiftDescriptors twice(2, 128);
  twice.row(0) = a.row(7);
  twice.row(1) = a.row(7);
  SiftDescriptors one(1, 128);
  one.row(0) = a.row(7);
  DescriptorMatchParams one_way = p;
  one_way.cross_check = false;
  CHECK(match_descriptors(twice, one, one_way).size() == 2);
  // With it, neither: the one descriptor of b has two equally near in a, which its ratio test rejects.
  CHECK(match_descriptors(twice, one, p).empty());
  CHECK(match_descriptors(SiftDescriptors(0, 128), b).empty());
}

TEST_CASE("descriptor matching: the result does not depend on the thread count", "[pipeline][matching]") {
  std::mt19937 rng(11);
  std::vector<ColmapDatabaseImage> images(6);
  const auto base = [&] {
    std::vector<Unit> v;
    for (int i = 0; i < 150; ++i) v.push_back(random_unit(rng));
    return v;
  }();
  std::normal_distribution<double> noise(0, 0.03);
  for (std::size_t k = 0; k < images.size(); ++k) {
    images[k].name = std::to_string(k + 1) + ".png";
    images[k].descriptors.resize(120, 128);
    for (int i = 0; i < 120; ++i) {
      set_row(images[k].descriptors, i, noisy(base[std::size_t(i + int(k) * 5)], noise, rng));
    }
  }
  const auto pairs = sequential_match_pairs(6, 3);
  const auto one = match_image_pairs(images, pairs, 1), three = match_image_pairs(images, pairs, 3);
  REQUIRE(one.size() == pairs.size());
  std::size_t total = 0;
  for (std::size_t k = 0; k < one.size(); ++k) {
    CHECK(one[k].first == pairs[k].first);
    CHECK(one[k].second == pairs[k].second);
    CHECK(one[k].matches == three[k].matches);
    total += one[k].matches.size();
  }
  CHECK(total > 300);
  const std::string list = raw_match_list(images, one);
  CHECK(list.rfind("1.png 2.png\n", 0) == 0);
  CHECK(std::count(list.begin(), list.end(), '\n') == std::ptrdiff_t(total + 2 * one.size()));
  CHECK_THROWS_WITH(match_image_pairs(images, {{0, 6}}, 1), Catch::Contains("(0, 6)"));
  images[0].name = "a b.png";
  CHECK_THROWS_WITH(raw_match_list(images, one), Catch::Contains("white space"));
}

// A database with COLMAP's two tables that the reader uses.
void write_database(const std::string& path, const std::vector<ColmapDatabaseImage>& images,
                    long long blob_rows_override = -1) {
  sqlite3* db = nullptr;
  REQUIRE(sqlite3_open(path.c_str(), &db) == SQLITE_OK);
  REQUIRE(sqlite3_exec(db,
                       "CREATE TABLE images (image_id INTEGER PRIMARY KEY, name TEXT NOT NULL UNIQUE, camera_id "
                       "INTEGER NOT NULL);"
                       "CREATE TABLE descriptors (image_id INTEGER PRIMARY KEY, rows INTEGER, cols INTEGER, data BLOB);",
                       nullptr, nullptr, nullptr) == SQLITE_OK);
  for (const auto& im : images) {
    sqlite3_stmt* s = nullptr;
    REQUIRE(sqlite3_prepare_v2(db, "INSERT INTO images VALUES (?, ?, 1)", -1, &s, nullptr) == SQLITE_OK);
    sqlite3_bind_int64(s, 1, im.id);
    sqlite3_bind_text(s, 2, im.name.c_str(), -1, SQLITE_TRANSIENT);
    REQUIRE(sqlite3_step(s) == SQLITE_DONE);
    sqlite3_finalize(s);
    if (im.descriptors.rows() == 0) continue;
    REQUIRE(sqlite3_prepare_v2(db, "INSERT INTO descriptors VALUES (?, ?, 128, ?)", -1, &s, nullptr) == SQLITE_OK);
    sqlite3_bind_int64(s, 1, im.id);
    sqlite3_bind_int64(s, 2, blob_rows_override >= 0 ? blob_rows_override : im.descriptors.rows());
    sqlite3_bind_blob(s, 3, im.descriptors.data(), int(im.descriptors.size()), SQLITE_TRANSIENT);
    REQUIRE(sqlite3_step(s) == SQLITE_DONE);
    sqlite3_finalize(s);
  }
  sqlite3_close(db);
}

TEST_CASE("COLMAP database: descriptors read back by image, in id order", "[pipeline][matching][io]") {
  orbitforge_test::TempDir t("colmap_database");
  std::mt19937 rng(5);
  std::vector<ColmapDatabaseImage> images(3);
  for (int k = 0; k < 3; ++k) {
    images[std::size_t(k)].id = 3 - k;  // stored out of order
    images[std::size_t(k)].name = "f" + std::to_string(3 - k) + ".png";
    images[std::size_t(k)].descriptors.resize(k == 1 ? 0 : 4 + k, 128);
    for (Eigen::Index i = 0; i < images[std::size_t(k)].descriptors.rows(); ++i)
      set_row(images[std::size_t(k)].descriptors, i, random_unit(rng));
  }
  write_database(t.str("a.db"), images);
  const auto read = read_colmap_database_descriptors(t.str("a.db"));
  REQUIRE(read.size() == 3);
  CHECK(read[0].id == 1);
  CHECK(read[0].name == "f1.png");
  CHECK(read[0].descriptors == images[2].descriptors);
  CHECK(read[1].descriptors.rows() == 0);  // no descriptors row: no features
  CHECK(read[2].descriptors == images[0].descriptors);

  // Matching by name through the database writes COLMAP's raw list.
  const ExactMatchSummary s =
      write_exact_match_list(t.str("a.db"), {{"f1.png", "f3.png"}, {"f1.png", "f2.png"}}, t.str("m.txt"), 1);
  CHECK(s.pairs == 2);
  CHECK(s.pairs_matched <= 1);
  CHECK_THROWS_WITH(write_exact_match_list(t.str("a.db"), {{"f1.png", "f9.png"}}, t.str("m.txt"), 1),
                    Catch::Contains("f9.png is not an image of"));

  // A blob shorter than its row count says, a missing file, a file that is not a database.
  write_database(t.str("bad.db"), {images[0]}, 9);
  CHECK_THROWS_WITH(read_colmap_database_descriptors(t.str("bad.db")),
                    Catch::Contains("f3.png: descriptor blob of 512 bytes, expected 9 x 128"));
  CHECK_THROWS_WITH(read_colmap_database_descriptors(t.str("none.db")), Catch::Contains("cannot open"));
  {
    std::ofstream junk(t.str("junk.db"));
    junk << "not a database, not at all, but long enough to have a header of sorts..............";
  }
  CHECK_THROWS_WITH(read_colmap_database_descriptors(t.str("junk.db")), Catch::Contains("junk.db"));
}

}  // namespace descriptor_matching_test

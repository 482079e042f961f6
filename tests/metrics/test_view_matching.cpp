#include <catch2/catch.hpp>
#include <cmath>
#include <random>

#include "orbitforge/metrics/coverage.hpp"
#include "orbitforge/metrics/view_matching.hpp"

using namespace orbitforge;

namespace {

// View v of a turntable: a 48x32 window onto a smooth periodic panorama, shifted
// 3 pixels per view, so neighbouring views look alike (as R0's renders do).
template <class S>
Image<S> panorama_view(int v, double noise, std::mt19937& rng) {
  std::normal_distribution<double> n(0.0, noise);
  Image<S> img(48, 32, 3);
  for (int y = 0; y < img.height; ++y)
    for (int x = 0; x < img.width; ++x) {
      const double u = 2 * M_PI * (x + 3.0 * v) / 240.0;
      const double w = 2 * M_PI * y / 32.0;
      const double base[3] = {0.5 + 0.3 * std::sin(u) * std::cos(w), 0.5 + 0.3 * std::sin(2 * u + 1),
                              0.5 + 0.2 * std::cos(3 * u + w)};
      for (int c = 0; c < 3; ++c)
        img.data[(std::size_t(y) * img.width + x) * 3 + c] = S(std::clamp(base[c] + n(rng), 0.0, 1.0));
    }
  return img;
}

}  // namespace

TEMPLATE_TEST_CASE("completion trace from pixels: stalls and reversals are seen", "[metrics][view_matching]", float,
                   double) {
  using S = TestType;
  std::mt19937 rng(7);
  constexpr int kViews = 60;  // the panorama repeats every 80 views, so all 60 differ
  std::vector<Image<S>> refs;
  std::vector<double> positions;
  for (int v = 0; v < kViews; ++v) {
    refs.push_back(panorama_view<S>(v, 0.0, rng));
    positions.push_back(v);
  }
  TraceParams tp;
  tp.period = 360;
  tp.stall_threshold = 0.5;
  auto trace_of = [&](const std::vector<int>& shown) {
    std::vector<Image<S>> frames;
    for (int v : shown) frames.push_back(panorama_view<S>(v, 0.03, rng));  // a generator's noise
    const ViewMatch m = match_views(frames, refs, positions);
    for (std::size_t i = 0; i < shown.size(); ++i) REQUIRE(m.positions[i] == shown[i]);
    return temporal_trace(m.positions, tp);
  };

  SECTION("a steady turn: no stall, no reversal") {
    std::vector<int> shown;
    for (int v = 10; v < 40; ++v) shown.push_back(v);
    const TemporalTrace tr = trace_of(shown);
    REQUIRE(tr.reversals == 0);
    REQUIRE(tr.stall_fraction == 0);
    REQUIRE(tr.net_turns == Approx(29.0 / 360));
  }
  SECTION("frames repeated (a stall) and played backwards (a reversal)") {
    const std::vector<int> shown = {10, 11, 12, 13, 13, 13, 13, 14, 15, 16, 15, 14, 13, 12, 13, 14, 15};
    const TemporalTrace tr = trace_of(shown);
    REQUIRE(tr.stall_fraction == Approx(3.0 / 16));
    REQUIRE(tr.reversals == 2);  // forward -> back at 16, back -> forward at 12
    REQUIRE(tr.absolute_turns == Approx(13.0 / 360));
    REQUIRE(tr.net_turns == Approx(5.0 / 360));
  }
}

TEST_CASE("view matching: bad input names the problem", "[metrics][view_matching]") {
  std::vector<Image<float>> none;
  std::vector<Image<float>> one = {Image<float>(4, 4, 3, 0.5f)};
  REQUIRE_THROWS_WITH(match_views(one, one, {}), Catch::Contains("1 references but 0 positions"));
  REQUIRE_THROWS_WITH(match_views(one, none, {}), Catch::Contains("no references"));
  REQUIRE_THROWS_WITH(thumbnail(Image<float>(4, 4, 1), 8), Catch::Contains("RGB"));
  REQUIRE(match_views(none, one, {3.0}).positions.empty());
}

TEMPLATE_TEST_CASE("centre crop to an aspect keeps the middle of the wider side", "[metrics][view_matching]", float,
                   double) {
  // Pixel (x, y) holds (x, y, x + 10 y) so every crop can be located exactly.
  Image<TestType> wide(9, 4, 3);
  for (int y = 0; y < wide.height; ++y)
    for (int x = 0; x < wide.width; ++x) {
      wide(x, y, 0) = TestType(x);
      wide(x, y, 1) = TestType(y);
      wide(x, y, 2) = TestType(x + 10 * y);
    }
  const auto sq = centre_crop_to_aspect(wide, 1.0);
  REQUIRE(sq.width == 4);
  REQUIRE(sq.height == 4);
  for (int y = 0; y < 4; ++y)
    for (int x = 0; x < 4; ++x) {
      CHECK(sq(x, y, 0) == TestType(x + 2));  // (9 - 4) / 2 = 2 columns off the left
      CHECK(sq(x, y, 1) == TestType(y));
      CHECK(sq(x, y, 2) == TestType(x + 2 + 10 * y));
    }
  // A taller target aspect crops rows instead: 9 wide at 9:2 keeps rows 1 and 2.
  const auto band = centre_crop_to_aspect(wide, 4.5);
  REQUIRE(band.width == 9);
  REQUIRE(band.height == 2);
  CHECK(band(0, 0, 1) == TestType(1));
  CHECK(band(8, 1, 2) == TestType(8 + 20));
  // The image's own aspect returns it unchanged.
  const auto same = centre_crop_to_aspect(wide, 9.0 / 4.0);
  CHECK(same.data == wide.data);
  REQUIRE_THROWS_WITH(centre_crop_to_aspect(wide, 0.0), Catch::Contains("aspect must be positive"));
}

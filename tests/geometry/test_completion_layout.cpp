#include <catch2/catch.hpp>

#include <set>

#include "orbitforge/geometry/completion_layout.hpp"

using namespace orbitforge;

// Source of T frames moving `step` degrees per frame from theta0 = 0.
static SupportBins support_of(int T, double step, int views = 361) {
  std::vector<double> az;
  for (int t = 0; t < T; ++t) az.push_back(wrap_deg_180(step * t));
  return bin_sources(az, 0.0, 1, views);
}

static std::vector<std::string> names_of(int T) {
  std::vector<std::string> n;
  for (int t = 0; t < T; ++t) n.push_back("f" + std::to_string(t + 1));
  return n;
}

TEST_CASE("endpoint-window layout: tail, gap, head, closed", "[geometry][layout]") {
  // 121 frames at ~1.0667 degrees: k = 128, s = 64.
  const auto sup = support_of(121, 128.0 / 120);
  REQUIRE(sup.arc_end == 128);
  const auto L = endpoint_window_layout(sup, names_of(121));
  REQUIRE(L.frames == 361);
  REQUIRE((L.frames - 1) % 8 == 0);
  REQUIRE(L.start == 64);
  REQUIRE(L.synthetic_to_canonical.front() == 64);
  REQUIRE(L.synthetic_to_canonical.back() == 64);  // ends where it started
  // Tail 64..128, then the gap 129..359, then the head 0..64.
  for (int j = 0; j <= 64; ++j) REQUIRE(L.synthetic_to_canonical[j] == 64 + j);
  for (int j = 65; j < 296; ++j) {
    REQUIRE(L.synthetic_to_canonical[j] == 64 + j);
    REQUIRE(!L.known[j]);
  }
  for (int j = 296; j <= 360; ++j) {
    REQUIRE(L.synthetic_to_canonical[j] == j - 296);
    REQUIRE(L.known[j]);
  }
  int known = 0;
  for (char k : L.known) known += k;
  REQUIRE(known == 65 + 65);
  // Map back: every canonical view but 360 appears, and canonical_to_synthetic inverts.
  std::set<int> seen(L.synthetic_to_canonical.begin(), L.synthetic_to_canonical.end());
  REQUIRE(seen.size() == 360);
  for (int v = 0; v < 360; ++v) REQUIRE(L.synthetic_to_canonical[L.canonical_to_synthetic(v)] == v);
  REQUIRE(L.canonical_to_synthetic(360) == L.canonical_to_synthetic(0));

  SECTION("anchors: frames 1, 25, ..., 121 at their own bins") {
    REQUIRE(L.anchors.size() == 6);
    const int expect_src[] = {0, 24, 48, 72, 96, 120};
    for (int a = 0; a < 6; ++a) {
      REQUIRE(L.anchors[a].source_index == expect_src[a]);
      REQUIRE(L.anchors[a].name == "f" + std::to_string(expect_src[a] + 1));
      REQUIRE(L.anchors[a].canonical == sup.source_bins[expect_src[a]]);
      REQUIRE(L.synthetic_to_canonical[L.anchors[a].synthetic] == L.anchors[a].canonical % 360);
      REQUIRE(L.known[L.anchors[a].synthetic]);
    }
    REQUIRE(L.anchor_error_mean == 0);
    REQUIRE(L.anchor_error_max == 0);
  }
  SECTION("target-half placement misplaces anchors") {
    LayoutParams p;
    p.placement = AnchorPlacement::target_half;
    const auto N = endpoint_window_layout(sup, names_of(121), p);
    REQUIRE(N.anchors.size() == 6);
    REQUIRE(N.anchors.front().synthetic == N.anchors.front().aligned_synthetic);  // both start at view 0
    REQUIRE(N.anchor_error_mean > 5);
    REQUIRE(N.anchor_error_max >= N.anchor_error_mean);
  }
  SECTION("assembly: arc from R0, gap from the completion") {
    const auto plan = assembly_plan(L);
    REQUIRE(plan.size() == 361);
    for (int v = 0; v <= 128; ++v) REQUIRE(plan[v].from == AssemblyEntry::From::first_reconstruction);
    for (int v = 129; v <= 360; ++v) {
      REQUIRE(plan[v].from == AssemblyEntry::From::completion);
      REQUIRE(L.synthetic_to_canonical[plan[v].synthetic] == v % 360);
    }
  }
}

TEST_CASE("target-half anchor error on a 49-frame source over 156 degrees is the paper's 12 / 24",
          "[geometry][layout]") {
  // A 49-frame source video (anchors: frames 1, 25, 49) covering 156 degrees sits
  // at bins 0, 78, 156; target-half places the three anchors at views 0, 90, 180,
  // i.e. 0, 12 and 24 frames away: mean 12, max 24, as in the paper's ablation.
  const auto sup = support_of(49, 156.0 / 48);
  REQUIRE(sup.arc_end == 156);
  LayoutParams half;
  half.placement = AnchorPlacement::target_half;
  const auto H = endpoint_window_layout(sup, names_of(49), half);
  REQUIRE(H.anchors.size() == 3);
  CHECK(H.anchors[1].name == "f25");
  CHECK(std::abs(H.anchors[1].synthetic - H.anchors[1].aligned_synthetic) == 12);
  CHECK(H.anchor_error_mean == Approx(12.0));
  CHECK(H.anchor_error_max == Approx(24.0));
  const auto A = endpoint_window_layout(sup, names_of(49));
  CHECK(A.anchor_error_mean == 0.0);
  CHECK(A.anchor_error_max == 0.0);
}

TEST_CASE("endpoint-window layout: last frame anchor, padding to 8m+1, tiny arcs", "[geometry][layout]") {
  REQUIRE(completion_frame_count(361) == 361);
  REQUIRE(completion_frame_count(49) == 49);
  REQUIRE(completion_frame_count(50) == 57);
  REQUIRE(completion_frame_count(1) == 1);
  SECTION("30 frames: anchors 1, 25 and the last (30)") {
    const auto sup = support_of(30, 4);
    const auto L = endpoint_window_layout(sup, names_of(30));
    REQUIRE(L.anchors.size() == 3);
    REQUIRE(L.anchors[2].source_index == 29);
    REQUIRE(L.anchors[2].canonical == 116);
  }
  SECTION("N = 100 is padded to 105 by repeating the closing view") {
    const auto sup = support_of(10, 10, 100);  // 10 degrees = 2.75 bins
    const auto L = endpoint_window_layout(sup, names_of(10));
    REQUIRE(L.frames == 105);
    for (int j = 99; j < 105; ++j) REQUIRE(L.synthetic_to_canonical[j] == L.start);
    REQUIRE(L.synthetic_to_canonical[0] == L.start);
  }
  SECTION("a single-bin arc") {
    const auto sup = support_of(3, 0.1);
    REQUIRE(sup.arc_end == 0);
    const auto L = endpoint_window_layout(sup, names_of(3));
    REQUIRE(L.start == 0);
    REQUIRE(L.known[0]);
    REQUIRE(!L.known[1]);
    REQUIRE(L.known[360]);
  }
  SECTION("bad input") {
    const auto sup = support_of(10, 3);
    REQUIRE_THROWS_AS(endpoint_window_layout(sup, names_of(9)), Error);
    LayoutParams p;
    p.anchor_stride = 0;
    REQUIRE_THROWS_AS(endpoint_window_layout(sup, names_of(10), p), Error);
  }
}

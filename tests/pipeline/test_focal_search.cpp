// The focal search's decisions (pipeline/inputs/focal_search.hpp): a wrong
// focal estimate is recovered on a synthetic rigid arc, and the grid extension,
// parabola vertex and choice on hand-made scores.
//
// COLMAP's mapper with the focal held fixed is stood in for by a bundle
// adjustment without priors at that focal length, from the same observations:
// both minimise reprojection error over poses and points at a fixed focal.
#include <catch2/catch.hpp>

#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "geometry/synthetic_bundle.hpp"
#include "orbitforge/pipeline/inputs/focal_search.hpp"

using namespace orbitforge;

namespace focal_search_test {

struct Candidate {
  double focal = 0;
  OrbitFitScore score;
};

// The scene's cameras mapped at `focal`: poses and points refined by
// reprojection alone, the focal held; scored as the search scores a model.
Candidate map_at(const orbitforge_test::RigidScene<double>& sc, double focal) {
  auto cams = sc.cameras;
  for (auto& c : cams) c.intrinsics.fx = c.intrinsics.fy = focal;
  const auto points = orbitforge_test::triangulate(cams, sc.points.size(), sc.observations);
  OrbitBundleParams p;
  p.sigma_radius = p.sigma_height = p.sigma_lookat_deg = p.sigma_roll_deg = p.sigma_accel_deg = 0;
  const auto res = orbit_bundle_adjust(cams, points, sc.observations, p);
  std::vector<FrameCamera<double>> frames;
  for (const auto& c : res.cameras) frames.push_back({"", c, true});
  return {focal, orbit_fit_score(frames, int(frames.size()))};
}

Candidate scored(double focal, double value) {
  Candidate c;
  c.focal = focal;
  c.score.usable = true;
  c.score.value = value;
  return c;
}

}  // namespace focal_search_test

TEST_CASE("focal search: a wrong focal estimate is recovered by the orbit fit", "[pipeline][cameras]") {
  using namespace focal_search_test;
  // The search as the cameras stage runs it (search_focal_grid with the
  // factors --focal-search sets), the mapping stood in for.
#ifdef ORBITFORGE_TEST_QUICK
  const std::vector<unsigned> seeds = {21};
#else
  const std::vector<unsigned> seeds = {21, 5};
#endif
  for (const unsigned seed : seeds) {
    const auto sc = orbitforge_test::rigid_scene<double>(2000, 0.5, seed);
    const double truth = sc.orbit.focal;
    const double arc = sc.orbit.step_deg * (sc.orbit.count - 1);
    // Mapper estimates 30 % short and 30 % long: the truth outside the grid
    // (0.8-1.25 times the estimate) on the short side, inside on the long one.
    for (const double wrong : {0.7, 1.3}) {
      INFO("seed " << seed << ", mapper's estimate " << wrong << " x the truth");
      std::vector<Candidate> cands{map_at(sc, wrong * truth)};
      search_focal_grid(cands, kFocalSearchFactors, [&](double focal, const char*) {
        cands.push_back(map_at(sc, focal));
      });
      const std::size_t best = best_focal_candidate(cands);
      const Candidate& b = cands[best];
      std::printf("focal search, seed %u, estimate %.2f x truth: %zu maps, chosen %.1f px (truth %.0f), arc %.2f deg "
                  "(truth %.0f, the estimate's %.2f)\n",
                  seed, wrong, cands.size(), b.focal, truth, b.score.arc_deg, arc, cands.front().score.arc_deg);
      REQUIRE(cands.front().score.usable);
      CHECK(std::abs(cands.front().score.arc_deg - arc) > 4);  // the wrong focal really turns the arc
      CHECK(best != 0);
      CHECK(std::abs(b.focal / truth - 1) < 0.03);
      CHECK(std::abs(b.score.arc_deg - arc) < 1);
    }
  }
}

TEST_CASE("focal search: grid extension, parabola vertex and choice on given scores", "[pipeline][cameras]") {
  using namespace focal_search_test;
  // A score that is a parabola in log focal with its minimum at 470 px.
  auto parabola = [](double f) { return 0.01 + std::pow(std::log(f / 470), 2); };
  std::vector<Candidate> c;
  for (double f : {400.0, 440.0, 500.0, 550.0}) c.push_back(scored(f, parabola(f)));
  CHECK(focal_grid_extension(c) == 0);  // the best (500) lies inside
  CHECK(std::abs(focal_parabola_vertex(c) - 470) < 1e-6);
  CHECK(c[best_focal_candidate(c)].focal == 500);

  // The best at either edge: one step beyond it.
  std::vector<Candidate> low{scored(300, parabola(300)), scored(330, parabola(330)), scored(360, parabola(360))};
  CHECK(std::abs(focal_grid_extension(low) - 360 * kFocalGridStep) < 1e-9);
  CHECK(focal_parabola_vertex(low) == 0);  // no neighbour above the best
  std::vector<Candidate> high{scored(700, parabola(700)), scored(600, parabola(600))};
  CHECK(std::abs(focal_grid_extension(high) - 600 / kFocalGridStep) < 1e-9);

  // Unusable candidates take no part; with none usable the first is kept.
  std::vector<Candidate> some = c;
  some.push_back(scored(470, -1));
  some.back().score.usable = false;
  CHECK(c[best_focal_candidate(c)].focal == some[best_focal_candidate(some)].focal);
  std::vector<Candidate> none{scored(400, 1), scored(500, 0.5)};
  for (auto& x : none) x.score.usable = false;
  CHECK(best_focal_candidate(none) == 0);
  CHECK(focal_grid_extension(none) == 0);
  CHECK(focal_parabola_vertex(none) == 0);
  // Equal scores about the best: no curvature, no vertex to map.
  std::vector<Candidate> flat{scored(450, 0.5), scored(400, 0.5), scored(500, 0.5)};
  CHECK(focal_parabola_vertex(flat) == 0);
}

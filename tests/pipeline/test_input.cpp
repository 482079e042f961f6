// The pipeline's input: only source evidence reaches G0 (the sparse-point
// filter), frame ranges count video frames (missing registrations are skipped
// by name and keep their time codes), and the background colour comes from the
// frames' borders.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>

#include "orbitforge/pipeline/inputs/input_json.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "support/data.hpp"
#include "support/temp_dir.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"

using namespace orbitforge;
namespace fs = std::filesystem;

namespace {


// An input of n registered frames (no images needed by the filter) with the
// source range [first, last] (0-based).
template <class S>
PipelineInput<S> frames_only(int n, int first, int last) {
  PipelineInput<S> in;
  for (int i = 0; i < n; ++i) {
    FrameCamera<S> fc;
    fc.name = std::to_string(1000 + i) + ".png";
    in.cameras.push_back(fc);
    in.images.emplace_back(2, 2, 3, S(0.5));
  }
  select_source(in, std::to_string(first + 1) + "-" + std::to_string(last + 1));
  return in;
}

template <class S>
void add_point(PipelineInput<S>& in, S x, std::vector<int> frames) {
  for (int c = 0; c < 3; ++c) {
    in.points.push_back(x + S(c));
    in.colors.push_back(S(0.25) * S(c));
  }
  in.point_frames.push_back(std::move(frames));
}

}  // namespace

TEMPLATE_TEST_CASE("source_points: a point reaches G0 only when two training source frames saw it",
                   "[pipeline][input][points]", float, double) {
  using S = TestType;
  PipelineInput<S> in = frames_only<S>(20, 0, 9);  // source: frames 0..9; gap: 10..19
  add_point(in, S(1), {0, 1});          // two source frames: kept
  add_point(in, S(2), {3, 12, 15});     // one source frame: dropped
  add_point(in, S(3), {12, 13, 19});    // seen only from the gap: dropped
  add_point(in, S(4), {5, 5, 5});       // one source frame three times: dropped
  add_point(in, S(5), {8, 9, 17});      // kept
  add_point(in, S(6), {7, 19});         // dropped
  const SourcePoints<S> sp = source_points(in);
  CHECK(sp.total == 6);
  CHECK(sp.kept == 2);
  CHECK(sp.dropped == 4);
  REQUIRE(sp.points.size() == 6);
  CHECK(sp.points[0] == S(1));
  CHECK(sp.points[3] == S(5));
  CHECK(sp.colors[4] == S(0.25));

  // Withheld frames do not count: frame 9 is the 10th of the range (every 5th withheld: 4, 9).
  withhold_every(in, 5);
  REQUIRE(in.withheld == std::vector<int>{4, 9});
  CHECK(source_points(in).kept == 1);  // {8, 9} is now one training frame

  // A point list without tracks cannot prove its points come from the source.
  in.point_frames.clear();
  const SourcePoints<S> none = source_points(in);
  CHECK(none.kept == 0);
  CHECK(none.dropped == 6);
  CHECK_THAT(none.rule, Catch::Contains("does not say which frames"));

  const auto j = points_json(frames_only<S>(3, 0, 2));
  CHECK(j.at("total") == 0);
}

TEMPLATE_TEST_CASE("select_source: frames are video frames; missing cameras are skipped and keep the clock",
                   "[pipeline][input][frames]", float, double) {
  using S = TestType;
  PipelineInput<S> in = frames_only<S>(40, 0, 39);
  for (int missing : {4, 5, 29}) in.cameras[std::size_t(missing)].valid = false;  // frames 5, 6, 30
  select_source(in, "1-33");
  CHECK(in.source_first == 0);
  CHECK(in.source_last == 32);
  CHECK(in.source.size() == 30);
  for (int f : in.source) CHECK((f != 4 && f != 5 && f != 29));
  REQUIRE(in.source_skipped.size() == 3);
  CHECK(in.source_skipped[0].name == "1004.png");
  CHECK_THAT(in.source_skipped[2].reason, Catch::Contains("no estimated camera"));
  // Time codes follow frame numbers: frame 7 (index 6) sits at 6/32 whatever is missing before it.
  CHECK(in.time_code(6) == Approx(6.0 / 32.0));
  CHECK(in.time_code(32) == Approx(1.0));

  const auto j = source_frames_json(in);
  CHECK(j.at("skipped").size() == 3);
  CHECK(j.at("skipped")[2].at("frame") == 30);
  CHECK(j.at("trained").size() == 30);

  // A range past the registered frames but within the video uses what it has.
  for (int i = 28; i < 40; ++i) in.cameras[std::size_t(i)].valid = false;
  select_source(in, "1-33");
  CHECK(in.source.size() == 26);  // 1..28 minus 5, 6
  CHECK_THROWS_WITH(select_source(in, "1-41"), Catch::Contains("41") && Catch::Contains("40 frames"));
}

TEMPLATE_TEST_CASE("estimate_background: white and black studios are found, cluttered borders fall back",
                   "[pipeline][input][background]", float, double) {
  using S = TestType;
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> u(0, 1);
  auto frame = [&](double r, double g, double b, double noise, bool object) {
    Image<S> img(64, 48, 3);
    for (int y = 0; y < 48; ++y)
      for (int x = 0; x < 64; ++x) {
        const bool inside = object && x > 12 && x < 52 && y > 8 && y < 40;
        const double c[3] = {inside ? u(rng) : r, inside ? u(rng) : g, inside ? u(rng) : b};
        for (int k = 0; k < 3; ++k)
          img(x, y, k) = S(std::min(1.0, std::max(0.0, c[k] + noise * (u(rng) - 0.5))));
      }
    return img;
  };
  std::vector<Image<S>> white, black, grey, cluttered;
  for (int i = 0; i < 4; ++i) {
    white.push_back(frame(1, 1, 1, 0.01, true));
    black.push_back(frame(0, 0, 0, 0.01, true));
    grey.push_back(frame(0.5, 0.45, 0.4, 0.02, true));
    cluttered.push_back(frame(0.5, 0.5, 0.5, 1.0, true));  // uniform noise everywhere
  }
  auto ptrs = [](const std::vector<Image<S>>& v) {
    std::vector<const Image<S>*> p;
    for (const auto& i : v) p.push_back(&i);
    return p;
  };
  const BackgroundEstimate w = estimate_background(ptrs(white));
  CHECK(w.from_data);
  CHECK(w.color == std::array<double, 3>{{1, 1, 1}});  // snapped to pure white
  const BackgroundEstimate b = estimate_background(ptrs(black));
  CHECK(b.from_data);
  CHECK(b.color == std::array<double, 3>{{0, 0, 0}});
  const BackgroundEstimate g = estimate_background(ptrs(grey));
  CHECK(g.from_data);
  CHECK(g.color[0] == Approx(0.5).margin(0.02));
  CHECK(g.color[2] == Approx(0.4).margin(0.02));
  BackgroundParams fallback;
  fallback.fallback = {{0.2, 0.3, 0.4}};
  const BackgroundEstimate c = estimate_background(ptrs(cluttered), fallback);
  CHECK_FALSE(c.from_data);
  CHECK(c.color == fallback.fallback);
  CHECK(c.agreement < 0.5);
  CHECK_THAT(c.reason, Catch::Contains("disagree"));

  // choose_background: the override wins and says so.
  PipelineInput<S> in = frames_only<S>(3, 0, 2);
  in.images = white;
  in.images.resize(3);
  const std::array<double, 3> red{{1, 0, 0}};
  CHECK(choose_background(in, &red).color == red);
  CHECK(in.background == red);
  CHECK(choose_background(in).color == std::array<double, 3>{{1, 1, 1}});
}

TEST_CASE("load_colmap_input: a longer side keeps the photographs' aspect", "[pipeline][input][data]") {
  using S = float;
  if (!orbitforge_test::have_shared_data("middlebury/dinoSparseRing")) return;
  const std::string dino = orbitforge_test::shared_path("middlebury/dinoSparseRing");
  const PipelineInput<S> own = load_colmap_input<S>(dino, "1-4", WorkingSize::native());
  REQUIRE(own.width == 640);
  REQUIRE(own.height == 480);
  const PipelineInput<S> in = load_colmap_input<S>(dino, "1-4", WorkingSize::longer_side(320));
  CHECK(in.width == 320);
  CHECK(in.height == 240);
  const int f = in.source.front();
  CHECK(in.images[std::size_t(f)].width == 320);
  CHECK(in.images[std::size_t(f)].height == 240);
  // Half the size in both directions: every intrinsic halves, so no direction is squeezed.
  const auto& k = in.cameras[std::size_t(f)].camera.intrinsics;
  const auto& k0 = own.cameras[std::size_t(f)].camera.intrinsics;
  CHECK(k.fx == Approx(k0.fx / 2));
  CHECK(k.fy == Approx(k0.fy / 2));
  CHECK(k.cy == Approx(k0.cy / 2));
  CHECK_THROWS_WITH(load_colmap_input<S>(dino, "1-4", WorkingSize::longer_side(4)), Catch::Contains("too small"));
}

TEST_CASE("load_colmap_input: a recorded model without frames 5, 6 and 30 uses the others by name",
          "[pipeline][input][frames][data]") {
  using S = float;
  if (!orbitforge_test::have_shared_data("v3d/cool_teddy")) return;
  orbitforge_test::TempDir tmp("input_test");
  const fs::path src = orbitforge_test::shared_path("v3d/cool_teddy");
  fs::create_directories(tmp.path() / "sparse" / "0");
  fs::create_symlink(src / "images", tmp.path() / "images");
  fs::copy_file(src / "sparse" / "0" / "cameras.txt", tmp.path() / "sparse" / "0" / "cameras.txt");
  fs::copy_file(src / "sparse" / "0" / "points3D.txt", tmp.path() / "sparse" / "0" / "points3D.txt");
  {
    // images.txt without 005.jpg, 006.jpg, 030.jpg (each an image line and its points line).
    std::ifstream in(src / "sparse" / "0" / "images.txt");
    std::ofstream out(tmp.path() / "sparse" / "0" / "images.txt");
    std::string line;
    bool skip_next = false;
    while (std::getline(in, line)) {
      if (skip_next) {
        skip_next = false;
        continue;
      }
      if (line.find("005.jpg") != std::string::npos || line.find("006.jpg") != std::string::npos ||
          line.find("030.jpg") != std::string::npos) {
        skip_next = true;
        continue;
      }
      out << line << "\n";
    }
  }
  const PipelineInput<S> in = load_colmap_input<S>(tmp.path().string(), "1-33", 64, 64);
  REQUIRE(in.cameras.size() == 90);
  REQUIRE(in.source.size() == 30);
  std::vector<std::string> names;
  for (int f : in.source) names.push_back(in.cameras[std::size_t(f)].name);
  for (const char* gone : {"005.jpg", "006.jpg", "030.jpg"})
    CHECK(std::find(names.begin(), names.end(), gone) == names.end());
  CHECK(names[4] == "007.jpg");
  CHECK(in.time_code(6) == Approx(6.0 / 32.0));  // 007.jpg keeps its place in time
  REQUIRE(in.source_skipped.size() == 3);
  CHECK(in.source_skipped[2].name == "030.jpg");
  // The points the model triangulated from all 90 frames: only those two source frames saw survive.
  const SourcePoints<S> sp = source_points(in);
  CHECK(sp.total > 1000);
  CHECK(sp.kept > 100);
  CHECK(sp.kept < sp.total);

  // The orbit and a (tiny) pipeline run use exactly those frames.
  PipelineParams p;
  p.orbit.views = 73;
  p.iters_g0 = p.iters_g1 = 20;
  p.median_samples = 8;
  p.train.field.width = 16;
  p.train.field.depth = 2;
  p.threads = 2;
  p.progress = false;
  p.static_proxy_diagnostics = false;
  p.completion = "none";
  run_pipeline(in, p, (tmp.path() / "run").string());
  const auto orbit = nlohmann::json::parse(read_file_bytes((tmp.path() / "run" / "orbit.json").string()));
  std::vector<std::string> fitted;
  for (const auto& s : orbit.at("source")) fitted.push_back(s.at("name").get<std::string>());
  CHECK(fitted == names);
  CHECK(orbit.at("source_frames").at("skipped").size() == 3);
  const auto report = nlohmann::json::parse(read_file_bytes((tmp.path() / "run" / "report.json").string()));
  CHECK(report.at("frames").at("trained").size() == 30);
  CHECK(report.at("points").at("kept") == sp.kept);
}

namespace {

// The angle (degrees) between two camera centres seen from the centres' centroid.
template <class S>
double centre_angle_deg(const Camera<S>& a, const Camera<S>& b, const Eigen::Matrix<S, 3, 1>& centroid) {
  const Eigen::Vector3d u = (a.center() - centroid).template cast<double>().normalized();
  const Eigen::Vector3d v = (b.center() - centroid).template cast<double>().normalized();
  return std::acos(std::max(-1.0, std::min(1.0, u.dot(v)))) * 180.0 / 3.14159265358979;
}

}  // namespace

TEMPLATE_TEST_CASE("ring_order: photographs named in any order come out around the ring, from one end",
                   "[pipeline][input]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  // 10 cameras every 25 degrees (a 225-degree arc), 2 m up, looking at the origin.
  const int n = 10;
  auto camera_at = [](double az_deg) {
    const double a = az_deg * 3.14159265358979 / 180;
    FrameCamera<S> f;
    f.valid = true;
    f.camera = Camera<S>::look_at(Vec3(S(3 * std::cos(a)), S(3 * std::sin(a)), S(2)), Vec3::Zero(), Vec3::UnitZ(),
                                  Intrinsics<S>{S(100), S(100), S(32), S(32), 64, 64});
    return f;
  };
  const std::vector<int> name_to_ring = {0, 1, 6, 2, 3, 4, 5, 9, 8, 7};  // as a gantry's file numbering might go
  std::vector<FrameCamera<S>> frames;
  for (int i = 0; i < n; ++i) {
    frames.push_back(camera_at(40 + 25.0 * name_to_ring[std::size_t(i)]));
    frames.back().name = "f" + std::to_string(i);
  }
  FrameCamera<S> lost;  // a photograph the model did not register
  lost.name = "lost";
  lost.valid = false;
  frames.insert(frames.begin() + 4, lost);

  auto check_ring = [&](const std::vector<FrameCamera<S>>& fs_, const std::vector<std::size_t>& order, int dir) {
    REQUIRE(order.size() == fs_.size());
    CHECK(fs_[order.back()].name == "lost");  // unregistered frames last
    const Vec3 ring_centre(0, 0, 2);
    for (std::size_t k = 0; k + 2 < order.size(); ++k) {
      CAPTURE(k);
      // Every step is to a 25-degree neighbour, all in one direction.
      const Vec3 ca = fs_[order[k]].camera.center(), cb = fs_[order[k + 1]].camera.center();
      CHECK(double(ca.x() * cb.y() - ca.y() * cb.x()) * dir > 0);
      CHECK(centre_angle_deg(fs_[order[k]].camera, fs_[order[k + 1]].camera, ring_centre) == Approx(25).margin(0.01));
    }
  };
  // Name order turns counter-clockwise on the whole: so does the ring order,
  // from the arc's first end (40 degrees).
  const auto order = ring_order(frames);
  check_ring(frames, order, +1);
  CHECK(frames[order.front()].name == "f0");
  // The same photographs named the other way round turn the other way.
  const std::vector<FrameCamera<S>> reversed(frames.rbegin(), frames.rend());
  const auto back = ring_order(reversed);
  check_ring(reversed, back, -1);
  CHECK(reversed[back.front()].name == "f7");  // ring position 9: the far end
  // Too few cameras to fit a ring.
  std::vector<FrameCamera<S>> two(frames.begin(), frames.begin() + 2);
  CHECK_THROWS_WITH(ring_order(two), Catch::Contains("at least 3 registered cameras"));
}

TEST_CASE("load_colmap_input: --image-order ring numbers the temple's photographs around its ring",
          "[pipeline][input][data]") {
  using S = float;
  if (!orbitforge_test::have_shared_data("middlebury/templeSparseRing")) return;
  const std::string temple = orbitforge_test::shared_path("middlebury/templeSparseRing");
  auto largest_step = [](const PipelineInput<S>& in) {
    Eigen::Vector3f centroid = Eigen::Vector3f::Zero();
    int count = 0;
    for (const auto& c : in.cameras)
      if (c.valid) centroid += c.camera.center(), ++count;
    centroid /= float(count);
    double worst = 0;
    for (std::size_t k = 0; k + 1 < in.cameras.size(); ++k)
      if (in.cameras[k].valid && in.cameras[k + 1].valid)
        worst = std::max(worst, centre_angle_deg(in.cameras[k].camera, in.cameras[k + 1].camera, centroid));
    return worst;
  };
  const PipelineInput<S> by_name = load_colmap_input<S>(temple, "1-", WorkingSize::longer_side(32));
  const PipelineInput<S> ring =
      load_colmap_input<S>(temple, "1-", WorkingSize::longer_side(32), false, ImageOrder::ring);
  REQUIRE(ring.cameras.size() == by_name.cameras.size());
  CHECK(largest_step(by_name) > 90);  // the file numbering jumps across the ring
  CHECK(largest_step(ring) < 40);     // 16 photographs around one ring
  CHECK(ring.description.find("numbered around the ring") != std::string::npos);
  // The same photographs, each with its own camera and image.
  for (const auto& c : ring.cameras) {
    const auto it = std::find_if(by_name.cameras.begin(), by_name.cameras.end(),
                                 [&](const FrameCamera<S>& b) { return b.name == c.name; });
    REQUIRE(it != by_name.cameras.end());
    CHECK((it->camera.t - c.camera.t).norm() == 0);
  }
}

#include <catch2/catch.hpp>

#include <chrono>
#include <cstdio>
#include <string>
#include <vector>

#include "io/io_test_util.hpp"
#include "orbitforge/io/colmap_observations.hpp"
#include "orbitforge/io/frames.hpp"
#include "support/data.hpp"

using namespace orbitforge;

TEST_CASE("colmap_bundle_input: observations in the caller's camera order", "[io][colmap]") {
  ColmapModel m;
  m.cameras = parse_colmap_cameras_text("1 SIMPLE_PINHOLE 64 48 50 32 24\n", "cameras.txt");
  m.images = parse_colmap_images_text(
      "5 1 0 0 0 0 0 0 1 b.png\n"
      "10 20 7 11 21 8 12 22 -1\n"
      "6 1 0 0 0 0 0 0 1 a.png\n"
      "1 2 8 3 4 7 5 6 9\n"
      "7 1 0 0 0 0 0 0 1 c.png\n"
      "30 31 7 32 33 99\n",
      "images.txt");
  m.points = parse_colmap_points3D_text(
      "7 1 2 3 0 0 0 0.5 5 0 6 1 7 0\n"
      "8 4 5 6 0 0 0 0.5 5 1 6 0\n"
      "9 7 8 9 0 0 0 0.5 6 2\n",
      "points3D.txt");
  // Camera order c, b, a (not the model's): point 7 seen by all three, point 8
  // by b and a, point 9 only by a (dropped), id 99 is not a point (skipped).
  const auto in = colmap_bundle_input<double>(m, std::vector<std::string>{"c.png", "b.png", "a.png"});
  REQUIRE(in.points.size() == 2);
  CHECK(in.point_ids == std::vector<std::int64_t>{7, 8});
  CHECK(in.points[1] == Eigen::Vector3d(4, 5, 6));
  CHECK(in.observations_per_camera == std::vector<int>{1, 2, 2});
  REQUIRE(in.observations.size() == 5);
  // Point 7: c (30, 31), b (10, 20), a (3, 4).
  CHECK(in.observations[0].camera == 0);
  CHECK(in.observations[0].point == 0);
  CHECK(in.observations[0].xy == Eigen::Vector2d(30, 31));
  CHECK(in.observations[1].camera == 1);
  CHECK(in.observations[1].xy == Eigen::Vector2d(10, 20));
  CHECK(in.observations[2].camera == 2);
  CHECK(in.observations[2].xy == Eigen::Vector2d(3, 4));
  // Point 8: b (11, 21), a (1, 2).
  CHECK(in.observations[3].point == 1);
  CHECK(in.observations[3].xy == Eigen::Vector2d(11, 21));
  CHECK(in.observations[4].xy == Eigen::Vector2d(1, 2));
  // min_track 1 keeps point 9.
  CHECK(colmap_bundle_input<float>(m, std::vector<std::string>{"c.png", "b.png", "a.png"}, 1).points.size() == 3);
  orbitforge_test::require_error(
      [&] { colmap_bundle_input<double>(m, std::vector<std::string>{"a.png", "d.png"}); },
      {"camera 1", "'d.png'", "no image"});
}

TEST_CASE("orbit_bundle_adjust on the recorded videos' frames 1-33", "[io][colmap][data]") {
  if (!orbitforge_test::have_shared_data("v3d")) return;
  for (const char* video : {"cool_teddy", "doll", "robot", "sunflower", "corgi_bread"}) {
    INFO(video);
    const auto model = read_colmap_model(orbitforge_test::shared_path(std::string("v3d/") + video));
    const auto frames = select_frames(colmap_frame_cameras<double>(model), FrameRange{1, 33});
    const auto in = colmap_bundle_input(model, frames);
    std::vector<Camera<double>> cams;
    for (const auto& f : frames) cams.push_back(f.camera);
    const auto t0 = std::chrono::steady_clock::now();
    const auto res = orbit_bundle_adjust(cams, in.points, in.observations);
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    double max_rot = 0, max_shift = 0;
    for (std::size_t i = 0; i < cams.size(); ++i) {
      max_rot = std::max(max_rot, res.rotation_change_deg[i]);
      max_shift = std::max(max_shift, res.center_shift[i]);
    }
    std::printf("orbit_ba %-11s: %zu points, %zu observations, %.2f s, %d iterations, rms %.3f -> %.3f px, max change "
                "%.3f deg / %.4f r\n",
                video, in.points.size(), in.observations.size(), seconds, res.iterations, res.initial_rms_px,
                res.final_rms_px, max_rot, max_shift);
    CHECK(in.points.size() > 500);
    for (int n : in.observations_per_camera) CHECK(n > 50);
    CHECK(res.final_cost <= res.initial_cost);
    CHECK(res.final_rms_px < 1.5);
    // The recorded cameras come from a bundle adjustment over all 90 frames; on
    // 1-33's observations alone the optimum moves, but by little (measured at
    // most 2.0 degrees / 0.034 r, on doll's last frame).
    CHECK(max_rot < 4);
    CHECK(max_shift < 0.07);
    // Its time is printed, not checked: a sanitizer build on a busy machine took 34 s
    // where a release build takes under 10 (speed targets live in bench/).
  }
  std::fflush(stdout);
}

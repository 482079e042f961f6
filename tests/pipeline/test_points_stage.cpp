// The points stage (a COLMAP model with cameras and no 3D points -> points
// COLMAP triangulates from the training frames at those cameras), on
// Middlebury's temple ring: the points lie on the object (its published
// bounding box), only training frames see them or reach COLMAP, and a resumed
// run re-reads a verified model and re-runs on a damaged one.
#include <catch2/catch.hpp>

#include <filesystem>
#include <string>

#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/image_order.hpp"
#include "orbitforge/pipeline/stages/points.hpp"
#include "support/data.hpp"
#include "support/programs.hpp"
#include "support/temp_dir.hpp"

using namespace orbitforge;

namespace points_stage_test {
namespace fs = std::filesystem;

struct TempDir : orbitforge_test::TempDir {
  TempDir() : orbitforge_test::TempDir("points_test") {}
};

TEST_CASE("points stage: the temple's triangulated points lie on the temple and come from training frames only",
          "[pipeline][points]") {
  if (!orbitforge_test::have_shared_data("middlebury/templeSparseRing")) return;
  if (!orbitforge_test::have_programs({"colmap"})) return;
  using S = float;
  const std::string dir = orbitforge_test::shared_path("middlebury/templeSparseRing");
  PipelineInput<S> in = load_colmap_input<S>(dir, "1-8", WorkingSize::from_pair(512, 384), /*normalise=*/true,
                                             ImageOrder::ring);
  withhold_every(in, 4);
  REQUIRE(in.withheld.size() == 2);
  REQUIRE(in.points.empty());
  REQUIRE(needs_triangulated_points(in));

  TempDir t;
  const std::string out = t.path().string();
  PointStageParams p;
  p.log = [](const std::string&) {};
  const PointStageResult r = stage_points(out, in, p);
  CHECK(r.ran);
  CHECK(!r.skipped);
  CHECK(r.frames == 6);
  CHECK(r.points >= 150);
  CHECK(!needs_triangulated_points(in));
  CHECK(in.points_origin == "triangulated by COLMAP from the 6 training frames at their cameras");
  REQUIRE(in.points.size() == 3 * r.points);
  REQUIRE(in.point_frames.size() == r.points);
  // Only the training frames reached COLMAP, and only they see a point.
  CHECK(list_image_files((t.path() / "points" / "images").string()).size() == 6);
  for (const auto& seen : in.point_frames) {
    CHECK(seen.size() >= 2);
    for (int f : seen) {
      CHECK(!in.is_withheld(f));
      CHECK(std::find(in.source.begin(), in.source.end(), f) != in.source.end());
    }
  }
  // The data set's tight bounding box of the temple, in the model's frame,
  // widened by a fifth of its size on each side: nearly every point on the object.
  const Eigen::Vector3d lo(-0.073568, 0.021728, -0.012445), hi(0.028855, 0.181892, 0.062736);
  const Eigen::Vector3d margin = 0.2 * (hi - lo);
  std::size_t inside = 0;
  for (std::size_t i = 0; i < r.points; ++i) {
    const Eigen::Vector3d x = in.frame.to_user(
        Eigen::Vector3d(double(in.points[3 * i]), double(in.points[3 * i + 1]), double(in.points[3 * i + 2])));
    inside += ((x.array() >= (lo - margin).array()).all() && (x.array() <= (hi + margin).array()).all()) ? 1 : 0;
  }
  CHECK(double(inside) >= 0.9 * double(r.points));
  for (S c : in.colors) CHECK((c >= 0 && c <= 1));

  SECTION("a second run verifies the record and reads the same points") {
    PipelineInput<S> again = load_colmap_input<S>(dir, "1-8", WorkingSize::from_pair(512, 384), true, ImageOrder::ring);
    withhold_every(again, 4);
    const PointStageResult r2 = stage_points(out, again, p);
    CHECK(r2.skipped);
    CHECK(!r2.ran);
    CHECK(r2.key == r.key);
    CHECK(!r2.key.empty());
    CHECK(again.points == in.points);
    CHECK(again.point_frames == in.point_frames);
  }
  SECTION("more frames than the exhaustive limit are matched in sequence") {
    PipelineInput<S> again = load_colmap_input<S>(dir, "1-8", WorkingSize::from_pair(512, 384), true, ImageOrder::ring);
    withhold_every(again, 4);
    PointStageParams seq = p;
    seq.exhaustive_up_to = 4;
    const PointStageResult r2 = stage_points(out, again, seq);
    CHECK(r2.ran);  // the matcher is part of the key
    CHECK(fs::exists(t.path() / "points" / "logs" / "sequential_matcher.log"));
    CHECK(!fs::exists(t.path() / "points" / "logs" / "exhaustive_matcher.log"));
    CHECK(r2.points >= 100);
  }
  SECTION("a damaged model or other training frames run COLMAP again") {
    const fs::path points_file = t.path() / "points" / "sparse" / "points3D.bin";
    std::string bytes = read_file_bytes(points_file.string());
    bytes[bytes.size() / 2] = char(bytes[bytes.size() / 2] ^ 0x5a);
    write_file_atomic(points_file.string(), bytes);
    PipelineInput<S> again = load_colmap_input<S>(dir, "1-8", WorkingSize::from_pair(512, 384), true, ImageOrder::ring);
    withhold_every(again, 4);
    const PointStageResult r2 = stage_points(out, again, p);
    CHECK(r2.ran);
    CHECK(again.points.size() >= 150);  // COLMAP's matching is not bit-reproducible: about as many

    PipelineInput<S> other = load_colmap_input<S>(dir, "1-8", WorkingSize::from_pair(512, 384), true, ImageOrder::ring);
    withhold_every(other, 3);
    const PointStageResult r3 = stage_points(out, other, p);
    CHECK(r3.ran);
    CHECK(r3.frames == 6);
    CHECK(r3.points > 0);
    for (const auto& seen : other.point_frames)
      for (int f : seen) CHECK(!other.is_withheld(f));
  }
}

TEST_CASE("points stage: frames with nothing in common give no points and leave the input as it was",
          "[pipeline][points]") {
  if (!orbitforge_test::have_programs({"colmap"})) return;
  // Two blank frames: no features, nothing to match or triangulate.
  PipelineInput<float> in;
  for (int i = 0; i < 2; ++i) {
    FrameCamera<float> c;
    c.name = std::to_string(i) + ".png";
    c.camera = Camera<float>::look_at(Eigen::Vector3f(3.0f * float(i), 0, -4), Eigen::Vector3f::Zero(),
                                      Eigen::Vector3f(0, -1, 0));
    c.camera.intrinsics = Intrinsics<float>{80, 80, 32, 32, 64, 64};
    in.cameras.push_back(c);
    in.images.push_back(Image<float>(64, 64, 3, 0.5f));
    in.source.push_back(i);
  }
  TempDir t;
  PointStageParams p;
  std::string said;
  p.log = [&said](const std::string& s) { said += s; };
  const PointStageResult r = stage_points(t.path().string(), in, p);
  CHECK(r.ran);
  CHECK(r.points == 0);
  CHECK(in.points.empty());
  CHECK(r.key.empty());
  CHECK(said.find("COLMAP triangulated no points from the 2 training frames") != std::string::npos);
  CHECK(!fs::exists(t.path() / "stages" / "points.json"));
}

TEST_CASE("points stage: fewer than two training frames is an error naming the problem", "[pipeline][points]") {
  PipelineInput<float> in;
  FrameCamera<float> c;
  c.name = "a.png";
  c.camera.intrinsics = Intrinsics<float>{100, 100, 50, 50, 100, 100};
  in.cameras.push_back(c);
  in.images.push_back(Image<float>(100, 100, 3));
  in.source = {0};
  TempDir t;
  CHECK_THROWS_WITH(stage_points(t.path().string(), in),
                    "points stage: triangulation needs at least two training frames, the input has 1");
}

}  // namespace points_stage_test

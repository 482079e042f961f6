// Recorded inputs with cameras from transforms.json or VGGT-style .npy arrays
// beside a folder of frames (pipeline/inputs/frame_inputs.hpp): frames in name order,
// cameras matched by file name or by position, intrinsics at the working size,
// and frames without a camera skipped with a reason.
#include <catch2/catch.hpp>

#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/npy.hpp"
#include "orbitforge/io/transforms_json.hpp"
#include "orbitforge/pipeline/inputs/frame_inputs.hpp"

using namespace orbitforge;

// The test cases too live in a named namespace: the layer's test files are compiled as
// one unity source, so nothing here may reach another file's names.
namespace frame_inputs_test {
namespace fs = std::filesystem;

struct Folder {
  fs::path root;
  Folder() {
    std::random_device rd;
    root = fs::temp_directory_path() / ("orbitforge_frame_inputs_" + std::to_string(rd()));
    fs::create_directories(root / "frames");
  }
  ~Folder() {
    std::error_code ec;
    fs::remove_all(root, ec);
  }
};

// Six 16 x 12 frames (each a flat grey of its own) and a camera for each, looking along +z.
std::vector<FrameCamera<double>> write_frames(const fs::path& dir) {
  std::vector<FrameCamera<double>> cams;
  for (int i = 0; i < 6; ++i) {
    const std::string name = "frame_" + std::to_string(10 + i) + ".png";
    write_png((dir / name).string(), Image<float>(16, 12, 3, 0.1f * float(i + 1)));
    FrameCamera<double> fc;
    fc.name = name;
    fc.camera.intrinsics = {20, 21, 8, 6, 16, 12};
    fc.camera.t = Eigen::Vector3d(0.5 * i, 0, 4);
    cams.push_back(fc);
  }
  return cams;
}


TEST_CASE("frame inputs: transforms.json with an image folder, matched by file name", "[pipeline][input]") {
  Folder f;
  auto cams = write_frames(f.root / "frames");
  auto listed = cams;
  listed.erase(listed.begin() + 2);  // frame 3 has no camera
  for (auto& c : listed) c.name = "images/" + c.name;
  const std::string tj = (f.root / "transforms.json").string();
  write_transforms_json(tj, listed);

  const auto in =
      load_transforms_input<float>(tj, (f.root / "frames").string(), "1-5", WorkingSize::exact(8, 8));
  REQUIRE(in.cameras.size() == 6);
  CHECK(in.width == 8);
  CHECK(in.height == 8);
  CHECK(in.source == std::vector<int>{0, 1, 3, 4});
  REQUIRE(in.source_skipped.size() == 1);
  CHECK(in.source_skipped[0].name == "frame_12.png");
  CHECK(in.cameras[3].name == "frame_13.png");
  CHECK(in.cameras[3].camera.t.x() == Approx(1.5));
  CHECK(in.cameras[0].camera.intrinsics.fx == Approx(10));  // 20 at 16 wide -> 10 at 8 wide
  CHECK(in.images[3](2, 2, 0) == Approx(0.4f).margin(0.01f));
  CHECK(in.points.empty());

  // A transforms frame whose image is not in the folder is an error naming it.
  fs::remove(f.root / "frames" / "frame_15.png");
  CHECK_THROWS_WITH(
      load_transforms_input<float>(tj, (f.root / "frames").string(), "1-3", WorkingSize::exact(8, 8)),
                    Catch::Contains("frame_15.png has no image"));
}

TEST_CASE("frame inputs: transforms.json with its own file paths at the frames' size", "[pipeline][input]") {
  Folder f;
  auto cams = write_frames(f.root / "frames");
  for (auto& c : cams) c.name = "frames/" + c.name;
  const std::string tj = (f.root / "transforms.json").string();
  write_transforms_json(tj, cams);
  const auto in = load_transforms_input<float>(tj, "", "2-6", WorkingSize::native());
  CHECK(in.width == 16);
  CHECK(in.height == 12);
  CHECK(in.source.size() == 5);
  CHECK(in.cameras[0].camera.intrinsics.fy == Approx(21));
}

TEST_CASE("frame inputs: npy arrays, camera i for the i-th image, intrinsics from the estimator's size",
          "[pipeline][input]") {
  Folder f;
  const auto cams = write_frames(f.root / "frames");
  // As VGGT would store them for 32 x 24 inputs: K at twice the frames' size.
  std::vector<double> e, k;
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const Eigen::Matrix4d T = cams[i].camera.camera_T_world();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 4; ++c) e.push_back(i == 4 ? std::nan("") : T(r, c));  // frame 5: no camera
    const Eigen::Matrix3d K = cams[i].camera.intrinsics.resized(32, 24).K();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) k.push_back(K(r, c));
  }
  const std::string ext = (f.root / "extrinsic.npy").string(), intr = (f.root / "intrinsic.npy").string();
  write_npy(ext, {cams.size(), 3, 4}, e);
  write_npy(intr, {cams.size(), 3, 3}, k);

  const auto in = load_npy_input<float>(ext, intr, (f.root / "frames").string(), 32, 24, "1-6",
                                        WorkingSize::exact(16, 12));
  CHECK(in.source == std::vector<int>{0, 1, 2, 3, 5});
  CHECK(in.cameras[1].camera.intrinsics.fx == Approx(20));
  CHECK(in.cameras[1].camera.intrinsics.cx == Approx(8));
  CHECK(in.cameras[5].camera.t.x() == Approx(2.5));
  CHECK(in.cameras[5].name == "frame_15.png");

  // The longer side given: the frames' 4:3 aspect is kept, and the intrinsics follow.
  const auto smaller = load_npy_input<float>(ext, intr, (f.root / "frames").string(), 32, 24, "1-6",
                                             WorkingSize::longer_side(12));
  CHECK(smaller.width == 12);
  CHECK(smaller.height == 9);
  CHECK(smaller.images[0].width == 12);
  CHECK(smaller.images[0].height == 9);
  CHECK(smaller.cameras[1].camera.intrinsics.fx == Approx(15));
  CHECK(smaller.cameras[1].camera.intrinsics.cy == Approx(4.5));

  // One camera too few for the folder: an error that says how they pair up.
  write_npy(ext, {5, 3, 4}, std::vector<double>(e.begin(), e.begin() + 60));
  write_npy(intr, {5, 3, 3}, std::vector<double>(k.begin(), k.begin() + 45));
  CHECK_THROWS_WITH(
      load_npy_input<float>(ext, intr, (f.root / "frames").string(), 0, 0, "1-5", WorkingSize::exact(16, 12)),
                    Catch::Contains("5 cameras but"));
}

}  // namespace frame_inputs_test

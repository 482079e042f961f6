#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "io/io_test_util.hpp"
#include "orbitforge/io/colmap.hpp"
#include "support/data.hpp"

using namespace orbitforge;
using orbitforge_test::require_error;
using orbitforge_test::TempDir;

namespace {

void write_text(const std::string& path, const std::string& text) {
  std::ofstream out(path, std::ios::binary);
  out << text;
}

template <class S>
double colmap_tol() {
  return std::is_same<S, double>::value ? 1e-12 : 1e-5;
}

// Little-endian byte writer for building COLMAP binary files in the test.
struct Bytes {
  std::string s;
  template <class T>
  Bytes& put(T v) {
    unsigned char raw[sizeof(T)];
    std::memcpy(raw, &v, sizeof(T));
    // The test machine is little-endian (x86/arm64); the reader does not assume it.
    s.append(reinterpret_cast<const char*>(raw), sizeof(T));
    return *this;
  }
  Bytes& name(const std::string& n) {
    s += n;
    s += '\0';
    return *this;
  }
};

// The same small model as text and as binary.
const char* kCamerasTxt =
    "# Camera list\n"
    "3 SIMPLE_RADIAL 640 480 500.5 320.25 240.75 -0.01\n"
    "7 PINHOLE 800 600 700 710 400.5 300.5\n";
const char* kImagesTxt =
    "# Image list\n"
    "11 0.9 0.1 -0.2 0.3 1.5 -2.5 3.25 7 b.png\n"
    "10.5 20.5 4 30.5 40.5 -1\n"
    "12 1 0 0 0 0 0 0 3 a.png\n"
    "\n"
    "13 0.5 0.5 0.5 0.5 -1 -2 -3 7 c.png\n"
    "1 2 -1\n";
const char* kPointsTxt =
    "# points\n"
    "4 0.5 1.5 2.5 10 20 30 0.75 11 0 13 0\n"
    "9 -1 -2 -3 255 0 128 1.25 11 1\n";

std::string cameras_bin() {
  Bytes b;
  b.put<std::uint64_t>(2);
  b.put<std::int32_t>(3).put<std::int32_t>(2).put<std::uint64_t>(640).put<std::uint64_t>(480);
  for (double v : {500.5, 320.25, 240.75, -0.01}) b.put(v);
  b.put<std::int32_t>(7).put<std::int32_t>(1).put<std::uint64_t>(800).put<std::uint64_t>(600);
  for (double v : {700.0, 710.0, 400.5, 300.5}) b.put(v);
  return b.s;
}

std::string images_bin() {
  Bytes b;
  b.put<std::uint64_t>(3);
  b.put<std::int32_t>(11);
  for (double v : {0.9, 0.1, -0.2, 0.3, 1.5, -2.5, 3.25}) b.put(v);
  b.put<std::int32_t>(7).name("b.png").put<std::uint64_t>(2);
  b.put(10.5).put(20.5).put<std::int64_t>(4).put(30.5).put(40.5).put<std::int64_t>(-1);
  b.put<std::int32_t>(12);
  for (double v : {1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0}) b.put(v);
  b.put<std::int32_t>(3).name("a.png").put<std::uint64_t>(0);
  b.put<std::int32_t>(13);
  for (double v : {0.5, 0.5, 0.5, 0.5, -1.0, -2.0, -3.0}) b.put(v);
  b.put<std::int32_t>(7).name("c.png").put<std::uint64_t>(1);
  b.put(1.0).put(2.0).put<std::int64_t>(-1);
  return b.s;
}

std::string points_bin() {
  Bytes b;
  b.put<std::uint64_t>(2);
  b.put<std::uint64_t>(4).put(0.5).put(1.5).put(2.5).put<std::uint8_t>(10).put<std::uint8_t>(20).put<std::uint8_t>(30);
  b.put(0.75).put<std::uint64_t>(2).put<std::int32_t>(11).put<std::int32_t>(0).put<std::int32_t>(13).put<std::int32_t>(0);
  b.put<std::uint64_t>(9).put(-1.0).put(-2.0).put(-3.0).put<std::uint8_t>(255).put<std::uint8_t>(0).put<std::uint8_t>(128);
  b.put(1.25).put<std::uint64_t>(1).put<std::int32_t>(11).put<std::int32_t>(1);
  return b.s;
}

void require_same_models(const ColmapModel& a, const ColmapModel& b) {
  REQUIRE(a.cameras.size() == b.cameras.size());
  for (const auto& [id, c] : a.cameras) {
    REQUIRE(b.cameras.count(id) == 1);
    const ColmapCamera& d = b.cameras.at(id);
    CHECK(c.id == d.id);
    CHECK(c.model == d.model);
    CHECK(c.width == d.width);
    CHECK(c.height == d.height);
    CHECK(c.params == d.params);
  }
  REQUIRE(a.images.size() == b.images.size());
  for (const auto& [id, im] : a.images) {
    REQUIRE(b.images.count(id) == 1);
    const ColmapImage& j = b.images.at(id);
    CHECK(im.qvec == j.qvec);
    CHECK(im.tvec == j.tvec);
    CHECK(im.camera_id == j.camera_id);
    CHECK(im.name == j.name);
    REQUIRE(im.points2D.size() == j.points2D.size());
    for (std::size_t k = 0; k < im.points2D.size(); ++k) {
      CHECK(im.points2D[k].xy == j.points2D[k].xy);
      CHECK(im.points2D[k].point3D_id == j.points2D[k].point3D_id);
    }
  }
  REQUIRE(a.points.size() == b.points.size());
  for (std::size_t i = 0; i < a.points.size(); ++i) {
    CHECK(a.points[i].id == b.points[i].id);
    CHECK(a.points[i].xyz == b.points[i].xyz);
    CHECK(a.points[i].rgb == b.points[i].rgb);
    CHECK(a.points[i].error == b.points[i].error);
    CHECK(a.points[i].track_images == b.points[i].track_images);
    CHECK(a.points[i].track_point2D == b.points[i].track_point2D);
  }
}

}  // namespace

TEMPLATE_TEST_CASE("COLMAP text: write then read gives the same cameras", "[io][colmap]", float, double) {
  using S = TestType;
  auto cams = orbitforge_test::random_frame_cameras<S>(12, 1234);
  TempDir tmp("colmap_rt");
  const std::string model_dir = tmp.str("sparse/0");
  write_colmap_text(model_dir, cams);
  // Read through the dataset folder: exercises find_colmap_model_dir too.
  const ColmapModel model = read_colmap_model(tmp.str());
  REQUIRE(model.cameras.size() == cams.size());
  REQUIRE(model.images.size() == cams.size());
  CHECK(model.points.empty());
  const auto back = colmap_frame_cameras<S>(model);
  REQUIRE(back.size() == cams.size());
  for (std::size_t i = 0; i < cams.size(); ++i) orbitforge_test::require_same_cameras(cams[i], back[i], colmap_tol<S>());

  // Frames with valid = false are left out of the model.
  cams[3].valid = false;
  write_colmap_text(model_dir, cams);
  const auto fewer = colmap_frame_cameras<S>(read_colmap_text(model_dir));
  REQUIRE(fewer.size() == cams.size() - 1);
  CHECK(fewer[3].name == cams[4].name);
}

TEMPLATE_TEST_CASE("COLMAP pose and intrinsics follow the documented conventions", "[io][colmap]", float, double) {
  using S = TestType;
  // 90 degrees about z: q = (cos 45, 0, 0, sin 45); x_cam = R x_world + t.
  const double h = std::sqrt(0.5);
  std::ostringstream images;
  images.precision(17);
  images << "1 " << h << " 0 0 " << h << " 1 2 3 1 z90.png\n\n";
  ColmapModel m;
  m.cameras = parse_colmap_cameras_text("1 OPENCV 640 480 500 510 320 240 0.1 0.2 0.01 0.02\n", "cameras.txt");
  m.images = parse_colmap_images_text(images.str(), "images.txt");
  const auto cams = colmap_frame_cameras<S>(m);
  REQUIRE(cams.size() == 1);
  const Camera<S>& c = cams[0].camera;
  Eigen::Matrix<S, 3, 3> R_expected;
  R_expected << 0, -1, 0, 1, 0, 0, 0, 0, 1;
  CHECK((c.R - R_expected).cwiseAbs().maxCoeff() < 1e-6);
  CHECK((c.t - Eigen::Matrix<S, 3, 1>(1, 2, 3)).cwiseAbs().maxCoeff() < 1e-6);
  // A world point on the x axis lands on camera y (+1) after the rotation.
  const Eigen::Matrix<S, 3, 1> x_cam = c.to_camera(Eigen::Matrix<S, 3, 1>(1, 0, 0));
  CHECK((x_cam - Eigen::Matrix<S, 3, 1>(1, 3, 3)).cwiseAbs().maxCoeff() < 1e-6);
  CHECK(c.intrinsics.fx == S(500));
  CHECK(c.intrinsics.fy == S(510));
  CHECK(c.intrinsics.cx == S(320));
  CHECK(c.intrinsics.cy == S(240));
  CHECK(c.intrinsics.width == 640);
  CHECK(c.intrinsics.height == 480);

  // Parameter layout of every model: single-focal models are f, cx, cy, ...
  struct Case {
    const char* model;
    int n;
    double fx, fy, cx, cy;
  };
  const Case cases[] = {
      {"SIMPLE_PINHOLE", 3, 1, 1, 2, 3},        {"PINHOLE", 4, 1, 2, 3, 4},
      {"SIMPLE_RADIAL", 4, 1, 1, 2, 3},         {"RADIAL", 5, 1, 1, 2, 3},
      {"OPENCV", 8, 1, 2, 3, 4},                {"OPENCV_FISHEYE", 8, 1, 2, 3, 4},
      {"FULL_OPENCV", 12, 1, 2, 3, 4},          {"FOV", 5, 1, 2, 3, 4},
      {"SIMPLE_RADIAL_FISHEYE", 4, 1, 1, 2, 3}, {"RADIAL_FISHEYE", 5, 1, 1, 2, 3},
      {"THIN_PRISM_FISHEYE", 12, 1, 2, 3, 4},
  };
  for (const Case& cs : cases) {
    INFO(cs.model);
    std::ostringstream line;
    line << "5 " << cs.model << " 100 50";
    for (int i = 1; i <= cs.n; ++i) line << ' ' << i;
    const auto cameras = parse_colmap_cameras_text(line.str(), "cameras.txt");
    const Intrinsics<S> k = colmap_intrinsics<S>(cameras.at(5));
    CHECK(k.fx == S(cs.fx));
    CHECK(k.fy == S(cs.fy));
    CHECK(k.cx == S(cs.cx));
    CHECK(k.cy == S(cs.cy));
    CHECK(k.width == 100);
    CHECK(k.height == 50);
  }
}

TEST_CASE("COLMAP binary model equals the same model in text", "[io][colmap]") {
  TempDir tmp("colmap_bin");
  write_text(tmp.str("cameras.bin"), cameras_bin());
  write_text(tmp.str("images.bin"), images_bin());
  write_text(tmp.str("points3D.bin"), points_bin());
  TempDir txt("colmap_txt");
  write_text(txt.str("cameras.txt"), kCamerasTxt);
  write_text(txt.str("images.txt"), kImagesTxt);
  write_text(txt.str("points3D.txt"), kPointsTxt);

  const ColmapModel b = read_colmap_binary(tmp.str());
  const ColmapModel t = read_colmap_text(txt.str());
  REQUIRE(b.cameras.size() == 2);
  REQUIRE(b.images.size() == 3);
  REQUIRE(b.points.size() == 2);
  CHECK(b.cameras.at(3).model == "SIMPLE_RADIAL");
  CHECK(b.images.at(13).name == "c.png");
  CHECK(b.points[1].rgb == std::array<std::uint8_t, 3>{{255, 0, 128}});
  CHECK(t.points[0].track_images == std::vector<int>{11, 13});  // which images saw each point
  CHECK(b.points[1].track_images == std::vector<int>{11});
  // The 2D observations: each image's keypoints with their 3D point (-1: none),
  // and each track element's keypoint index.
  for (const ColmapModel* m : {&b, &t}) {
    const ColmapImage& im11 = m->images.at(11);
    REQUIRE(im11.points2D.size() == 2);
    CHECK(im11.points2D[0].xy == Eigen::Vector2d(10.5, 20.5));
    CHECK(im11.points2D[0].point3D_id == 4);
    CHECK(im11.points2D[1].xy == Eigen::Vector2d(30.5, 40.5));
    CHECK(im11.points2D[1].point3D_id == -1);
    CHECK(m->images.at(12).points2D.empty());
    REQUIRE(m->images.at(13).points2D.size() == 1);
    CHECK(m->images.at(13).points2D[0].xy == Eigen::Vector2d(1, 2));
    CHECK(m->points[0].track_point2D == std::vector<int>{0, 0});
    CHECK(m->points[1].track_point2D == std::vector<int>{1});
  }
  require_same_models(b, t);

  const auto fb = colmap_frame_cameras<double>(b);
  REQUIRE(fb.size() == 3);
  CHECK(fb[0].name == "a.png");  // sorted by name, not by image id
  CHECK(fb[1].name == "b.png");
  CHECK(fb[2].name == "c.png");
  CHECK(fb[0].camera.intrinsics.fx == 500.5);
  CHECK(fb[1].camera.intrinsics.fy == 710.0);

  // Both formats in one folder: binary is read. Make the text differ to tell.
  write_text(tmp.str("cameras.txt"), "3 SIMPLE_RADIAL 640 480 1 1 1 0\n7 PINHOLE 800 600 1 1 1 1\n");
  write_text(tmp.str("images.txt"), kImagesTxt);
  const ColmapModel both = read_colmap_model(tmp.str());
  CHECK(both.cameras.at(3).params[0] == 500.5);

  // points3D is optional.
  std::filesystem::remove(tmp.str("points3D.bin"));
  CHECK(read_colmap_binary(tmp.str()).points.empty());
}

TEST_CASE("COLMAP text: a whole model (observations and tracks) is written and read back exactly", "[io][colmap]") {
  TempDir tmp("colmap_model_rt");
  write_text(tmp.str("cameras.bin"), cameras_bin());
  write_text(tmp.str("images.bin"), images_bin());
  write_text(tmp.str("points3D.bin"), points_bin());
  ColmapModel m = read_colmap_binary(tmp.str());
  // Values that need all 17 digits survive.
  m.images.at(11).tvec.x() = 0.1 + 1e-16;
  m.points[0].xyz.y() = -1.0 / 3.0;
  m.images.at(12).name = "with space.png";
  write_colmap_model_text(tmp.str("text"), m);
  const ColmapModel back = read_colmap_text(tmp.str("text"));
  require_same_models(m, back);

  m.images.at(13).name = "two\nlines.png";
  CHECK_THROWS_WITH(write_colmap_model_text(tmp.str("bad"), m), Catch::Contains("cannot be stored"));
  m.images.at(13).name = "c.png";
  m.images.at(13).qvec[0] = std::nan("");
  CHECK_THROWS_WITH(write_colmap_model_text(tmp.str("bad"), m), Catch::Contains("non-finite pose"));
}

TEST_CASE("COLMAP binary: corrupt files are clear errors", "[io][colmap]") {
  // Every truncation of every file is an Error (never a crash or a huge allocation).
  for (const auto& [name, bytes] : std::vector<std::pair<std::string, std::string>>{
           {"cameras.bin", cameras_bin()}, {"images.bin", images_bin()}, {"points3D.bin", points_bin()}}) {
    for (std::size_t n = 0; n < bytes.size(); ++n) {
      INFO(name << " cut to " << n << " bytes");
      const std::string cut = bytes.substr(0, n);
      require_error(
          [&] {
            if (name == "cameras.bin") parse_colmap_cameras_binary(cut, name);
            if (name == "images.bin") parse_colmap_images_binary(cut, name);
            if (name == "points3D.bin") parse_colmap_points3D_binary(cut, name);
          },
          {name});
    }
  }
  require_error([] { parse_colmap_cameras_binary(cameras_bin().substr(0, 30), "cameras.bin"); },
                {"cameras.bin", "truncated", "byte offset"});
  // A corrupt count must not allocate: 2^40 cameras in a 100-byte file.
  {
    std::string b = cameras_bin();
    const std::uint64_t huge = std::uint64_t(1) << 40;
    std::memcpy(&b[0], &huge, 8);
    require_error([&] { parse_colmap_cameras_binary(b, "cameras.bin"); }, {"cameras.bin", "cannot fit"});
  }
  {
    std::string b = points_bin();
    const std::uint64_t huge = ~std::uint64_t(0);
    std::memcpy(&b[8 + 8 + 24 + 3 + 8], &huge, 8);  // first point's track length
    require_error([&] { parse_colmap_points3D_binary(b, "points3D.bin"); }, {"points3D.bin", "track element", "cannot fit"});
  }
  {
    std::string b = cameras_bin();
    const std::int32_t bad_model = 42;
    std::memcpy(&b[8 + 4], &bad_model, 4);
    require_error([&] { parse_colmap_cameras_binary(b, "cameras.bin"); },
                  {"cameras.bin", "camera record 0", "byte offset 8", "unknown camera model id 42"});
  }
  {
    // A POINTS2D count beyond the file: refused before anything is allocated.
    std::string b = images_bin();
    const std::size_t at = 8 + 4 + 7 * 8 + 4 + 6;  // first image's POINTS2D count, after "b.png\0"
    const std::uint64_t huge = std::uint64_t(1) << 50;
    std::memcpy(&b[at], &huge, 8);
    require_error([&] { parse_colmap_images_binary(b, "images.bin"); }, {"images.bin", "POINTS2D count", "cannot fit"});
  }
  {
    std::string b = images_bin();
    const std::size_t at = 8 + 4 + 7 * 8 + 4 + 6 + 8 + 16;  // first keypoint's POINT3D_ID
    const std::int64_t bad = -7;
    std::memcpy(&b[at], &bad, 8);
    require_error([&] { parse_colmap_images_binary(b, "images.bin"); },
                  {"images.bin", "image record 0", "POINTS2D 0", "POINT3D_ID -7"});
  }
  {
    std::string b = points_bin();
    const std::uint32_t bad = 0x80000000u;
    std::memcpy(&b[8 + 8 + 24 + 3 + 8 + 8 + 4], &bad, 4);  // first point's first POINT2D_IDX
    require_error([&] { parse_colmap_points3D_binary(b, "points3D.bin"); },
                  {"points3D.bin", "point record 0", "point2D index 2147483648", "too large"});
  }
  require_error([] { parse_colmap_images_binary(images_bin() + "xyz", "images.bin"); },
                {"images.bin", "3 unexpected bytes"});
  {
    // A name without its NUL: cut the file in the middle of the last name.
    const std::string b = images_bin();
    const std::size_t pos = b.rfind("c.png");
    require_error([&] { parse_colmap_images_binary(b.substr(0, pos + 3), "images.bin"); },
                  {"images.bin", "no terminating NUL"});
  }
  {
    std::string b = images_bin();
    const double zero = 0;
    for (int k = 0; k < 4; ++k) std::memcpy(&b[8 + 4 + 8 * k], &zero, 8);
    require_error([&] { parse_colmap_images_binary(b, "images.bin"); }, {"images.bin", "image record 0", "zero norm"});
  }
}

TEST_CASE("COLMAP text: bad input is a clear error naming file and line", "[io][colmap]") {
  require_error([] { parse_colmap_cameras_text("# c\n# d\n1 PINHOLE 640 480 abc 1 2 3\n", "cameras.txt"); },
                {"cameras.txt:3", "'abc' is not a number"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 640 480 1.5x 1 2 3\n", "cameras.txt"); },
                {"cameras.txt:1", "not a number"});
  require_error([] { parse_colmap_cameras_text("1 BROWN 640 480 1 1 2 3\n", "cameras.txt"); },
                {"cameras.txt:1", "unknown camera model 'BROWN'"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 640 480 1 2 3\n", "cameras.txt"); },
                {"cameras.txt:1", "needs 4 parameters, got 3"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 640\n", "cameras.txt"); },
                {"cameras.txt:1", "expected CAMERA_ID MODEL WIDTH HEIGHT"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 0 480 1 1 1 1\n", "cameras.txt"); },
                {"cameras.txt:1", "must be positive"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 640 480 nan 1 1 1\n", "cameras.txt"); },
                {"cameras.txt:1", "not finite"});
  require_error([] { parse_colmap_cameras_text("1 PINHOLE 640 480 1 1 1 1\n1 PINHOLE 640 480 1 1 1 1\n", "cameras.txt"); },
                {"cameras.txt:2", "duplicate CAMERA_ID 1"});
  require_error([] { parse_colmap_cameras_text("99999999999 PINHOLE 640 480 1 1 1 1\n", "cameras.txt"); },
                {"cameras.txt:1", "out of range"});

  require_error([] { parse_colmap_images_text("1 1 0 0 0 0 0 0 1\n\n", "images.txt"); },
                {"images.txt:1", "expected IMAGE_ID"});
  require_error([] { parse_colmap_images_text("1 0 0 0 0 0 0 0 1 a.png\n\n", "images.txt"); },
                {"images.txt:1", "zero norm"});
  require_error([] { parse_colmap_images_text("#\n1 1 0 0 0 0 0 0 1 a.png\n1 2\n", "images.txt"); },
                {"images.txt:3", "POINTS2D", "triples"});
  require_error([] { parse_colmap_images_text("1 1 0 0 0 0 0 0 1 a.png\n1 2 x\n", "images.txt"); },
                {"images.txt:2", "POINT3D_ID", "'x'"});
  require_error([] { parse_colmap_images_text("1 1 0 0 0 0 0 0 1 a.png\n1 2 3 4 5 -2\n", "images.txt"); },
                {"images.txt:2", "image 1", "POINTS2D 1", "POINT3D_ID -2"});
  require_error(
      [] { parse_colmap_images_text("1 1 0 0 0 0 0 0 1 a.png\n\n1 1 0 0 0 0 0 0 1 b.png\n\n", "images.txt"); },
      {"images.txt:3", "duplicate IMAGE_ID 1"});

  require_error([] { parse_colmap_points3D_text("1 0 0 0 1 2 300 0.5\n", "points3D.txt"); },
                {"points3D.txt:1", "outside 0..255"});
  require_error([] { parse_colmap_points3D_text("1 0 0 0 1 2 3 0.5 7\n", "points3D.txt"); },
                {"points3D.txt:1", "TRACK[]", "pairs"});
  require_error([] { parse_colmap_points3D_text("1 0 0 0 1 2 3 0.5 7 -1\n", "points3D.txt"); },
                {"points3D.txt:1", "POINT2D_IDX -1", "negative"});
  require_error([] { parse_colmap_points3D_text("1 0 0 0 1 2 3\n", "points3D.txt"); },
                {"points3D.txt:1", "expected POINT3D_ID"});

  // Through files: the message carries the full path.
  TempDir tmp("colmap_err");
  write_text(tmp.str("cameras.txt"), "1 PINHOLE 640 480 1 1 1 1\n");
  write_text(tmp.str("images.txt"), "# x\n5 1 0 0 0 0 0 0 7 a.png\n\n");
  require_error([&] { read_colmap_text(tmp.str()); }, {tmp.str("images.txt"), "image 5", "references camera 7"});
  write_text(tmp.str("images.txt"), "5 1 0 0 0 0 0 0 1 a.png\n\n");
  write_text(tmp.str("points3D.txt"), "1 2 3\n");
  require_error([&] { read_colmap_text(tmp.str()); }, {tmp.str("points3D.txt") + ":1"});
  std::filesystem::remove(tmp.str("images.txt"));
  require_error([&] { read_colmap_text(tmp.str()); }, {tmp.str("images.txt"), "does not exist"});
  require_error([&] { find_colmap_model_dir(tmp.str()); }, {"no COLMAP model found", tmp.str(), "sparse/0"});
  require_error([&] { read_colmap_model(tmp.str("nowhere")); }, {"no COLMAP model found", "nowhere"});

  // The writer refuses what the reader would reject, naming the file.
  auto cams = orbitforge_test::random_frame_cameras<double>(3, 8);
  cams[1].camera.intrinsics.fx = 0;
  require_error([&] { write_colmap_text(tmp.str("out"), cams); }, {"cameras.txt", "frame 1", "focal"});
  cams = orbitforge_test::random_frame_cameras<double>(3, 8);
  cams[2].name = "two\nlines";
  require_error([&] { write_colmap_text(tmp.str("out"), cams); }, {"images.txt", "frame 2", "cannot be stored"});
}

TEMPLATE_TEST_CASE("COLMAP non-finite poses become invalid frames, kept in order", "[io][colmap]", float, double) {
  ColmapModel m;
  m.cameras = parse_colmap_cameras_text("1 SIMPLE_PINHOLE 64 48 50 32 24\n", "cameras.txt");
  m.images = parse_colmap_images_text(
      "1 1 0 0 0 0 0 0 1 f1.png\n\n"
      "2 nan 0 0 0 0 0 0 1 f2.png\n\n"
      "3 1 0 0 0 0 inf 0 1 f3.png\n\n"
      "4 1 0 0 0 1 2 3 1 f4.png\n",
      "images.txt");
  const auto cams = colmap_frame_cameras<TestType>(m);
  REQUIRE(cams.size() == 4);
  CHECK(cams[0].valid);
  CHECK_FALSE(cams[1].valid);
  CHECK_FALSE(cams[2].valid);
  CHECK(cams[3].valid);
  for (const auto& f : cams) CHECK(f.camera.is_finite());  // never NaN, even when invalid
  CHECK(cams[3].camera.t.x() == TestType(1));

  // Huge quaternion components still give a rotation (the norm must not overflow).
  m.images = parse_colmap_images_text("1 1e300 0 0 1e300 0 0 0 1 a.png\n", "images.txt");
  const auto big = colmap_frame_cameras<TestType>(m);
  REQUIRE(big.size() == 1);
  CHECK(std::abs(big[0].camera.R(0, 1) + TestType(1)) < 1e-6);  // 90 degrees about z
  // Finite in double but beyond float: an error rather than an inf in a valid camera.
  m.images = parse_colmap_images_text("1 1 0 0 0 1e300 0 0 1 a.png\n", "images.txt");
  if (std::is_same<TestType, float>::value) {
    require_error([&] { colmap_frame_cameras<TestType>(m); }, {"image 1 (a.png)", "do not fit the precision"});
  } else {
    CHECK(colmap_frame_cameras<TestType>(m)[0].camera.t.x() == 1e300);
  }
}

TEMPLATE_TEST_CASE("COLMAP shared data: v3d and Middlebury models load", "[io][colmap][data]", float, double) {
  using S = TestType;
  for (const std::string name : {"cool_teddy", "corgi_bread", "doll", "robot", "sunflower"}) {
    const std::string rel = "v3d/" + name + "/sparse/0";
    if (!orbitforge_test::have_shared_data(rel)) return;
    INFO(rel);
    const ColmapModel m = read_colmap_model(orbitforge_test::shared_path("v3d/" + name));
    CHECK(m.images.size() == 90);
    CHECK(m.points.size() > 100);
    // Both sides of the 2D observations agree: each track element's keypoint
    // names its point, and the keypoints with a point are the track elements.
    std::size_t track_total = 0, mismatched = 0, with_point = 0;
    for (const ColmapPoint& p : m.points) {
      REQUIRE(p.track_point2D.size() == p.track_images.size());
      track_total += p.track_images.size();
      for (std::size_t k = 0; k < p.track_images.size(); ++k) {
        const auto& kps = m.images.at(p.track_images[k]).points2D;
        const auto idx = std::size_t(p.track_point2D[k]);
        if (idx >= kps.size() || kps[idx].point3D_id != p.id) ++mismatched;
      }
    }
    for (const auto& [id, im] : m.images)
      for (const auto& q : im.points2D) with_point += q.point3D_id >= 0;
    CHECK(mismatched == 0);
    CHECK(with_point == track_total);
    CHECK(track_total > 1000);
    const auto cams = colmap_frame_cameras<S>(m);
    REQUIRE(cams.size() == 90);
    for (int i = 0; i < 90; ++i) {
      char expected[16];
      std::snprintf(expected, sizeof(expected), "%03d.jpg", i + 1);
      CHECK(cams[i].name == expected);
      CHECK(cams[i].valid);
      CHECK(cams[i].camera.is_finite());
      CHECK(cams[i].camera.intrinsics.width == 512);
      CHECK(cams[i].camera.intrinsics.height == 512);
      // A rotation.
      CHECK((cams[i].camera.R.transpose() * cams[i].camera.R - Eigen::Matrix<S, 3, 3>::Identity())
                .cwiseAbs()
                .maxCoeff() < 1e-5);
    }
  }
  const std::string doll = orbitforge_test::shared_path("v3d/doll");
  CHECK(find_colmap_model_dir(doll) == (std::filesystem::path(doll) / "sparse" / "0").string());
  CHECK(find_colmap_model_dir(doll + "/sparse/0") == doll + "/sparse/0");

  if (!orbitforge_test::have_shared_data("middlebury/dinoSparseRing/sparse/0")) return;
  const std::string dino = orbitforge_test::shared_path("middlebury/dinoSparseRing");
  const auto cams = colmap_frame_cameras<S>(read_colmap_model(dino));
  REQUIRE(cams.size() == 16);
  for (std::size_t i = 1; i < cams.size(); ++i) CHECK(cams[i - 1].name < cams[i].name);

  // The original calibration: "name K(9) R(9) t(3)" per line, x = K [R | t] X.
  std::ifstream par(dino + "/dinoSR_par.txt");
  REQUIRE(par.good());
  int n = 0;
  par >> n;
  REQUIRE(n == 16);
  std::map<std::string, std::pair<Eigen::Matrix3d, Eigen::Vector3d>> truth;
  std::map<std::string, Eigen::Matrix3d> truth_K;
  for (int i = 0; i < n; ++i) {
    std::string name;
    Eigen::Matrix3d K, R;
    Eigen::Vector3d t;
    par >> name;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) par >> K(r, c);
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) par >> R(r, c);
    par >> t(0) >> t(1) >> t(2);
    REQUIRE(par.good());
    truth[name] = {R, t};
    truth_K[name] = K;
  }
  const double tol = std::is_same<S, double>::value ? 1e-6 : 1e-5;
  for (const auto& f : cams) {
    INFO(f.name);
    REQUIRE(truth.count(f.name) == 1);
    const auto& [R, t] = truth.at(f.name);
    const Eigen::Vector3d centre_truth = -R.transpose() * t;
    const Eigen::Vector3d centre = f.camera.center().template cast<double>();
    CHECK((centre - centre_truth).norm() < tol);
    const Eigen::Matrix3d& K = truth_K.at(f.name);
    CHECK(std::abs(f.camera.intrinsics.fx - K(0, 0)) < 1e-3);
    CHECK(std::abs(f.camera.intrinsics.fy - K(1, 1)) < 1e-3);
    CHECK(std::abs(f.camera.intrinsics.cx - K(0, 2)) < 1e-3);
    CHECK(std::abs(f.camera.intrinsics.cy - K(1, 2)) < 1e-3);
  }
}

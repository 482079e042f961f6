#include <catch2/catch.hpp>

#include <cmath>
#include <fstream>
#include <string>

#include "io/io_test_util.hpp"
#include "orbitforge/io/transforms_json.hpp"

using namespace orbitforge;
using orbitforge_test::require_error;
using orbitforge_test::TempDir;

namespace {

template <class S>
double json_tol() {
  return std::is_same<S, double>::value ? 1e-12 : 2e-6;
}

// One frame with an identity-rotation OpenGL camera at (0, 0, 4): it looks
// down -z, i.e. at the origin, with world +y up on the image.
const char* kIdentityAtZ4 = R"({
  "w": 640, "h": 480, "fl_x": 500, "fl_y": 520, "cx": 320, "cy": 240,
  "frames": [ { "file_path": "images/0001.png",
                "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4],[0,0,0,1]] } ]
})";

}  // namespace

TEMPLATE_TEST_CASE("transforms.json: write then read gives the same cameras", "[io][transforms_json]", float, double) {
  using S = TestType;
  auto cams = orbitforge_test::random_frame_cameras<S>(10, 99);
  TempDir tmp("tj_rt");
  const std::string path = tmp.str("transforms.json");
  write_transforms_json(path, cams);
  const auto back = read_transforms_json<S>(path);
  REQUIRE(back.size() == cams.size());
  for (std::size_t i = 0; i < cams.size(); ++i) orbitforge_test::require_same_cameras(cams[i], back[i], json_tol<S>());

  cams[2].valid = false;
  write_transforms_json(path, cams);
  const auto fewer = read_transforms_json<S>(path);
  REQUIRE(fewer.size() == cams.size() - 1);
  CHECK(fewer[2].name == cams[3].name);
}

TEMPLATE_TEST_CASE("transforms.json: OpenGL camera-to-world becomes the OpenCV camera", "[io][transforms_json]", float,
                   double) {
  using S = TestType;
  using V3 = Eigen::Matrix<S, 3, 1>;
  const auto cams = parse_transforms_json<S>(kIdentityAtZ4, "transforms.json");
  REQUIRE(cams.size() == 1);
  const Camera<S>& c = cams[0].camera;
  CHECK(cams[0].name == "images/0001.png");
  CHECK(cams[0].valid);
  // Hand-derived: centre (0,0,4), OpenCV axes right = +x, down = -y, forward = -z,
  // so R = diag(1, -1, -1) and t = -R c = (0, 0, 4).
  Eigen::Matrix<S, 3, 3> R_expected = Eigen::Matrix<S, 3, 3>::Zero();
  R_expected.diagonal() << 1, -1, -1;
  CHECK((c.R - R_expected).cwiseAbs().maxCoeff() == S(0));
  CHECK((c.t - V3(0, 0, 4)).cwiseAbs().maxCoeff() == S(0));
  CHECK((c.center() - V3(0, 0, 4)).norm() < 1e-6);
  // The origin projects to the principal point; world up is image up (smaller v);
  // world +x is image right.
  const auto o = c.project(V3(0, 0, 0));
  CHECK(std::abs(o.x() - 320) < 1e-4);
  CHECK(std::abs(o.y() - 240) < 1e-4);
  const auto up = c.project(V3(0, 1, 0));
  CHECK(std::abs(up.y() - (240 - 520.0 / 4)) < 1e-3);
  const auto right = c.project(V3(1, 0, 0));
  CHECK(std::abs(right.x() - (320 + 500.0 / 4)) < 1e-3);
  CHECK(c.intrinsics.width == 640);
  CHECK(c.intrinsics.height == 480);
  // And back.
  const Eigen::Matrix<S, 4, 4> gl = c.to_opengl_camera_to_world();
  Eigen::Matrix<S, 4, 4> expected = Eigen::Matrix<S, 4, 4>::Identity();
  expected(2, 3) = 4;
  CHECK((gl - expected).cwiseAbs().maxCoeff() < 1e-6);
}

TEST_CASE("transforms.json: intrinsics from top level, per frame and camera_angle_x", "[io][transforms_json]") {
  const char* text = R"({
    "camera_angle_x": 0.7610127542247298, "w": 800, "h": 600,
    "frames": [
      { "file_path": "b", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3]] },
      { "file_path": "a", "fl_x": 900, "cy": 310, "h": 620,
        "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3],[0,0,0,1]] },
      { "file_path": "c", "camera_angle_y": 1.0, "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,3]] }
    ]})";
  const auto cams = parse_transforms_json<double>(text, "t.json");
  REQUIRE(cams.size() == 3);
  // Sorted by file_path.
  CHECK(cams[0].name == "a");
  CHECK(cams[1].name == "b");
  CHECK(cams[2].name == "c");
  // b: fl = (w / 2) / tan(angle_x / 2) = 400 / 0.4 = 1000; fl_y = fl_x; centre at w/2, h/2.
  const auto& kb = cams[1].camera.intrinsics;
  CHECK(std::abs(0.5 * 800 / std::tan(0.5 * 0.7610127542247298) - 1000.0) < 1e-9);  // the angle was chosen so
  CHECK(std::abs(kb.fx - 1000) < 1e-9);
  CHECK(std::abs(kb.fy - 1000) < 1e-9);
  CHECK(kb.cx == 400);
  CHECK(kb.cy == 300);
  // a: per-frame values win.
  const auto& ka = cams[0].camera.intrinsics;
  CHECK(ka.fx == 900);
  CHECK(ka.fy == 900);
  CHECK(ka.cy == 310);
  CHECK(ka.cx == 400);
  CHECK(ka.height == 620);
  // c: fl_y from camera_angle_y.
  const auto& kc = cams[2].camera.intrinsics;
  CHECK(std::abs(kc.fy - 300 / std::tan(0.5)) < 1e-9);
}

TEST_CASE("transforms.json: bad input is a clear error naming the file", "[io][transforms_json]") {
  auto parse = [](const std::string& text) { parse_transforms_json<double>(text, "scene/transforms.json"); };
  require_error([&] { parse("{ \"frames\": [ "); }, {"scene/transforms.json", "invalid JSON"});
  require_error([&] { parse("[1, 2]"); }, {"scene/transforms.json", "top level must be a JSON object"});
  require_error([&] { parse("{\"w\": 4}"); }, {"scene/transforms.json", "\"frames\" array is missing"});
  require_error([&] { parse(R"({"fl_x": "500", "frames": []})"); },
                {"scene/transforms.json", "\"fl_x\" must be a number, got string"});
  const std::string m = R"("transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,4]])";
  require_error([&] { parse(R"({"fl_x": 5, "h": 4, "frames": [{"file_path": "a", )" + m + "}]}"); },
                {"scene/transforms.json", "frames[0]", "\"w\"", "missing"});
  require_error([&] { parse(R"({"fl_x": 5, "w": 4.5, "h": 4, "frames": [{"file_path": "a", )" + m + "}]}"); },
                {"scene/transforms.json", "frames[0]", "not a positive whole number"});
  require_error([&] { parse(R"({"w": 4, "h": 4, "frames": [{"file_path": "a", )" + m + "}]}"); },
                {"scene/transforms.json", "frames[0]", "no focal length"});
  require_error([&] { parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": 7, )" + m + "}]}"); },
                {"scene/transforms.json", "frames[0]", "file_path"});
  require_error([&] { parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": "a"}]})"); },
                {"scene/transforms.json", "frames[0]", "transform_matrix\" is missing"});
  require_error(
      [&] {
        parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}]})");
      },
      {"scene/transforms.json", "frames[0]", "row 0 must be an array of 4 numbers"});
  require_error(
      [&] {
        parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": "a", "transform_matrix": [[2,0,0,0],[0,1,0,0],[0,0,1,0]]}]})");
      },
      {"scene/transforms.json", "frames[0]", "not a rotation"});
  require_error(
      [&] {
        parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[0,0,1,1]]}]})");
      },
      {"scene/transforms.json", "frames[0]", "last row must be 0 0 0 1"});
  require_error(
      [&] {
        parse(R"({"w": 4, "h": 4, "fl_x": 5, "frames": [{"file_path": "a", "transform_matrix": [[1,0,0,0],[0,1,0,null],[0,0,1,0]]}]})");
      },
      {"scene/transforms.json", "frames[0]", "[1][3] is not a number"});
  require_error([&] { parse(R"({"w": 4, "h": 4, "camera_angle_x": 4, "frames": [{"file_path": "a", )" + m + "}]}"); },
                {"scene/transforms.json", "camera_angle_x", "not an angle"});
  require_error([&] { parse(R"({"w": 4, "h": 4, "fl_x": -5, "frames": [{"file_path": "a", )" + m + "}]}"); },
                {"scene/transforms.json", "focal lengths must be positive"});

  TempDir tmp("tj_err");
  require_error([&] { read_transforms_json<float>(tmp.str("missing.json")); }, {"missing.json", "does not exist"});
  {
    std::ofstream out(tmp.str("bad.json"));
    out << "{\"frames\": [}";
  }
  require_error([&] { read_transforms_json<float>(tmp.str("bad.json")); }, {tmp.str("bad.json"), "invalid JSON"});
  // Writing non-finite cameras is refused, naming the file.
  auto cams = orbitforge_test::random_frame_cameras<double>(2, 5);
  cams[1].camera.t.x() = std::nan("");
  require_error([&] { write_transforms_json(tmp.str("out.json"), cams); }, {"out.json", "frame 1", "non-finite"});
  CHECK_FALSE(std::filesystem::exists(tmp.str("out.json")));
  cams = orbitforge_test::random_frame_cameras<double>(2, 5);
  cams[0].camera.intrinsics.width = 0;
  require_error([&] { write_transforms_json(tmp.str("out.json"), cams); }, {"out.json", "frame 0", "positive image size"});
}

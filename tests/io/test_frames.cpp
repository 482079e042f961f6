#include <catch2/catch.hpp>

#include <string>
#include <vector>

#include "io/io_test_util.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "support/data.hpp"

using namespace orbitforge;
using orbitforge_test::require_error;

TEST_CASE("parse_frame_range: accepted forms and errors", "[io][frames]") {
  auto check = [](const std::string& text, int first, int last) {
    INFO(text);
    const FrameRange r = parse_frame_range(text);
    CHECK(r.first == first);
    CHECK(r.last == last);
  };
  check("1-33", 1, 33);
  check(" 5 - 10 ", 5, 10);
  check("7", 7, 7);
  check("7-", 7, -1);
  check("12-12", 12, 12);

  require_error([] { parse_frame_range(""); }, {"frame range ''", "not a whole number"});
  require_error([] { parse_frame_range("a-3"); }, {"frame range 'a-3'", "first frame 'a'"});
  require_error([] { parse_frame_range("1-x"); }, {"frame range '1-x'", "last frame 'x'"});
  require_error([] { parse_frame_range("1-2-3"); }, {"frame range '1-2-3'", "not a whole number"});
  require_error([] { parse_frame_range("-5"); }, {"frame range '-5'", "first frame ''"});
  require_error([] { parse_frame_range("0-5"); }, {"frame range '0-5'", "numbered from 1"});
  require_error([] { parse_frame_range("9-3"); }, {"frame range '9-3'", "last frame 3 is before first frame 9"});
  require_error([] { parse_frame_range("1.5-3"); }, {"frame range '1.5-3'", "not a whole number"});
  require_error([] { parse_frame_range("1-99999999999"); }, {"frame range '1-99999999999'"});
}

TEMPLATE_TEST_CASE("select_frames: slices in order, errors out of range", "[io][frames]", float, double) {
  const auto cams = orbitforge_test::random_frame_cameras<TestType>(90, 1);
  const auto a = select_frames(cams, parse_frame_range("1-33"));
  REQUIRE(a.size() == 33);
  CHECK(a.front().name == "frame_001.png");
  CHECK(a.back().name == "frame_033.png");
  const auto b = select_frames(cams, parse_frame_range("80-"));
  REQUIRE(b.size() == 11);
  CHECK(b.front().name == "frame_080.png");
  CHECK(b.back().name == "frame_090.png");
  CHECK(select_frames(cams, FrameRange{}).size() == 90);
  const auto c = select_frames(cams, parse_frame_range("90"));
  REQUIRE(c.size() == 1);
  CHECK(c[0].name == "frame_090.png");

  require_error([&] { select_frames(cams, parse_frame_range("85-95")); }, {"85-95", "last frame 95 is beyond the 90"});
  require_error([&] { select_frames(cams, parse_frame_range("91-")); }, {"first frame 91 is beyond the 90"});
  require_error([&] { select_frames(cams, FrameRange{0, 3}); }, {"first frame 0 is below 1"});
  require_error([&] { select_frames(cams, FrameRange{5, 3}); }, {"last frame is before the first"});
  require_error([&] { select_frames(std::vector<FrameCamera<TestType>>{}, FrameRange{}); }, {"beyond the 0"});
}

TEMPLATE_TEST_CASE("select_registered_frames: video frame numbers, unregistered frames named", "[io][frames]", float,
                   double) {
  auto frames = orbitforge_test::random_frame_cameras<TestType>(90, 1);
  for (int unregistered : {29, 30, 31, 32, 33, 60}) frames[std::size_t(unregistered - 1)].valid = false;
  const auto a = select_registered_frames(frames, parse_frame_range("1-33"));
  REQUIRE(a.cameras.size() == 28);
  CHECK(a.numbers.front() == 1);
  CHECK(a.numbers.back() == 28);
  CHECK(a.cameras.back().name == "frame_028.png");
  REQUIRE(a.skipped.size() == 5);
  CHECK(a.skipped.front() == "frame 29 (frame_029.png)");
  CHECK(a.skipped.back() == "frame 33 (frame_033.png)");
  // The same range means the same frames when every frame is registered.
  const auto all = orbitforge_test::random_frame_cameras<TestType>(90, 1);
  const auto b = select_registered_frames(all, parse_frame_range("1-33"));
  CHECK(b.cameras.size() == 33);
  CHECK(b.skipped.empty());
  CHECK(select_registered_frames(frames, FrameRange{}).cameras.size() == 84);

  require_error([&] { select_registered_frames(frames, parse_frame_range("85-95")); },
                {"last frame 95 is beyond the 90 frames of the video"});
  require_error([&] { select_registered_frames(frames, parse_frame_range("29-33")); },
                {"29-33", "none of its 5 frames has a camera"});
  require_error([&] { parse_frame_range(""); }, {"is not a whole number"});
}

TEST_CASE("select_frames on a recorded video: frames 1-33 of doll", "[io][frames][data]") {
  if (!orbitforge_test::have_shared_data("v3d/doll/sparse/0")) return;
  const auto cams = colmap_frame_cameras<double>(read_colmap_model(orbitforge_test::shared_path("v3d/doll")));
  const auto v0 = select_frames(cams, parse_frame_range("1-33"));
  REQUIRE(v0.size() == 33);
  CHECK(v0.front().name == "001.jpg");
  CHECK(v0.back().name == "033.jpg");
}

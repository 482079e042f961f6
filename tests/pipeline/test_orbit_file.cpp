#include <catch2/catch.hpp>

#include <filesystem>
#include <fstream>

#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"

using namespace orbitforge;

TEST_CASE("orbit.json holds the fields scripts read, and its cameras read back", "[pipeline][orbit_file]") {
  SyntheticInputParams sp;
  auto in = make_synthetic_input<double>(sp);
  in.recorded.resize(sp.source_frames);
  const auto fit = fit_orbit(in.recorded, OrbitParams{});
  std::vector<std::string> names;
  for (const auto& s : fit.source) names.push_back(s.name);
  const auto layout = endpoint_window_layout(fit.support, names);
  const auto j = orbit_json(fit, layout);
  for (const char* key : {"orbit", "diagnostics", "support", "source", "layout", "coverage", "cameras"})
    REQUIRE(j.contains(key));
  for (const char* key : {"center", "normal", "e1", "e2", "radius", "theta0_deg", "direction", "look_at",
                          "elevation_offset_deg", "views", "width", "height", "fx", "fy", "cx", "cy"})
    REQUIRE(j["orbit"].contains(key));
  REQUIRE(j["cameras"].size() == 361);
  REQUIRE(j["source"].size() == std::size_t(sp.source_frames));
  REQUIRE(j["coverage"]["closed"].get<bool>());
  REQUIRE(j["layout"]["frames"].get<int>() % 8 == 1);
  // Support partitions the orbit.
  REQUIRE(j["support"]["arc"].size() + j["support"]["gap"].size() == 361);

  const auto path = (std::filesystem::temp_directory_path() / "orbitforge_test_orbit.json").string();
  write_orbit_json(path, fit, layout);
  const auto cams = read_cameras_json<double>(path);
  REQUIRE(cams.size() == 361);
  for (int i = 0; i < 361; i += 30) {
    REQUIRE((cams[i].R - fit.cameras[i].R).cwiseAbs().maxCoeff() < 1e-12);
    REQUIRE((cams[i].t - fit.cameras[i].t).cwiseAbs().maxCoeff() < 1e-12);
    REQUIRE(cams[i].intrinsics.width == 896);
  }
  // The synthetic orbit is recovered: radius and the true elevation ring.
  REQUIRE(fit.orbit.radius == Approx(sp.radius).epsilon(0.02));
  std::filesystem::remove(path);
}

TEST_CASE("camera JSON errors name the file, the camera and the problem", "[pipeline][orbit_file]") {
  const auto path = (std::filesystem::temp_directory_path() / "orbitforge_bad_cam.json").string();
  auto write = [&](const std::string& s) { std::ofstream(path) << s; };
  auto message = [&]() -> std::string {
    try {
      read_cameras_json<float>(path);
    } catch (const Error& e) {
      return e.what();
    }
    return "";
  };
  write("{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2, \"cy\": 2, \"R\": [[1,0,0],[0,1,0]], \"t\": [0,0,0]}");
  CHECK(message().find("\"R\" must be 3 rows") != std::string::npos);
  write("[{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2, \"cy\": 2, \"R\": [[2,0,0],[0,1,0],[0,0,1]], "
        "\"t\": [0,0,0]}]");
  CHECK(message().find("not a rotation") != std::string::npos);
  write("{\"height\": 4}");
  CHECK(message().find("camera 0: missing or non-numeric \"width\"") != std::string::npos);
  write("[1, 2");
  CHECK(message().find("not valid JSON") != std::string::npos);
  CHECK(message().find(path) != std::string::npos);
  write("{\"width\": 4, \"height\": 4, \"fx\": 1, \"fy\": 1, \"cx\": 2, \"cy\": 2, \"R\": [[1,0,0],[0,1,0],[0,0,1]], "
        "\"t\": [0,0,1]}");
  CHECK(read_cameras_json<float>(path).size() == 1);
  std::filesystem::remove(path);
}

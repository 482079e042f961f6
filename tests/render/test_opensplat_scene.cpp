// A PLY written by another program (OpenSplat) loads and renders: the spheres are
// in front of every one of its cameras and cover part of the image.
#include <catch2/catch.hpp>

#include <nlohmann/json.hpp>

#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "support/data.hpp"

using namespace orbitforge;

TEST_CASE("OpenSplat's spheres PLY renders at OpenSplat's cameras", "[render][data]") {
  if (!orbitforge_test::have_shared_data("ply/opensplat_spheres_10k.ply")) return;
  const auto scene = read_ply<float>(orbitforge_test::shared_path("ply/opensplat_spheres_10k.ply"));
  REQUIRE(scene.size() == 10000);
  REQUIRE(scene.sh_degree == 3);
  const auto cams = nlohmann::json::parse(read_file_bytes(orbitforge_test::shared_path("ply/opensplat_spheres_cameras.json")));
  REQUIRE(cams.size() == 12);
  Renderer<float> renderer;
  for (std::size_t i = 0; i < cams.size(); i += 4) {
    // OpenSplat writes position = centre and rotation = camera-to-world (OpenCV axes).
    Eigen::Matrix3f world_R_camera;
    Eigen::Vector3f centre;
    for (int r = 0; r < 3; ++r) {
      centre[r] = cams[i]["position"][r].get<float>();
      for (int c = 0; c < 3; ++c) world_R_camera(r, c) = cams[i]["rotation"][r][c].get<float>();
    }
    const int w = cams[i]["width"].get<int>() / 4, h = cams[i]["height"].get<int>() / 4;  // smaller, faster
    Intrinsics<float> k{cams[i]["fx"].get<float>() / 4, cams[i]["fy"].get<float>() / 4, w / 2.f, h / 2.f, w, h};
    const auto cam = Camera<float>::from_world_T_camera(world_R_camera, centre, k);
    const auto& out = renderer.render(SceneView<float>(scene), cam);
    std::size_t covered = 0;
    for (int p = 0; p < w * h; ++p) {
      REQUIRE(std::isfinite(out.color.data[3 * p]));
      if (out.transmittance.data[p] < 0.5f) ++covered;
    }
    INFO("camera " << i << ": " << covered << " of " << w * h << " pixels covered");
    CHECK(covered > std::size_t(w * h / 20));   // the object is in view
    CHECK(covered < std::size_t(w * h * 9 / 10));  // and does not fill the frame
    CHECK(out.frame.gaussians_visible > 5000);
  }
}

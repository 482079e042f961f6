// scripts/closed_loop_reference.sh: a reference model of a recorded video that
// orbits the whole way round, with its last frames matched to its first. The
// recorded videos end one frame's step before they began (their first and last
// frames differ as little as two neighbours do), so a model that knows it spans
// 360 degrees in even steps and closes with one more step; the shared models,
// made with the sequential matcher, leave a wider last step.
#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "orbitforge/geometry/orbit_loop.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "support/data.hpp"
#include "support/programs.hpp"
#include "support/temp_dir.hpp"

using namespace orbitforge;

namespace closed_loop_reference_test {

// A model's cameras in frame order (their names sort so) and how they go round.
OrbitLoop loop_of(const std::string& model_dir) {
  std::vector<FrameCamera<double>> cams = colmap_frame_cameras<double>(read_colmap_model(model_dir));
  std::sort(cams.begin(), cams.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  std::vector<int> frame;
  for (std::size_t i = 0; i < cams.size(); ++i) frame.push_back(int(i));
  return orbit_loop(cams, frame);
}

TEST_CASE("closed_loop_reference.sh: a whole orbit's model closes with one even step; the sequential one's does not",
          "[pipeline][reference][data]") {
  const std::string video = "v3d/robot";
  if (!orbitforge_test::have_shared_data(video + "/sparse/0")) return;
  if (!orbitforge_test::have_programs({"bash", "colmap"})) return;
  orbitforge_test::TempDir t("closed_loop");
  const std::string out = (t.path() / "robot").string();
  run_tool({"closed_loop_reference.sh",
            {"bash", ORBITFORGE_SCRIPTS_DIR "/closed_loop_reference.sh", orbitforge_test::shared_path(video), out},
            {{"ORBITFORGE_COLMAP_THREADS", "2"}}},
           (t.path() / "script.log").string());

  const OrbitLoop closed = loop_of(out + "/sparse/0");
  const OrbitLoop shared = loop_of(orbitforge_test::shared_path(video + "/sparse/0"));
  REQUIRE(closed.cameras == 90);  // every frame registered
  REQUIRE(shared.cameras == 90);
  const double even = 360.0 / 90.0;
  // 89 steps and the closing one share the turn evenly, within a few per cent.
  CHECK(std::abs(closed.mean_step_deg / even - 1) < 0.03);
  CHECK(std::abs(closed.last_to_first_deg / even - 1) < 0.25);
  CHECK(closed.smallest_step_deg > 0.8 * even);
  CHECK(closed.largest_step_deg < 1.2 * even);
  // The sequential model turns less per frame and leaves a last step several
  // frames wide: its orbit does not close.
  CHECK(shared.last_to_first_deg > 3 * even);
  // The focal lengths differ with the turn: a shorter lens explains the same
  // image motion with less rotation.
  const double f_closed = read_colmap_model(out + "/sparse/0").cameras.begin()->second.params[0];
  const double f_shared =
      read_colmap_model(orbitforge_test::shared_path(video + "/sparse/0")).cameras.begin()->second.params[0];
  CHECK(f_closed > f_shared);
  WARN("robot: closed-loop model " << closed.mean_step_deg << " deg a frame and " << closed.last_to_first_deg
                                   << " deg back to the first frame, focal " << f_closed << " px; sequential model "
                                   << shared.mean_step_deg << " and " << shared.last_to_first_deg << " deg, focal "
                                   << f_shared << " px");
}

}  // namespace closed_loop_reference_test

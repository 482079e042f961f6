// scripts/closed_loop_reference.sh: a reference model of a recorded video that
// orbits the whole way round, with its last frames matched to its first. The
// recorded videos end one frame's step before they began (their first and last
// frames differ as little as two neighbours do), so a model that knows it spans
// 360 degrees in even steps and closes with one more step; the shared models,
// made with the sequential matcher, leave a wider last step.
#include <catch2/catch.hpp>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "orbitforge/io/colmap.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "support/data.hpp"
#include "support/temp_dir.hpp"

using namespace orbitforge;

namespace closed_loop_reference_test {

// How a model's cameras go round: the azimuth steps between consecutive frames
// (by name) about their centroid in their best-fit plane, the sum of those steps,
// and the step from the last frame back to the first.
struct LoopSteps {
  std::vector<double> steps;
  double total = 0, last_to_first = 0;
};

LoopSteps loop_steps(const std::string& model_dir) {
  std::vector<FrameCamera<double>> cams = colmap_frame_cameras<double>(read_colmap_model(model_dir));
  std::sort(cams.begin(), cams.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  Eigen::MatrixXd P(Eigen::Index(cams.size()), 3);
  for (std::size_t i = 0; i < cams.size(); ++i) P.row(Eigen::Index(i)) = cams[i].camera.center().transpose();
  const Eigen::RowVector3d mean = P.colwise().mean();
  const Eigen::MatrixXd Q = P.rowwise() - mean;
  const Eigen::JacobiSVD<Eigen::MatrixXd> svd(Q, Eigen::ComputeThinV);
  const Eigen::Vector3d e1 = svd.matrixV().col(0), e2 = svd.matrixV().col(1);
  LoopSteps s;
  auto azimuth = [&](Eigen::Index i) { return std::atan2(Q.row(i).dot(e2), Q.row(i).dot(e1)) * (180.0 / 3.14159265358979323846); };
  auto wrap = [](double d) { return d - 360.0 * std::floor((d + 180.0) / 360.0); };
  for (Eigen::Index i = 1; i < Q.rows(); ++i) s.steps.push_back(wrap(azimuth(i) - azimuth(i - 1)));
  for (double d : s.steps) s.total += d;
  const double sign = s.total < 0 ? -1.0 : 1.0;
  for (double& d : s.steps) d *= sign;
  s.total *= sign;
  s.last_to_first = 360.0 - s.total;
  return s;
}

TEST_CASE("closed_loop_reference.sh: a whole orbit's model closes with one even step; the sequential one's does not",
          "[pipeline][reference][data]") {
  const std::string video = "v3d/robot";
  if (!orbitforge_test::have_shared_data(video + "/sparse/0")) return;
  for (const char* p : {"bash", "colmap"})
    if (find_program(p).empty()) {
      if (orbitforge_test::running_in_ci()) FAIL("program " << p << " missing in CI (scripts/setup.sh installs it)");
      WARN("SKIPPED: the " << p << " program is not on PATH");
      return;
    }
  orbitforge_test::TempDir t("closed_loop");
  const std::string out = (t.path() / "robot").string();
  run_tool({"closed_loop_reference.sh",
            {"bash", ORBITFORGE_SCRIPTS_DIR "/closed_loop_reference.sh", orbitforge_test::shared_path(video), out},
            {{"ORBITFORGE_COLMAP_THREADS", "2"}}},
           (t.path() / "script.log").string());

  const LoopSteps closed = loop_steps(out + "/sparse/0");
  const LoopSteps shared = loop_steps(orbitforge_test::shared_path(video + "/sparse/0"));
  REQUIRE(closed.steps.size() == 89);  // every one of the 90 frames registered
  REQUIRE(shared.steps.size() == 89);
  const double even = 360.0 / 90.0;
  double mean = 0;
  for (double d : closed.steps) mean += d / double(closed.steps.size());
  // 89 steps and the closing one share the turn evenly, within a few per cent.
  CHECK(std::abs(mean / even - 1) < 0.03);
  CHECK(std::abs(closed.last_to_first / even - 1) < 0.25);
  CHECK(*std::min_element(closed.steps.begin(), closed.steps.end()) > 0.8 * even);
  CHECK(*std::max_element(closed.steps.begin(), closed.steps.end()) < 1.2 * even);
  // The sequential model turns less per frame and leaves a last step several
  // frames wide: its orbit does not close.
  CHECK(shared.last_to_first > 3 * even);
  // The focal lengths differ with the turn: a shorter lens explains the same
  // image motion with less rotation.
  const double f_closed = read_colmap_model(out + "/sparse/0").cameras.begin()->second.params[0];
  const double f_shared =
      read_colmap_model(orbitforge_test::shared_path(video + "/sparse/0")).cameras.begin()->second.params[0];
  CHECK(f_closed > f_shared);
  WARN("robot: closed-loop model " << closed.total << " deg in 89 steps + " << closed.last_to_first
                                   << " deg back to the first frame, focal " << f_closed
                                   << " px; sequential model " << shared.total << " + " << shared.last_to_first
                                   << " deg, focal " << f_shared << " px");
}

}  // namespace closed_loop_reference_test

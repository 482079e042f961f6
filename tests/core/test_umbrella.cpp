// The umbrella header compiles on its own and its parts work together: explicit
// instantiation of the main templates in both precisions (so every member compiles).
#include "orbitforge/orbitforge.hpp"

#include <catch2/catch.hpp>

namespace orbitforge {
template struct Camera<float>;
template struct Camera<double>;
template struct GaussianScene<float>;
template struct GaussianScene<double>;
template class Renderer<float>;
template class Renderer<double>;
template class Mlp<float>;
template class Mlp<double>;
template class Adam<float>;
template class Adam<double>;
}  // namespace orbitforge

TEST_CASE("umbrella header: fit an orbit and render a scene through it", "[core][umbrella]") {
  using namespace orbitforge;
  SyntheticInputParams p;
  p.object_gaussians = 200;
  p.ground_gaussians = 100;
  auto in = make_synthetic_input<float>(p);
  Renderer<float> r;
  const auto& out = r.render(SceneView<float>(in.scene), in.true_cameras[0]);
  REQUIRE(out.color.width == p.width);
  REQUIRE(out.frame.gaussians_visible > 0);
  in.recorded.resize(p.source_frames);
  OrbitParams op;
  op.width = 64;
  op.height = 64;
  const auto fit = fit_orbit(in.recorded, op);
  REQUIRE(fit.cameras.size() == 361);
}

TEST_CASE("the version macro matches the CMake project version", "[core][version]") {
  REQUIRE(std::string(ORBITFORGE_VERSION_STRING) == ORBITFORGE_CMAKE_VERSION);
  REQUIRE(ORBITFORGE_VERSION == ORBITFORGE_VERSION_MAJOR * 10000 + ORBITFORGE_VERSION_MINOR * 100 +
                                    ORBITFORGE_VERSION_PATCH);
  REQUIRE(std::to_string(ORBITFORGE_VERSION_MAJOR) + "." + std::to_string(ORBITFORGE_VERSION_MINOR) + "." +
              std::to_string(ORBITFORGE_VERSION_PATCH) ==
          ORBITFORGE_VERSION_STRING);
}

#include <iostream>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/splat/gaussians.hpp"

int main() {
  orbitforge::GaussianScenef scene;
  scene.resize(2, 1);
  const auto cam = orbitforge::Camerad::look_at({0, -3, 0}, {0, 0, 0}, {0, 0, 1});
  std::cout << "consumer ok: " << scene.size() << " gaussians, camera at " << cam.center().transpose() << "\n";
  return scene.size() == 2 ? 0 : 1;
}

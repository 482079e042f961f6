// Placeholder main example until fit_orbit lands: prints a look-at camera.
#include <iostream>

#include "orbitforge/core/camera.hpp"

int main() {
  using namespace orbitforge;
  const auto cam = Camerad::look_at({4, 0, 1}, {0, 0, 0}, {0, 0, 1}, {500, 500, 256, 256, 512, 512});
  std::cout << "camera centre: " << cam.center().transpose() << "\nforward: " << cam.forward().transpose() << "\n";
  return 0;
}

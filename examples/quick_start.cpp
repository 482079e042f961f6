// Render two Gaussians and differentiate the image's mean brightness.
#include <cmath>
#include <cstdio>

#include "orbitforge/splat/renderer.hpp"
using namespace orbitforge;

int main() {
  GaussianScene<float> scene;  // struct of arrays; rotations w, x, y, z; log standard deviations
  scene.resize(2, /*sh_degree=*/0);
  scene.means = {-0.4f, 0, 0, 0.4f, 0, 0};
  scene.log_scales.assign(6, std::log(0.25f));
  scene.opacity_logits = {2, 2};  // opacity = sigmoid(logit)
  scene.sh = {1.5f, 0, 0, 0, 0, 1.5f};  // degree-0 SH per colour channel: red, blue

  const Intrinsics<float> k{100, 100, 64, 64, 128, 128};  // fx, fy, cx, cy, width, height
  const Camera<float> camera = Camera<float>::look_at({0, -3, 0}, {0, 0, 0}, {0, 0, 1}, k);
  Renderer<float> renderer;  // owns and reuses every buffer of a frame
  const RenderOutput<float>& image = renderer.render(SceneView<float>(scene), camera);

  Image<float> v_color(128, 128, 3, 1.0f / (128 * 128 * 3));  // dL/d colour for L = mean
  const GaussianSceneGrad<float>& g = renderer.backward(SceneView<float>(scene), camera, v_color);
  std::printf("centre pixel red %.3f; dL/d(opacity logit) %.4g %.4g; %.2f ms\n",
              image.color(64, 64, 0), g.opacity_logits[0], g.opacity_logits[1], image.frame.total_ms);
}

// quick_start: the library in a few calls (the README's C++ quick start).
//
//   quick_start COLMAP_MODEL_DIR SCENE.ply OUT.png
//
// Fits the canonical 361-view orbit to the cameras of a COLMAP model (frames
// 1-33 in name order: the source video), prints where the source supports the
// orbit, and renders an INRIA-PLY Gaussian scene at the orbit view opposite the
// first source frame (the middle of the gap a video model must complete).
#include <cstdio>
#include <exception>

#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/splat/renderer.hpp"

int main(int argc, char** argv) {
  using namespace orbitforge;
  if (argc != 4) {
    std::fprintf(stderr, "usage: quick_start COLMAP_MODEL_DIR SCENE.ply OUT.png\n");
    return 2;
  }
  try {
    // The source video's cameras, in frame order (colmap_frame_cameras sorts by name).
    std::vector<FrameCamera<float>> cameras = colmap_frame_cameras<float>(read_colmap_model(argv[1]));
    if (cameras.size() > 33) cameras.resize(33);

    // The canonical orbit: 361 views at 512 x 512, 10 degrees above the source.
    OrbitParams op;
    op.width = op.height = 512;
    const OrbitFit<float> fit = fit_orbit(cameras, op);
    std::printf("radius %.3f, source arc %zu views, gap %zu views\n", double(fit.orbit.radius),
                fit.support.arc.size(), fit.support.gap.size());

    // Render a scene at the view half a turn from the first source frame.
    const GaussianScene<float> scene = read_ply<float>(argv[2]);
    Renderer<float> renderer;  // RenderParams: background, threads, SH degree ...
    const auto& out = renderer.render(SceneView<float>(scene), fit.cameras[std::size_t(fit.views / 2)]);
    write_png(argv[3], out.color);
    std::printf("%zu Gaussians visible -> %s\n", out.frame.gaussians_visible, argv[3]);
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "quick_start: %s\n", e.what());
    return 1;
  }
}

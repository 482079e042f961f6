// render_orbit: render a Gaussian Splatting scene on the CPU at given cameras.
//
//   render_orbit --ply scene.ply (--camera cam.json | --orbit orbit.json [--every K]) --out DIR
//                [--format png|pfm] [--background r,g,b] [--threads N] [--stats]
//
// cam.json: one camera or a list {"width","height","fx","fy","cx","cy","R": 3x3,"t": 3}
// with x_cam = R x_world + t (OpenCV axes); orbit.json: what fit_orbit writes.
// Frames are written as DIR/00000.png (or .pfm) in camera order (with --every K the
// file name keeps the camera's index). --stats prints one JSON line per frame.
#include <cstdio>
#include <filesystem>
#include <iostream>
#include <nlohmann/json.hpp>
#include <string>

#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/splat/renderer.hpp"
#include "orbitforge/train/densify.hpp"
#include "orbitforge/train/train_params.hpp"
#include "cli.hpp"

using namespace orbitforge;

namespace {

const char* kDescription =
    "render_orbit: render a Gaussian Splatting scene on the CPU at given cameras.\n"
    "  render_orbit --ply scene.ply (--camera cam.json | --orbit orbit.json [--every K]) --out DIR [flags]\n"
    "Frames are written as DIR/00000.png (or .pfm) in camera order (with --every K the file name keeps the\n"
    "camera's index).";

}  // namespace

int main(int argc, char** argv) {
  relaunch_with_huge_pages(argv);  // first: glibc reads its tunables only at start
  return cli::run([&] {
    std::string ply, camera_file, orbit_file, out, format = "png", background;
    int every = 1, threads = 0;
    bool stats = false;
    double near_fraction = TrainParams{}.near_plane_fraction;
    RenderParams<float> params;
    CLI::App app(kDescription, "render_orbit");
    cli::setup(app);
    app.add_option("--ply", ply, "the scene")->required();
    app.add_option("--camera", camera_file,
                   "one camera or a list {\"width\",\"height\",\"fx\",\"fy\",\"cx\",\"cy\",\"R\": 3x3,\"t\": 3}, "
                   "x_cam = R x_world + t (OpenCV axes)");
    app.add_option("--orbit", orbit_file, "an orbit file (what fit_orbit writes)");
    app.add_option("--every", every, "every K-th camera")->transform(cli::at_least(1));
    app.add_option("--out", out, "output folder")->required();
    app.add_option("--format", format, "png or pfm")->check(CLI::IsMember({"png", "pfm"}));
    app.add_option("--background", background, "r,g,b in [0,1] (default black)")->check(cli::rgb());
    app.add_option("--threads", threads, "worker threads (0 = all hardware threads)")->transform(cli::thread_count());
    app.add_flag("--stats", stats, "print one JSON line of render statistics per frame");
    app.add_option("--near-plane-fraction", near_fraction, "near plane as a share of the scene's scale")
        ->check(cli::finite());
    cli::parse(app, argc, argv);
    if (!background.empty()) {
      const auto c = cli::parse_rgb(background);
      params.background = {float(c[0]), float(c[1]), float(c[2])};
    }
    auto usage = [](bool ok, const char* message) {
      if (!ok) throw cli::UsageError(std::string("render_orbit: ") + message);
    };
    usage(camera_file.empty() != orbit_file.empty(), "give exactly one of --camera and --orbit");
    usage(near_fraction > 0 && near_fraction < 1, "--near-plane-fraction must be in (0, 1)");
    params.threads = threads;

    const auto scene = read_ply<float>(ply);
    const auto cameras = read_cameras_json<float>(camera_file.empty() ? orbit_file : camera_file);
    // The near plane scales with the scene, as in training: a share of the cameras'
    // extent, or for one camera of its distance to the Gaussians' mean.
    double scale = 0;
    if (cameras.size() > 1) {
      scale = double(camera_extent(cameras));
    } else if (scene.size() > 0) {
      Eigen::Vector3d mean = Eigen::Vector3d::Zero();
      for (std::size_t g = 0; g < scene.size(); ++g)
        for (int k = 0; k < 3; ++k) mean(k) += double(scene.means[3 * g + std::size_t(k)]);
      scale = (cameras[0].cast<double>().center() - mean / double(scene.size())).norm();
    }
    if (!(scale > 1e-12) || !std::isfinite(scale)) scale = 1;
    params.near_plane = near_fraction * scale;
    std::filesystem::create_directories(out);
    Renderer<float> renderer(params);
    bool warned = false, warned_near = false;
    for (std::size_t i = 0; i < cameras.size(); i += std::size_t(every)) {
      const auto& frame = renderer.render(SceneView<float>(scene), cameras[i]);
      if (!warned) {  // once: the same Gaussians are skipped at every camera
        const std::string w = nonfinite_warning(frame.frame);
        if (!w.empty()) std::cerr << "render_orbit: warning: " << ply << ": " << w << "\n";
        warned = !w.empty();
      }
      if (!warned_near) {
        const std::string w = near_cull_warning(frame.frame, params.near_plane);
        if (!w.empty()) std::cerr << "render_orbit: warning: " << ply << ": " << w << "\n";
        warned_near = !w.empty();
      }
      char name[32];
      std::snprintf(name, sizeof(name), "%05zu.%s", i, format.c_str());
      const std::string path = (std::filesystem::path(out) / name).string();
      if (format == "pfm") write_pfm(path, frame.color);
      else write_png(path, frame.color);
      if (stats) {
        const auto& s = frame.frame;
        std::cout << nlohmann::json{{"frame", i},
                                    {"ms", s.total_ms},
                                    {"project_ms", s.project_ms},
                                    {"sort_ms", s.sort_ms},
                                    {"raster_ms", s.raster_ms},
                                    {"pairs_evaluated", s.pairs_evaluated},
                                    {"contributions", s.contributions},
                                    {"gaussians_visible", s.gaussians_visible},
                                    {"gaussians_nonfinite", s.projection.culled_nonfinite},
                                    {"threads", s.threads}}
                         .dump()
                  << "\n";
      }
    }
    if (!stats) std::cout << "render_orbit: wrote " << (cameras.size() + every - 1) / every << " frames to " << out << "\n";
    return 0;
  });
}

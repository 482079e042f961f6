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

#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/splat/renderer.hpp"

using namespace orbitforge;

namespace {

const char* kUsage =
    "usage: render_orbit --ply scene.ply (--camera cam.json | --orbit orbit.json [--every K]) --out DIR\n"
    "                    [--format png|pfm] [--background r,g,b] [--threads N] [--stats]\n";

int to_int(const std::string& flag, const std::string& v) {
  std::size_t used = 0;
  int x = 0;
  try {
    x = std::stoi(v, &used);
  } catch (...) {
    used = 0;
  }
  ensure(used == v.size() && !v.empty(), "render_orbit: ", flag, " expects an integer, got '", v, "'");
  return x;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc == 1 || (argc == 2 && (std::string(argv[1]) == "-h" || std::string(argv[1]) == "--help"))) {
    std::cout << kUsage;
    return argc == 1 ? 2 : 0;
  }
  try {
    std::string ply, camera_file, orbit_file, out, format = "png";
    int every = 1, threads = 0;
    bool stats = false;
    RenderParams<float> params;
    for (int i = 1; i < argc; ++i) {
      const std::string f = argv[i];
      auto value = [&]() -> std::string {
        ensure(i + 1 < argc, "render_orbit: ", f, " needs a value");
        return argv[++i];
      };
      if (f == "--ply") ply = value();
      else if (f == "--camera") camera_file = value();
      else if (f == "--orbit") orbit_file = value();
      else if (f == "--every") every = to_int(f, value());
      else if (f == "--out") out = value();
      else if (f == "--format") format = value();
      else if (f == "--threads") threads = to_int(f, value());
      else if (f == "--stats") stats = true;
      else if (f == "--background") {
        const std::string v = value();
        float r, g, b;
        char extra;
        ensure(std::sscanf(v.c_str(), "%f,%f,%f%c", &r, &g, &b, &extra) == 3,
               "render_orbit: --background expects r,g,b in [0,1], got '", v, "'");
        params.background = {r, g, b};
      } else {
        fail("render_orbit: unknown argument '", f, "'");
      }
    }
    ensure(!ply.empty(), "render_orbit: --ply is required");
    ensure(!out.empty(), "render_orbit: --out DIR is required");
    ensure(camera_file.empty() != orbit_file.empty(), "render_orbit: give exactly one of --camera and --orbit");
    ensure(format == "png" || format == "pfm", "render_orbit: --format must be png or pfm");
    ensure(every >= 1, "render_orbit: --every must be >= 1");
    ensure(threads >= 0, "render_orbit: --threads must be >= 0");
    params.threads = threads;

    const auto scene = read_ply<float>(ply);
    const auto cameras = read_cameras_json<float>(camera_file.empty() ? orbit_file : camera_file);
    std::filesystem::create_directories(out);
    Renderer<float> renderer(params);
    for (std::size_t i = 0; i < cameras.size(); i += std::size_t(every)) {
      const auto& frame = renderer.render(SceneView<float>(scene), cameras[i]);
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
  } catch (const std::exception& e) {
    std::cerr << e.what() << "\n";
    return 1;
  }
}

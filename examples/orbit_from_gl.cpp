// orbit_from_gl: the canonical 360-degree orbit from a host's own camera
// matrices, OpenGL camera-to-world (x right, y up, looking along -z), as a
// three.js, Blender or nerfstudio tool keeps them. Needs only orbitforge::core
// (and CLI11, header-only, for its command line).
//
//   orbit_from_gl [POSES.txt WIDTH HEIGHT FOV_Y_DEG]
//
// POSES.txt: one camera per line, the 16 numbers of its 4x4 camera-to-world
// matrix in row-major order. Without arguments it makes a 120-degree arc of 33
// cameras around the origin. Prints where the source supports the orbit and the
// first canonical camera back as an OpenGL camera-to-world matrix.
#include <cmath>
#include <cstdio>
#include <exception>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "orbitforge/geometry/orbit.hpp"

using namespace orbitforge;

namespace {

std::vector<Eigen::Matrix4d> example_arc() {
  std::vector<Eigen::Matrix4d> poses;
  for (int i = 0; i < 33; ++i) {
    const double a = i * (120.0 / 32) * M_PI / 180, eye_height = 0.8;
    const Eigen::Vector3d eye(3 * std::cos(a), 3 * std::sin(a), eye_height);
    // look_at in OpenCV axes, then the same pose as OpenGL camera-to-world.
    poses.push_back(Camerad::look_at(eye, {0, 0, 0}, {0, 0, 1}).to_opengl_camera_to_world());
  }
  return poses;
}

std::vector<Eigen::Matrix4d> read_poses(const std::string& path) {
  std::ifstream in(path);
  ensure(bool(in), "cannot open ", path);
  std::vector<Eigen::Matrix4d> poses;
  std::string line;
  for (int line_no = 1; std::getline(in, line); ++line_no) {
    if (line.find_first_not_of(" \t\r") == std::string::npos) continue;
    std::istringstream ls(line);
    Eigen::Matrix4d m;
    for (int k = 0; k < 16; ++k)
      ensure(bool(ls >> m(k / 4, k % 4)), path, " line ", line_no, ": expected 16 numbers");
    poses.push_back(m);
  }
  return poses;
}

}  // namespace

int main(int argc, char** argv) {
  std::string poses_file;
  int width = 512, height = 512;
  double fov_y_deg = 50;
  CLI::App app(
      "orbit_from_gl: the canonical 360-degree orbit from OpenGL camera-to-world matrices (x right, y up, looking\n"
      "along -z). POSES.txt: one camera per line, the 16 numbers of its 4x4 matrix in row-major order; without\n"
      "arguments a 120-degree arc of 33 cameras around the origin.",
      "orbit_from_gl");
  app.option_defaults()->always_capture_default();
  app.add_option("POSES.txt", poses_file, "the cameras, one 4x4 camera-to-world matrix a line");
  app.add_option("WIDTH", width, "image width")->check(CLI::Range(1, 1 << 20));
  app.add_option("HEIGHT", height, "image height")->check(CLI::Range(1, 1 << 20));
  app.add_option("FOV_Y_DEG", fov_y_deg, "vertical field of view in degrees")->check(CLI::Range(0.001, 179.999));
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    std::printf("%s", app.help().c_str());
    return 0;
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "orbit_from_gl: %s\n", e.what());
    return 2;
  }
  if (argc != 1 && argc != 5) {
    std::fprintf(stderr, "orbit_from_gl: give POSES.txt WIDTH HEIGHT FOV_Y_DEG, or nothing\n");
    return 2;
  }
  try {
    const std::vector<Eigen::Matrix4d> gl = poses_file.empty() ? example_arc() : read_poses(poses_file);
    const double fov_y = fov_y_deg * M_PI / 180;
    const double f = 0.5 * height / std::tan(0.5 * fov_y);
    const Intrinsics<double> k{f, f, 0.5 * width, 0.5 * height, width, height};

    std::vector<FrameCamera<double>> source;
    for (std::size_t i = 0; i < gl.size(); ++i)
      source.push_back({"frame " + std::to_string(i + 1), Camerad::from_opengl_camera_to_world(gl[i], k)});
    OrbitParams op;
    op.elevation_offset_deg = 10;  // the paper's: 10 degrees above the source cameras (0 keeps their height)
    op.width = width;
    op.height = height;
    const OrbitFit<double> fit = fit_orbit(source, op);

    std::printf("%d cameras used, radius %.3f, centre (%.3f, %.3f, %.3f)\n", fit.diagnostics.cameras_used,
                fit.orbit.radius, fit.orbit.center.x(), fit.orbit.center.y(), fit.orbit.center.z());
    std::printf("supported views 0-%d of %d, %zu in the gap a video model must complete\n", fit.support.arc_end,
                fit.views, fit.support.gap.size());
    const Eigen::Matrix4d first = fit.cameras.front().to_opengl_camera_to_world();
    std::printf("canonical view 0, OpenGL camera-to-world:\n");
    for (int r = 0; r < 4; ++r)
      std::printf("  %8.4f %8.4f %8.4f %8.4f\n", first(r, 0), first(r, 1), first(r, 2), first(r, 3));
    return 0;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "orbit_from_gl: %s\n", e.what());
    return 1;
  }
}

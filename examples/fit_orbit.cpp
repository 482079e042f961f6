// fit_orbit: the canonical 360-degree orbit from a source video's estimated cameras.
//
//   fit_orbit --colmap DIR | --transforms FILE | --npy-extrinsics F --npy-intrinsics F --npy-size WxH
//             | --synthetic
//             [--frames A-B] [--views 361] [--width 896 --height 512] [--elevation-offset 10]
//             [--circle-fit geometric|kasa] [--anchors source_aligned|target_half]
//             --out orbit.json [--export-colmap DIR] [--export-transforms FILE]
//
// --synthetic uses the project's own deterministic recorded input (a partial arc
// with noise and drift), so the program runs on a fresh machine with no data.
// On bad arguments or inputs: a message naming the problem, exit status 2 or 1,
// and no orbit.json (outputs are written to a temporary name and renamed).
#include <cstdio>
#include <iostream>
#include <string>

#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/colmap_frames.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/npy.hpp"
#include "orbitforge/io/transforms_json.hpp"
#include "orbitforge/pipeline/inputs/synthetic_input.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "cli.hpp"

using namespace orbitforge;

namespace {

const char* kDescription =
    "fit_orbit: the canonical 360-degree orbit from a source video's estimated cameras.\n"
    "  fit_orbit (--colmap DIR | --transforms FILE | --npy-extrinsics F --npy-intrinsics F --npy-size WxH |\n"
    "             --synthetic) [flags] --out orbit.json [--export-colmap DIR] [--export-transforms FILE]\n"
    "--frames counts every frame of the video, registered or not, as the pipeline does. On bad arguments or\n"
    "inputs: a message naming the problem, exit status 2 or 1, and no orbit.json.";

struct Args {
  std::string colmap, transforms, npy_ext, npy_int, npy_size, frames, out, export_colmap, export_transforms;
  std::string circle = "geometric", anchors = "source_aligned";
  bool synthetic = false, frames_given = false;
  OrbitParams orbit;
};

Args parse(int argc, char** argv) {
  Args a;
  CLI::App app(kDescription, "fit_orbit");
  cli::setup(app);
  const char* input = "Input (exactly one)";
  app.add_option("--colmap", a.colmap, "a COLMAP dataset (images/ + sparse/0)")->group(input);
  app.add_option("--transforms", a.transforms, "cameras from transforms.json")->group(input);
  app.add_option("--npy-extrinsics", a.npy_ext, "VGGT-style camera arrays (with --npy-intrinsics, --npy-size)")
      ->group(input);
  app.add_option("--npy-intrinsics", a.npy_int, "see --npy-extrinsics")->group(input);
  app.add_option("--npy-size", a.npy_size, "WxH, the estimator's image size (required with .npy cameras)")
      ->group(input);
  app.add_flag("--synthetic", a.synthetic,
               "the project's own deterministic recorded input (a partial arc with noise and drift), so the "
               "program runs on a fresh machine with no data")
      ->group(input);
  app.add_option("--frames", a.frames, "source video frames A-B (1-based, counting every frame; default all)")
      ->check(cli::frame_range());
  app.add_option("--views", a.orbit.views, "views of the canonical orbit")
      ->transform(cli::at_least(3))
      ->check(CLI::Range(3, kMaxOrbitViews));
  app.add_option("--width", a.orbit.width, "canonical view width")->transform(cli::at_least(1));
  app.add_option("--height", a.orbit.height, "canonical view height")->transform(cli::at_least(1));
  app.add_option("--elevation-offset", a.orbit.elevation_offset_deg, "degrees above the source cameras")
      ->check(cli::finite());
  app.add_option("--circle-fit", a.circle, "geometric or kasa")->check(CLI::IsMember({"geometric", "kasa"}));
  app.add_option("--anchors", a.anchors, "source_aligned or target_half")
      ->check(CLI::IsMember({"source_aligned", "target_half"}));
  app.add_option("--out", a.out, "the orbit file to write")->required();
  app.add_option("--export-colmap", a.export_colmap, "also write the orbit's cameras as a COLMAP text model");
  app.add_option("--export-transforms", a.export_transforms, "also write them as transforms.json");
  cli::parse(app, argc, argv);
  a.frames_given = app.count("--frames") > 0;
  if (a.frames_given) cli::recheck(app.get_name(), "--frames", a.frames, cli::frame_range());
  const int inputs = int(!a.colmap.empty()) + int(!a.transforms.empty()) + int(!a.npy_ext.empty() || !a.npy_int.empty()) +
                     int(a.synthetic);
  if (inputs != 1)
    throw cli::UsageError(
        "fit_orbit: give exactly one input: --colmap, --transforms, --npy-extrinsics/--npy-intrinsics or --synthetic");
  a.orbit.circle_fit = a.circle == "kasa" ? CircleFitMethod::kasa : CircleFitMethod::geometric;
  return a;
}

std::vector<FrameCamera<double>> load_cameras(const Args& a) {
  if (!a.colmap.empty())
    return colmap_video_frames<double>(read_colmap_model(find_colmap_model_dir(a.colmap)), colmap_images_dir(a.colmap));
  if (!a.transforms.empty()) return read_transforms_json<double>(a.transforms);
  if (a.synthetic) {
    SyntheticInputParams sp;
    auto in = make_synthetic_input<double>(sp);
    in.recorded.resize(sp.source_frames);  // the source video
    return in.recorded;
  }
  ensure(!a.npy_ext.empty() && !a.npy_int.empty(), "fit_orbit: --npy-extrinsics and --npy-intrinsics go together");
  int w = 0, h = 0;
  ensure(std::sscanf(a.npy_size.c_str(), "%dx%d", &w, &h) == 2 && w > 0 && h > 0,
         "fit_orbit: --npy-size WxH (the estimator's image size) is required with .npy cameras, got '", a.npy_size,
         "'");
  return read_npy_cameras<double>(a.npy_ext, a.npy_int, w, h);
}

}  // namespace

int main(int argc, char** argv) {
  return cli::run([&] {
    const Args a = parse(argc, argv);
    // --frames counts every frame of the video, registered or not, as the
    // pipeline does; frames without a camera are skipped and named.
    const RegisteredFrames<double> sel =
        select_registered_frames(load_cameras(a), a.frames_given ? parse_frame_range(a.frames) : FrameRange{});
    if (!sel.skipped.empty()) {
      std::cout << "fit_orbit: skipping " << sel.skipped.size() << " frames without a camera:";
      for (const auto& s : sel.skipped) std::cout << ' ' << s;
      std::cout << '\n';
    }
    const auto& cams = sel.cameras;
    const auto fit = fit_orbit(cams, a.orbit);
    std::vector<std::string> names;
    for (const auto& s : fit.source) names.push_back(s.name);
    LayoutParams lp;
    lp.placement = a.anchors == "target_half" ? AnchorPlacement::target_half : AnchorPlacement::source_aligned;
    const auto layout = endpoint_window_layout(fit.support, names, lp);
    write_orbit_json(a.out, fit, layout);

    if (!a.export_colmap.empty() || !a.export_transforms.empty()) {
      std::vector<FrameCamera<double>> views;
      for (int i = 0; i < fit.views; ++i) {
        char name[32];
        std::snprintf(name, sizeof(name), "%05d.png", i);
        views.push_back({name, fit.cameras[i], true});
      }
      if (!a.export_colmap.empty()) write_colmap_text(a.export_colmap, views);
      if (!a.export_transforms.empty()) write_transforms_json(a.export_transforms, views);
    }
    const auto& d = fit.diagnostics;
    std::cout << "fit_orbit: " << d.cameras_used << " cameras used, " << d.cameras_skipped.size() << " skipped; span "
              << d.source_span_deg << " deg; circle RMSE " << d.circle_rmse << "; look-at error " << d.lookat_error_deg
              << " deg (" << d.convention << "); normal by " << d.normal_rule << "; direction "
              << fit.orbit.direction << "; observed bins " << d.observed_bins << ", arc 0 to "
              << 360.0 * fit.support.arc_end / (fit.views - 1) << " deg, gap bins " << d.gap_bins << "; anchors " << layout.anchors.size()
              << " (index error mean " << layout.anchor_error_mean << ", max " << layout.anchor_error_max << ")\n"
              << "fit_orbit: wrote " << a.out << "\n";
    return 0;
  });
}

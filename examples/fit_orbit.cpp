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

const char* kUsage =
    "usage: fit_orbit (--colmap DIR | --transforms FILE | --npy-extrinsics F --npy-intrinsics F --npy-size WxH |\n"
    "                  --synthetic) [--frames A-B] [--views 361] [--width 896 --height 512]\n"
    "                 [--elevation-offset 10] [--circle-fit geometric|kasa] [--anchors source_aligned|target_half]\n"
    "                 --out orbit.json [--export-colmap DIR] [--export-transforms FILE]\n";

struct Args {
  std::string colmap, transforms, npy_ext, npy_int, npy_size, frames, out, export_colmap, export_transforms;
  std::string circle = "geometric", anchors = "source_aligned";
  bool synthetic = false, frames_given = false;
  OrbitParams orbit;
};

Args parse(int argc, char** argv) {
  Args a;
  cli::ArgWalker w("fit_orbit", argc, argv);
  auto integer = [&](long lo) { const std::string f = w.flag(); return int(cli::parse_int("fit_orbit", f, w.value(), lo)); };
  while (w.next()) {
    const std::string f = w.flag();
    if (f == "--colmap") a.colmap = w.value();
    else if (f == "--transforms") a.transforms = w.value();
    else if (f == "--npy-extrinsics") a.npy_ext = w.value();
    else if (f == "--npy-intrinsics") a.npy_int = w.value();
    else if (f == "--npy-size") a.npy_size = w.value();
    else if (f == "--synthetic") a.synthetic = true;
    else if (f == "--frames") {
      a.frames = w.value();
      a.frames_given = true;
      try {
        parse_frame_range(a.frames);
      } catch (const Error& e) {
        throw cli::UsageError(std::string("fit_orbit: --frames: ") + e.what());
      }
    }
    else if (f == "--views") a.orbit.views = int(cli::parse_int("fit_orbit", f, w.value(), 3, kMaxOrbitViews));
    else if (f == "--width") a.orbit.width = integer(1);
    else if (f == "--height") a.orbit.height = integer(1);
    else if (f == "--elevation-offset") a.orbit.elevation_offset_deg = cli::parse_double("fit_orbit", f, w.value());
    else if (f == "--circle-fit") a.circle = w.value();
    else if (f == "--anchors") a.anchors = w.value();
    else if (f == "--out") a.out = w.value();
    else if (f == "--export-colmap") a.export_colmap = w.value();
    else if (f == "--export-transforms") a.export_transforms = w.value();
    else w.unknown();
  }
  const int inputs = int(!a.colmap.empty()) + int(!a.transforms.empty()) + int(!a.npy_ext.empty() || !a.npy_int.empty()) +
                     int(a.synthetic);
  auto usage = [](bool ok, const char* message) {
    if (!ok) throw cli::UsageError(std::string("fit_orbit: ") + message);
  };
  usage(inputs == 1, "give exactly one input: --colmap, --transforms, --npy-extrinsics/--npy-intrinsics or --synthetic");
  usage(!a.out.empty(), "--out orbit.json is required");
  usage(a.circle == "geometric" || a.circle == "kasa", "--circle-fit must be geometric or kasa");
  a.orbit.circle_fit = a.circle == "kasa" ? CircleFitMethod::kasa : CircleFitMethod::geometric;
  usage(a.anchors == "source_aligned" || a.anchors == "target_half", "--anchors must be source_aligned or target_half");
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
  if (argc == 1 || (argc == 2 && (std::string(argv[1]) == "-h" || std::string(argv[1]) == "--help"))) {
    std::cout << kUsage;
    return argc == 1 ? 2 : 0;
  }
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

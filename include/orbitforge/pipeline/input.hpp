#pragma once
// The recorded input of the pipeline: every recorded frame of a video (name
// order), its estimated camera and its image at the working resolution, plus
// which frames play the source video. Loaders for a COLMAP dataset folder
// (images/ + sparse/0/) and for the embedded synthetic input.
//
// Frames outside the source range are never trained on by G0; the oracle
// completion and the held-out evaluation use them (pipeline/completion.hpp).
#include <cstdint>
#include <filesystem>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/synthetic_input.hpp"
#include "orbitforge/splat/renderer.hpp"

namespace orbitforge {

template <class Scalar>
struct PipelineInput {
  std::vector<FrameCamera<Scalar>> cameras;  // all recorded frames, name order; intrinsics at width x height
  std::vector<Image<Scalar>> images;         // parallel to cameras, [H][W][3] in [0, 1]
  std::vector<int> source;                   // indices into cameras: the source video
  std::vector<Scalar> points, colors;        // optional sparse points [N][3] and RGB in [0, 1]
  int width = 0, height = 0;
  std::string description;                   // where it came from (for the report)
  std::array<double, 3> background{{0, 0, 0}};
};

// FNV-1a 64-bit, used for the stages' input/settings hashes.
inline std::uint64_t fnv1a(const void* data, std::size_t n, std::uint64_t h = 1469598103934665603ull) {
  const auto* p = static_cast<const unsigned char*>(data);
  for (std::size_t i = 0; i < n; ++i) {
    h ^= p[i];
    h *= 1099511628211ull;
  }
  return h;
}
inline std::uint64_t fnv1a(const std::string& s, std::uint64_t h = 1469598103934665603ull) {
  return fnv1a(s.data(), s.size(), h);
}

inline std::string hex64(std::uint64_t h) {
  std::ostringstream os;
  os << std::hex << h;
  return os.str();
}

// A hash of everything in the input that results depend on.
template <class Scalar>
std::uint64_t input_hash(const PipelineInput<Scalar>& in) {
  std::ostringstream os;
  os.precision(10);
  os << in.width << 'x' << in.height << ' ' << in.background[0] << ',' << in.background[1] << ','
     << in.background[2] << '\n';
  for (const auto& c : in.cameras) {
    const auto& k = c.camera.intrinsics;
    os << c.name << ' ' << c.valid << ' ' << k.fx << ' ' << k.fy << ' ' << k.cx << ' ' << k.cy << ' ' << k.width
       << ' ' << k.height;
    for (int r = 0; r < 3; ++r)
      for (int q = 0; q < 3; ++q) os << ' ' << c.camera.R(r, q);
    for (int r = 0; r < 3; ++r) os << ' ' << c.camera.t[r];
    os << '\n';
  }
  for (int s : in.source) os << s << ' ';
  std::uint64_t h = fnv1a(os.str());
  for (const auto& img : in.images) h = fnv1a(img.data.data(), img.data.size() * sizeof(Scalar), h);
  h = fnv1a(in.points.data(), in.points.size() * sizeof(Scalar), h);
  h = fnv1a(in.colors.data(), in.colors.size() * sizeof(Scalar), h);
  return h;
}

// A COLMAP dataset folder (images/ and sparse/0/, or a model folder whose parent
// holds images/). `source` selects the source frames (1-based, name order); every
// registered frame's image is loaded and resized to width x height.
template <class Scalar>
PipelineInput<Scalar> load_colmap_input(const std::string& dir, const std::string& source_range, int width,
                                        int height) {
  namespace fs = std::filesystem;
  ensure(width >= 8 && height >= 8, "load_colmap_input: working size ", width, "x", height, " is too small");
  const std::string model_dir = find_colmap_model_dir(dir);
  const ColmapModel model = read_colmap_model(model_dir);
  PipelineInput<Scalar> in;
  in.width = width;
  in.height = height;
  in.cameras = colmap_frame_cameras<Scalar>(model);
  ensure(!in.cameras.empty(), dir, ": the COLMAP model has no images");
  const FrameRange r = parse_frame_range(source_range.empty() ? std::string("1-") : source_range);
  const auto selected = select_frames(in.cameras, r);  // checks the range against the frame count
  const int first = r.first - 1;
  for (int i = 0; i < int(selected.size()); ++i) in.source.push_back(first + i);
  fs::path images = fs::path(dir) / "images";
  if (!fs::is_directory(images)) images = fs::path(model_dir).parent_path().parent_path() / "images";
  ensure(fs::is_directory(images), dir, ": no images/ folder next to the COLMAP model");
  in.images.resize(in.cameras.size());
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    auto& fc = in.cameras[i];
    if (!fc.valid) continue;
    const std::string path = (images / fc.name).string();
    ensure(fs::exists(path), path, ": frame ", i + 1, " (", fc.name, ") is in the COLMAP model but its image is missing");
    const Image<Scalar> img = to_rgb(read_image<Scalar>(path));
    const auto& k = fc.camera.intrinsics;
    ensure(img.width == k.width && img.height == k.height, path, ": image is ", img.width, "x", img.height,
           ", its COLMAP camera is ", k.width, "x", k.height);
    in.images[i] =
        (img.width == width && img.height == height) ? img : resize_image(img, width, height, ResizeFilter::area);
    fc.camera.intrinsics = k.resized(width, height);
  }
  for (const auto& p : model.points) {
    for (int c = 0; c < 3; ++c) {
      in.points.push_back(Scalar(p.xyz[c]));
      in.colors.push_back(Scalar(p.rgb[std::size_t(c)]) / Scalar(255));
    }
  }
  in.description = "colmap " + dir + " frames " + (source_range.empty() ? std::string("all") : source_range);
  return in;
}

// The embedded synthetic recorded input: frames rendered from the ground-truth
// scene at the TRUE cameras; the recorded (noisy) cameras are what the pipeline
// sees. The first p.source_frames frames are the source.
template <class Scalar>
PipelineInput<Scalar> synthetic_pipeline_input(const SyntheticInputParams& p, int threads = 0) {
  const SyntheticInput<Scalar> syn = make_synthetic_input<Scalar>(p);
  PipelineInput<Scalar> in;
  in.width = p.width;
  in.height = p.height;
  in.cameras = syn.recorded;
  RenderParams<Scalar> rp;
  rp.threads = threads;
  Renderer<Scalar> r(rp);
  for (const auto& cam : syn.true_cameras) in.images.push_back(r.render(SceneView<Scalar>(syn.scene), cam).color);
  for (auto& img : in.images)
    for (auto& v : img.data) v = std::min(Scalar(1), std::max(Scalar(0), v));
  for (int i = 0; i < p.source_frames; ++i) in.source.push_back(i);
  std::ostringstream os;
  os << "synthetic (" << p.frames << " frames, source 1-" << p.source_frames << ", " << p.width << "x" << p.height
     << ", seed " << p.seed << ")";
  in.description = os.str();
  return in;
}

}  // namespace orbitforge

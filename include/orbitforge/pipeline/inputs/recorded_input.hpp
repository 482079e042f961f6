#pragma once
// The recorded input of the pipeline: every frame of a video (name order of its
// image folder, whether or not the camera estimator gave it a camera), the
// estimated cameras, the images at the working resolution, which frames play
// the source video, and the sparse points with the frames that observed them.
// The loaders are pipeline/inputs/colmap_input.hpp (a COLMAP dataset folder),
// frame_inputs.hpp (transforms.json, .npy cameras) and synthetic_pipeline_input.hpp.
//
// Frame numbers are video frames: a source range "1-33" means the first 33
// images of the folder. Frames of the range without an estimated camera are
// left out (source_skipped says which and why) and do not shift the others; a
// frame's time code follows its number, (frame - first) / (last - first) over
// the range, so a missing frame leaves a gap in time.
//
// Evidence: only what the source frames show may reach the method. Frames
// outside the source range are used by the oracle completion provider and for
// held-out evaluation only (pipeline/completion/provider.hpp); sparse points reach a
// reconstruction only when at least `min_observations` source frames that it
// trains on observed them (source_points), since a camera estimator run on the
// source video alone could not have triangulated the others.
#include <algorithm>
#include <array>
#include <cstdint>
#include <filesystem>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/hash.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/geometry/camera_alignment.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/splat/scene_frame.hpp"
#include "orbitforge/train/background.hpp"

namespace orbitforge {

// A reference model of the whole recorded orbit, aligned to the input's cameras
// (pipeline/report/reference.hpp); scoring reads it, the method never does.
template <class Scalar>
struct ReferenceInfo {
  std::string description;
  CameraAlignment alignment;                       // reference -> the input's frame
  std::map<int, Camera<Scalar>> source_cameras;   // aligned reference cameras of the source frames
};

struct SkippedFrame {
  int frame = 0;        // index into PipelineInput::cameras
  std::string name, reason;
};

template <class Scalar>
struct PipelineInput {
  std::vector<FrameCamera<Scalar>> cameras;  // every frame, name order; valid = has an estimated camera;
                                             // intrinsics at width x height
  std::vector<Image<Scalar>> images;         // parallel to cameras, [H][W][3] in [0, 1]; empty without a camera
  int source_first = 0, source_last = -1;    // the source range (indices into cameras, inclusive)
  std::vector<int> source;                   // frames of the range with a camera: the successful-camera set
  std::vector<SkippedFrame> source_skipped;  // frames of the range left out, and why
  std::vector<int> withheld;                 // source frames no reconstruction trains on (scored only)
  // Sparse points [N][3], RGB [N][3] in [0, 1], and for each point the frames
  // (indices into cameras) that observed it. Without tracks, nothing tells which
  // frames saw a point, and source_points() uses none of them.
  std::vector<Scalar> points, colors;
  std::vector<std::vector<int>> point_frames;
  std::string points_origin = "the input's model";  // or the points stage (stages/points.hpp)
  int width = 0, height = 0;
  std::string description;                   // where it came from (for the report)
  std::array<double, 3> background{{0, 0, 0}};
  std::string background_reason = "default";
  bool random_background = false;  // training draws a background colour per iteration (TrainParams)
  // Where the cameras came from, for the report: a figure measured on cameras
  // estimated with frames outside the source is a lab figure.
  std::string camera_path = "recorded";
  bool estimated_cameras = false;  // estimated by the method from the source frames (the cameras stage)
  std::optional<ReferenceInfo<Scalar>> reference;
  std::map<int, Camera<Scalar>> scoring_cameras;  // frames scored at another camera than their own
  // The similarity from the recorded model's frame to the one cameras and points
  // are in here (splat/scene_frame.hpp): identity unless loaded normalised; outputs
  // go back through frame.to_user.
  SceneFrame frame;

  // The camera a frame is scored at.
  const Camera<Scalar>& scoring_camera(int frame) const {
    const auto it = scoring_cameras.find(frame);
    return it != scoring_cameras.end() ? it->second : cameras[std::size_t(frame)].camera;
  }

  bool is_withheld(int frame) const { return std::find(withheld.begin(), withheld.end(), frame) != withheld.end(); }

  // Time code of a frame of the source range: its place in the range.
  double time_code(int frame) const {
    const int span = source_last - source_first;
    return span > 0 ? std::min(1.0, std::max(0.0, double(frame - source_first) / double(span))) : 0.0;
  }
};

// Withholds every k-th frame of the source range (by frame number within the
// range, 1-based: frames k, 2k, ...) from every reconstruction; they are scored
// as supported views no reconstruction saw. k = 0 withholds nothing.
template <class Scalar>
void withhold_every(PipelineInput<Scalar>& in, int k) {
  ensure(k == 0 || k >= 2, "withhold_every: k must be 0 (none) or at least 2, got ", k);
  in.withheld.clear();
  if (k == 0) return;
  for (int f : in.source)
    if ((f - in.source_first + 1) % k == 0) in.withheld.push_back(f);
}

// The source frames a reconstruction trains on: the source minus the withheld.
template <class Scalar>
std::vector<int> training_source(const PipelineInput<Scalar>& in) {
  std::vector<int> t;
  for (int f : in.source)
    if (!in.is_withheld(f)) t.push_back(f);
  return t;
}

template <class Scalar>
struct SourcePoints {
  std::vector<Scalar> points, colors;  // the kept points, [N][3]
  std::size_t total = 0, kept = 0, dropped = 0;
  std::string rule;
};

// The sparse points that at least `min_observations` training source frames
// observed (a track is counted once per frame).
template <class Scalar>
SourcePoints<Scalar> source_points(const PipelineInput<Scalar>& in, int min_observations = 2) {
  SourcePoints<Scalar> r;
  r.total = in.points.size() / 3;
  r.rule = "kept when at least " + std::to_string(min_observations) +
           " source frames used for training observed the point";
  if (r.total == 0) return r;
  if (in.point_frames.size() != r.total) {
    r.dropped = r.total;
    r.rule = "dropped: the input does not say which frames observed its points";
    return r;
  }
  std::vector<char> training(in.cameras.size(), 0);
  for (int f : training_source(in)) training[std::size_t(f)] = 1;
  std::vector<int> seen;
  for (std::size_t i = 0; i < r.total; ++i) {
    seen.clear();
    for (int f : in.point_frames[i])
      if (f >= 0 && std::size_t(f) < training.size() && training[std::size_t(f)]) seen.push_back(f);
    std::sort(seen.begin(), seen.end());
    const auto distinct = std::unique(seen.begin(), seen.end()) - seen.begin();
    if (distinct < min_observations) continue;
    for (int c = 0; c < 3; ++c) {
      r.points.push_back(in.points[3 * i + std::size_t(c)]);
      r.colors.push_back(in.colors[3 * i + std::size_t(c)]);
    }
  }
  r.kept = r.points.size() / 3;
  r.dropped = r.total - r.kept;
  return r;
}

// Sets in.background from the borders of the training source frames
// (train/background.hpp), unless `override_color` is given (e.g. --background).
template <class Scalar>
BackgroundEstimate choose_background(PipelineInput<Scalar>& in, const std::array<double, 3>* override_color = nullptr,
                                     const BackgroundParams& bp = {}) {
  BackgroundEstimate e;
  if (override_color) {
    e.color = *override_color;
    e.reason = "given by the caller (--background)";
  } else {
    std::vector<const Image<Scalar>*> frames;
    for (int f : training_source(in)) frames.push_back(&in.images[std::size_t(f)]);
    e = estimate_background(frames, bp);
  }
  in.background = e.color;
  in.background_reason = e.reason;
  in.random_background = e.random;
  return e;
}

// `--background random`: training draws a colour per iteration whatever the
// borders say; the chosen colour stays that of every other render.
template <class Scalar>
void force_random_background(PipelineInput<Scalar>& in, BackgroundEstimate& e) {
  e.random = in.random_background = true;
  e.reason += "; training draws a random background colour each iteration (--background random)";
  in.background_reason = e.reason;
}

// A hash of everything in the input that results depend on.
template <class Scalar>
std::uint64_t input_hash(const PipelineInput<Scalar>& in) {
  std::ostringstream os;
  os.precision(10);
  os << in.width << 'x' << in.height << ' ' << (in.random_background ? "random " : "") << in.background[0] << ','
     << in.background[1] << ','
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
  os << "range " << in.source_first << ' ' << in.source_last << " source";
  for (int s : in.source) os << ' ' << s;
  os << " withheld";
  for (int s : in.withheld) os << ' ' << s;
  os << " scored at";
  for (const auto& [f, c] : in.scoring_cameras) {
    os << ' ' << f;
    for (int r = 0; r < 3; ++r) os << ' ' << c.R(r, 0) << ' ' << c.R(r, 1) << ' ' << c.R(r, 2) << ' ' << c.t[r];
    os << ' ' << c.intrinsics.fx << ' ' << c.intrinsics.fy;
  }
  os << '\n';
  if (!in.frame.is_identity())  // (only then, so that earlier hashes stay valid)
    os << "frame " << in.frame.origin[0] << ' ' << in.frame.origin[1] << ' ' << in.frame.origin[2] << ' '
       << in.frame.scale << '\n';
  std::uint64_t h = fnv1a(os.str());
  for (const auto& img : in.images) h = fnv1a(img.data.data(), img.data.size() * sizeof(Scalar), h);
  h = fnv1a(in.points.data(), in.points.size() * sizeof(Scalar), h);
  h = fnv1a(in.colors.data(), in.colors.size() * sizeof(Scalar), h);
  for (const auto& t : in.point_frames) h = fnv1a(t.data(), t.size() * sizeof(int), h);
  return h;
}

// Selects the source range over the input's frames (by position in name order)
// and fills source / source_skipped. Checks the range against the frame count.
template <class Scalar>
void select_source(PipelineInput<Scalar>& in, const std::string& range_text) {
  const FrameRange r = parse_frame_range(range_text.empty() ? std::string("1-") : range_text);
  const int n = int(in.cameras.size());
  ensure(r.first <= n, "frame range ", range_text, ": first frame ", r.first, " is beyond the ", n,
         " frames of the input");
  const int last = r.last < 0 ? n : r.last;
  ensure(last <= n, "frame range ", range_text, ": last frame ", last, " is beyond the ", n, " frames of the input");
  in.source_first = r.first - 1;
  in.source_last = last - 1;
  in.source.clear();
  in.source_skipped.clear();
  for (int i = in.source_first; i <= in.source_last; ++i) {
    const auto& fc = in.cameras[std::size_t(i)];
    if (!fc.valid)
      in.source_skipped.push_back({i, fc.name, "no estimated camera (the camera estimator did not register it)"});
    else if (in.images[std::size_t(i)].empty())
      in.source_skipped.push_back({i, fc.name, "no image"});
    else
      in.source.push_back(i);
  }
}

}  // namespace orbitforge

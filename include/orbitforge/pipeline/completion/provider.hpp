#pragma once
// Completion of the unsupported gap U_gap behind one small interface, and the
// assembled training set V_hat of the second reconstruction.
//
// A provider gets the fitted orbit, the endpoint-window layout, the first
// reconstruction's renders R0 (by canonical view) and a folder of its own, and
// returns either the completion frames (each with the camera it was taken from
// and its position on the canonical orbit) or "not ready" with a message (the
// pipeline then stops; a later run asks again).
//
//   none     - no completion: R0 is reused (the MedianGS-only baseline).
//   oracle   - recorded frames outside the source whose cameras fall in U_gap,
//              split by 1-based name-order index: even -> completion (with their
//              own recorded camera), odd -> held out for evaluation only.
//   external - writes the request for a keyframe-conditioned video model
//              (conditioning frames in synthetic order, anchors with synthetic
//              indices, the 8m+1 frame count, the prompt, manifest.json) and
//              waits for the completed clip in the folder the manifest names.
#include <cmath>
#include <filesystem>
#include <functional>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/binning.hpp"
#include "orbitforge/geometry/completion_layout.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"

namespace orbitforge {

// One training frame of V_hat (or a completion frame before assembly).
template <class Scalar>
struct VhatFrame {
  Image<Scalar> image;
  Camera<Scalar> camera;
  double position = 0;  // canonical view index (fractional for off-orbit cameras), for order and time code
  std::string origin;   // "R0 view 12", "recorded 046.png", "completed 0123.png"
  bool from_r0 = false; // an R0 render of the supported arc (else a completion frame)
  int order = -1;       // a completion frame's place in the provider's own sequence (the clip's order)
};

// Position of a recorded camera on the canonical orbit, in views (0 .. N-1, fractional).
template <class Scalar>
double orbit_position(const OrbitFit<Scalar>& fit, const Camera<Scalar>& cam) {
  const auto& g = fit.orbit;
  const double az = double(orbit_azimuth_deg<Scalar>(cam.center(), g.center, g.e1, g.e2));
  const double delta = wrap_deg_360(double(g.direction) * (az - double(g.theta0_deg)));
  return delta / 360.0 * double(fit.views - 1);
}

// Recorded frames (not in the source, valid, with an image) whose cameras fall in
// U_gap, split by 1-based name-order index: even -> completion, odd -> held out.
struct GapFrames {
  std::vector<int> completion;  // indices into input.cameras
  std::vector<int> heldout;
};

template <class Scalar>
GapFrames gap_frames(const PipelineInput<Scalar>& in, const OrbitFit<Scalar>& fit) {
  GapFrames g;
  std::vector<char> is_source(in.cameras.size(), 0);
  for (int s : in.source) is_source[std::size_t(s)] = 1;
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    if (is_source[i] || !in.cameras[i].valid || in.images[i].empty()) continue;
    if (!camera_problem(in.cameras[i]).empty()) continue;
    const double pos = orbit_position(fit, in.cameras[i].camera);
    const int bin = std::min(fit.views - 1, int(std::lround(pos)));
    if (fit.support.in_arc(bin)) continue;
    ((i + 1) % 2 == 0 ? g.completion : g.heldout).push_back(int(i));
  }
  return g;
}

template <class Scalar>
struct CompletionContext {
  const PipelineInput<Scalar>* input = nullptr;
  const OrbitFit<Scalar>* fit = nullptr;
  const CompletionLayout* layout = nullptr;
  std::function<Image<Scalar>(int)> r0;  // R0 render of a canonical view (must be a rendered view)
  std::function<bool(int)> r0_rendered;  // whether R0 exists for that view
  std::string folder;                    // the provider's own folder (created by the pipeline)
  std::string prompt;
  std::string negative_prompt;           // what the video model should avoid (may be empty)
  bool condition_on_r0 = true;           // the request lists R0's known frames (else sparse anchors only)
};

template <class Scalar>
struct CompletionResult {
  bool ready = false;
  bool reuse_r0 = false;                 // "none": the second reconstruction is R0's scene
  std::string message;                   // why not ready / what was done
  std::vector<VhatFrame<Scalar>> frames; // completion frames for U_gap
  nlohmann::json summary = nlohmann::json::object();
};

template <class Scalar>
class CompletionProvider {
 public:
  virtual ~CompletionProvider() = default;
  virtual std::string name() const = 0;
  // Something that changes when the provider's answer would change (for resuming).
  virtual std::string state_key(const CompletionContext<Scalar>&) const { return name(); }
  virtual CompletionResult<Scalar> complete(const CompletionContext<Scalar>& ctx) = 0;
};

template <class Scalar>
class NoCompletion : public CompletionProvider<Scalar> {
 public:
  std::string name() const override { return "none"; }
  CompletionResult<Scalar> complete(const CompletionContext<Scalar>&) override {
    CompletionResult<Scalar> r;
    r.ready = true;
    r.reuse_r0 = true;
    r.message = "no completion: R0 is reused (MedianGS-only baseline)";
    return r;
  }
};

template <class Scalar>
class OracleCompletion : public CompletionProvider<Scalar> {
 public:
  std::string name() const override { return "oracle"; }
  CompletionResult<Scalar> complete(const CompletionContext<Scalar>& ctx) override {
    const GapFrames g = gap_frames(*ctx.input, *ctx.fit);
    ensure(!g.completion.empty(), "oracle completion: no recorded frame outside the source falls in the gap U_gap (",
           ctx.fit->support.gap.size(), " bins); the oracle needs a video that covers more than the source frames");
    CompletionResult<Scalar> r;
    r.ready = true;
    nlohmann::json used = nlohmann::json::array(), held = nlohmann::json::array();
    for (int i : g.completion) {
      VhatFrame<Scalar> f;
      f.image = ctx.input->images[std::size_t(i)];
      f.camera = ctx.input->cameras[std::size_t(i)].camera;
      f.position = orbit_position(*ctx.fit, f.camera);
      f.origin = "recorded " + ctx.input->cameras[std::size_t(i)].name;
      used.push_back(ctx.input->cameras[std::size_t(i)].name);
      r.frames.push_back(std::move(f));
    }
    for (int i : g.heldout) held.push_back(ctx.input->cameras[std::size_t(i)].name);
    r.summary = {{"completion_frames", used}, {"heldout_frames", held}};
    r.message = std::to_string(g.completion.size()) + " recorded gap frames given as completion, " +
                std::to_string(g.heldout.size()) + " held out";
    return r;
  }
};

// The request folder (ctx.folder):
//   conditioning/NNNN.png   known slots of the clip (R0 renders), NNNN = synthetic index
//   anchors/NNNN.png        sparse source-frame anchors at their synthetic index
//   manifest.json           frames (8m+1), size, prompt, the lists above, synthetic_to_canonical,
//                           "completed_dir" and "completed_pattern"
//   completed/NNNN.png      expected: the whole completed clip, frames 0 .. frames-1
template <class Scalar>
class ExternalCompletion : public CompletionProvider<Scalar> {
 public:
  std::string name() const override { return "external"; }

  std::string state_key(const CompletionContext<Scalar>& ctx) const override {
    namespace fs = std::filesystem;
    std::uint64_t h = fnv1a(name());
    const int frames = ctx.layout->frames;
    for (int j = 0; j < frames; ++j) {
      const fs::path p = completed_path(ctx.folder, j);
      std::error_code ec;
      if (fs::exists(p, ec)) h = fnv1a(read_file_bytes(p.string()), h);
    }
    return name() + ":" + hex64(h);
  }

  CompletionResult<Scalar> complete(const CompletionContext<Scalar>& ctx) override {
    namespace fs = std::filesystem;
    const CompletionLayout& L = *ctx.layout;
    const fs::path dir(ctx.folder);
    fs::create_directories(dir / "conditioning");
    fs::create_directories(dir / "anchors");
    fs::create_directories(dir / "completed");
    nlohmann::json cond = nlohmann::json::array(), anchors = nlohmann::json::array();
    for (int j = 0; j < L.frames && ctx.condition_on_r0; ++j) {
      const int v = L.synthetic_to_canonical[std::size_t(j)];
      if (!L.known[std::size_t(j)] || !ctx.r0_rendered(v)) continue;
      const std::string file = "conditioning/" + frame_name(j);
      if (!fs::exists(dir / file)) write_png((dir / file).string(), ctx.r0(v));
      cond.push_back({{"synthetic", j}, {"canonical", v}, {"file", file}});
    }
    const auto& in = *ctx.input;
    const int width = ctx.fit->intrinsics.width, height = ctx.fit->intrinsics.height;  // the canonical views
    for (const auto& a : L.anchors) {
      // fit.source indexes the source list; in.source maps it to the input's frames.
      const int frame = in.source[std::size_t(ctx.fit->source[std::size_t(a.source_index)].input_index)];
      if (in.is_withheld(frame)) continue;  // withheld frames reach no model
      const std::string file = "anchors/" + frame_name(a.synthetic);
      const auto& img = in.images[std::size_t(frame)];
      write_png((dir / file).string(), img);
      // The canonical focal length is the source's scaled by the height ratio, so
      // a source frame of another aspect shows the centre of the view at that
      // scale: the box it covers, in the canonical view's pixels.
      const double scale = double(height) / double(img.height);
      const double covered = double(img.width) * scale, x0 = 0.5 * (double(width) - covered);
      anchors.push_back({{"synthetic", a.synthetic},
                         {"canonical", a.canonical},
                         {"name", a.name},
                         {"file", file},
                         {"width", img.width},
                         {"height", img.height},
                         {"covers", {x0, 0.0, x0 + covered, double(height)}}});
    }
    nlohmann::json m = {{"frames", L.frames},
                        {"width", width},
                        {"height", height},
                        {"prompt", ctx.prompt},
                        {"negative_prompt", ctx.negative_prompt},
                        {"start", L.start},
                        {"arc_end", L.arc_end},
                        {"synthetic_to_canonical", L.synthetic_to_canonical},
                        {"conditioning", cond},
                        {"anchors", anchors},
                        {"completed_dir", "completed"},
                        {"completed_pattern", "%04d.png"},
                        {"note",
                         "Generate a clip of `frames` frames (8m+1). Frame j shows canonical view "
                         "synthetic_to_canonical[j]. Condition on the conditioning frames and the anchors at their "
                         "synthetic indices (for LTX-Video: conditioning media paths = the files, conditioning start "
                         "frames = the synthetic indices). An anchor of another size than width x height shows the "
                         "box `covers` of its view (x0, y0, x1, y1 in the view's pixels; a square source frame is "
                         "the centre of a wide view): place it there, do not stretch it. Write every frame as "
                         "completed/NNNN.png (NNNN = synthetic index, 0-based) at width x height, then run the "
                         "pipeline again."}};
    write_file_atomic((dir / "manifest.json").string(), m.dump(1) + "\n");

    CompletionResult<Scalar> r;
    std::vector<int> missing;
    for (int j = 0; j < L.frames; ++j)
      if (!fs::exists(completed_path(ctx.folder, j))) missing.push_back(j);
    if (!missing.empty()) {
      r.ready = false;
      r.message = "completion request written to " + (dir / "manifest.json").string() + "; " +
                  std::to_string(missing.size()) + " of " + std::to_string(L.frames) +
                  " completed frames are missing in " + (dir / "completed").string() +
                  " (first missing: " + frame_name(missing.front()) +
                  "). Run the video model, put its frames there, and run the pipeline again.";
      return r;
    }
    for (const auto& e : assembly_plan(L)) {
      if (e.from != AssemblyEntry::From::completion) continue;
      const std::string path = completed_path(ctx.folder, e.synthetic).string();
      Image<Scalar> img = to_rgb(read_image<Scalar>(path));
      ensure(img.width > 0 && img.height > 0, path, ": empty image");
      if (img.width != width || img.height != height) img = resize_image(img, width, height, ResizeFilter::area);
      VhatFrame<Scalar> f;
      f.image = std::move(img);
      f.camera = ctx.fit->cameras[std::size_t(e.canonical)];
      f.position = e.canonical;
      f.origin = "completed " + frame_name(e.synthetic);
      r.frames.push_back(std::move(f));
    }
    r.ready = true;
    r.message = std::to_string(r.frames.size()) + " completed gap views read from " + (dir / "completed").string();
    r.summary = {{"completed_dir", (dir / "completed").string()}, {"gap_views", r.frames.size()}};
    return r;
  }

  static std::string frame_name(int j) { return numbered_png(j, 4); }
  static std::filesystem::path completed_path(const std::string& folder, int j) {
    return std::filesystem::path(folder) / "completed" / frame_name(j);
  }
};

}  // namespace orbitforge

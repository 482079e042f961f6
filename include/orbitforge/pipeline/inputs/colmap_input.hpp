#pragma once
// Loads a COLMAP dataset folder as the pipeline's recorded input
// (pipeline/inputs/recorded_input.hpp says what the input holds and which frames
// are evidence).
#include <algorithm>
#include <filesystem>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/colmap_frames.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/inputs/image_order.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/working_size.hpp"
#include "orbitforge/splat/scene_frame.hpp"

namespace orbitforge {

// A COLMAP dataset folder (images/ and sparse/0/, or a model folder whose parent
// holds images/). Frames are the image files of images/ in name order, with a
// camera when the model registered them. `source_range` selects the source
// frames (1-based frame numbers, e.g. "1-33"); every registered frame's image is
// loaded and resized to the working size (intrinsics rescaled). The frames' own
// size (WorkingSize::native) needs every registered camera to have one size; a
// longer side takes the aspect of the first registered camera.
// normalise: cameras and points are moved, in double, into the frame fitted to
// the registered cameras (fit_scene_frame), recorded in `frame`; else as recorded.
// order: ImageOrder::ring numbers the frames around their cameras' ring instead of
// by name (image_order.hpp).
template <class Scalar>
PipelineInput<Scalar> load_colmap_input(const std::string& dir, const std::string& source_range,
                                        const WorkingSize& size, bool normalise = false,
                                        ImageOrder order = ImageOrder::name) {
  namespace fs = std::filesystem;
  size.check("load_colmap_input");
  const bool native = size.is_native();
  int width = size.width, height = size.height;
  const ColmapModel model = read_colmap_model(find_colmap_model_dir(dir));
  const std::string images_dir = colmap_images_dir(dir);
  ensure(!images_dir.empty(), dir, ": no images/ folder next to the COLMAP model");
  const fs::path images(images_dir);
  // Every frame in double; the normalised frame is fitted and applied before the
  // cast, so a model far from the origin or at any scale keeps its precision.
  std::vector<FrameCamera<double>> frames_d = colmap_video_frames<double>(model, images_dir);
  if (order == ImageOrder::ring) {
    std::vector<FrameCamera<double>> ring;
    for (std::size_t i : ring_order(frames_d)) ring.push_back(frames_d[i]);
    frames_d = std::move(ring);
  }
  SceneFrame frame;
  if (normalise) {
    std::vector<Eigen::Vector3d> centres;
    for (const auto& fc : frames_d)
      if (fc.valid) centres.push_back(fc.camera.center());
    std::vector<double> xyz;
    for (const auto& p : model.points) xyz.insert(xyz.end(), p.xyz.data(), p.xyz.data() + 3);
    frame = fit_scene_frame(centres, xyz);
  }
  PipelineInput<Scalar> in;
  for (const auto& fc : frames_d) {
    FrameCamera<Scalar> c;
    c.name = fc.name;
    c.valid = fc.valid;
    c.camera = (fc.valid ? frame.to_normalised(fc.camera) : fc.camera).template cast<Scalar>();
    ensure(c.camera.is_finite(), dir, ": image ", fc.name, ": camera values do not fit the precision (too large)");
    in.cameras.push_back(std::move(c));
  }
  in.frame = frame;
  if (native || size.long_side > 0) {
    const FrameCamera<Scalar>* first = nullptr;
    for (const auto& fc : in.cameras) {
      if (!fc.valid) continue;
      if (!first) first = &fc;
      ensure(!native || (fc.camera.intrinsics.width == first->camera.intrinsics.width &&
                         fc.camera.intrinsics.height == first->camera.intrinsics.height),
             dir, ": image ", fc.name, " is ", fc.camera.intrinsics.width, "x", fc.camera.intrinsics.height,
             ", the first is ", first->camera.intrinsics.width, "x", first->camera.intrinsics.height,
             "; give a working size to load frames of several sizes");
    }
    ensure(first != nullptr, dir, ": the COLMAP model registers none of the frames");
    const auto wh = size.for_frames(first->camera.intrinsics.width, first->camera.intrinsics.height);
    width = wh[0];
    height = wh[1];
  }
  in.width = width;
  in.height = height;

  in.images.resize(in.cameras.size());
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    auto& fc = in.cameras[i];
    const auto k = fc.camera.intrinsics;
    fc.camera.intrinsics = k.resized(width, height);
    if (!fc.valid) continue;
    const std::string path = (images / fc.name).string();
    const Image<Scalar> img = to_rgb(read_image<Scalar>(path));
    ensure(img.width == k.width && img.height == k.height, path, ": image is ", img.width, "x", img.height,
           ", its COLMAP camera is ", k.width, "x", k.height);
    in.images[i] =
        (img.width == width && img.height == height) ? img : resize_image(img, width, height, ResizeFilter::area);
  }
  select_source(in, source_range);

  // Points with the frames that observed them.
  std::map<int, int> frame_of_image;
  {
    std::map<std::string, int> frame_of_name;
    for (std::size_t i = 0; i < in.cameras.size(); ++i) frame_of_name[in.cameras[i].name] = int(i);
    for (const auto& [id, im] : model.images) frame_of_image[id] = frame_of_name.at(im.name);
  }
  for (const auto& p : model.points) {
    std::vector<int> frames;
    for (int image_id : p.track_images) {
      const auto it = frame_of_image.find(image_id);
      if (it != frame_of_image.end()) frames.push_back(it->second);
    }
    const Eigen::Vector3d x = frame.to_normalised(Eigen::Vector3d(p.xyz[0], p.xyz[1], p.xyz[2]));
    for (int c = 0; c < 3; ++c) {
      in.points.push_back(Scalar(x[c]));
      in.colors.push_back(Scalar(p.rgb[std::size_t(c)]) / Scalar(255));
    }
    in.point_frames.push_back(std::move(frames));
  }
  in.description = "colmap " + dir + " frames " + (source_range.empty() ? std::string("all") : source_range) +
                   (order == ImageOrder::ring ? " (numbered around the ring)" : "");
  in.camera_path = "recorded model (a lab figure when its maker estimated it with frames outside the source)";
  return in;
}

// width x height; 0 x 0: the frames' own size.
template <class Scalar>
PipelineInput<Scalar> load_colmap_input(const std::string& dir, const std::string& source_range, int width,
                                        int height, bool normalise = false) {
  return load_colmap_input<Scalar>(dir, source_range, WorkingSize::from_pair(width, height), normalise);
}

}  // namespace orbitforge

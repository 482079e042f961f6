#pragma once
// Recorded inputs whose cameras come from files beside the frames instead of a
// COLMAP model: a transforms.json (nerfstudio / instant-ngp) and VGGT-style .npy
// arrays (io/npy.hpp). Frames, numbering, source range and skipped frames work
// as in load_colmap_input (pipeline/inputs/recorded_input.hpp); these inputs have no sparse
// points, so reconstructions start from random points (reconstruction.hpp).
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/npy.hpp"
#include "orbitforge/io/transforms_json.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/inputs/working_size.hpp"

namespace orbitforge {

// Frames (image paths in frame order) with one camera each (valid = false: none)
// at the working size (the frames' own: every frame must share the first one's;
// a longer side: the first frame's aspect). Each valid camera's intrinsics must
// describe its image's size, unless `scale_intrinsics_to_images` (the estimator
// saw the frames at another size, e.g. VGGT's 518 pixels wide), when they are
// rescaled to it.
template <class Scalar>
PipelineInput<Scalar> frames_input(const std::vector<std::string>& paths, std::vector<FrameCamera<Scalar>> cameras,
                                   const std::string& source_range, const WorkingSize& size,
                                   bool scale_intrinsics_to_images = false) {
  namespace fs = std::filesystem;
  ensure(paths.size() == cameras.size(), "frames_input: ", paths.size(), " frames but ", cameras.size(), " cameras");
  size.check("frames_input");
  const bool native = size.is_native();
  int width = size.width, height = size.height;
  PipelineInput<Scalar> in;
  in.images.resize(cameras.size());
  const Intrinsics<Scalar>* first = nullptr;
  for (std::size_t i = 0; i < cameras.size(); ++i) {
    auto& fc = cameras[i];
    fc.name = fs::path(paths[i]).filename().string();
    if (!fc.valid) continue;
    const Image<Scalar> img = to_rgb(read_image<Scalar>(paths[i]));
    auto& k = fc.camera.intrinsics;
    if (scale_intrinsics_to_images) k = k.resized(img.width, img.height);
    ensure(img.width == k.width && img.height == k.height, paths[i], ": image is ", img.width, "x", img.height,
           ", its camera's intrinsics are for ", k.width, "x", k.height);
    if (width == 0) {
      const auto wh = size.for_frames(img.width, img.height);
      width = wh[0];
      height = wh[1];
    }
    ensure(!native || (img.width == width && img.height == height), paths[i], ": image is ", img.width, "x",
           img.height, ", the first is ", width, "x", height, "; give a working size to load frames of several sizes");
    in.images[i] =
        (img.width == width && img.height == height) ? img : resize_image(img, width, height, ResizeFilter::area);
    k = k.resized(width, height);
    if (!first) first = &k;
  }
  ensure(first != nullptr, "frames_input: none of the ", cameras.size(), " frames has a camera");
  // Frames without a camera keep the first camera's intrinsics (never used to render).
  const Intrinsics<Scalar> k0 = *first;
  for (auto& fc : cameras)
    if (!fc.valid) fc.camera.intrinsics = k0;
  in.width = width;
  in.height = height;
  in.cameras = std::move(cameras);
  select_source(in, source_range);
  return in;
}

// transforms.json: with `images_dir`, the frames are that folder's images in name
// order and each takes the camera whose file_path has its file name (frames with
// none are left without a camera); without it, the frames are the file's own
// (file_path relative to its folder, ".png" added when there is no extension).
template <class Scalar>
PipelineInput<Scalar> load_transforms_input(const std::string& transforms, const std::string& images_dir,
                                            const std::string& source_range, const WorkingSize& size) {
  namespace fs = std::filesystem;
  const auto cams = read_transforms_json<Scalar>(transforms);
  ensure(!cams.empty(), transforms, ": no frames");
  std::vector<std::string> paths;
  std::vector<FrameCamera<Scalar>> frames;
  if (images_dir.empty()) {
    for (const auto& c : cams) {
      fs::path p = fs::path(transforms).parent_path() / c.name;
      if (!p.has_extension()) p += ".png";
      paths.push_back(p.string());
      frames.push_back(c);
    }
  } else {
    std::map<std::string, const FrameCamera<Scalar>*> by_file;
    for (const auto& c : cams) {
      const std::string file = fs::path(c.name).filename().string();
      ensure(by_file.emplace(file, &c).second, transforms, ": two frames name the file ", file);
    }
    for (const auto& name : list_image_files(images_dir)) {
      paths.push_back((fs::path(images_dir) / name).string());
      FrameCamera<Scalar> fc;
      auto it = by_file.find(name);
      if (it == by_file.end()) it = by_file.find(fs::path(name).stem().string());  // file_path without extension
      if (it != by_file.end()) {
        fc = *it->second;
        by_file.erase(it);
      } else {
        fc.valid = false;
      }
      frames.push_back(std::move(fc));
    }
    ensure(by_file.empty(), transforms, ": frame ", by_file.empty() ? "" : by_file.begin()->first, " has no image in ",
           images_dir);
  }
  PipelineInput<Scalar> in = frames_input(paths, std::move(frames), source_range, size);
  in.description = "transforms " + transforms + " frames " + (source_range.empty() ? "all" : source_range);
  return in;
}

// VGGT-style arrays: camera i belongs to the i-th image of `images_dir` (name
// order). `npy_width` x `npy_height` is the size the estimator saw (0 x 0: the
// frames' own); intrinsics are rescaled from it to each frame's size.
template <class Scalar>
PipelineInput<Scalar> load_npy_input(const std::string& extrinsics, const std::string& intrinsics,
                                     const std::string& images_dir, int npy_width, int npy_height,
                                     const std::string& source_range, const WorkingSize& size) {
  namespace fs = std::filesystem;
  const std::vector<std::string> names = list_image_files(images_dir);
  ensure(!names.empty(), images_dir, ": no image files");
  std::vector<std::string> paths;
  for (const auto& n : names) paths.push_back((fs::path(images_dir) / n).string());
  if (npy_width <= 0 || npy_height <= 0) {
    const Image<Scalar> img = read_image<Scalar>(paths.front());
    npy_width = img.width;
    npy_height = img.height;
  }
  auto cams = read_npy_cameras<Scalar>(extrinsics, intrinsics, npy_width, npy_height);
  ensure(cams.size() == names.size(), extrinsics, " has ", cams.size(), " cameras but ", images_dir, " has ",
         names.size(), " images (camera i belongs to the i-th image in name order)");
  PipelineInput<Scalar> in = frames_input(paths, std::move(cams), source_range, size, true);
  in.description = "npy " + extrinsics + " frames " + (source_range.empty() ? "all" : source_range);
  return in;
}

}  // namespace orbitforge

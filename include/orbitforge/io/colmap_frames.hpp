#pragma once
// A COLMAP dataset as a video: every image file of its images/ folder, in name
// order, is a frame (frame numbers are 1-based positions in that order), with
// its camera where the model registered it. Frame ranges then mean the same
// frames whichever frames the estimator registered.
#include <filesystem>
#include <map>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/image_folder.hpp"

namespace orbitforge {

// images/ of a dataset folder, or the one two levels above a model folder
// (DATASET/sparse/0); empty when neither exists.
inline std::string colmap_images_dir(const std::string& dataset_or_model_dir) {
  namespace fs = std::filesystem;
  const fs::path own = fs::path(dataset_or_model_dir) / "images";
  if (fs::is_directory(own)) return own.string();
  const fs::path above = fs::path(find_colmap_model_dir(dataset_or_model_dir)).parent_path().parent_path() / "images";
  return fs::is_directory(above) ? above.string() : std::string();
}

// The frames of `model`'s video: the images of `images_dir` with the model's
// cameras attached by name (valid false, intrinsics of the first registered
// camera, where it registered none). Without an images folder, the registered
// frames alone. Refuses a registered image that is missing from the folder.
template <class S>
std::vector<FrameCamera<S>> colmap_video_frames(const ColmapModel& model, const std::string& images_dir) {
  const std::vector<FrameCamera<S>> registered = colmap_frame_cameras<S>(model);
  ensure(!registered.empty(), "the COLMAP model has no images");
  if (images_dir.empty()) return registered;
  std::map<std::string, const FrameCamera<S>*> by_name;
  for (const auto& fc : registered) by_name[fc.name] = &fc;
  std::vector<FrameCamera<S>> frames;
  for (const std::string& name : list_image_files(images_dir)) {
    FrameCamera<S> fc;
    fc.name = name;
    const auto it = by_name.find(name);
    if (it != by_name.end()) {
      fc = *it->second;
      by_name.erase(it);
    } else {
      fc.valid = false;
      fc.camera.intrinsics = registered.front().camera.intrinsics;  // never used to render
    }
    frames.push_back(std::move(fc));
  }
  if (!by_name.empty())
    fail((std::filesystem::path(images_dir) / by_name.begin()->first).string(),
         ": in the COLMAP model but its image is missing");
  return frames;
}

}  // namespace orbitforge

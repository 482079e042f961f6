#pragma once
// The 2D observations of a COLMAP model as bundle-adjustment input
// (orbit_bundle_adjust.hpp), for cameras in the caller's order.
//
// Decisions:
//  - Images are matched to the caller's cameras by name (the caller's list
//    usually comes from colmap_frame_cameras, sorted by name, or a selection
//    of it); images not named are left out, and a name without an image is an
//    error.
//  - Observations are taken from the images' POINTS2D with a POINT3D_ID; an id
//    missing from points3D is skipped (the reader does not cross-check the two
//    files, see colmap.hpp). Points seen by fewer than `min_track` of the
//    named cameras are dropped: a point seen once constrains no pose.
//  - Pixel positions are used as they are: orbitforge's pinhole ignores lens
//    distortion (colmap_intrinsics), so models with distortion give
//    observations that carry it.
#include <Eigen/Core>
#include <cstdint>
#include <map>
#include <string>
#include <unordered_map>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/orbit_bundle_adjust.hpp"
#include "orbitforge/io/colmap.hpp"

namespace orbitforge {

template <class Scalar>
struct ColmapBundleInput {
  std::vector<Eigen::Matrix<Scalar, 3, 1>> points;
  std::vector<std::int64_t> point_ids;  // POINT3D_ID of each point
  std::vector<BundleObservation<Scalar>> observations;
  std::vector<int> observations_per_camera;
};

template <class Scalar>
ColmapBundleInput<Scalar> colmap_bundle_input(const ColmapModel& model, const std::vector<std::string>& camera_names,
                                              int min_track = 2) {
  std::map<std::string, const ColmapImage*> by_name;
  for (const auto& [id, im] : model.images) by_name[im.name] = &im;
  std::unordered_map<std::int64_t, std::size_t> point_index;
  for (std::size_t j = 0; j < model.points.size(); ++j) point_index[model.points[j].id] = j;

  // Observations per COLMAP point, in camera order.
  std::vector<std::vector<BundleObservation<Scalar>>> per_point(model.points.size());
  for (std::size_t i = 0; i < camera_names.size(); ++i) {
    const auto it = by_name.find(camera_names[i]);
    ensure(it != by_name.end(), "colmap_bundle_input: camera ", i, " ('", camera_names[i],
           "') has no image of that name in the model");
    for (const ColmapPoint2D& q : it->second->points2D) {
      if (q.point3D_id < 0) continue;
      const auto pj = point_index.find(q.point3D_id);
      if (pj == point_index.end()) continue;
      per_point[pj->second].push_back({int(i), 0, q.xy.template cast<Scalar>()});
    }
  }
  ColmapBundleInput<Scalar> in;
  in.observations_per_camera.assign(camera_names.size(), 0);
  for (std::size_t j = 0; j < per_point.size(); ++j) {
    if (int(per_point[j].size()) < min_track) continue;
    const int index = int(in.points.size());
    in.points.push_back(model.points[j].xyz.template cast<Scalar>());
    in.point_ids.push_back(model.points[j].id);
    for (auto o : per_point[j]) {
      o.point = index;
      in.observations.push_back(o);
      ++in.observations_per_camera[std::size_t(o.camera)];
    }
  }
  return in;
}

template <class Scalar>
ColmapBundleInput<Scalar> colmap_bundle_input(const ColmapModel& model, const std::vector<FrameCamera<Scalar>>& cameras,
                                              int min_track = 2) {
  std::vector<std::string> names;
  for (const auto& f : cameras) names.push_back(f.name);
  return colmap_bundle_input<Scalar>(model, names, min_track);
}

}  // namespace orbitforge

#pragma once
// transforms.json as nerfstudio and instant-ngp write it: per frame an OpenGL
// camera-to-world "transform_matrix" (x right, y up, z backward) and a
// "file_path"; intrinsics fl_x, fl_y, cx, cy, w, h at the top level and/or per
// frame (per-frame values win).
//
// Reading:
//  - w and h are required (top level or per frame); fl_x falls back to
//    camera_angle_x (fl_x = w / (2 tan(angle_x / 2))), fl_y to camera_angle_y,
//    then to fl_x; cx, cy default to w / 2, h / 2.
//  - transform_matrix has 3 or 4 rows of 4 numbers; its rotation part must be
//    a rotation (orthonormal to 1e-3, det > 0) and a 4th row must be 0 0 0 1.
//  - Distortion (k1.., p1..), instant-ngp's scale/offset/aabb_scale and
//    nerfstudio's applied_transform are ignored.
//  - Frames are returned sorted by file_path (stable), the order in which
//    frames are numbered everywhere in orbitforge.
//  - JSON syntax and type errors become orbitforge::Error naming the file.
// Writing: every valid frame with its own intrinsics, plus the first frame's
// intrinsics at the top level for readers that only look there; frames with
// valid = false are left out. camera_model is "OPENCV" (no distortion terms).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"

namespace orbitforge {

namespace detail {

// A numeric field that may be absent; present but not a number is an error.
inline std::optional<double> json_number(const nlohmann::json& obj, const char* key, const std::string& where) {
  const auto it = obj.find(key);
  if (it == obj.end()) return std::nullopt;
  ensure(it->is_number(), where, ": \"", key, "\" must be a number, got ", it->type_name());
  const double v = it->get<double>();
  ensure(std::isfinite(v), where, ": \"", key, "\" is not finite");
  return v;
}

struct TransformsIntrinsics {
  std::optional<double> fl_x, fl_y, cx, cy, w, h, angle_x, angle_y;

  static TransformsIntrinsics from(const nlohmann::json& obj, const std::string& where) {
    TransformsIntrinsics k;
    k.fl_x = json_number(obj, "fl_x", where);
    k.fl_y = json_number(obj, "fl_y", where);
    k.cx = json_number(obj, "cx", where);
    k.cy = json_number(obj, "cy", where);
    k.w = json_number(obj, "w", where);
    k.h = json_number(obj, "h", where);
    k.angle_x = json_number(obj, "camera_angle_x", where);
    k.angle_y = json_number(obj, "camera_angle_y", where);
    return k;
  }
  // Per-frame values over top-level ones.
  TransformsIntrinsics over(const TransformsIntrinsics& base) const {
    TransformsIntrinsics k;
    k.fl_x = fl_x ? fl_x : base.fl_x;
    k.fl_y = fl_y ? fl_y : base.fl_y;
    k.cx = cx ? cx : base.cx;
    k.cy = cy ? cy : base.cy;
    k.w = w ? w : base.w;
    k.h = h ? h : base.h;
    k.angle_x = angle_x ? angle_x : base.angle_x;
    k.angle_y = angle_y ? angle_y : base.angle_y;
    return k;
  }
};

inline int json_image_size(const std::optional<double>& v, const char* key, const std::string& where) {
  ensure(v.has_value(), where, ": \"", key, "\" (image ", key[0] == 'w' ? "width" : "height",
         ") is missing at the top level and in the frame");
  ensure(*v >= 1 && *v <= 1e9 && std::floor(*v) == *v, where, ": \"", key, "\" = ", *v,
         " is not a positive whole number of pixels");
  return static_cast<int>(*v);
}

inline double focal_from_angle(double angle, int size, const char* key, const std::string& where) {
  ensure(angle > 0 && angle < 3.14159, where, ": \"", key, "\" = ", angle, " is not an angle in (0, pi) radians");
  return 0.5 * size / std::tan(0.5 * angle);
}

template <class S>
Intrinsics<S> resolve_transforms_intrinsics(const TransformsIntrinsics& k, const std::string& where) {
  Intrinsics<double> out;
  out.width = json_image_size(k.w, "w", where);
  out.height = json_image_size(k.h, "h", where);
  if (k.fl_x) {
    out.fx = *k.fl_x;
  } else {
    ensure(k.angle_x.has_value(), where, ": no focal length: neither \"fl_x\" nor \"camera_angle_x\" is given");
    out.fx = focal_from_angle(*k.angle_x, out.width, "camera_angle_x", where);
  }
  if (k.fl_y) {
    out.fy = *k.fl_y;
  } else if (k.angle_y) {
    out.fy = focal_from_angle(*k.angle_y, out.height, "camera_angle_y", where);
  } else {
    out.fy = out.fx;
  }
  ensure(out.fx > 0 && out.fy > 0, where, ": focal lengths must be positive (fl_x ", out.fx, ", fl_y ", out.fy, ")");
  out.cx = k.cx ? *k.cx : 0.5 * out.width;
  out.cy = k.cy ? *k.cy : 0.5 * out.height;
  return out.template cast<S>();
}

inline Eigen::Matrix4d json_transform_matrix(const nlohmann::json& frame, const std::string& where) {
  const auto it = frame.find("transform_matrix");
  ensure(it != frame.end(), where, ": \"transform_matrix\" is missing");
  const nlohmann::json& m = *it;
  ensure(m.is_array() && (m.size() == 3 || m.size() == 4), where,
         ": \"transform_matrix\" must be an array of 3 or 4 rows");
  Eigen::Matrix4d T = Eigen::Matrix4d::Identity();
  for (std::size_t r = 0; r < m.size(); ++r) {
    ensure(m[r].is_array() && m[r].size() == 4, where, ": \"transform_matrix\" row ", r,
           " must be an array of 4 numbers");
    for (std::size_t c = 0; c < 4; ++c) {
      ensure(m[r][c].is_number(), where, ": \"transform_matrix\"[", r, "][", c, "] is not a number");
      T(r, c) = m[r][c].get<double>();
    }
  }
  ensure(T.allFinite(), where, ": \"transform_matrix\" has non-finite values");
  if (m.size() == 4) {
    const double bottom_err = (T.row(3) - Eigen::RowVector4d(0, 0, 0, 1)).cwiseAbs().maxCoeff();
    ensure(bottom_err < 1e-6, where, ": \"transform_matrix\" last row must be 0 0 0 1");
  }
  const Eigen::Matrix3d R = T.topLeftCorner<3, 3>();
  const double orth_err = (R.transpose() * R - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff();
  ensure(orth_err < 1e-3 && R.determinant() > 0, where,
         ": rotation part of \"transform_matrix\" is not a rotation (|R^T R - I| = ", orth_err,
         ", det = ", R.determinant(), ")");
  return T;
}

}  // namespace detail

// Parses transforms.json text; `file_name` is only used in messages.
template <class S>
std::vector<FrameCamera<S>> parse_transforms_json(const std::string& text, const std::string& file_name) {
  using nlohmann::json;
  json root;
  try {
    root = json::parse(text);
  } catch (const json::exception& e) {
    fail(file_name, ": invalid JSON: ", e.what());
  }
  std::vector<FrameCamera<S>> out;
  try {
    ensure(root.is_object(), file_name, ": top level must be a JSON object");
    const auto top = detail::TransformsIntrinsics::from(root, file_name);
    const auto frames = root.find("frames");
    ensure(frames != root.end() && frames->is_array(), file_name, ": \"frames\" array is missing");
    out.reserve(frames->size());
    for (std::size_t i = 0; i < frames->size(); ++i) {
      const json& fr = (*frames)[i];
      std::ostringstream w;
      w << file_name << ": frames[" << i << "]";
      const std::string where = w.str();
      ensure(fr.is_object(), where, ": frame must be a JSON object");
      const auto path = fr.find("file_path");
      ensure(path != fr.end() && path->is_string(), where, ": \"file_path\" string is missing");
      const auto k = detail::TransformsIntrinsics::from(fr, where).over(top);
      FrameCamera<S> f;
      f.name = path->get<std::string>();
      const Intrinsics<S> intr = detail::resolve_transforms_intrinsics<S>(k, where);
      const Camerad cam = Camerad::from_opengl_camera_to_world(detail::json_transform_matrix(fr, where),
                                                               intr.template cast<double>());
      ensure(cam.R.allFinite() && cam.t.allFinite(), where, ": camera pose is not finite (values too large)");
      f.camera = cam.template cast<S>();
      f.camera.intrinsics = intr;
      ensure(f.camera.is_finite(), where, ": camera does not fit the precision (values too large)");
      out.push_back(std::move(f));
    }
  } catch (const json::exception& e) {
    fail(file_name, ": unexpected JSON content: ", e.what());
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const FrameCamera<S>& a, const FrameCamera<S>& b) { return a.name < b.name; });
  return out;
}

template <class S>
std::vector<FrameCamera<S>> read_transforms_json(const std::string& path) {
  return parse_transforms_json<S>(read_file_bytes(path), path);
}

// The JSON text write_transforms_json stores; `file_name` is only used in messages.
template <class S>
std::string transforms_json_text(const std::vector<FrameCamera<S>>& cams, const std::string& file_name) {
  using nlohmann::json;
  auto intrinsics_json = [](json& obj, const Intrinsics<double>& k) {
    obj["w"] = k.width;
    obj["h"] = k.height;
    obj["fl_x"] = k.fx;
    obj["fl_y"] = k.fy;
    obj["cx"] = k.cx;
    obj["cy"] = k.cy;
  };
  json root = json::object();
  root["camera_model"] = "OPENCV";
  json frames = json::array();
  bool have_top = false;
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const FrameCamera<S>& f = cams[i];
    if (!f.valid) continue;
    ensure(f.camera.is_finite(), file_name, ": cannot write frame ", i, " (", f.name, ") has non-finite values");
    const Camerad c = f.camera.template cast<double>();
    const Intrinsics<double>& k = c.intrinsics;
    ensure(k.width > 0 && k.height > 0 && k.fx > 0 && k.fy > 0, file_name, ": cannot write frame ", i, " (", f.name,
           "): needs a positive image size and focal lengths, has ", k.width, "x", k.height, ", fx ", k.fx, ", fy ",
           k.fy);
    if (!have_top) {
      intrinsics_json(root, c.intrinsics);
      have_top = true;
    }
    json fr = json::object();
    fr["file_path"] = f.name;
    intrinsics_json(fr, c.intrinsics);
    const Eigen::Matrix4d T = c.to_opengl_camera_to_world();
    json m = json::array();
    for (int r = 0; r < 4; ++r) m.push_back({T(r, 0), T(r, 1), T(r, 2), T(r, 3)});
    fr["transform_matrix"] = std::move(m);
    frames.push_back(std::move(fr));
  }
  root["frames"] = std::move(frames);
  return root.dump(2) + "\n";
}

template <class S>
void write_transforms_json(const std::string& path, const std::vector<FrameCamera<S>>& cams) {
  write_file_atomic(path, transforms_json_text(cams, path));
}

}  // namespace orbitforge

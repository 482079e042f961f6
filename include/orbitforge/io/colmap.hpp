#pragma once
// COLMAP sparse models (cameras, images, points3D) in the text and the binary
// format, and their conversion to orbitforge cameras.
//
// COLMAP's image pose (qvec = w,x,y,z; tvec) is world-to-camera with OpenCV axes,
// i.e. exactly Camera::R, Camera::t. COLMAP's pixel convention (centre of the
// top-left pixel at (0.5, 0.5)) is orbitforge's, so cx, cy are taken as they are.
//
// Decisions:
//  - read_colmap_model prefers the binary files when cameras.bin and images.bin
//    exist (as COLMAP itself does), otherwise the text files. points3D is
//    optional in both (an empty point list when the file is missing): camera
//    estimators that only export poses are common.
//  - Non-finite pose values (nan/inf in qvec or tvec) are kept in ColmapImage;
//    colmap_frame_cameras turns such an image into a FrameCamera with
//    valid = false (identity pose, never NaN). Finite values too large for
//    the precision S are an error. A finite quaternion of (near) zero norm, an image referencing a missing camera, unknown camera models,
//    wrong parameter counts, non-finite or non-positive intrinsics and
//    duplicate ids are errors naming the file and the line / record.
//  - 2D observations are kept: each image's POINTS2D[] (pixel xy, POINT3D_ID or
//    -1) and each point's POINT2D_IDX per track element. The reader checks each
//    record's form (a POINT3D_ID below -1 or a negative POINT2D_IDX is an error)
//    but not the cross references between images and points: COLMAP's own
//    models are consistent, and a caller that needs both sides (e.g.
//    colmap_observations.hpp) looks ids up and skips what it cannot find.
//  - colmap_intrinsics keeps fx, fy, cx, cy only: lens distortion parameters
//    are ignored (orbitforge renders ideal pinhole cameras).
//
// Parsers from memory (parse_colmap_*) exist so that fuzzing and tests need no
// files; `file_name` is only used in messages.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>
#include <string>
#include <string_view>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/byte_reader.hpp"
#include "orbitforge/io/text_reader.hpp"

namespace orbitforge {

struct ColmapCamera {
  int id = 0;
  std::string model;
  int width = 0, height = 0;
  std::vector<double> params;
};

// One keypoint of an image (POINTS2D[] element): pixel position in COLMAP's
// convention (= orbitforge's) and the 3D point it was triangulated into.
struct ColmapPoint2D {
  Eigen::Vector2d xy = Eigen::Vector2d::Zero();
  std::int64_t point3D_id = -1;  // -1: not part of any 3D point
};

struct ColmapImage {
  int id = 0;
  Eigen::Vector4d qvec = Eigen::Vector4d(1, 0, 0, 0);  // w, x, y, z; world-to-camera rotation
  Eigen::Vector3d tvec = Eigen::Vector3d::Zero();      // world-to-camera translation
  int camera_id = 0;
  std::string name;
  std::vector<ColmapPoint2D> points2D;  // POINTS2D[], in file order (POINT2D_IDX = index)
};

struct ColmapPoint {
  std::int64_t id = 0;
  Eigen::Vector3d xyz = Eigen::Vector3d::Zero();
  std::array<std::uint8_t, 3> rgb{{0, 0, 0}};
  double error = 0;
  std::vector<int> track_images;     // IMAGE_ID of each observation (TRACK[]), in file order
  std::vector<int> track_point2D;    // POINT2D_IDX of each observation, parallel to track_images
};

struct ColmapModel {
  std::map<int, ColmapCamera> cameras;
  std::map<int, ColmapImage> images;
  std::vector<ColmapPoint> points;
};

// COLMAP's camera model table (id, name, parameter count). Models whose first
// parameter is a single focal length f (fx = fy = f, then cx, cy) are marked.
struct ColmapCameraModelInfo {
  int id;
  const char* name;
  int num_params;
  bool single_focal;
};

inline const std::array<ColmapCameraModelInfo, 11>& colmap_camera_models() {
  static const std::array<ColmapCameraModelInfo, 11> table{{
      {0, "SIMPLE_PINHOLE", 3, true},
      {1, "PINHOLE", 4, false},
      {2, "SIMPLE_RADIAL", 4, true},
      {3, "RADIAL", 5, true},
      {4, "OPENCV", 8, false},
      {5, "OPENCV_FISHEYE", 8, false},
      {6, "FULL_OPENCV", 12, false},
      {7, "FOV", 5, false},
      {8, "SIMPLE_RADIAL_FISHEYE", 4, true},
      {9, "RADIAL_FISHEYE", 5, true},
      {10, "THIN_PRISM_FISHEYE", 12, false},
  }};
  return table;
}

inline const ColmapCameraModelInfo* find_colmap_camera_model(std::string_view name) {
  for (const auto& m : colmap_camera_models())
    if (name == m.name) return &m;
  return nullptr;
}

inline const ColmapCameraModelInfo* find_colmap_camera_model(int id) {
  for (const auto& m : colmap_camera_models())
    if (id == m.id) return &m;
  return nullptr;
}

namespace detail {

inline std::string colmap_model_names() {
  std::string s;
  for (const auto& m : colmap_camera_models()) {
    if (!s.empty()) s += ", ";
    s += m.name;
  }
  return s;
}

// Checks shared by the text and binary camera readers; `where` locates the record.
template <class Where>
void check_colmap_camera(const ColmapCamera& c, const ColmapCameraModelInfo& info, const Where& where) {
  ensure(c.width > 0 && c.height > 0, where, ": camera ", c.id, ": image size ", c.width, "x", c.height,
         " must be positive");
  ensure(static_cast<int>(c.params.size()) == info.num_params, where, ": camera ", c.id, ": model ", info.name,
         " needs ", info.num_params, " parameters, got ", c.params.size());
  for (std::size_t i = 0; i < c.params.size(); ++i)
    ensure(std::isfinite(c.params[i]), where, ": camera ", c.id, ": parameter ", i, " is not finite");
  ensure(c.params[0] > 0 && (info.single_focal || c.params[1] > 0), where, ": camera ", c.id,
         ": focal length must be positive");
}

// Norm without overflow or underflow for extreme components.
inline double colmap_quaternion_norm(const Eigen::Vector4d& q) {
  const double s = q.cwiseAbs().maxCoeff();
  return s > 0 ? s * (q / s).norm() : 0.0;
}

template <class Where>
void check_colmap_quaternion(const ColmapImage& im, const Where& where) {
  // Non-finite poses are kept (-> FrameCamera::valid = false); a finite
  // quaternion without a direction is a corrupt record.
  if (im.qvec.allFinite()) {
    ensure(colmap_quaternion_norm(im.qvec) > 1e-12, where, ": image ", im.id, " (", im.name,
           "): quaternion has zero norm");
  }
}

}  // namespace detail

// ---------------------------------------------------------------- text, from memory

inline std::map<int, ColmapCamera> parse_colmap_cameras_text(std::string_view text, const std::string& file_name) {
  std::map<int, ColmapCamera> cameras;
  LineReader lines(text, file_name);
  std::string_view line;
  while (lines.next_data_line(line)) {
    const TextLocation at = lines.location();
    const auto tok = split_tokens(line);
    ensure(tok.size() >= 4, at, ": expected CAMERA_ID MODEL WIDTH HEIGHT PARAMS[], got ", tok.size(), " tokens");
    ColmapCamera c;
    c.id = parse_int_token<int>(tok[0], at, "CAMERA_ID");
    c.model = std::string(tok[1]);
    const ColmapCameraModelInfo* info = find_colmap_camera_model(tok[1]);
    ensure(info != nullptr, at, ": camera ", c.id, ": unknown camera model '", c.model, "' (known: ",
           detail::colmap_model_names(), ")");
    c.width = parse_int_token<int>(tok[2], at, "WIDTH");
    c.height = parse_int_token<int>(tok[3], at, "HEIGHT");
    for (std::size_t i = 4; i < tok.size(); ++i) c.params.push_back(parse_double_token(tok[i], at, "camera parameter"));
    detail::check_colmap_camera(c, *info, at);
    ensure(cameras.count(c.id) == 0, at, ": duplicate CAMERA_ID ", c.id);
    cameras.emplace(c.id, std::move(c));
  }
  return cameras;
}

inline std::map<int, ColmapImage> parse_colmap_images_text(std::string_view text, const std::string& file_name) {
  std::map<int, ColmapImage> images;
  LineReader lines(text, file_name);
  std::string_view line;
  while (lines.next_data_line(line)) {
    const TextLocation at = lines.location();
    const auto tok = split_tokens(line);
    ensure(tok.size() >= 10, at, ": expected IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME, got ", tok.size(),
           " tokens");
    ColmapImage im;
    im.id = parse_int_token<int>(tok[0], at, "IMAGE_ID");
    for (int k = 0; k < 4; ++k) im.qvec[k] = parse_double_token(tok[1 + k], at, "quaternion component");
    for (int k = 0; k < 3; ++k) im.tvec[k] = parse_double_token(tok[5 + k], at, "translation component");
    im.camera_id = parse_int_token<int>(tok[8], at, "CAMERA_ID");
    // The name is the rest of the line, so names with spaces survive.
    const std::size_t name_start = static_cast<std::size_t>(tok[9].data() - line.data());
    im.name = std::string(trim_view(line.substr(name_start)));
    detail::check_colmap_quaternion(im, at);
    ensure(images.count(im.id) == 0, at, ": duplicate IMAGE_ID ", im.id);

    // Second line: POINTS2D[] as (X, Y, POINT3D_ID); may be empty or, at the
    // very end of the file, missing.
    std::string_view points;
    if (lines.next_line(points)) {
      const TextLocation pat = lines.location();
      const auto ptok = split_tokens(points);
      ensure(ptok.size() % 3 == 0, pat, ": POINTS2D line of image ", im.id, " has ", ptok.size(),
             " tokens, expected triples X Y POINT3D_ID");
      im.points2D.reserve(ptok.size() / 3);
      for (std::size_t i = 0; i < ptok.size(); i += 3) {
        ColmapPoint2D q;
        q.xy.x() = parse_double_token(ptok[i], pat, "POINTS2D x");
        q.xy.y() = parse_double_token(ptok[i + 1], pat, "POINTS2D y");
        q.point3D_id = parse_int_token<std::int64_t>(ptok[i + 2], pat, "POINT3D_ID");
        ensure(q.point3D_id >= -1, pat, ": image ", im.id, ": POINTS2D ", i / 3, " has POINT3D_ID ", q.point3D_id,
               " (expected -1 or an id >= 0)");
        im.points2D.push_back(q);
      }
    }
    images.emplace(im.id, std::move(im));
  }
  return images;
}

inline std::vector<ColmapPoint> parse_colmap_points3D_text(std::string_view text, const std::string& file_name) {
  std::vector<ColmapPoint> points;
  LineReader lines(text, file_name);
  std::string_view line;
  while (lines.next_data_line(line)) {
    const TextLocation at = lines.location();
    const auto tok = split_tokens(line);
    ensure(tok.size() >= 8, at, ": expected POINT3D_ID X Y Z R G B ERROR TRACK[], got ", tok.size(), " tokens");
    ensure((tok.size() - 8) % 2 == 0, at, ": TRACK[] has ", tok.size() - 8,
           " tokens, expected pairs IMAGE_ID POINT2D_IDX");
    ColmapPoint p;
    p.id = parse_int_token<std::int64_t>(tok[0], at, "POINT3D_ID");
    for (int k = 0; k < 3; ++k) p.xyz[k] = parse_double_token(tok[1 + k], at, "point coordinate");
    for (int k = 0; k < 3; ++k) {
      const int v = parse_int_token<int>(tok[4 + k], at, "colour component");
      ensure(v >= 0 && v <= 255, at, ": colour component ", v, " outside 0..255");
      p.rgb[k] = static_cast<std::uint8_t>(v);
    }
    p.error = parse_double_token(tok[7], at, "ERROR");
    p.track_images.reserve((tok.size() - 8) / 2);
    p.track_point2D.reserve((tok.size() - 8) / 2);
    for (std::size_t i = 8; i < tok.size(); i += 2) {
      p.track_images.push_back(parse_int_token<int>(tok[i], at, "track IMAGE_ID"));
      const int idx = parse_int_token<int>(tok[i + 1], at, "track POINT2D_IDX");
      ensure(idx >= 0, at, ": point ", p.id, ": track POINT2D_IDX ", idx, " is negative");
      p.track_point2D.push_back(idx);
    }
    points.push_back(std::move(p));
  }
  return points;
}

// ---------------------------------------------------------------- binary, from memory

inline std::map<int, ColmapCamera> parse_colmap_cameras_binary(std::string_view bytes, const std::string& file_name) {
  ByteReader in(bytes, file_name);
  const auto count = in.read<std::uint64_t>("camera count");
  in.check_count(count, 4 + 4 + 8 + 8, "camera");
  std::map<int, ColmapCamera> cameras;
  for (std::uint64_t i = 0; i < count; ++i) {
    std::ostringstream where;
    where << file_name << ": camera record " << i << " (byte offset " << in.offset() << ")";
    ColmapCamera c;
    c.id = in.read<std::int32_t>("camera id");
    const auto model_id = in.read<std::int32_t>("camera model id");
    const ColmapCameraModelInfo* info = find_colmap_camera_model(model_id);
    ensure(info != nullptr, where.str(), ": camera ", c.id, ": unknown camera model id ", model_id);
    c.model = info->name;
    const auto w = in.read<std::uint64_t>("camera width");
    const auto h = in.read<std::uint64_t>("camera height");
    ensure(w <= std::uint64_t(std::numeric_limits<int>::max()) && h <= std::uint64_t(std::numeric_limits<int>::max()),
           where.str(), ": camera ", c.id, ": image size ", w, "x", h, " is too large");
    c.width = static_cast<int>(w);
    c.height = static_cast<int>(h);
    c.params.resize(static_cast<std::size_t>(info->num_params));
    for (auto& v : c.params) v = in.read<double>("camera parameter");
    detail::check_colmap_camera(c, *info, where.str());
    ensure(cameras.count(c.id) == 0, where.str(), ": duplicate camera id ", c.id);
    cameras.emplace(c.id, std::move(c));
  }
  ensure(in.at_end(), file_name, ": ", in.remaining(), " unexpected bytes after the last camera record (byte offset ",
         in.offset(), ")");
  return cameras;
}

inline std::map<int, ColmapImage> parse_colmap_images_binary(std::string_view bytes, const std::string& file_name) {
  ByteReader in(bytes, file_name);
  const auto count = in.read<std::uint64_t>("image count");
  // id, 7 doubles, camera id, at least a NUL, point count
  in.check_count(count, 4 + 7 * 8 + 4 + 1 + 8, "image");
  std::map<int, ColmapImage> images;
  for (std::uint64_t i = 0; i < count; ++i) {
    std::ostringstream where;
    where << file_name << ": image record " << i << " (byte offset " << in.offset() << ")";
    ColmapImage im;
    im.id = in.read<std::int32_t>("image id");
    for (int k = 0; k < 4; ++k) im.qvec[k] = in.read<double>("quaternion");
    for (int k = 0; k < 3; ++k) im.tvec[k] = in.read<double>("translation");
    im.camera_id = in.read<std::int32_t>("image camera id");
    im.name = in.read_cstring("image name");
    ensure(!im.name.empty(), where.str(), ": image ", im.id, " has an empty name");
    const auto num_points = in.read<std::uint64_t>("POINTS2D count");
    in.check_count(num_points, 8 + 8 + 8, "POINTS2D");
    im.points2D.resize(static_cast<std::size_t>(num_points));
    for (std::size_t k = 0; k < im.points2D.size(); ++k) {
      ColmapPoint2D& q = im.points2D[k];
      q.xy.x() = in.read<double>("POINTS2D x");
      q.xy.y() = in.read<double>("POINTS2D y");
      // COLMAP writes "no 3D point" as the uint64 maximum, i.e. -1 as int64.
      q.point3D_id = in.read<std::int64_t>("POINT3D_ID");
      ensure(q.point3D_id >= -1, where.str(), ": image ", im.id, ": POINTS2D ", k, " has POINT3D_ID ", q.point3D_id,
             " (expected -1 or an id >= 0)");
    }
    detail::check_colmap_quaternion(im, where.str());
    ensure(images.count(im.id) == 0, where.str(), ": duplicate image id ", im.id);
    images.emplace(im.id, std::move(im));
  }
  ensure(in.at_end(), file_name, ": ", in.remaining(), " unexpected bytes after the last image record (byte offset ",
         in.offset(), ")");
  return images;
}

inline std::vector<ColmapPoint> parse_colmap_points3D_binary(std::string_view bytes, const std::string& file_name) {
  ByteReader in(bytes, file_name);
  const auto count = in.read<std::uint64_t>("point count");
  in.check_count(count, 8 + 3 * 8 + 3 + 8 + 8, "point");
  std::vector<ColmapPoint> points;
  points.reserve(static_cast<std::size_t>(count));
  for (std::uint64_t i = 0; i < count; ++i) {
    const std::size_t record_offset = in.offset();
    ColmapPoint p;
    const auto id = in.read<std::uint64_t>("point id");
    ensure(id <= std::uint64_t(std::numeric_limits<std::int64_t>::max()), file_name, ": point record ", i,
           " (byte offset ", record_offset, "): point id ", id, " is too large");
    p.id = static_cast<std::int64_t>(id);
    for (int k = 0; k < 3; ++k) p.xyz[k] = in.read<double>("point coordinate");
    for (int k = 0; k < 3; ++k) p.rgb[k] = in.read<std::uint8_t>("point colour");
    p.error = in.read<double>("point error");
    const auto track = in.read<std::uint64_t>("track length");
    in.check_count(track, 4 + 4, "track element");
    p.track_images.reserve(static_cast<std::size_t>(track));
    p.track_point2D.reserve(static_cast<std::size_t>(track));
    for (std::uint64_t k = 0; k < track; ++k) {
      const auto image_id = in.read<std::uint32_t>("track image id");
      const auto point2D_idx = in.read<std::uint32_t>("track point2D index");
      ensure(image_id <= std::uint32_t(std::numeric_limits<int>::max()), file_name, ": point record ", i,
             " (byte offset ", record_offset, "): track image id ", image_id, " is too large");
      ensure(point2D_idx <= std::uint32_t(std::numeric_limits<int>::max()), file_name, ": point record ", i,
             " (byte offset ", record_offset, "): track point2D index ", point2D_idx, " is too large");
      p.track_images.push_back(int(image_id));
      p.track_point2D.push_back(int(point2D_idx));
    }
    points.push_back(std::move(p));
  }
  ensure(in.at_end(), file_name, ": ", in.remaining(), " unexpected bytes after the last point record (byte offset ",
         in.offset(), ")");
  return points;
}

// Every image must reference an existing camera.
inline void check_colmap_model(const ColmapModel& model, const std::string& images_file) {
  for (const auto& [id, im] : model.images) {
    ensure(model.cameras.count(im.camera_id) != 0, images_file, ": image ", id, " (", im.name,
           ") references camera ", im.camera_id, ", which is not in the camera list");
  }
}

// ---------------------------------------------------------------- files

namespace detail {
inline bool colmap_file_exists(const std::filesystem::path& p) {
  std::error_code ec;
  return std::filesystem::is_regular_file(p, ec);
}
inline bool is_colmap_model_dir(const std::filesystem::path& dir) {
  return (colmap_file_exists(dir / "cameras.bin") && colmap_file_exists(dir / "images.bin")) ||
         (colmap_file_exists(dir / "cameras.txt") && colmap_file_exists(dir / "images.txt"));
}
}  // namespace detail

// A model folder is one holding cameras + images (.txt or .bin). Tries the
// folder itself, then DIR/sparse/0, then DIR/sparse.
inline std::string find_colmap_model_dir(const std::string& dataset_or_model_dir) {
  namespace fs = std::filesystem;
  const fs::path base(dataset_or_model_dir);
  const fs::path candidates[] = {base, base / "sparse" / "0", base / "sparse"};
  for (const auto& c : candidates)
    if (detail::is_colmap_model_dir(c)) return c.string();
  fail("no COLMAP model found: looked for cameras.{bin,txt} and images.{bin,txt} in ", candidates[0].string(), ", ",
       candidates[1].string(), " and ", candidates[2].string());
}

inline ColmapModel read_colmap_text(const std::string& model_dir) {
  namespace fs = std::filesystem;
  const fs::path dir(model_dir);
  ColmapModel m;
  const std::string cameras_file = (dir / "cameras.txt").string();
  const std::string images_file = (dir / "images.txt").string();
  const std::string points_file = (dir / "points3D.txt").string();
  m.cameras = parse_colmap_cameras_text(read_file_bytes(cameras_file), cameras_file);
  m.images = parse_colmap_images_text(read_file_bytes(images_file), images_file);
  if (detail::colmap_file_exists(points_file))
    m.points = parse_colmap_points3D_text(read_file_bytes(points_file), points_file);
  check_colmap_model(m, images_file);
  return m;
}

inline ColmapModel read_colmap_binary(const std::string& model_dir) {
  namespace fs = std::filesystem;
  const fs::path dir(model_dir);
  ColmapModel m;
  const std::string cameras_file = (dir / "cameras.bin").string();
  const std::string images_file = (dir / "images.bin").string();
  const std::string points_file = (dir / "points3D.bin").string();
  m.cameras = parse_colmap_cameras_binary(read_file_bytes(cameras_file), cameras_file);
  m.images = parse_colmap_images_binary(read_file_bytes(images_file), images_file);
  if (detail::colmap_file_exists(points_file))
    m.points = parse_colmap_points3D_binary(read_file_bytes(points_file), points_file);
  check_colmap_model(m, images_file);
  return m;
}

// Accepts a model folder or a dataset folder (see find_colmap_model_dir);
// binary preferred when both formats are present.
inline ColmapModel read_colmap_model(const std::string& model_dir) {
  namespace fs = std::filesystem;
  const fs::path dir(find_colmap_model_dir(model_dir));
  if (detail::colmap_file_exists(dir / "cameras.bin") && detail::colmap_file_exists(dir / "images.bin"))
    return read_colmap_binary(dir.string());
  return read_colmap_text(dir.string());
}

// ---------------------------------------------------------------- conversion

// fx, fy, cx, cy of any COLMAP model; distortion parameters are ignored.
template <class S>
Intrinsics<S> colmap_intrinsics(const ColmapCamera& c) {
  const ColmapCameraModelInfo* info = find_colmap_camera_model(c.model);
  ensure(info != nullptr, "COLMAP camera ", c.id, ": unknown camera model '", c.model, "'");
  ensure(static_cast<int>(c.params.size()) == info->num_params, "COLMAP camera ", c.id, ": model ", c.model,
         " needs ", info->num_params, " parameters, got ", c.params.size());
  Intrinsics<S> k;
  const auto& p = c.params;
  if (info->single_focal) {
    k.fx = k.fy = S(p[0]);
    k.cx = S(p[1]);
    k.cy = S(p[2]);
  } else {
    k.fx = S(p[0]);
    k.fy = S(p[1]);
    k.cx = S(p[2]);
    k.cy = S(p[3]);
  }
  k.width = c.width;
  k.height = c.height;
  return k;
}

// One FrameCamera per image, sorted by image name (std::string order). An image
// with a non-finite pose becomes valid = false with an identity pose.
template <class S>
std::vector<FrameCamera<S>> colmap_frame_cameras(const ColmapModel& model) {
  std::vector<FrameCamera<S>> out;
  out.reserve(model.images.size());
  for (const auto& [id, im] : model.images) {
    const auto cam = model.cameras.find(im.camera_id);
    ensure(cam != model.cameras.end(), "COLMAP image ", id, " (", im.name, ") references camera ", im.camera_id,
           ", which is not in the camera list");
    FrameCamera<S> f;
    f.name = im.name;
    f.camera.intrinsics = colmap_intrinsics<S>(cam->second);
    f.valid = im.qvec.allFinite() && im.tvec.allFinite();
    if (f.valid) {
      ensure(detail::colmap_quaternion_norm(im.qvec) > 1e-12, "COLMAP image ", id, " (", im.name,
             "): quaternion has zero norm");
      const Eigen::Vector4d qs = im.qvec / im.qvec.cwiseAbs().maxCoeff();  // no overflow in the norm
      const Eigen::Quaterniond q(qs[0], qs[1], qs[2], qs[3]);
      f.camera.R = q.normalized().toRotationMatrix().template cast<S>();
      f.camera.t = im.tvec.template cast<S>();
    }
    ensure(f.camera.is_finite(), "COLMAP image ", id, " (", im.name,
           "): camera values do not fit the precision (too large)");
    out.push_back(std::move(f));
  }
  std::stable_sort(out.begin(), out.end(),
                   [](const FrameCamera<S>& a, const FrameCamera<S>& b) { return a.name < b.name; });
  return out;
}

namespace detail {
// A text model holds a name as the rest of its line, trimmed.
inline bool colmap_name_storable(const std::string& name) {
  return !name.empty() && name.find_first_of("\n\r") == std::string::npos && trim_view(name).size() == name.size();
}
}  // namespace detail

// Sets an image's pose from a world-to-camera rotation and translation
// (x_cam = R x_world + t), the quaternion with w >= 0 as COLMAP writes it.
inline void set_colmap_pose(ColmapImage& im, const Eigen::Matrix3d& R, const Eigen::Vector3d& t) {
  Eigen::Quaterniond q(R);
  q.normalize();
  if (q.w() < 0) q.coeffs() *= -1.0;
  im.qvec = Eigen::Vector4d(q.w(), q.x(), q.y(), q.z());
  im.tvec = t;
}

// Writes `model` as a text model (cameras.txt, images.txt with each image's
// POINTS2D, points3D.txt with each track), 17 significant digits, so that
// read_colmap_text gives the model back. Creates the folder; each file is
// written atomically. Names that a text model cannot hold (empty, a line break,
// leading or trailing white space) and non-finite poses are errors.
inline void write_colmap_model_text(const std::string& model_dir, const ColmapModel& model) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(model_dir, ec);
  ensure(!ec, model_dir, ": cannot create folder: ", ec.message());
  const fs::path dir(model_dir);

  std::ostringstream cameras, images, points;
  for (auto* o : {&cameras, &images, &points}) *o << std::setprecision(17);
  cameras << "# Camera list with one line of data per camera:\n"
          << "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]\n";
  for (const auto& [id, c] : model.cameras) {
    cameras << id << ' ' << c.model << ' ' << c.width << ' ' << c.height;
    for (double v : c.params) cameras << ' ' << v;
    cameras << '\n';
  }
  images << "# Image list with two lines of data per image:\n"
         << "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME\n"
         << "#   POINTS2D[] as (X, Y, POINT3D_ID)\n";
  const std::string images_file = (dir / "images.txt").string();
  for (const auto& [id, im] : model.images) {
    ensure(detail::colmap_name_storable(im.name), images_file, ": image ", id, " name '", im.name,
           "' cannot be stored (empty, a line break, or leading/trailing white space)");
    ensure(im.qvec.allFinite() && im.tvec.allFinite(), images_file, ": image ", id, " (", im.name,
           ") has a non-finite pose");
    images << id;
    for (int k = 0; k < 4; ++k) images << ' ' << im.qvec[k];
    for (int k = 0; k < 3; ++k) images << ' ' << im.tvec[k];
    images << ' ' << im.camera_id << ' ' << im.name << '\n';
    for (std::size_t i = 0; i < im.points2D.size(); ++i)
      images << (i ? " " : "") << im.points2D[i].xy.x() << ' ' << im.points2D[i].xy.y() << ' '
             << im.points2D[i].point3D_id;
    images << '\n';
  }
  points << "# 3D point list with one line of data per point:\n"
         << "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)\n";
  for (const ColmapPoint& p : model.points) {
    ensure(p.track_images.size() == p.track_point2D.size(), (dir / "points3D.txt").string(), ": point ", p.id, " has ",
           p.track_images.size(), " track images but ", p.track_point2D.size(), " POINT2D_IDX");
    points << p.id << ' ' << p.xyz.x() << ' ' << p.xyz.y() << ' ' << p.xyz.z() << ' ' << int(p.rgb[0]) << ' '
           << int(p.rgb[1]) << ' ' << int(p.rgb[2]) << ' ' << p.error;
    for (std::size_t k = 0; k < p.track_images.size(); ++k) points << ' ' << p.track_images[k] << ' ' << p.track_point2D[k];
    points << '\n';
  }
  write_file_atomic((dir / "cameras.txt").string(), cameras.str());
  write_file_atomic(images_file, images.str());
  write_file_atomic((dir / "points3D.txt").string(), points.str());
}

// Writes cameras as a text model: one PINHOLE camera per frame (id = index + 1),
// images with empty POINTS2D and no points. Frames with valid = false are not
// written (COLMAP has no unregistered images).
template <class S>
void write_colmap_text(const std::string& model_dir, const std::vector<FrameCamera<S>>& cams) {
  const std::string images_file = (std::filesystem::path(model_dir) / "images.txt").string();
  ColmapModel model;
  int id = 0;
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const FrameCamera<S>& f = cams[i];
    if (!f.valid) continue;
    ensure(f.camera.is_finite(), images_file, ": frame ", i, " (", f.name, ") has non-finite camera values");
    ensure(detail::colmap_name_storable(f.name), images_file, ": frame ", i, " name '", f.name,
           "' cannot be stored (empty, a line break, or leading/trailing white space)");
    const Intrinsics<double> k = f.camera.intrinsics.template cast<double>();
    ensure(k.width > 0 && k.height > 0 && k.fx > 0 && k.fy > 0,
           (std::filesystem::path(model_dir) / "cameras.txt").string(), ": frame ", i, " (", f.name,
           ") needs a positive image size and focal lengths, has ", k.width, "x", k.height, ", fx ", k.fx, ", fy ",
           k.fy);
    ++id;
    model.cameras[id] = ColmapCamera{id, "PINHOLE", k.width, k.height, {k.fx, k.fy, k.cx, k.cy}};
    ColmapImage im;
    im.id = id;
    im.camera_id = id;
    im.name = f.name;
    set_colmap_pose(im, f.camera.R.template cast<double>(), f.camera.t.template cast<double>());
    model.images[id] = std::move(im);
  }
  write_colmap_model_text(model_dir, model);
}

}  // namespace orbitforge

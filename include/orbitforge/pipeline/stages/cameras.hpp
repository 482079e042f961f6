#pragma once
// Stage 0, cameras: a video file or a folder of frames becomes a COLMAP dataset
// the pipeline loads like --colmap (load_colmap_input):
//
//   cameras/images/NNNNN.png      every frame (ffmpeg's decode of the video, or a
//                                 copy of the folder's images, names kept)
//   cameras/colmap/images/        the SOURCE frames only (hard links): the
//                                 folder COLMAP sees
//   cameras/colmap/database.db    features and matches
//   cameras/colmap/sparse/N/      every model the mapper wrote
//   cameras/sparse/0/             the model with the most registered images
//   cameras/logs/*.log            each tool's command line and output
//
// Evidence: frames outside the source range (--frames) never reach COLMAP, as a
// camera estimator run on the generated source video alone could not have seen
// them; they have no cameras, so the oracle completion provider cannot use them.
//
// Resuming: stages/cameras.json records the key (the input's bytes and the
// settings) and the size and hash of every output above except the logs and
// the mapper's raw models; when it verifies, nothing is extracted or estimated.
// Otherwise the stage's folders are cleared and it runs again, saying why.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/hash.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/frames.hpp"
#include "orbitforge/io/image_folder.hpp"
#include "orbitforge/pipeline/external_tools.hpp"
#include "orbitforge/pipeline/stage_record.hpp"

namespace orbitforge {

struct CameraStageParams {
  std::string video;            // a video file (decoded with ffmpeg), or
  std::string images;           // a folder of frames, in name order
  std::string frames = "1-33";  // the source range: the only frames COLMAP sees
  double fps = 0;               // video only: resample to this frame rate (0 = every decoded frame)
  std::string camera_model = "SIMPLE_PINHOLE";  // one camera for all frames: SIMPLE_PINHOLE or PINHOLE
  int sequential_overlap = 10;                  // sequential_matcher: neighbours matched per frame
  // A generated orbit turns a few degrees per frame, so the default 16 degrees
  // for the initial pair rejects every nearby pair; v3d's cameras were made with 4.
  double init_min_tri_angle_deg = 4;
  int threads = 0;  // COLMAP's threads (0 = all)
  std::function<void(const std::string&)> log;  // progress lines (stderr when empty)
};

struct CameraStageResult {
  std::string dataset;   // OUT/cameras: images/ + sparse/0, for load_colmap_input
  std::string key;
  bool skipped = false;  // the record verified: nothing ran
  int frames = 0;        // frames in cameras/images
  std::vector<std::string> source_names, registered_names;  // given to COLMAP / in the chosen model
  double seconds = 0;    // this run's wall time (the recorded one when skipped)
};

// Programs a camera stage with these inputs needs: {program, Debian package}.
inline std::vector<std::pair<std::string, std::string>> camera_stage_programs(const CameraStageParams& p) {
  std::vector<std::pair<std::string, std::string>> v;
  if (!p.video.empty()) v.push_back({"ffmpeg", "ffmpeg"});
  v.push_back({"colmap", "colmap"});
  return v;
}

namespace cameras_detail {
namespace fs = std::filesystem;

inline std::string frame_name(int i) { return numbered_png(i, 5); }

inline std::uint64_t hash_file(const std::string& path, std::uint64_t h) {
  std::ifstream in(path, std::ios::binary);
  ensure(in.is_open(), path, ": cannot open for reading");
  std::vector<char> buf(1 << 20);
  while (in) {
    in.read(buf.data(), std::streamsize(buf.size()));
    h = fnv1a(buf.data(), std::size_t(in.gcount()), h);
  }
  ensure(!in.bad(), path, ": read error");
  return h;
}

// COLMAP runs headless: its Qt parts need the offscreen platform without a display.
inline std::vector<std::pair<std::string, std::string>> colmap_env() { return {{"QT_QPA_PLATFORM", "offscreen"}}; }

inline std::string number_text(double x) {
  std::ostringstream os;
  os.precision(10);
  os << x;
  return os.str();
}

}  // namespace cameras_detail

// ffmpeg: every frame of `video` (or `fps` frames per second) as dir/00001.png, ...
// Paths are made absolute (a relative name with ':' would read as a protocol)
// and '%' in the folder is doubled (the image2 muxer's pattern syntax).
inline ToolCommand ffmpeg_extract_command(const std::string& video, const std::string& dir, double fps = 0) {
  namespace fs = std::filesystem;
  std::string pattern;
  for (char c : fs::absolute(dir).string()) pattern += c == '%' ? std::string("%%") : std::string(1, c);
  pattern += "/%05d.png";
  ToolCommand c{"ffmpeg", {"ffmpeg", "-nostdin", "-hide_banner", "-y", "-i", fs::absolute(video).string()}, {}};
  if (fps > 0) {
    c.argv.push_back("-vf");
    c.argv.push_back("fps=" + cameras_detail::number_text(fps));
  }
  // -vsync 0: one PNG per decoded frame, none duplicated or dropped to fit a rate.
  for (const char* a : {"-vsync", "0", "-start_number", "1"}) c.argv.push_back(a);
  c.argv.push_back(pattern);
  return c;
}

inline ToolCommand colmap_feature_extractor_command(const std::string& database, const std::string& image_dir,
                                                    const CameraStageParams& p) {
  ToolCommand c{"colmap feature_extractor",
                {"colmap", "feature_extractor", "--database_path", database, "--image_path", image_dir,
                 "--ImageReader.single_camera", "1", "--ImageReader.camera_model", p.camera_model,
                 "--SiftExtraction.use_gpu", "0", "--log_to_stderr", "1"},
                cameras_detail::colmap_env()};
  if (p.threads > 0) {
    c.argv.push_back("--SiftExtraction.num_threads");
    c.argv.push_back(std::to_string(p.threads));
  }
  return c;
}

inline ToolCommand colmap_sequential_matcher_command(const std::string& database, const CameraStageParams& p) {
  ToolCommand c{"colmap sequential_matcher",
                {"colmap", "sequential_matcher", "--database_path", database, "--SiftMatching.use_gpu", "0",
                 "--SequentialMatching.overlap", std::to_string(p.sequential_overlap), "--log_to_stderr", "1"},
                cameras_detail::colmap_env()};
  if (p.threads > 0) {
    c.argv.push_back("--SiftMatching.num_threads");
    c.argv.push_back(std::to_string(p.threads));
  }
  return c;
}

inline ToolCommand colmap_mapper_command(const std::string& database, const std::string& image_dir,
                                         const std::string& output_dir, const CameraStageParams& p) {
  ToolCommand c{"colmap mapper",
                {"colmap", "mapper", "--database_path", database, "--image_path", image_dir, "--output_path",
                 output_dir, "--Mapper.init_min_tri_angle", cameras_detail::number_text(p.init_min_tri_angle_deg),
                 "--log_to_stderr", "1"},
                cameras_detail::colmap_env()};
  if (p.threads > 0) {
    c.argv.push_back("--Mapper.num_threads");
    c.argv.push_back(std::to_string(p.threads));
  }
  return c;
}

// Hard-links (or copies, across file systems) the frames of `range` (1-based
// positions in `names`) from `from` into the fresh folder `to`; returns their names.
inline std::vector<std::string> link_source_frames(const std::string& from, const std::vector<std::string>& names,
                                                   const std::string& range, const std::string& to) {
  namespace fs = std::filesystem;
  const FrameRange r = parse_frame_range(range);
  const int n = int(names.size());
  const int last = r.last < 0 ? n : r.last;
  ensure(r.first <= n && last <= n, "--frames ", range, ": the input has only ", n, " frames");
  fs::create_directories(to);
  std::vector<std::string> linked;
  for (int i = r.first; i <= last; ++i) {
    const std::string& name = names[std::size_t(i - 1)];
    const fs::path src = fs::path(from) / name, dst = fs::path(to) / name;
    std::error_code ec;
    fs::create_hard_link(src, dst, ec);
    if (ec) fs::copy_file(src, dst, fs::copy_options::overwrite_existing);
    linked.push_back(name);
  }
  return linked;
}

// The numbered model folder under `sparse_dir` with the most registered images
// ("" when there is none); `registered` gets its count. Ties go to the lower number.
inline std::string largest_colmap_model(const std::string& sparse_dir, std::size_t* registered = nullptr) {
  namespace fs = std::filesystem;
  std::string best;
  std::size_t best_n = 0;
  long best_index = -1;
  std::error_code ec;
  if (!fs::is_directory(sparse_dir, ec)) return best;
  for (const auto& e : fs::directory_iterator(sparse_dir, ec)) {
    const std::string name = e.path().filename().string();
    if (!e.is_directory() || name.empty() || name.find_first_not_of("0123456789") != std::string::npos) continue;
    const std::size_t n = read_colmap_model(e.path().string()).images.size();
    const long index = std::stol(name);
    if (best.empty() || n > best_n || (n == best_n && index < best_index)) {
      best = e.path().string();
      best_n = n;
      best_index = index;
    }
  }
  if (registered) *registered = best_n;
  return best;
}

// Runs (or verifies and skips) the cameras stage into out/cameras; see the top of the file.
inline CameraStageResult stage_cameras(const std::string& out, const CameraStageParams& p) {
  namespace fs = std::filesystem;
  using namespace cameras_detail;
  const auto t0 = std::chrono::steady_clock::now();
  auto log = [&](const std::string& s) {
    if (p.log) p.log(s);
    else std::fprintf(stderr, "%s\n", s.c_str());
  };
  ensure(p.video.empty() != p.images.empty(), "cameras stage: give a video file or an image folder (one of them)");
  ensure(p.camera_model == "SIMPLE_PINHOLE" || p.camera_model == "PINHOLE",
         "cameras stage: camera model must be SIMPLE_PINHOLE or PINHOLE (orbitforge renders ideal pinhole cameras), got ",
         p.camera_model);
  ensure(p.fps >= 0, "cameras stage: fps must be positive or 0, got ", p.fps);
  ensure(p.images.empty() || p.fps == 0, "cameras stage: fps applies to a video, not to an image folder");
  parse_frame_range(p.frames);
  const fs::path stage_dir = fs::path(out) / "cameras";
  const fs::path images_dir = stage_dir / "images", colmap_dir = stage_dir / "colmap", logs = stage_dir / "logs";
  const fs::path colmap_images = colmap_dir / "images", database = colmap_dir / "database.db";
  const fs::path raw_models = colmap_dir / "sparse", model_dir = stage_dir / "sparse" / "0";

  // The key: the input's bytes and the settings that shape the result.
  nlohmann::json settings = {{"frames", p.frames},
                             {"camera_model", p.camera_model},
                             {"sequential_overlap", p.sequential_overlap},
                             {"init_min_tri_angle_deg", p.init_min_tri_angle_deg}};
  std::uint64_t h = kFnv1aSeed;
  std::vector<std::string> input_names;
  if (!p.video.empty()) {
    std::error_code ec;
    ensure(fs::exists(p.video, ec), p.video, ": no such video file");
    ensure(fs::is_regular_file(p.video, ec), p.video, ": not a file (a video file is expected)");
    settings["input"] = "video";
    settings["fps"] = p.fps;
    settings["input_bytes"] = fs::file_size(p.video);
    h = hash_file(p.video, h);
  } else {
    input_names = list_image_files(p.images);
    ensure(!input_names.empty(), p.images, ": no image files (png, jpg, ...) in the folder");
    // The copies would replace their own originals.
    std::error_code ec;
    const fs::path in_canon = fs::weakly_canonical(p.images, ec), stage_canon = fs::weakly_canonical(stage_dir, ec);
    const auto rel = in_canon.lexically_relative(stage_canon);
    ensure(rel.empty() || *rel.begin() == "..", p.images, ": the image folder lies inside the stage's own folder ",
           stage_dir.string());
    settings["input"] = "images";
    std::uint64_t bytes = 0;
    for (const auto& n : input_names) {
      h = fnv1a(n + '\n', h);
      h = hash_file((fs::path(p.images) / n).string(), h);
      bytes += fs::file_size(fs::path(p.images) / n);
    }
    settings["input_bytes"] = bytes;
    settings["input_frames"] = input_names.size();
  }
  CameraStageResult r;
  r.dataset = stage_dir.string();
  r.key = hex64(fnv1a(settings.dump(), h));

  const StageCheck check = check_stage(out, "cameras", r.key, {});
  if (check.current) {
    r.skipped = true;
    r.seconds = recorded_seconds(out, "cameras");
    r.frames = int(list_image_files(images_dir.string()).size());
    r.source_names = list_image_files(colmap_images.string());
    for (const auto& [id, im] : read_colmap_model(model_dir.string()).images) r.registered_names.push_back(im.name);
    std::sort(r.registered_names.begin(), r.registered_names.end());
    return r;
  }
  if (check.why != "no record") log("   cameras: running again: " + check.why);
  for (const auto& [program, package] : camera_stage_programs(p))
    require_program("cameras stage", p.video.empty() ? "an image folder input" : "a video input", program, package);

  // A fresh start: stale frames (a longer earlier video) would shift the numbering,
  // and feature_extractor keeps what an old database holds.
  {
    std::error_code ec;
    fs::remove(fs::path(out) / "stages" / "cameras.json", ec);
    for (const fs::path& d : {images_dir, colmap_dir, stage_dir / "sparse", logs}) fs::remove_all(d, ec);
  }
  fs::create_directories(images_dir);
  fs::create_directories(logs);

  // 1. Frames.
  std::vector<std::string> names;
  if (!p.video.empty()) {
    const ToolRun t = run_tool(ffmpeg_extract_command(p.video, images_dir.string(), p.fps), (logs / "ffmpeg.log").string());
    names = list_image_files(images_dir.string());
    ensure(!names.empty(), "ffmpeg decoded no frames from ", p.video, "; its log: ", (logs / "ffmpeg.log").string());
    ensure(names.size() < 100000, p.video, ": ", names.size(), " frames, more than the 99999 that 5-digit names hold");
    char b[160];
    std::snprintf(b, sizeof(b), "   cameras: ffmpeg: %zu frames in %.1f s", names.size(), t.seconds);
    log(b);
  } else {
    for (const auto& n : input_names) fs::copy_file(fs::path(p.images) / n, images_dir / n);
    names = input_names;
    log("   cameras: " + std::to_string(names.size()) + " frames copied from " + p.images);
  }

  // 2. Cameras of the source frames only.
  r.frames = int(names.size());
  r.source_names = link_source_frames(images_dir.string(), names, p.frames, colmap_images.string());
  log("   cameras: COLMAP on the " + std::to_string(r.source_names.size()) + " source frames (" + p.frames + ") of " +
      std::to_string(names.size()));
  fs::create_directories(raw_models);
  const std::vector<std::pair<ToolCommand, std::string>> steps = {
      {colmap_feature_extractor_command(database.string(), colmap_images.string(), p), "feature_extractor.log"},
      {colmap_sequential_matcher_command(database.string(), p), "sequential_matcher.log"},
      {colmap_mapper_command(database.string(), colmap_images.string(), raw_models.string(), p), "mapper.log"}};
  for (const auto& [cmd, log_name] : steps) {
    const ToolRun t = run_tool(cmd, (logs / log_name).string());
    char b[160];
    std::snprintf(b, sizeof(b), "   cameras: %s: %.1f s", cmd.tool.c_str(), t.seconds);
    log(b);
  }
  std::size_t registered = 0;
  const std::string best = largest_colmap_model(raw_models.string(), &registered);
  ensure(!best.empty() && registered > 0, "colmap mapper registered none of the ", r.source_names.size(),
         " source frames (no model written); its log: ", (logs / "mapper.log").string());
  fs::create_directories(model_dir);
  std::vector<std::string> outputs;
  for (const char* f : {"cameras.bin", "images.bin", "points3D.bin"}) {
    ensure(fs::exists(fs::path(best) / f), "colmap mapper: model ", best, " has no ", f);
    fs::copy_file(fs::path(best) / f, model_dir / f, fs::copy_options::overwrite_existing);
  }
  for (const auto& [id, im] : read_colmap_model(model_dir.string()).images) r.registered_names.push_back(im.name);
  std::sort(r.registered_names.begin(), r.registered_names.end());
  std::size_t models = 0;
  for (const auto& e : fs::directory_iterator(raw_models)) models += e.is_directory() ? 1 : 0;
  log("   cameras: COLMAP registered " + std::to_string(r.registered_names.size()) + " of " +
      std::to_string(r.source_names.size()) + " source frames (model " + fs::path(best).filename().string() + " of " +
      std::to_string(models) + " the mapper wrote)");

  // The record: every frame, what COLMAP saw, its database and the chosen model.
  const std::string base = "cameras/";
  for (const auto& n : names) outputs.push_back(base + "images/" + n);
  for (const auto& n : r.source_names) outputs.push_back(base + "colmap/images/" + n);
  outputs.push_back(base + "colmap/database.db");
  for (const char* f : {"cameras.bin", "images.bin", "points3D.bin"}) outputs.push_back(base + "sparse/0/" + f);
  settings["frames_total"] = names.size();
  settings["source_frames"] = r.source_names.size();
  settings["registered"] = r.registered_names.size();
  settings["mapper_models"] = models;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  record_stage(out, "cameras", r.key, r.seconds, settings, outputs);
  return r;
}

}  // namespace orbitforge

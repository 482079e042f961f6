#pragma once
// Stage 0, cameras: a video file or a folder of frames becomes a COLMAP dataset
// the pipeline loads like --colmap (load_colmap_input):
//
//   cameras/images/NNNNN.png      every frame (ffmpeg's decode of the video, or a
//                                 copy of the folder's images, names kept)
//   cameras/colmap/images/        the SOURCE frames only (hard links): the
//                                 folder COLMAP sees
//   cameras/colmap/database.db    features and matches
//   cameras/colmap/matches.txt    the matches as computed here (exact,
//                                 pipeline/inputs/descriptor_matching.hpp), before
//                                 COLMAP's geometric verification
//   cameras/colmap/sparse/N/      every model the mapper wrote with its focal free
//   cameras/colmap/fixed/focal_F/ the mapper's model with the focal held at F
//                                 (--focal / --fov, or each candidate of the search)
//   cameras/sparse/0/             the chosen model: the free mapper's largest, or
//                                 the given focal's, or the search's best (binary,
//                                 as the mapper wrote it); in text when the orbit
//                                 refinement changed it
//   cameras/estimate.json         the focal length, how it was chosen, every
//                                 candidate, the orbit check and refinement, and
//                                 the COLMAP settings that shaped the model
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
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/pipeline/inputs/colmap_commands.hpp"
#include "orbitforge/pipeline/inputs/descriptor_matching.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/focal_search.hpp"
#include "orbitforge/pipeline/inputs/orbit_refinement.hpp"
#include "orbitforge/pipeline/stage_record.hpp"

namespace orbitforge {

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

namespace cameras_detail {

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

}  // namespace cameras_detail

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
  const fs::path model_dir = stage_dir / "sparse" / "0";

  // The key: the input's bytes and the settings that shape the result.
  // The COLMAP settings also go into estimate.json, for the report.
  const nlohmann::json colmap_settings = {{"camera_model", p.camera_model},
                                          {"sift_peak_threshold", p.sift_peak_threshold},
                                          {"sift_retry_threshold", p.sift_retry_threshold},
                                          {"sift_few_features", p.sift_few_features},
                                          {"matcher", "exact, sequential pairs"},
                                          {"sequential_overlap", p.sequential_overlap},
                                          {"init_min_tri_angle_deg", p.init_min_tri_angle_deg}};
  nlohmann::json settings = {{"frames", p.frames},
                             {"colmap", colmap_settings},
                             {"focal_given_px", p.focal_px},
                             {"fov_given_deg", p.fov_deg},
                             {"focal_factors", p.focal_factors},
                             {"orbit_refine", orbit_refine_name(p.orbit_refine)}};
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
  auto timed = [&](const ToolCommand& cmd, const std::string& log_name) {
    const ToolRun t = run_tool(cmd, (logs / log_name).string());
    char b[200];
    std::snprintf(b, sizeof(b), "   cameras: %s: %.1f s", cmd.tool.c_str(), t.seconds);
    log(b);
    return t.seconds;
  };
  // Features at the given threshold, or at COLMAP's and again at the retry
  // threshold when they are few (CameraStageParams::sift_peak_threshold).
  timed(colmap_feature_extractor_command(database.string(), colmap_images.string(), p), "feature_extractor.log");
  nlohmann::json features = {{"threshold", p.sift_peak_threshold}};
  if (p.sift_peak_threshold == 0 && p.sift_retry_threshold > 0) {
    const std::vector<int> counts = sift_feature_counts(read_file_bytes((logs / "feature_extractor.log").string()));
    ensure(counts.size() == r.source_names.size(), "colmap feature_extractor: its log lists ", counts.size(),
           " feature counts for ", r.source_names.size(), " source frames (see ", (logs / "feature_extractor.log").string(),
           "); pass a SIFT threshold to skip the count");
    const double median = percentile(std::vector<double>(counts.begin(), counts.end()), 50);
    features["median_per_frame_at_colmap_default"] = median;
    if (median < p.sift_few_features) {
      log("   cameras: " + number_text(median) + " SIFT features per frame (median) at COLMAP's threshold, under " +
          std::to_string(p.sift_few_features) + ": extracting again at " + number_text(p.sift_retry_threshold));
      for (const char* suffix : {"", "-journal", "-wal", "-shm"}) fs::remove(database.string() + suffix);
      CameraStageParams retry = p;
      retry.sift_peak_threshold = p.sift_retry_threshold;
      timed(colmap_feature_extractor_command(database.string(), colmap_images.string(), retry),
            "feature_extractor_retry.log");
      features["threshold"] = p.sift_retry_threshold;
    }
  }
  // Matches: exact, so that a second run gives the same cameras (descriptor_matching.hpp).
  ExactMatchSummary matched;
  {
    std::vector<std::pair<std::string, std::string>> pairs;
    for (const auto& [i, j] : sequential_match_pairs(int(r.source_names.size()), p.sequential_overlap))
      pairs.push_back({r.source_names[std::size_t(i)], r.source_names[std::size_t(j)]});
    matched = write_exact_match_list(database.string(), pairs, (colmap_dir / "matches.txt").string(), p.threads);
    log("   cameras: " + matched.text());
  }
  timed(colmap_raw_matches_importer_command(database.string(), (colmap_dir / "matches.txt").string(), p),
        "matches_importer.log");
  FocalChoice choice = map_source_frames(colmap_dir.string(), colmap_images.string(), r.source_names, p, timed);
  const std::string best = choice.model_dir;
  fs::create_directories(model_dir);
  for (const char* f : {"cameras.bin", "images.bin", "points3D.bin"})
    ensure(fs::exists(fs::path(best) / f), "colmap mapper: model ", best, " has no ", f);
  const OrbitRefinement refined = refine_model_on_orbit(read_colmap_model(best), p.orbit_refine);
  for (const auto& w : refined.before.warnings) log("   cameras: warning: the cameras are not an orbit: " + w);
  log("   cameras: " + refined.summary);
  std::vector<std::string> model_files;
  if (refined.applied) {
    write_colmap_model_text(model_dir.string(), refined.model);
    model_files = {"cameras.txt", "images.txt", "points3D.txt"};
  } else {
    model_files = {"cameras.bin", "images.bin", "points3D.bin"};
    for (const auto& f : model_files) fs::copy_file(fs::path(best) / f, model_dir / f, fs::copy_options::overwrite_existing);
  }
  choice.json["orbit_refinement"] = refined.json;
  choice.json["colmap"] = colmap_settings;
  choice.json["colmap"]["features"] = features;
  choice.json["colmap"]["matches"] = {{"pairs", matched.pairs},
                                      {"pairs_matched", matched.pairs_matched},
                                      {"matches_before_verification", matched.matches},
                                      {"seconds", matched.seconds}};
  write_file_atomic((stage_dir / "estimate.json").string(), choice.json.dump(1) + "\n");
  for (const auto& [id, im] : refined.model.images) r.registered_names.push_back(im.name);
  std::sort(r.registered_names.begin(), r.registered_names.end());
  log("   cameras: COLMAP registered " + std::to_string(r.registered_names.size()) + " of " +
      std::to_string(r.source_names.size()) + " source frames; " + choice.summary);

  // The record: every frame, what COLMAP saw, its database and the chosen model.
  const std::string base = "cameras/";
  std::vector<std::string> outputs;
  for (const auto& n : names) outputs.push_back(base + "images/" + n);
  for (const auto& n : r.source_names) outputs.push_back(base + "colmap/images/" + n);
  outputs.push_back(base + "colmap/database.db");
  for (const auto& f : model_files) outputs.push_back(base + "sparse/0/" + f);
  outputs.push_back(base + "estimate.json");
  settings["frames_total"] = names.size();
  settings["source_frames"] = r.source_names.size();
  settings["registered"] = r.registered_names.size();
  settings["focal_px"] = choice.focal_px;
  settings["orbit_refined"] = refined.applied;
  r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  record_stage(out, "cameras", r.key, r.seconds, settings, outputs);
  return r;
}

}  // namespace orbitforge

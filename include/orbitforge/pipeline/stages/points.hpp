#pragma once
// Stage 0, points: a COLMAP model that holds cameras but no 3D points
// (calibrated photographs, as Middlebury's rings come) gets points triangulated
// by COLMAP at those cameras, so that training starts from the object's surface
// rather than from a random cloud in the view volume:
//
//   points/images/NNNN.png   the training frames as training sees them (working
//                            size, the loaded pixels); NNNN = the frame's index
//   points/database.db       their features (one extractor run per frame, so
//                            image and camera ids follow the frames' order) and
//                            matches: every pair up to 40 frames
//                            (PointStageParams), else each frame with its 10
//                            neighbours in order (all pairs grow as frames^2)
//   points/known/            the frames' cameras as a text model, no points
//   points/sparse/           point_triangulator's model (cameras held fixed)
//   points/logs/*.log        each tool's command line and output
//
// Evidence: only the training frames (the source range less the withheld
// frames) reach COLMAP, so no point is placed with a view the method scores on.
//
// Resuming: stages/points.json records the key (the frames' pixels, cameras and
// names) and the size and hash of the images, the database and the model; when
// it verifies, the model is read again and nothing runs.
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/hash.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/inputs/colmap_commands.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/stage_record.hpp"

namespace orbitforge {

struct PointStageParams {
  std::size_t exhaustive_up_to = 40;  // training frames up to which every pair is matched
  int threads = 0;  // COLMAP's threads (0 = all)
  std::function<void(const std::string&)> log;  // progress lines (stderr when empty)
};

struct PointStageResult {
  bool ran = false;       // COLMAP ran (else the record verified, or nothing was needed)
  bool skipped = false;   // the record verified: nothing ran
  std::string key;        // stages/points.json's key, when there is a record (points found)
  std::size_t frames = 0; // training frames given to COLMAP
  std::size_t points = 0; // points triangulated
  double seconds = 0;
  std::string summary;
};

namespace points_detail {

inline std::string frame_file(int frame) {
  char b[32];
  std::snprintf(b, sizeof(b), "%04d.png", frame);
  return b;
}

// The known cameras of `frames` (image and camera id k + 1 for frames[k]),
// one PINHOLE camera each at the working size, no points.
template <class Scalar>
ColmapModel known_camera_model(const PipelineInput<Scalar>& in, const std::vector<int>& frames) {
  ColmapModel m;
  for (std::size_t k = 0; k < frames.size(); ++k) {
    const int id = int(k) + 1;
    const Camera<double> c = in.cameras[std::size_t(frames[k])].camera.template cast<double>();
    const auto& q = c.intrinsics;
    m.cameras[id] = ColmapCamera{id, "PINHOLE", q.width, q.height, {q.fx, q.fy, q.cx, q.cy}};
    ColmapImage im;
    im.id = id;
    im.camera_id = id;
    im.name = frame_file(frames[std::size_t(k)]);
    set_colmap_pose(im, c.R, c.t);
    m.images[id] = std::move(im);
  }
  return m;
}

}  // namespace points_detail

// Whether the input needs points: it has none that two training frames saw.
template <class Scalar>
bool needs_triangulated_points(const PipelineInput<Scalar>& in) {
  return source_points(in).kept < 4;
}

// Triangulates points for `in` from its training frames (see the top of the
// file) into out/points and replaces in.points, colors and point_frames with
// them; when COLMAP finds none, `in` is left as it was (result: 0 points).
// Needs colmap on PATH and at least two training frames.
template <class Scalar>
PointStageResult stage_points(const std::string& out, PipelineInput<Scalar>& in, const PointStageParams& p = {}) {
  namespace fs = std::filesystem;
  const auto t0 = std::chrono::steady_clock::now();
  auto log = [&](const std::string& s) {
    if (p.log) p.log(s);
    else std::fprintf(stderr, "%s\n", s.c_str());
  };
  const std::vector<int> frames = training_source(in);
  ensure(frames.size() >= 2, "points stage: triangulation needs at least two training frames, the input has ",
         frames.size());
  const fs::path stage_dir = fs::path(out) / "points";
  const fs::path images_dir = stage_dir / "images", database = stage_dir / "database.db";
  const fs::path known_dir = stage_dir / "known", model_dir = stage_dir / "sparse", logs = stage_dir / "logs";
  const ColmapModel known = points_detail::known_camera_model(in, frames);

  // The key: what COLMAP sees (pixels, cameras, names) and the tools' settings.
  const bool exhaustive = frames.size() <= p.exhaustive_up_to;
  nlohmann::json settings = {
      {"frames", frames}, {"matcher", exhaustive ? "exhaustive" : "sequential 10"}, {"camera_model", "PINHOLE"}};
  std::uint64_t h = kFnv1aSeed;
  for (int f : frames) {
    const auto& img = in.images[std::size_t(f)];
    h = fnv1a(points_detail::frame_file(f) + '\n', h);
    h = fnv1a(img.data.data(), img.data.size() * sizeof(Scalar), h);
  }
  for (const auto& [id, im] : known.images) {
    const auto& c = known.cameras.at(im.camera_id);
    h = fnv1a(im.qvec.data(), 4 * sizeof(double), h);
    h = fnv1a(im.tvec.data(), 3 * sizeof(double), h);
    h = fnv1a(c.params.data(), c.params.size() * sizeof(double), h);
  }
  const std::string key = hex64(fnv1a(settings.dump(), h));
  std::vector<std::string> outputs;
  for (int f : frames) outputs.push_back("points/images/" + points_detail::frame_file(f));
  outputs.push_back("points/database.db");
  for (const char* f : {"cameras.bin", "images.bin", "points3D.bin"}) outputs.push_back(std::string("points/sparse/") + f);

  PointStageResult r;
  r.frames = frames.size();
  const StageCheck check = check_stage(out, "points", key, outputs);
  if (check.current) {
    r.skipped = true;
    r.seconds = recorded_seconds(out, "points");
  } else {
    if (check.why != "no record") log("   points: running again: " + check.why);
    require_program("points stage", "a COLMAP model without 3D points", "colmap", "colmap");
    std::error_code ec;
    fs::remove(fs::path(out) / "stages" / "points.json", ec);
    fs::remove_all(stage_dir, ec);  // feature_extractor would keep what an old database holds
    for (const fs::path& d : {images_dir, known_dir, model_dir, logs}) fs::create_directories(d);
    for (int f : frames) write_png((images_dir / points_detail::frame_file(f)).string(), in.images[std::size_t(f)]);
    write_colmap_model_text(known_dir.string(), known);

    auto run = [&](const ToolCommand& cmd, const std::string& log_name) { run_tool(cmd, (logs / log_name).string()); };
    const auto env = cameras_detail::colmap_env();
    const std::string threads = std::to_string(p.threads > 0 ? p.threads : -1);
    CameraStageParams colmap_settings;  // the cameras stage's extractor and sequential matcher
    colmap_settings.camera_model = "PINHOLE";
    // COLMAP's own threshold: the photograph rings' figures were measured with it.
    colmap_settings.sift_peak_threshold = 0;
    colmap_settings.threads = p.threads;
    for (const auto& [id, im] : known.images) {
      // One run per frame: the database numbers images and cameras in the order
      // it stores them, which a run over a folder does not fix.
      const fs::path list = logs / ("list_" + std::to_string(id) + ".txt");
      write_file_atomic(list.string(), im.name + "\n");
      const auto& c = known.cameras.at(im.camera_id);
      using cameras_detail::number_text;
      const std::string params = number_text(c.params[0]) + "," + number_text(c.params[1]) + "," +
                                 number_text(c.params[2]) + "," + number_text(c.params[3]);
      ToolCommand fe = colmap_feature_extractor_command(database.string(), images_dir.string(), colmap_settings);
      for (const std::string& arg : {std::string("--image_list_path"), list.string(),
                                     std::string("--ImageReader.camera_params"), params})
        fe.argv.push_back(arg);
      run(fe, "feature_extractor_" + std::to_string(id) + ".log");
    }
    if (exhaustive) {
      run(ToolCommand{"colmap exhaustive_matcher",
                      {"colmap", "exhaustive_matcher", "--database_path", database.string(), "--SiftMatching.use_gpu",
                       "0", "--SiftMatching.num_threads", threads, "--log_to_stderr", "1"},
                      env},
          "exhaustive_matcher.log");
    } else {
      run(colmap_sequential_matcher_command(database.string(), colmap_settings), "sequential_matcher.log");
    }
    // Frames that share too few features leave nothing to triangulate, and
    // point_triangulator then stops on a failed bundle adjustment: no points,
    // not an error (training starts from a random cloud, as without the stage).
    try {
      run(ToolCommand{"colmap point_triangulator",
                      {"colmap", "point_triangulator", "--database_path", database.string(), "--image_path",
                       images_dir.string(), "--input_path", known_dir.string(), "--output_path", model_dir.string(),
                       "--Mapper.ba_refine_focal_length", "0", "--Mapper.ba_refine_principal_point", "0",
                       "--Mapper.ba_refine_extra_params", "0", "--Mapper.num_threads", threads, "--log_to_stderr",
                       "1"},
                      env},
          "point_triangulator.log");
    } catch (const Error&) {
      r.ran = true;
      r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      r.summary = "   points: COLMAP triangulated no points from the " + std::to_string(r.frames) +
                  " training frames (point_triangulator stopped, as it does when the frames share too few "
                  "features; its log: " + (logs / "point_triangulator.log").string() + ")";
      log(r.summary);
      return r;
    }
    for (const auto& f : outputs)
      ensure(fs::exists(fs::path(out) / f), "points stage: COLMAP wrote no ", f, " (logs in ", logs.string(), ")");
    r.ran = true;
    r.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  }

  // The points, with the frames that observed them (image id k + 1 = frames[k]).
  const ColmapModel model = read_colmap_model(model_dir.string());
  for (const auto& [id, im] : model.images) {
    const auto it = known.images.find(id);
    ensure(it != known.images.end() && it->second.name == im.name, "points stage: ", model_dir.string(),
           ": image ", id, " (", im.name, ") is not the frame the stage gave that id");
  }
  in.points.clear();
  in.colors.clear();
  in.point_frames.clear();
  for (const ColmapPoint& q : model.points) {
    std::vector<int> seen;
    for (int id : q.track_images) {
      ensure(id >= 1 && std::size_t(id) <= frames.size(), "points stage: ", model_dir.string(), ": point ", q.id,
             " is seen by image ", id, ", which the stage did not give");
      seen.push_back(frames[std::size_t(id - 1)]);
    }
    for (int c = 0; c < 3; ++c) {
      in.points.push_back(Scalar(q.xyz[c]));
      in.colors.push_back(Scalar(q.rgb[std::size_t(c)]) / Scalar(255));
    }
    in.point_frames.push_back(std::move(seen));
  }
  r.points = model.points.size();
  in.points_origin = "triangulated by COLMAP from the " + std::to_string(r.frames) + " training frames at their cameras";
  if (r.ran) {
    settings["points"] = r.points;
    record_stage(out, "points", key, r.seconds, settings, outputs);
  }
  r.key = key;
  char b[200];
  std::snprintf(b, sizeof(b), "   points: %zu points triangulated by COLMAP from %zu training frames at their cameras%s",
                r.points, r.frames, r.skipped ? " (outputs verified, skipped)" : "");
  r.summary = b;
  if (r.ran) {
    std::snprintf(b, sizeof(b), " in %.1f s", r.seconds);
    r.summary += b;
  }
  log(r.summary);
  return r;
}

}  // namespace orbitforge

#pragma once
// The settings of the cameras stage and the command lines of the programs it
// runs (ffmpeg, COLMAP's feature_extractor, matches_importer and mapper),
// built as argument vectors (pipeline/inputs/external_tools.hpp runs them), and the
// COLMAP model files the stage writes or picks.
//
// A known focal length is held fixed by giving the mapper an input model that
// holds only the camera (cameras.txt with the focal, no images, no points) and
// turning off its focal refinement: the database keeps the extractor's camera,
// so one feature and match database serves every focal length tried.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <functional>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/orbit_refinement.hpp"

namespace orbitforge {

// The multiples of the mapper's focal estimate the focal search maps at.
inline const std::vector<double> kFocalSearchFactors = {0.8, 0.9, 1.1, 1.25};

struct CameraStageParams {
  std::string video;            // a video file (decoded with ffmpeg), or
  std::string images;           // a folder of frames, in name order
  std::string frames = "1-33";  // the source range: the only frames COLMAP sees
  double fps = 0;               // video only: resample to this frame rate (0 = every decoded frame)
  std::string camera_model = "SIMPLE_PINHOLE";  // one camera for all frames: SIMPLE_PINHOLE or PINHOLE
  int sequential_overlap = 10;                  // as COLMAP's sequential_matcher: neighbours matched per frame
  // A generated orbit turns a few degrees per frame, so the default 16 degrees
  // for the initial pair rejects every nearby pair; v3d's cameras were made with 4.
  double init_min_tri_angle_deg = 4;
  // SIFT's difference-of-Gaussians threshold; 0 = COLMAP's default (0.0067), and
  // then, when the source frames give few features at it (a median under
  // sift_few_features a frame), the features are extracted again at
  // sift_retry_threshold. With few features the mapper's focal length and arc
  // come out short (sunflower: 218 a frame, 4 % and 5 degrees short; 0.004
  // fixes both); with enough, COLMAP's threshold gave the focal length closer
  // to the all-frame model's than 0.004 did (corgi_bread, 387 a frame: -0.2 to
  // -1.4 % against -1.6 to -2.1 %). docs/cameras.md.
  double sift_peak_threshold = 0;
  double sift_retry_threshold = 0.004;  // 0 = never extract again
  int sift_few_features = 300;
  int threads = 0;  // COLMAP's threads (0 = all)
  // The lens, when the user knows it (pixels of the frames' own size, or the
  // horizontal field of view): held fixed while mapping. 0 = unknown.
  double focal_px = 0, fov_deg = 0;
  // Without it the mapper's own estimate is kept, unless these multiples of it
  // are given: then the stage maps again at each and keeps the focal length
  // whose cameras fit an orbit best (pipeline/inputs/focal_search.hpp). Off by default:
  // on the recorded videos the search moved the focal further from the
  // reference model's as often as closer (docs/cameras.md).
  std::vector<double> focal_factors;  // `--focal-search` sets kFocalSearchFactors
  // The chosen model's cameras refined with the orbit as a prior: when the
  // orbit check warns (default), always, or never (pipeline/inputs/orbit_refinement.hpp).
  OrbitRefine orbit_refine = OrbitRefine::flagged;
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

// The per-image feature counts feature_extractor printed ("Features: N" lines
// of its log, in the order it read the images).
inline std::vector<int> sift_feature_counts(const std::string& log_text) {
  std::vector<int> counts;
  std::istringstream in(log_text);
  std::string line;
  while (std::getline(in, line)) {
    const std::size_t at = line.find("Features:");
    if (at == std::string::npos) continue;
    std::istringstream rest(line.substr(at + 9));
    long n = -1;
    if (rest >> n && n >= 0) counts.push_back(int(n));
  }
  return counts;
}

namespace cameras_detail {

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
  if (p.sift_peak_threshold > 0) {
    c.argv.push_back("--SiftExtraction.peak_threshold");
    c.argv.push_back(cameras_detail::number_text(p.sift_peak_threshold));
  }
  // One thread: on more, images get their database ids in the order they
  // finish, and the mapper's result depends on the ids (the same frames, two
  // runs: two different models).
  c.argv.push_back("--SiftExtraction.num_threads");
  c.argv.push_back("1");
  return c;
}

namespace cameras_detail {

inline ToolCommand colmap_matcher_command(const std::string& matcher, const std::string& database,
                                          const std::vector<std::string>& options, const CameraStageParams& p) {
  ToolCommand c{"colmap " + matcher,
                {"colmap", matcher, "--database_path", database, "--SiftMatching.use_gpu", "0", "--log_to_stderr", "1"},
                colmap_env()};
  c.argv.insert(c.argv.end(), options.begin(), options.end());
  if (p.threads > 0) {
    c.argv.push_back("--SiftMatching.num_threads");
    c.argv.push_back(std::to_string(p.threads));
  }
  return c;
}

}  // namespace cameras_detail

inline ToolCommand colmap_sequential_matcher_command(const std::string& database, const CameraStageParams& p) {
  return cameras_detail::colmap_matcher_command(
      "sequential_matcher", database, {"--SequentialMatching.overlap", std::to_string(p.sequential_overlap)}, p);
}

// The matches listed in `match_list` (pipeline/inputs/descriptor_matching.hpp's
// raw list), verified geometrically by COLMAP. On one thread as a precaution:
// COLMAP draws RANSAC samples per thread (repeated imports kept the same
// inliers on one and on two threads alike; docs/cameras.md).
inline ToolCommand colmap_raw_matches_importer_command(const std::string& database, const std::string& match_list,
                                                       const CameraStageParams& p) {
  CameraStageParams one_thread = p;
  one_thread.threads = 1;
  return cameras_detail::colmap_matcher_command("matches_importer", database,
                                                {"--match_list_path", match_list, "--match_type", "raw"}, one_thread);
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

// The mapper with the focal length held at the one in `camera_model_dir` (a
// model with one camera and no images, write_colmap_camera_only); it writes
// its one model straight into `output_dir`.
inline ToolCommand colmap_mapper_fixed_focal_command(const std::string& database, const std::string& image_dir,
                                                     const std::string& camera_model_dir,
                                                     const std::string& output_dir, const CameraStageParams& p) {
  ToolCommand c = colmap_mapper_command(database, image_dir, output_dir, p);
  c.tool = "colmap mapper (fixed focal)";
  for (const char* a : {"--input_path", camera_model_dir.c_str(), "--Mapper.ba_refine_focal_length", "0",
                        "--Mapper.ba_refine_principal_point", "0"})
    c.argv.push_back(a);
  return c;
}

// The focal length in pixels of a `width`-wide frame with horizontal field of view `fov_deg`.
inline double focal_from_fov(double fov_deg, int width) {
  ensure(fov_deg > 0 && fov_deg < 180, "field of view ", fov_deg, " degrees: must lie in (0, 180)");
  return 0.5 * double(width) / std::tan(fov_deg * 3.14159265358979323846 / 360.0);
}

// A COLMAP text model holding only camera 1 (the database's single camera) with
// focal length `focal_px` and the principal point at the frame's centre.
inline void write_colmap_camera_only(const std::string& dir, const std::string& camera_model, int width, int height,
                                     double focal_px) {
  namespace fs = std::filesystem;
  ensure(camera_model == "SIMPLE_PINHOLE" || camera_model == "PINHOLE", "camera model ", camera_model,
         ": only SIMPLE_PINHOLE or PINHOLE can be held at a focal length");
  ensure(std::isfinite(focal_px) && focal_px > 0, "focal length ", focal_px, " px: must be positive");
  ensure(width > 0 && height > 0, "frame size ", width, "x", height);
  fs::create_directories(dir);
  std::ostringstream cam;
  cam.precision(12);
  cam << "1 " << camera_model << ' ' << width << ' ' << height << ' ' << focal_px << ' ';
  if (camera_model == "PINHOLE") cam << focal_px << ' ';
  cam << 0.5 * width << ' ' << 0.5 * height << '\n';
  write_file_atomic((fs::path(dir) / "cameras.txt").string(), cam.str());
  write_file_atomic((fs::path(dir) / "images.txt").string(), "");
  write_file_atomic((fs::path(dir) / "points3D.txt").string(), "");
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

}  // namespace orbitforge

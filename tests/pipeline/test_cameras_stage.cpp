// The cameras stage (a video or an image folder -> frames + COLMAP cameras of the
// source frames only) and the external-program runner under it: commands as
// argument vectors, the missing-program message, tool failures naming the log,
// and, with ffmpeg, colmap and a recorded v3d video, a short clip end to end
// (registration, no gap frame given to COLMAP, resume and re-run on damage).
#include <catch2/catch.hpp>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"
#include "orbitforge/pipeline/inputs/focal_search.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"
#include "orbitforge/pipeline/stages/cameras.hpp"
#include "support/data.hpp"
#include "support/programs.hpp"
#include "support/temp_dir.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"

using namespace orbitforge;

// The test cases too live in a named namespace: the layer's test files are compiled as
// one unity source, so nothing here may reach another file's names.
namespace cameras_stage_test {
namespace fs = std::filesystem;

struct TempDir : orbitforge_test::TempDir {
  TempDir() : orbitforge_test::TempDir("cameras_test") {}
};

// Sets PATH for the scope and restores it.
struct PathOverride {
  std::string saved;
  bool had = false;
  explicit PathOverride(const std::string& path) {
    if (const char* p = std::getenv("PATH")) {
      saved = p;
      had = true;
    }
    ::setenv("PATH", path.c_str(), 1);
  }
  ~PathOverride() {
    if (had) ::setenv("PATH", saved.c_str(), 1);
    else ::unsetenv("PATH");
  }
};

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

// The argument after `flag` in argv ("" when absent).
std::string after(const std::vector<std::string>& argv, const std::string& flag) {
  for (std::size_t i = 0; i + 1 < argv.size(); ++i)
    if (argv[i] == flag) return argv[i + 1];
  return "";
}

std::string text_of(const fs::path& p) { return read_file_bytes(p.string()); }


TEST_CASE("cameras stage: ffmpeg and colmap commands are argument vectors", "[pipeline][cameras]") {
  const std::string video = "/data/my clip's.mp4";
  const ToolCommand f = ffmpeg_extract_command(video, "/tmp/run 100%/cameras/images", 12.5);
  CHECK(f.argv.front() == "ffmpeg");
  CHECK(after(f.argv, "-i") == video);  // one argument, unchanged
  CHECK(after(f.argv, "-vf") == "fps=12.5");
  CHECK(after(f.argv, "-vsync") == "0");
  // '%' in the folder is the image2 muxer's literal percent; the frame number stays a pattern.
  CHECK(f.argv.back() == "/tmp/run 100%%/cameras/images/%05d.png");
  CHECK(after(ffmpeg_extract_command("clip.mp4", "d").argv, "-i") == (fs::current_path() / "clip.mp4").string());
  CHECK(!contains(ffmpeg_extract_command(video, "/o").argv, "-vf"));
  // Shell-quoted only for the log: pasting it back gives the same words.
  CHECK(command_text(f).find("'/data/my clip'\\''s.mp4'") != std::string::npos);

  CameraStageParams p;
  p.threads = 2;
  const ToolCommand fe = colmap_feature_extractor_command("/o/db.db", "/o/images", p);
  CHECK(fe.argv[0] == "colmap");
  CHECK(fe.argv[1] == "feature_extractor");
  CHECK(after(fe.argv, "--database_path") == "/o/db.db");
  CHECK(after(fe.argv, "--image_path") == "/o/images");
  CHECK(after(fe.argv, "--ImageReader.single_camera") == "1");
  CHECK(after(fe.argv, "--ImageReader.camera_model") == "SIMPLE_PINHOLE");
  CHECK(after(fe.argv, "--SiftExtraction.use_gpu") == "0");
  CHECK(after(fe.argv, "--SiftExtraction.num_threads") == "1");  // database ids in name order
  // COLMAP's own threshold by default; a given one is passed on.
  CHECK(!contains(fe.argv, "--SiftExtraction.peak_threshold"));
  CameraStageParams held = p;
  held.sift_peak_threshold = 0.004;
  CHECK(after(colmap_feature_extractor_command("/o/db.db", "/o/images", held).argv,
              "--SiftExtraction.peak_threshold") == "0.004");
  REQUIRE(fe.env.size() == 1);
  CHECK(fe.env[0].first == "QT_QPA_PLATFORM");
  CHECK(fe.env[0].second == "offscreen");
  const ToolCommand sm = colmap_sequential_matcher_command("/o/db.db", p);
  CHECK(sm.argv[1] == "sequential_matcher");
  CHECK(after(sm.argv, "--SiftMatching.use_gpu") == "0");
  CHECK(after(sm.argv, "--SequentialMatching.overlap") == "10");
  // Verification of the stage's own matches, always on one thread (its RANSAC draws depend on the dealing).
  const ToolCommand mi = colmap_raw_matches_importer_command("/o/db.db", "/o/matches.txt", p);
  CHECK(mi.argv[1] == "matches_importer");
  CHECK(after(mi.argv, "--match_type") == "raw");
  CHECK(after(mi.argv, "--match_list_path") == "/o/matches.txt");
  CHECK(after(mi.argv, "--SiftMatching.num_threads") == "1");
  CHECK(after(mi.argv, "--SiftMatching.use_gpu") == "0");
  const ToolCommand mp = colmap_mapper_command("/o/db.db", "/o/images", "/o/sparse", p);
  CHECK(mp.argv[1] == "mapper");
  CHECK(after(mp.argv, "--output_path") == "/o/sparse");
  CHECK(after(mp.argv, "--Mapper.init_min_tri_angle") == "4");
  p.threads = 0;
  CHECK(!contains(colmap_mapper_command("d", "i", "o", p).argv, "--Mapper.num_threads"));
}

TEST_CASE("cameras stage: a known focal length is held by a camera-only model; the orbit score", "[pipeline][cameras]") {
  CameraStageParams p;
  const ToolCommand mf = colmap_mapper_fixed_focal_command("/o/db.db", "/o/images", "/o/cam", "/o/out", p);
  CHECK(mf.argv[1] == "mapper");
  CHECK(after(mf.argv, "--input_path") == "/o/cam");
  CHECK(after(mf.argv, "--output_path") == "/o/out");
  CHECK(after(mf.argv, "--Mapper.ba_refine_focal_length") == "0");
  CHECK(std::abs(focal_from_fov(90, 512) - 256) < 1e-9);
  CHECK(std::abs(focal_from_fov(60, 640) - 320 / std::tan(3.14159265358979 / 6)) < 1e-9);
  CHECK_THROWS_WITH(focal_from_fov(180, 512), Catch::Contains("field of view"));

  TempDir t;
  write_colmap_camera_only((t.path() / "cam").string(), "SIMPLE_PINHOLE", 512, 384, 431.5);
  const ColmapModel m = read_colmap_model((t.path() / "cam").string());
  REQUIRE(m.cameras.size() == 1);
  CHECK(m.cameras.begin()->first == 1);
  CHECK(m.cameras.begin()->second.params == std::vector<double>{431.5, 256, 192});
  CHECK(m.images.empty());
  write_colmap_camera_only((t.path() / "cam2").string(), "PINHOLE", 100, 100, 80);
  CHECK(read_colmap_model((t.path() / "cam2").string()).cameras.begin()->second.params ==
        std::vector<double>{80, 80, 50, 50});
  CHECK_THROWS_WITH(write_colmap_camera_only((t.path() / "c3").string(), "SIMPLE_RADIAL", 10, 10, 5),
                    Catch::Contains("SIMPLE_RADIAL"));
  CHECK_THROWS_WITH(write_colmap_camera_only((t.path() / "c4").string(), "PINHOLE", 10, 10, -5),
                    Catch::Contains("must be positive"));

  // The orbit score: an even arc scores lower than one whose steps are uneven,
  // and a missing frame costs its share.
  auto arc = [](double unevenness, int frames) {
    std::vector<FrameCamera<double>> cams;
    const Intrinsics<double> k{400, 400, 256, 256, 512, 512};
    double az = 0;
    for (int i = 0; i < frames; ++i) {
      az += 3.8 * (1 + unevenness * ((i % 2) ? 1 : -1));
      const double a = az * 3.14159265358979 / 180;
      FrameCamera<double> f;
      f.name = std::to_string(1000 + i);
      f.camera = Camera<double>::look_at({4 * std::cos(a), 4 * std::sin(a), 1}, {0, 0, 0}, {0, 0, 1}, k);
      cams.push_back(f);
    }
    return cams;
  };
  const OrbitFitScore even = orbit_fit_score(arc(0, 33), 33), uneven = orbit_fit_score(arc(0.3, 33), 33),
                      short_one = orbit_fit_score(arc(0, 30), 33);
  REQUIRE(even.usable);
  CHECK(even.step_spread < 1e-6);
  CHECK(uneven.value > even.value + 0.2);
  CHECK(std::abs(short_one.missing - 3.0 / 33) < 1e-12);
  CHECK(short_one.value > even.value);
  CHECK(!orbit_fit_score(arc(0, 2), 2).usable);
}

TEST_CASE("cameras stage: a missing program is named with its Debian package before any work", "[pipeline][cameras]") {
  TempDir t;
  const fs::path empty = t.path() / "empty_bin";
  fs::create_directories(empty);
  CHECK(find_program("ffmpeg", empty.string()).empty());
  CHECK(find_program("sh", "/nonexistent:" + empty.string() + ":/bin:/usr/bin") != "");
  CHECK(missing_program_message("full_pipeline", "--video", "ffmpeg", "ffmpeg") ==
        "full_pipeline: --video needs the ffmpeg program (Debian package ffmpeg): not found on PATH");

  std::ofstream(t.path() / "clip.mp4") << "not really a video";
  CameraStageParams p;
  p.video = (t.path() / "clip.mp4").string();
  p.log = [](const std::string&) {};
  const fs::path out = t.path() / "out";
  {
    PathOverride path(empty.string());
    CHECK_THROWS_WITH(require_program("x", "--images", "colmap", "colmap"),
                      "x: --images needs the colmap program (Debian package colmap): not found on PATH");
    CHECK_THROWS_WITH(stage_cameras(out.string(), p),
                      Catch::Contains("needs the ffmpeg program (Debian package ffmpeg): not found on PATH"));
  }
  CHECK(!fs::exists(out / "cameras" / "images"));  // nothing was started
}

TEST_CASE("external tools: arguments, environment and failures with their log", "[pipeline][cameras]") {
  TempDir t;
  const std::string log = (t.path() / "logs" / "printf.log").string();
  run_tool({"printf", {"printf", "[%s]\\n", "a b", "c'd", "$HOME", "*"}, {}}, log);
  const std::string text = text_of(log);
  CHECK(text.rfind("$ printf ", 0) == 0);                       // the command line first
  CHECK(text.find("[a b]\n[c'd]\n[$HOME]\n[*]\n") != std::string::npos);  // no shell touched them

  const std::string env_log = (t.path() / "env.log").string();
  run_tool({"sh", {"sh", "-c", "echo platform=$QT_QPA_PLATFORM"}, {{"QT_QPA_PLATFORM", "offscreen"}}}, env_log);
  CHECK(text_of(env_log).find("platform=offscreen") != std::string::npos);

  const std::string fail_log = (t.path() / "fail.log").string();
  try {
    run_tool({"colmap mapper", {"sh", "-c", "echo 'no good initial pair' >&2; exit 3"}, {}}, fail_log);
    FAIL("expected a failure");
  } catch (const Error& e) {
    const std::string m = e.what();
    CHECK(m.find("colmap mapper failed with exit status 3") != std::string::npos);
    CHECK(m.find(fail_log) != std::string::npos);
    CHECK(m.find("no good initial pair") != std::string::npos);
  }
  CHECK_THROWS_WITH(run_tool({"tool", {"orbitforge-no-such-program"}, {}}, (t.path() / "x.log").string()),
                    Catch::Contains("orbitforge-no-such-program is not found on PATH"));
}

TEST_CASE("cameras stage: only the source frames reach COLMAP's folder; the largest model wins",
          "[pipeline][cameras]") {
  TempDir t;
  const fs::path frames = t.path() / "frames";
  fs::create_directories(frames);
  std::vector<std::string> names;
  for (int i = 1; i <= 12; ++i) {
    char b[16];
    std::snprintf(b, sizeof(b), "%05d.png", i);
    names.push_back(b);
    std::ofstream(frames / b) << "frame " << i;
  }
  const fs::path seen = t.path() / "colmap_images";
  const auto linked = link_source_frames(frames.string(), names, "3-10", seen.string());
  CHECK(linked == std::vector<std::string>(names.begin() + 2, names.begin() + 10));
  CHECK(list_image_files(seen.string()) == linked);
  CHECK(text_of(seen / "00003.png") == "frame 3");
  CHECK_THROWS_WITH(link_source_frames(frames.string(), names, "1-13", (t.path() / "x").string()),
                    Catch::Contains("only 12 frames"));

  // Two models as the mapper may write them: 1/ registers more images than 0/.
  auto model = [&](const std::string& dir, int images) {
    std::vector<FrameCamera<double>> cams;
    for (int i = 0; i < images; ++i) {
      FrameCamera<double> fc;
      fc.name = names[std::size_t(i)];
      fc.camera.intrinsics = {100, 100, 32, 32, 64, 64};
      fc.camera.t = Eigen::Vector3d(0.1 * i, 0, 4);
      cams.push_back(fc);
    }
    write_colmap_text((t.path() / "sparse" / dir).string(), cams);
  };
  model("0", 2);
  model("1", 3);
  model("2", 3);
  std::size_t n = 0;
  CHECK(fs::path(largest_colmap_model((t.path() / "sparse").string(), &n)).filename() == "1");
  CHECK(n == 3);
  CHECK(largest_colmap_model((t.path() / "nothing").string()).empty());
}

TEST_CASE("cameras stage: a short video through ffmpeg and COLMAP, source frames only, resumable",
          "[pipeline][cameras][data]") {
  const std::string video_name = "v3d/cool_teddy/images";
  if (!orbitforge_test::have_shared_data(video_name)) return;
  if (!orbitforge_test::have_programs({"ffmpeg", "colmap"})) return;
  const auto t0 = std::chrono::steady_clock::now();
  TempDir t;
  // A 12-frame clip at 256 x 256 from recorded frames 1-12, as a user's mp4.
  const std::string clip = (t.path() / "clip.mp4").string();
  run_tool({"ffmpeg",
            {"ffmpeg", "-nostdin", "-y", "-framerate", "30", "-start_number", "1", "-i",
             orbitforge_test::shared_path(video_name) + "/%03d.jpg", "-frames:v", "12", "-vf", "scale=256:256",
             "-c:v", "libx264", "-crf", "12", "-pix_fmt", "yuv420p", clip},
            {}},
           (t.path() / "make_clip.log").string());

  CameraStageParams p;
  p.video = clip;
  p.frames = "1-10";
  p.threads = 2;
  std::vector<std::string> lines;
  p.log = [&](const std::string& s) { lines.push_back(s); };
  const fs::path out = t.path() / "out";
  const CameraStageResult r = stage_cameras(out.string(), p);
  CHECK(!r.skipped);
  CHECK(r.frames == 12);
  REQUIRE(r.source_names.size() == 10);
  CHECK(r.source_names.front() == "00001.png");
  CHECK(r.source_names.back() == "00010.png");
  CHECK(r.registered_names.size() >= 8);
  for (const auto& n : r.registered_names) CHECK(contains(r.source_names, n));

  // What COLMAP saw: its image folder and its database hold the source frames only.
  const fs::path cam = out / "cameras";
  CHECK(list_image_files((cam / "images").string()).size() == 12);
  CHECK(list_image_files((cam / "colmap" / "images").string()) == r.source_names);
  const std::string db = text_of(cam / "colmap" / "database.db");
  for (const auto& n : r.source_names) CHECK(db.find(n) != std::string::npos);
  CHECK(db.find("00011.png") == std::string::npos);
  CHECK(db.find("00012.png") == std::string::npos);
  for (const char* log : {"ffmpeg.log", "feature_extractor.log", "matches_importer.log", "mapper.log"})
    CHECK(fs::file_size(cam / "logs" / log) > 0);
  CHECK(fs::file_size(cam / "colmap" / "matches.txt") > 0);
  CHECK(fs::exists(out / "stages" / "cameras.json"));

  // Loaded like --colmap: every frame listed, the gap frames without cameras.
  const auto in = load_colmap_input<float>(r.dataset, p.frames, 64, 64);
  CHECK(in.cameras.size() == 12);
  CHECK(in.source.size() == r.registered_names.size());
  CHECK(!in.cameras[10].valid);
  CHECK(!in.cameras[11].valid);

  // A second run verifies the record and runs nothing.
  lines.clear();
  const CameraStageResult again = stage_cameras(out.string(), p);
  CHECK(again.skipped);
  CHECK(again.registered_names == r.registered_names);
  CHECK(lines.empty());

  // A damaged output: the stage runs again and says why.
  {
    std::ofstream damage(cam / "sparse" / "0" / "images.bin", std::ios::binary | std::ios::app);
    damage << "x";
  }
  const CameraStageResult third = stage_cameras(out.string(), p);
  CHECK(!third.skipped);
  REQUIRE(!lines.empty());
  CHECK(lines.front().find("running again: cameras/sparse/0/images.bin changed size") != std::string::npos);
  CHECK(third.registered_names.size() >= 8);

  // A given focal length is held: the chosen model carries it exactly.
  CameraStageParams given = p;
  given.focal_px = 0.9 * read_colmap_model((cam / "sparse" / "0").string()).cameras.begin()->second.params[0];
  const CameraStageResult fixed = stage_cameras(out.string(), given);
  CHECK(!fixed.skipped);
  CHECK(fixed.registered_names.size() >= 8);
  CHECK(std::abs(read_colmap_model((cam / "sparse" / "0").string()).cameras.begin()->second.params[0] -
                 given.focal_px) < 1e-6 * given.focal_px);
  const std::string estimate = text_of(cam / "estimate.json");
  CHECK(estimate.find("\"chosen_by\": \"given\"") != std::string::npos);
  WARN("cameras stage end to end: " << std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count()
                                    << " s, " << r.registered_names.size() << " of 10 registered");
}

TEST_CASE("cameras stage: feature counts from feature_extractor's log", "[pipeline][cameras]") {
  const std::string log =
      "colmap feature_extractor --database_path db\n"
      "Processed file [1/3]\n  Name:            001.jpg\n  Dimensions:      512 x 512\n  Features:        938\n"
      "Processed file [2/3]\n  Name:            002.jpg\n  Features:        12\n"
      "Processed file [3/3]\n  Name:            003.jpg\n  Features:        450\n"
      "Elapsed time: 0.1 [minutes]\n";
  CHECK(sift_feature_counts(log) == std::vector<int>{938, 12, 450});
  CHECK(sift_feature_counts("no counts here\nFeatures: none\n").empty());
}

// Sunflower gives the fewest SIFT features of the five recorded videos (about
// 220 a frame at COLMAP's default threshold), and at that threshold its 33
// frames under-rotated by 4-5 degrees with the focal length 3-4 % short: the
// stage extracts them again at the lower threshold.
TEST_CASE("cameras stage: sunflower's source frames alone give the all-frame model's arc and focal length, "
          "the same on every run",
          "[pipeline][cameras][data]") {
  const std::string video = "v3d/sunflower";
  if (!orbitforge_test::have_shared_data(video + "/sparse/0")) return;
  if (!orbitforge_test::have_programs({"colmap"})) return;
  TempDir t;
  CameraStageParams p;
  p.images = orbitforge_test::shared_path(video + "/images");
  p.frames = "1-33";
  p.threads = 2;
  p.log = [](const std::string&) {};
  const CameraStageResult r = stage_cameras((t.path() / "out").string(), p);
  REQUIRE(r.registered_names.size() == 33);
  const nlohmann::json estimate =
      nlohmann::json::parse(text_of(t.path() / "out" / "cameras" / "estimate.json"));
  CHECK(estimate.at("colmap").at("sift_peak_threshold") == p.sift_peak_threshold);
  // Its frames give few features at COLMAP's threshold, so they were extracted again.
  const nlohmann::json& features = estimate.at("colmap").at("features");
  CHECK(features.at("median_per_frame_at_colmap_default").get<double>() < p.sift_few_features);
  CHECK(features.at("threshold").get<double>() == p.sift_retry_threshold);
  // Every one of the 270 sequential pairs of 33 frames was matched.
  const nlohmann::json& matches = estimate.at("colmap").at("matches");
  CHECK(matches.at("pairs").get<int>() == 270);
  CHECK(matches.at("pairs_matched").get<int>() == 270);
  CHECK(matches.at("matches_before_verification").get<int>() > 270 * 15);

  const std::string user_model = (t.path() / "out" / "cameras" / "sparse" / "0").string();
  const std::string reference_model = orbitforge_test::shared_path(video + "/sparse/0");
  auto reference_cams = model_source_cameras(reference_model);
  REQUIRE(reference_cams.size() >= 33);
  reference_cams.resize(33);  // names sort in frame order: 001.jpg ... 033.jpg
  CHECK(reference_cams.back().name == "033.jpg");
  const OrbitFitScore user = orbit_fit_score(model_source_cameras(user_model), 33);
  const OrbitFitScore reference = orbit_fit_score(reference_cams, 33);
  REQUIRE(user.usable);
  REQUIRE(reference.usable);
  const double user_focal = read_colmap_model(user_model).cameras.begin()->second.params[0];
  const double reference_focal = read_colmap_model(reference_model).cameras.begin()->second.params[0];
  CHECK(std::abs(user.arc_deg - reference.arc_deg) <= 2.0);
  CHECK(std::abs(user_focal / reference_focal - 1) <= 0.05);
  WARN("sunflower, frames 1-33: arc " << user.arc_deg << " deg (all-frame model " << reference.arc_deg
                                      << "), focal " << user_focal << " px (" << reference_focal << "), "
                                      << r.seconds << " s");

  // A second run from scratch gives the same cameras, bit for bit: the matching
  // is exact and COLMAP's verification and mapper repeat on the same matches.
  // (COLMAP's own matcher gave a different focal length on most runs.)
  const CameraStageResult again = stage_cameras((t.path() / "again").string(), p);
  CHECK(!again.skipped);
  for (const char* f : {"cameras.bin", "images.bin", "points3D.bin"}) {
    INFO(f);
    CHECK(text_of(t.path() / "again" / "cameras" / "sparse" / "0" / f) ==
          text_of(t.path() / "out" / "cameras" / "sparse" / "0" / f));
  }
}

}  // namespace cameras_stage_test

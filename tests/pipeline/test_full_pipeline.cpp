// End-to-end pipeline on a tiny synthetic input (48x48, 73 orbit views, a few
// hundred iterations): coverage, outputs that exist and parse, R1 beating R0 on
// the held-out gap views with the oracle provider, resuming, the none and
// external providers, and bad inputs that leave earlier outputs intact.
#include <catch2/catch.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <stdexcept>
#include <string>
#include <vector>

#include "orbitforge/core/huge_pages.hpp"
#include "orbitforge/pipeline/pipeline.hpp"
#include "support/data.hpp"
#include "support/temp_dir.hpp"
#include "orbitforge/pipeline/inputs/colmap_input.hpp"
#include "orbitforge/pipeline/inputs/synthetic_pipeline_input.hpp"

using namespace orbitforge;
namespace fs = std::filesystem;

namespace {

#ifdef ORBITFORGE_TEST_QUICK
constexpr bool kQuick = true;
#else
constexpr bool kQuick = false;
#endif

struct Scratch : orbitforge_test::TempDir {
  Scratch() : orbitforge_test::TempDir("pipeline_test") {}
};

Scratch& scratch() {
  static Scratch s;
  return s;
}

SyntheticInputParams tiny_input(int source_frames = 33) {
  SyntheticInputParams sp;
  sp.width = sp.height = kQuick ? 32 : 48;
  sp.focal = 160.0 * sp.height / 128.0;
  sp.source_frames = source_frames;
  sp.object_gaussians = 1500;
  sp.ground_gaussians = 1000;
  return sp;
}

PipelineParams tiny_params() {
  PipelineParams p;
  p.orbit.views = 73;
  p.iters_g0 = p.iters_g1 = kQuick ? 60 : 500;
  p.init_points = kQuick ? 400 : 3000;
  p.median_samples = 16;
  p.train.field.width = 32;
  p.train.field.depth = 2;
  p.checkpoint_every = 100;
  p.threads = 2;
  p.progress = false;
  p.completion = "oracle";
  p.static_proxy_diagnostics = true;  // opt-in; these runs cover the stage
  return p;
}

// Every 8th source frame withheld, as the audit does.
const PipelineInput<float>& tiny_input_data() {
  static const PipelineInput<float> in = [] {
    PipelineInput<float> i = synthetic_pipeline_input<float>(tiny_input(), 2);
    withhold_every(i, 8);
    return i;
  }();
  return in;
}

// The oracle run also trains the two comparisons.
PipelineParams oracle_params() {
  PipelineParams p = tiny_params();
  p.compare_g1_paper = true;
  p.oracle_bound = true;
  return p;
}

// The oracle run every other test starts from (run once).
const fs::path& oracle_run() {
  static fs::path dir;
  if (dir.empty()) {
    dir = scratch().path() / "oracle";
    run_pipeline(tiny_input_data(), oracle_params(), dir.string());
  }
  return dir;
}

nlohmann::json parse_file(const fs::path& p) {
  INFO(p.string());
  REQUIRE(fs::exists(p));
  return nlohmann::json::parse(read_file_bytes(p.string()));
}

void copy_run(const fs::path& from, const fs::path& to) {
  fs::remove_all(to);
  fs::copy(from, to, fs::copy_options::recursive);
}

// A copy of the oracle run that forgets G1 (its record and outputs), as if the
// run had never reached it, then is interrupted halfway between G1's first and
// second partial checkpoints. Returns the run's parameters.
PipelineParams interrupt_g1(const fs::path& dir) {
  copy_run(oracle_run(), dir);
  fs::remove(dir / "stages" / "g1.json");
  fs::remove(dir / "final.ply");
  fs::remove(dir / "final.spz");
  fs::remove_all(dir / "g1");
  fs::remove_all(dir / "R1");
  PipelineParams p = oracle_params();
  p.checkpoint_every = kQuick ? 20 : 100;  // not part of any stage key
  const int stop_at = p.checkpoint_every + p.checkpoint_every / 2;
  p.on_iteration = [stop_at](const std::string& label, int it) {
    if (label == "G1" && it == stop_at) throw std::runtime_error("interrupted");
  };
  REQUIRE_THROWS_WITH(run_pipeline(tiny_input_data(), p, dir.string()), "interrupted");
  return p;
}

}  // namespace

TEST_CASE("pipeline: oracle run writes every output, coverage closes, R1 beats R0 in the gap", "[pipeline][full]") {
  const fs::path& dir = oracle_run();
  const int views = 73;

  // orbit.json
  const auto orbit = parse_file(dir / "orbit.json");
  REQUIRE(orbit.at("cameras").size() == std::size_t(views));
  REQUIRE(orbit.at("layout").at("frames").get<int>() == 73);  // 8m + 1

  // Scenes and checkpoints.
  for (const char* ply : {"gmed0.ply", "final.ply"}) {
    const auto s = read_ply<float>((dir / ply).string());
    CHECK(s.size() > 100);
  }
  {  // final.spz: the same scene, quantised (means on the format's 1/4096 grid)
    const auto ply = read_ply<float>((dir / "final.ply").string());
    const auto spz = read_spz<float>((dir / "final.spz").string());
    REQUIRE(spz.size() == ply.size());
    CHECK(spz.sh_degree == ply.sh_degree);
    for (std::size_t i = 0; i < ply.means.size(); i += 97)
      CHECK(std::abs(spz.means[i] - ply.means[i]) <= 0.5f / 4096 + 1e-5f * std::abs(ply.means[i]));
    CHECK(fs::file_size(dir / "final.spz") * 4 < fs::file_size(dir / "final.ply"));
  }
  for (const char* ck : {"g0/checkpoint.bin", "g1/checkpoint.bin", "g1_paper/checkpoint.bin", "bound/checkpoint.bin"}) {
    INFO(ck);
    REQUIRE(fs::exists(dir / ck));
    CHECK(fs::file_size(dir / ck) > 1000);
    CHECK_FALSE(fs::exists(dir / fs::path(ck).parent_path() / "partial.bin"));
  }
  // R0 / R1 frames: every canonical view, at the working size.
  for (const char* seq : {"R0", "R1"}) {
    for (int v = 0; v < views; v += 12) {
      const auto img = read_image<float>((dir / seq / pipeline_detail::view_file(v)).string());
      CHECK(img.width == tiny_input().width);
      CHECK(img.height == tiny_input().height);
    }
    CHECK(fs::exists(dir / seq / pipeline_detail::view_file(views - 1)));
  }
  // V_hat and the pictures.
  const auto vhat = parse_file(dir / "vhat.json");
  REQUIRE(vhat.at("frames").size() > 10);
  for (const char* pic : {"contact_sheet.png", "support_mask.png", "top_view.png"}) {
    const auto img = read_image<float>((dir / pic).string());
    CHECK(img.width > 100);
  }
  CHECK(fs::file_size(dir / "report.md") > 200);

  // report.json: the names scripts read.
  const auto r = parse_file(dir / "report.json");
  for (const char* s : {"orbit", "g0", "completion", "g1", "report"}) {
    INFO(s);
    REQUIRE(r.at("stages").contains(s));
    CHECK(r["stages"][s].get<double>() >= 0);
  }
  // Recorded cameras: G1 trains at them; only cameras the method estimated are estimated again.
  CHECK_FALSE(r.at("stages").contains("recalibrate"));
  CHECK_FALSE(fs::exists(dir / "recalibrate"));
  CHECK_FALSE(r.at("cameras").contains("recalibrated"));
  CHECK(r.at("total_seconds").get<double>() > 0);
  for (const char* k : {"R0", "R1"})
    for (const char* f : {"A", "M", "closed"}) REQUIRE(r.at("coverage").at(k).contains(f));
  REQUIRE(r.at("diagnostics").contains("cameras_used"));
  for (const char* k : {"R0", "R1", "R1_paper", "bound"})
    for (const char* s : {"supported_train", "supported_heldout", "gap_heldout"})
      for (const char* f : {"psnr", "ssim", "views"}) REQUIRE(r.at("quality").at(k).at(s).contains(f));
  for (const char* s : {"g1_paper", "bound"}) CHECK(r.at("comparison_seconds").at(s).get<double>() > 0);
  CHECK(r.at("background").at("color") == nlohmann::json::array({0, 0, 0}));  // the synthetic frames' black borders
  REQUIRE(r.at("completion").contains("loop_endpoint_l1"));
  // What each reconstruction's levers decided: the still check is off by default.
  for (const char* s : {"g0", "g1", "g1_paper", "bound"}) {
    INFO(s);
    REQUIRE(r.at("training").contains(s));
    CHECK(r["training"][s].at("iterations").get<int>() == tiny_params().iters_g0);
    CHECK(r["training"][s].at("still_check").is_null());
    CHECK_FALSE(r["training"][s].at("plateau_stopped").get<bool>());
    // Where the training time went: every phase timed, and the renderer's
    // stages within its wall time.
    const nlohmann::json& t = r["training"][s].at("timing");
    REQUIRE(t.is_object());
    CHECK(t.at("iterations").get<int>() == tiny_params().iters_g0);
    double phases = 0;
    for (const char* phase : {"projection", "sort_and_binning", "rasterization", "loss", "rasterization_backward",
                              "projection_backward", "deformation_field", "adam", "densification", "other"}) {
      INFO(phase);
      CHECK(t.at(phase).get<double>() >= 0);
      phases += t.at(phase).get<double>();
    }
    CHECK(t.at("rasterization").get<double>() > 0);
    CHECK(t.at("rasterization_backward").get<double>() > 0);
    CHECK(phases <= 1.001 * t.at("wall").get<double>());
  }
  REQUIRE(r.at("completion").contains("temporal_trace"));
  REQUIRE(r.at("completion").contains("anchor_index_error"));
  CHECK(r["completion"]["anchor_index_error"]["max"].get<double>() == 0);

  // Static-proxy diagnostics of G0: three variants along views 0 .. 71 (72 repeats 0).
  const auto sp = parse_file(dir / "static_proxy.json");
  REQUIRE(r.contains("static_proxy"));
  CHECK(r["static_proxy"] == sp);
  CHECK(r.at("stages").contains("static_proxy"));
  if (!kQuick || !sp.contains("note")) {
    CHECK(sp.at("views_scored").get<int>() == views - 1);
    for (const char* v : {"frame_varying", "fixed_slice", "median"})
      for (const char* f : {"adjacent_l1", "adjacent_l1_p95", "loop_l1"}) {
        INFO(v << " " << f);
        const double x = sp.at("variants").at(v).at(f).get<double>();
        CHECK(std::isfinite(x));
        CHECK(x > 0);    // consecutive views differ
        CHECK(x < 100);  // and not by noise-level amounts at 5-degree steps
      }
    // P95 over pairs is at least the mean of a non-negative sample's upper tail.
    CHECK(sp["variants"]["median"]["adjacent_l1_p95"].get<double>() >=
          sp["variants"]["median"]["adjacent_l1"].get<double>() * 0.999);
  }

  // Coverage: the 33 source frames cover 33/90 of 352 degrees (~125); R1 adds the
  // recorded gap frames (up to 348 degrees) and closes the orbit.
  const double a0 = r["coverage"]["R0"]["A"].get<double>();
  CHECK(a0 > 110);
  CHECK(a0 < 140);
  CHECK_FALSE(r["coverage"]["R0"]["closed"].get<bool>());
  CHECK(r["coverage"]["R1"]["A"].get<double>() > 330);
  CHECK(r["coverage"]["R1"]["M"].get<double>() > 0.9);
  CHECK(r["coverage"]["R1"]["closed"].get<bool>());
  CHECK(r["coverage"]["R0"]["rendered"]["closed"].get<bool>());

  // Held-out gap frames: odd 1-based indices among 34..90 whose cameras fall in the gap.
  const int held = r["quality"]["R0"]["gap_heldout"]["views"].get<int>();
  CHECK(held >= 20);
  CHECK(held <= 29);
  CHECK(r["quality"]["R0"]["supported_train"]["views"].get<int>() == 29);  // 33 minus frames 8, 16, 24, 32
  CHECK(r["quality"]["R0"]["supported_heldout"]["views"].get<int>() == 4);
  // Each row lists its views: one entry per scored view, distinct frames, and the
  // row's PSNR is their mean.
  for (const char* k : {"R0", "R1"})
    for (const char* s : {"supported_train", "supported_heldout", "gap_heldout"}) {
      INFO(k << " " << s);
      const nlohmann::json& row = r["quality"][k][s];
      const nlohmann::json& views = row.at("per_view");
      REQUIRE(views.size() == row["views"].get<std::size_t>());
      std::set<std::string> names;
      double sum = 0;
      for (const auto& v : views) {
        names.insert(v.at("frame").get<std::string>());
        sum += v.at("psnr").get<double>();
      }
      CHECK(names.size() == views.size());
      CHECK(sum / double(views.size()) == Approx(row["psnr"].get<double>()).epsilon(1e-12));
    }
  if (!kQuick) {
    const double g0 = r["quality"]["R0"]["gap_heldout"]["psnr"].get<double>();
    const double g1 = r["quality"]["R1"]["gap_heldout"]["psnr"].get<double>();
    INFO("gap PSNR R0 " << g0 << " R1 " << g1);
    CHECK(g1 > g0 + 2.0);
    CHECK(r["quality"]["R0"]["supported_train"]["psnr"].get<double>() > 18);
  }
}

TEST_CASE("pipeline: no held-out frame reaches G1, the paper-data G1 or the bound, for every provider",
          "[pipeline][honest]") {
  const fs::path& ref = oracle_run();
  const auto& in = tiny_input_data();
  for (const char* provider : {"oracle", "perturbed", "perturbed-geometric", "none", "external"}) {
    INFO(provider);
    fs::path dir = ref;
    PipelineParams p = oracle_params();
    if (std::string(provider) != "oracle") {
      dir = scratch().path() / (std::string("honest_") + provider);
      copy_run(ref, dir);
      p.completion = provider;
      p.iters_g1 = kQuick ? 20 : 60;
      if (std::string(provider) == "external") {
        REQUIRE_THROWS_AS(run_pipeline(in, p, dir.string()), PipelineStopped);
        const auto m = parse_file(dir / "completion_request" / "manifest.json");
        const auto s2c = m.at("synthetic_to_canonical").get<std::vector<int>>();
        for (std::size_t j = 0; j < s2c.size(); ++j)
          fs::copy_file(dir / "R0" / pipeline_detail::view_file(s2c[j]),
                        dir / "completion_request" / "completed" / pipeline_detail::view_file(int(j)),
                        fs::copy_options::overwrite_existing);
      }
    }
    PipelineRun<float> state;
    const auto r = run_pipeline(in, p, dir.string(), nullptr, &state);
    // The held-out frames, from frame numbers alone (not from the library's gap
    // selection): every odd-numbered frame after the source, and every 8th frame
    // of the source range. Checked by name and by the hash of their pixels.
    std::vector<std::string> held, held_hashes;
    for (std::size_t i = 0; i < in.cameras.size(); ++i) {
      const int number = int(i) + 1;
      const bool after_source = int(i) > in.source_last && number % 2 == 1;
      const bool withheld = int(i) >= in.source_first && int(i) <= in.source_last && (number - in.source_first) % 8 == 0;
      if (!after_source && !withheld) continue;
      held.push_back(in.cameras[i].name);
      const auto& img = in.images[i].data;
      held_hashes.push_back(hex64(fnv1a(img.data(), img.size() * sizeof(float))));
    }
    REQUIRE(held.size() >= 24);
    REQUIRE(r.at("frames").at("withheld").size() == 4);
    for (const auto& n : r.at("frames").at("withheld"))
      CHECK(std::find(held.begin(), held.end(), n.get<std::string>()) != held.end());
    (void)state;
    std::vector<std::string> lists = {"vhat.json", "g0/frames.json", "g1/frames.json", "g1_paper/frames.json",
                                      "bound/frames.json"};
    for (const auto& list : lists) {
      if (!fs::exists(dir / list)) {
        CHECK(std::string(provider) == "none");  // no second reconstruction to train
        continue;
      }
      const auto j = parse_file(dir / list);
      std::size_t n = 0;
      for (const auto& f : j.at("frames")) {
        const std::string origin = f.contains("origin") ? f.at("origin").get<std::string>() : f.at("name").get<std::string>();
        if (f.contains("image_hash"))
          CHECK(std::find(held_hashes.begin(), held_hashes.end(), f.at("image_hash").get<std::string>()) ==
                held_hashes.end());
        ++n;
        // "source 012.png", "recorded 046.png", "perturbed recorded 046.png", "R0 view 3",
        // "completed 0016.png" (a synthetic index, not a recorded frame).
        const std::string name = origin.substr(origin.rfind(' ') + 1);
        const bool recorded = origin.rfind("completed ", 0) != 0 && origin.rfind("R0 view", 0) != 0;
        INFO(list << ": " << origin);
        if (recorded) CHECK(std::find(held.begin(), held.end(), name) == held.end());
      }
      CHECK(n > 0);
    }
  }
}

TEST_CASE("pipeline: G1 that keeps the source beats the paper's V_hat-only G1 on withheld source frames",
          "[pipeline][g1]") {
  if (kQuick) return;  // needs the full tiny budget to separate the two
  const auto r = parse_file(oracle_run() / "report.json");
  const double def = r["quality"]["R1"]["supported_heldout"]["psnr"].get<double>();
  const double paper = r["quality"]["R1_paper"]["supported_heldout"]["psnr"].get<double>();
  const double r0 = r["quality"]["R0"]["supported_heldout"]["psnr"].get<double>();
  INFO("withheld-frame PSNR: R0 " << r0 << ", R1 (source + completion) " << def << ", R1 paper-data " << paper);
  CHECK(def > paper + 0.5);
  // The bound (perfect completion) sees what G1 sees with the oracle provider.
  CHECK(r["quality"]["bound"]["gap_heldout"]["psnr"].get<double>() > r["quality"]["R0"]["gap_heldout"]["psnr"].get<double>());
}

// A model far from its origin and 100 times larger: the run works in the
// normalised frame (here exactly the tiny input's), so it trains the same model;
// its files are in the model's frame, positions in float64.
TEST_CASE("pipeline: a far, rescaled model trains as the normalised one, files in the model's frame",
          "[pipeline][frame]") {
  PipelineParams p = tiny_params();
  p.iters_g0 = p.iters_g1 = 60;
  p.checkpoint_every = 0;
  p.static_proxy_diagnostics = false;
  PipelineInput<float> far = tiny_input_data();
  far.frame.origin = Eigen::Vector3d(1e5, -7e4, 5e4);
  far.frame.scale = 0.01;
  REQUIRE(far.frame.far_from_origin());
  const fs::path near_dir = scratch().path() / "frame_near", far_dir = scratch().path() / "frame_far";
  const auto rn = run_pipeline(tiny_input_data(), p, near_dir.string());
  const auto rf = run_pipeline(far, p, far_dir.string());

  // The same quality, view for view.
  for (const char* k : {"R0", "R1"})
    for (const char* set : {"supported_train", "supported_heldout", "gap_heldout"}) {
      CAPTURE(k, set);
      CHECK(rf.at("quality").at(k).at(set).at("psnr").get<double>() ==
            Approx(rn.at("quality").at(k).at(set).at("psnr").get<double>()).margin(1e-3));
    }
  CHECK(rf.at("frame").at("scale").get<double>() == 0.01);
  CHECK_FALSE(rn.contains("frame"));

  // gmed0.ply and final.ply: the near run's scenes moved to the model's frame.
  // Gmed0 is the same to float rounding; G1 reads V_hat's cameras back from
  // vhat.json, whose rotations are written orthonormal in double (one float step
  // from the near run's), so its scene differs by a little more.
  for (const char* ply : {"gmed0.ply", "final.ply"}) {
    CAPTURE(ply);
    const auto near_scene = read_ply<double>((near_dir / ply).string());
    const auto far_scene = read_ply<double>((far_dir / ply).string());
    REQUIRE(far_scene.size() == near_scene.size());
    CHECK(read_file_bytes((far_dir / ply).string()).find("property double x") != std::string::npos);
    double mean_error = 0, log_scale_error = 0, log_scale_sum = 0;  // in the normalised frame
    for (std::size_t i = 0; i < near_scene.means.size(); ++i)
      mean_error = std::max(mean_error,
                            std::abs((far_scene.means[i] - far.frame.origin[long(i % 3)]) * 0.01 - near_scene.means[i]));
    for (std::size_t i = 0; i < near_scene.log_scales.size(); ++i) {
      const double e = std::abs(far_scene.log_scales[i] + std::log(0.01) - near_scene.log_scales[i]);
      log_scale_error = std::max(log_scale_error, e);
      log_scale_sum += e;
    }
    const double log_scale_mean = log_scale_sum / double(std::max<std::size_t>(1, near_scene.log_scales.size()));
    const bool g1 = std::string(ply) == "final.ply";
    CAPTURE(mean_error, log_scale_error, log_scale_mean);
    CHECK(mean_error < (g1 ? 1e-4 : 1e-6));  // the scene is about 2 units across
    // G1's training amplifies the cameras' one float step in a few Gaussians
    // (the largest log-scale difference, 1.9e-3, is 0.2 % of one Gaussian's
    // size, where the mean is 7e-7): the mean pins the model, the maximum only
    // bounds the outliers.
    CHECK(log_scale_mean < (g1 ? 1e-5 : 1e-6));
    CHECK(log_scale_error < (g1 ? 1e-2 : 1e-5));
  }

  // orbit.json: lengths and camera centres in the model's frame, angles unchanged.
  const auto on = parse_file(near_dir / "orbit.json"), of = parse_file(far_dir / "orbit.json");
  CHECK(of["orbit"]["radius"].get<double>() == Approx(on["orbit"]["radius"].get<double>() / 0.01).epsilon(1e-6));
  for (int a = 0; a < 3; ++a)
    CHECK(of["orbit"]["center"][a].get<double>() ==
          Approx(on["orbit"]["center"][a].get<double>() / 0.01 + far.frame.origin[a]).margin(1e-6));
  for (int v : {0, 36}) {
    const auto& cn = on["cameras"][v];
    const auto& cf = of["cameras"][v];
    CHECK(cf["azimuth_deg"] == cn["azimuth_deg"]);
    Eigen::Matrix3d Rn, Rf;
    Eigen::Vector3d tn, tf;
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) {
        Rn(r, c) = cn["R"][r][c].get<double>();
        Rf(r, c) = cf["R"][r][c].get<double>();
      }
      tn[r] = cn["t"][r].get<double>();
      tf[r] = cf["t"][r].get<double>();
    }
    CHECK((Rf - Rn).cwiseAbs().maxCoeff() < 1e-6);
    CHECK((Rf.transpose() * Rf - Eigen::Matrix3d::Identity()).cwiseAbs().maxCoeff() < 1e-14);
    // The centre a reader computes, 1.3e5 out, against the near run's moved back.
    const Eigen::Vector3d centre_near = -Rn.transpose() * tn, centre_far = -Rf.transpose() * tf;
    CHECK((centre_far - (centre_near / 0.01 + far.frame.origin)).norm() < 1e-4);
  }
}

TEST_CASE("pipeline: a second run skips every stage and changes nothing", "[pipeline][resume]") {
  const fs::path& dir = oracle_run();
  const auto before = read_file_bytes((dir / "report.json").string());
  const auto t_before = fs::last_write_time(dir / "final.ply");
  PipelineRun<float> state;
  // Spelled differently: the invocation is a record only, in no stage key.
  PipelineParams again = oracle_params();
  again.invocation = {"full_pipeline --config settings.toml", "iters = 60\n"};
  const auto r = run_pipeline(tiny_input_data(), again, dir.string(), nullptr, &state);
  CHECK(state.ran.empty());
  CHECK(state.skipped.size() == 8);
  CHECK(read_file_bytes((dir / "report.json").string()) == before);
  CHECK(fs::last_write_time(dir / "final.ply") == t_before);
  CHECK(r.at("coverage") == nlohmann::json::parse(before).at("coverage"));

  // A changed G1 setting re-runs G1 and the report only.
  const fs::path copy = scratch().path() / "resume_copy";
  copy_run(dir, copy);
  PipelineParams p = tiny_params();
  p.iters_g1 = kQuick ? 20 : 40;
  p.invocation = {"full_pipeline --iters-g1 40 --out 'resume copy'", "iters-g1=40\n", huge_page_state()};
  PipelineRun<float> s2;
  const auto r2 = run_pipeline(tiny_input_data(), p, copy.string(), nullptr, &s2);
  CHECK(s2.ran == std::vector<std::string>{"g1", "report"});
  // The report the run wrote records its invocation as given.
  CHECK(r2.at("invocation").at("command") == p.invocation.command);
  CHECK(r2.at("invocation").at("settings") == p.invocation.settings);
  CHECK(r2.at("invocation").at("memory_pages") == p.invocation.memory_pages);
  CHECK_FALSE(p.invocation.memory_pages.empty());
  CHECK(parse_file(copy / "report.json").at("invocation") == r2.at("invocation"));
  CHECK_FALSE(nlohmann::json::parse(before).contains("invocation"));  // none given: none recorded
  CHECK(s2.skipped == std::vector<std::string>{"orbit", "g0", "static_proxy", "completion"});
}

TEST_CASE("pipeline: an interrupted run resumes from its partial checkpoint and ends as an uninterrupted one",
          "[pipeline][resume]") {
  const fs::path& ref = oracle_run();
  const fs::path dir = scratch().path() / "interrupted";
  PipelineParams p = interrupt_g1(dir);
  CHECK(fs::exists(dir / "g1" / "partial.bin"));
  CHECK_FALSE(fs::exists(dir / "final.ply"));
  CHECK(read_file_bytes((dir / "gmed0.ply").string()) == read_file_bytes((ref / "gmed0.ply").string()));

  int first = -1;
  p.on_iteration = [&first](const std::string& label, int it) {
    if (label == "G1" && first < 0) first = it;
  };
  PipelineRun<float> state;
  run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  // G1 reruns; the report's key (G1's settings and inputs) is unchanged, so the
  // report from before counts as current, rightly: final.ply comes out the same.
  CHECK(state.ran == std::vector<std::string>{"g1"});
  CHECK(first == p.checkpoint_every + 1);  // resumed after the last partial checkpoint
  CHECK_FALSE(fs::exists(dir / "g1" / "partial.bin"));
  // Checkpoints hold the optimizer, densification statistics and random state:
  // the resumed G1 is the uninterrupted one, bit for bit.
  CHECK(read_file_bytes((dir / "final.ply").string()) == read_file_bytes((ref / "final.ply").string()));
}

// A partial checkpoint with damaged bytes (0xFF over part of it: NaN parameters
// that would parse) is refused by its checksum with a message, and G1 trains from
// the start: the result is the uninterrupted one.
TEST_CASE("pipeline: a damaged partial checkpoint is not resumed", "[pipeline][resume]") {
  const fs::path& ref = oracle_run();
  const fs::path dir = scratch().path() / "damaged_partial";
  PipelineParams p = interrupt_g1(dir);
  const fs::path partial = dir / "g1" / "partial.bin";
  REQUIRE(fs::exists(partial));
  std::string bytes = read_file_bytes(partial.string());
  for (std::size_t i = bytes.size() / 2; i < bytes.size() / 2 + 256 && i < bytes.size(); ++i) bytes[i] = char(0xFF);
  write_file_atomic(partial.string(), bytes);

  int first = -1;
  p.on_iteration = [&first](const std::string& label, int it) {
    if (label == "G1" && first < 0) first = it;
  };
  PipelineRun<float> state;
  std::vector<std::string> log;
  state.log = [&log](const std::string& line) { log.push_back(line); };
  run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  CHECK(first == 1);  // trained from the start, not from the damaged state
  bool said = false;
  for (const auto& line : log)
    said = said || (line.find("partial.bin not usable") != std::string::npos &&
                    line.find("checksum mismatch") != std::string::npos);
  CHECK(said);
  CHECK(read_file_bytes((dir / "final.ply").string()) == read_file_bytes((ref / "final.ply").string()));
}

TEST_CASE("pipeline: none provider reuses R0", "[pipeline][none]") {
  const fs::path dir = scratch().path() / "none";
  copy_run(oracle_run(), dir);
  PipelineParams p = tiny_params();
  p.completion = "none";
  PipelineRun<float> state;
  const auto r = run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  CHECK(state.skipped == std::vector<std::string>{"orbit", "g0", "static_proxy"});
  CHECK(r.at("training").contains("g0"));
  CHECK_FALSE(r["training"].contains("g1"));  // G1 did not train: the oracle run's record is not reported
  CHECK(r["coverage"]["R1"]["A"] == r["coverage"]["R0"]["A"]);
  CHECK(read_file_bytes((dir / "final.ply").string()) == read_file_bytes((dir / "gmed0.ply").string()));
  CHECK(r["quality"]["R1"]["gap_heldout"]["psnr"].get<double>() ==
        Approx(r["quality"]["R0"]["gap_heldout"]["psnr"].get<double>()));
}

TEST_CASE("pipeline: view-fitted scores re-run the report only, and add rows beside the plain ones",
          "[pipeline][report]") {
  const fs::path dir = scratch().path() / "view_fitted";
  copy_run(oracle_run(), dir);
  const auto plain = parse_file(dir / "report.json");
  PipelineParams p = oracle_params();
  p.score_view_fitted = true;
  PipelineRun<float> state;
  const auto r = run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  CHECK(state.ran == std::vector<std::string>{"report"});
  for (const char* k : {"R0", "R1"}) {
    INFO(k);
    const auto& q = r["quality"][k];
    CHECK(q["gap_heldout"] == plain["quality"][k]["gap_heldout"]);  // the plain row is unchanged
    const auto& f = q["gap_heldout_view_fitted"];
    REQUIRE(f.is_object());
    CHECK(f["views"] == q["gap_heldout"]["views"]);
    const auto& fit = f["view_fit"];
    CHECK(fit["fitted_views"].get<int>() <= f["views"].get<int>());
    CHECK(fit["turn_max_deg"].get<double>() <= fit["limits"]["turn_deg"].get<double>());
    CHECK(fit["zoom_change_max"].get<double>() <= fit["limits"]["zoom_change"].get<double>());
    // A fit is kept only where it lowers the error: the score cannot fall by more
    // than the pixels the fit brings in from outside the overlap it was judged on.
    CHECK(f["psnr"].get<double>() > q["gap_heldout"]["psnr"].get<double>() - 0.2);
    CHECK_FALSE(q.contains("supported_heldout_at_reference_view_fitted"));  // no reference here
  }
  CHECK(read_file_bytes((dir / "report.md").string()).find("turned and zoomed about its centre") != std::string::npos);
  // Evaluation, not the method: its time is kept out of the report stage's.
  CHECK(r["comparison_seconds"]["view_fitted_scoring"].get<double>() > 0);
}

TEST_CASE("pipeline: the still check's figures and decision are in report.json", "[pipeline][levers]") {
  const fs::path dir = scratch().path() / "still_check";
  PipelineParams p = tiny_params();
  p.completion = "none";
  p.static_proxy_diagnostics = false;
  p.train.still_check_iterations = p.iters_g0 / 4;
  PipelineRun<float> state;
  const auto r = run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  const nlohmann::json& c = r.at("training").at("g0").at("still_check");
  REQUIRE(c.is_object());
  const TrainParams defaults;
  CHECK(c.at("thresholds_db").at("gain").get<double>() == defaults.still_gain_db);
  CHECK(c.at("thresholds_db").at("region_gain").get<double>() == defaults.still_region_gain_db);
  const double gain = c.at("gain_db").get<double>(), region = c.at("region_gain_db").get<double>();
  CHECK(std::isfinite(gain));
  CHECK(std::isfinite(region));
  const bool bake = gain < defaults.still_gain_db && region < defaults.still_region_gain_db;
  CHECK(c.at("decision").get<std::string>() == (bake ? "baked" : "kept"));
  CHECK(c.at("region").size() == 2);
  CHECK(c.at("iteration").get<int>() > p.train.still_check_iterations);
  // The stage's file says the same, and a second run reads it back unchanged.
  CHECK(parse_file(dir / "g0" / "training.json").at("still_check") == c);
  const auto again = run_pipeline(tiny_input_data(), p, dir.string());
  CHECK(again.at("training").at("g0") == r.at("training").at("g0"));
}

TEST_CASE("pipeline: the plateau stop on G0 only leaves G1 its whole budget", "[pipeline][levers]") {
  PipelineParams p = tiny_params();
  p.static_proxy_diagnostics = false;
  // A quiet span (no densification, no still check) a few passes long, so that
  // both stages could stop.
  p.train.densify = false;
  p.train.still_check_iterations = 0;
  p.iters_g0 = p.iters_g1 = std::max(p.iters_g0, 150);
  p.train.plateau_window = 1;       // one pass over the frames
  p.train.plateau_tolerance = 1e9;  // the second window after the quiet span starts ends training
  for (const bool g1 : {true, false}) {
    INFO("plateau_g1 " << g1);
    p.plateau_g1 = g1;
    const fs::path dir = scratch().path() / (g1 ? "plateau_both" : "plateau_g0");
    const auto r = run_pipeline(tiny_input_data(), p, dir.string());
    CHECK(r.at("settings").at("plateau_g1").get<bool>() == g1);
    const nlohmann::json& g0 = r.at("training").at("g0");
    CHECK(g0.at("plateau_stopped").get<bool>());
    CHECK(g0.at("iterations").get<int>() < p.iters_g0);
    const nlohmann::json& g1_record = r.at("training").at("g1");
    CHECK(g1_record.at("plateau_stopped").get<bool>() == g1);
    CHECK((g1_record.at("iterations").get<int>() < p.iters_g1) == g1);
  }
}

// The paper's protocol on a square source: the canonical views are wider than
// the source frames (same focal), so the oracle's completion frames (recorded,
// square) and R0's arc renders (wide) differ in shape inside V_hat and G1.
TEST_CASE("pipeline: canonical views wider than a square source (oracle V_hat and G1, external anchors)", "[pipeline][protocol]") {
  const fs::path dir = scratch().path() / "wide";
  PipelineParams p = tiny_params();
  p.iters_g0 = p.iters_g1 = 60;
  p.init_points = 400;
  p.static_proxy_diagnostics = false;
  p.g1_data = G1Data::paper;  // G1 trains on both shapes
  const int w = tiny_input().width, h = tiny_input().height;
  p.canonical_width = w * 7 / 4;
  p.canonical_height = h;
  const auto r = run_pipeline(tiny_input_data(), p, dir.string());

  const auto r1 = read_image<float>((dir / "R1" / pipeline_detail::view_file(0)).string());
  CHECK(r1.width == p.canonical_width);
  CHECK(r1.height == h);
  const auto vhat = parse_file(dir / "vhat.json");
  std::set<std::pair<int, int>> shapes;
  for (const auto& f : vhat.at("frames")) {
    const auto img = read_image<float>((dir / f.at("file").get<std::string>()).string());
    shapes.insert({img.width, img.height});
  }
  CHECK(shapes == std::set<std::pair<int, int>>{{w, h}, {p.canonical_width, h}});
  // The loop seam is scored on the view both endpoint frames share (the square
  // centre of the wide one); the content trace on the same centre crops.
  const auto& c = r.at("completion");
  const double loop = c.at("loop_endpoint_l1").get<double>();
  CHECK(std::isfinite(loop));
  CHECK(loop < 60);
  const auto& trace = c.at("completion_trace");
  REQUIRE(trace.is_object());
  CHECK(trace.at("matched_views").size() > 10);
  CHECK(std::isfinite(r["quality"]["R1"]["gap_heldout"]["psnr"].get<double>()));

  // The external request: square anchors in a wide clip say which box they show.
  p.completion = "external";
  REQUIRE_THROWS_AS(run_pipeline(tiny_input_data(), p, dir.string()), PipelineStopped);
  const auto m = parse_file(dir / "completion_request" / "manifest.json");
  CHECK(m.at("width").get<int>() == p.canonical_width);
  REQUIRE(m.at("anchors").size() >= 2);
  for (const auto& a : m.at("anchors")) {
    CHECK(a.at("width").get<int>() == w);
    CHECK(a.at("height").get<int>() == h);
    const auto box = a.at("covers").get<std::vector<double>>();
    REQUIRE(box.size() == 4);
    CHECK(box[0] == Approx((p.canonical_width - w) / 2.0));
    CHECK(box[2] - box[0] == Approx(w));
    CHECK(box[1] == 0);
    CHECK(box[3] == h);
  }
}

TEST_CASE("pipeline: external provider writes the request, stops, and resumes with completed frames",
          "[pipeline][external]") {
  const fs::path dir = scratch().path() / "external";
  copy_run(oracle_run(), dir);
  PipelineParams p = tiny_params();
  p.completion = "external";
  p.iters_g1 = kQuick ? 20 : 60;
  const std::string report_before = read_file_bytes((dir / "report.json").string());
  REQUIRE_THROWS_AS(run_pipeline(tiny_input_data(), p, dir.string()), PipelineStopped);
  CHECK(read_file_bytes((dir / "report.json").string()) == report_before);  // earlier outputs intact
  const auto m = parse_file(dir / "completion_request" / "manifest.json");
  const int frames = m.at("frames").get<int>();
  CHECK(frames == 73);
  CHECK((frames - 1) % 8 == 0);
  REQUIRE(m.at("synthetic_to_canonical").size() == std::size_t(frames));
  REQUIRE(m.at("anchors").size() >= 2);
  CHECK(m.at("anchors")[0].at("synthetic").get<int>() ==
        (m.at("synthetic_to_canonical").get<std::vector<int>>()[0] == 0 ? 0 : frames - 1 - m.at("start").get<int>()));
  for (const auto& c : m.at("conditioning")) CHECK(fs::exists(dir / "completion_request" / c.at("file").get<std::string>()));
  for (const auto& a : m.at("anchors")) CHECK(fs::exists(dir / "completion_request" / a.at("file").get<std::string>()));
  CHECK(m.at("prompt").get<std::string>().size() > 10);

  // A "video model": every synthetic frame = the R1 render of the view it shows.
  const auto s2c = m.at("synthetic_to_canonical").get<std::vector<int>>();
  for (int j = 0; j < frames; ++j)
    fs::copy_file(dir / "R1" / pipeline_detail::view_file(s2c[std::size_t(j)]),
                  dir / "completion_request" / "completed" / pipeline_detail::view_file(j),
                  fs::copy_options::overwrite_existing);
  PipelineRun<float> state;
  const auto r = run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  CHECK(state.ran == std::vector<std::string>{"completion", "g1", "report"});
  CHECK(r["completion_provider"] == "external");
  // V_hat: one frame per canonical view 0 .. N-1 (arc from R0, gap from the clip).
  const auto vhat = parse_file(dir / "vhat.json");
  CHECK(vhat.at("frames").size() == 73);
  CHECK(r["coverage"]["R1"]["closed"].get<bool>());
  CHECK(r["completion"]["temporal_trace"]["reversals"].get<int>() == 0);

  // A video model that stalls and turns back: frames repeated, then a stretch
  // played backwards. The requested cameras cannot show it; the pixels do.
  std::vector<int> gap;  // synthetic indices of the gap frames, in the clip's order
  for (const auto& f : vhat.at("frames"))
    if (f.at("kind") == "completion") gap.push_back(std::stoi(f.at("origin").get<std::string>().substr(10, 4)));
  std::sort(gap.begin(), gap.end());
  REQUIRE(gap.size() >= 24);
  std::vector<int> expected;  // canonical view each gap frame now shows
  for (std::size_t i = 0; i < gap.size(); ++i) {
    std::size_t k = i;
    if (i >= 4 && i < 8) k = 4;             // a stall: four copies of one frame
    if (i >= 12 && i < 18) k = 12 - (i - 12);  // a reversal: back over six frames
    if (i >= 18 && i < 24) k = 7 + (i - 18);   // and forward again
    const int v = s2c[std::size_t(gap[k])];
    expected.push_back(v);
    fs::copy_file(dir / "R0" / pipeline_detail::view_file(v),
                  dir / "completion_request" / "completed" / pipeline_detail::view_file(gap[i]),
                  fs::copy_options::overwrite_existing);
  }
  const auto r2 = run_pipeline(tiny_input_data(), p, dir.string());
  const auto& ct = r2["completion"]["completion_trace"];
  INFO(ct.dump());
  REQUIRE(ct.is_object());
  CHECK(ct["stall_fraction"].get<double>() >= 3.0 / double(gap.size() - 1));
  CHECK(ct["reversals"].get<int>() == 2);
  CHECK(r2["completion"]["temporal_trace"]["reversals"].get<int>() == 0);  // the cameras asked for
  // Each gap frame is matched to the R0 render it was made from.
  std::vector<double> matched = ct["matched_views"].get<std::vector<double>>();
  std::vector<double> want(expected.begin(), expected.end());
  if (matched.size() == want.size() && !matched.empty() && matched.front() != want.front())
    std::reverse(want.begin(), want.end());  // the clip may run against the canonical order
  CHECK(matched == want);
}

TEMPLATE_TEST_CASE("pipeline: bad inputs give clear errors and leave earlier outputs intact", "[pipeline][errors]",
                   float, double) {
  using S = TestType;
  const fs::path dir = scratch().path() / (std::string("bad_") + (sizeof(S) == 4 ? "f" : "d"));
  fs::create_directories(dir);
  write_file_atomic((dir / "orbit.json").string(), "{\"earlier\": true}\n");
  PipelineParams p = tiny_params();

  SECTION("too few cameras") {
    PipelineInput<S> in = synthetic_pipeline_input<S>(tiny_input(3), 1);
    in.source = {0, 1};
    REQUIRE_THROWS_WITH(run_pipeline(in, p, dir.string()), Catch::Contains("at least 3 source frames"));
  }
  SECTION("source arc under 20 degrees") {
    SyntheticInputParams sp = tiny_input(30);
    sp.arc_deg = 30;  // 30 frames of 90 over 30 degrees: a 10-degree source arc
    sp.position_noise = 0.002;
    sp.rotation_noise_deg = 0.02;
    sp.drift_per_frame = 0;
    const PipelineInput<S> in = synthetic_pipeline_input<S>(sp, 1);
    REQUIRE_THROWS_WITH(run_pipeline(in, p, dir.string()), Catch::Contains("under the minimum of 20"));
  }
  SECTION("a source frame without image") {
    PipelineInput<S> in = synthetic_pipeline_input<S>(tiny_input(10), 1);
    in.images[4] = Image<S>();
    REQUIRE_THROWS_WITH(run_pipeline(in, p, dir.string()), Catch::Contains("005.png") && Catch::Contains("no image"));
  }
  SECTION("missing frames in a COLMAP dataset") {
    const SyntheticInput<S> syn = make_synthetic_input<S>(tiny_input(10));
    const fs::path data = dir / "dataset";
    fs::create_directories(data / "images");
    fs::create_directories(data / "sparse" / "0");
    write_colmap_text((data / "sparse" / "0").string(), syn.recorded);
    const Image<S> grey(tiny_input().width, tiny_input().height, 3, S(0.5));
    for (int i = 0; i < 20; ++i) write_png((data / "images" / syn.recorded[std::size_t(i)].name).string(), grey);
    REQUIRE_THROWS_WITH(load_colmap_input<S>(data.string(), "1-10", 32, 32),
                        Catch::Contains("021.png") && Catch::Contains("missing"));
    // The frames that exist load.
    fs::remove_all(data / "sparse");
    fs::create_directories(data / "sparse" / "0");
    std::vector<FrameCamera<S>> first(syn.recorded.begin(), syn.recorded.begin() + 20);
    write_colmap_text((data / "sparse" / "0").string(), first);
    const auto in = load_colmap_input<S>(data.string(), "1-10", 32, 32);
    CHECK(in.source.size() == 10);
    CHECK(in.images[0].width == 32);
    REQUIRE_THROWS_WITH(load_colmap_input<S>(data.string(), "15-30", 32, 32), Catch::Contains("30"));
  }
  SECTION("unknown provider") {
    p.completion = "magic";
    const PipelineInput<S> in = synthetic_pipeline_input<S>(tiny_input(10), 1);
    REQUIRE_THROWS_WITH(run_pipeline(in, p, dir.string()), Catch::Contains("unknown completion provider"));
  }
  CHECK(read_file_bytes((dir / "orbit.json").string()) == "{\"earlier\": true}\n");
}

TEST_CASE("pipeline: G1 gives completion frames the source's lens unless told to keep the provider's",
          "[pipeline][g1]") {
  // A provider that knows its frames' cameras from another estimate (the oracle on
  // the user's path) gives them another focal length than the source cameras'.
  Intrinsics<double> source_k;
  source_k.fx = 100, source_k.fy = 101, source_k.cx = 32, source_k.cy = 24, source_k.width = 64, source_k.height = 48;
  // (the canonical cameras carry the source cameras' median focal lengths: orbit.hpp)
  PipelineRun<double> run;
  run.fit.views = 5;
  Camerad canonical;
  canonical.intrinsics = source_k;
  run.fit.cameras.assign(5, canonical);

  Camerad given = canonical;
  given.R = Eigen::AngleAxisd(0.3, Eigen::Vector3d(0, 1, 0)).toRotationMatrix();
  given.t = Eigen::Vector3d(0.1, -0.2, 3);
  given.intrinsics.fx = 110, given.intrinsics.fy = 111, given.intrinsics.cx = 62, given.intrinsics.cy = 50;
  given.intrinsics.width = 128, given.intrinsics.height = 96;
  auto vhat = [&] {
    std::vector<VhatFrame<double>> v(2);
    v[0].image = Image<double>(64, 48, 3);
    v[0].camera = canonical;
    v[0].from_r0 = true;
    v[0].position = 1;
    v[1].image = Image<double>(128, 96, 3);  // twice the source's size
    v[1].camera = given;
    v[1].position = 3;
    return v;
  };

  REQUIRE(run.params.g1_source_lens);  // the default
  const auto frames = g1_frames(run, vhat(), G1Data::paper);
  REQUIRE(frames.size() == 2);
  CHECK(frames[0].camera.intrinsics.fx == 100);  // R0's render keeps its canonical camera
  const auto& k = frames[1].camera.intrinsics;
  CHECK(k.fx == Approx(200));  // the source's lens at the frame's size
  CHECK(k.fy == Approx(202));
  CHECK(k.cx == 62);  // the principal point, like the pose, is the provider's
  CHECK(k.cy == 50);
  CHECK(k.width == 128);
  CHECK(frames[1].camera.R.isApprox(given.R));
  CHECK(frames[1].camera.t.isApprox(given.t));

  run.params.g1_source_lens = false;
  const auto kept = g1_frames(run, vhat(), G1Data::paper);
  CHECK(kept[1].camera.intrinsics.fx == 110);
  CHECK(kept[1].camera.intrinsics.fy == 111);
}

TEST_CASE("pipeline: after the recalibrate stage G1 trains at its cameras and lens, G0's scoring keeps the first",
          "[pipeline][g1]") {
  Intrinsics<double> first_k;
  first_k.fx = first_k.fy = 100, first_k.cx = 32, first_k.cy = 24, first_k.width = 64, first_k.height = 48;
  PipelineInput<double> in;
  in.cameras.resize(1);
  in.cameras[0].camera.intrinsics = first_k;
  in.cameras[0].camera.t = Eigen::Vector3d(0, 0, 3);
  PipelineRun<double> run;
  run.input = &in;
  run.fit.views = 5;
  Camerad canonical;
  canonical.intrinsics = first_k;
  run.fit.cameras.assign(5, canonical);

  G1Cameras<double> g;
  g.lens = first_k;
  g.lens.fx = g.lens.fy = 104;
  Camerad source = in.cameras[0].camera, registered = canonical;
  source.intrinsics = g.lens;
  source.t = Eigen::Vector3d(0.01, 0, 3);
  registered.intrinsics = g.lens;
  registered.R = Eigen::AngleAxisd(0.2, Eigen::Vector3d(0, 1, 0)).toRotationMatrix();
  g.source[0] = source;
  g.completion[1] = registered;  // V_hat's frame 1; frame 2 was not registered
  run.g1_cameras = g;

  std::vector<VhatFrame<double>> v(3);
  for (std::size_t i = 0; i < v.size(); ++i) {
    v[i].image = Image<double>(64, 48, 3);
    v[i].camera = canonical;
    v[i].camera.t = Eigen::Vector3d(0, 0, 2 + double(i));
    v[i].position = double(i);
  }
  v[0].from_r0 = true;
  const auto frames = g1_frames(run, v, G1Data::paper);
  REQUIRE(frames.size() == 3);
  CHECK(frames[0].camera.intrinsics.fx == 100);  // R0's render keeps its canonical camera
  CHECK(frames[1].camera.R.isApprox(registered.R));  // the registered frame at its new camera
  CHECK(frames[1].camera.intrinsics.fx == 104);
  CHECK(frames[2].camera.t.isApprox(v[2].camera.t));  // the other at the provider's pose, with G1's lens
  CHECK(frames[2].camera.intrinsics.fx == 104);

  CHECK(run.source_camera(0, true).t.isApprox(source.t));  // R1 is scored at G1's source cameras ...
  CHECK(run.source_camera(0, false).t.isApprox(in.cameras[0].camera.t));  // ... R0 at G0's
  CHECK(run.completion_camera(canonical, 64, 48, true).intrinsics.fx == 104);
  CHECK(run.completion_camera(canonical, 64, 48, false).intrinsics.fx == 100);
}

// PipelineParams::g1_refine_completion_at: G1 fits its completion frames'
// cameras once, part way, writes them (g1/completion_cameras.json) and reports
// the fit; interrupted after the fit, it resumes on the fitted cameras and ends
// as the run that was not interrupted.
TEST_CASE("pipeline: G1 fits its completion cameras part way and resumes with them", "[pipeline][resume]") {
  const fs::path& ref = oracle_run();
  PipelineParams p = oracle_params();
  p.compare_g1_paper = p.oracle_bound = false;
  p.g1_refine_completion_at = 0.5;
  const int fit_at = (p.iters_g1 + 1) / 2;

  const fs::path dir = scratch().path() / "fit_completion";
  copy_run(ref, dir);
  PipelineRun<float> state;
  std::vector<std::string> log;
  state.log = [&log](const std::string& line) { log.push_back(line); };
  const auto r = run_pipeline(tiny_input_data(), p, dir.string(), nullptr, &state);
  CHECK(std::find(state.ran.begin(), state.ran.end(), "g1") != state.ran.end());
  const auto fc = parse_file(dir / "g1" / "completion_cameras.json");
  CHECK(fc.at("iteration") == fit_at);
  const int fitted = fc.at("fit").at("frames");
  // Every completion frame G1 trains on, and nothing else (frames.json: "source ..." names G0's frames).
  int completion_frames = 0;
  const auto g1_frames = parse_file(dir / "g1" / "frames.json");  // named: a range-for would not keep a temporary alive
  for (const auto& e : g1_frames.at("frames"))
    if (e.at("name").get<std::string>().rfind("source ", 0) != 0) ++completion_frames;
  CHECK(fitted > 0);
  CHECK(fitted == completion_frames);
  CHECK(int(fc.at("frames").size()) == fitted);
  CHECK(r.at("cameras").at("g1_completion_fit").at("fit") == fc.at("fit"));
  CHECK_FALSE(r.at("cameras").at("g1_completion_fit").contains("frames"));
  bool said = false;
  for (const auto& line : log) said = said || line.find("completion cameras fitted to their images") != std::string::npos;
  CHECK(said);

  // Interrupted between the first partial checkpoint after the fit and the next.
  const fs::path cut = scratch().path() / "fit_completion_cut";
  copy_run(ref, cut);
  PipelineParams q = p;
  q.checkpoint_every = kQuick ? 20 : 100;
  const int stop_at = (fit_at / q.checkpoint_every + 1) * q.checkpoint_every + q.checkpoint_every / 2;
  REQUIRE(stop_at < q.iters_g1);
  q.on_iteration = [stop_at](const std::string& label, int it) {
    if (label == "G1" && it == stop_at) throw std::runtime_error("interrupted");
  };
  REQUIRE_THROWS_WITH(run_pipeline(tiny_input_data(), q, cut.string()), "interrupted");
  REQUIRE(fs::exists(cut / "g1" / "partial.bin"));
  q.on_iteration = nullptr;

  // The same interrupted run with its fitted cameras' file damaged: it is not
  // trusted; the fit runs again where training resumes.
  const fs::path damaged = scratch().path() / "fit_completion_damaged";
  copy_run(cut, damaged);
  {
    const std::string f = (damaged / "g1" / "completion_cameras.json").string();
    const std::string bytes = read_file_bytes(f);
    std::ofstream(f, std::ios::binary) << bytes.substr(0, bytes.size() / 2);
  }
  std::vector<std::string> log3;
  PipelineRun<float> refit;
  refit.log = [&log3](const std::string& line) { log3.push_back(line); };
  run_pipeline(tiny_input_data(), q, damaged.string(), nullptr, &refit);
  bool distrusted = false;
  for (const auto& line : log3) distrusted = distrusted || line.find("not usable") != std::string::npos;
  CHECK(distrusted);
  const auto fc3 = parse_file(damaged / "g1" / "completion_cameras.json");
  CHECK(fc3.at("iteration") == (fit_at / q.checkpoint_every + 1) * q.checkpoint_every);
  CHECK(fc3.at("fit").at("frames") == fitted);

  PipelineRun<float> resumed;
  std::vector<std::string> log2;
  resumed.log = [&log2](const std::string& line) { log2.push_back(line); };
  run_pipeline(tiny_input_data(), q, cut.string(), nullptr, &resumed);
  bool reused = false;
  for (const auto& line : log2) reused = reused || line.find("completion cameras as fitted at iteration") != std::string::npos;
  CHECK(reused);
  CHECK(read_file_bytes((cut / "g1" / "completion_cameras.json").string()) ==
        read_file_bytes((dir / "g1" / "completion_cameras.json").string()));
  CHECK(read_file_bytes((cut / "final.ply").string()) == read_file_bytes((dir / "final.ply").string()));
}

#pragma once
// Stage 5, report: coverage, support-stratified quality and completion metrics
// -> report.json, report.md, contact_sheet.png, support_mask.png, top_view.png.
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/io/ply.hpp"
#include "orbitforge/metrics/coverage.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/metrics/view_alignment.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"
#include "orbitforge/pipeline/inputs/input_json.hpp"
#include "orbitforge/pipeline/report/pictures.hpp"
#include "orbitforge/pipeline/report/reference.hpp"
#include "orbitforge/pipeline/report/report_markdown.hpp"
#include "orbitforge/pipeline/run_state.hpp"
#include "orbitforge/pipeline/stages/completion.hpp"

namespace orbitforge {

template <class Scalar>
nlohmann::json coverage_json(const std::vector<double>& azimuth_deg) {
  std::vector<Scalar> az(azimuth_deg.begin(), azimuth_deg.end());
  const auto c = orbit_coverage(az);
  return {{"A", double(c.span_deg)}, {"M", double(c.monotone)}, {"closed", c.closed}};
}

// Where a scored frame is rendered: at its own camera, at its scoring camera
// (PipelineInput::scoring_camera: on the user's path a withheld source frame's
// aligned reference camera), or at the camera G1 gives a completion frame of
// that pose (PipelineRun::completion_camera), for gap views.
enum class ScoreAt { own, reference, completion };

// Whose cameras a scene is scored at: G0's (R0) or G1's (R1 and the
// comparisons), which differ after the recalibrate stage.
enum class CamerasOf { g0, g1 };

// After the recalibrate stage G1's cameras are another estimate than the one
// the reference was aligned to, and differ from it by more than a similarity
// (a degree or two on the recorded videos). R1's yardstick then carries the
// reference's cameras into G1's estimate (carry_camera, reference.hpp), from
// every frame both place: the source frames (the reference's aligned cameras
// against G1's) and the registered completion frames (the reference's camera of
// the recorded frame a completion frame shows, else its provider's, against
// G1's). Null without a reference or a recalibration.
template <class Scalar>
std::optional<EstimatePairs<Scalar>> reference_in_g1(const PipelineRun<Scalar>& run) {
  const auto& in = *run.input;
  if (!in.reference || !run.g1_cameras) return std::nullopt;
  std::vector<double> position;
  std::vector<Camera<Scalar>> from, to;
  for (const auto& [f, cam] : run.g1_cameras->source) {
    const auto it = in.reference->source_cameras.find(f);
    if (it == in.reference->source_cameras.end()) continue;
    position.push_back(orbit_position(run.fit, it->second));
    from.push_back(it->second);
    to.push_back(cam);
  }
  std::map<std::string, int> outside_source;  // recorded frames outside the source, by name
  for (std::size_t i = 0; i < in.cameras.size(); ++i)
    if ((int(i) < in.source_first || int(i) > in.source_last) && in.cameras[i].valid)
      outside_source[in.cameras[i].name] = int(i);
  const std::vector<VhatFrame<Scalar>> vhat =
      read_vhat<Scalar>(run.out, "vhat.json", in.frame, nullptr, VhatImages::skip);  // cameras only
  for (const auto& [i, cam] : run.g1_cameras->completion) {
    const VhatFrame<Scalar>& v = vhat.at(std::size_t(i));
    const std::string shown = v.origin.substr(v.origin.find_last_of(' ') + 1);  // "recorded 034.jpg" -> "034.jpg"
    const auto it = outside_source.find(shown);
    position.push_back(v.position);
    from.push_back(it != outside_source.end() ? in.cameras[std::size_t(it->second)].camera : v.camera);
    to.push_back(cam);
  }
  return estimate_pairs(std::move(position), std::move(from), std::move(to), run.fit.views);
}

// The neighbours carry_camera averages over: two on each side of a gap view.
constexpr int kCarryNeighbours = 4;

// `fit_view`: each view's camera is first turned and zoomed
// about its centre to fit its image (metrics/view_alignment.hpp, the scene
// fixed), and where the fit moved it the view is rendered again there and scored;
// the fits are reported.
template <class Scalar>
nlohmann::json quality_of(const PipelineRun<Scalar>& run, const GaussianScene<Scalar>& scene,
                          const std::vector<int>& frames, ScoreAt at, CamerasOf of,
                          const std::optional<EstimatePairs<Scalar>>& in_g1, bool fit_view = false) {
  nlohmann::json j = {{"psnr", nullptr}, {"ssim", nullptr}, {"views", 0}};
  if (frames.empty()) return j;
  Renderer<Scalar> r = run.renderer();
  std::vector<ImageQuality> q;
  double turn_sum = 0, turn_max = 0, zoom_sum = 0, zoom_max = 0;
  int fitted = 0;
  for (int i : frames) {
    const auto& fc = run.input->cameras[std::size_t(i)];
    const Image<Scalar>& image = run.input->images[std::size_t(i)];
    const bool g1 = of == CamerasOf::g1;
    Camera<Scalar> cam = at == ScoreAt::own ? run.source_camera(i, g1) : run.input->scoring_camera(i);
    if (g1 && in_g1 && at != ScoreAt::own) {  // the reference's camera in G1's estimate
      const bool outside_source = i < run.input->source_first || i > run.input->source_last;
      cam = outside_source ? carry_camera(cam, orbit_position(run.fit, cam), *in_g1, kCarryNeighbours)
                           : in_g1->global.transform.apply(cam);
    }
    if (at == ScoreAt::completion) cam = run.completion_camera(cam, image.width, image.height, g1);
    Image<Scalar> rendered = r.render(SceneView<Scalar>(scene), cam).color;
    if (fit_view) {
      const ViewAlignment a = fit_view_alignment(rendered, image, cam.intrinsics);
      if (a.refined) {
        cam = aligned_camera(cam, a);
        rendered = r.render(SceneView<Scalar>(scene), cam).color;  // only a moved camera renders again
        turn_sum += a.angle_deg;
        turn_max = std::max(turn_max, a.angle_deg);
        zoom_sum += std::abs(a.zoom - 1);
        zoom_max = std::max(zoom_max, std::abs(a.zoom - 1));
        ++fitted;
      }
    }
    q.push_back(compare_images(rendered, image, fc.name, run.params.threads));
  }
  const QualityMean m = mean_quality(q);
  // Each view's figures too, in `frames`' order: a mean hides where along the
  // orbit a reconstruction fails (near the arc's ends, or across the gap).
  nlohmann::json per_view = nlohmann::json::array();
  for (std::size_t k = 0; k < q.size(); ++k)
    per_view.push_back({{"frame", run.input->cameras[std::size_t(frames[k])].name},
                        {"psnr", q[k].psnr},
                        {"ssim", q[k].ssim}});
  j = {{"psnr", m.psnr}, {"ssim", m.ssim}, {"views", m.views}, {"per_view", per_view}};
  if (fit_view) {
    const ViewAlignmentParams limits;
    j["view_fit"] = {{"fitted_views", fitted},
                     {"turn_mean_deg", fitted ? turn_sum / fitted : 0.0},
                     {"turn_max_deg", turn_max},
                     {"zoom_change_mean", fitted ? zoom_sum / fitted : 0.0},
                     {"zoom_change_max", zoom_max},
                     {"limits", {{"turn_deg", limits.max_angle_deg}, {"zoom_change", limits.max_zoom}}}};
  }
  return j;
}

// Where the cameras came from and, on the user's path, what the reference says of them.
// `estimate` is the cameras stage's account of its focal length ("" when no stage ran).
template <class Scalar>
nlohmann::json cameras_json(const PipelineInput<Scalar>& in, const OrbitFit<Scalar>& fit, const std::string& estimate) {
  nlohmann::json j = {{"path", in.camera_path}};
  if (!estimate.empty()) j["estimate"] = nlohmann::json::parse(read_file_bytes(estimate));
  if (in.reference) j["reference"] = reference_report(in, fit);
  return j;
}

template <class Scalar>
nlohmann::json stage_report(PipelineRun<Scalar>& run) {
  namespace fs = std::filesystem;
  using namespace pipeline_detail;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  std::uint64_t h = fnv1a(run.keys.at("static_proxy"), fnv1a(run.keys.at("g1")));
  for (const char* extra : {"g1_paper", "bound"})
    if (run.keys.count(extra)) h = fnv1a(run.keys.at(extra), h);
  const std::string key = hex64(fnv1a(p.score_view_fitted ? "report v9 view-fitted" : "report v9", h));
  run.keys["report"] = key;
  const std::vector<std::string> outputs = {"report.json", "report.md", "contact_sheet.png", "support_mask.png",
                                            "top_view.png"};
  if (run.stage_current("report", key, outputs))
    return nlohmann::json::parse(read_file_bytes((out / "report.json").string()));
  const auto& in = *run.input;
  const double period = double(run.fit.views - 1);

  // Coverage: views backed by evidence.
  std::vector<double> az0, az1, az_rendered;
  for (const auto& s : run.fit.source) {
    const int idx = in.source[std::size_t(s.input_index)];
    az0.push_back(orbit_position(run.fit, in.cameras[std::size_t(idx)].camera) * 360.0 / period);
  }
  const nlohmann::json vj = nlohmann::json::parse(read_file_bytes((out / "vhat.json").string()));
  const bool reuse = vj.value("reuse_r0", false);
  if (reuse)
    az1 = az0;
  else {
    // R1's cameras as they come: the arc's renders along the orbit, then the
    // completion in its own order (the clip's), so a completion that turns back
    // or jumps shows in M instead of being sorted away.
    std::vector<std::pair<int, double>> completion;
    for (const auto& e : vj.at("frames")) {
      const double deg = e.at("position").get<double>() * 360.0 / period;
      if (e.value("kind", std::string()) == "completion")
        completion.push_back({e.value("completion_order", int(completion.size())), deg});
      else
        az1.push_back(deg);
    }
    std::stable_sort(completion.begin(), completion.end(),
                     [](const auto& a, const auto& b) { return a.first < b.first; });
    for (const auto& c : completion) az1.push_back(c.second);
  }
  for (int v : rendered_views(run.fit.views, p.render_stride)) az_rendered.push_back(v * 360.0 / period);
  nlohmann::json coverage = {{"R0", coverage_json<Scalar>(az0)}, {"R1", coverage_json<Scalar>(az1)}};
  coverage["R0"]["rendered"] = coverage_json<Scalar>(az_rendered);
  coverage["R1"]["rendered"] = coverage_json<Scalar>(az_rendered);

  // Quality at the recorded cameras: supported = source frames (those trained on,
  // and the withheld ones no reconstruction saw); gap_heldout = the recorded
  // frames of the gap the oracle holds out (odd frame numbers).
  std::vector<int> supported_train, supported_heldout;
  for (std::size_t t = 0; t < run.fit.source.size(); ++t) {
    const int idx = run.input_index_of_source(int(t));
    (in.is_withheld(idx) ? supported_heldout : supported_train).push_back(idx);
  }
  const GapFrames gap = gap_frames(in, run.fit);
  run.log("report: scoring " + std::to_string(supported_train.size()) + " training, " +
          std::to_string(supported_heldout.size()) + " withheld source and " + std::to_string(gap.heldout.size()) +
          " held-out gap views");
  // Withheld source frames score at their own estimated cameras (the user has
  // them: COLMAP saw every source frame); with a reference, also at its aligned
  // cameras, which adds the two estimates' disagreement to the method's error.
  double view_fit_secs = 0;  // evaluation only: not the method's time
  const std::optional<EstimatePairs<Scalar>> in_g1 = reference_in_g1(run);
  auto rows = [&](const GaussianScene<Scalar>& scene, CamerasOf of) {
    nlohmann::json j{{"supported_train", quality_of(run, scene, supported_train, ScoreAt::own, of, in_g1)},
                     {"supported_heldout", quality_of(run, scene, supported_heldout, ScoreAt::own, of, in_g1)},
                     {"gap_heldout", quality_of(run, scene, gap.heldout, ScoreAt::completion, of, in_g1)}};
    if (!in.scoring_cameras.empty())
      j["supported_heldout_at_reference"] = quality_of(run, scene, supported_heldout, ScoreAt::reference, of, in_g1);
    // On the user's path with the source lens, the gap views at the reference's
    // own lens too: a focal-length disagreement of a few per cent shows there.
    if (in.reference && p.g1_source_lens)
      j["gap_heldout_at_reference_lens"] = quality_of(run, scene, gap.heldout, ScoreAt::reference, of, in_g1);
    // The same views with each camera's turn and zoom fitted to its image: what
    // remains is the scene's error, not the yardstick's (on the user's path the
    // reference's cameras disagree with the user's by tenths of a degree and
    // their focal lengths by a few per cent).
    if (p.score_view_fitted) {
      const auto f0 = std::chrono::steady_clock::now();
      j["gap_heldout_view_fitted"] = quality_of(run, scene, gap.heldout, ScoreAt::completion, of, in_g1, true);
      if (!in.scoring_cameras.empty())
        j["supported_heldout_at_reference_view_fitted"] =
            quality_of(run, scene, supported_heldout, ScoreAt::reference, of, in_g1, true);
      view_fit_secs += std::chrono::duration<double>(std::chrono::steady_clock::now() - f0).count();
    }
    return j;
  };
  nlohmann::json quality = {{"R0", rows(run.read_scene((out / "gmed0.ply").string()), CamerasOf::g0)},
                            {"R1", rows(run.read_scene((out / "final.ply").string()), CamerasOf::g1)}};
  if (run.keys.count("g1_paper")) quality["R1_paper"] = rows(run.read_scene((out / "g1_paper" / "final.ply").string()), CamerasOf::g1);
  if (run.keys.count("bound")) {
    // With G1 trained on exactly the oracle's set the bound is G1: its figures would only repeat R1's.
    const nlohmann::json rec = nlohmann::json::parse(read_file_bytes((out / "stages" / "bound.json").string()));
    if (rec.at("settings").value("same_as_g1", false))
      quality["bound"] = {{"equals", "R1"},
                          {"why", "G1 trained on the oracle's frames with the bound's settings: the bound is G1 by "
                                  "construction, not a separate measurement"}};
    else
      quality["bound"] = rows(run.read_scene((out / "bound" / "bound.ply").string()), CamerasOf::g1);
  }

  // Pictures.
  const int tile = std::min(128, in.width), tile_height = std::max(1, int(std::lround(double(tile) * in.height / in.width)));
  auto nearest = [&](int v) { return std::min(run.fit.views - 1, int(std::lround(double(v) / p.render_stride)) * p.render_stride); };
  const Image<float> sheet = contact_sheet(2, run.fit.views, tile, tile_height, [&](int row, int v) {
    const fs::path f = out / (row == 0 ? "R0" : "R1") / view_file(nearest(v));
    std::error_code ec;
    return fs::exists(f, ec) ? read_image<float>(f.string()) : Image<float>();
  });
  write_png((out / "contact_sheet.png").string(), sheet);
  write_png((out / "support_mask.png").string(), support_mask_picture(run.fit.support));
  std::vector<Camera<Scalar>> src_cams, other_cams;
  std::vector<char> is_source(in.cameras.size(), 0);
  for (int s : in.source) is_source[std::size_t(s)] = 1;
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    if (!in.cameras[i].valid || !in.cameras[i].camera.is_finite()) continue;
    (is_source[i] ? src_cams : other_cams).push_back(in.cameras[i].camera);
  }
  write_png((out / "top_view.png").string(), top_view_picture(run.fit, src_cams, other_cams));

  // Stage times from the records (a resumed run reports the times of the runs that did the work).
  nlohmann::json stages = nlohmann::json::object();
  double total = 0;
  const bool recalibrated = run.keys.at("recalibrate") != run.keys.at("completion");  // the stage ran or verified
  for (const char* s : {"orbit", "g0", "static_proxy", "completion", "recalibrate", "g1"}) {
    if (std::string(s) == "static_proxy" && !(p.deformable && p.static_proxy_diagnostics)) continue;
    if (std::string(s) == "recalibrate" && !recalibrated) continue;
    const double secs = recorded_seconds(run.out, s);
    stages[s] = secs;
    total += secs;
  }
  // The stages before the method's own, when the caller ran them: the camera
  // estimation of a video or image-folder input (stages/cameras.hpp), the points
  // of a model without them (stages/points.hpp).
  for (const char* s : {"cameras", "points"})
    if (run.keys.count(s)) {
      stages[s] = recorded_seconds(run.out, s);
      total += stages[s].get<double>();
    }
  // Comparisons an audit asked for are not part of the method's time.
  nlohmann::json comparisons = nlohmann::json::object();
  for (const char* s : {"g1_paper", "bound"})
    if (run.keys.count(s)) comparisons[s] = recorded_seconds(run.out, s);
  if (p.score_view_fitted) comparisons["view_fitted_scoring"] = view_fit_secs;
  const double report_secs =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count() - view_fit_secs;
  stages["report"] = report_secs;
  total += report_secs;

  const nlohmann::json orbit = nlohmann::json::parse(read_file_bytes((out / "orbit.json").string()));
  std::string estimate;
  if (run.keys.count("cameras") && fs::exists(out / "cameras" / "estimate.json"))
    estimate = (out / "cameras" / "estimate.json").string();
  nlohmann::json completion = vj.at("metrics");
  nlohmann::json r = {{"input", in.description},
                      {"completion_provider", vj.value("provider", std::string())},
                      {"prompt", run.prompt.video_prompt},
                      {"settings",
                       {{"iters_g0", p.iters_g0},
                        {"iters_g1", p.iters_g1},
                        {"deformable", p.deformable},
                        {"g1_from_gmed0", p.g1_from_gmed0},
                        {"g1_data", g1_data_name(p.g1_data)},
                        {"g1_deformable", p.g1_deformable},
                        {"g1_arc_renders", p.g1_arc_renders},
                        {"g1_completion_lens", p.g1_source_lens ? "source" : "provider"},
                        {"plateau_g1", p.plateau_g1},
                        {"median_samples", p.median_samples},
                        {"views", run.fit.views},
                        {"render_stride", p.render_stride},
                        {"width", in.width},
                        {"height", in.height}}},
                      {"stages", stages},
                      {"total_seconds", total},
                      {"comparison_seconds", comparisons},
                      {"frames", source_frames_json(in)},
                      {"points", points_json(in)},
                      {"background", {{"color", in.background}, {"random", in.random_background}, {"reason", in.background_reason}}},
                      {"cameras", cameras_json(in, run.fit, estimate)},
                      {"coverage", coverage},
                      {"diagnostics", orbit.at("diagnostics")},
                      {"orbit_check", orbit.value("check", nlohmann::json())},
                      {"quality", quality},
                      {"completion", completion}};
  if (recalibrated) {
    nlohmann::json rc = nlohmann::json::parse(read_file_bytes((out / "recalibrate" / "cameras.json").string()));
    rc.erase("frames");
    if (in_g1) {
      rc["reference_alignment"] = camera_alignment_json(in_g1->global);
      rc["reference_alignment"]["gap_views_carried_by_neighbours"] = kCarryNeighbours;
    }
    r["cameras"]["recalibrated"] = rc;
  }
  // G1's completion cameras fitted to their images (stages/g1.hpp).
  if (recorded_output(run.out, "g1", "g1/completion_cameras.json")) {
    nlohmann::json fc = nlohmann::json::parse(read_file_bytes((out / "g1" / "completion_cameras.json").string()));
    fc.erase("frames");
    fc.erase("key");
    if (in_g1) fc["reference_alignment"] = camera_alignment_json(in_g1->global);
    r["cameras"]["g1_completion_fit"] = fc;
  }
  // The frame the run worked in; its files are in the model's own (run_state.hpp).
  if (!in.frame.is_identity())
    r["frame"] = {{"origin", {in.frame.origin[0], in.frame.origin[1], in.frame.origin[2]}},
                  {"scale", in.frame.scale},
                  {"files", in.frame.far_from_origin() ? "model frame, float64 positions" : "model frame"}};
  if (!p.invocation.empty()) {
    r["invocation"] = {{"command", p.invocation.command}, {"settings", p.invocation.settings}};
    // The stages' timings depend on it; it is the report writer's, which a resumed run shares with the stages it ran.
    if (!p.invocation.memory_pages.empty()) r["invocation"]["memory_pages"] = p.invocation.memory_pages;
  }
  // What each reconstruction's levers decided (training_record.hpp).
  nlohmann::json training = nlohmann::json::object();
  for (const std::string s : {"g0", "g1", "g1_paper", "bound"})
    if (run.keys.count(s) && recorded_output(run.out, s, s + "/training.json"))
      training[s] = nlohmann::json::parse(read_file_bytes((out / s / "training.json").string()));
  r["training"] = training;
  if (p.deformable && p.static_proxy_diagnostics)
    r["static_proxy"] = nlohmann::json::parse(read_file_bytes((out / "static_proxy.json").string()));
  write_file_atomic((out / "report.json").string(), r.dump(1) + "\n");
  write_file_atomic((out / "report.md").string(), report_markdown(r));
  record_stage(run.out, "report", key, report_secs, nlohmann::json::object(), outputs);
  run.ran.push_back("report");
  return r;
}

}  // namespace orbitforge

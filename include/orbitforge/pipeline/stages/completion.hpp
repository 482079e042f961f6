#pragma once
// Stage 3, completion: a provider (pipeline/completion/provider.hpp) fills the gap, and
// V_hat, the second reconstruction's training set, is assembled -> vhat.json,
// vhat/NNNN.png (+ the provider's own folder).
#include <algorithm>
#include <chrono>
#include <filesystem>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/io/atomic_file.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/metrics/coverage.hpp"
#include "orbitforge/metrics/image.hpp"
#include "orbitforge/metrics/view_matching.hpp"
#include "orbitforge/pipeline/completion/provider.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/pipeline/run_state.hpp"

namespace orbitforge {

// Whether read_vhat decodes the frames' images or reads only their cameras.
enum class VhatImages { load, skip };

// vhat.json's cameras are in the model's frame; `frame` moves them (in double)
// into the one the run works in.
template <class Scalar>
std::vector<VhatFrame<Scalar>> read_vhat(const std::string& out, const std::string& file, const SceneFrame& frame,
                                         bool* reuse_r0 = nullptr, VhatImages images = VhatImages::load) {
  namespace fs = std::filesystem;
  const std::string path = (fs::path(out) / file).string();
  nlohmann::json j;
  try {
    j = nlohmann::json::parse(read_file_bytes(path));
  } catch (const nlohmann::json::exception& e) {
    fail(path, ": not valid JSON: ", e.what());
  }
  if (reuse_r0) *reuse_r0 = j.value("reuse_r0", false);
  std::vector<VhatFrame<Scalar>> frames;
  ensure(j.contains("frames") && j["frames"].is_array(), path, ": no \"frames\" list");
  const auto cams = cameras_from_json<double>(j["frames"], path);
  for (std::size_t i = 0; i < cams.size(); ++i) {
    const auto& e = j["frames"][i];
    VhatFrame<Scalar> f;
    f.camera = frame.to_normalised(cams[i]).template cast<Scalar>();
    f.position = e.at("position").get<double>();
    f.origin = e.value("origin", std::string());
    f.from_r0 = e.value("kind", std::string()) == "arc_render";
    if (images == VhatImages::load)
      f.image = to_rgb(read_image<Scalar>((fs::path(out) / e.at("file").get<std::string>()).string()));
    frames.push_back(std::move(f));
  }
  return frames;
}

// V_hat's completion frames (not R0's renders), by index into vhat.json.
template <class Scalar>
std::vector<int> completion_indices(const std::vector<VhatFrame<Scalar>>& vhat) {
  std::vector<int> idx;
  for (std::size_t i = 0; i < vhat.size(); ++i)
    if (!vhat[i].from_r0) idx.push_back(int(i));
  return idx;
}

// Whether the source alone already closes the orbit: no gap bins, or the
// source cameras pass the closed-orbit gate (A > 330 degrees, M > 0.9). Then
// nothing needs completing and G1 is Gmed0.
template <class Scalar>
std::string source_closes_orbit(const PipelineRun<Scalar>& run) {
  if (run.fit.support.gap.empty()) return "the source covers every canonical view (no gap)";
  const double period = double(run.fit.views - 1);
  std::vector<Scalar> az;
  for (const auto& s : run.fit.source) {
    const int idx = run.input->source[std::size_t(s.input_index)];
    az.push_back(Scalar(orbit_position(run.fit, run.input->cameras[std::size_t(idx)].camera) * 360.0 / period));
  }
  const auto c = orbit_coverage(az);
  if (!c.closed) return "";
  char b[160];
  std::snprintf(b, sizeof(b), "the source cameras already close the orbit (A = %.1f deg, M = %.3f)", double(c.span_deg),
                double(c.monotone));
  return b;
}

template <class Scalar>
void stage_completion(PipelineRun<Scalar>& run, CompletionProvider<Scalar>& provider) {
  namespace fs = std::filesystem;
  using namespace pipeline_detail;
  const auto t0 = std::chrono::steady_clock::now();
  const auto& p = run.params;
  const fs::path out(run.out);
  const std::string folder = provider.name() == "external" ? "completion_request" : ("completion_" + provider.name());
  fs::create_directories(out / folder);
  CompletionContext<Scalar> ctx;
  ctx.input = run.input;
  ctx.fit = &run.fit;
  ctx.layout = &run.layout;
  ctx.folder = (out / folder).string();
  ctx.prompt = run.prompt.video_prompt;
  ctx.negative_prompt = p.negative_prompt;
  ctx.condition_on_r0 = p.request_conditioning;
  const std::string r0_dir = (out / "R0").string();
  ctx.r0_rendered = [&p, r0_dir](int v) {
    return v % p.render_stride == 0 && fs::exists(fs::path(r0_dir) / view_file(v));
  };
  ctx.r0 = [r0_dir](int v) { return to_rgb(read_image<Scalar>((fs::path(r0_dir) / view_file(v)).string())); };

  const std::string closed = source_closes_orbit(run);
  const nlohmann::json settings = {{"provider", closed.empty() ? provider.name() : std::string("none")},
                                   {"state", closed.empty() ? provider.state_key(ctx) : closed},
                                   {"prompt", run.prompt.video_prompt},
                                   {"negative_prompt", p.negative_prompt},
                                   {"conditioning", p.request_conditioning}};
  const std::string key = hex64(fnv1a(settings.dump(), fnv1a(run.keys.at("g0"))));
  run.keys["completion"] = key;
  if (run.stage_current("completion", key, {})) return;  // vhat.json and its frames, as recorded
  CompletionResult<Scalar> res;
  if (closed.empty()) {
    res = provider.complete(ctx);
  } else {
    res.ready = true;
    res.reuse_r0 = true;
    res.message = closed + ": no completion and no second reconstruction are needed; final.ply is Gmed0";
    res.summary = {{"skipped", closed}};
  }
  if (!res.ready) throw PipelineStopped(res.message);
  run.log("completion (" + std::string(closed.empty() ? provider.name() : "skipped") + "): " + res.message);

  // The completion's own trace: its frames, in the provider's (the video's)
  // order, placed on the orbit by the R0 render they look most like.
  nlohmann::json content_trace = nullptr;
  if (!res.reuse_r0 && res.frames.size() >= 2) {
    constexpr int kGrid = 24;
    std::vector<double> ref_positions;
    for (int v : rendered_views(run.fit.views, p.render_stride))
      if (ctx.r0_rendered(v)) ref_positions.push_back(v);
    // Renders and frames may differ in shape (a square source's recorded frames
    // against wide canonical renders): both are compared on their shared view.
    double aspect = double(run.fit.cameras[0].intrinsics.width) / double(run.fit.cameras[0].intrinsics.height);
    for (const auto& f : res.frames) aspect = std::min(aspect, double(f.image.width) / double(f.image.height));
    std::vector<std::vector<double>> refs(ref_positions.size()), frames(res.frames.size());
    parallel_for(refs.size(), p.threads, [&](std::size_t i, int) {
      refs[i] = thumbnail(centre_crop_to_aspect(ctx.r0(int(ref_positions[i])), aspect), kGrid);
    });
    parallel_for(frames.size(), p.threads, [&](std::size_t i, int) {
      frames[i] = thumbnail(centre_crop_to_aspect(res.frames[i].image, aspect), kGrid);
    });
    if (!refs.empty()) {
      const ViewMatch m = match_views(frames, refs, ref_positions);
      TraceParams tp;
      tp.period = double(run.fit.views - 1);
      tp.stall_threshold = 0.5;  // matched positions are whole views: a step of 0 is a stall
      const TemporalTrace tr = temporal_trace(m.positions, tp);
      double mean_distance = 0;
      for (double d : m.distances) mean_distance += d / double(m.distances.size());
      content_trace = {{"absolute_turns", tr.absolute_turns},
                       {"net_turns", tr.net_turns},
                       {"stall_fraction", tr.stall_fraction},
                       {"reversals", tr.reversals},
                       {"steps", tr.steps},
                       {"matched_views", m.positions},
                       {"mean_match_l1", mean_distance},
                       {"source", "completion frames in the provider's order, each placed at the canonical view "
                                  "whose R0 render its 24x24 thumbnail matches best"}};
    }
  }

  // V_hat: R0's renders (on the supported arc, or everywhere when R0 is reused)
  // and the completion's frames.
  std::vector<VhatFrame<Scalar>> vhat;
  for (int v : rendered_views(run.fit.views, p.render_stride)) {
    if (!res.reuse_r0 && !run.fit.support.in_arc(v)) continue;
    VhatFrame<Scalar> f;
    f.image = ctx.r0(v);
    f.camera = run.fit.cameras[std::size_t(v)];
    f.position = v;
    f.origin = "R0 view " + std::to_string(v);
    f.from_r0 = true;
    vhat.push_back(std::move(f));
  }
  if (!res.reuse_r0)
    for (std::size_t k = 0; k < res.frames.size(); ++k) {
      res.frames[k].order = int(k);
      vhat.push_back(std::move(res.frames[k]));
    }
  std::stable_sort(vhat.begin(), vhat.end(),
                   [](const VhatFrame<Scalar>& a, const VhatFrame<Scalar>& b) { return a.position < b.position; });
  ensure(!vhat.empty(), "pipeline: V_hat is empty (no rendered R0 view in the arc and no completion frame)");

  // Completion metrics of V_hat (canonical order).
  const double period = double(run.fit.views - 1);
  std::vector<double> positions;
  for (const auto& f : vhat) positions.push_back(f.position);
  TraceParams tp;
  tp.period = period;
  const TemporalTrace tr = temporal_trace(positions, tp);
  // The loop seam on the view both endpoint frames show (see centre_crop_to_aspect);
  // null when they still differ in resolution.
  nlohmann::json loop_l1 = 0.0;
  if (vhat.size() > 1) {
    const auto& a = vhat.back().image;
    const auto& b = vhat.front().image;
    const double aspect =
        std::min(double(a.width) / double(a.height), double(b.width) / double(b.height));
    const Image<Scalar> ca = centre_crop_to_aspect(a, aspect), cb = centre_crop_to_aspect(b, aspect);
    loop_l1 = ca.same_shape(cb) ? nlohmann::json(mae_255(clamp01(ca), clamp01(cb))) : nlohmann::json(nullptr);
  }

  fs::create_directories(out / "vhat");
  nlohmann::json list = nlohmann::json::array();
  std::vector<std::string> vhat_outputs;
  parallel_for(vhat.size(), run.params.threads, [&](std::size_t i, int) {
    write_png((out / "vhat" / view_file(int(i))).string(), vhat[i].image);
  });
  for (std::size_t i = 0; i < vhat.size(); ++i) {
    const std::string file = "vhat/" + view_file(int(i));
    vhat_outputs.push_back(file);
    nlohmann::json e = orbit_file_detail::camera_json(int(i), double(Scalar(vhat[i].position * 360.0 / period)),
                                                      run.input->frame.to_user_for_file(vhat[i].camera));
    e["file"] = file;
    e["position"] = vhat[i].position;
    e["origin"] = vhat[i].origin;
    e["kind"] = vhat[i].from_r0 ? "arc_render" : "completion";
    if (!vhat[i].from_r0) e["completion_order"] = vhat[i].order;
    list.push_back(e);
  }
  const nlohmann::json metrics = {
      {"loop_endpoint_l1", loop_l1},
      {"loop_endpoint_frames", {vhat.front().origin, vhat.back().origin}},
      {"temporal_trace",
       {{"absolute_turns", tr.absolute_turns},
        {"net_turns", tr.net_turns},
        {"stall_fraction", tr.stall_fraction},
        {"reversals", tr.reversals},
        {"steps", tr.steps},
        {"source", "V_hat's camera positions on the orbit (as requested)"}}},
      {"completion_trace", content_trace},
      {"anchor_index_error", {{"mean", run.layout.anchor_error_mean}, {"max", run.layout.anchor_error_max}}},
      {"frames_requested", run.layout.frames}};
  const nlohmann::json j = {{"provider", closed.empty() ? provider.name() : std::string("none (orbit closed)")},
                            {"reuse_r0", res.reuse_r0}, {"message", res.message},
                            {"summary", res.summary},     {"metrics", metrics},         {"frames", list}};
  write_file_atomic((out / "vhat.json").string(), j.dump(1) + "\n");
  vhat_outputs.push_back("vhat.json");
  finish_stage(run, "completion", key, t0, settings, vhat_outputs);
}

}  // namespace orbitforge

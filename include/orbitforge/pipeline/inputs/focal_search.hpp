#pragma once
// Choosing the focal length of a generated video's cameras by how well they fit
// an orbit.
//
// On a short arc of a generated video the mapper's own focal estimate can be
// far off (the frames are not a rigid capture, and nothing closes the loop),
// and a wrong focal length turns the arc: too short a lens under-rotates it. The
// method assumes the camera moves on a circle at constant height and speed,
// looking at one point; the cameras mapped at the right focal length should
// fit that assumption best. The stage maps once with the focal free, then again
// on the same features with the focal held at multiples of that estimate, and
// scores each model's source cameras here:
//
//   score = circle RMSE / radius + height std / radius
//           + angular-step spread (std / mean of the steps between frames)
//           + missing frames (each unregistered source frame costs 1 / frames)
//
// Lower is better. Every term is scale-free; the step spread carries the
// constant-speed assumption, which the circle alone cannot see.
#include <algorithm>
#include <cmath>
#include <filesystem>
#include <functional>
#include <sstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/io/colmap.hpp"
#include "orbitforge/io/image_io.hpp"
#include "orbitforge/pipeline/inputs/colmap_commands.hpp"
#include "orbitforge/pipeline/inputs/external_tools.hpp"

namespace orbitforge {

struct OrbitFitScore {
  bool usable = false;  // at least three usable cameras and a finite fit
  int cameras = 0;
  double circle_rmse = 0, height_std = 0, step_spread = 0, missing = 0;  // the terms, scale-free
  double arc_deg = 0;
  double value = std::numeric_limits<double>::infinity();
  std::string why;  // when not usable
};

// Scores the cameras of `source` (in frame order; `expected` is the number of
// source frames, registered or not).
template <class Scalar>
OrbitFitScore orbit_fit_score(const std::vector<FrameCamera<Scalar>>& source, int expected) {
  OrbitFitScore s;
  OrbitFit<Scalar> fit;
  try {
    fit = fit_orbit_shape(source);
  } catch (const std::exception& e) {
    s.why = e.what();
    return s;
  }
  const double r = double(fit.orbit.radius);
  s.cameras = fit.diagnostics.cameras_used;
  s.circle_rmse = double(fit.diagnostics.circle_rmse) / r;
  s.height_std = double(fit.diagnostics.height_std) / r;
  s.arc_deg = double(fit.diagnostics.source_span_deg);
  std::vector<double> steps;
  for (std::size_t t = 1; t < fit.source.size(); ++t)
    steps.push_back(double(fit.orbit.direction) *
                    wrap_deg_180(double(fit.source[t].azimuth_deg) - double(fit.source[t - 1].azimuth_deg)));
  double mean = 0, var = 0;
  for (double d : steps) mean += d / double(steps.size());
  for (double d : steps) var += (d - mean) * (d - mean) / double(steps.size());
  s.step_spread = mean > 0 ? std::sqrt(var) / mean : std::numeric_limits<double>::infinity();
  s.missing = expected > 0 ? double(std::max(0, expected - s.cameras)) / double(expected) : 0;
  s.value = s.circle_rmse + s.height_std + s.step_spread + s.missing;
  s.usable = std::isfinite(s.value) && s.cameras >= 3;
  if (!s.usable) s.why = "the fit is not finite";
  return s;
}

inline nlohmann::json to_json(const OrbitFitScore& s) {
  nlohmann::json j = {{"usable", s.usable},        {"cameras", s.cameras},       {"circle_rmse", s.circle_rmse},
                      {"height_std", s.height_std}, {"step_spread", s.step_spread}, {"missing", s.missing},
                      {"arc_deg", s.arc_deg}};
  j["score"] = s.usable ? nlohmann::json(s.value) : nlohmann::json(nullptr);
  if (!s.why.empty()) j["why"] = s.why;
  return j;
}

// The source cameras of a COLMAP model, in frame (name) order.
inline std::vector<FrameCamera<double>> model_source_cameras(const std::string& model_dir) {
  auto cams = colmap_frame_cameras<double>(read_colmap_model(model_dir));
  std::sort(cams.begin(), cams.end(), [](const auto& a, const auto& b) { return a.name < b.name; });
  return cams;
}

struct FocalChoice {
  std::string model_dir;  // the chosen model
  double focal_px = 0;    // its focal length, in pixels of the frames' own size
  std::string how;        // "given" (by the user), "mapper" (its own estimate), "orbit fit" (the search)
  std::string summary;    // one line for the log
  nlohmann::json json;    // the choice and every candidate with its score
};

// The search's decisions on scored candidates (anything with `focal` and
// `score`), apart from the mapping so that they can be tested on their own
// (search_focal_grid runs them in the stage's order).

// One step of the focal grid's extension.
constexpr double kFocalGridStep = 1.15;

// The lowest usable score wins; the first candidate (given, or the mapper's
// own) when none is usable.
template <class Candidate>
std::size_t best_focal_candidate(const std::vector<Candidate>& cands) {
  std::size_t best = 0;
  for (std::size_t i = 1; i < cands.size(); ++i)
    if (cands[i].score.usable && (!cands[best].score.usable || cands[i].score.value < cands[best].score.value))
      best = i;
  return best;
}

// The focal length to map next when the best usable candidate is the shortest
// or the longest focal mapped so far: one more step (x 1.15) beyond it, since
// the best score lies outside the grid. 0 when the best lies inside, or fewer
// than two candidates are usable.
template <class Candidate>
double focal_grid_extension(const std::vector<Candidate>& cands) {
  double lo = std::numeric_limits<double>::infinity(), hi = 0;
  int usable = 0;
  for (const auto& c : cands)
    if (c.score.usable) {
      lo = std::min(lo, c.focal);
      hi = std::max(hi, c.focal);
      ++usable;
    }
  if (usable < 2) return 0;
  const auto& best = cands[best_focal_candidate(cands)];
  if (best.focal == hi) return hi * kFocalGridStep;
  if (best.focal == lo) return lo / kFocalGridStep;
  return 0;
}

// The focal length to map last: the vertex of the parabola through the best
// usable candidate and its usable neighbours in focal (score against log
// focal), when it lies between the neighbours, away from all three; the grid's
// spacing alone would leave up to half a step of focal error. 0 when the best
// has no neighbour on one side or the parabola opens downwards.
template <class Candidate>
double focal_parabola_vertex(const std::vector<Candidate>& cands) {
  const std::size_t best = best_focal_candidate(cands);
  if (!cands[best].score.usable) return 0;
  const Candidate* l = nullptr;
  const Candidate* h = nullptr;
  for (const auto& c : cands) {
    if (!c.score.usable) continue;
    if (c.focal < cands[best].focal && (!l || c.focal > l->focal)) l = &c;
    if (c.focal > cands[best].focal && (!h || c.focal < h->focal)) h = &c;
  }
  if (!l || !h) return 0;
  const Candidate& m = cands[best];
  const double x0 = std::log(l->focal), x1 = std::log(m.focal), x2 = std::log(h->focal);
  const double d0 = (m.score.value - l->score.value) / (x1 - x0), d1 = (h->score.value - m.score.value) / (x2 - x1);
  const double curvature = (d1 - d0) / (x2 - x0);
  if (!(curvature > 0)) return 0;
  const double xv = std::clamp(0.5 * (x0 + x1) - d0 / (2 * curvature), x0, x2);
  if (std::abs(xv - x1) > 0.01 && std::abs(xv - x0) > 0.01 && std::abs(xv - x2) > 0.01) return std::exp(xv);
  return 0;
}

// The search after the mapper's own estimate (cands.front()): its multiples
// `factors`, the grid stepped beyond its edge while the edge wins (at most
// twice: up to 1.25 x 1.15^2 = 1.65 times the estimate), then the parabola's
// vertex. map(focal, how) maps at a focal length and appends the scored
// candidate to cands.
template <class Candidate, class Map>
void search_focal_grid(std::vector<Candidate>& cands, const std::vector<double>& factors, Map&& map) {
  const double estimate = cands.front().focal;
  for (double f : factors) map(estimate * f, "orbit fit");
  for (int step = 0; step < 2; ++step) {
    const double beyond = focal_grid_extension(cands);
    if (beyond <= 0) break;
    map(beyond, "orbit fit (grid extended)");
  }
  const double vertex = focal_parabola_vertex(cands);
  if (vertex > 0) map(vertex, "orbit fit (refined)");
}

// Maps the source frames (features and matches already in colmap_dir/database.db)
// and chooses the focal length: the user's when given, else the best-scoring of
// the mapper's own estimate and its multiples p.focal_factors. `timed` runs a
// command with its log file name and returns its seconds.
inline FocalChoice map_source_frames(const std::string& colmap_dir, const std::string& images,
                                     const std::vector<std::string>& source_names, const CameraStageParams& p,
                                     const std::function<double(const ToolCommand&, const std::string&)>& timed) {
  namespace fs = std::filesystem;
  ensure(!source_names.empty(), "cameras stage: no source frames to map");
  const fs::path database = fs::path(colmap_dir) / "database.db";
  const int expected = int(source_names.size());
  struct Candidate {
    std::string dir, how;
    double focal = 0, factor = 0, seconds = 0;
    OrbitFitScore score;
  };
  std::vector<Candidate> cands;
  auto fixed = [&](double focal, double factor, const std::string& how, int width, int height,
                   const std::string& camera_model) {
    std::ostringstream name;
    name << "focal_" << std::lround(focal * 10) / 10.0;
    const fs::path dir = fs::path(colmap_dir) / "fixed" / name.str();
    write_colmap_camera_only((dir / "camera").string(), camera_model, width, height, focal);
    fs::create_directories(dir / "model");
    Candidate c{(dir / "model").string(), how, focal, factor, 0, {}};
    try {
      c.seconds = timed(colmap_mapper_fixed_focal_command(database.string(), images, (dir / "camera").string(),
                                                          c.dir, p),
                        "mapper_" + name.str() + ".log");
      c.score = orbit_fit_score(model_source_cameras(c.dir), expected);
    } catch (const std::exception& e) {
      c.score.why = e.what();  // a focal the mapper cannot work with loses; the others go on
    }
    cands.push_back(c);
  };

  // The frames' size, for a given field of view and for the camera-only models.
  const Image<float> first = read_image<float>((fs::path(images) / source_names.front()).string());
  const double given = p.focal_px > 0 ? p.focal_px : p.fov_deg > 0 ? focal_from_fov(p.fov_deg, first.width) : 0;
  FocalChoice choice;
  if (given > 0) {
    fixed(given, 1, "given", first.width, first.height, p.camera_model);
    if (!cands.front().score.usable && cands.front().score.why.empty()) cands.front().score.why = "unusable";
    ensure(fs::exists(fs::path(cands.front().dir) / "images.bin"), "colmap mapper registered none of the ",
           expected, " source frames at the given focal length ", given, " px (",
           cands.front().score.why, ")");
  } else {
    const fs::path raw = fs::path(colmap_dir) / "sparse";
    fs::create_directories(raw);
    Candidate free;
    free.how = "mapper";
    free.factor = 1;
    free.seconds = timed(colmap_mapper_command(database.string(), images, raw.string(), p), "mapper.log");
    std::size_t registered = 0;
    free.dir = largest_colmap_model(raw.string(), &registered);
    ensure(!free.dir.empty() && registered > 0, "colmap mapper registered none of the ", expected,
           " source frames (no model written); its log: ", (fs::path(colmap_dir).parent_path() / "logs/mapper.log").string());
    const ColmapModel m = read_colmap_model(free.dir);
    const ColmapCamera& cam = m.cameras.begin()->second;
    free.focal = cam.params.at(0);
    free.score = orbit_fit_score(model_source_cameras(free.dir), expected);
    cands.push_back(free);
    search_focal_grid(cands, p.focal_factors, [&](double focal, const char* how) {
      fixed(focal, focal / free.focal, how, cam.width, cam.height, p.camera_model);
    });
  }
  const std::size_t best = best_focal_candidate(cands);
  choice.model_dir = cands[best].dir;
  choice.focal_px = cands[best].focal;
  choice.how = given > 0 ? "given" : best == 0 ? "mapper" : "orbit fit";
  nlohmann::json list = nlohmann::json::array();
  for (const auto& c : cands)
    list.push_back({{"focal_px", c.focal}, {"factor", c.factor}, {"how", c.how}, {"seconds", c.seconds},
                    {"orbit_fit", to_json(c.score)}});
  choice.json = {{"focal_px", choice.focal_px},
                 {"chosen_by", choice.how},
                 {"mapper_estimate_px", given > 0 ? nlohmann::json(nullptr) : nlohmann::json(cands.front().focal)},
                 {"candidates", list}};
  std::ostringstream os;
  os.precision(4);
  os << "focal " << choice.focal_px << " px (" << choice.how;
  if (given <= 0 && cands.size() > 1) os << " of " << cands.size() << " candidates; the mapper's own " << cands.front().focal;
  os << ")";
  choice.summary = os.str();
  return choice;
}

}  // namespace orbitforge

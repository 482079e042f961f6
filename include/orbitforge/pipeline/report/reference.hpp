#pragma once
// Scoring on the user's path: cameras estimated from the source frames alone,
// judged against a reference model estimated from every frame.
//
// A user has only the source video, so the method's cameras (and everything
// after them: the orbit, the support bins, the completion request, G1's
// cameras) must come from the source frames alone. A reference model of the
// whole recorded orbit is evidence the method would not have; it reaches only
// what is evaluated:
//   - it is aligned to the estimated cameras by a similarity fitted on the
//     source frames' centres (geometry/camera_alignment.hpp), checked on their
//     rotations;
//   - frames outside the source get the aligned reference camera (with the
//     reference intrinsics) and the reference image: the oracle completion
//     provider and the gap scores read them, as they read a recorded model's;
//   - withheld source frames are scored twice: at the camera the user's
//     estimator gave them (the user has it), and at the aligned reference
//     camera (PipelineInput::scoring_cameras), where a wrong focal length or a
//     drifting arc shows, and so does the two estimates' own disagreement
//     (a few tenths of a degree per frame costs several dB on sharp frames).
// Training frames, sparse points and the orbit fit never see the reference.
#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/camera_alignment.hpp"
#include "orbitforge/geometry/orbit.hpp"
#include "orbitforge/geometry/orbit_loop.hpp"
#include "orbitforge/pipeline/inputs/recorded_input.hpp"

namespace orbitforge {

// Attaches `ref` (the same video's frames in the same order, loaded at the
// input's working size) to `user`, whose cameras were estimated from the source
// frames only. Call after the withheld frames are chosen. Returns the alignment.
template <class Scalar>
CameraAlignment attach_reference(PipelineInput<Scalar>& user, const PipelineInput<Scalar>& ref,
                                 const std::string& ref_description) {
  ensure(user.cameras.size() == ref.cameras.size(), "reference ", ref_description, ": ", ref.cameras.size(),
         " frames, the input has ", user.cameras.size(), " (the reference must be the same video's frames)");
  ensure(user.width == ref.width && user.height == ref.height, "reference ", ref_description, ": loaded at ",
         ref.width, "x", ref.height, ", the input works at ", user.width, "x", user.height);
  std::vector<Camera<Scalar>> from, to;
  for (int f : user.source) {
    const auto& rc = ref.cameras[std::size_t(f)];
    if (!rc.valid || !camera_problem(rc).empty()) continue;
    from.push_back(rc.camera);
    to.push_back(user.cameras[std::size_t(f)].camera);
  }
  ensure(from.size() >= 3, "reference ", ref_description, ": only ", from.size(),
         " source frames have a camera in both the input and the reference; 3 are needed to align them");
  const CameraAlignment a = align_camera_centres(from, to);

  std::vector<char> is_source(user.cameras.size(), 0);
  for (int f : user.source) is_source[std::size_t(f)] = 1;
  user.scoring_cameras.clear();
  for (std::size_t i = 0; i < user.cameras.size(); ++i) {
    const auto& rc = ref.cameras[i];
    const bool usable = rc.valid && !ref.images[i].empty() && camera_problem(rc).empty();
    if (is_source[i]) {
      if (usable && user.is_withheld(int(i))) user.scoring_cameras[int(i)] = a.transform.apply(rc.camera);
      continue;
    }
    if (i >= std::size_t(user.source_first) && i <= std::size_t(user.source_last)) continue;  // skipped source frame
    user.cameras[i].valid = usable;
    user.images[i] = usable ? ref.images[i] : Image<Scalar>();
    if (usable) user.cameras[i].camera = a.transform.apply(rc.camera);
  }
  ReferenceInfo<Scalar> info;
  info.description = ref_description;
  info.alignment = a;
  for (int f : user.source)
    if (ref.cameras[std::size_t(f)].valid) info.source_cameras[f] = a.transform.apply(ref.cameras[std::size_t(f)].camera);
  user.reference = std::move(info);
  return a;
}

// A camera alignment's figures for report.json: pairs, scale and residuals.
inline nlohmann::json camera_alignment_json(const CameraAlignment& a) {
  return {{"cameras", a.cameras},
          {"scale", a.transform.scale},
          {"centre_rms_relative", a.centre_rms_relative},
          {"rotation_mean_deg", a.rotation_mean_deg},
          {"rotation_max_deg", a.rotation_max_deg}};
}

namespace reference_detail {

// Least-squares line through (x, y).
inline std::pair<double, double> line_fit(const std::vector<double>& x, const std::vector<double>& y) {
  const double n = double(x.size());
  double sx = 0, sy = 0, sxx = 0, sxy = 0;
  for (std::size_t i = 0; i < x.size(); ++i) {
    sx += x[i];
    sy += y[i];
    sxx += x[i] * x[i];
    sxy += x[i] * y[i];
  }
  const double d = n * sxx - sx * sx;
  const double slope = d != 0 ? (n * sxy - sx * sy) / d : 0;
  return {(sy - slope * sx) / n, slope};
}

}  // namespace reference_detail

// How the reference's own cameras go round the video (geometry/orbit_loop.hpp):
// a reference of a whole-orbit video whose last step is several mean steps
// wide was never told that its loop closes. Null with fewer than 4 cameras.
template <class Scalar>
nlohmann::json reference_loop_json(const PipelineInput<Scalar>& in) {
  if (!in.reference) return nullptr;
  std::vector<FrameCamera<Scalar>> cams;
  std::vector<int> frame;
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    const auto it = in.reference->source_cameras.find(int(i));
    const bool outside = int(i) < in.source_first || int(i) > in.source_last;
    if (it != in.reference->source_cameras.end())
      cams.push_back({in.cameras[i].name, it->second, true});
    else if (outside && in.cameras[i].valid)
      cams.push_back(in.cameras[i]);
    else
      continue;
    frame.push_back(int(i));
  }
  if (cams.size() < 4) return nullptr;
  const OrbitLoop l = orbit_loop(cams, frame);
  return {{"frames", l.cameras},
          {"mean_step_deg", l.mean_step_deg},
          {"largest_step_deg", l.largest_step_deg},
          {"last_to_first_deg", l.last_to_first_deg}};
}

// What the reference says of the estimated cameras and the fitted orbit:
// the alignment's residuals; the source arc on the fitted orbit by the user's
// cameras and by the reference on an orbit fitted to its own cameras; the focal lengths (at the working
// size); and, for every frame outside the source, how far its reference camera
// lies from where the fitted orbit's constant-speed motion puts that frame.
template <class Scalar>
nlohmann::json reference_report(const PipelineInput<Scalar>& in, const OrbitFit<Scalar>& fit) {
  if (!in.reference) return nullptr;
  const CameraAlignment& a = in.reference->alignment;
  const auto& g = fit.orbit;
  auto azimuth = [&](const Camera<Scalar>& c) {
    return double(orbit_azimuth_deg<Scalar>(c.center(), g.center, g.e1, g.e2));
  };
  // Source azimuths, unwrapped along the frame order, against frame numbers.
  std::vector<double> frame, az;
  for (int f : in.source) {
    const double v = azimuth(in.cameras[std::size_t(f)].camera);
    frame.push_back(f);
    az.push_back(az.empty() ? v : az.back() + wrap_deg_180(v - az.back()));
  }
  const auto [a0, speed] = reference_detail::line_fit(frame, az);
  double sum_abs = 0, max_abs = 0;
  int n = 0;
  std::vector<char> is_source(in.cameras.size(), 0);
  for (int f : in.source) is_source[std::size_t(f)] = 1;
  for (std::size_t i = 0; i < in.cameras.size(); ++i) {
    if (is_source[i] || !in.cameras[i].valid) continue;
    if (int(i) >= in.source_first && int(i) <= in.source_last) continue;
    const double predicted = a0 + speed * double(i);
    const double err = wrap_deg_180(azimuth(in.cameras[i].camera) - predicted);
    sum_abs += std::abs(err);
    max_abs = std::max(max_abs, std::abs(err));
    ++n;
  }
  // The reference's own source arc, on an orbit fitted to its own cameras: on
  // the user's orbit a bent estimate would bend the yardstick too.
  std::vector<FrameCamera<Scalar>> ref_source;
  std::vector<double> ref_focal, user_focal;
  for (const auto& [f, c] : in.reference->source_cameras) {
    ref_source.push_back({std::to_string(f), c, true});
    ref_focal.push_back(double(c.intrinsics.fx));
  }
  double ref_arc = 0;
  if (ref_source.size() >= 3) {
    OrbitParams own;
    own.views = std::max(fit.views, 4);
    ref_arc = double(fit_orbit(ref_source, own).diagnostics.source_span_deg);
  }
  for (int f : in.source) user_focal.push_back(double(in.cameras[std::size_t(f)].camera.intrinsics.fx));
  auto median = [](std::vector<double> v) {
    if (v.empty()) return 0.0;
    std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(v.size() / 2), v.end());
    return v[v.size() / 2];
  };
  return {{"reference", in.reference->description},
          {"alignment", camera_alignment_json(a)},
          {"source_arc_deg", {{"user", double(fit.diagnostics.source_span_deg)}, {"reference", ref_arc}}},
          {"focal_px", {{"user", median(user_focal)}, {"reference", median(ref_focal)}}},
          {"orbit_speed_deg_per_frame", speed},
          {"loop", reference_loop_json(in)},
          {"gap_azimuth_error_deg", {{"frames", n}, {"mean_abs", n ? sum_abs / n : 0.0}, {"max_abs", max_abs}}}};
}

// The same frames' cameras in two estimates (`from`, `to`) and each frame's
// place on the canonical orbit (in views), for carrying a camera from one
// estimate into the other.
template <class Scalar>
struct EstimatePairs {
  std::vector<double> position;
  std::vector<Camera<Scalar>> from, to;
  int views = 0;  // the orbit's period, for distances along it
  CameraAlignment global;  // from -> to, fitted on every pair
};

template <class Scalar>
EstimatePairs<Scalar> estimate_pairs(std::vector<double> position, std::vector<Camera<Scalar>> from,
                                     std::vector<Camera<Scalar>> to, int views) {
  EstimatePairs<Scalar> e;
  e.global = align_camera_centres(from, to);
  e.position = std::move(position);
  e.from = std::move(from);
  e.to = std::move(to);
  e.views = views;
  return e;
}

// `cam` of `from`'s estimate, at orbit position `position`, in `to`'s: moved
// by the similarity fitted on every pair, then turned and shifted by the mean
// disagreement that remains at its `k` nearest pairs along the orbit. Two
// estimates of one orbit differ by more than a similarity (a degree or so from
// frame to frame on the recorded videos), slowly along the orbit, so a held-out
// view is placed as its neighbours are. The frame's own image plays no part.
template <class Scalar>
Camera<Scalar> carry_camera(const Camera<Scalar>& cam, double position, const EstimatePairs<Scalar>& e, int k) {
  const Camera<double> moved = e.global.transform.apply(cam).template cast<double>();
  std::vector<std::pair<double, std::size_t>> by_distance;
  const double period = double(std::max(e.views - 1, 1));
  for (std::size_t i = 0; i < e.position.size(); ++i) {
    const double d = std::abs(wrap_deg_180((e.position[i] - position) * 360.0 / period));
    by_distance.push_back({d, i});
  }
  const std::size_t n = std::min(by_distance.size(), std::size_t(std::max(k, 0)));
  if (n == 0) return moved.template cast<Scalar>();
  std::partial_sort(by_distance.begin(), by_distance.begin() + std::ptrdiff_t(n), by_distance.end());
  Eigen::Vector3d turn = Eigen::Vector3d::Zero(), shift = Eigen::Vector3d::Zero();
  for (std::size_t j = 0; j < n; ++j) {
    const std::size_t i = by_distance[j].second;
    const Camera<double> a = e.global.transform.apply(e.from[i]).template cast<double>();
    const Camera<double> b = e.to[i].template cast<double>();
    // world_R_camera of b times its inverse of a: the world-frame turn from a to b.
    const Eigen::AngleAxisd d(Eigen::Matrix3d(b.R.transpose() * a.R));
    turn += d.angle() * d.axis() / double(n);
    shift += (b.center() - a.center()) / double(n);
  }
  const double angle = turn.norm();
  const Eigen::Matrix3d world_turn =
      angle > 0 ? Eigen::AngleAxisd(angle, turn / angle).toRotationMatrix() : Eigen::Matrix3d::Identity();
  const Eigen::Matrix3d world_R_camera = world_turn * moved.R.transpose();
  return Camera<double>::from_world_T_camera(world_R_camera, moved.center() + shift, moved.intrinsics)
      .template cast<Scalar>();
}

}  // namespace orbitforge

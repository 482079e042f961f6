#pragma once
// Canonical 360-degree orbit from estimated source cameras (paper appendix
// "Canonical Orbit Construction and Coverage-Aware Completion"):
//
//  1. successful camera set: valid, finite, proper rotation, positive focal;
//  2. forward-axis convention with the smallest mean look-at ray angle, and the
//     least-squares look-at point x_look (Eq. lookat-fit);
//  3. orbit plane by SVD of the centres, normal sign by camera up / look-down;
//  4. circle in the plane (geometric by default; Kasa = the paper's Eq. circle-fit),
//     c_orb = o-bar + a e1 + b e2; then, by default (OrbitCenter::look_at), the
//     centre is replaced by the look-at point projected onto the plane and r by
//     the mean in-plane distance of the centres from it. Why: on a 113-128 degree
//     source arc the circle centre is poorly pinned along the arc's bisector,
//     while the optical axes of an object-centred orbit pin it across the arc.
//     On the five recorded v3d videos (fit frames 1-33, predict 34-90) the mean
//     held-out azimuth error is 0.93/0.07/0.15/0.23/0.32 degrees with the look-at
//     centre vs 1.11/0.06/0.14/0.35/0.20 with the circle centre (worst video
//     1.11 -> 0.93; Kasa and geometric give the same there). OrbitCenter::circle
//     is the paper's literal choice. diagnostics.center_offset reports the
//     distance between the two centres relative to r, so a source whose cameras
//     do not aim at the orbit axis shows up;
//  5. theta0 = azimuth of the first successful camera; d = sign of the sum of
//     the wrapped azimuth steps (+1 when it is 0); e2 = n x e1 so that +theta is
//     counter-clockwise seen from +n;
//     theta_i = theta0 + d 360 i / (N - 1),
//     o_i = c_orb + r cos(theta_i) e1 + r sin(theta_i) e2 + r tan(offset) n,
//     camera i = look_at(o_i, x_look, up = n) (no roll);
//  6. intrinsics: median over sources of f * H_render / H_source, principal point
//     at the render grid's centre;
//  7. binning (binning.hpp) and fitting diagnostics.
// Azimuths are in degrees, measured about the fitted centre in the (e1, e2) frame.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/geometry/angles.hpp"
#include "orbitforge/geometry/axis_convention.hpp"
#include "orbitforge/geometry/binning.hpp"
#include "orbitforge/geometry/circle_fit.hpp"
#include "orbitforge/geometry/lookat.hpp"
#include "orbitforge/geometry/plane_fit.hpp"

namespace orbitforge {

// Which point is the orbit centre (see the header comment).
enum class OrbitCenter { look_at, circle };

inline const char* orbit_center_name(OrbitCenter c) { return c == OrbitCenter::look_at ? "look_at" : "circle"; }

// The most canonical views an orbit may have: one each 0.01 degree. Checked
// before anything is allocated, so a mistyped count is refused at once.
constexpr int kMaxOrbitViews = 36001;

struct OrbitParams {
  int views = 361;                   // the paper's N: 0, 1, ..., 360 degrees (the last repeats the first)
  int width = 896, height = 512;     // the paper's canonical render size
  double elevation_offset_deg = 10;  // the paper's: canonical cameras sit 10 degrees above the source plane
                                     // (0 keeps them at the source cameras' height)
  CircleFitMethod circle_fit = CircleFitMethod::geometric;
  OrbitCenter center = OrbitCenter::look_at;
  std::optional<ForwardConvention> convention;  // empty: select automatically
  LookAtParams look_at;
  PlaneFitParams plane;
  double rotation_tolerance = 1e-3;  // |R R^T - I|_max above which a frame is skipped
};

// One source frame's usability (the paper's "successful camera set").
template <class Scalar>
std::string camera_problem(const FrameCamera<Scalar>& f, double rotation_tolerance = 1e-3) {
  if (!f.valid) return "not registered";
  if (!f.camera.is_finite()) return "non-finite pose or intrinsics";
  const auto& R = f.camera.R;
  const Scalar dev = (R * R.transpose() - Eigen::Matrix<Scalar, 3, 3>::Identity()).cwiseAbs().maxCoeff();
  if (!(dev <= Scalar(rotation_tolerance)) || !(R.determinant() > 0)) return "rotation is not a proper rotation";
  if (!(f.camera.intrinsics.fx > 0) || !(f.camera.intrinsics.fy > 0)) return "non-positive focal length";
  if (f.camera.intrinsics.height <= 0 || f.camera.intrinsics.width <= 0) return "unknown image size";
  return {};
}

struct SkippedCamera {
  std::string name;
  std::string reason;
};

template <class Scalar>
struct SuccessfulCameras {
  std::vector<int> indices;  // into the input list
  std::vector<SkippedCamera> skipped;
};

template <class Scalar>
SuccessfulCameras<Scalar> successful_cameras(const std::vector<FrameCamera<Scalar>>& source,
                                             double rotation_tolerance = 1e-3) {
  SuccessfulCameras<Scalar> s;
  for (std::size_t i = 0; i < source.size(); ++i) {
    const std::string why = camera_problem(source[i], rotation_tolerance);
    if (why.empty())
      s.indices.push_back(int(i));
    else
      s.skipped.push_back({source[i].name, why});
  }
  return s;
}

// Azimuth (degrees, (-180, 180]) of p about `center` in the (e1, e2) frame.
template <class Scalar>
Scalar orbit_azimuth_deg(const Eigen::Matrix<Scalar, 3, 1>& p, const Eigen::Matrix<Scalar, 3, 1>& center,
                         const Eigen::Matrix<Scalar, 3, 1>& e1, const Eigen::Matrix<Scalar, 3, 1>& e2) {
  const Eigen::Matrix<Scalar, 3, 1> d = p - center;
  return Constants<Scalar>::rad2deg(std::atan2(d.dot(e2), d.dot(e1)));
}

// d = sign of the sum of wrapped azimuth steps in source order (+1 for a zero sum).
template <class Scalar>
int motion_direction(const std::vector<Scalar>& azimuth_deg) {
  double sum = 0;
  for (std::size_t t = 1; t < azimuth_deg.size(); ++t)
    sum += wrap_deg_180(double(azimuth_deg[t]) - double(azimuth_deg[t - 1]));
  return sum < 0 ? -1 : 1;
}

template <class Scalar>
struct OrbitGeometry {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  Vec3 center = Vec3::Zero();  // c_orb
  Vec3 normal = Vec3::UnitZ(), e1 = Vec3::UnitX(), e2 = Vec3::UnitY();
  Scalar radius = 1;
  Vec3 look_at = Vec3::Zero();
  Scalar theta0_deg = 0;
  int direction = 1;
  Scalar elevation_offset_deg = 0;
  // Azimuth of canonical view i.
  Scalar azimuth_deg(int i, int views) const {
    return theta0_deg + Scalar(direction) * Scalar(360) * Scalar(i) / Scalar(views - 1);
  }
  Vec3 position(Scalar azimuth_deg_) const {
    const Scalar a = Constants<Scalar>::deg2rad(azimuth_deg_);
    return center + radius * std::cos(a) * e1 + radius * std::sin(a) * e2 +
           radius * std::tan(Constants<Scalar>::deg2rad(elevation_offset_deg)) * normal;
  }
};

// The canonical cameras o_0 .. o_{N-1}.
template <class Scalar>
std::vector<Camera<Scalar>> canonical_cameras(const OrbitGeometry<Scalar>& g, int views,
                                              const Intrinsics<Scalar>& k) {
  ensure(views >= 2 && views <= kMaxOrbitViews, "canonical_cameras: views must lie in [2, ", kMaxOrbitViews,
         "], got ", views);
  std::vector<Camera<Scalar>> cams;
  cams.reserve(views);
  for (int i = 0; i < views; ++i)
    cams.push_back(Camera<Scalar>::look_at(g.position(g.azimuth_deg(i, views)), g.look_at, g.normal, k));
  return cams;
}

// Median source focal scaled by H_render / H_source; principal point at the centre.
template <class Scalar>
Intrinsics<Scalar> canonical_intrinsics(const std::vector<Camera<Scalar>>& source, int width, int height) {
  ensure(!source.empty(), "canonical_intrinsics: no source cameras");
  ensure(width > 0 && height > 0, "canonical_intrinsics: render size ", width, "x", height);
  std::vector<Scalar> fx, fy;
  for (const auto& c : source) {
    ensure(c.intrinsics.height > 0, "canonical_intrinsics: source camera without image height");
    const Scalar s = Scalar(height) / Scalar(c.intrinsics.height);
    fx.push_back(c.intrinsics.fx * s);
    fy.push_back(c.intrinsics.fy * s);
  }
  auto median = [](std::vector<Scalar> v) {
    const std::size_t m = v.size() / 2;
    std::nth_element(v.begin(), v.begin() + m, v.end());
    if (v.size() % 2) return v[m];
    const Scalar hi = v[m];
    std::nth_element(v.begin(), v.begin() + m - 1, v.end());
    return (v[m - 1] + hi) / 2;
  };
  Intrinsics<Scalar> k;
  k.fx = median(fx);
  k.fy = median(fy);
  k.cx = Scalar(width) / 2;
  k.cy = Scalar(height) / 2;
  k.width = width;
  k.height = height;
  return k;
}

template <class Scalar>
struct OrbitDiagnostics {
  int cameras_used = 0;
  std::vector<std::string> cameras_skipped;  // names
  std::vector<std::string> skipped_reasons;  // parallel to cameras_skipped
  Scalar source_span_deg = 0;  // 360 - largest circular gap of the source azimuths
  Scalar circle_rmse = 0;
  Scalar radius_std = 0;
  Scalar height_std = 0;
  Scalar lookat_error_deg = 0;
  Scalar center_offset = 0;  // |circle-fit centre - projected look-at point| / r
  std::string center_rule;   // "look_at" or "circle"
  std::string convention;
  std::string normal_rule;
  int observed_bins = 0;
  int gap_bins = 0;
};

template <class Scalar>
struct SourceBin {
  std::string name;
  int input_index = 0;  // index into the input list
  int bin = 0;
  Scalar azimuth_deg = 0;  // about the fitted centre, (-180, 180]
};

template <class Scalar>
struct OrbitFit {
  OrbitGeometry<Scalar> orbit;
  PlaneFit<Scalar> plane;
  Circle2<Scalar> circle;  // in plane coordinates about plane.centroid
  ConventionChoice<Scalar> convention;
  Intrinsics<Scalar> intrinsics;
  std::vector<Camera<Scalar>> cameras;  // N canonical cameras
  std::vector<SourceBin<Scalar>> source;
  SupportBins support;
  OrbitDiagnostics<Scalar> diagnostics;
  int views = 0;
};

// 360 minus the largest circular gap between the sorted azimuths (degrees).
template <class Scalar>
Scalar azimuth_span_of(std::vector<Scalar> az) {
  if (az.size() < 2) return 0;
  for (auto& a : az) a = wrap_deg_360(a);
  std::sort(az.begin(), az.end());
  Scalar gap = az.front() + Scalar(360) - az.back();
  for (std::size_t i = 1; i < az.size(); ++i) gap = std::max(gap, az[i] - az[i - 1]);
  return Scalar(360) - gap;
}

template <class Scalar>
OrbitFit<Scalar> fit_orbit(const std::vector<FrameCamera<Scalar>>& source, const OrbitParams& p = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Vec2 = Eigen::Matrix<Scalar, 2, 1>;
  ensure(p.views >= 3 && p.views <= kMaxOrbitViews, "fit_orbit: canonical views must lie in [3, ", kMaxOrbitViews,
         "] (one each 0.01 degree at most), got ", p.views);
  ensure(p.width > 0 && p.height > 0, "fit_orbit: render size ", p.width, "x", p.height);
  ensure(std::isfinite(p.elevation_offset_deg) && std::abs(p.elevation_offset_deg) < 89,
         "fit_orbit: elevation offset ", p.elevation_offset_deg, " outside (-89, 89) degrees");
  OrbitFit<Scalar> fit;
  fit.views = p.views;

  // 1. successful camera set
  const auto ok = successful_cameras(source, p.rotation_tolerance);
  for (const auto& s : ok.skipped) {
    fit.diagnostics.cameras_skipped.push_back(s.name);
    fit.diagnostics.skipped_reasons.push_back(s.reason);
  }
  if (ok.indices.size() < 3) {
    // Say why the others were skipped: the reasons, each with how many cameras and a first example.
    std::map<std::string, std::pair<int, std::string>> why;
    for (const auto& s : ok.skipped) {
      auto& w = why[s.reason];
      if (w.first++ == 0) w.second = s.name;
    }
    std::ostringstream os;
    for (const auto& [reason, w] : why)
      os << "; " << w.first << " skipped: " << reason << " (e.g. '" << w.second << "')";
    fail("fit_orbit: need at least 3 usable source cameras, got ", ok.indices.size(), " of ", source.size(), os.str());
  }
  std::vector<Camera<Scalar>> cams;
  for (int i : ok.indices) cams.push_back(source[i].camera);
  fit.diagnostics.cameras_used = int(cams.size());

  // 2. forward convention and look-at point
  if (p.convention) {
    std::vector<Vec3> o, d;
    for (const auto& c : cams) {
      o.push_back(c.center());
      d.push_back(forward_axis<Scalar>(c.R, *p.convention));
    }
    const auto la = fit_lookat_point(o, d, p.look_at);
    fit.convention.convention = *p.convention;
    fit.convention.error_deg = la.mean_angle_deg;
    fit.convention.look_at = la.point;
  } else {
    fit.convention = select_forward_convention(cams, p.look_at);
  }
  const ForwardConvention conv = fit.convention.convention;

  // 3. plane
  std::vector<Vec3> centres;
  Vec3 mean_up = Vec3::Zero(), mean_fwd = Vec3::Zero();
  for (const auto& c : cams) {
    centres.push_back(c.center());
    mean_up += up_axis<Scalar>(c.R, conv).normalized();
    mean_fwd += forward_axis<Scalar>(c.R, conv).normalized();
  }
  mean_up /= Scalar(cams.size());
  mean_fwd /= Scalar(cams.size());
  fit.plane = fit_plane(centres, mean_up, mean_fwd, p.plane);

  // 4. circle
  std::vector<Vec2> uv;
  for (const auto& c : centres) uv.push_back(fit.plane.to_plane(c));
  CircleFitParams cp;
  cp.method = p.circle_fit;
  fit.circle = fit_circle(uv, cp);
  ensure(fit.circle.radius > 0 && std::isfinite(fit.circle.radius), "fit_orbit: circle fit gave radius ",
         fit.circle.radius);
  const Vec2 look_uv = fit.plane.to_plane(fit.convention.look_at);
  fit.diagnostics.center_offset = (look_uv - fit.circle.center).norm() / fit.circle.radius;
  fit.diagnostics.center_rule = orbit_center_name(p.center);
  if (p.center == OrbitCenter::look_at) {
    Scalar sum = 0;
    for (const auto& q : uv) sum += (q - look_uv).norm();
    fit.circle.center = look_uv;
    fit.circle.radius = sum / Scalar(uv.size());
    fit.circle.iterations = 0;
    ensure(fit.circle.radius > 0, "fit_orbit: every camera centre projects onto the look-at point");
    detail::circle_residual_stats(uv, fit.circle);
  }

  auto& g = fit.orbit;
  g.normal = fit.plane.normal;
  g.e1 = fit.plane.e1;
  g.e2 = fit.plane.e2;
  g.center = fit.plane.centroid + fit.circle.center.x() * g.e1 + fit.circle.center.y() * g.e2;
  g.radius = fit.circle.radius;
  g.look_at = fit.convention.look_at;
  g.elevation_offset_deg = Scalar(p.elevation_offset_deg);

  // 5. start angle and direction
  std::vector<Scalar> az;
  for (const auto& c : centres) az.push_back(orbit_azimuth_deg<Scalar>(c, g.center, g.e1, g.e2));
  g.theta0_deg = az.front();
  g.direction = motion_direction(az);

  // 6. intrinsics and cameras
  fit.intrinsics = canonical_intrinsics(cams, p.width, p.height);
  fit.cameras = canonical_cameras(g, p.views, fit.intrinsics);

  // 7. bins and diagnostics
  fit.support = bin_sources(az, g.theta0_deg, g.direction, p.views);
  for (std::size_t t = 0; t < cams.size(); ++t)
    fit.source.push_back({source[ok.indices[t]].name, ok.indices[t], fit.support.source_bins[t], az[t]});
  auto& dg = fit.diagnostics;
  dg.source_span_deg = azimuth_span_of(az);
  dg.circle_rmse = fit.circle.rmse;
  dg.radius_std = fit.circle.radius_std;
  dg.height_std = fit.plane.height_std;
  dg.lookat_error_deg = fit.convention.error_deg;
  dg.convention = convention_name(conv);
  dg.normal_rule = fit.plane.normal_rule;
  dg.observed_bins = int(fit.support.observed.size());
  dg.gap_bins = int(fit.support.gap.size());
  return fit;
}

// fit_orbit where only the fitted circle, axes and source azimuths are used
// (checks and scores of the source cameras): the canonical views are rendered
// at a token size.
template <class Scalar>
OrbitFit<Scalar> fit_orbit_shape(const std::vector<FrameCamera<Scalar>>& source) {
  OrbitParams op;
  op.width = op.height = 64;
  return fit_orbit(source, op);
}

}  // namespace orbitforge

#pragma once
// Which axis of a recorded rotation is the camera's viewing ray.
//
// orbitforge's contract is x_cam = R x_world + t with OpenCV axes, so the
// forward ray in world coordinates is row 2 of R. Camera estimators and the
// readers in front of them do not always honour that: a rotation can arrive
// transposed (camera-to-world stored where world-to-camera was expected) or in
// OpenGL axes (camera looking along -z). The paper therefore tries several
// conventions and keeps the one whose rays meet best. Candidates, given R:
//
//   row2      R^T e_z = row 2    OpenCV world-to-camera (the contract). up = -row 1
//   neg_row2  -row 2             OpenGL world-to-camera (looks along -z). up = +row 1
//   col2      R e_z  = column 2  R is really camera-to-world (transposed), OpenCV axes. up = -column 1
//   neg_col2  -column 2          R is camera-to-world in OpenGL axes. up = +column 1
//
// Camera centres are NOT re-derived per convention: every candidate uses
// c = -R^T t. Reinterpreting [R | t] as camera-to-world would make the centre t,
// but for cameras aimed at an object near the world origin t = R (0 - c) is the
// same (0, 0, distance) for every camera: all "centres" collapse onto one point
// whose rays meet there exactly, so such a candidate would win with zero error
// for any input. Centres are the reader's job (io/); only the forward axis (and
// with it the up axis used for the normal sign) is chosen here.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <vector>

#include "orbitforge/core/camera.hpp"
#include "orbitforge/geometry/lookat.hpp"

namespace orbitforge {

enum class ForwardConvention { row2, neg_row2, col2, neg_col2 };

inline const char* convention_name(ForwardConvention c) {
  switch (c) {
    case ForwardConvention::row2: return "row2";
    case ForwardConvention::neg_row2: return "neg_row2";
    case ForwardConvention::col2: return "col2";
    case ForwardConvention::neg_col2: return "neg_col2";
  }
  return "?";
}

inline ForwardConvention convention_from_name(const std::string& name) {
  for (auto c : {ForwardConvention::row2, ForwardConvention::neg_row2, ForwardConvention::col2,
                 ForwardConvention::neg_col2})
    if (name == convention_name(c)) return c;
  fail("convention_from_name: unknown forward convention '", name, "' (row2, neg_row2, col2, neg_col2)");
}

// The forward (viewing) ray of `R` under convention `c`, in world coordinates.
template <class Scalar>
Eigen::Matrix<Scalar, 3, 1> forward_axis(const Eigen::Matrix<Scalar, 3, 3>& R, ForwardConvention c) {
  switch (c) {
    case ForwardConvention::row2: return R.row(2).transpose();
    case ForwardConvention::neg_row2: return -R.row(2).transpose();
    case ForwardConvention::col2: return R.col(2);
    case ForwardConvention::neg_col2: return -R.col(2);
  }
  return R.row(2).transpose();
}

// The image-up axis (minus OpenCV y; plus y in OpenGL axes) under convention `c`.
template <class Scalar>
Eigen::Matrix<Scalar, 3, 1> up_axis(const Eigen::Matrix<Scalar, 3, 3>& R, ForwardConvention c) {
  switch (c) {
    case ForwardConvention::row2: return -R.row(1).transpose();
    case ForwardConvention::neg_row2: return R.row(1).transpose();
    case ForwardConvention::col2: return -R.col(1);
    case ForwardConvention::neg_col2: return R.col(1);
  }
  return -R.row(1).transpose();
}

template <class Scalar>
struct ConventionCandidate {
  ForwardConvention convention = ForwardConvention::row2;
  bool solvable = false;  // false when this convention's rays were near-parallel
  Scalar error_deg = std::numeric_limits<Scalar>::infinity();
  Eigen::Matrix<Scalar, 3, 1> look_at = Eigen::Matrix<Scalar, 3, 1>::Zero();
};

template <class Scalar>
struct ConventionChoice {
  ForwardConvention convention = ForwardConvention::row2;
  Scalar error_deg = 0;                          // mean look-at ray angle of the winner
  Eigen::Matrix<Scalar, 3, 1> look_at;           // its least-squares look-at point
  std::vector<ConventionCandidate<Scalar>> candidates;  // all four, in enum order
};

// Evaluates every candidate on `cameras` (all assumed usable) and keeps the one
// with the smallest mean angle between each camera's ray and the direction from
// its centre to that candidate's look-at point. Ties keep the earlier candidate
// (row2 first, the contract). Throws Error when no candidate is solvable.
template <class Scalar>
ConventionChoice<Scalar> select_forward_convention(const std::vector<Camera<Scalar>>& cameras,
                                                   const LookAtParams& params = {}) {
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  std::vector<Vec3> origins;
  origins.reserve(cameras.size());
  for (const auto& c : cameras) origins.push_back(c.center());
  ConventionChoice<Scalar> choice;
  bool any = false;
  std::string why;
  for (auto conv : {ForwardConvention::row2, ForwardConvention::neg_row2, ForwardConvention::col2,
                    ForwardConvention::neg_col2}) {
    ConventionCandidate<Scalar> cand;
    cand.convention = conv;
    std::vector<Vec3> dirs;
    dirs.reserve(cameras.size());
    for (const auto& c : cameras) dirs.push_back(forward_axis<Scalar>(c.R, conv));
    try {
      const auto fit = fit_lookat_point(origins, dirs, params);
      cand.solvable = true;
      cand.error_deg = fit.mean_angle_deg;
      cand.look_at = fit.point;
    } catch (const Error& e) {
      why = e.what();
    }
    if (cand.solvable && (!any || cand.error_deg < choice.error_deg)) {
      any = true;
      choice.convention = conv;
      choice.error_deg = cand.error_deg;
      choice.look_at = cand.look_at;
    }
    choice.candidates.push_back(cand);
  }
  ensure(any, "select_forward_convention: no forward-axis convention gives a look-at point: ", why);
  return choice;
}

}  // namespace orbitforge

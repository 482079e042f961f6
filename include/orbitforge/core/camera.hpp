#pragma once
// Pinhole cameras in ONE convention, used everywhere in orbitforge:
//
//   OpenCV axes: x right, y down, z forward (the camera looks along +z).
//   Pose: x_cam = R * x_world + t   (R, t = camera_T_world, "camera from world").
//   Pixel (i, j) has its centre at (i + 0.5, j + 0.5); u = fx * x / z + cx.
//
// Conversions to and from other conventions (OpenGL / nerfstudio camera-to-world,
// world_T_camera) live here and nowhere else.
#include <Eigen/Core>
#include <Eigen/Geometry>
#include <cmath>
#include <string>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"

namespace orbitforge {

template <class Scalar>
struct Intrinsics {
  Scalar fx = 1, fy = 1, cx = 0, cy = 0;
  int width = 0, height = 0;

  // The same camera on a resized image grid: focal lengths and principal point
  // scale with the grid.
  Intrinsics resized(int new_width, int new_height) const {
    ensure(width > 0 && height > 0, "Intrinsics::resized: source size is ", width, "x", height);
    Intrinsics k = *this;
    const Scalar sx = Scalar(new_width) / Scalar(width), sy = Scalar(new_height) / Scalar(height);
    k.fx *= sx; k.cx *= sx; k.fy *= sy; k.cy *= sy;
    k.width = new_width; k.height = new_height;
    return k;
  }
  Eigen::Matrix<Scalar, 3, 3> K() const {
    Eigen::Matrix<Scalar, 3, 3> m;
    m << fx, 0, cx, 0, fy, cy, 0, 0, 1;
    return m;
  }
  bool is_finite() const {
    return std::isfinite(fx) && std::isfinite(fy) && std::isfinite(cx) && std::isfinite(cy);
  }
  template <class T>
  Intrinsics<T> cast() const { return {T(fx), T(fy), T(cx), T(cy), width, height}; }
};

template <class Scalar>
struct Camera {
  using Vec2 = Eigen::Matrix<Scalar, 2, 1>;
  using Vec3 = Eigen::Matrix<Scalar, 3, 1>;
  using Mat3 = Eigen::Matrix<Scalar, 3, 3>;
  using Mat4 = Eigen::Matrix<Scalar, 4, 4>;

  Intrinsics<Scalar> intrinsics;
  Mat3 R = Mat3::Identity();  // camera_R_world
  Vec3 t = Vec3::Zero();      // camera_t_world

  // Camera centre in world coordinates.
  Vec3 center() const { return -R.transpose() * t; }
  // Camera axes expressed in the world frame (rows of R).
  Vec3 right() const { return R.row(0).transpose(); }
  Vec3 down() const { return R.row(1).transpose(); }
  Vec3 forward() const { return R.row(2).transpose(); }
  Vec3 up() const { return -down(); }

  Vec3 to_camera(const Vec3& x_world) const { return R * x_world + t; }
  // Pixel coordinates (continuous, centre of pixel i at i + 0.5) of a world point.
  Vec2 project(const Vec3& x_world) const {
    const Vec3 x = to_camera(x_world);
    return {intrinsics.fx * x.x() / x.z() + intrinsics.cx, intrinsics.fy * x.y() / x.z() + intrinsics.cy};
  }

  Mat4 camera_T_world() const {
    Mat4 m = Mat4::Identity();
    m.template topLeftCorner<3, 3>() = R;
    m.template topRightCorner<3, 1>() = t;
    return m;
  }
  Mat4 world_T_camera() const {
    Mat4 m = Mat4::Identity();
    m.template topLeftCorner<3, 3>() = R.transpose();
    m.template topRightCorner<3, 1>() = center();
    return m;
  }

  static Camera from_world_T_camera(const Mat3& world_R_camera, const Vec3& center_world,
                                    const Intrinsics<Scalar>& k = {}) {
    Camera c;
    c.intrinsics = k;
    c.R = world_R_camera.transpose();
    c.t = -c.R * center_world;
    return c;
  }

  // OpenGL / nerfstudio / instant-ngp camera-to-world: x right, y up, z backward.
  static Camera from_opengl_camera_to_world(const Mat4& c2w, const Intrinsics<Scalar>& k = {}) {
    Mat3 world_R_gl = c2w.template topLeftCorner<3, 3>();
    Mat3 world_R_cv = world_R_gl;
    world_R_cv.col(1) = -world_R_gl.col(1);
    world_R_cv.col(2) = -world_R_gl.col(2);
    return from_world_T_camera(world_R_cv, c2w.template topRightCorner<3, 1>(), k);
  }
  Mat4 to_opengl_camera_to_world() const {
    Mat4 m = world_T_camera();
    m.template block<3, 1>(0, 1) *= Scalar(-1);
    m.template block<3, 1>(0, 2) *= Scalar(-1);
    return m;
  }

  // A camera at `eye` looking at `target` with no roll: its image "up" (-y) is the
  // component of `up_hint` orthogonal to the viewing direction.
  static Camera look_at(const Vec3& eye, const Vec3& target, const Vec3& up_hint,
                        const Intrinsics<Scalar>& k = {}) {
    Vec3 f = target - eye;
    ensure(f.norm() > Constants<Scalar>::small(), "Camera::look_at: eye and target coincide");
    f.normalize();
    Vec3 right = f.cross(up_hint);  // x = y × z with y = down = -up
    ensure(right.norm() > Constants<Scalar>::small(),
           "Camera::look_at: viewing direction is parallel to the up vector");
    right.normalize();
    const Vec3 down = f.cross(right);
    Mat3 world_R_camera;
    world_R_camera.col(0) = right;
    world_R_camera.col(1) = down;
    world_R_camera.col(2) = f;
    return from_world_T_camera(world_R_camera, eye, k);
  }

  bool is_finite() const { return intrinsics.is_finite() && R.allFinite() && t.allFinite(); }

  template <class T>
  Camera<T> cast() const {
    Camera<T> c;
    c.intrinsics = intrinsics.template cast<T>();
    c.R = R.template cast<T>();
    c.t = t.template cast<T>();
    return c;
  }
};

// A source-video frame's camera as an estimator recorded it. `valid` is false
// for frames the estimator did not register (they stay listed so that frame
// numbering in image-name order is preserved).
template <class Scalar>
struct FrameCamera {
  std::string name;
  Camera<Scalar> camera;
  bool valid = true;
};

using Cameraf = Camera<float>;
using Camerad = Camera<double>;

}  // namespace orbitforge

// The perturbed provider's camera error: a frame's camera turned about the
// orbit's look-at point keeps its distance and its view of that point, and
// moves by the angle asked.
#include <catch2/catch.hpp>

#include <cmath>

#include "orbitforge/pipeline/completion/perturbed.hpp"

using namespace orbitforge;

namespace perturbed_completion_test {

TEMPLATE_TEST_CASE("turn_about_point moves a camera on a sphere about the pivot, still looking at it",
                   "[pipeline][perturbed]", float, double) {
  using S = TestType;
  using Vec3 = Eigen::Matrix<S, 3, 1>;
  const Intrinsics<S> k{S(100), S(100), S(64), S(64), 128, 128};
  const Vec3 pivot(S(0.3), S(-0.2), S(0.1));
  const Camera<S> cam = Camera<S>::look_at(Vec3(S(4), S(1), S(1.5)), pivot, Vec3(0, 0, 1), k);
  const double tol = std::is_same<S, float>::value ? 1e-3 : 1e-9;
  for (double deg : {1.0, 1.5, 2.0}) {
    const Camera<S> moved = perturb_detail::turn_about_point(cam, pivot, Vec3(S(0.2), S(1), S(-0.4)), deg);
    CHECK(std::abs(double((moved.center() - pivot).norm() - (cam.center() - pivot).norm())) < tol);
    const Vec3 a = (cam.center() - pivot).normalized(), b = (moved.center() - pivot).normalized();
    const double angle = std::acos(std::min(1.0, double(a.dot(b)))) * 180 / 3.14159265358979;
    CHECK(angle <= deg + 1e-3);          // the axis is not perpendicular to the view: at most deg
    CHECK(angle > 0.5 * deg);
    CHECK((moved.project(pivot) - cam.project(pivot)).norm() < S(100 * tol));  // still centred on the pivot
    CHECK(moved.R.determinant() > S(0.999));
  }
}

}  // namespace perturbed_completion_test

#pragma once
// The batch path of project_scene: simd::native_batch<Scalar>::size Gaussians at
// a time. Each lane's parameters are read through the adaptor into small
// structure-of-arrays buffers (any adaptor works), the projection runs in SIMD,
// and the results go to ProjectedSplats. project_gaussian stays the reference:
// the batch path gives the same culling reasons, radii and rectangles, and values
// within float rounding of it. Where a decision of the reference (near plane,
// opacity threshold, a ceil/floor of a rectangle bound or of the radius) lies
// within a bound on the rounding difference between the two (operations in
// another order, xsimd's exp and log for std's), project_gaussian makes that
// decision for the lane; where the 2D covariance is degenerate or overflows, or
// the scales overflow once activated, it gives the lane's values too. That is
// rare (about 2 in 100 Gaussians of the benchmark scene) and keeps the decisions
// identical.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <limits>

#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/project_gaussian.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_adaptor.hpp"

namespace orbitforge {

namespace detail {

// Each lane's parameters as one row (mean 3, quaternion 4, scale 3 as the
// adaptor returns it, opacity logit, padding, SH [3 k + c]), then transposed
// block by block into one row per parameter and a column per lane.
template <class Scalar, int W>
struct GaussianLanes {
  static constexpr int kMean = 0, kQuat = 3, kScale = 7, kLogit = 10, kSh = 16, kRow = 64;
  alignas(64) Scalar aos[W][kRow];
  alignas(64) Scalar soa[kRow][W];
  const Scalar* operator[](int row) const { return soa[row]; }
};

// Lanes j < count <- Gaussians i0 + j; the other lanes get harmless values.
// An adaptor with sh_data() has a whole batch's coefficients transposed from
// its memory, where the blocks' reads past the batch's last row (up to B::size
// - 1 values of the next Gaussian) stay inside the array; the rows past 3
// k_count are then unspecified, and unread.
template <class B, class Scene, class Scalar, int W>
inline void gather_lanes(const Scene& scene, std::size_t i0, int count, int k_count,
                         GaussianLanes<Scalar, W>& L) {
  using G = GaussianLanes<Scalar, W>;
  const std::size_t sh_values = std::size_t(3 * k_count);
  bool sh_direct = false;
  if constexpr (adaptor_detail::has_sh_data<Scene>::value) {
    const std::size_t blocks = (sh_values + std::size_t(W) - 1) / std::size_t(W);
    const std::size_t last_read = (i0 + std::size_t(W) - 1) * sh_values + blocks * std::size_t(W);
    sh_direct = count == W && last_read <= scene.size() * sh_values;
  }
  for (int j = 0; j < count; ++j) {
    const std::size_t i = i0 + std::size_t(j);
    Scalar* row = L.aos[j];
    scene.mean(i, row + G::kMean);
    scene.rotation(i, row + G::kQuat);
    scene.scale(i, row + G::kScale);
    row[G::kLogit] = scene.opacity_logit(i);
    if (sh_direct) continue;
    Scalar* sh = row + G::kSh;
    for (int k = 0; k < k_count; ++k)
      for (int c = 0; c < 3; ++c) sh[3 * k + c] = scene.sh(i, k, c);
  }
  for (int j = count; j < W; ++j)
    for (int r = 0; r < G::kRow; ++r) L.aos[j][r] = Scalar(r == G::kQuat);
  // Rows used: the parameters, then the SH rows.
  const int rows = G::kSh + (sh_direct ? 0 : int(sh_values));
  for (int r0 = 0; r0 < rows; r0 += W) simd::transpose_block<B>(&L.aos[0][r0], G::kRow, &L.soa[r0][0], W);
  if constexpr (adaptor_detail::has_sh_data<Scene>::value) {
    if (sh_direct) {
      const Scalar* sh = scene.sh_data() + i0 * sh_values;
      for (std::size_t r0 = 0; r0 < sh_values; r0 += std::size_t(W))
        simd::transpose_block<B>(sh + r0, sh_values, &L.soa[std::size_t(G::kSh) + r0][0], W);
    }
  }
}

// Distance from x to the nearest integer.
template <class B>
inline B dist_to_int(const B& x) { return simd::abs(x - simd::round_nearest(x)); }

// GCC 12 reports -Wuninitialized inside avx512fintrin.h for xsimd's AVX-512
// kernels once inlined here (the unmasked intrinsics pass _mm512_undefined_*():
// a false positive).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif
// The covariance chain shared by the forward and VJP batch paths: the rotation
// of q / |q|, Sigma = (R diag(s)) (R diag(s))^T, the EWA Jacobian with the x/z,
// y/z clamp, T = J W and cov2d = T Sigma T^T + eps2d I.
template <class B>
struct LanesCov2d {
  B qw, qx, qy, qz, qinv;         // q / |q| and 1 / |q|
  B Rq[3][3], Mq[3][3], S[3][3];  // rotation, Rq diag(s), Sigma
  B iz, iz2, ux, uy, clx, cly;    // 1 / t_z, t_x / t_z, t_y / t_z and their clamped values
  B j00, j02, j11, j12;           // J = [[j00, 0, j02], [0, j11, j12]]
  B T0[3], T1[3], TS0[3], TS1[3]; // the rows of T and of T Sigma
  B cov0, cov1, cov2;             // cov2d (xx, xy, yy)
};

template <class B, int W>
inline void lanes_cov2d(const ProjectionCamera<typename B::value_type>& cam,
                        const GaussianLanes<typename B::value_type, W>& L, const B t[3], const B s[3],
                        LanesCov2d<B>& c) {
  using Scalar = typename B::value_type;
  using G = GaussianLanes<Scalar, W>;
  const B one(Scalar(1)), two(Scalar(2));
  const B qw = B::load_unaligned(L[G::kQuat]), qx = B::load_unaligned(L[G::kQuat + 1]);
  const B qy = B::load_unaligned(L[G::kQuat + 2]), qz = B::load_unaligned(L[G::kQuat + 3]);
  c.qinv = one / simd::sqrt(qw * qw + qx * qx + qy * qy + qz * qz);
  c.qw = qw * c.qinv; c.qx = qx * c.qinv; c.qy = qy * c.qinv; c.qz = qz * c.qinv;
  const B &w = c.qw, &x = c.qx, &y = c.qy, &z = c.qz;
  c.Rq[0][0] = one - two * (y * y + z * z);
  c.Rq[0][1] = two * (x * y - w * z);
  c.Rq[0][2] = two * (x * z + w * y);
  c.Rq[1][0] = two * (x * y + w * z);
  c.Rq[1][1] = one - two * (x * x + z * z);
  c.Rq[1][2] = two * (y * z - w * x);
  c.Rq[2][0] = two * (x * z - w * y);
  c.Rq[2][1] = two * (y * z + w * x);
  c.Rq[2][2] = one - two * (x * x + y * y);
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) c.Mq[r][k] = c.Rq[r][k] * s[k];
  for (int r = 0; r < 3; ++r)
    for (int k = r; k < 3; ++k)
      c.S[r][k] = c.S[k][r] = c.Mq[r][0] * c.Mq[k][0] + c.Mq[r][1] * c.Mq[k][1] + c.Mq[r][2] * c.Mq[k][2];

  c.iz = one / t[2];
  c.iz2 = c.iz * c.iz;
  const B lx(cam.lim_x), ly(cam.lim_y), fx(cam.fx), fy(cam.fy);
  c.ux = t[0] * c.iz;
  c.uy = t[1] * c.iz;
  c.clx = simd::min(lx, simd::max(-lx, c.ux));
  c.cly = simd::min(ly, simd::max(-ly, c.uy));
  c.j00 = fx * c.iz;
  c.j02 = -fx * (c.clx * t[2]) * c.iz2;
  c.j11 = fy * c.iz;
  c.j12 = -fy * (c.cly * t[2]) * c.iz2;
  for (int k = 0; k < 3; ++k) {
    c.T0[k] = c.j00 * B(cam.R(0, k)) + c.j02 * B(cam.R(2, k));
    c.T1[k] = c.j11 * B(cam.R(1, k)) + c.j12 * B(cam.R(2, k));
  }
  for (int k = 0; k < 3; ++k) {
    c.TS0[k] = c.T0[0] * c.S[0][k] + c.T0[1] * c.S[1][k] + c.T0[2] * c.S[2][k];
    c.TS1[k] = c.T1[0] * c.S[0][k] + c.T1[1] * c.S[1][k] + c.T1[2] * c.S[2][k];
  }
  const B eps2d(cam.eps2d);
  c.cov0 = c.TS0[0] * c.T0[0] + c.TS0[1] * c.T0[1] + c.TS0[2] * c.T0[2] + eps2d;
  c.cov1 = c.TS0[0] * c.T1[0] + c.TS0[1] * c.T1[1] + c.TS0[2] * c.T1[2];
  c.cov2 = c.TS1[0] * c.T1[0] + c.TS1[1] * c.T1[1] + c.TS1[2] * c.T1[2] + eps2d;
}

// SH basis b[k] of each lane's viewing direction (mean - camera centre), and the
// unit direction d; returns 1 / |mean - centre| (0 for degree 0, which reads no
// direction).
template <class B>
inline B lanes_sh_basis(int degree, const B& x, const B& y, const B& z,
                        const ProjectionCamera<typename B::value_type>& cam, B b[16], B d[3]) {
  using Scalar = typename B::value_type;
  if (degree == 0) {
    b[0] = B(ShConstants<Scalar>::C0);
    return B(Scalar(0));
  }
  const B dx = x - B(cam.center[0]), dy = y - B(cam.center[1]), dz = z - B(cam.center[2]);
  const B inv = B(Scalar(1)) / simd::sqrt(dx * dx + dy * dy + dz * dz);
  d[0] = dx * inv;
  d[1] = dy * inv;
  d[2] = dz * inv;
  sh_basis(degree, d[0], d[1], d[2], b);
  return inv;
}

// Unclamped colour sum_k b[k] sh[k][c] + 0.5 of each lane, in sh_to_color's order.
template <class B, int W>
inline void lanes_sh_raw_color(int k_count, const B* b, const GaussianLanes<typename B::value_type, W>& L,
                               B raw[3]) {
  using Scalar = typename B::value_type;
  using G = GaussianLanes<Scalar, W>;
  for (int c = 0; c < 3; ++c) {
    B acc(Scalar(0));
    for (int k = 0; k < k_count; ++k) acc = acc + b[k] * B::load_unaligned(L[G::kSh + 3 * k + c]);
    raw[c] = acc + B(Scalar(0.5));
  }
}

// Outcome codes of a lane: CullReason values; kLaneScalar: project_gaussian
// gives everything (the batch values are unusable: overflow, degenerate 2D
// covariance); kLaneDecision: project_gaussian gives the decision (reason,
// radius, rectangle), the values are the batch's (so that they never depend on
// a decision, e.g. an image on tight_extents).
constexpr int kLaneScalar = 5, kLaneDecision = 6;

// Projects Gaussians i0 .. i0 + count - 1 (count <= B::size) into `out`,
// counting reasons into local[5].
template <class B, class Scene>
inline void project_lanes(const Scene& scene, const ProjectionCamera<typename B::value_type>& cam, int degree,
                          std::size_t i0, int count, GaussianLanes<typename B::value_type, int(B::size)>& L,
                          ProjectedSplats<typename B::value_type>& out, std::size_t local[5]) {
  using Scalar = typename B::value_type;
  using M = simd::mask_t<B>;
  constexpr int W = int(B::size);
  const int k_count = sh_coefficient_count(degree);
  gather_lanes<B>(scene, i0, count, k_count, L);
  using G = GaussianLanes<Scalar, W>;

  const B zero(Scalar(0)), one(Scalar(1)), half(Scalar(0.5));
  // The rounding difference of a short chain of operations evaluated in another
  // order, relative to the sum of the magnitudes of its terms (4 units in the
  // last place; the bounds below are sums of such terms, so generous: in 10^6
  // random Gaussians even 1/64 of this let no decision differ).
  const B tol(Scalar(4) * std::numeric_limits<Scalar>::epsilon());
  auto ld = [](const Scalar* p) { return B::load_unaligned(p); };

  // Non-finite inputs (x * 0 is NaN only for NaN and inf): certain, as in
  // project_gaussian, which checks the activated scales (exp(-inf) = 0 is fine).
  B p0 = zero, p1 = zero, p2 = zero, p3 = zero;
  for (int a = 0; a < 3; ++a) p0 = p0 + ld(L[G::kMean + a]) * zero;
  for (int a = 0; a < 4; ++a) p1 = p1 + ld(L[G::kQuat + a]) * zero;
  p3 = p3 + ld(L[G::kLogit]) * zero;
  for (int r = 0; r < 3 * k_count; r += 4) {
    p0 = p0 + ld(L[G::kSh + r]) * zero;
    if (r + 1 < 3 * k_count) p1 = p1 + ld(L[G::kSh + r + 1]) * zero;
    if (r + 2 < 3 * k_count) p2 = p2 + ld(L[G::kSh + r + 2]) * zero;
    if (r + 3 < 3 * k_count) p3 = p3 + ld(L[G::kSh + r + 3]) * zero;
  }
  B s[3], raw_poison = zero, act_poison = zero;
  for (int a = 0; a < 3; ++a) {
    const B raw = ld(L[G::kScale + a]);
    s[a] = Scene::scale_mode == ScaleMode::log ? simd::exp(raw) : raw;
    raw_poison = raw_poison + raw * zero;
    act_poison = act_poison + s[a] * zero;
  }
  const M bad_act = ~(act_poison <= zero);
  const M bad_in = ~((p0 + p1) + (p2 + p3) <= zero) | (bad_act & ~(raw_poison <= zero));
  M decided = bad_in;
  // Finite log-scales whose exp overflows (at the threshold xsimd's exp and
  // std::exp may disagree): the reference decides.
  M scalar = ~bad_in & bad_act;
  decided = decided | scalar;
  // Lanes where m holds and nothing is decided yet go to the reference.
  auto defer = [&](const M& m) {
    const M d = ~decided & m;
    scalar = scalar | d;
    decided = decided | d;
  };

  // Camera space, and bounds on its rounding difference (et: absolute).
  const B x = ld(L[G::kMean]), y = ld(L[G::kMean + 1]), z = ld(L[G::kMean + 2]);
  B t[3], et[3];
  for (int k = 0; k < 3; ++k) {
    t[k] = B(cam.R(k, 0)) * x + B(cam.R(k, 1)) * y + B(cam.R(k, 2)) * z + B(cam.t[k]);
    et[k] = tol * (B(std::abs(cam.R(k, 0))) * simd::abs(x) + B(std::abs(cam.R(k, 1))) * simd::abs(y) +
                   B(std::abs(cam.R(k, 2))) * simd::abs(z) + B(std::abs(cam.t[k])));
  }
  const B near(cam.near_plane);
  defer(simd::abs(t[2] - near) <= et[2]);
  const M cull_near = ~decided & (t[2] <= near);
  decided = decided | cull_near;

  LanesCov2d<B> c2;
  lanes_cov2d(cam, L, t, s, c2);
  const B &iz = c2.iz, &j00 = c2.j00, &j02 = c2.j02, &j11 = c2.j11, &j12 = c2.j12;
  const B &cov0 = c2.cov0, &cov1 = c2.cov1, &cov2 = c2.cov2;
  const B two(Scalar(2)), eps2d(cam.eps2d);
  const B lx(cam.lim_x), ly(cam.lim_y), fx(cam.fx), fy(cam.fy);
  const B det = cov0 * cov2 - cov1 * cov1;
  const B idet = one / det;
  const B conic0 = cov2 * idet, conic1 = -cov1 * idet, conic2 = cov0 * idet;

  // Bounds on the rounding differences: rz relative in t_z; rJ relative in J
  // (w.r.t. its norm); ecov, edet absolute.
  const B rz = et[2] * iz;
  const B rJ = rz * (one + B(Scalar(3)) * simd::max(lx, ly)) + (et[0] + et[1]) * iz + tol;
  const B smax2 = simd::max(s[0] * s[0], simd::max(s[1] * s[1], s[2] * s[2]));
  const B ecov = smax2 * (j00 * j00 + j02 * j02 + j11 * j11 + j12 * j12) * (B(Scalar(4)) * rJ + B(Scalar(4)) * tol) +
                 tol * eps2d;
  const B acov1 = simd::abs(cov1);
  const B edet = ecov * (cov0 + cov2 + two * acov1) + tol * (cov0 * cov2 + cov1 * cov1);
  // Degenerate, non-finite or overflowing 2D covariances: the reference decides.
  const B big(std::numeric_limits<Scalar>::max() / Scalar(16));
  const M det_bad = ~((det > edet) & (det < big) & ((conic0 * zero + conic1 * zero + conic2 * zero) <= zero));
  defer(det_bad);

  const B o = one / (one + simd::exp(-ld(L[G::kLogit])));
  const B amin(cam.alpha_min);
  const B eo = tol * o;
  defer(simd::abs(o - amin) <= eo);
  const M cull_faint_o = ~decided & (o < amin);
  decided = decided | cull_faint_o;

  const B u = fx * t[0] * iz + B(cam.cx), v = fy * t[1] * iz + B(cam.cy);
  const B eu = two * fx * iz * (et[0] + simd::abs(t[0]) * rz) + tol * (simd::abs(u) + B(std::abs(cam.cx)));
  const B ev = two * fy * iz * (et[1] + simd::abs(t[1]) * rz) + tol * (simd::abs(v) + B(std::abs(cam.cy)));
  const B lim_int(Scalar(1 << 22));  // beyond: rectangle arithmetic left to the reference
  defer(~((simd::abs(u) < lim_int) & (simd::abs(v) < lim_int)));

  const B mid = half * (cov0 + cov2), half_diff = half * (cov0 - cov2);
  const B lambda = mid + simd::sqrt(half_diff * half_diff + cov1 * cov1);
  // The root is the norm of (half_diff, cov1): it moves by at most the norm of
  // their differences (<= sqrt(2) ecov), mid by ecov; the rest is rounding of
  // terms no larger than lambda.
  const B elam = B(Scalar(3)) * ecov + two * tol * lambda;
  const B sr = B(Scalar(3)) * simd::sqrt(lambda);
  const B esr = B(Scalar(3)) * elam / simd::sqrt(lambda) + tol * sr;
  defer(~(sr < lim_int) | (dist_to_int(sr) <= esr));
  const B r = simd::ceil(sr);

  // Pixel i is inside when |i + 0.5 - u| <= r.
  const B W1(Scalar(cam.width - 1)), H1(Scalar(cam.height - 1));
  const B X0 = u - r - half, X1 = u + r - half, Y0 = v - r - half, Y1 = v + r - half;
  const B ex = eu + tol * (simd::abs(u) + r), ey = ev + tol * (simd::abs(v) + r);
  defer(((dist_to_int(X0) <= ex) & (X0 > -one - ex)) | ((dist_to_int(X1) <= ex) & (X1 < W1 + one + ex)) |
        ((dist_to_int(Y0) <= ey) & (Y0 > -one - ey)) | ((dist_to_int(Y1) <= ey) & (Y1 < H1 + one + ey)));
  B x0 = simd::max(zero, simd::ceil(X0)), x1 = simd::min(W1, simd::floor(X1));
  B y0 = simd::max(zero, simd::ceil(Y0)), y1 = simd::min(H1, simd::floor(Y1));
  const M cull_outside = ~decided & ((x0 > x1) | (y0 > y1));
  decided = decided | cull_outside;

  M cull_faint = cull_faint_o;
  if (cam.tight_extents) {
    // alpha >= alpha_min only where d^T conic d <= 2 ln(o / alpha_min), with the
    // reference's slack.
    const B lo = simd::log(o / amin);
    const B tt = lo * B(Scalar(1 + 1e-3)) + B(Scalar(1e-3));
    const B ett = tol * (simd::abs(lo) + two);
    const B hx = simd::sqrt(two * tt * cov0), hy = simd::sqrt(two * tt * cov2);
    const B eh = half * (ett / tt + ecov / simd::min(cov0, cov2)) + tol;
    const B Xt0 = u - hx - half, Xt1 = u + hx - half, Yt0 = v - hy - half, Yt1 = v + hy - half;
    const B ext = eu + hx * eh + tol * (simd::abs(u) + hx), eyt = ev + hy * eh + tol * (simd::abs(v) + hy);
    defer(((dist_to_int(Xt0) <= ext) & (Xt0 > x0 - one - ext)) |
          ((dist_to_int(Xt1) <= ext) & (Xt1 < x1 + one + ext)) |
          ((dist_to_int(Yt0) <= eyt) & (Yt0 > y0 - one - eyt)) |
          ((dist_to_int(Yt1) <= eyt) & (Yt1 < y1 + one + eyt)));
    x0 = simd::max(x0, simd::ceil(Xt0));
    x1 = simd::min(x1, simd::floor(Xt1));
    y0 = simd::max(y0, simd::ceil(Yt0));
    y1 = simd::min(y1, simd::floor(Yt1));
    const M empty = ~decided & ((x0 > x1) | (y0 > y1));
    cull_faint = cull_faint | empty;
    decided = decided | empty;
  }

  // SH colour in the direction mean - camera centre, + 0.5, clamped at 0.
  B b[16], d[3], raw[3];
  lanes_sh_basis(degree, x, y, z, cam, b, d);
  lanes_sh_raw_color(k_count, b, L, raw);
  const B cr = simd::select(raw[0] < zero, zero, raw[0]);
  const B cg = simd::select(raw[1] < zero, zero, raw[1]);
  const B cb = simd::select(raw[2] < zero, zero, raw[2]);

  // Outcome per lane.
  B code = simd::select(bad_in, B(Scalar(int(CullReason::nonfinite))), zero);
  code = simd::select(scalar, B(Scalar(kLaneDecision)), code);
  code = simd::select(scalar & (bad_act | det_bad), B(Scalar(kLaneScalar)), code);
  code = simd::select(cull_near, B(Scalar(int(CullReason::near))), code);
  code = simd::select(cull_faint, B(Scalar(int(CullReason::faint))), code);
  code = simd::select(cull_outside, B(Scalar(int(CullReason::outside))), code);
  const B radius = simd::max(one, r);

  // Values (unspecified for culled lanes): straight into `out` for whole batches.
  const B* vals[10] = {&u, &v, &conic0, &conic1, &conic2, &o, &cr, &cg, &cb, &t[2]};
  Scalar* dst[10] = {out.mean_x.data(), out.mean_y.data(), out.conic_a.data(), out.conic_b.data(),
                     out.conic_c.data(), out.opacity.data(), out.color_r.data(), out.color_g.data(),
                     out.color_b.data(), out.depth.data()};
  if (count == W) {
    for (int f = 0; f < 10; ++f) vals[f]->store_unaligned(dst[f] + i0);
  } else {
    alignas(64) Scalar buf[W];
    for (int f = 0; f < 10; ++f) {
      vals[f]->store_unaligned(buf);
      for (int j = 0; j < count; ++j) dst[f][i0 + std::size_t(j)] = buf[j];
    }
  }
  // A whole batch that the reference decides nowhere (nearly all of them):
  // the outcome counts from the codes' masks and the integer fields without a
  // branch per lane (a culled lane gets radius 0 and a rectangle of zeros).
  if (count == W && !simd::any(code >= B(Scalar(kLaneScalar)))) {
    for (int r = 0; r < 5; ++r) local[r] += std::size_t(simd::popcount(simd::mask_bits(code == B(Scalar(r)))));
    const M vis = code == zero;
    alignas(64) Scalar f[5][W];
    simd::select(vis, radius, zero).store_unaligned(f[0]);
    simd::select(vis, x0, zero).store_unaligned(f[1]);
    simd::select(vis, y0, zero).store_unaligned(f[2]);
    simd::select(vis, x1, zero).store_unaligned(f[3]);
    simd::select(vis, y1, zero).store_unaligned(f[4]);
    std::int32_t* ints[5] = {out.radius.data() + i0, out.rect_x0.data() + i0, out.rect_y0.data() + i0,
                             out.rect_x1.data() + i0, out.rect_y1.data() + i0};
    for (int k = 0; k < 5; ++k)
      for (int j = 0; j < W; ++j) ints[k][j] = std::int32_t(f[k][j]);
    return;
  }
  alignas(64) Scalar codes[W], rad[W], rx0[W], ry0[W], rx1[W], ry1[W];
  code.store_unaligned(codes);
  radius.store_unaligned(rad);
  x0.store_unaligned(rx0);
  y0.store_unaligned(ry0);
  x1.store_unaligned(rx1);
  y1.store_unaligned(ry1);
  for (int j = 0; j < count; ++j) {
    const std::size_t i = i0 + std::size_t(j);
    const int why = int(codes[j]);
    if (why >= kLaneScalar) {
      Scalar sh_buf[48];
      GaussianParams<Scalar> g;
      Splat<Scalar> sp;
      gather_gaussian(scene, i, degree, g, sh_buf);
      const CullReason w = project_gaussian(cam, g, sp);
      ++local[int(w)];
      out.radius[i] = sp.radius;
      if (w != CullReason::none) continue;
      out.rect_x0[i] = sp.rect_x0;
      out.rect_y0[i] = sp.rect_y0;
      out.rect_x1[i] = sp.rect_x1;
      out.rect_y1[i] = sp.rect_y1;
      if (why == kLaneDecision) continue;
      out.mean_x[i] = sp.mean_x;
      out.mean_y[i] = sp.mean_y;
      out.conic_a[i] = sp.conic_a;
      out.conic_b[i] = sp.conic_b;
      out.conic_c[i] = sp.conic_c;
      out.opacity[i] = sp.opacity;
      out.color_r[i] = sp.color[0];
      out.color_g[i] = sp.color[1];
      out.color_b[i] = sp.color[2];
      out.depth[i] = sp.depth;
      continue;
    }
    ++local[why];
    out.radius[i] = why == 0 ? std::int32_t(rad[j]) : 0;
    if (why != 0) continue;
    out.rect_x0[i] = std::int32_t(rx0[j]);
    out.rect_y0[i] = std::int32_t(ry0[j]);
    out.rect_x1[i] = std::int32_t(rx1[j]);
    out.rect_y1[i] = std::int32_t(ry1[j]);
  }
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
}  // namespace detail

}  // namespace orbitforge

#pragma once
// The batch path of project_scene_vjp: simd::native_batch<Scalar>::size
// Gaussians at a time, read through the adaptor as the forward's batch path reads
// them (detail::gather_lanes), their gradients computed in SIMD, transposed back
// to one row per Gaussian and written through the SceneGradView.
// project_gaussian_vjp stays the reference: the batch gives its values within
// float rounding (the same formulas, evaluated in another order). Its two
// piecewise choices, the EWA Jacobian's clamp and the colour's clamp at 0, are
// made on the same values as the forward's batch path, so the gradient follows
// the branch that the rendered image took. A kept lane whose batch gradient is
// not finite is recomputed by the reference.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <vector>

#include "orbitforge/core/simd.hpp"
#include "orbitforge/splat/project_gaussian.hpp"
#include "orbitforge/splat/project_lanes.hpp"
#include "orbitforge/splat/projected.hpp"
#include "orbitforge/splat/scene_grad.hpp"
#include "orbitforge/splat/scene_grad_view.hpp"

namespace orbitforge {

namespace detail {

// One batch's gradients: a row per value, a column per lane, then one row per
// lane (transposed block by block) for the writes through the view.
template <class Scalar, int W>
struct GradLanes {
  static constexpr int kMean = 0, kQuat = 3, kScale = 7, kLogScale = 10, kLogit = 13, kOpacity = 14,
                       kScreen = 15, kScreenNdc = 16, kSh = 32, kRow = kSh + 48;
  alignas(64) Scalar soa[kRow][W];
  alignas(64) Scalar aos[W][kRow];
  Scalar* operator[](int row) { return soa[row]; }
};

// What the view asks for (a null field is not computed or written).
struct GradWanted {
  bool mean, cov3, sh;
  int sh_first, sh_end;  // coefficients written: [sh_first, sh_end)
  int sh_zero_end;       // and zeros in [sh_end, sh_zero_end): the host holds more than the adaptor
};

// The GCC 12 false positive of project_lanes.hpp (xsimd's AVX-512 kernels).
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wuninitialized"
#endif
// Gradients of Gaussians i0 .. i0 + count - 1 (count <= B::size) into `out`.
template <class B, class Scene>
inline void project_lanes_vjp(const Scene& scene, const ProjectionCamera<typename B::value_type>& cam, int degree,
                              std::size_t i0, int count, const ProjectedSplats<typename B::value_type>& fwd,
                              const ProjectedSplatsGrad<typename B::value_type>& v_in,
                              const SceneGradView<typename B::value_type>& out, const Freeze& freeze,
                              const GradWanted& want, GaussianLanes<typename B::value_type, int(B::size)>& L,
                              GradLanes<typename B::value_type, int(B::size)>& GL) {
  using Scalar = typename B::value_type;
  using M = simd::mask_t<B>;
  constexpr int W = int(B::size);
  using G = GaussianLanes<Scalar, W>;
  using GG = GradLanes<Scalar, W>;
  const int k_count = sh_coefficient_count(degree);
  gather_lanes<B>(scene, i0, count, k_count, L);
  auto ld = [](const Scalar* p) { return B::load_unaligned(p); };
  const B zero(Scalar(0)), one(Scalar(1)), two(Scalar(2)), half(Scalar(0.5));

  // The rasterizer's gradients; lanes past `count` get zeros and radius 0.
  alignas(64) Scalar vbuf[10][W], kept_buf[W];
  const std::vector<Scalar>* v_src[10] = {&v_in.v_mean_x, &v_in.v_mean_y, &v_in.v_conic_a, &v_in.v_conic_b,
                                          &v_in.v_conic_c, &v_in.v_opacity, &v_in.v_color_r, &v_in.v_color_g,
                                          &v_in.v_color_b, &v_in.v_depth};
  B vv[10];
  if (count == W) {
    for (int f = 0; f < 10; ++f) vv[f] = ld(v_src[f]->data() + i0);
  } else {
    for (int f = 0; f < 10; ++f) {
      for (int j = 0; j < W; ++j) vbuf[f][j] = j < count ? (*v_src[f])[i0 + std::size_t(j)] : Scalar(0);
      vv[f] = ld(vbuf[f]);
    }
  }
  for (int j = 0; j < W; ++j) kept_buf[j] = j < count && fwd.radius[i0 + std::size_t(j)] > 0 ? Scalar(1) : Scalar(0);
  const M kept = ld(kept_buf) > zero;
  const B &v_mx = vv[0], &v_my = vv[1], &v_ca = vv[2], &v_cb = vv[3], &v_cc = vv[4], &v_op = vv[5],
          &v_depth = vv[9];
  const B v_rgb[3] = {vv[6], vv[7], vv[8]};

  const B x = ld(L[G::kMean]), y = ld(L[G::kMean + 1]), z = ld(L[G::kMean + 2]);
  B s[3];
  for (int a = 0; a < 3; ++a) {
    const B raw = ld(L[G::kScale + a]);
    s[a] = Scene::scale_mode == ScaleMode::log ? simd::exp(raw) : raw;
  }
  B poison = zero;  // x * 0 is NaN only for NaN and inf
  auto put = [&](int row, const B& value) {
    poison = poison + value * zero;
    simd::select(kept, value, zero).store_unaligned(GL[row]);
  };

  const B o = one / (one + simd::exp(-ld(L[G::kLogit])));
  put(GG::kLogit, v_op * o * (one - o));
  put(GG::kOpacity, v_op);
  {
    const B nx = v_mx * B(Scalar(0.5) * Scalar(cam.width)), ny = v_my * B(Scalar(0.5) * Scalar(cam.height));
    put(GG::kScreen, simd::sqrt(v_mx * v_mx + v_my * v_my));
    put(GG::kScreenNdc, simd::sqrt(nx * nx + ny * ny));
  }

  // Colour: v_sh[k][c] = b_k g_c, where g passes v_rgb where the colour was not clamped.
  B v_dir[3] = {zero, zero, zero};
  if (want.sh || want.mean) {
    B b[16], d[3], raw[3];
    const B inv_norm = lanes_sh_basis(degree, x, y, z, cam, b, d);
    lanes_sh_raw_color(k_count, b, L, raw);
    B g[3];
    for (int c = 0; c < 3; ++c) g[c] = simd::select(raw[c] < zero, zero, v_rgb[c]);
    if (want.sh)
      for (int k = 0; k < k_count; ++k)
        for (int c = 0; c < 3; ++c) put(GG::kSh + 3 * k + c, b[k] * g[c]);
    if (want.mean && degree > 0) {
      B v_b[16], v_d[3];
      for (int k = 0; k < k_count; ++k)
        v_b[k] = ld(L[G::kSh + 3 * k]) * g[0] + ld(L[G::kSh + 3 * k + 1]) * g[1] + ld(L[G::kSh + 3 * k + 2]) * g[2];
      sh_basis_vjp(degree, d[0], d[1], d[2], v_b, v_d);
      const B dot = d[0] * v_d[0] + d[1] * v_d[1] + d[2] * v_d[2];
      for (int a = 0; a < 3; ++a) v_dir[a] = (v_d[a] - d[a] * dot) * inv_norm;
    }
  }

  if (want.mean || want.cov3) {
    // Forward quantities, as in the forward's batch path.
    B t[3];
    for (int k = 0; k < 3; ++k)
      t[k] = B(cam.R(k, 0)) * x + B(cam.R(k, 1)) * y + B(cam.R(k, 2)) * z + B(cam.t[k]);
    LanesCov2d<B> c2;
    lanes_cov2d(cam, L, t, s, c2);
    const B &qw = c2.qw, &qx = c2.qx, &qy = c2.qy, &qz = c2.qz, &qinv = c2.qinv;
    const B &iz = c2.iz, &iz2 = c2.iz2, &clx = c2.clx, &cly = c2.cly;
    const B &cov0 = c2.cov0, &cov1 = c2.cov1, &cov2 = c2.cov2;
    const B(&Rq)[3][3] = c2.Rq;
    const B(&Mq)[3][3] = c2.Mq;
    const B(&T0)[3] = c2.T0;
    const B(&T1)[3] = c2.T1;
    const B(&TS0)[3] = c2.TS0;
    const B(&TS1)[3] = c2.TS1;
    const B iz3 = iz2 * iz;
    const B lx(cam.lim_x), ly(cam.lim_y), fx(cam.fx), fy(cam.fy);
    const M in_x = (c2.ux > -lx) & (c2.ux < lx), in_y = (c2.uy > -ly) & (c2.uy < ly);
    const B tx = clx * t[2], ty = cly * t[2];
    const B idet = one / (cov0 * cov2 - cov1 * cov1);
    const B ca = cov2 * idet, cb = -cov1 * idet, cc = cov0 * idet;

    // conic = cov^-1 (inverse2x2_vjp): v_cov = -Q V Q, xy counted once.
    const B va = v_ca, vb = half * v_cb, vc = v_cc;
    const B qv00 = ca * va + cb * vb, qv01 = ca * vb + cb * vc, qv10 = cb * va + cc * vb, qv11 = cb * vb + cc * vc;
    const B V00 = -(qv00 * ca + qv01 * cb), V01 = -(qv00 * cb + qv01 * cc), V11 = -(qv10 * cb + qv11 * cc);

    if (want.mean) {
      // cov = T Sigma T^T: v_T = 2 V (T Sigma); T = J W: v_J = v_T W^T; then J(t).
      B vT0[3], vT1[3];
      for (int c = 0; c < 3; ++c) {
        vT0[c] = two * (V00 * TS0[c] + V01 * TS1[c]);
        vT1[c] = two * (V01 * TS0[c] + V11 * TS1[c]);
      }
      auto row_dot = [&](const B* v, int r) {
        return v[0] * B(cam.R(r, 0)) + v[1] * B(cam.R(r, 1)) + v[2] * B(cam.R(r, 2));
      };
      const B v_j00 = row_dot(vT0, 0), v_j02 = row_dot(vT0, 2), v_j11 = row_dot(vT1, 1), v_j12 = row_dot(vT1, 2);
      const B d02 = -fx * iz2, d12 = -fy * iz2;
      const B v_t0 = simd::select(in_x, v_j02 * d02, zero) + fx * iz * v_mx;
      const B v_t1 = simd::select(in_y, v_j12 * d12, zero) + fy * iz * v_my;
      const B v_t2 = -fx * iz2 * v_j00 - fy * iz2 * v_j11 +
                     v_j02 * (simd::select(in_x, zero, d02 * clx) + two * fx * tx * iz3) +
                     v_j12 * (simd::select(in_y, zero, d12 * cly) + two * fy * ty * iz3) -
                     (fx * t[0] * v_mx + fy * t[1] * v_my) * iz2 + v_depth;
      for (int a = 0; a < 3; ++a)
        put(GG::kMean + a,
            B(cam.R(0, a)) * v_t0 + B(cam.R(1, a)) * v_t1 + B(cam.R(2, a)) * v_t2 + v_dir[a]);
    }

    if (want.cov3) {
      // v_Sigma = T^T V T (symmetric); Sigma = M M^T: v_M = 2 v_Sigma M.
      B VT0[3], VT1[3], vS[3][3];
      for (int c = 0; c < 3; ++c) {
        VT0[c] = V00 * T0[c] + V01 * T1[c];
        VT1[c] = V01 * T0[c] + V11 * T1[c];
      }
      for (int r = 0; r < 3; ++r)
        for (int c = r; c < 3; ++c) vS[r][c] = vS[c][r] = T0[r] * VT0[c] + T1[r] * VT1[c];
      B vR[3][3];
      for (int c = 0; c < 3; ++c) {
        B dot = zero;
        for (int r = 0; r < 3; ++r) {
          const B vM = two * (vS[r][0] * Mq[0][c] + vS[r][1] * Mq[1][c] + vS[r][2] * Mq[2][c]);
          vR[r][c] = vM * s[c];
          dot = dot + vM * Rq[r][c];
        }
        put(GG::kScale + c, dot);
        put(GG::kLogScale + c, dot * s[c]);
      }
      // Rotation of the normalised quaternion, then through the normalisation.
      const B gw = two * (-qz * vR[0][1] + qy * vR[0][2] + qz * vR[1][0] - qx * vR[1][2] - qy * vR[2][0] +
                          qx * vR[2][1]);
      const B gx = two * (qy * vR[0][1] + qz * vR[0][2] + qy * vR[1][0] - two * qx * vR[1][1] - qw * vR[1][2] +
                          qz * vR[2][0] + qw * vR[2][1] - two * qx * vR[2][2]);
      const B gy = two * (-two * qy * vR[0][0] + qx * vR[0][1] + qw * vR[0][2] + qx * vR[1][0] + qz * vR[1][2] -
                          qw * vR[2][0] + qz * vR[2][1] - two * qy * vR[2][2]);
      const B gz = two * (-two * qz * vR[0][0] - qw * vR[0][1] + qx * vR[0][2] + qw * vR[1][0] -
                          two * qz * vR[1][1] + qy * vR[1][2] + qx * vR[2][0] + qy * vR[2][1]);
      const B dot = qw * gw + qx * gx + qy * gy + qz * gz;
      put(GG::kQuat + 0, (gw - qw * dot) * qinv);
      put(GG::kQuat + 1, (gx - qx * dot) * qinv);
      put(GG::kQuat + 2, (gy - qy * dot) * qinv);
      put(GG::kQuat + 3, (gz - qz * dot) * qinv);
    }
  }

  // One row per lane. Rows never put are never read.
  const int rows = want.sh ? GG::kSh + 3 * k_count : GG::kScreenNdc + 1;
  for (int r0 = 0; r0 < rows; r0 += W) {
    if (r0 >= GG::kScreenNdc + 1 && r0 < GG::kSh) continue;  // the unused gap
    simd::transpose_block<B>(&GL.soa[r0][0], W, &GL.aos[0][r0], GG::kRow);
  }
  alignas(64) Scalar bad[W];
  simd::select(kept & ~(poison <= zero), one, zero).store_unaligned(bad);

  const bool xyzw = out.rotation_order == QuatOrder::xyzw;
  // The channels of consecutive coefficients adjacent (GaussianSceneGrad's layout).
  const bool sh_packed = out.sh_coefficient_stride_bytes == std::ptrdiff_t(3 * sizeof(Scalar));
  for (int j = 0; j < count; ++j) {
    const std::size_t i = i0 + std::size_t(j);
    Scalar* row = GL.aos[j];
    if (bad[j] != Scalar(0)) {  // the reference recomputes this lane
      Scalar sh_buf[48], v_mean[3] = {0, 0, 0}, v_quat[4] = {0, 0, 0, 0}, v_scale[3] = {0, 0, 0}, v_logit = 0;
      GaussianParams<Scalar> g;
      SplatGrad<Scalar> vg;
      gather_gaussian(scene, i, degree, g, sh_buf);
      vg.v_mean_x = v_mx.get(std::size_t(j));
      vg.v_mean_y = v_my.get(std::size_t(j));
      vg.v_conic_a = v_ca.get(std::size_t(j));
      vg.v_conic_b = v_cb.get(std::size_t(j));
      vg.v_conic_c = v_cc.get(std::size_t(j));
      vg.v_opacity = v_op.get(std::size_t(j));
      for (int c = 0; c < 3; ++c) vg.v_color[c] = v_rgb[c].get(std::size_t(j));
      vg.v_depth = v_depth.get(std::size_t(j));
      project_gaussian_vjp(cam, g, vg, freeze, v_mean, v_quat, v_scale, &v_logit, row + GG::kSh);
      for (int a = 0; a < 3; ++a) {
        row[GG::kMean + a] = v_mean[a];
        row[GG::kScale + a] = v_scale[a];
        row[GG::kLogScale + a] = v_scale[a] * g.scale[a];
      }
      for (int a = 0; a < 4; ++a) row[GG::kQuat + a] = v_quat[a];
      row[GG::kLogit] = v_logit;
    }
    if (out.means)
      for (int a = 0; a < 3; ++a) out.means.at(i)[a] = row[GG::kMean + a];
    if (out.rotations) {
      Scalar* q = out.rotations.at(i);
      for (int a = 0; a < 4; ++a) q[xyzw ? (a + 3) % 4 : a] = row[GG::kQuat + a];  // w goes last for xyzw
    }
    if (out.scales)
      for (int a = 0; a < 3; ++a) out.scales.at(i)[a] = row[GG::kScale + a];
    if (out.log_scales)
      for (int a = 0; a < 3; ++a) out.log_scales.at(i)[a] = row[GG::kLogScale + a];
    if (out.opacity_logits) *out.opacity_logits.at(i) = row[GG::kLogit];
    if (out.opacities) *out.opacities.at(i) = row[GG::kOpacity];
    if (out.sh && sh_packed) {  // one run per Gaussian: stored a value at a time, it took a third of this pass
      Scalar* dst = out.sh.at(i);
      std::copy_n(row + GG::kSh + 3 * want.sh_first, 3 * (want.sh_end - want.sh_first), dst + 3 * want.sh_first);
      std::fill(dst + 3 * want.sh_end, dst + 3 * want.sh_zero_end, Scalar(0));
    } else if (out.sh) {
      char* base = reinterpret_cast<char*>(out.sh.at(i));
      for (int k = want.sh_first; k < want.sh_end; ++k) {
        Scalar* dst = reinterpret_cast<Scalar*>(base + std::ptrdiff_t(k) * out.sh_coefficient_stride_bytes);
        for (int c = 0; c < 3; ++c) dst[c] = row[GG::kSh + 3 * k + c];
      }
      for (int k = want.sh_end; k < want.sh_zero_end; ++k) {
        Scalar* dst = reinterpret_cast<Scalar*>(base + std::ptrdiff_t(k) * out.sh_coefficient_stride_bytes);
        for (int c = 0; c < 3; ++c) dst[c] = Scalar(0);
      }
    }
    if (out.screen_grad_norm) *out.screen_grad_norm.at(i) = row[GG::kScreen];
    if (out.screen_grad_ndc_norm) *out.screen_grad_ndc_norm.at(i) = row[GG::kScreenNdc];
  }
}
#if defined(__GNUC__) && !defined(__clang__)
#pragma GCC diagnostic pop
#endif
}  // namespace detail

}  // namespace orbitforge

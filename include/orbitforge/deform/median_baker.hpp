#pragma once
// MedianGS (paper section 3.3): turn a canonical scene plus a deformation field
// into ONE static scene. With tau_k = k / (T_m - 1), k = 0 .. T_m-1 (T_m = 128):
//
//   med dx = median_k dx(tau_k), med dq = median_k dq(tau_k), med ds = median_k ds(tau_k)
//                                   (coordinate-wise; even count: the LOWER middle value)
//   x~ = x + med dx
//   q~ = normalize(normalize(q) + med dq)
//   s~ = max(|exp(log s) + med ds|, eps_s),  stored as log s~   (additive scale offsets)
//   s~ = max(exp(log s + med ds), eps_s)                          (relative offsets,
//        ScaleOffset::log: the median of s exp(ds_k) itself, as exp is monotone)
//   opacity and SH copied from the canonical scene.
//
// The two ablation variants of the paper use the same conversion with the offsets
// of one time code: bake_time_slice(t) (frame-varying: one scene per frame's t) and
// bake_fixed_slice (t = 0.5).
//
// Any deformation works: a callable
//     void deformation(const Eigen::Ref<const Matrix3X<S>>& means, S t, DeformationOffsets<S>& out)
// that fills out (resized to means.cols()) for those means at time t. The baker
// calls it from one thread at a time (so it may keep a workspace and run its own
// parallel_for); FieldDeformation wraps a DeformationField this way.
//
// Non-finite values: a non-finite offset sample is an "abnormal offset" and is left
// out of that coordinate's median (counted in BakeReport); a coordinate with no
// finite sample at all, a non-finite or zero-length canonical quaternion, or any
// non-finite result is an Error naming the Gaussian. If normalize(q) + med dq has
// (near) zero length the rotation is undefined; the baker then keeps normalize(q)
// and counts it (BakeReport::rotation_fallbacks). The result is always finite.
//
// Memory: Gaussians are processed in chunks of chunk_gaussians, so at most
// chunk x T_m x 10 samples are held (4096 x 128 x 10 floats = 21 MB).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/deform/deformation_field.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

struct MedianBakeParams {
  int samples = 128;                  // T_m
  double scale_floor = 1e-6;          // eps_s, in scene units (activated scale)
  std::size_t chunk_gaussians = 4096;
  int threads = 0;                    // for the median step; 0 = default
};

struct BakeReport {
  std::size_t nonfinite_samples = 0;   // offset samples left out of medians
  std::size_t rotation_fallbacks = 0;  // Gaussians that kept normalize(q)
};

// A DeformationField as a baker deformation (owns its workspace; one caller at a time).
template <class Scalar>
class FieldDeformation {
 public:
  explicit FieldDeformation(const DeformationField<Scalar>& field, int threads = 0)
      : field_(&field), threads_(threads) {}
  void operator()(const Eigen::Ref<const Matrix3X<Scalar>>& means, Scalar t, DeformationOffsets<Scalar>& out) {
    field_->evaluate(means, t, ws_, out, threads_);
  }

 private:
  const DeformationField<Scalar>* field_;
  int threads_;
  typename DeformationField<Scalar>::Workspace ws_;
};

namespace median_baker_detail {

// The lower middle of the finite values in v[0, n) (reorders v). Returns false
// when there is none. `dropped` counts the non-finite ones.
template <class Scalar>
bool lower_median(Scalar* v, int n, Scalar& out, std::size_t& dropped) {
  Scalar* end = std::partition(v, v + n, [](Scalar a) { return std::isfinite(a); });
  const int m = int(end - v);
  dropped += std::size_t(n - m);
  if (m == 0) return false;
  Scalar* mid = v + (m - 1) / 2;  // m even: element m/2 - 1 of the sorted values
  std::nth_element(v, mid, end);
  out = *mid;
  return true;
}

// Static state of Gaussian j from its offsets; writes into `out` (same index).
// Returns true when the rotation fell back to normalize(q).
template <class Scalar>
bool write_static(const GaussianScene<Scalar>& c, std::size_t j, const Scalar* dx, const Scalar* dq, const Scalar* ds,
                  ScaleOffset mode, Scalar scale_floor, GaussianScene<Scalar>& out) {
  for (int a = 0; a < 3; ++a) out.means[3 * j + a] = c.means[3 * j + a] + dx[a];
  Eigen::Map<const Eigen::Matrix<Scalar, 4, 1>> q(&c.rotations[4 * j]);
  const Scalar qn = q.norm();
  ensure(std::isfinite(qn) && qn > Scalar(0), "MedianGS bake: Gaussian ", j,
         " has a zero-length or non-finite canonical quaternion");
  Eigen::Matrix<Scalar, 4, 1> r = q / qn + Eigen::Map<const Eigen::Matrix<Scalar, 4, 1>>(dq);
  const Scalar rn = r.norm();
  bool fallback = false;
  if (!(rn > Scalar(1e3) * std::numeric_limits<Scalar>::epsilon()) || !std::isfinite(rn)) {
    r = q / qn;
    fallback = true;
  } else {
    r /= rn;
  }
  for (int a = 0; a < 4; ++a) out.rotations[4 * j + a] = r[a];
  for (int a = 0; a < 3; ++a) {
    if (mode == ScaleOffset::log) {
      out.log_scales[3 * j + a] = std::max(c.log_scales[3 * j + a] + ds[a], std::log(scale_floor));
    } else {
      const Scalar s = std::exp(c.log_scales[3 * j + a]) + ds[a];
      out.log_scales[3 * j + a] = std::log(std::max(std::abs(s), scale_floor));
    }
  }
  bool finite = true;
  for (int a = 0; a < 3; ++a)
    finite = finite && std::isfinite(out.means[3 * j + a]) && std::isfinite(out.log_scales[3 * j + a]);
  ensure(finite, "MedianGS bake: Gaussian ", j, " has a non-finite static state (position or scale overflow)");
  return fallback;
}

template <class Scalar>
GaussianScene<Scalar> copy_appearance(const GaussianScene<Scalar>& c) {
  c.check_consistent();
  GaussianScene<Scalar> out;
  out.sh_degree = c.sh_degree;
  out.means.resize(c.means.size());
  out.rotations.resize(c.rotations.size());
  out.log_scales.resize(c.log_scales.size());
  out.opacity_logits = c.opacity_logits;
  out.sh = c.sh;
  return out;
}

}  // namespace median_baker_detail

// MedianGS: the static proxy from T_m time samples.
template <class Scalar, class Deformation>
GaussianScene<Scalar> bake_median(const GaussianScene<Scalar>& canonical, Deformation&& deformation,
                                  const MedianBakeParams& p = {}, BakeReport* report = nullptr) {
  namespace d = median_baker_detail;
  ensure(p.samples >= 2, "bake_median: need at least 2 time samples, got ", p.samples);
  ensure(p.scale_floor > 0 && std::isfinite(p.scale_floor), "bake_median: scale_floor must be positive, got ",
         p.scale_floor);
  ensure(p.chunk_gaussians >= 1, "bake_median: chunk_gaussians must be >= 1");
  GaussianScene<Scalar> out = d::copy_appearance(canonical);
  const std::size_t n = canonical.size();
  const int T = p.samples;
  const std::size_t chunk = std::min(p.chunk_gaussians, std::max<std::size_t>(n, 1));
  // samples[(g * 10 + c) * T + k]: per Gaussian and coordinate, T contiguous values.
  std::vector<Scalar> samples(chunk * 10 * std::size_t(T));
  DeformationOffsets<Scalar> off;
  const int threads = resolve_threads(p.threads);
  constexpr std::size_t kBlock = 64;  // Gaussians per median task
  std::vector<std::size_t> dropped(std::size_t(threads), 0), fallbacks(std::size_t(threads), 0);
  ScaleOffset mode = ScaleOffset::additive;
  for (std::size_t g0 = 0; g0 < n; g0 += chunk) {
    const std::size_t m = std::min(chunk, n - g0);
    Eigen::Map<const Matrix3X<Scalar>> means(canonical.means.data() + 3 * g0, 3, Eigen::Index(m));
    for (int k = 0; k < T; ++k) {
      const Scalar t = Scalar(k) / Scalar(T - 1);
      deformation(means, t, off);
      ensure(off.dx.cols() == Eigen::Index(m) && off.dq.cols() == Eigen::Index(m) && off.ds.cols() == Eigen::Index(m),
             "bake_median: the deformation returned ", off.dx.cols(), " offsets for ", m, " Gaussians");
      mode = off.scale_offset;
      for (std::size_t g = 0; g < m; ++g) {
        Scalar* s = &samples[g * 10 * std::size_t(T) + std::size_t(k)];
        const Eigen::Index gi = Eigen::Index(g);
        for (int c = 0; c < 3; ++c) s[std::size_t(c) * T] = off.dx(c, gi);
        for (int c = 0; c < 4; ++c) s[std::size_t(3 + c) * T] = off.dq(c, gi);
        for (int c = 0; c < 3; ++c) s[std::size_t(7 + c) * T] = off.ds(c, gi);
      }
    }
    const std::size_t blocks = (m + kBlock - 1) / kBlock;
    parallel_for(blocks, threads, [&](std::size_t b, int worker) {
      for (std::size_t g = b * kBlock; g < std::min(m, (b + 1) * kBlock); ++g) {
        Scalar med[10];
        for (int c = 0; c < 10; ++c) {
          Scalar* v = &samples[(g * 10 + std::size_t(c)) * std::size_t(T)];
          ensure(d::lower_median(v, T, med[c], dropped[std::size_t(worker)]), "bake_median: Gaussian ", g0 + g,
                 ", offset coordinate ", c, ": all ", T, " deformation samples are non-finite");
        }
        if (d::write_static(canonical, g0 + g, med, med + 3, med + 7, mode, Scalar(p.scale_floor), out))
          ++fallbacks[std::size_t(worker)];
      }
    });
  }
  if (report) {
    *report = {};
    for (int w = 0; w < threads; ++w) {
      report->nonfinite_samples += dropped[std::size_t(w)];
      report->rotation_fallbacks += fallbacks[std::size_t(w)];
    }
  }
  return out;
}

// The deformed scene at one time code t as a static scene (the paper's
// frame-varying variant: call it with each frame's t). Non-finite offsets are an
// Error here: one sample has no majority to fall back on.
template <class Scalar, class Deformation>
GaussianScene<Scalar> bake_time_slice(const GaussianScene<Scalar>& canonical, Deformation&& deformation, Scalar t,
                                      const MedianBakeParams& p = {}, BakeReport* report = nullptr) {
  namespace d = median_baker_detail;
  ensure(p.scale_floor > 0 && std::isfinite(p.scale_floor), "bake_time_slice: scale_floor must be positive, got ",
         p.scale_floor);
  ensure(std::isfinite(t), "bake_time_slice: time code is not finite");
  GaussianScene<Scalar> out = d::copy_appearance(canonical);
  const std::size_t n = canonical.size();
  const std::size_t chunk = std::max<std::size_t>(p.chunk_gaussians, 1);
  DeformationOffsets<Scalar> off;
  std::size_t fallbacks = 0;
  for (std::size_t g0 = 0; g0 < n; g0 += chunk) {
    const std::size_t m = std::min(chunk, n - g0);
    Eigen::Map<const Matrix3X<Scalar>> means(canonical.means.data() + 3 * g0, 3, Eigen::Index(m));
    deformation(means, t, off);
    ensure(off.dx.cols() == Eigen::Index(m) && off.dq.cols() == Eigen::Index(m) && off.ds.cols() == Eigen::Index(m),
           "bake_time_slice: the deformation returned ", off.dx.cols(), " offsets for ", m, " Gaussians");
    for (std::size_t g = 0; g < m; ++g) {
      const Eigen::Index gi = Eigen::Index(g);
      Scalar o[10];
      for (int c = 0; c < 3; ++c) o[c] = off.dx(c, gi);
      for (int c = 0; c < 4; ++c) o[3 + c] = off.dq(c, gi);
      for (int c = 0; c < 3; ++c) o[7 + c] = off.ds(c, gi);
      for (int c = 0; c < 10; ++c)
        ensure(std::isfinite(o[c]), "bake_time_slice: Gaussian ", g0 + g, ", offset coordinate ", c,
               " is non-finite at t = ", t);
      if (d::write_static(canonical, g0 + g, o, o + 3, o + 7, off.scale_offset, Scalar(p.scale_floor), out)) ++fallbacks;
    }
  }
  if (report) *report = BakeReport{0, fallbacks};
  return out;
}

// The paper's fixed-slice ablation: the deformed scene at t = 0.5.
template <class Scalar, class Deformation>
GaussianScene<Scalar> bake_fixed_slice(const GaussianScene<Scalar>& canonical, Deformation&& deformation,
                                       const MedianBakeParams& p = {}, BakeReport* report = nullptr) {
  return bake_time_slice(canonical, std::forward<Deformation>(deformation), Scalar(0.5), p, report);
}

}  // namespace orbitforge

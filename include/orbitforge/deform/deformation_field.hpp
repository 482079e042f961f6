#pragma once
// The deformation field of Deformable 3D Gaussians (Yang et al. 2023):
//
//   (dx, dq, ds) = F(x, t) = heads( MLP( [gamma_10(x); gamma_6(t)] ) )
//
// gamma_L is the frequency encoding of nn/encoding.hpp (input included, no pi:
// 3 + 60 = 63 rows for x, 1 + 12 = 13 rows for t), the MLP is ReLU with the
// input concatenated to one hidden layer's output, and three linear heads give
// dx (3), dq (4), ds (3). The offsets are applied as in that method's renderer:
//
//   x' = x + dx,   q' = normalize(q) + dq (the rasteriser normalises again),
//   s' = exp(log s) + ds  (the activated scale; it may come out negative, which
//                          the covariance R S S^T R^T does not see)
//
// t is the video time code normalised to [0, 1]. Points are COLUMNS: means
// [3 x N] is the [N][3] layout of GaussianScene::means mapped without copies.
//
// Gradient w.r.t. the means: Deformable 3D Gaussians feeds get_xyz.detach() to
// the network, so its means get gradients only through x' = x + dx. evaluate_vjp
// can return d/dx through the network too (v_means != nullptr); pass nullptr to
// train as that method does.
//
// Scale: a camera estimator reconstructs in an arbitrary unit, and the network's
// offsets, frequencies and learning rate are not scale-free (dx and ds are
// lengths; sin(2^k x) has a period in scene units). The field therefore works in
// a normalised frame: it sees x_n = (x - center) / unit and returns
// dx = unit * dx_n, ds = unit * ds_n (dq is unit-free). The trainer sets
// unit = camera extent / kFieldReferenceExtent, so every scene looks to the
// network like one whose cameras span kFieldReferenceExtent, the scale the
// published settings were tuned at (D-NeRF's scenes: cameras 4 units from the
// object). Without it a scene 5x smaller than that (Middlebury's dino ring,
// extent 0.77) saw its Gaussians grown by the fresh field's ds, pruned as too
// large, and collapsed to a few hundred.
//
// Head initialisation: the original code keeps PyTorch's default init for the
// heads and relies on a warm-up (3000 iterations rendering without the
// deformation). Here the heads' weights and biases are scaled by head_init_scale
// (default 0.01), so the initial offsets are ~1e-3 of the trunk's activations:
// enabling the field after the warm-up then barely moves the scene. 1 gives
// PyTorch's init.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <istream>
#include <ostream>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/nn/binary_io.hpp"
#include "orbitforge/nn/encoding.hpp"
#include "orbitforge/nn/mlp.hpp"
#include "orbitforge/splat/gaussians.hpp"

namespace orbitforge {

template <class Scalar>
using Matrix3X = Eigen::Matrix<Scalar, 3, Eigen::Dynamic>;
template <class Scalar>
using Matrix4X = Eigen::Matrix<Scalar, 4, Eigen::Dynamic>;

// Per-Gaussian offsets, Gaussians as columns.
template <class Scalar>
struct DeformationOffsets {
  Matrix3X<Scalar> dx;  // [3 x N]
  Matrix4X<Scalar> dq;  // [4 x N] (w, x, y, z) offsets added to the normalised quaternion
  Matrix3X<Scalar> ds;  // [3 x N] scale offsets, combined with the scale as scale_offset says
  ScaleOffset scale_offset = ScaleOffset::additive;

  Eigen::Index size() const { return dx.cols(); }
  void resize(Eigen::Index n) {
    if (dx.cols() != n) dx.resize(3, n);
    if (dq.cols() != n) dq.resize(4, n);
    if (ds.cols() != n) ds.resize(3, n);
  }
  void set_zero(Eigen::Index n) {
    resize(n);
    dx.setZero();
    dq.setZero();
    ds.setZero();
  }
};

struct DeformationFieldParams {
  int depth = 4;
  int width = 64;
  int skip_layer = -1;       // see MlpParams::skip_layer
  int x_frequencies = 10;
  int t_frequencies = 6;     // D-NeRF / synthetic setting of Deformable 3DGS (its real-scene setting is 10)
  double head_init_scale = 0.01;
  // How ds changes a scale (splat/gaussians.hpp): relative by default, chosen by
  // measurement (additive offsets collapsed or exploded the Gaussian count on real
  // photographs); additive is Deformable 3D Gaussians' and the paper's form.
  ScaleOffset scale_offset = ScaleOffset::log;
  std::uint32_t seed = 0;

  // The published network: 8 x 256, input concatenated after hidden layer 4,
  // additive scale offsets.
  static DeformationFieldParams original() {
    DeformationFieldParams p;
    p.depth = 8;
    p.width = 256;
    p.skip_layer = 4;
    p.scale_offset = ScaleOffset::additive;
    return p;
  }
  // The CPU default, chosen by measurement (bench_mlp; 50k Gaussians, float, CPU
  // time of one thread, best of 3, AVX-512 EPYC 2.1 GHz):
  //              forward   backward   per training step
  //   8 x 256     405 ms    787 ms     ~1.2 s   (original)
  //   6 x 128      99 ms   ~170 ms     ~270 ms
  //   4 x 128      62 ms   ~100 ms     ~165 ms
  //   4 x 64       25 ms     38 ms      ~63 ms  (this default; ~32 ms on 2 threads)
  //   3 x 64       22 ms     30 ms      ~51 ms
  //   2 x 64       17 ms     20 ms      ~37 ms
  // 4 x 64 keeps the deformable step within the "under twice the static step"
  // budget on 2 cores while keeping a 4-layer trunk; the skip is not worth its
  // extra 76-column GEMM at this depth (+15% time). At equal training time (~4
  // min, cool_teddy, README "Losses and network") it also scores best: 38.42 dB
  // holdout against 37.94 for 4 x 128; 8 x 256 gets too few iterations to train.
  static DeformationFieldParams fast() { return DeformationFieldParams{}; }
};

// The camera extent (train/camera_extent.hpp) a normalised scene has.
inline constexpr double kFieldReferenceExtent = 4.0;

template <class Scalar>
class DeformationField {
 public:
  using Matrix = Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic>;
  static constexpr int kOutputs = 10;  // dx 3, dq 4, ds 3

  // The time code's encoding is the same for every point: it goes to the network
  // once per call as its shared input (nn/mlp.hpp), not as 13 rows per column.
  struct Workspace {
    Matrix input;    // [x_dims x N] the means' encodings (kept for the vjp)
    Matrix out;      // [10 x N]
    Matrix v_out;    // [10 x N]
    Matrix v_input;  // [x_dims x N]
    typename Mlp<Scalar>::Workspace mlp;
  };

  explicit DeformationField(const DeformationFieldParams& p = DeformationFieldParams::fast())
      : p_(p),
        x_enc_(FrequencyEncodingParams{3, p.x_frequencies, true, false}),
        t_enc_(FrequencyEncodingParams{1, p.t_frequencies, true, false}),
        mlp_(mlp_params(p)) {
    mlp_.init(p.seed, Scalar(p.head_init_scale));
  }

  const DeformationFieldParams& params() const { return p_; }

  // The normalised frame (see the top of this file): x_n = (x - center) / unit.
  void set_frame(const Eigen::Matrix<Scalar, 3, 1>& center, Scalar unit) {
    ensure(center.allFinite() && std::isfinite(double(unit)) && unit > Scalar(0),
           "DeformationField::set_frame: need a finite centre and a positive unit, got unit ", unit);
    center_ = center;
    unit_ = unit;
  }
  const Eigen::Matrix<Scalar, 3, 1>& frame_center() const { return center_; }
  Scalar frame_unit() const { return unit_; }
  const Mlp<Scalar>& mlp() const { return mlp_; }
  Mlp<Scalar>& mlp() { return mlp_; }
  int input_dims() const { return x_enc_.output_dims() + t_enc_.output_dims(); }
  std::size_t parameter_count() const { return mlp_.parameter_count(); }
  std::vector<Scalar>& parameters() { return mlp_.parameters(); }
  const std::vector<Scalar>& parameters() const { return mlp_.parameters(); }

  // in:  means [3 x N], t in [0, 1] (not enforced: extrapolation is the caller's choice)
  // out: offsets (resized to N); ws keeps what evaluate_vjp needs.
  void evaluate(const Eigen::Ref<const Matrix3X<Scalar>>& means, Scalar t, Workspace& ws,
                DeformationOffsets<Scalar>& out, int threads = 0) const {
    ensure(std::isfinite(t), "DeformationField::evaluate: time code is not finite");
    const Eigen::Index n = means.cols();
    const int xr = x_enc_.output_dims();
    if (ws.input.rows() != xr || ws.input.cols() != n) ws.input.resize(xr, n);
    Eigen::Matrix<Scalar, Eigen::Dynamic, 1> tcode(t_enc_.output_dims());
    t_enc_.encode(Eigen::Matrix<Scalar, 1, 1>::Constant(t), tcode);
    const int ranges = int(std::max<Eigen::Index>(1, std::min<Eigen::Index>(resolve_threads(threads), n / 2048)));
    const bool identity = unit_ == Scalar(1) && center_.isZero();
    const Scalar inv_unit = Scalar(1) / unit_;
    parallel_for(std::size_t(ranges), ranges, [&](std::size_t r, int) {
      const Eigen::Index b = n * Eigen::Index(r) / ranges, e = n * Eigen::Index(r + 1) / ranges;
      if (identity) {
        x_enc_.encode(means.middleCols(b, e - b), ws.input.middleCols(b, e - b), 0);
      } else {  // x_n as an expression: a copy of the means would be a fresh 12 bytes a point per call
        x_enc_.encode((means.middleCols(b, e - b).colwise() - center_) * inv_unit, ws.input.middleCols(b, e - b), 0);
      }
    });
    mlp_.forward(ws.input, ws.mlp, ws.out, threads, tcode.data());
    out.resize(n);
    out.scale_offset = p_.scale_offset;
    out.dx = ws.out.topRows(3) * unit_;
    out.dq = ws.out.middleRows(3, 4);
    out.ds = ws.out.middleRows(7, 3) * ds_unit();  // relative offsets have no unit
  }

  // in:  ws        from evaluate() (same field parameters)
  //      v_offsets gradient of the loss w.r.t. the offsets [3|4|3 x N]
  // out: v_params  [parameter_count], ACCUMULATED (+=)
  //      v_means   [3 x N] gradient through the network's x input, overwritten;
  //                nullptr: skip (Deformable 3DGS detaches x from the network)
  void evaluate_vjp(Workspace& ws, const DeformationOffsets<Scalar>& v_offsets, Scalar* v_params,
                    Matrix3X<Scalar>* v_means, int threads = 0) const {
    const Eigen::Index n = ws.input.cols();
    ensure(v_offsets.dx.cols() == n && v_offsets.dq.cols() == n && v_offsets.ds.cols() == n,
           "DeformationField::evaluate_vjp: gradients for ", v_offsets.dx.cols(), " Gaussians, evaluated ", n);
    if (ws.v_out.rows() != kOutputs || ws.v_out.cols() != n) ws.v_out.resize(kOutputs, n);
    ws.v_out.topRows(3) = v_offsets.dx * unit_;
    ws.v_out.middleRows(3, 4) = v_offsets.dq;
    ws.v_out.middleRows(7, 3) = v_offsets.ds * ds_unit();
    mlp_.backward(ws.input, ws.mlp, ws.v_out, v_params, v_means ? &ws.v_input : nullptr, threads);
    if (v_means) {
      if (v_means->cols() != n) v_means->resize(3, n);
      x_enc_.encode_vjp(ws.input, ws.v_input, *v_means, 0);
      *v_means /= unit_;
    }
  }

  void save(std::ostream& os) const {
    binary_io::write_tag(os, kTag, sizeof(Scalar));
    const std::int32_t ints[7] = {p_.depth,         p_.width, p_.skip_layer, p_.x_frequencies, p_.t_frequencies,
                                  std::int32_t(p_.seed), std::int32_t(p_.scale_offset)};
    for (auto v : ints) binary_io::write(os, v);
    binary_io::write(os, p_.head_init_scale);
    for (int k = 0; k < 3; ++k) binary_io::write(os, center_[k]);
    binary_io::write(os, unit_);
    binary_io::write_array(os, parameters().data(), parameters().size());
    ensure(bool(os), "DeformationField::save: write failed");
  }
  static DeformationField load(std::istream& is) {
    binary_io::read_tag(is, kTag, sizeof(Scalar));
    DeformationFieldParams p;
    p.depth = binary_io::read<std::int32_t>(is, "deformation depth");
    p.width = binary_io::read<std::int32_t>(is, "deformation width");
    p.skip_layer = binary_io::read<std::int32_t>(is, "deformation skip layer");
    p.x_frequencies = binary_io::read<std::int32_t>(is, "deformation x frequencies");
    p.t_frequencies = binary_io::read<std::int32_t>(is, "deformation t frequencies");
    p.seed = std::uint32_t(binary_io::read<std::int32_t>(is, "deformation seed"));
    const auto mode = binary_io::read<std::int32_t>(is, "deformation scale offset");
    ensure(mode == std::int32_t(ScaleOffset::additive) || mode == std::int32_t(ScaleOffset::log),
           "DeformationField::load: unknown scale offset mode ", mode);
    p.scale_offset = ScaleOffset(mode);
    p.head_init_scale = binary_io::read<double>(is, "deformation head scale");
    ensure(p.depth >= 1 && p.depth <= 1024 && p.width >= 1 && p.width <= 65536 && p.x_frequencies >= 0 &&
               p.x_frequencies <= 64 && p.t_frequencies >= 0 && p.t_frequencies <= 64,
           "DeformationField::load: implausible network (depth ", p.depth, ", width ", p.width, ", frequencies ",
           p.x_frequencies, " and ", p.t_frequencies, ")");
    Eigen::Matrix<Scalar, 3, 1> c;
    for (int k = 0; k < 3; ++k) c[k] = binary_io::read<Scalar>(is, "deformation frame centre");
    const Scalar unit = binary_io::read<Scalar>(is, "deformation frame unit");
    auto w = binary_io::read_array<Scalar>(is, "deformation parameters");
    // The network is built (and its parameters allocated) only when the stored ones
    // can fill it: its hidden layers alone hold width x (depth + width x (depth - 1)).
    const std::uint64_t least =
        std::uint64_t(p.width) * (std::uint64_t(p.depth) + std::uint64_t(p.width) * std::uint64_t(p.depth - 1));
    ensure(w.size() >= least, "DeformationField::load: ", w.size(), " parameters stored, a ", p.depth, "x", p.width,
           " network has more");
    DeformationField f(p);
    f.set_frame(c, unit);
    ensure(w.size() == f.parameter_count(), "DeformationField::load: ", w.size(), " parameters stored, the ",
           p.depth, "x", p.width, " network has ", f.parameter_count());
    ensure(std::all_of(w.begin(), w.end(), [](Scalar x) { return std::isfinite(double(x)); }),
           "DeformationField::load: non-finite parameters");
    f.parameters() = std::move(w);
    return f;
  }

 private:
  static constexpr char kTag[9] = "OFDEFRM2";
  Scalar ds_unit() const { return p_.scale_offset == ScaleOffset::log ? Scalar(1) : unit_; }
  static MlpParams mlp_params(const DeformationFieldParams& p) {
    ensure(p.x_frequencies >= 0 && p.t_frequencies >= 0, "DeformationField: negative frequency count");
    MlpParams m;
    m.input_dims = 3 * (1 + 2 * p.x_frequencies) + (1 + 2 * p.t_frequencies);
    m.depth = p.depth;
    m.width = p.width;
    m.skip_layer = p.skip_layer;
    m.head_dims = {3, 4, 3};
    m.shared_input_dims = 1 + 2 * p.t_frequencies;  // the time code's rows, last
    return m;
  }

  DeformationFieldParams p_;
  FrequencyEncoding<Scalar> x_enc_, t_enc_;
  Mlp<Scalar> mlp_;
  Eigen::Matrix<Scalar, 3, 1> center_ = Eigen::Matrix<Scalar, 3, 1>::Zero();
  Scalar unit_ = Scalar(1);
};

// ---------------------------------------------------------------------------
// Applying offsets to canonical Gaussians.

// Deformed geometry, Gaussians as columns.
template <class Scalar>
struct DeformedGeometry {
  Matrix3X<Scalar> means;      // x + dx
  Matrix4X<Scalar> rotations;  // normalize(q) + dq, NOT normalised (the renderer normalises)
  Matrix3X<Scalar> scales;     // exp(log s) + ds, activated, any sign
};

// torch.nn.functional.normalize's guard: q / max(|q|, 1e-12).
template <class Scalar>
constexpr Scalar quaternion_norm_floor() { return Scalar(1e-12); }

// in:  means [3 x N], rotations [4 x N] (w, x, y, z; any norm), log_scales [3 x N], off
// out: out (resized)
template <class Scalar>
void apply_deformation(const Eigen::Ref<const Matrix3X<Scalar>>& means,
                       const Eigen::Ref<const Matrix4X<Scalar>>& rotations,
                       const Eigen::Ref<const Matrix3X<Scalar>>& log_scales, const DeformationOffsets<Scalar>& off,
                       DeformedGeometry<Scalar>& out) {
  const Eigen::Index n = means.cols();
  ensure(rotations.cols() == n && log_scales.cols() == n && off.dx.cols() == n && off.dq.cols() == n &&
             off.ds.cols() == n,
         "apply_deformation: inconsistent Gaussian counts (means ", n, ", rotations ", rotations.cols(),
         ", log_scales ", log_scales.cols(), ", offsets ", off.dx.cols(), ")");
  out.means = means + off.dx;
  out.rotations.resize(4, n);
  for (Eigen::Index j = 0; j < n; ++j) {
    const Scalar norm = std::max(rotations.col(j).norm(), quaternion_norm_floor<Scalar>());
    out.rotations.col(j) = rotations.col(j) / norm + off.dq.col(j);
  }
  out.scales = log_scales.array().exp().matrix() + off.ds;
}

// in:  means, rotations, log_scales   as given to apply_deformation
//      v_out                          gradients w.r.t. its outputs
// out: v_means, v_rotations, v_log_scales  gradients w.r.t. the canonical parameters (overwritten)
//      v_off                          gradients w.r.t. the offsets (overwritten)
template <class Scalar>
void apply_deformation_vjp(const Eigen::Ref<const Matrix4X<Scalar>>& rotations,
                           const Eigen::Ref<const Matrix3X<Scalar>>& log_scales, const DeformedGeometry<Scalar>& v_out,
                           Matrix3X<Scalar>& v_means, Matrix4X<Scalar>& v_rotations, Matrix3X<Scalar>& v_log_scales,
                           DeformationOffsets<Scalar>& v_off) {
  const Eigen::Index n = rotations.cols();
  ensure(log_scales.cols() == n && v_out.means.cols() == n && v_out.rotations.cols() == n && v_out.scales.cols() == n,
         "apply_deformation_vjp: inconsistent Gaussian counts");
  v_means = v_out.means;
  v_off.dx = v_out.means;
  v_off.dq = v_out.rotations;
  v_off.ds = v_out.scales;
  v_log_scales = (v_out.scales.array() * log_scales.array().exp()).matrix();
  v_rotations.resize(4, n);
  for (Eigen::Index j = 0; j < n; ++j) {
    const Scalar len = rotations.col(j).norm();
    const auto g = v_out.rotations.col(j);
    if (len < quaternion_norm_floor<Scalar>()) {  // q / floor: linear
      v_rotations.col(j) = g / quaternion_norm_floor<Scalar>();
      continue;
    }
    const Eigen::Matrix<Scalar, 4, 1> u = rotations.col(j) / len;
    // d(q/|q|)/dq = (I - u u^T) / |q|
    v_rotations.col(j) = (g - u * u.dot(g)) / len;
  }
}

// The log-scale a static renderer stores for an activated scale of any sign:
// l = log(max(|s|, eps)). Its vjp is v_s = v_l / s where |s| > eps, else 0.
template <class Scalar>
void log_abs_scales(const Eigen::Ref<const Matrix3X<Scalar>>& scales, Scalar eps, Matrix3X<Scalar>& out) {
  out = scales.array().abs().max(eps).log().matrix();
}
template <class Scalar>
void log_abs_scales_vjp(const Eigen::Ref<const Matrix3X<Scalar>>& scales, Scalar eps,
                        const Eigen::Ref<const Matrix3X<Scalar>>& v_log, Matrix3X<Scalar>& v_scales) {
  v_scales = (scales.array().abs() > eps).select(v_log.array() / scales.array(), Scalar(0)).matrix();
}

// Views of a scene's geometry as [k x N] matrices (no copies).
template <class Scalar>
Eigen::Map<const Matrix3X<Scalar>> means_matrix(const GaussianScene<Scalar>& s) {
  return {s.means.data(), 3, Eigen::Index(s.size())};
}
template <class Scalar>
Eigen::Map<const Matrix4X<Scalar>> rotations_matrix(const GaussianScene<Scalar>& s) {
  return {s.rotations.data(), 4, Eigen::Index(s.size())};
}
template <class Scalar>
Eigen::Map<const Matrix3X<Scalar>> log_scales_matrix(const GaussianScene<Scalar>& s) {
  return {s.log_scales.data(), 3, Eigen::Index(s.size())};
}

}  // namespace orbitforge

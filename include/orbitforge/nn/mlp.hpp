#pragma once
// A fully connected ReLU network evaluated on many points at once, points as
// COLUMNS (features x points, column-major): each layer is one matrix product
// W [out x in] * A [in x n] over a chunk of points (dense.hpp's kernels up to
// dense_max_width units, Eigen's GEMM above), and a [3 x N] column-major matrix
// is exactly the [N][3] layout of GaussianScene::means, so inputs and outputs
// need no transposes.
//
// Architecture (Deformable 3D Gaussians' deformation MLP when depth 8, width 256,
// skip_layer 4):
//   h_0 = relu(W_0 x + b_0)
//   h_i = relu(W_i h_{i-1} + b_i)                 i = 1 .. depth-1
//   h_i = relu(W_i [x; h_{i-1}] + b_i)            i = skip_layer + 1 (input first, as
//                                                 torch.cat([x, h]) in that code)
//   y   = W_o h_{depth-1} + b_o                   all linear heads stacked as one layer;
//                                                 head k is rows [head_offset(k), +head_dims[k])
//
// Shared input: the last shared_input_dims rows of x may be the same for every
// point (the deformation field's time code). They are then given once per call
// instead of per column, and their product with the weights is added to the
// bias of the layers that read x: W [x_v; s] + b = W_v x_v + (W_s s + b).
// Their weights' gradient is the bias gradient times s^T.
//
// Parameters live in ONE flat buffer (tiny-cuda-nn style) so that Adam runs over a
// single array; per layer: W (rows x cols, column-major) then b (rows). Gradients
// use the same layout.
//
// Threading: the N points are split into `threads` contiguous ranges, one task
// each, processed in column chunks of `chunk_columns`. Parameter gradients are
// accumulated per RANGE (not per worker) and summed in a fixed order, so results
// are bitwise reproducible for a given thread count.
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <numeric>
#include <random>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
#include "orbitforge/nn/dense.hpp"

namespace orbitforge {

struct MlpParams {
  int input_dims = 0;
  int depth = 8;               // hidden layers (linear + ReLU), >= 1
  int width = 256;
  int skip_layer = -1;         // input concatenated to h_skip_layer (feeds layer skip_layer+1); -1: none
  std::vector<int> head_dims;  // linear output heads on h_{depth-1}; at least one
  int shared_input_dims = 0;   // the last rows of the input, the same for every point (see above); < input_dims
};

template <class Scalar>
class Mlp {
 public:
  using Matrix = Eigen::Matrix<Scalar, Eigen::Dynamic, Eigen::Dynamic>;  // features x points
  using Vector = Eigen::Matrix<Scalar, Eigen::Dynamic, 1>;
  using MatrixMap = Eigen::Map<Matrix>;
  using ConstMatrixMap = Eigen::Map<const Matrix>;

  struct Layer {
    int rows = 0, cols = 0;       // W is rows x cols
    std::size_t w = 0, b = 0;     // offsets of W and b in the flat buffer
  };

  // Forward activations (kept for the backward pass) and backward scratch.
  // Owned by the caller and reused across calls; it only grows.
  struct Workspace {
    std::vector<Matrix> hidden;  // depth x [width x N], post-ReLU
    Eigen::Index points = 0;
    Vector shared;               // the shared input rows of the last forward
    std::vector<Vector> biases;  // per layer: b_i with W_i's shared columns times `shared` added (forward)
    std::vector<Matrix> scratch_a, scratch_b;              // per range: [width x chunk]
    std::vector<std::vector<Scalar>> range_grads;         // per range: [parameter_count]
    std::vector<std::vector<Scalar>> outer_scratch;       // per range: dense_accumulate_outer's
    std::vector<Vector> chunk_bias_grad;                  // per range: a layer's bias gradient over one chunk
    // The layers' weights laid out for dense_forward, set at each call: W_i and b_i
    // for the forward; W_i^T (the skip layer: its h_{i-1} columns, transposed) and
    // the heads' W^T for the backward (index depth), layer 0's unused.
    std::vector<DenseWeights<Scalar>> forward_weights, backward_weights;
  };

  // Column chunk processed per GEMM; measured in bench_mlp (512..2048 perform alike).
  Eigen::Index chunk_columns = 1024;
  // Networks up to this width use dense.hpp's kernels, which keep a layer's
  // weights in L1 (64 x 64 floats: 16 KB); wider ones use Eigen's packed GEMM,
  // which reuses each weight over more points (bench_mlp, 4 x 64 fwd+bwd x0.82-0.95
  // with the kernels; 4 x 128 x0.92-1.04; 8 x 256 x1.2-1.6).
  int dense_max_width = 64;

  explicit Mlp(const MlpParams& p) : p_(p) {
    ensure(p.input_dims > 0, "Mlp: input_dims must be positive, got ", p.input_dims);
    ensure(p.depth >= 1, "Mlp: depth must be >= 1, got ", p.depth);
    ensure(p.width >= 1, "Mlp: width must be >= 1, got ", p.width);
    ensure(p.skip_layer == -1 || (p.skip_layer >= 0 && p.skip_layer < p.depth - 1), "Mlp: skip_layer ",
           p.skip_layer, " must be -1 or in [0, depth-1) = [0, ", p.depth - 1, ")");
    ensure(!p.head_dims.empty(), "Mlp: at least one output head is needed");
    ensure(p.shared_input_dims >= 0 && p.shared_input_dims < p.input_dims, "Mlp: shared_input_dims ",
           p.shared_input_dims, " must be in [0, input_dims) = [0, ", p.input_dims, ")");
    std::size_t off = 0;
    auto add = [&](int rows, int cols) {
      Layer l;
      l.rows = rows;
      l.cols = cols;
      l.w = off;
      off += std::size_t(rows) * std::size_t(cols);
      l.b = off;
      off += std::size_t(rows);
      layers_.push_back(l);
    };
    for (int i = 0; i < p.depth; ++i) {
      const int in = i == 0 ? p.input_dims : (i == p.skip_layer + 1 && p.skip_layer >= 0 ? p.input_dims + p.width : p.width);
      add(p.width, in);
    }
    int out = 0;
    for (int h : p.head_dims) {
      ensure(h > 0, "Mlp: head dimensions must be positive, got ", h);
      head_offsets_.push_back(out);
      out += h;
    }
    add(out, p.width);
    params_.assign(off, Scalar(0));
  }

  const MlpParams& params() const { return p_; }
  int input_dims() const { return p_.input_dims; }
  // Rows of the input matrix forward() takes: the input less its shared rows.
  int point_input_dims() const { return p_.input_dims - p_.shared_input_dims; }
  int output_dims() const { return layers_.back().rows; }
  int head_offset(int k) const { return head_offsets_.at(std::size_t(k)); }
  const std::vector<Layer>& layers() const { return layers_; }
  bool is_skip_input(int i) const { return p_.skip_layer >= 0 && i == p_.skip_layer + 1; }

  std::size_t parameter_count() const { return params_.size(); }
  std::vector<Scalar>& parameters() { return params_; }
  const std::vector<Scalar>& parameters() const { return params_; }

  // PyTorch nn.Linear default: W and b ~ U(-1/sqrt(fan_in), 1/sqrt(fan_in)) (that is
  // kaiming_uniform with a = sqrt(5)). The heads' W and b are further multiplied by
  // head_scale (1 = PyTorch default). Portable: uniform values come straight from
  // mt19937 words, not from a library distribution.
  void init(std::uint32_t seed, Scalar head_scale = Scalar(1)) {
    std::mt19937 rng(seed);
    auto uniform = [&rng](double bound) {
      const double u = (double(rng()) + 0.5) / 4294967296.0;  // (0, 1)
      return bound * (2.0 * u - 1.0);
    };
    for (std::size_t li = 0; li < layers_.size(); ++li) {
      const Layer& l = layers_[li];
      const double bound = 1.0 / std::sqrt(double(l.cols));
      const double scale = li + 1 == layers_.size() ? double(head_scale) : 1.0;
      for (std::size_t k = l.w; k < l.b + std::size_t(l.rows); ++k) params_[k] = Scalar(scale * uniform(bound));
    }
  }

  ConstMatrixMap weight(int i) const {
    const Layer& l = layers_[std::size_t(i)];
    return ConstMatrixMap(params_.data() + l.w, l.rows, l.cols);
  }
  Eigen::Map<const Vector> bias(int i) const {
    const Layer& l = layers_[std::size_t(i)];
    return Eigen::Map<const Vector>(params_.data() + l.b, l.rows);
  }

  // in:  input  [point_input_dims x N]
  //      shared [shared_input_dims] the input's last rows, the same for every point (null when none)
  // out: out    [output_dims x N] (resized), ws.hidden filled for backward()
  void forward(const Matrix& input, Workspace& ws, Matrix& out, int threads = 0, const Scalar* shared = nullptr) const {
    ensure(input.rows() == point_input_dims(), "Mlp::forward: input has ", input.rows(), " rows, expected ",
           point_input_dims());
    ensure((shared != nullptr) == (p_.shared_input_dims > 0), "Mlp::forward: the network has ",
           p_.shared_input_dims, " shared input rows, and they were ", shared ? "" : "not ", "given");
    ws.shared = Eigen::Map<const Vector>(shared, shared ? p_.shared_input_dims : 0);
    ensure(ws.shared.allFinite(), "Mlp::forward: the shared input contains non-finite values");
    const Eigen::Index n = input.cols();
    ws.hidden.resize(std::size_t(p_.depth));
    for (auto& h : ws.hidden)
      if (h.rows() != p_.width || h.cols() != n) h.resize(p_.width, n);
    ws.points = n;
    if (out.rows() != output_dims() || out.cols() != n) out.resize(output_dims(), n);
    ws.biases.resize(layers_.size());
    for (std::size_t i = 0; i < layers_.size(); ++i) {
      const Layer& l = layers_[i];
      ws.biases[i] = Eigen::Map<const Vector>(params_.data() + l.b, l.rows);
      if (reads_input(int(i)) && p_.shared_input_dims > 0)
        ws.biases[i].noalias() +=
            weight(int(i)).middleCols(point_input_dims(), p_.shared_input_dims) * ws.shared;
    }
    ws.forward_weights.resize(dense_kernels() ? layers_.size() : 0);
    for (std::size_t i = 0; i < ws.forward_weights.size(); ++i) {
      const Layer& l = layers_[i];
      ws.forward_weights[i].template assign<Batch>(params_.data() + l.w, l.rows, l.rows, l.cols, false,
                                                   ws.biases[i].data());
    }
    const int ranges = range_count(n, threads);
    parallel_for(std::size_t(ranges), ranges, [&](std::size_t r, int) {
      const auto [begin, end] = range(n, ranges, int(r));
      for (Eigen::Index c0 = begin; c0 < end; c0 += chunk_columns) {
        const Eigen::Index m = std::min(chunk_columns, end - c0);
        // x - x is 0 exactly where x is finite, NaN elsewhere. Eigen vectorises
        // this sum but not allFinite (76 x 36k floats: 0.15 ms against 1.7 ms).
        const auto chunk_in = input.middleCols(c0, m).array();
        ensure((chunk_in - chunk_in).sum() == Scalar(0), "Mlp::forward: input contains non-finite values (points ", c0,
               " to ", c0 + m - 1, ")");
        forward_chunk(input, ws, out, c0, m);
      }
    });
  }

  // in:  input    [point_input_dims x N]  as given to forward()
  //      ws                               from forward() on that input
  //      v_out    [output_dims x N]       gradient of the loss w.r.t. the outputs
  // out: v_params [parameter_count]       gradient w.r.t. the parameters, ACCUMULATED (+=)
  //      v_input  [point_input_dims x N]  gradient w.r.t. the input, overwritten; nullptr: skip
  void backward(const Matrix& input, Workspace& ws, const Matrix& v_out, Scalar* v_params, Matrix* v_input,
                int threads = 0) const {
    const Eigen::Index n = input.cols();
    ensure(ws.points == n && ws.hidden.size() == std::size_t(p_.depth),
           "Mlp::backward: workspace does not hold a forward pass over these ", n, " points");
    ensure(v_out.rows() == output_dims() && v_out.cols() == n, "Mlp::backward: v_out is ", v_out.rows(), "x",
           v_out.cols(), ", expected ", output_dims(), "x", n);
    ensure(v_params != nullptr, "Mlp::backward: v_params is null");
    if (v_input && (v_input->rows() != point_input_dims() || v_input->cols() != n))
      v_input->resize(point_input_dims(), n);
    const int ranges = range_count(n, threads);
    const Eigen::Index chunk = std::min<Eigen::Index>(chunk_columns, std::max<Eigen::Index>(n, 1));
    ws.scratch_a.resize(std::size_t(ranges));
    ws.scratch_b.resize(std::size_t(ranges));
    ws.outer_scratch.resize(std::size_t(ranges));
    ws.chunk_bias_grad.resize(std::size_t(ranges));
    ws.backward_weights.resize(dense_kernels() ? layers_.size() : 0);
    for (std::size_t i = 1; i < ws.backward_weights.size(); ++i) {
      const Layer& l = layers_[i];
      // The part of W_i that multiplies h_{i-1}: all of it, or the skip layer's last width columns.
      const Eigen::Index in_cols = is_skip_input(int(i)) ? p_.input_dims : 0;
      ws.backward_weights[i].template assign<Batch>(params_.data() + l.w + std::size_t(in_cols) * std::size_t(l.rows),
                                                    l.rows, l.cols - in_cols, l.rows, true, nullptr);
    }
    // With one range the gradients go straight into v_params (still accumulated).
    if (ranges > 1) ws.range_grads.resize(std::size_t(ranges));
    parallel_for(std::size_t(ranges), ranges, [&](std::size_t r, int) {
      Matrix& a = ws.scratch_a[r];
      Matrix& b = ws.scratch_b[r];
      const Eigen::Index rows = std::max(p_.width, output_dims());
      if (a.rows() != rows || a.cols() != chunk) a.resize(rows, chunk);
      if (b.rows() != rows || b.cols() != chunk) b.resize(rows, chunk);
      Scalar* g = v_params;
      if (ranges > 1) {
        ws.range_grads[r].assign(params_.size(), Scalar(0));
        g = ws.range_grads[r].data();
      }
      const auto [begin, end] = range(n, ranges, int(r));
      for (Eigen::Index c0 = begin; c0 < end; c0 += chunk_columns) {
        const Eigen::Index m = std::min(chunk_columns, end - c0);
        backward_chunk(input, ws, v_out, g, v_input, c0, m, a, b, ws.outer_scratch[r], ws.chunk_bias_grad[r]);
      }
    });
    if (ranges > 1) {
      Eigen::Map<Vector> total(v_params, Eigen::Index(params_.size()));
      for (int r = 0; r < ranges; ++r)
        total += Eigen::Map<const Vector>(ws.range_grads[std::size_t(r)].data(), Eigen::Index(params_.size()));
    }
  }

 private:
  using Batch = simd::native_batch<Scalar>;
  bool dense_kernels() const { return p_.width <= dense_max_width; }

  int range_count(Eigen::Index n, int threads) const {
    const Eigen::Index by_size = (n + chunk_columns - 1) / chunk_columns;
    return int(std::max<Eigen::Index>(1, std::min<Eigen::Index>(resolve_threads(threads), by_size)));
  }
  static std::pair<Eigen::Index, Eigen::Index> range(Eigen::Index n, int ranges, int r) {
    return {n * r / ranges, n * (r + 1) / ranges};
  }

  // gb += sum of the columns of a, in column order. (Eigen's rowwise().sum() picks
  // its summation order by the runtime alignment of the data, which would make
  // gradients differ from run to run in the last bits.)
  template <class Block>
  static void add_column_sum(const Block& a, Eigen::Map<Vector>& gb) {
    for (Eigen::Index j = 0; j < a.cols(); ++j) gb += a.col(j);
  }

  using StridedMap = Eigen::Map<Matrix, 0, Eigen::OuterStride<>>;
  using ConstStridedMap = Eigen::Map<const Matrix, 0, Eigen::OuterStride<>>;

  bool reads_input(int i) const { return i == 0 || is_skip_input(i); }

  // Layer i over m points: z = act(W_i [x; h] + b_i), x (its point rows) only in
  // layer 0 and the skip layer, h (the previous layer's output) in every other;
  // act is ReLU except for the heads (i == depth).
  void layer_forward(const Workspace& ws, int i, const Scalar* x, Eigen::Index ldx, const Scalar* h, Eigen::Index m,
                     Scalar* z, Eigen::Index ldz) const {
    const Layer& l = layers_[std::size_t(i)];
    const bool relu = i < p_.depth;
    const Eigen::Index x_cols = reads_input(i) ? point_input_dims() : 0;
    const Eigen::Index h_col = reads_input(i) ? p_.input_dims : 0;  // W_i's first column on h
    if (dense_kernels()) {
      const DenseWeights<Scalar>& w = ws.forward_weights[std::size_t(i)];
      DenseTerm<Scalar> terms[2];
      int n_terms = 0;
      if (x_cols > 0) terms[n_terms++] = {w.column(0), w.ld, x_cols, x, ldx};
      if (i > 0) terms[n_terms++] = {w.column(h_col), w.ld, p_.width, h, p_.width};
      dense_forward<Batch>(w.rows, terms, n_terms, w.b.data(), m, z, ldz, relu);
      return;
    }
    ConstMatrixMap w(params_.data() + l.w, l.rows, l.cols);
    StridedMap zm(z, l.rows, m, Eigen::OuterStride<>(ldz));
    if (x_cols > 0) zm.noalias() = w.leftCols(x_cols) * ConstStridedMap(x, x_cols, m, Eigen::OuterStride<>(ldx));
    if (i > 0) {
      const ConstMatrixMap hm(h, p_.width, m);
      if (x_cols > 0) zm.noalias() += w.middleCols(h_col, p_.width) * hm;
      else zm.noalias() = w * hm;
    }
    const Vector& b = ws.biases[std::size_t(i)];
    if (relu) zm = (zm.colwise() + b).cwiseMax(Scalar(0));  // one pass over z
    else zm.colwise() += b;
  }

  // g (rows x cols, leading dimension ldg) += d h^T over m points; bias_grad
  // (rows values, or nullptr) += the sum of d's columns.
  void weight_gradient(Scalar* g, Eigen::Index ldg, Eigen::Index rows, Eigen::Index cols, const Scalar* d,
                       Eigen::Index ldd, const Scalar* h, Eigen::Index ldh, Eigen::Index m,
                       std::vector<Scalar>& outer, Scalar* bias_grad) const {
    if (dense_kernels()) {
      dense_accumulate_outer<Batch>(g, ldg, rows, cols, d, ldd, h, ldh, m, outer, bias_grad);
      return;
    }
    StridedMap(g, rows, cols, Eigen::OuterStride<>(ldg)).noalias() +=
        ConstStridedMap(d, rows, m, Eigen::OuterStride<>(ldd)) *
        ConstStridedMap(h, cols, m, Eigen::OuterStride<>(ldh)).transpose();
    if (bias_grad) {
      Eigen::Map<Vector> gb(bias_grad, rows);
      add_column_sum(ConstStridedMap(d, rows, m, Eigen::OuterStride<>(ldd)), gb);
    }
  }

  // v_h (width x m) = W_i^T v_z over the columns of W_i that multiply h_{i-1}
  // (i == depth: the heads'), then zero where h_{i-1} (the saved ReLU output,
  // width x m) is not positive: the gradient w.r.t. layer i-1's pre-activation.
  void back_through(const Workspace& ws, int i, const Scalar* v_z, Eigen::Index ld_v_z, Eigen::Index m,
                    const Scalar* h, Matrix& v_h) const {
    if (dense_kernels()) {
      const DenseWeights<Scalar>& wt = ws.backward_weights[std::size_t(i)];
      const DenseTerm<Scalar> term{wt.column(0), wt.ld, wt.cols, v_z, ld_v_z};
      dense_forward<Batch>(p_.width, &term, 1, nullptr, m, v_h.data(), v_h.rows(), false, h, p_.width);
      return;
    }
    const Layer& l = layers_[std::size_t(i)];
    ConstMatrixMap w(params_.data() + l.w, l.rows, l.cols);
    auto dz = v_h.topLeftCorner(p_.width, m);
    dz.noalias() = w.rightCols(p_.width).transpose() * ConstStridedMap(v_z, l.rows, m, Eigen::OuterStride<>(ld_v_z));
    // ReLU: relu(z) > 0 exactly where z > 0, so the saved output is the mask.
    dz.array() = (ConstMatrixMap(h, p_.width, m).array() > Scalar(0)).select(dz.array(), Scalar(0));
  }

  void forward_chunk(const Matrix& input, Workspace& ws, Matrix& out, Eigen::Index c0, Eigen::Index m) const {
    const Scalar* x = input.data() + c0 * input.rows();
    for (int i = 0; i <= p_.depth; ++i) {
      const Scalar* h = i > 0 ? ws.hidden[std::size_t(i - 1)].data() + c0 * p_.width : nullptr;
      if (i == p_.depth) layer_forward(ws, i, x, input.rows(), h, m, out.data() + c0 * out.rows(), out.rows());
      else layer_forward(ws, i, x, input.rows(), h, m, ws.hidden[std::size_t(i)].data() + c0 * p_.width, p_.width);
    }
  }

  void backward_chunk(const Matrix& input, const Workspace& ws, const Matrix& v_out, Scalar* g, Matrix* v_input,
                      Eigen::Index c0, Eigen::Index m, Matrix& sa, Matrix& sb, std::vector<Scalar>& outer,
                      Vector& chunk_bias_grad) const {
    const Eigen::Index in_rows = input.rows(), width = p_.width;
    const Scalar* x = input.data() + c0 * in_rows;
    auto hidden = [&](int i) { return ws.hidden[std::size_t(i)].data() + c0 * width; };
    // Heads.
    {
      const Layer& l = layers_.back();
      Eigen::Map<Vector> gb(g + l.b, l.rows);
      const Scalar* vy = v_out.data() + c0 * v_out.rows();
      weight_gradient(g + l.w, l.rows, l.rows, l.cols, vy, v_out.rows(), hidden(p_.depth - 1), width, m, outer, nullptr);
      add_column_sum(v_out.middleCols(c0, m), gb);
      back_through(ws, p_.depth, vy, v_out.rows(), m, hidden(p_.depth - 1), sa);  // v_z of layer depth-1
    }
    if (v_input) v_input->middleCols(c0, m).setZero();
    Matrix* cur = &sa;
    Matrix* nxt = &sb;
    for (int i = p_.depth - 1; i >= 0; --i) {
      const Layer& l = layers_[std::size_t(i)];
      Scalar* gb = g + l.b;
      const Scalar* v_z = cur->data();
      const Eigen::Index ld_v_z = cur->rows();
      if (reads_input(i)) {
        // The input's columns of W_i: its point rows' from the products, its
        // shared rows' as the chunk's bias gradient times the shared values.
        Scalar* sums = gb;
        if (p_.shared_input_dims > 0) {
          chunk_bias_grad.setZero(width);
          sums = chunk_bias_grad.data();
        }
        weight_gradient(g + l.w, l.rows, l.rows, in_rows, v_z, ld_v_z, x, in_rows, m, outer, sums);
        if (p_.shared_input_dims > 0) {
          Eigen::Map<Vector>(gb, l.rows) += chunk_bias_grad;
          MatrixMap(g + l.w, l.rows, l.cols).middleCols(in_rows, p_.shared_input_dims).noalias() +=
              chunk_bias_grad * ws.shared.transpose();
        }
        if (v_input) {
          ConstMatrixMap w(params_.data() + l.w, l.rows, l.cols);
          v_input->middleCols(c0, m).noalias() += w.leftCols(in_rows).transpose() * cur->topLeftCorner(width, m);
        }
        if (i == 0) break;
        gb = nullptr;  // summed above
      }
      const Eigen::Index h_col = reads_input(i) ? p_.input_dims : 0;
      weight_gradient(g + l.w + std::size_t(h_col * l.rows), l.rows, l.rows, width, v_z, ld_v_z, hidden(i - 1),
                      width, m, outer, gb);
      back_through(ws, i, v_z, ld_v_z, m, hidden(i - 1), *nxt);
      std::swap(cur, nxt);
    }
  }

  MlpParams p_;
  std::vector<Layer> layers_;
  std::vector<int> head_offsets_;
  std::vector<Scalar> params_;
};

}  // namespace orbitforge

#pragma once
// Adam over named parameter groups, each a flat array of `rows` x `row_width`
// values (a per-Gaussian attribute: rows = Gaussians, row_width = 3 for means; a
// network: rows = parameter count, row_width = 1). Each group has its own
// learning rate and step count, as each torch parameter does in 3DGS.
//
// Update (PyTorch's Adam, no weight decay, no amsgrad):
//   m = b1 m + (1 - b1) g,  v = b2 v + (1 - b2) g^2,  t = t + 1
//   p -= lr / (1 - b1^t) * m / (sqrt(v) / sqrt(1 - b2^t) + eps)
// Defaults b1 = 0.9, b2 = 0.999, eps = 1e-15: the eps that 3DGS and Deformable 3D
// Gaussians pass to torch.optim.Adam for both the Gaussians and the deformation
// network (torch's own default would be 1e-8).
//
// Densification support: keep(mask) drops rows (prune), append(n) adds rows with
// zero moments (clone/split, like 3DGS's cat_tensors_to_optimizer), gather(src)
// does any reindexing at once. Checkpoints: save/load to a binary stream.
#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/nn/binary_io.hpp"

namespace orbitforge {

struct AdamParams {
  double beta1 = 0.9;
  double beta2 = 0.999;
  double eps = 1e-15;
};

// 3DGS's get_expon_lr_func: log-linear interpolation from lr_init to lr_final over
// max_steps, optionally ramped in over delay_steps by a sine from delay_mult:
//   t = clamp(step / max_steps, 0, 1),  lr = lr_init^(1-t) * lr_final^t
//   delay = delay_mult + (1 - delay_mult) sin(pi/2 clamp(step / delay_steps, 0, 1))
struct ExponentialLr {
  double lr_init = 1e-3;
  double lr_final = 1e-5;
  long max_steps = 30000;
  long delay_steps = 0;
  double delay_mult = 1.0;

  double operator()(long step) const {
    if (step < 0 || (lr_init == 0.0 && lr_final == 0.0)) return 0.0;
    ensure(lr_init > 0.0 && lr_final > 0.0, "ExponentialLr: learning rates must be positive (or both 0), got ",
           lr_init, " and ", lr_final);
    double delay = 1.0;
    if (delay_steps > 0) {
      const double u = std::min(1.0, std::max(0.0, double(step) / double(delay_steps)));
      delay = delay_mult + (1.0 - delay_mult) * std::sin(0.5 * Constants<double>::pi() * u);
    }
    const double t = max_steps > 0 ? std::min(1.0, std::max(0.0, double(step) / double(max_steps))) : 1.0;
    return delay * std::exp(std::log(lr_init) * (1.0 - t) + std::log(lr_final) * t);
  }
};

template <class Scalar>
class Adam {
 public:
  struct Group {
    std::string name;
    Scalar lr = 0;
    std::size_t rows = 0;
    int row_width = 1;
    std::int64_t step = 0;
    std::vector<Scalar> m, v;  // [rows * row_width]
    std::size_t size() const { return rows * std::size_t(row_width); }
  };

  explicit Adam(const AdamParams& p = {}) : p_(p) {
    ensure(p.beta1 >= 0 && p.beta1 < 1 && p.beta2 >= 0 && p.beta2 < 1 && p.eps >= 0,
           "Adam: need 0 <= beta < 1 and eps >= 0, got beta1 ", p.beta1, ", beta2 ", p.beta2, ", eps ", p.eps);
  }

  const AdamParams& params() const { return p_; }
  int group_count() const { return int(groups_.size()); }

  // Returns the group's id (its index).
  int add_group(const std::string& name, std::size_t rows, int row_width, Scalar lr) {
    ensure(find(name) < 0, "Adam::add_group: a group named '", name, "' exists already");
    ensure(row_width >= 1, "Adam::add_group: row_width of '", name, "' must be >= 1, got ", row_width);
    Group g;
    g.name = name;
    g.lr = lr;
    g.rows = rows;
    g.row_width = row_width;
    g.m.assign(g.size(), Scalar(0));
    g.v.assign(g.size(), Scalar(0));
    groups_.push_back(std::move(g));
    return int(groups_.size()) - 1;
  }
  int find(const std::string& name) const {
    for (std::size_t i = 0; i < groups_.size(); ++i)
      if (groups_[i].name == name) return int(i);
    return -1;
  }
  Group& group(int id) { return groups_.at(std::size_t(check(id))); }
  const Group& group(int id) const { return groups_.at(std::size_t(check(id))); }
  void set_lr(int id, Scalar lr) { group(id).lr = lr; }

  // params, grads: [rows * row_width] of group `id`.
  void step(int id, Scalar* params, const Scalar* grads) { update(group(id), p_, params, grads, group(id).size()); }

  // One Adam step of a group over `count` values. A plain loop on purpose: with
  // Eigen packets the scalar head depends on the array's address, and head and
  // packets can round differently (FMA contraction), so two identical runs could
  // differ in the last bit, which Adam amplifies for rounding-level gradients.
  static void update(Group& g, const AdamParams& ap, Scalar* params, const Scalar* grads, std::size_t count) {
    ++g.step;
    const double bc1 = 1.0 - std::pow(ap.beta1, double(g.step));
    const double bc2 = 1.0 - std::pow(ap.beta2, double(g.step));
    const Scalar b1 = Scalar(ap.beta1), b2 = Scalar(ap.beta2), eps = Scalar(ap.eps);
    const Scalar step_size = Scalar(double(g.lr) / bc1);
    const Scalar inv_sqrt_bc2 = Scalar(1.0 / std::sqrt(bc2));
    Scalar* m = g.m.data();
    Scalar* v = g.v.data();
    for (std::size_t i = 0; i < count; ++i) {
      m[i] = b1 * m[i] + (Scalar(1) - b1) * grads[i];
      v[i] = b2 * v[i] + (Scalar(1) - b2) * grads[i] * grads[i];
      params[i] -= step_size * m[i] / (std::sqrt(v[i]) * inv_sqrt_bc2 + eps);
    }
  }

  // Keeps the rows whose mask entry is true, in order (prune). mask: [rows].
  void keep(int id, const std::vector<bool>& mask) {
    Group& g = group(id);
    ensure(mask.size() == g.rows, "Adam::keep: group '", g.name, "' has ", g.rows, " rows, mask has ", mask.size());
    const std::size_t w = std::size_t(g.row_width);
    std::size_t out = 0;
    for (std::size_t r = 0; r < g.rows; ++r) {
      if (!mask[r]) continue;
      for (std::size_t k = 0; k < w; ++k) {
        g.m[out * w + k] = g.m[r * w + k];
        g.v[out * w + k] = g.v[r * w + k];
      }
      ++out;
    }
    g.rows = out;
    g.m.resize(g.size());
    g.v.resize(g.size());
  }

  // Appends `count` rows with zero moments (new Gaussians from clone/split).
  void append(int id, std::size_t count) {
    Group& g = group(id);
    g.rows += count;
    g.m.resize(g.size(), Scalar(0));
    g.v.resize(g.size(), Scalar(0));
  }

  // New row i takes old row source[i]'s moments; source[i] < 0 gives zeros.
  void gather(int id, const std::vector<std::int64_t>& source) {
    Group& g = group(id);
    const std::size_t w = std::size_t(g.row_width);
    std::vector<Scalar> m(source.size() * w, Scalar(0)), v(source.size() * w, Scalar(0));
    for (std::size_t i = 0; i < source.size(); ++i) {
      const std::int64_t s = source[i];
      if (s < 0) continue;
      ensure(std::size_t(s) < g.rows, "Adam::gather: group '", g.name, "': source row ", s, " (entry ", i,
             ") out of range, rows = ", g.rows);
      for (std::size_t k = 0; k < w; ++k) {
        m[i * w + k] = g.m[std::size_t(s) * w + k];
        v[i * w + k] = g.v[std::size_t(s) * w + k];
      }
    }
    g.rows = source.size();
    g.m = std::move(m);
    g.v = std::move(v);
  }

  void save(std::ostream& os) const {
    binary_io::write_tag(os, kTag, sizeof(Scalar));
    binary_io::write(os, p_.beta1);
    binary_io::write(os, p_.beta2);
    binary_io::write(os, p_.eps);
    binary_io::write<std::uint64_t>(os, groups_.size());
    for (const Group& g : groups_) {
      binary_io::write_string(os, g.name);
      binary_io::write(os, g.lr);
      binary_io::write<std::uint64_t>(os, g.rows);
      binary_io::write<std::int32_t>(os, g.row_width);
      binary_io::write<std::int64_t>(os, g.step);
      binary_io::write_array(os, g.m.data(), g.m.size());
      binary_io::write_array(os, g.v.data(), g.v.size());
    }
    ensure(bool(os), "Adam::save: write failed");
  }

  // Replaces this optimiser's state with the stream's.
  void load(std::istream& is) {
    binary_io::read_tag(is, kTag, sizeof(Scalar));
    AdamParams p;
    p.beta1 = binary_io::read<double>(is, "Adam beta1");
    p.beta2 = binary_io::read<double>(is, "Adam beta2");
    p.eps = binary_io::read<double>(is, "Adam eps");
    const auto count = binary_io::read<std::uint64_t>(is, "Adam group count");
    ensure(count < (1u << 20), "Adam::load: implausible group count ", count);
    std::vector<Group> groups;
    for (std::uint64_t i = 0; i < count; ++i) {
      Group g;
      g.name = binary_io::read_string(is, "Adam group name");
      g.lr = binary_io::read<Scalar>(is, "Adam group lr");
      g.rows = binary_io::read<std::uint64_t>(is, "Adam group rows");
      g.row_width = binary_io::read<std::int32_t>(is, "Adam group row width");
      g.step = binary_io::read<std::int64_t>(is, "Adam group step");
      g.m = binary_io::read_array<Scalar>(is, "Adam first moments");
      g.v = binary_io::read_array<Scalar>(is, "Adam second moments");
      ensure(g.row_width >= 1 && g.m.size() == g.size() && g.v.size() == g.size(), "Adam::load: group '", g.name,
             "' (", i, ") has inconsistent sizes");
      groups.push_back(std::move(g));
    }
    p_ = p;
    groups_ = std::move(groups);
  }

 private:
  static constexpr char kTag[9] = "OFADAM01";
  int check(int id) const {
    ensure(id >= 0 && std::size_t(id) < groups_.size(), "Adam: no group with id ", id, " (", groups_.size(),
           " groups)");
    return id;
  }
  AdamParams p_;
  std::vector<Group> groups_;
};

}  // namespace orbitforge

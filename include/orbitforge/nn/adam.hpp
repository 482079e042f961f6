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
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <istream>
#include <ostream>
#include <string>
#include <vector>

#include "orbitforge/core/constants.hpp"
#include "orbitforge/core/error.hpp"
#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/core/simd.hpp"
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

// The coefficients of one Adam step of a group (bias corrections folded in).
template <class Scalar>
struct AdamStep {
  Scalar b1, b2, eps, step_size, inv_sqrt_bc2;
  static AdamStep of(const AdamParams& ap, double lr, std::int64_t step) {
    const double bc1 = 1.0 - std::pow(ap.beta1, double(step));
    const double bc2 = 1.0 - std::pow(ap.beta2, double(step));
    return {Scalar(ap.beta1), Scalar(ap.beta2), Scalar(ap.eps), Scalar(lr / bc1), Scalar(1.0 / std::sqrt(bc2))};
  }
};

// Values per parallel block of an update (a multiple of every SIMD width).
constexpr std::size_t kAdamBlock = 16384;

// The Adam arithmetic on `count` values, SIMD (the compiler leaves std::sqrt
// scalar because of errno). The tail goes through the same vector formula in a
// zero-padded batch (zero moments give a zero step), so every value is rounded
// the same way wherever it sits, and results do not depend on addresses, block
// boundaries or thread counts: two identical runs agree bit for bit.
template <class Scalar>
void adam_apply(const AdamStep<Scalar>& c, Scalar* params, const Scalar* grads, Scalar* m, Scalar* v,
                std::size_t count) {
  using B = simd::native_batch<Scalar>;
  constexpr std::size_t L = B::size;
  const B b1(c.b1), b2(c.b2), a1(Scalar(1) - c.b1), a2(Scalar(1) - c.b2), eps(c.eps), step(c.step_size),
      inv(c.inv_sqrt_bc2);
  auto kernel = [&](Scalar* p, const Scalar* g, Scalar* mm, Scalar* vv) {
    const B gb = B::load_unaligned(g);
    const B mb = b1 * B::load_unaligned(mm) + a1 * gb;
    const B vb = b2 * B::load_unaligned(vv) + a2 * gb * gb;
    mb.store_unaligned(mm);
    vb.store_unaligned(vv);
    (B::load_unaligned(p) - step * mb / (simd::sqrt(vb) * inv + eps)).store_unaligned(p);
  };
  std::size_t i = 0;
  for (; i + L <= count; i += L) kernel(params + i, grads + i, m + i, v + i);
  if (i < count) {
    Scalar tp[L] = {}, tg[L] = {}, tm[L] = {}, tv[L] = {};
    const std::size_t r = count - i;
    std::copy_n(params + i, r, tp);
    std::copy_n(grads + i, r, tg);
    std::copy_n(m + i, r, tm);
    std::copy_n(v + i, r, tv);
    kernel(tp, tg, tm, tv);
    std::copy_n(tp, r, params + i);
    std::copy_n(tm, r, m + i);
    std::copy_n(tv, r, v + i);
  }
}

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

  // One Adam step of a group over `count` values, on `threads` threads.
  static void update(Group& g, const AdamParams& ap, Scalar* params, const Scalar* grads, std::size_t count,
                     int threads = 1) {
    ++g.step;
    const AdamStep<Scalar> c = AdamStep<Scalar>::of(ap, double(g.lr), g.step);
    const std::size_t blocks = (count + kAdamBlock - 1) / kAdamBlock;
    parallel_for(blocks, threads, [&](std::size_t b, int) {
      const std::size_t i0 = b * kAdamBlock, n = std::min(kAdamBlock, count - i0);
      adam_apply(c, params + i0, grads + i0, g.m.data() + i0, g.v.data() + i0, n);
    });
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
    ensure(p.beta1 >= 0 && p.beta1 < 1 && p.beta2 >= 0 && p.beta2 < 1 && p.eps >= 0 && std::isfinite(p.eps),
           "Adam::load: need 0 <= beta < 1 and a finite eps >= 0, got beta1 ", p.beta1, ", beta2 ", p.beta2,
           ", eps ", p.eps);
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
      ensure(g.row_width >= 1 && g.m.size() % std::size_t(g.row_width) == 0 &&
                 g.m.size() / std::size_t(g.row_width) == g.rows && g.v.size() == g.m.size(),
             "Adam::load: group '", g.name, "' (", i, ") has inconsistent sizes");
      ensure(std::isfinite(double(g.lr)) && g.lr >= 0 && g.step >= 0 &&
                 std::all_of(g.m.begin(), g.m.end(), [](Scalar x) { return std::isfinite(double(x)); }) &&
                 std::all_of(g.v.begin(), g.v.end(), [](Scalar x) { return std::isfinite(double(x)) && x >= 0; }),
             "Adam::load: group '", g.name, "' (", i, ") has a non-finite or negative learning rate, step or moment");
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

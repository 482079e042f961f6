#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <random>
#include <sstream>
#include <vector>

#include "orbitforge/deform/deformation_field.hpp"

using namespace orbitforge;

namespace {

template <class S>
Matrix3X<S> random3(Eigen::Index n, std::mt19937& rng, double lo = -1, double hi = 1) {
  std::uniform_real_distribution<double> u(lo, hi);
  Matrix3X<S> m(3, n);
  for (Eigen::Index i = 0; i < m.size(); ++i) m(i) = S(u(rng));
  return m;
}
template <class S>
Matrix4X<S> random4(Eigen::Index n, std::mt19937& rng) {
  std::uniform_real_distribution<double> u(-1, 1);
  Matrix4X<S> m(4, n);
  for (Eigen::Index i = 0; i < m.size(); ++i) m(i) = S(u(rng));
  return m;
}

bool close(double fd, double an, double rel = 1e-6, double floor = 1e-3) {
  return std::abs(fd - an) <= rel * std::max({std::abs(fd), std::abs(an), floor});
}

}  // namespace

TEMPLATE_TEST_CASE("apply_deformation follows Deformable 3DGS's formulas", "[deform]", float, double) {
  using S = TestType;
  std::mt19937 rng(1);
  const Eigen::Index n = 5;
  const Matrix3X<S> x = random3<S>(n, rng), ls = random3<S>(n, rng, -3, 0);
  const Matrix4X<S> q = random4<S>(n, rng);
  DeformationOffsets<S> off;
  off.dx = random3<S>(n, rng);
  off.dq = random4<S>(n, rng);
  off.ds = random3<S>(n, rng, -0.5, 0.5);
  DeformedGeometry<S> out;
  apply_deformation<S>(x, q, ls, off, out);
  const S tol = std::is_same<S, float>::value ? S(1e-6) : S(1e-15);
  for (Eigen::Index j = 0; j < n; ++j) {
    for (int a = 0; a < 3; ++a) {
      CHECK(out.means(a, j) == x(a, j) + off.dx(a, j));
      CHECK(std::abs(out.scales(a, j) - (std::exp(ls(a, j)) + off.ds(a, j))) <= tol);
    }
    const double qn = std::sqrt(double(q.col(j).squaredNorm()));
    for (int a = 0; a < 4; ++a) CHECK(std::abs(out.rotations(a, j) - S(double(q(a, j)) / qn + double(off.dq(a, j)))) <= 4 * tol);
  }
  Matrix3X<S> l;
  log_abs_scales<S>(out.scales, S(1e-6), l);
  for (Eigen::Index i = 0; i < l.size(); ++i)
    CHECK(std::abs(l(i) - std::log(std::max(std::abs(out.scales(i)), S(1e-6)))) <= tol);
}

TEST_CASE("apply_deformation_vjp matches central differences", "[deform]") {
  using S = double;
  std::mt19937 rng(2);
  const Eigen::Index n = 4;
  Matrix3X<S> x = random3<S>(n, rng), ls = random3<S>(n, rng, -2, 0.5);
  Matrix4X<S> q = random4<S>(n, rng) * 1.7;  // not normalised
  DeformationOffsets<S> off;
  off.dx = random3<S>(n, rng);
  off.dq = random4<S>(n, rng);
  off.ds = random3<S>(n, rng);
  DeformedGeometry<S> w;  // random weights of a linear loss
  w.means = random3<S>(n, rng);
  w.rotations = random4<S>(n, rng);
  w.scales = random3<S>(n, rng);
  auto loss = [&](const Matrix3X<S>& x_, const Matrix4X<S>& q_, const Matrix3X<S>& ls_,
                  const DeformationOffsets<S>& o_) {
    DeformedGeometry<S> g;
    apply_deformation<S>(x_, q_, ls_, o_, g);
    return w.means.cwiseProduct(g.means).sum() + w.rotations.cwiseProduct(g.rotations).sum() +
           w.scales.cwiseProduct(g.scales).sum();
  };
  Matrix3X<S> v_x, v_ls;
  Matrix4X<S> v_q;
  DeformationOffsets<S> v_off;
  apply_deformation_vjp<S>(q, ls, w, v_x, v_q, v_ls, v_off);
  const double h = 1e-6;
  int bad = 0;
  auto check = [&](auto& param, const auto& grad, const char* name) {
    for (Eigen::Index i = 0; i < param.size(); ++i) {
      const S keep = param(i);
      param(i) = keep + h;
      const double lp = loss(x, q, ls, off);
      param(i) = keep - h;
      const double lm = loss(x, q, ls, off);
      param(i) = keep;
      const double fd = (lp - lm) / (2 * h);
      if (!close(fd, grad(i))) {
        ++bad;
        UNSCOPED_INFO(name << "[" << i << "] fd " << fd << " analytic " << grad(i));
      }
    }
  };
  check(x, v_x, "x");
  check(q, v_q, "q");
  check(ls, v_ls, "log_s");
  check(off.dx, v_off.dx, "dx");
  check(off.dq, v_off.dq, "dq");
  check(off.ds, v_off.ds, "ds");
  CHECK(bad == 0);

  // log|s| with its floor.
  Matrix3X<S> s = random3<S>(n, rng, -2, 2), ws = random3<S>(n, rng), l, v_s;
  s(0, 0) = 1e-9;  // under the floor: zero gradient
  log_abs_scales_vjp<S>(s, 1e-6, ws, v_s);
  CHECK(v_s(0, 0) == 0.0);
  for (Eigen::Index i = 1; i < s.size(); ++i) {
    Matrix3X<S> sp = s, sm = s, lp, lm;
    sp(i) += h;
    sm(i) -= h;
    log_abs_scales<S>(sp, 1e-6, lp);
    log_abs_scales<S>(sm, 1e-6, lm);
    const double fd = (ws.cwiseProduct(lp).sum() - ws.cwiseProduct(lm).sum()) / (2 * h);
    CHECK(close(fd, v_s(i)));
  }
}

TEST_CASE("deformation field: shapes, presets, small initial offsets", "[deform]") {
  const auto orig = DeformationFieldParams::original();
  CHECK(orig.depth == 8);
  CHECK(orig.width == 256);
  CHECK(orig.skip_layer == 4);
  DeformationField<float> f(orig);
  CHECK(f.input_dims() == 63 + 13);
  // 76->256, 4 x 256->256, (256+76)->256, 2 x 256->256, heads 256->10
  CHECK(f.parameter_count() == std::size_t(76 * 256 + 256 + 4 * (256 * 256 + 256) + (332 * 256 + 256) +
                                           2 * (256 * 256 + 256) + 10 * 256 + 10));
  std::mt19937 rng(4);
  const Matrix3X<float> x = random3<float>(200, rng);
  typename DeformationField<float>::Workspace ws;
  DeformationOffsets<float> off;
  f.evaluate(x, 0.3f, ws, off);
  REQUIRE(off.size() == 200);
  // head_init_scale 0.01: offsets far below the scene's unit scale.
  CHECK(off.dx.cwiseAbs().maxCoeff() < 0.05f);
  CHECK(off.dq.cwiseAbs().maxCoeff() < 0.05f);
  CHECK(off.ds.cwiseAbs().maxCoeff() < 0.05f);
  CHECK(off.dx.cwiseAbs().maxCoeff() > 0.f);
  // Time matters; batch composition does not.
  DeformationOffsets<float> off2, one;
  f.evaluate(x, 0.8f, ws, off2);
  CHECK((off2.dx - off.dx).cwiseAbs().maxCoeff() > 0.f);
  f.evaluate(x.col(17), 0.3f, ws, one);
  CHECK((one.dx.col(0) - off.dx.col(17)).cwiseAbs().maxCoeff() <= 1e-5f);
  CHECK((one.dq.col(0) - off.dq.col(17)).cwiseAbs().maxCoeff() <= 1e-5f);
}

TEST_CASE("deformation field: save/load round trip; float and double agree", "[deform]") {
  DeformationFieldParams p;
  p.depth = 3;
  p.width = 16;
  p.skip_layer = 0;
  p.seed = 77;
  p.head_init_scale = 1.0;
  DeformationField<double> fd(p);
  DeformationField<float> ff(p);
  std::mt19937 rng(5);
  const Matrix3X<double> x = random3<double>(30, rng);
  typename DeformationField<double>::Workspace wd;
  typename DeformationField<float>::Workspace wf;
  DeformationOffsets<double> od, ol;
  DeformationOffsets<float> of;
  fd.evaluate(x, 0.25, wd, od);
  ff.evaluate(x.cast<float>(), 0.25f, wf, of);
  CHECK((of.dx.cast<double>() - od.dx).cwiseAbs().maxCoeff() < 1e-4);
  CHECK((of.ds.cast<double>() - od.ds).cwiseAbs().maxCoeff() < 1e-4);
  std::stringstream ss;
  fd.save(ss);
  auto loaded = DeformationField<double>::load(ss);
  CHECK(loaded.parameters() == fd.parameters());
  loaded.evaluate(x, 0.25, wd, ol);
  CHECK(ol.dq == od.dq);
  std::stringstream bad(ss.str().substr(0, 30));
  CHECK_THROWS_AS(DeformationField<double>::load(bad), Error);
  // A damaged size is refused before the network is built (seen while writing
  // fuzz/fuzz_checkpoint): a 1000 x 65536 network was allocated (std::bad_alloc),
  // 2^30 frequencies overflowed the input width. Layout: tag 12 bytes, then
  // depth, width, skip layer, x and t frequencies (int32).
  auto patched = [&ss](std::size_t at, std::int32_t v) {
    std::string b = ss.str();
    std::memcpy(&b[at], &v, 4);
    return std::stringstream(b);
  };
  for (auto [at, v] : {std::pair<std::size_t, std::int32_t>{12, 1000}, {16, 65536}, {24, 1 << 30}, {28, -1}}) {
    INFO("int32 at " << at << " = " << v);
    auto damaged = patched(at, v);
    if (at == 12) {  // deep and wide
      std::string b = damaged.str();
      const std::int32_t w = 65536;
      std::memcpy(&b[16], &w, 4);
      damaged = std::stringstream(b);
    }
    CHECK_THROWS_AS(DeformationField<double>::load(damaged), Error);
  }
}

TEST_CASE("deformation field: vjp matches central differences end to end", "[deform]") {
  using S = double;
  DeformationFieldParams p;
  p.depth = 3;
  p.width = 16;
  p.skip_layer = 0;
  p.seed = 3;
  p.head_init_scale = 1.0;
  DeformationField<S> field(p);
  std::mt19937 rng(8);
  const Eigen::Index n = 6;
  Matrix3X<S> x = random3<S>(n, rng, -0.5, 0.5);
  const S t = 0.37;
  DeformationOffsets<S> w;  // weights of a linear loss on the offsets
  w.dx = random3<S>(n, rng);
  w.dq = random4<S>(n, rng);
  w.ds = random3<S>(n, rng);
  typename DeformationField<S>::Workspace ws;
  DeformationOffsets<S> off;
  field.evaluate(x, t, ws, off, 1);
  // ReLU pattern of the unperturbed pass; perturbed passes must keep it (no kinks crossed).
  std::vector<Eigen::Array<bool, Eigen::Dynamic, Eigen::Dynamic>> masks;
  for (const auto& h : ws.mlp.hidden) masks.push_back(h.array() > 0.0);
  std::vector<S> g(field.parameter_count(), 0.0);
  Matrix3X<S> v_x;
  field.evaluate_vjp(ws, w, g.data(), &v_x, 1);

  int kinks = 0;
  auto loss = [&](const DeformationField<S>& f, const Matrix3X<S>& xx) {
    typename DeformationField<S>::Workspace w2;
    DeformationOffsets<S> o;
    f.evaluate(xx, t, w2, o, 1);
    for (std::size_t l = 0; l < masks.size(); ++l)
      if (((w2.mlp.hidden[l].array() > 0.0) != masks[l]).any()) ++kinks;
    return w.dx.cwiseProduct(o.dx).sum() + w.dq.cwiseProduct(o.dq).sum() + w.ds.cwiseProduct(o.ds).sum();
  };
  // Parameters enter (multi)linearly: h = 1e-6 keeps round-off low. The means pass
  // through sin(2^9 x): h = 1e-7 keeps the truncation error (~h^2 512^3) low.
  const double h = 1e-6, hx = 1e-7;
  int bad = 0;
  for (std::size_t k = 0; k < g.size(); ++k) {
    DeformationField<S> fp = field, fm = field;
    fp.parameters()[k] += h;
    fm.parameters()[k] -= h;
    const double fd = (loss(fp, x) - loss(fm, x)) / (2 * h);
    if (!close(fd, g[k], 1e-6, 1e-2)) {
      ++bad;
      UNSCOPED_INFO("param " << k << " fd " << fd << " analytic " << g[k]);
    }
  }
  for (Eigen::Index i = 0; i < x.size(); ++i) {
    Matrix3X<S> xp = x, xm = x;
    xp(i) += hx;
    xm(i) -= hx;
    const double fd = (loss(field, xp) - loss(field, xm)) / (2 * hx);
    if (!close(fd, v_x(i), 1e-6, 1e-2)) {
      ++bad;
      UNSCOPED_INFO("mean " << i << " fd " << fd << " analytic " << v_x(i));
    }
  }
  CHECK(kinks == 0);
  CHECK(bad == 0);
  // The heads matter: the means' gradient through the network is not trivially zero.
  CHECK(v_x.cwiseAbs().maxCoeff() > 1e-3);

  // Multi-threaded vjp accumulates the same gradient.
  std::vector<S> g2(field.parameter_count(), 0.0);
  field.mlp().chunk_columns = 2;
  field.evaluate(x, t, ws, off, 2);
  field.evaluate_vjp(ws, w, g2.data(), nullptr, 2);
  double maxdiff = 0;
  for (std::size_t k = 0; k < g.size(); ++k) maxdiff = std::max(maxdiff, std::abs(g[k] - g2[k]));
  CHECK(maxdiff < 1e-12);
}

TEMPLATE_TEST_CASE("deformation field: in a normalised frame it is the same network at another scale",
                   "[deform]", float, double) {
  using S = TestType;
  DeformationFieldParams p;
  p.depth = 3;
  p.width = 16;
  p.seed = 11;
  p.head_init_scale = 1.0;
  p.scale_offset = ScaleOffset::additive;  // ds is a length; the relative mode is checked below
  DeformationField<S> scaled(p), unit(p);
  const Eigen::Matrix<S, 3, 1> c(S(0.3), S(-1.2), S(2.0));
  const S L = S(0.2);
  scaled.set_frame(c, L);
  std::mt19937 rng(21);
  const Matrix3X<S> xn = random3<S>(40, rng, -1, 1);
  const Matrix3X<S> x = (xn * L).colwise() + c;  // the same points in world units
  typename DeformationField<S>::Workspace ws_s, ws_u;
  DeformationOffsets<S> os, ou;
  scaled.evaluate(x, S(0.6), ws_s, os, 1);
  unit.evaluate(xn, S(0.6), ws_u, ou, 1);
  const S tol = sizeof(S) == 4 ? S(2e-5) : S(1e-12);
  CHECK((os.dx - ou.dx * L).cwiseAbs().maxCoeff() <= tol);
  CHECK((os.ds - ou.ds * L).cwiseAbs().maxCoeff() <= tol);
  CHECK((os.dq - ou.dq).cwiseAbs().maxCoeff() <= tol);

  // Gradients follow the chain rule through the frame.
  DeformationOffsets<S> w, wl;
  w.dx = random3<S>(40, rng);
  w.dq = random4<S>(40, rng);
  w.ds = random3<S>(40, rng);
  wl.dx = w.dx * L;
  wl.dq = w.dq;
  wl.ds = w.ds * L;
  std::vector<S> gs(scaled.parameter_count(), S(0)), gu(unit.parameter_count(), S(0));
  Matrix3X<S> vs, vu;
  scaled.evaluate_vjp(ws_s, w, gs.data(), &vs, 1);
  unit.evaluate_vjp(ws_u, wl, gu.data(), &vu, 1);
  S gmax = 0, gdiff = 0;
  for (std::size_t k = 0; k < gs.size(); ++k) {
    gmax = std::max(gmax, std::abs(gu[k]));
    gdiff = std::max(gdiff, std::abs(gs[k] - gu[k]));
  }
  CHECK(gdiff <= tol * std::max(S(1), gmax) * S(10));
  CHECK((vs - vu / L).cwiseAbs().maxCoeff() <= tol * S(10) * std::max(S(1), (vu / L).cwiseAbs().maxCoeff()));

  // Relative scale offsets have no unit: the frame leaves ds alone.
  DeformationFieldParams pl = p;
  pl.scale_offset = ScaleOffset::log;
  DeformationField<S> rel(pl), rel_unit(pl);
  rel.set_frame(c, L);
  DeformationOffsets<S> rs, ru;
  rel.evaluate(x, S(0.6), ws_s, rs, 1);
  rel_unit.evaluate(xn, S(0.6), ws_u, ru, 1);
  CHECK(rs.scale_offset == ScaleOffset::log);
  CHECK((rs.ds - ru.ds).cwiseAbs().maxCoeff() <= tol);
  CHECK((rs.dx - ru.dx * L).cwiseAbs().maxCoeff() <= tol);

  // The frame is saved with the network.
  std::stringstream ss;
  scaled.save(ss);
  const auto loaded = DeformationField<S>::load(ss);
  CHECK(loaded.frame_unit() == L);
  CHECK(loaded.frame_center() == c);
  CHECK(loaded.params().scale_offset == ScaleOffset::additive);
  CHECK_THROWS_AS(scaled.set_frame(c, S(0)), Error);
}

// The full renderer (project -> bin -> rasterize, and its backward) against the
// independent double-precision reference (its own projection and SH) and against
// finite differences w.r.t. the GaussianScene parameters.
#include <catch2/catch.hpp>

#include <random>

#include "orbitforge/splat/renderer.hpp"
#include "render/reference_renderer.hpp"

using namespace orbitforge;
using namespace orbitforge_test;

namespace {

template <class S>
Camera<S> test_camera(int w, int h, S f) {
  Camera<S> cam;
  cam.intrinsics = {f, f, S(0.5) * S(w) + S(0.3), S(0.5) * S(h) - S(0.2), w, h};  // principal point off-centre
  cam.R = Eigen::AngleAxis<S>(S(0.1), Eigen::Matrix<S, 3, 1>(0.2, 1, 0.1).normalized()).toRotationMatrix();
  cam.t = Eigen::Matrix<S, 3, 1>(S(0.05), S(-0.1), S(4));
  return cam;
}

template <class S>
GaussianScene<S> random_scene(std::uint32_t seed, std::size_t n, int degree, double log_scale = -2.3) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> nd;
  std::uniform_real_distribution<double> u(-1, 1);
  GaussianScene<S> s;
  s.resize(n, degree);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + a] = S(u(rng));
    for (int a = 0; a < 4; ++a) s.rotations[4 * i + a] = S(nd(rng));
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + a] = S(log_scale + 0.6 * u(rng));
    s.opacity_logits[i] = S(1.5 * u(rng));
  }
  for (auto& v : s.sh) v = S(0.4 * u(rng));
  return s;
}

// The library's image against the independent double reference (see
// compare_with_reference): in double every pixel, in float all but a few.
template <class S, class Scene>
void check_render_against_reference(const RenderOutput<S>& out, const Scene& scene, const Camera<S>& cam,
                                    std::array<S, 3> bg) {
  const ReferenceComparison c = compare_with_reference(out, scene, cam, bg);
  INFO("fragile pixels " << c.fragile << " of " << c.pixels);
  CHECK(c.worst_color <= reference_tol<S>());
  CHECK(c.worst_T <= reference_tol<S>());
  CHECK(c.count_mismatch == 0);
  if (sizeof(S) == 4)
    CHECK(c.fragile * 25 <= c.pixels + 25);  // 4%, or one pixel
  else
    CHECK(c.fragile == 0);
}

}  // namespace

TEMPLATE_TEST_CASE("renderer matches the reference for every SH degree and odd sizes", "[render]", float, double) {
  using S = TestType;
  RenderParams<S> p;
  p.background = {{S(0.1), S(0.4), S(0.7)}};
  p.threads = 2;
  Renderer<S> r(p);
  struct Case { int w, h; };
  for (int degree = 0; degree <= 3; ++degree)
    for (const Case c : {Case{40, 30}, Case{17, 9}, Case{1, 1}, Case{1000, 3}}) {
      INFO("degree " << degree << " size " << c.w << "x" << c.h);
      const auto scene = random_scene<S>(std::uint32_t(10 + degree), 400, degree);
      const auto cam = test_camera<S>(c.w, c.h, S(c.h > 3 ? 1.2 * c.w : 40));
      const auto& out = r.render(SceneView<S>(scene), cam);
      check_render_against_reference(out, SceneView<S>(scene), cam, p.background);
      CHECK(out.frame.gaussians_visible == out.frame.projection.visible);
      CHECK(out.frame.contributions == out.stats.contributions);
      CHECK(out.frame.threads == 2);
    }
}

TEMPLATE_TEST_CASE("renderer hard cases: near plane, empty, NaN culled and counted", "[render]", float, double) {
  using S = TestType;
  RenderParams<S> p;
  p.background = {{S(1), S(0), S(0)}};
  Renderer<S> r(p);
  const auto cam = test_camera<S>(24, 20, S(30));
  SECTION("empty scene") {
    GaussianScene<S> scene;
    scene.resize(0, 0);
    const auto& out = r.render(SceneView<S>(scene), cam);
    for (int y = 0; y < 20; ++y)
      for (int x = 0; x < 24; ++x) CHECK(out.color(x, y, 0) == S(1));
    CHECK(out.frame.gaussians_visible == 0);
  }
  SECTION("behind / straddling the near plane, NaN and inf parameters") {
    auto scene = random_scene<S>(77, 50, 1);
    // Camera centre is at -R^T t; put Gaussian 0 at the centre (z = 0), 1 behind.
    const Eigen::Matrix<S, 3, 1> c = cam.center();
    for (int a = 0; a < 3; ++a) scene.means[a] = c[a];
    const Eigen::Matrix<S, 3, 1> behind = c - cam.forward();
    for (int a = 0; a < 3; ++a) scene.means[3 + a] = behind[a];
    scene.means[6] = std::numeric_limits<S>::quiet_NaN();
    scene.log_scales[9] = std::numeric_limits<S>::infinity();
    const auto& out = r.render(SceneView<S>(scene), cam);
    CHECK(out.frame.projection.culled_near >= 2);
    CHECK(out.frame.projection.culled_nonfinite >= 1);
    for (S v : out.color.data) CHECK(std::isfinite(v));
    check_render_against_reference(out, SceneView<S>(scene), cam, p.background);
  }
  SECTION("flattened Gaussians (zero scale on one axis)") {
    auto scene = random_scene<S>(78, 100, 0);
    for (std::size_t i = 0; i < scene.size(); ++i) scene.log_scales[3 * i + 2] = S(-30);
    const auto& out = r.render(SceneView<S>(scene), cam);
    check_render_against_reference(out, SceneView<S>(scene), cam, p.background);
  }
  SECTION("a Gaussian covering the whole image") {
    auto scene = random_scene<S>(79, 1, 0);
    for (int a = 0; a < 3; ++a) scene.log_scales[std::size_t(a)] = S(1.5);
    scene.opacity_logits[0] = S(8);
    const auto& out = r.render(SceneView<S>(scene), cam);
    CHECK(out.count(0, 0) == 1);
    CHECK(out.count(23, 19) == 1);
    check_render_against_reference(out, SceneView<S>(scene), cam, p.background);
  }
}

TEST_CASE("renderer: tile size, threads and tight extents do not change the image", "[render]") {
  const auto scene = random_scene<float>(5, 3000, 2);
  const auto cam = test_camera<float>(70, 50, 60.f);
  RenderParams<float> p;
  p.threads = 1;
  Renderer<float> r(p);
  const Image<float> base = r.render(SceneView<float>(scene), cam).color;
  for (int tile : {8, 16, 32})
    for (int threads : {1, 2}) {
      std::size_t entries[2] = {0, 0};
      for (bool tight : {false, true}) {
        r.params().tile_size = tile;
        r.params().threads = threads;
        r.params().tight_extents = tight;
        const auto& out = r.render(SceneView<float>(scene), cam);
        CHECK(max_abs_diff(out.color, base) == 0);
        entries[tight] = out.frame.tile_entries;
      }
      CHECK(entries[1] < entries[0]);  // tight extents skip tiles
    }
}

namespace {

// L = sum wc colour + sum wa alpha + sum wd depth.
struct Weights { Imaged wc, wa, wd; };

double scene_loss(Renderer<double>& r, const GaussianScened& s, const Camerad& cam, const Weights& w,
                  std::vector<std::int32_t>* rects = nullptr) {
  const auto& out = r.render(SceneView<double>(s), cam);
  if (rects) {
    const auto& ps = r.projected();
    rects->clear();
    for (std::size_t i = 0; i < ps.size(); ++i)
      for (auto v : {ps.radius[i], ps.rect_x0[i], ps.rect_x1[i], ps.rect_y0[i], ps.rect_y1[i]}) rects->push_back(v);
  }
  double L = 0;
  for (std::size_t i = 0; i < out.color.data.size(); ++i) L += w.wc.data[i] * out.color.data[i];
  for (std::size_t i = 0; i < out.depth.data.size(); ++i)
    L += w.wa.data[i] * (1 - out.transmittance.data[i]) + w.wd.data[i] * out.depth.data[i];
  return L;
}

}  // namespace

TEST_CASE("renderer backward matches finite differences of the scene parameters", "[render][grad]") {
  const int W = 28, H = 22;
  const auto cam = test_camera<double>(W, H, 30.0);
  for (int degree : {0, 1, 3}) {
    INFO("SH degree " << degree);
    auto scene = random_scene<double>(std::uint32_t(300 + degree), 25, degree, -1.8);
    for (auto& l : scene.opacity_logits) l = std::min(l, 1.5);  // opacity <= 0.82: off the 0.99 clamp
    // Keep every (pixel, Gaussian) pair off the thresholds.
    RenderParams<double> p;
    p.background = {{0.2, 0.3, 0.4}};
    p.threads = 2;
    Renderer<double> r(p);
    for (int iter = 0; iter < 50; ++iter) {
      r.render(SceneView<double>(scene), cam);
      const auto bad = threshold_violators(r.projected(), W, H, 1e-3);
      if (bad.empty()) break;
      for (std::size_t i : bad) scene.opacity_logits[i] -= 0.1;
    }
    r.render(SceneView<double>(scene), cam);
    REQUIRE(threshold_violators(r.projected(), W, H, 1e-3).empty());

    std::mt19937 rng(degree);
    std::uniform_real_distribution<double> u(-1, 1);
    Weights w{Imaged(W, H, 3), Imaged(W, H, 1), Imaged(W, H, 1)};
    for (auto& v : w.wc.data) v = u(rng);
    for (auto& v : w.wa.data) v = u(rng);
    for (auto& v : w.wd.data) v = 0.1 * u(rng);
    std::vector<std::int32_t> rects0, rects;
    scene_loss(r, scene, cam, w, &rects0);
    const GaussianSceneGradd g = r.backward(SceneView<double>(scene), cam, w.wc, &w.wa, &w.wd);

    struct Group { const char* name; std::vector<double>* x; const std::vector<double>* v; };
    Group groups[] = {{"means", &scene.means, &g.means},
                      {"rotations", &scene.rotations, &g.rotations},
                      {"log_scales", &scene.log_scales, &g.scales},
                      {"opacity_logits", &scene.opacity_logits, &g.opacity_logits},
                      {"sh", &scene.sh, &g.sh}};
    int skipped = 0, checked = 0;
    double worst = 0;
    for (const Group& grp : groups) {
      double scale = 0;
      for (double x : *grp.v) scale = std::max(scale, std::abs(x));
      REQUIRE(scale > 0);
      for (std::size_t j = 0; j < grp.x->size(); ++j) {
        const double x0 = (*grp.x)[j], h = 1e-5;
        (*grp.x)[j] = x0 + h;
        const double lp = scene_loss(r, scene, cam, w, &rects);
        const bool same_p = rects == rects0;
        (*grp.x)[j] = x0 - h;
        const double lm = scene_loss(r, scene, cam, w, &rects);
        const bool same_m = rects == rects0;
        (*grp.x)[j] = x0;
        if (!same_p || !same_m) { ++skipped; continue; }  // a rect edge moved: L jumps there
        const double fd = (lp - lm) / (2 * h);
        const double an = (*grp.v)[j];
        const double err = std::abs(fd - an) / std::max(std::abs(fd), 1e-2 * scale);
        INFO(grp.name << "[" << j << "]: analytic " << an << " fd " << fd);
        CHECK(err < 1e-6);
        worst = std::max(worst, err);
        ++checked;
      }
    }
    CHECK(skipped * 20 < checked);
    WARN("degree " << degree << ": worst relative error " << worst << " over " << checked << " entries, " << skipped
                   << " skipped at rect edges");
  }
}

TEST_CASE("renderer backward: freezing groups leaves them unwritten", "[render][grad]") {
  const auto scene = random_scene<float>(9, 200, 1);
  const auto cam = test_camera<float>(32, 24, 30.f);
  Renderer<float> r;
  r.render(SceneView<float>(scene), cam);
  Imagef v(32, 24, 3, 1.f);
  Freeze fr;
  fr.sh_dc = fr.sh_rest = true;
  const auto& g = r.backward(SceneView<float>(scene), cam, v, nullptr, nullptr, fr);
  double n_means = 0, n_sh = 0;
  for (float x : g.means) n_means += std::abs(x);
  for (float x : g.sh) n_sh += std::abs(x);
  CHECK(n_means > 0);
  CHECK(n_sh == 0);
  CHECK_THROWS_AS(r.backward(SceneView<float>(scene), test_camera<float>(32, 24, 31.f), v), Error);
}

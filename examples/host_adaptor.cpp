// host_adaptor: render Gaussians that live in a host program's own storage
// (an array of structs in double precision, standard deviations, opacities,
// quaternions x, y, z, w) without copying them, and have the backward pass write
// gradients straight into the host's arrays in that parametrisation. The
// contracts: splat/scene_adaptor.hpp (reading) and splat/scene_grad_view.hpp
// (writing). Besides the library it needs only CLI11 (header-only), for its
// command line.
//
//   host_adaptor OUT.png
#include <cmath>
#include <cstdio>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>

#include "orbitforge/io/image_io.hpp"
#include "orbitforge/splat/renderer.hpp"

struct HostSplat {  // the host's type
  double xyz[3], quat_xyzw[4], sigma[3], opacity, rgb[3];
};
struct HostSplatGrad {  // and its gradients, one per splat
  double xyz[3], quat_xyzw[4], sigma[3], opacity, sh_dc[3];
};

// The adaptor: a few accessors over the host's vector.
struct SplatAdaptor {
  using scalar_type = double;
  static constexpr orbitforge::ScaleMode scale_mode = orbitforge::ScaleMode::activated;  // sigma, not log sigma
  const std::vector<HostSplat>& s;
  std::size_t size() const { return s.size(); }
  int sh_degree() const { return 0; }
  void mean(std::size_t i, double out[3]) const { std::copy(s[i].xyz, s[i].xyz + 3, out); }
  void rotation(std::size_t i, double out[4]) const {
    const double* q = s[i].quat_xyzw;
    out[0] = q[3], out[1] = q[0], out[2] = q[1], out[3] = q[2];  // w first
  }
  void scale(std::size_t i, double out[3]) const { std::copy(s[i].sigma, s[i].sigma + 3, out); }
  double opacity_logit(std::size_t i) const { return std::log(s[i].opacity / (1 - s[i].opacity)); }
  double sh(std::size_t i, int, int c) const { return (s[i].rgb[c] - 0.5) / 0.28209479177387814; }  // DC term
};

int main(int argc, char** argv) {
  using namespace orbitforge;
  std::string out_png;
  CLI::App app("host_adaptor: render Gaussians kept in a host program's own storage, and write gradients back into it.",
               "host_adaptor");
  app.add_option("OUT.png", out_png, "the rendered image")->required();
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp&) {
    std::printf("%s", app.help().c_str());
    return 0;
  } catch (const CLI::ParseError& e) {
    std::fprintf(stderr, "host_adaptor: %s\n", e.what());
    return 2;
  }
  std::vector<HostSplat> splats;
  for (int k = 0; k < 12; ++k) {
    const double a = 2 * M_PI * k / 12;
    splats.push_back({{0.6 * std::cos(a), 0.6 * std::sin(a), 3.0}, {0, 0, std::sin(a / 2), std::cos(a / 2)},
                      {0.15, 0.04, 0.04}, 0.8, {0.5 + 0.5 * std::cos(a), 0.5 + 0.5 * std::sin(a), 0.6}});
  }
  Camera<double> cam;
  cam.intrinsics = {120, 120, 64, 64, 128, 128};

  Renderer<double> renderer;
  const SplatAdaptor view{splats};
  write_png(out_png, renderer.render(view, cam).color);

  // d(mean brightness)/d(parameters), written into the host's gradient structs:
  // d/d sigma, d/d opacity, quaternion x, y, z, w.
  std::vector<HostSplatGrad> grads(splats.size());
  SceneGradView<double> into;
  into.size = grads.size();
  into.means = strided(grads[0].xyz, sizeof(HostSplatGrad));
  into.rotations = strided(grads[0].quat_xyzw, sizeof(HostSplatGrad));
  into.rotation_order = QuatOrder::xyzw;
  into.scales = strided(grads[0].sigma, sizeof(HostSplatGrad));
  into.opacities = strided(&grads[0].opacity, sizeof(HostSplatGrad));
  into.sh = strided(grads[0].sh_dc, sizeof(HostSplatGrad));
  into.sh_coefficients = 1;  // the host keeps the DC term only
  Image<double> v_color(128, 128, 3, 1.0 / (128.0 * 128.0 * 3.0));
  renderer.backward(view, cam, v_color, into);
  const HostSplatGrad& g = grads[0];
  std::printf("splat 0: d brightness / d sigma = (%.4g, %.4g, %.4g), d / d opacity = %.4g\n", g.sigma[0], g.sigma[1],
              g.sigma[2], g.opacity);
  return 0;
}

// ply_tool: inspect and convert Gaussian splat files (.ply in the INRIA 3DGS layout,
// antimatter15 .splat, Niantic .spz).
//
//   ply_tool --help                    prints this usage on stdout (exit 0)
//   ply_tool info FILE                 count, SH degree and per-attribute statistics
//                                      (min / max / mean, count of non-finite values)
//                                      as one JSON object
//   ply_tool convert IN OUT            converts by extension between .ply, .splat and
//                                      .spz (.splat and .spz are lossy: see
//                                      io/splat_format.hpp and io/spz.hpp)
//   ply_tool dump FILE [FIRST [COUNT]] prints Gaussians as JSON lines with the values
//                                      as stored (PLY names, f_rest channel-major)
//   ply_tool random N DEGREE SEED OUT  writes a random scene (for format checks)
//   ply_tool visible FILE CAMERAS [FIRST LAST]
//                                      how many Gaussians projection keeps in each
//                                      camera of a camera file (orbit.json, a list),
//                                      or cameras FIRST..LAST of it, and how many no
//                                      camera keeps, as one JSON object
// Bad usage exits 2 with a message naming the command or argument; bad input 1.
#include <cctype>
#include <cmath>
#include <cstdio>
#include <iostream>
#include <limits>
#include <random>
#include <string>

#include <nlohmann/json.hpp>

#include "orbitforge/io/ply.hpp"
#include "orbitforge/io/splat_format.hpp"
#include "orbitforge/io/spz.hpp"
#include "orbitforge/pipeline/orbit_file.hpp"
#include "orbitforge/splat/project.hpp"
#include "cli.hpp"

using namespace orbitforge;

namespace {

bool ends_with(const std::string& s, const std::string& suffix) {
  return s.size() >= suffix.size() && s.compare(s.size() - suffix.size(), suffix.size(), suffix) == 0;
}

GaussianScene<float> load(const std::string& path) {
  if (ends_with(path, ".splat")) return read_splat<float>(path);
  if (ends_with(path, ".spz")) return read_spz<float>(path);
  if (ends_with(path, ".ply")) return read_ply<float>(path);
  fail(path, ": unknown extension (expected .ply, .splat or .spz)");
}

void save(const std::string& path, const GaussianScene<float>& s) {
  if (ends_with(path, ".splat")) return write_splat(path, s);
  if (ends_with(path, ".spz")) return write_spz(path, s);
  if (ends_with(path, ".ply")) return write_ply(path, s);
  fail(path, ": unknown extension (expected .ply, .splat or .spz)");
}

nlohmann::json stats(const std::vector<float>& v, std::size_t stride, std::size_t component) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0;
  std::size_t finite = 0, bad = 0;
  for (std::size_t i = component; i < v.size(); i += stride) {
    const double x = v[i];
    if (!std::isfinite(x)) {
      ++bad;
      continue;
    }
    lo = std::min(lo, x);
    hi = std::max(hi, x);
    sum += x;
    ++finite;
  }
  nlohmann::json j;
  j["min"] = finite ? lo : 0.0;
  j["max"] = finite ? hi : 0.0;
  j["mean"] = finite ? sum / double(finite) : 0.0;
  j["non_finite"] = bad;
  return j;
}

int info(const std::string& path) {
  const auto s = load(path);
  nlohmann::json j;
  j["file"] = path;
  j["count"] = s.size();
  j["sh_degree"] = s.sh_degree;
  const char* axes[] = {"x", "y", "z"};
  for (int i = 0; i < 3; ++i) j[axes[i]] = stats(s.means, 3, std::size_t(i));
  for (int i = 0; i < 3; ++i) j["scale_" + std::to_string(i)] = stats(s.log_scales, 3, std::size_t(i));
  for (int i = 0; i < 4; ++i) j["rot_" + std::to_string(i)] = stats(s.rotations, 4, std::size_t(i));
  j["opacity"] = stats(s.opacity_logits, 1, 0);
  const std::size_t K = std::size_t(s.sh_coefficients());
  for (int c = 0; c < 3; ++c) j["f_dc_" + std::to_string(c)] = stats(s.sh, 3 * K, std::size_t(c));
  std::cout << j.dump() << "\n";
  return 0;
}

int dump(const std::string& path, std::size_t first, std::size_t count) {
  const auto s = load(path);
  const std::size_t K = std::size_t(s.sh_coefficients());
  for (std::size_t g = first; g < s.size() && g < first + count; ++g) {
    nlohmann::json j;
    j["index"] = g;
    for (int i = 0; i < 3; ++i) j[std::string(1, "xyz"[i])] = s.means[3 * g + std::size_t(i)];
    for (int c = 0; c < 3; ++c) j["f_dc_" + std::to_string(c)] = s.sh[g * 3 * K + std::size_t(c)];
    for (std::size_t c = 0; c < 3; ++c)
      for (std::size_t k = 1; k < K; ++k)
        j["f_rest_" + std::to_string(c * (K - 1) + (k - 1))] = s.sh[g * 3 * K + 3 * k + c];
    j["opacity"] = s.opacity_logits[g];
    for (int i = 0; i < 3; ++i) j["scale_" + std::to_string(i)] = s.log_scales[3 * g + std::size_t(i)];
    for (int i = 0; i < 4; ++i) j["rot_" + std::to_string(i)] = s.rotations[4 * g + std::size_t(i)];
    std::cout << j.dump() << "\n";
  }
  return 0;
}

int random_scene(std::size_t n, int degree, unsigned seed, const std::string& out) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  GaussianScene<float> s;
  s.resize(n, degree);
  for (auto& v : s.means) v = 2.0f * u(rng);
  for (auto& v : s.rotations) v = u(rng);
  for (auto& v : s.log_scales) v = u(rng) - 3.0f;
  for (auto& v : s.opacity_logits) v = 3.0f * u(rng);
  for (auto& v : s.sh) v = 0.8f * u(rng);
  save(out, s);
  return 0;
}

// The work a "skip Gaussians outside every training frustum" lever could save:
// those no camera keeps after projection's culling.
int visible(const std::string& path, const std::string& cameras_path, std::size_t first, std::size_t last) {
  const auto s = load(path);
  const auto all = read_cameras_json<float>(cameras_path);
  ensure(!all.empty(), "ply_tool visible: ", cameras_path, " lists no camera");
  if (last == std::numeric_limits<std::size_t>::max()) last = all.size() - 1;  // no range given: every camera
  ensure(first <= last && last < all.size(), "ply_tool visible: cameras ", first, "..", last, " of ", all.size());
  std::vector<std::uint32_t> kept_by(s.size(), 0);
  ProjectedSplats<float> ps;
  double mean = 0, lowest = 1;
  for (std::size_t c = first; c <= last; ++c) {
    project_scene(SceneView<float>(s), all[c], ProjectionParams{}, ps, nullptr, 0);
    std::size_t kept = 0;
    for (std::size_t i = 0; i < ps.size(); ++i)
      if (ps.radius[i] > 0) ++kept_by[i], ++kept;
    const double f = s.size() ? double(kept) / double(s.size()) : 0.0;
    mean += f / double(last - first + 1);
    lowest = std::min(lowest, f);
  }
  std::size_t none = 0;
  for (auto k : kept_by) none += k == 0 ? 1 : 0;
  nlohmann::json j = {{"file", path},
                      {"gaussians", s.size()},
                      {"cameras", last - first + 1},
                      {"kept_per_camera", {{"mean", mean}, {"min", lowest}}},
                      {"kept_by_no_camera", none},
                      {"kept_by_no_camera_fraction", s.size() ? double(none) / double(s.size()) : 0.0}};
  std::cout << j.dump() << "\n";
  return 0;
}

const char* const usage_text =
    "usage: ply_tool info FILE\n"
    "       ply_tool convert IN OUT        (.ply, .splat, .spz by extension)\n"
    "       ply_tool dump FILE [FIRST [COUNT]]\n"
    "       ply_tool random N DEGREE SEED OUT\n"
    "       ply_tool visible FILE CAMERAS.json [FIRST LAST]\n"
    "       ply_tool --help\n";

// Bad usage: the message names what was wrong, then the usage (exit 2).
int usage_error(const std::string& what) {
  std::cerr << "ply_tool: " << what << "\n" << usage_text;
  return 2;
}

}  // namespace

int main(int argc, char** argv) {
  try {
    if (argc == 2 && (std::string(argv[1]) == "--help" || std::string(argv[1]) == "-h")) {
      std::cout << usage_text;
      return 0;
    }
    if (argc < 2) return usage_error("no command given");
    const std::string cmd = argv[1];
    if (!cmd.empty() && cmd[0] == '-') return usage_error("unknown option '" + cmd + "'");
    for (int i = 2; i < argc; ++i)
      if (argv[i][0] == '-' && argv[i][1] != '\0' && !std::isdigit(static_cast<unsigned char>(argv[i][1])))
        return usage_error("unknown option '" + std::string(argv[i]) + "' for '" + cmd + "'");
    if (cmd == "info" && argc == 3) return info(argv[2]);
    if (cmd == "convert" && argc == 4) {
      save(argv[3], load(argv[2]));
      return 0;
    }
    if (cmd == "dump" && argc >= 3 && argc <= 5) {
      const std::size_t first = argc >= 4 ? std::stoull(argv[3]) : 0;
      const std::size_t count = argc >= 5 ? std::stoull(argv[4]) : std::numeric_limits<std::size_t>::max() - first;
      return dump(argv[2], first, count);
    }
    if (cmd == "random" && argc == 6)
      return random_scene(std::stoull(argv[2]), std::stoi(argv[3]), unsigned(std::stoul(argv[4])), argv[5]);
    if (cmd == "visible" && (argc == 4 || argc == 6))
      return visible(argv[2], argv[3], argc == 6 ? std::stoull(argv[4]) : 0,
                     argc == 6 ? std::stoull(argv[5]) : std::numeric_limits<std::size_t>::max());
    for (const char* known : {"info", "convert", "dump", "random", "visible"})
      if (cmd == known) return usage_error("wrong number of arguments for '" + cmd + "' (" + std::to_string(argc - 2) + " given)");
    return usage_error("unknown command '" + cmd + "'");
  } catch (const std::exception& e) {
    std::cerr << "ply_tool: " << cli::describe(e) << "\n";
    return 1;
  }
}

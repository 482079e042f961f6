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
// `ply_tool COMMAND --help` describes one command.
#include <cmath>
#include <algorithm>
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

}  // namespace

int main(int argc, char** argv) {
  return cli::run([&] {
    CLI::App app(
        "ply_tool: inspect and convert Gaussian splat files (.ply in the INRIA 3DGS layout, antimatter15 .splat,\n"
        "Niantic .spz). Bad usage exits 2 with a message naming the command or argument; bad input 1.",
        "ply_tool");
    cli::setup(app);
    app.require_subcommand(1);
    std::string file, out;
    std::size_t first = 0, count = std::numeric_limits<std::size_t>::max(), n = 0;
    std::size_t last = std::numeric_limits<std::size_t>::max();
    int degree = 0;
    unsigned seed = 0;

    CLI::App* info_cmd = app.add_subcommand(
        "info", "count, SH degree and per-attribute statistics (min / max / mean, count of non-finite values) as one "
                "JSON object");
    info_cmd->add_option("FILE", file, "a .ply, .splat or .spz file")->required();

    CLI::App* convert_cmd = app.add_subcommand(
        "convert", "converts IN to OUT by extension between .ply, .splat and .spz (.splat and .spz are lossy: see "
                   "io/splat_format.hpp and io/spz.hpp)");
    convert_cmd->add_option("IN", file, "the file to read")->required();
    convert_cmd->add_option("OUT", out, "the file to write")->required();

    CLI::App* dump_cmd = app.add_subcommand(
        "dump", "prints Gaussians FIRST.. (COUNT of them) as JSON lines with the values as stored (PLY names, f_rest "
                "channel-major)");
    dump_cmd->add_option("FILE", file, "a .ply, .splat or .spz file")->required();
    dump_cmd->add_option("FIRST", first, "the first Gaussian");
    dump_cmd->add_option("COUNT", count, "how many (default: to the end)");

    CLI::App* random_cmd = app.add_subcommand("random", "writes a random scene (for format checks)");
    random_cmd->add_option("N", n, "Gaussians")->required();
    random_cmd->add_option("DEGREE", degree, "SH degree")->required()->check(CLI::Range(0, 3));
    random_cmd->add_option("SEED", seed, "random seed")->required();
    random_cmd->add_option("OUT", out, "the file to write")->required();

    CLI::App* visible_cmd = app.add_subcommand(
        "visible", "how many Gaussians projection keeps in each camera of a camera file (orbit.json, a list), or "
                   "cameras FIRST..LAST of it, and how many no camera keeps, as one JSON object");
    visible_cmd->add_option("FILE", file, "a .ply, .splat or .spz file")->required();
    std::string cameras;
    visible_cmd->add_option("CAMERAS", cameras, "a camera file")->required();
    CLI::Option* first_opt = visible_cmd->add_option("FIRST", first, "the first camera (0-based)");
    CLI::Option* last_opt = visible_cmd->add_option("LAST", last, "the last camera");
    first_opt->needs(last_opt);

    // CLI11 alone would only say that a command is required: name the word it did not know.
    const std::string word = argc > 1 ? argv[1] : "";
    if (!word.empty() && word[0] != '-' && word != "info" && word != "convert" && word != "dump" &&
        word != "random" && word != "visible")
      throw cli::UsageError("ply_tool: unknown command '" + word + "' (info, convert, dump, random or visible)");
    cli::parse(app, argc, argv);
    if (info_cmd->parsed()) return info(file);
    if (convert_cmd->parsed()) {
      save(out, load(file));
      return 0;
    }
    if (dump_cmd->parsed()) return dump(file, first, std::min(count, std::numeric_limits<std::size_t>::max() - first));
    if (random_cmd->parsed()) return random_scene(n, degree, seed, out);
    return visible(file, cameras, first, last);
  });
}

#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "orbitforge/io/ply.hpp"
#include "orbitforge/io/splat_format.hpp"
#include "io/io_test_util.hpp"
#include "support/data.hpp"

using namespace orbitforge;
namespace fs = std::filesystem;
using orbitforge_test::scratch_dir;
using orbitforge_test::slurp;

namespace {

template <class S>
GaussianScene<S> random_scene(std::size_t n, int degree, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-3.0, 3.0);
  GaussianScene<S> s;
  s.resize(n, degree);
  for (auto& v : s.means) v = S(u(rng));
  for (auto& v : s.rotations) v = S(u(rng));
  for (auto& v : s.log_scales) v = S(u(rng) - 2.0);
  for (auto& v : s.opacity_logits) v = S(u(rng));
  for (auto& v : s.sh) v = S(u(rng) * 0.5);
  return s;
}

// Standard INRIA property names for a degree.
std::vector<std::string> standard_names(int degree) {
  std::vector<std::string> n = {"x", "y", "z", "nx", "ny", "nz", "f_dc_0", "f_dc_1", "f_dc_2"};
  const int rest = 3 * (sh_coefficient_count(degree) - 1);
  for (int i = 0; i < rest; ++i) n.push_back("f_rest_" + std::to_string(i));
  n.push_back("opacity");
  for (int i = 0; i < 3; ++i) n.push_back("scale_" + std::to_string(i));
  for (int i = 0; i < 4; ++i) n.push_back("rot_" + std::to_string(i));
  return n;
}

// The value a named INRIA property has for Gaussian g, from the scene (independent of
// the library's writer: the f_rest transposition is spelled out here).
template <class S>
double property_value(const GaussianScene<S>& s, std::size_t g, const std::string& name) {
  const int K = s.sh_coefficients();
  auto idx = [&](const std::string& prefix) { return std::stoi(name.substr(prefix.size())); };
  if (name == "x") return double(s.means[3 * g]);
  if (name == "y") return double(s.means[3 * g + 1]);
  if (name == "z") return double(s.means[3 * g + 2]);
  if (name == "nx" || name == "ny" || name == "nz") return 0.0;
  if (name == "opacity") return double(s.opacity_logits[g]);
  if (name.rfind("f_dc_", 0) == 0) return double(s.sh[g * 3 * K + idx("f_dc_")]);
  if (name.rfind("f_rest_", 0) == 0) {
    const int i = idx("f_rest_");
    const int c = i / (K - 1), k = 1 + i % (K - 1);
    return double(s.sh[g * 3 * K + 3 * k + c]);
  }
  if (name.rfind("scale_", 0) == 0) return double(s.log_scales[3 * g + idx("scale_")]);
  if (name.rfind("rot_", 0) == 0) return double(s.rotations[4 * g + idx("rot_")]);
  FAIL("unknown property " << name);
  return 0;
}

// A tiny independent PLY writer for the tests: any property order, types, format.
struct TestProp {
  std::string name;
  std::string type;  // PLY type name
};

void put_binary(std::string& out, double v, const std::string& type, bool big) {
  unsigned char b[8];
  int n = 0;
  auto raw = [&](const auto& x) {
    n = int(sizeof(x));
    std::memcpy(b, &x, sizeof(x));
  };
  if (type == "float") raw(float(v));
  else if (type == "double") raw(double(v));
  else if (type == "uchar") raw(static_cast<unsigned char>(v));
  else if (type == "char") raw(static_cast<signed char>(v));
  else if (type == "short") raw(static_cast<short>(v));
  else if (type == "ushort") raw(static_cast<unsigned short>(v));
  else if (type == "int") raw(static_cast<int>(v));
  else if (type == "uint") raw(static_cast<unsigned>(v));
  else FAIL("bad type " << type);
  if (big) std::reverse(b, b + n);
  out.append(reinterpret_cast<const char*>(b), std::size_t(n));
}

template <class S>
std::string make_ply(const GaussianScene<S>& s, const std::vector<TestProp>& props, const std::string& format,
                     const std::string& extra_header_before = "") {
  std::ostringstream h;
  h << "ply\nformat " << format << " 1.0\ncomment made by the test\n" << extra_header_before;
  h << "element vertex " << s.size() << "\n";
  for (const auto& p : props) h << "property " << p.type << " " << p.name << "\n";
  h << "end_header\n";
  std::string out = h.str();
  const bool big = format == "binary_big_endian";
  for (std::size_t g = 0; g < s.size(); ++g) {
    for (std::size_t i = 0; i < props.size(); ++i) {
      const auto& p = props[i];
      const bool known = p.name != "extra_u8" && p.name != "extra_d";
      const double v = known ? property_value(s, g, p.name) : (p.name == "extra_u8" ? 200.0 : -7.25);
      if (format == "ascii") {
        std::ostringstream os;
        os.precision(17);
        os << v << (i + 1 == props.size() ? "\n" : " ");
        out += os.str();
      } else {
        put_binary(out, v, p.type, big);
      }
    }
  }
  return out;
}

template <class S>
void require_same_scene(const GaussianScene<S>& a, const GaussianScene<S>& b) {
  REQUIRE(a.sh_degree == b.sh_degree);
  REQUIRE(a.size() == b.size());
  REQUIRE(a.means == b.means);
  REQUIRE(a.rotations == b.rotations);
  REQUIRE(a.log_scales == b.log_scales);
  REQUIRE(a.opacity_logits == b.opacity_logits);
  REQUIRE(a.sh == b.sh);
}

std::string ply_error_of(const std::string& bytes) {
  try {
    read_ply_from_memory<float>(bytes, "bad.ply");
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEMPLATE_TEST_CASE("PLY round trip preserves every value (degrees 0..3)", "[io][ply]", float, double) {
  using S = TestType;
  for (int degree = 0; degree <= 3; ++degree) {
    CAPTURE(degree);
    // Values representable in float, so the double scene must also survive exactly.
    const auto scene = random_scene<float>(57, degree, 100u + unsigned(degree)).template cast<S>();
    const auto path = (scratch_dir("ply") / ("rt_" + std::to_string(degree) + ".ply")).string();
    write_ply(path, scene);
    const auto back = read_ply<S>(path);
    require_same_scene(scene, back);

    // PLY -> library -> PLY: byte-identical file.
    const auto path2 = (scratch_dir("ply") / ("rt2_" + std::to_string(degree) + ".ply")).string();
    write_ply(path2, back);
    REQUIRE(slurp(path) == slurp(path2));
  }
  for (const auto& e : fs::directory_iterator(scratch_dir("ply")))
    REQUIRE(e.path().filename().string().find(".tmp") == std::string::npos);  // temporaries renamed
}

TEST_CASE("PLY writer produces the standard INRIA layout", "[io][ply]") {
  const int degree = 2;
  const auto scene = random_scene<float>(5, degree, 7u);
  const std::string bytes = ply_bytes(scene);
  const auto names = standard_names(degree);
  std::string expected_header = "ply\nformat binary_little_endian 1.0\n";
  const std::string header_end = "end_header\n";
  const auto end = bytes.find(header_end);
  REQUIRE(end != std::string::npos);
  const std::string header = bytes.substr(0, end + header_end.size());
  REQUIRE(header.rfind(expected_header, 0) == 0);
  // Property lines in exactly the standard order.
  std::istringstream hs(header);
  std::string line;
  std::vector<std::string> props;
  while (std::getline(hs, line)) {
    if (line.rfind("element vertex ", 0) == 0) REQUIRE(line == "element vertex 5");
    if (line.rfind("property ", 0) == 0) {
      REQUIRE(line.rfind("property float ", 0) == 0);
      props.push_back(line.substr(15));
    }
  }
  REQUIRE(props == names);
  // Raw little-endian floats, row by row, f_rest channel-major.
  REQUIRE(bytes.size() == header.size() + 5 * names.size() * 4);
  const unsigned char* d = reinterpret_cast<const unsigned char*>(bytes.data() + header.size());
  for (std::size_t g = 0; g < 5; ++g)
    for (std::size_t p = 0; p < names.size(); ++p) {
      const unsigned char* q = d + (g * names.size() + p) * 4;
      const std::uint32_t u = std::uint32_t(q[0]) | std::uint32_t(q[1]) << 8 | std::uint32_t(q[2]) << 16 |
                              std::uint32_t(q[3]) << 24;
      float v;
      std::memcpy(&v, &u, 4);
      CAPTURE(g, names[p]);
      REQUIRE(double(v) == property_value(scene, g, names[p]));
    }
}

TEST_CASE("PLY writer: float64 positions keep a scene far from the origin", "[io][ply]") {
  auto scene = random_scene<float>(40, 1, 11u).cast<double>();
  // 1.3e5 units out, detail at 1e-4: float32 steps by 0.0078 there.
  for (std::size_t i = 0; i < scene.means.size(); ++i) scene.means[i] = 1.3e5 + 1e-4 * double(i % 17) + 1e-9;
  PlyWriteOptions o;
  o.double_positions = true;
  const std::string bytes = ply_bytes(scene, o);
  const std::string header = bytes.substr(0, bytes.find("end_header\n"));
  CHECK(header.find("property double x\nproperty double y\nproperty double z\nproperty float nx\n") !=
        std::string::npos);
  const auto back = read_ply_from_memory<double>(bytes, "far.ply");
  REQUIRE(back.size() == scene.size());
  for (std::size_t i = 0; i < scene.means.size(); ++i) REQUIRE(back.means[i] == scene.means[i]);
  for (std::size_t i = 0; i < scene.sh.size(); ++i) REQUIRE(back.sh[i] == double(float(scene.sh[i])));
  for (std::size_t i = 0; i < scene.rotations.size(); ++i)
    REQUIRE(back.rotations[i] == double(float(scene.rotations[i])));
  // The same scene in float32 loses its detail, which is why the option exists.
  const auto lossy = read_ply_from_memory<double>(ply_bytes(scene), "near.ply");
  double worst = 0;
  for (std::size_t i = 0; i < scene.means.size(); ++i) worst = std::max(worst, std::abs(lossy.means[i] - scene.means[i]));
  CHECK(worst > 1e-3);
}

TEMPLATE_TEST_CASE("PLY reader accepts any property order, types and byte order", "[io][ply]", float, double) {
  using S = TestType;
  std::mt19937 rng(42);
  for (int degree = 0; degree <= 3; ++degree) {
    const auto scene = random_scene<float>(9, degree, 300u + unsigned(degree));
    std::vector<TestProp> props;
    for (const auto& n : standard_names(degree)) props.push_back({n, "float"});
    props.push_back({"extra_u8", "uchar"});
    props.push_back({"extra_d", "double"});
    for (int trial = 0; trial < 4; ++trial) {
      std::shuffle(props.begin(), props.end(), rng);
      // Some properties stored as double: still exact for float-representable values.
      for (auto& p : props)
        if (p.name.rfind("extra", 0) != 0) p.type = (rng() % 3 == 0) ? "double" : "float";
      for (const std::string format : {"binary_little_endian", "binary_big_endian", "ascii"}) {
        CAPTURE(degree, trial, format);
        const auto back = read_ply_from_memory<S>(make_ply(scene, props, format), "perm.ply");
        require_same_scene(scene.template cast<S>(), back);
      }
    }
  }
}

TEST_CASE("PLY reader: integer property types", "[io][ply]") {
  auto scene = random_scene<float>(3, 0, 5u);
  for (auto& v : scene.means) v = std::round(v * 10);
  for (auto& v : scene.rotations) v = std::round(v * 10);
  std::vector<TestProp> props = {{"x", "int"},         {"y", "short"},       {"z", "char"},
                                 {"f_dc_0", "float"},  {"f_dc_1", "float"},  {"f_dc_2", "float"},
                                 {"opacity", "float"}, {"scale_0", "float"}, {"scale_1", "float"},
                                 {"scale_2", "float"}, {"rot_0", "int"},     {"rot_1", "int"},
                                 {"rot_2", "short"},   {"rot_3", "char"}};
  const auto back = read_ply_from_memory<float>(make_ply(scene, props, "binary_little_endian"), "int.ply");
  require_same_scene(scene, back);
}

TEST_CASE("PLY reader: hand-written ascii file with other elements", "[io][ply]") {
  const std::string text =
      "ply\r\n"
      "format ascii 1.0\r\n"
      "comment a hand-written file\n"
      "obj_info anything at all\n"
      "element nothing 18446744073709551615\n"  // rows without properties: no data, no loop
      "element camera 1\n"
      "property float px\n"
      "property list uchar int ids\n"
      "element vertex 2\n"
      "property float x\nproperty float y\nproperty float z\n"
      "property float nx\n"
      "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\n"
      "property float opacity\n"
      "property float scale_0\nproperty float scale_1\nproperty float scale_2\n"
      "property float rot_0\nproperty float rot_1\nproperty float rot_2\nproperty float rot_3\n"
      "element face 1\n"
      "property list uchar int vertex_indices\n"
      "end_header\n"
      "0.5 3 7 8 9\n"
      "1 2 3 0 0.25 -0.5 1e-1 2.5 -1 -2 -3 1 0 0 0\n"
      "-1.5 +0 4e2 0 1 1 1 -7 0 0 0 0.5 0.5 0.5 0.5\n"
      "3 0 1 1\n";
  const auto s = read_ply_from_memory<double>(text, "hand.ply");
  REQUIRE(s.size() == 2);
  REQUIRE(s.sh_degree == 0);
  const std::vector<double> means = {1, 2, 3, -1.5, 0, 400};
  for (std::size_t i = 0; i < 6; ++i) REQUIRE(s.means[i] == Approx(means[i]));
  REQUIRE(s.sh[0] == Approx(0.25));
  REQUIRE(s.sh[1] == Approx(-0.5));
  REQUIRE(s.sh[2] == Approx(0.1));
  REQUIRE(s.opacity_logits[0] == Approx(2.5));
  REQUIRE(s.opacity_logits[1] == Approx(-7));
  REQUIRE(s.log_scales[2] == Approx(-3));
  REQUIRE(s.rotations[0] == 1);
  REQUIRE(s.rotations[7] == Approx(0.5));
}

TEST_CASE("PLY reader skips binary elements before the vertex element", "[io][ply]") {
  const auto scene = random_scene<float>(4, 1, 11u);
  std::vector<TestProp> props;
  for (const auto& n : standard_names(1)) props.push_back({n, "float"});
  std::string ply = make_ply(scene, props, "binary_little_endian",
                             "element fixed 3\nproperty double a\nproperty uchar b\n"
                             "element listy 2\nproperty list uchar ushort ids\nproperty float w\n");
  // Insert the bytes of those elements right after the header.
  const auto at = ply.find("end_header\n") + 11;
  std::string pre;
  for (int r = 0; r < 3; ++r) {
    put_binary(pre, 1.5 * r, "double", false);
    put_binary(pre, r, "uchar", false);
  }
  for (int r = 0; r < 2; ++r) {
    put_binary(pre, 2 + r, "uchar", false);
    for (int k = 0; k < 2 + r; ++k) put_binary(pre, k, "ushort", false);
    put_binary(pre, 0.5, "float", false);
  }
  ply.insert(at, pre);
  // And an element after it, which is never read.
  ply.insert(ply.find("end_header"), "element trailing 1000000\nproperty list int int ids\n");
  require_same_scene(scene, read_ply_from_memory<float>(ply, "pre.ply"));
}

TEST_CASE("PLY reader: non-finite values are read as stored", "[io][ply]") {
  auto scene = random_scene<float>(3, 0, 3u);
  scene.means[1] = std::numeric_limits<float>::quiet_NaN();
  scene.log_scales[4] = std::numeric_limits<float>::infinity();
  scene.opacity_logits[2] = -std::numeric_limits<float>::infinity();
  const auto back = read_ply_from_memory<float>(ply_bytes(scene), "nan.ply");
  REQUIRE(std::isnan(back.means[1]));
  REQUIRE(back.log_scales[4] == std::numeric_limits<float>::infinity());
  REQUIRE(back.opacity_logits[2] == -std::numeric_limits<float>::infinity());
  REQUIRE(back.means[0] == scene.means[0]);
}

TEST_CASE("PLY reader: malformed files give errors naming the problem", "[io][ply]") {
  const auto scene = random_scene<float>(10, 1, 9u);
  const std::string good = ply_bytes(scene);
  const std::size_t header_size = good.find("end_header\n") + 11;
  auto replace = [&](const std::string& from, const std::string& to) {
    std::string s = good;
    const auto p = s.find(from);
    REQUIRE(p != std::string::npos);
    s.replace(p, from.size(), to);
    return s;
  };
  auto has = [](const std::string& msg, const std::string& part) {
    INFO("message: " << msg);
    REQUIRE(msg.find("bad.ply") != std::string::npos);
    REQUIRE(msg.find(part) != std::string::npos);
  };
  has(ply_error_of(""), "not a PLY");
  has(ply_error_of("PLY\nformat ascii 1.0\nend_header\n"), "not a PLY");
  has(ply_error_of(good.substr(0, 60)), "without 'end_header'");
  has(ply_error_of(replace("binary_little_endian", "binary_middle_endian")), "unsupported format");
  has(ply_error_of(replace("property float rot_2\n", "")), "'rot_2'");
  has(ply_error_of(replace("property float opacity\n", "")), "'opacity'");
  has(ply_error_of(replace("property float x\n", "property float q\n")), "'x'");
  has(ply_error_of(replace("property float f_dc_1\n", "")), "'f_dc_1'");
  has(ply_error_of(replace("property float f_rest_8\n", "")), "8 f_rest_* properties");
  has(ply_error_of(replace("property float f_rest_8\n", "property float f_rest_9\n")), "'f_rest_8'");
  has(ply_error_of(replace("property float y\n", "property floaty y\n")), "line 6");
  has(ply_error_of(replace("property float y\n", "property float x\n")), "declared twice");
  has(ply_error_of(replace("element vertex 10", "element vertex -3")), "bad element count");
  has(ply_error_of(replace("element vertex 10", "element vertex 11")), "truncated");
  has(ply_error_of(replace("element vertex 10", "element vertex 18446744073709551615")), "vertex count");
  has(ply_error_of(replace("element vertex 10", "element vertex 99999999999999999999")), "bad element count");
  has(ply_error_of(good.substr(0, good.size() - 1)), "truncated");
  has(ply_error_of(good.substr(0, header_size)), "byte offset");
  has(ply_error_of(replace("format binary_little_endian 1.0\n", "")), "no format");
  has(ply_error_of(replace("element vertex", "element vortex")), "no 'vertex' element");
  has(ply_error_of(replace("comment", "commentary")), "unknown keyword");

  // ascii: a bad number names the vertex.
  const std::string ascii =
      "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n"
      "property float f_dc_0\nproperty float f_dc_1\nproperty float f_dc_2\nproperty float opacity\n"
      "property float scale_0\nproperty float scale_1\nproperty float scale_2\nproperty float rot_0\n"
      "property float rot_1\nproperty float rot_2\nproperty float rot_3\nend_header\n"
      "0 0 0 0 0 0 0 0 0 0 1 0 0 0\n0 0 0 0 0 0 0 0 0 0 1 0 0 x\n";
  has(ply_error_of(ascii), "vertex 1");
  has(ply_error_of(ascii.substr(0, ascii.size() - 6)), "vertex count");
  {
    std::string s = ascii;
    s.replace(s.find("element vertex 2"), 16, "element vertex 3");
    has(ply_error_of(s), "vertex count");
  }

  // A count the file cannot hold is rejected before any allocation.
  std::string giant = replace("element vertex 10", "element vertex 4000000000000");
  has(ply_error_of(giant), "vertex count 4000000000000");

  REQUIRE_THROWS_AS(read_ply<float>((scratch_dir("ply") / "does_not_exist.ply").string()), Error);
}

TEST_CASE("PLY reader loads a file written by OpenSplat", "[io][ply][shared]") {
  const std::string rel = "ply/opensplat_spheres_10k.ply";
  if (!orbitforge_test::have_shared_data(rel)) return;
  const std::string path = orbitforge_test::shared_path(rel);
  const auto s = read_ply<float>(path);
  REQUIRE(s.size() == 10000);
  REQUIRE(s.sh_degree == 3);
  s.check_consistent();
  auto all_finite = [](const std::vector<float>& v) {
    return std::all_of(v.begin(), v.end(), [](float x) { return std::isfinite(x); });
  };
  REQUIRE(all_finite(s.means));
  REQUIRE(all_finite(s.rotations));
  REQUIRE(all_finite(s.log_scales));
  REQUIRE(all_finite(s.opacity_logits));
  REQUIRE(all_finite(s.sh));
  // Plausible values for a normalised scene after 200 steps.
  for (float v : s.means) REQUIRE(std::abs(v) < 50);
  for (float v : s.log_scales) REQUIRE((v > -20 && v < 3));
  for (float v : s.sh) REQUIRE(std::abs(v) < 20);
  for (std::size_t g = 0; g < s.size(); ++g) {
    double n2 = 0;
    for (int i = 0; i < 4; ++i) n2 += double(s.rotations[4 * g + i]) * s.rotations[4 * g + i];
    REQUIRE(n2 > 1e-8);
  }
  double mean_opacity = 0;
  for (float v : s.opacity_logits) mean_opacity += sigmoid(double(v));
  mean_opacity /= double(s.size());
  REQUIRE((mean_opacity > 0.01 && mean_opacity < 0.99));

  // Every value of the third-party file survives our writer bit-exactly: compare our
  // data rows with the original rows (same layout), normals excepted.
  const std::string original = slurp(path);
  const std::string ours = ply_bytes(s);
  const std::size_t ho = original.find("end_header\n") + 11, hw = ours.find("end_header\n") + 11;
  const std::size_t row = 62 * 4;
  REQUIRE(original.size() - ho == 10000 * row);
  REQUIRE(ours.size() - hw == 10000 * row);
  std::size_t differing = 0;
  for (std::size_t g = 0; g < 10000; ++g)
    for (std::size_t p = 0; p < 62; ++p) {
      if (p >= 3 && p < 6) continue;
      if (std::memcmp(original.data() + ho + g * row + p * 4, ours.data() + hw + g * row + p * 4, 4) != 0)
        ++differing;
    }
  REQUIRE(differing == 0);
}

// ----------------------------------------------------------------------- .splat

TEST_CASE(".splat writer: byte layout", "[io][splat]") {
  GaussianScene<float> s;
  s.resize(1, 1);
  s.means = {1.0f, -2.0f, 3.5f};
  s.log_scales = {std::log(0.5f), 0.0f, std::log(2.0f)};
  s.opacity_logits = {0.0f};  // alpha 0.5 -> 127.5 -> 128
  s.sh[0] = 0.0f;                                   // 0.5 -> 128
  s.sh[1] = rgb_to_sh_dc(1.0f);                     // 255
  s.sh[2] = rgb_to_sh_dc(-0.3f);                    // clamped to 0
  s.sh[3] = 5.0f;                                   // degree-1 coefficient: dropped
  s.rotations = {0.0f, 0.0f, 0.0f, 2.0f};           // normalised to (0,0,0,1)
  const std::string b = splat_bytes(s);
  REQUIRE(b.size() == 32);
  float f[6];
  std::memcpy(f, b.data(), 24);  // the test host is little endian
  REQUIRE(f[0] == 1.0f);
  REQUIRE(f[1] == -2.0f);
  REQUIRE(f[2] == 3.5f);
  REQUIRE(f[3] == Approx(0.5f));
  REQUIRE(f[4] == 1.0f);
  REQUIRE(f[5] == Approx(2.0f));
  const auto* u = reinterpret_cast<const unsigned char*>(b.data());
  REQUIRE(int(u[24]) == 128);
  REQUIRE(int(u[25]) == 255);
  REQUIRE(int(u[26]) == 0);
  REQUIRE(int(u[27]) == 128);
  REQUIRE(int(u[28]) == 128);  // w = 0
  REQUIRE(int(u[29]) == 128);
  REQUIRE(int(u[30]) == 128);
  REQUIRE(int(u[31]) == 255);  // z = 1 -> 256 clamped
}

TEMPLATE_TEST_CASE(".splat round trip within quantisation", "[io][splat]", float, double) {
  using S = TestType;
  const std::size_t n = 200;
  std::mt19937 rng(77);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  GaussianScene<S> s;
  s.resize(n, 3);
  for (auto& v : s.means) v = S(10 * u(rng));
  for (auto& v : s.log_scales) v = S(3 * u(rng) - 3);
  for (auto& v : s.opacity_logits) v = S(4 * u(rng));
  for (auto& v : s.rotations) v = S(u(rng));
  for (auto& v : s.sh) v = S(1.5 * u(rng));  // |0.5 + C0 dc| stays inside [0, 1]
  const auto path = (scratch_dir("ply") / "rt.splat").string();
  write_splat(path, s);
  REQUIRE(fs::file_size(path) == 32 * n);
  const auto r = read_splat<S>(path);
  REQUIRE(r.size() == n);
  REQUIRE(r.sh_degree == 0);
  const int K = s.sh_coefficients();
  for (std::size_t g = 0; g < n; ++g) {
    for (int i = 0; i < 3; ++i) {
      REQUIRE(r.means[3 * g + i] == S(float(s.means[3 * g + i])));
      REQUIRE(std::abs(double(r.log_scales[3 * g + i] - s.log_scales[3 * g + i])) < 1e-6);
      // Colour: half a byte.
      const double c_in = 0.5 + sh_c0<double>() * double(s.sh[g * 3 * K + i]);
      const double c_out = 0.5 + sh_c0<double>() * double(r.sh[3 * g + i]);
      REQUIRE(std::abs(c_in - c_out) <= 0.5 / 255 + 1e-6);
    }
    REQUIRE(std::abs(sigmoid(double(s.opacity_logits[g])) - sigmoid(double(r.opacity_logits[g]))) <=
            0.5 / 255 + 1e-6);
    double qn = 0;
    for (int i = 0; i < 4; ++i) qn += double(s.rotations[4 * g + i]) * double(s.rotations[4 * g + i]);
    qn = std::sqrt(qn);
    for (int i = 0; i < 4; ++i)
      REQUIRE(std::abs(double(s.rotations[4 * g + i]) / qn - double(r.rotations[4 * g + i])) <= 0.5 / 128 + 1e-6);
  }
  // Writing what was read keeps colour and opacity bytes; rotations move by at most one.
  const std::string b1 = slurp(path), b2 = splat_bytes(r);
  REQUIRE(b1.size() == b2.size());
  for (std::size_t g = 0; g < n; ++g) {
    for (int i = 0; i < 12; ++i) REQUIRE(b1[32 * g + i] == b2[32 * g + i]);
    for (int i = 24; i < 28; ++i) REQUIRE(b1[32 * g + i] == b2[32 * g + i]);
    for (int i = 28; i < 32; ++i)
      REQUIRE(std::abs(int(static_cast<unsigned char>(b1[32 * g + i])) -
                       int(static_cast<unsigned char>(b2[32 * g + i]))) <= 1);
  }
}

TEST_CASE(".splat reader: extremes and malformed size", "[io][splat]") {
  std::string b(64, '\0');
  auto* u = reinterpret_cast<unsigned char*>(&b[0]);
  u[27] = 255;  // alpha 255 -> finite logit that writes back as 255
  u[28] = 255;
  u[32 + 27] = 0;
  const auto s = read_splat_from_memory<float>(b, "x.splat");
  REQUIRE(std::isfinite(s.opacity_logits[0]));
  REQUIRE(std::isfinite(s.opacity_logits[1]));
  REQUIRE(s.log_scales[0] == -std::numeric_limits<float>::infinity());  // stored scale 0
  const std::string again = splat_bytes(s);
  REQUIRE(static_cast<unsigned char>(again[27]) == 255);
  REQUIRE(static_cast<unsigned char>(again[32 + 27]) == 0);

  try {
    read_splat_from_memory<float>(std::string(33, '\0'), "x.splat");
    FAIL("no error");
  } catch (const Error& e) {
    const std::string m = e.what();
    REQUIRE(m.find("x.splat") != std::string::npos);
    REQUIRE(m.find("not a multiple of 32") != std::string::npos);
  }
}

TEST_CASE("PLY reader: data beyond the declared vertices is read as declared, with a warning", "[io][ply]") {
  const auto scene = random_scene<float>(10, 1, 21);
  const std::string full = ply_bytes(scene);
  const std::size_t header = full.find("end_header\n") + std::string("end_header\n").size();
  const std::size_t row = (full.size() - header) / 10;
  // The same bytes with the header claiming 7 vertices ("10" -> " 7": same length).
  std::string short_count = full;
  const std::size_t at = short_count.find("element vertex 10\n");
  REQUIRE(at != std::string::npos);
  short_count.replace(at, 18, "element vertex  7\n");

  std::vector<std::string> warnings;
  const auto s = read_ply_from_memory<float>(short_count, "short.ply", &warnings);
  REQUIRE(s.size() == 7);
  REQUIRE(std::equal(s.means.begin(), s.means.end(), scene.means.begin()));
  REQUIRE(warnings.size() == 1);
  INFO(warnings[0]);
  CHECK(warnings[0].find("short.ply: " + std::to_string(3 * row) + " bytes beyond the 7 vertices the header declares") ==
        0);
  CHECK(warnings[0].find("(3 more vertices of " + std::to_string(row) + " bytes)") != std::string::npos);

  SECTION("without a list the warning goes to stderr") {
    std::ostringstream captured;
    auto* old = std::cerr.rdbuf(captured.rdbuf());
    read_ply_from_memory<float>(short_count, "short.ply");
    std::cerr.rdbuf(old);
    CHECK(captured.str().find("warning: short.ply: " + std::to_string(3 * row) + " bytes beyond") !=
          std::string::npos);
  }
  SECTION("an exact file warns of nothing") {
    warnings.clear();
    read_ply_from_memory<float>(full, "full.ply", &warnings);
    CHECK(warnings.empty());
  }
  SECTION("ascii: values after the last vertex") {
    const auto names = standard_names(0);
    std::vector<TestProp> props;
    for (const auto& n : names) props.push_back({n, "float"});
    const auto small = random_scene<float>(3, 0, 4);
    std::string text = make_ply(small, props, "ascii");
    warnings.clear();
    read_ply_from_memory<float>(text + "\n\n", "a.ply", &warnings);
    CHECK(warnings.empty());  // trailing blank lines are not data
    text += "1 2 3\n";
    read_ply_from_memory<float>(text, "a.ply", &warnings);
    REQUIRE(warnings.size() == 1);
    CHECK(warnings[0].find("a.ply: 5 bytes of ascii data beyond the 3 vertices") == 0);
  }
}

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <fstream>
#include <limits>
#include <random>
#include <string>
#include <vector>

#include "io/io_test_util.hpp"
#include "orbitforge/io/npy.hpp"

using namespace orbitforge;
using orbitforge_test::require_error;
using orbitforge_test::TempDir;

namespace {

// A .npy file built by hand from its parts (header dict typed as numpy writes it).
std::string npy_file(int major, const std::string& dict, const std::string& data) {
  std::string header = dict;
  const std::size_t prefix = major == 1 ? 10 : 12;
  while ((prefix + header.size() + 1) % 64 != 0) header += ' ';
  header += '\n';
  std::string out("\x93NUMPY", 6);
  out += char(major);
  out += char(0);
  const std::size_t len = header.size();
  for (int i = 0; i < (major == 1 ? 2 : 4); ++i) out += char((len >> (8 * i)) & 0xff);
  return out + header + data;
}

template <class T>
std::string raw(const std::vector<T>& v) {
  std::string s(v.size() * sizeof(T), '\0');
  std::memcpy(&s[0], v.data(), s.size());  // little-endian test machine
  return s;
}

void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary);
  out << bytes;
}

// Extrinsics N x rows x 4 ([R | t] and, for rows = 4, 0 0 0 1) and K N x 3 x 3.
template <class S>
void write_cameras(const std::string& ext, const std::string& intr, const std::vector<FrameCamera<S>>& cams,
                   int rows) {
  std::vector<double> e, k;
  for (const auto& f : cams) {
    const Eigen::Matrix4d T = f.camera.camera_T_world().template cast<double>();
    for (int r = 0; r < rows; ++r)
      for (int c = 0; c < 4; ++c) e.push_back(T(r, c));
    const Eigen::Matrix3d K = f.camera.intrinsics.K().template cast<double>();
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) k.push_back(K(r, c));
  }
  write_npy(ext, {cams.size(), std::size_t(rows), 4}, e);
  write_npy(intr, {cams.size(), 3, 3}, k);
}

}  // namespace

TEST_CASE("npy: write_npy then read_npy, and hand-made files of every version", "[io][npy]") {
  TempDir tmp("npy_rt");
  std::mt19937 rng(7);
  std::normal_distribution<double> g;
  for (const std::vector<std::size_t>& shape :
       std::vector<std::vector<std::size_t>>{{2, 3, 4}, {5}, {}, {0, 3}, {1, 1, 1, 7}}) {
    std::size_t n = 1;
    for (auto d : shape) n *= d;
    std::vector<double> data(n);
    for (auto& v : data) v = g(rng);
    const std::string path = tmp.str("a.npy");
    write_npy(path, shape, data);
    const NpyArray a = read_npy(path);
    CHECK(a.shape == shape);
    CHECK(a.data == data);
  }
  // The header written is the one numpy writes, padded to a multiple of 64 bytes.
  write_npy(tmp.str("b.npy"), {3}, {1, 2, 3});
  const std::string b = read_file_bytes(tmp.str("b.npy"));
  CHECK(b.size() == 128 + 24);
  CHECK(b.compare(10, 57, "{'descr': '<f8', 'fortran_order': False, 'shape': (3,), }") == 0);
  CHECK(b.find("'shape': (3,), }") != std::string::npos);
  CHECK(b[127] == '\n');

  // float32, versions 1, 2 and 3, quotes and spacing numpy might use.
  const std::vector<float> f = {1.5f, -2.25f, 3.0f, 1e-3f};
  for (int major : {1, 2, 3}) {
    INFO("version " << major);
    const std::string bytes =
        npy_file(major, "{\"descr\":'<f4','fortran_order':False,'shape':(2,2)}", raw(f));
    const NpyArray a = parse_npy(bytes, "f.npy");
    CHECK(a.shape == std::vector<std::size_t>{2, 2});
    REQUIRE(a.data.size() == 4);
    for (int i = 0; i < 4; ++i) CHECK(a.data[i] == double(f[i]));
  }
  // Old numpy wrote Python 2 longs: (2L, 2L).
  CHECK(parse_npy(npy_file(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (2L, 2L), }", raw(f)), "f.npy").shape ==
        std::vector<std::size_t>{2, 2});
}

TEST_CASE("npy: bad files are clear errors naming the file", "[io][npy]") {
  const std::string f8 = raw(std::vector<double>{1, 2, 3, 4});
  const std::string good_dict = "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), }";
  REQUIRE(parse_npy(npy_file(1, good_dict, f8), "x.npy").data.size() == 4);

  require_error([&] { parse_npy("PK\x03\x04 not numpy at all", "x.npy"); }, {"x.npy", "bad magic"});
  require_error([&] { parse_npy("\x93NUM", "x.npy"); }, {"x.npy", "truncated"});
  {
    std::string b = npy_file(1, good_dict, f8);
    b[6] = 4;
    require_error([&] { parse_npy(b, "x.npy"); }, {"x.npy", "unsupported .npy format version 4"});
  }
  {
    std::string b = npy_file(1, good_dict, f8);
    require_error([&] { parse_npy(b.substr(0, 40), "x.npy"); }, {"x.npy", "truncated", ".npy header"});
  }
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<i8', 'fortran_order': False, 'shape': (2, 2), }", f8), "x.npy"); },
                {"x.npy", "unsupported dtype '<i8'"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '>f8', 'fortran_order': False, 'shape': (2, 2), }", f8), "x.npy"); },
                {"x.npy", "big-endian"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': True, 'shape': (2, 2), }", f8), "x.npy"); },
                {"x.npy", "Fortran-order"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'shape': (2, 2), }", f8), "x.npy"); },
                {"x.npy", "bad .npy header", "'fortran_order'"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2), 'x': 1}", f8), "x.npy"); },
                {"x.npy", "bad .npy header", "unexpected key 'x'"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': Maybe, 'shape': (2, 2)}", f8), "x.npy"); },
                {"x.npy", "bad .npy header", "True or False"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2, -2)}", f8), "x.npy"); },
                {"x.npy", "bad .npy header", "non-negative integer"});
  require_error([&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (2, 2}", f8), "x.npy"); },
                {"x.npy", "bad .npy header", "expected ')'"});
  require_error([&] { parse_npy(npy_file(1, good_dict, f8.substr(0, 31)), "x.npy"); },
                {"x.npy", "data size mismatch", "needs 32 bytes", "has 31 bytes"});
  require_error([&] { parse_npy(npy_file(1, good_dict, f8 + "extra"), "x.npy"); },
                {"x.npy", "data size mismatch"});
  // An absurd shape is rejected before anything is allocated.
  require_error(
      [&] { parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (1000000000000, 1000000), }", f8), "x.npy"); },
      {"x.npy", "data size mismatch"});
  require_error(
      [&] {
        parse_npy(npy_file(1, "{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999, 99999999999, 99999999999), }", f8),
                  "x.npy");
      },
      {"x.npy", "too many elements"});
  TempDir tmp("npy_err");
  require_error([&] { read_npy(tmp.str("none.npy")); }, {"none.npy", "does not exist"});
  require_error([&] { write_npy(tmp.str("w.npy"), {2, 2}, {1, 2, 3}); }, {"w.npy", "holds 4 values, got 3"});
}

TEMPLATE_TEST_CASE("npy cameras: extrinsics and intrinsics round trip", "[io][npy]", float, double) {
  using S = TestType;
  const double tol = std::is_same<S, double>::value ? 1e-12 : 2e-6;
  TempDir tmp("npy_cams");
  auto cams = orbitforge_test::random_frame_cameras<S>(7, 3);
  // npy cameras share the image size passed in, and are named frame_00001...
  for (std::size_t i = 0; i < cams.size(); ++i) {
    cams[i].camera.intrinsics.width = 518;
    cams[i].camera.intrinsics.height = 294;
    char name[32];
    std::snprintf(name, sizeof(name), "frame_%05d", int(i + 1));
    cams[i].name = name;
  }
  for (int rows : {3, 4}) {
    INFO("extrinsics rows " << rows);
    write_cameras(tmp.str("extri.npy"), tmp.str("intri.npy"), cams, rows);
    const auto back = read_npy_cameras<S>(tmp.str("extri.npy"), tmp.str("intri.npy"), 518, 294);
    REQUIRE(back.size() == cams.size());
    for (std::size_t i = 0; i < cams.size(); ++i) orbitforge_test::require_same_cameras(cams[i], back[i], tol);
  }
  // A leading batch axis of 1 (as VGGT's B x S x 3 x 4 outputs) is accepted.
  {
    NpyArray e = read_npy(tmp.str("extri.npy"));  // 7 x 4 x 4 from the last loop
    NpyArray k = read_npy(tmp.str("intri.npy"));
    write_npy(tmp.str("e1.npy"), {1, 7, 4, 4}, e.data);
    write_npy(tmp.str("k1.npy"), {1, 7, 3, 3}, k.data);
    const auto back = read_npy_cameras<S>(tmp.str("e1.npy"), tmp.str("k1.npy"), 518, 294);
    REQUIRE(back.size() == 7);
    orbitforge_test::require_same_cameras(cams[6], back[6], tol);
  }
  // Non-finite rows: kept, valid = false, never NaN.
  {
    NpyArray e = read_npy(tmp.str("extri.npy"));
    NpyArray k = read_npy(tmp.str("intri.npy"));
    e.data[2 * 16 + 5] = std::numeric_limits<double>::quiet_NaN();
    k.data[4 * 9 + 0] = std::numeric_limits<double>::infinity();
    write_npy(tmp.str("e2.npy"), e.shape, e.data);
    write_npy(tmp.str("k2.npy"), k.shape, k.data);
    const auto back = read_npy_cameras<S>(tmp.str("e2.npy"), tmp.str("k2.npy"), 518, 294);
    REQUIRE(back.size() == 7);
    for (int i = 0; i < 7; ++i) {
      INFO(i);
      CHECK(back[i].valid == (i != 2 && i != 4));
      CHECK(back[i].camera.is_finite());
      CHECK(back[i].name == cams[i].name);
    }
  }
}

TEST_CASE("npy cameras: wrong shapes and contents are clear errors", "[io][npy]") {
  TempDir tmp("npy_cam_err");
  auto cams = orbitforge_test::random_frame_cameras<double>(3, 11);
  write_cameras(tmp.str("e.npy"), tmp.str("k.npy"), cams, 3);
  const std::string e = tmp.str("e.npy"), k = tmp.str("k.npy");
  REQUIRE(read_npy_cameras<double>(e, k, 64, 48).size() == 3);

  write_npy(tmp.str("e33.npy"), {3, 3, 3}, std::vector<double>(27, 0.0));
  require_error([&] { read_npy_cameras<double>(tmp.str("e33.npy"), k, 64, 48); },
                {"e33.npy", "shape 3 x 3 x 3", "expected N x 3 x 4 or N x 4 x 4"});
  write_npy(tmp.str("k34.npy"), {3, 3, 4}, std::vector<double>(36, 0.0));
  require_error([&] { read_npy_cameras<double>(e, tmp.str("k34.npy"), 64, 48); },
                {"k34.npy", "shape 3 x 3 x 4", "expected N x 3 x 3"});
  write_cameras(tmp.str("e2.npy"), tmp.str("k2.npy"), std::vector<FrameCamera<double>>(cams.begin(), cams.begin() + 2), 3);
  require_error([&] { read_npy_cameras<double>(e, tmp.str("k2.npy"), 64, 48); },
                {"e.npy has 3 frames", "k2.npy has 2"});
  require_error([&] { read_npy_cameras<double>(e, k, 0, 48); }, {"e.npy", "image size 0x48"});
  {
    NpyArray a = read_npy(e);
    a.data[0] *= 2;  // frame 0's R no longer a rotation
    write_npy(tmp.str("ebad.npy"), a.shape, a.data);
    require_error([&] { read_npy_cameras<double>(tmp.str("ebad.npy"), k, 64, 48); },
                  {"ebad.npy", "frame 0", "not a rotation"});
  }
  {
    NpyArray a = read_npy(k);
    a.data[9 + 8] = 2;  // frame 1's K(2,2)
    write_npy(tmp.str("kbad.npy"), a.shape, a.data);
    require_error([&] { read_npy_cameras<double>(e, tmp.str("kbad.npy"), 64, 48); },
                  {"kbad.npy", "frame 1", "last row of K"});
  }
  write_npy(tmp.str("e0.npy"), {0, 3, 4}, {});
  write_npy(tmp.str("k0.npy"), {0, 3, 3}, {});
  require_error([&] { read_npy_cameras<double>(tmp.str("e0.npy"), tmp.str("k0.npy"), 64, 48); },
                {"e0.npy", "no frames"});
  write_bytes(tmp.str("junk.npy"), "junk");
  require_error([&] { read_npy_cameras<double>(tmp.str("junk.npy"), k, 64, 48); }, {"junk.npy"});
}

#include <catch2/catch.hpp>

#include <cmath>
#include <cstdint>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/io/spz.hpp"
#include "io/io_test_util.hpp"

using namespace orbitforge;
using orbitforge_test::require_error;

namespace spz_test {

// Values inside the format's ranges (log scales -10..5.9, DC colours +-3.3, SH +-1), so
// every difference is quantisation alone.
template <class S>
GaussianScene<S> random_scene(std::size_t n, int degree, unsigned seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> u(-1.0, 1.0);
  GaussianScene<S> s;
  s.resize(n, degree);
  for (auto& v : s.means) v = S(5.0 * u(rng));
  for (auto& v : s.rotations) v = S(u(rng));
  for (auto& v : s.log_scales) v = S(4.0 * u(rng) - 3.0);
  for (auto& v : s.opacity_logits) v = S(4.0 * u(rng));
  for (auto& v : s.sh) v = S(0.9 * u(rng));
  return s;
}

template <class S>
std::vector<double> unit_quaternion(const GaussianScene<S>& s, std::size_t g) {
  std::vector<double> q(4);
  double n = 0;
  for (int i = 0; i < 4; ++i) n += double(s.rotations[4 * g + i]) * double(s.rotations[4 * g + i]);
  for (int i = 0; i < 4; ++i) q[i] = double(s.rotations[4 * g + i]) / std::sqrt(n);
  return q;
}

// Largest difference per attribute, each scaled by its quantisation bound (so <= 1 passes).
struct Worst {
  double mean = 0, scale = 0, alpha = 0, dc = 0, rot = 0, sh1 = 0, sh_rest = 0;
};

template <class S>
Worst compare(const GaussianScene<S>& a, const GaussianScene<S>& b, int fractional_bits,
              const SpzOptions& options = {}) {
  REQUIRE(a.size() == b.size());
  REQUIRE(a.sh_degree == b.sh_degree);
  // Half a step of each quantiser, plus the rounding of the scalar type.
  const double slack = std::is_same<S, float>::value ? 1e-5 : 1e-12;
  const double mean_bound = 0.5 / double(1 << fractional_bits);
  const double scale_bound = 0.5 / 16.0 + slack;
  const double alpha_bound = 0.5 / 255.0 + slack;
  const double dc_bound = 0.5 / (spz_color_scale * 255.0) + slack;
  // Stored components: half of sqrt(1/2)/511; the rebuilt largest one (>= 1/2) moves
  // by at most sum |q_i| d / q_max <= (3/2) d / (1/2) = 3 d.
  const double rot_bound = 3.0 * 0.5 * std::sqrt(0.5) / 511.0 + slack;
  const double sh1_bound = 0.5 * double(1 << (8 - options.sh1_bits)) / 128.0 + slack;
  const double sh_rest_bound = 0.5 * double(1 << (8 - options.sh_rest_bits)) / 128.0 + slack;
  Worst w;
  const int K = a.sh_coefficients();
  for (std::size_t g = 0; g < a.size(); ++g) {
    for (int i = 0; i < 3; ++i) {
      const double m = double(a.means[3 * g + i]);
      w.mean = std::max(w.mean, std::abs(m - double(b.means[3 * g + i])) / (mean_bound + slack * std::abs(m)));
      w.scale = std::max(w.scale, std::abs(double(a.log_scales[3 * g + i]) - double(b.log_scales[3 * g + i])) / scale_bound);
    }
    w.alpha = std::max(w.alpha, std::abs(sigmoid(double(a.opacity_logits[g])) - sigmoid(double(b.opacity_logits[g]))) /
                                    alpha_bound);
    const auto qa = unit_quaternion(a, g), qb = unit_quaternion(b, g);
    double dot = 0;
    for (int i = 0; i < 4; ++i) dot += qa[i] * qb[i];
    const double sign = dot < 0 ? -1.0 : 1.0;  // q and -q are one rotation
    for (int i = 0; i < 4; ++i) w.rot = std::max(w.rot, std::abs(qa[i] - sign * qb[i]) / rot_bound);
    for (int k = 0; k < K; ++k)
      for (int c = 0; c < 3; ++c) {
        const std::size_t j = (g * std::size_t(K) + std::size_t(k)) * 3 + std::size_t(c);
        const double d = std::abs(double(a.sh[j]) - double(b.sh[j]));
        if (k == 0) w.dc = std::max(w.dc, d / dc_bound);
        else if (k < 4) w.sh1 = std::max(w.sh1, d / sh1_bound);
        else w.sh_rest = std::max(w.sh_rest, d / sh_rest_bound);
      }
  }
  return w;
}

inline void put_u32(std::string& s, std::uint32_t v) {
  for (int i = 0; i < 4; ++i) s.push_back(char((v >> (8 * i)) & 0xff));
}

inline std::string header(std::uint32_t magic, std::uint32_t version, std::uint32_t n, int degree, int bits,
                          int flags = 0) {
  std::string h;
  put_u32(h, magic);
  put_u32(h, version);
  put_u32(h, n);
  h.push_back(char(degree));
  h.push_back(char(bits));
  h.push_back(char(flags));
  h.push_back(0);
  return h;
}

inline void put_i24(std::string& s, std::int32_t v) {
  for (int i = 0; i < 3; ++i) s.push_back(char((std::uint32_t(v) >> (8 * i)) & 0xff));
}

}  // namespace spz_test

TEMPLATE_TEST_CASE("spz: a random scene round-trips within the format's quantisation", "[spz]", float, double) {
  using S = TestType;
  for (int degree = 0; degree <= 3; ++degree) {
    INFO("SH degree " << degree);
    const auto scene = spz_test::random_scene<S>(300, degree, 40u + unsigned(degree));
    const std::string bytes = spz_bytes(scene);
    const auto back = read_spz_from_memory<S>(bytes, "mem.spz");
    const auto w = spz_test::compare(scene, back, spz_default_fractional_bits);
    CHECK(w.mean <= 1.0);
    CHECK(w.scale <= 1.0);
    CHECK(w.alpha <= 1.0);
    CHECK(w.dc <= 1.0);
    CHECK(w.rot <= 1.0);
    CHECK(w.sh1 <= 1.0);
    CHECK(w.sh_rest <= 1.0);
    // The bounds are near what quantisation does: a round trip that changed nothing
    // (or a bound far too loose) would show here.
    CHECK(w.mean > 0.5);
    CHECK(w.scale > 0.5);
    CHECK(w.dc > 0.5);
    if (degree >= 1) CHECK(w.sh1 > 0.5);
    if (degree >= 2) CHECK(w.sh_rest > 0.5);
    // Writing what was read gives the same stream (every value sits on its grid), but
    // for rotations, whose largest component may change places in a near tie.
    const std::string p0 = spz_payload(scene), p1 = spz_payload(back);
    const std::size_t rot_at = 16 + 16 * scene.size(), rot_end = rot_at + 4 * scene.size();
    CHECK(p1.substr(0, rot_at) == p0.substr(0, rot_at));
    CHECK(p1.substr(rot_end) == p0.substr(rot_end));
    // The SPZ is much smaller than the float PLY (62 floats a Gaussian at degree 3).
    if (degree == 3) CHECK(bytes.size() * 4 < 300 * 62 * 4);
  }
}

TEST_CASE("spz: more SH bits keep the SH closer and cost size", "[spz]") {
  const auto scene = spz_test::random_scene<double>(400, 3, 12u);
  for (const SpzOptions o : {SpzOptions{8, 8}, SpzOptions{6, 5}, SpzOptions{3, 2}}) {
    INFO("SH bits " << o.sh1_bits << ", " << o.sh_rest_bits);
    const auto back = read_spz_from_memory<double>(spz_bytes(scene, o), "bits.spz");
    const auto w = spz_test::compare(scene, back, spz_default_fractional_bits, o);
    CHECK(w.sh1 <= 1.0);
    CHECK(w.sh_rest <= 1.0);
    CHECK(w.sh1 > 0.5);
    CHECK(w.sh_rest > 0.5);
  }
  CHECK(spz_bytes(scene, SpzOptions{8, 8}).size() > spz_bytes(scene).size());
  require_error([&] { spz_payload(scene, SpzOptions{0, 4}); }, {"SH bits must be 1..8"});
}

TEST_CASE("spz: files round-trip through write_spz and read_spz", "[spz]") {
  const auto dir = orbitforge_test::scratch_dir("spz_file");
  const auto scene = spz_test::random_scene<float>(50, 2, 7u);
  const std::string path = (dir / "scene.spz").string();
  write_spz(path, scene);
  const auto back = read_spz<float>(path);
  const auto w = spz_test::compare(scene, back, spz_default_fractional_bits);
  CHECK(w.mean <= 1.0);
  CHECK(w.rot <= 1.0);
  CHECK(w.sh_rest <= 1.0);
}

TEST_CASE("spz: the stream follows the published layout in the format's RUB axes", "[spz]") {
  GaussianScened s;
  s.resize(1, 1);
  s.means = {1.0, 2.0, -3.0};
  s.log_scales = {0.0, -10.0, 1.5};
  s.opacity_logits = {0.0};
  s.sh = {1.0, 0.0, -1.0, /* k=1 (y) */ 0.5, 0.5, 0.5, /* k=2 (z) */ 0.25, 0, 0, /* k=3 (x) */ 0.25, 0, 0};
  // 90 degrees about z: (w, x, y, z) = (c, 0, 0, c); in RUB (w, x, -y, -z).
  s.rotations = {std::sqrt(0.5), 0.0, 0.0, std::sqrt(0.5)};
  const std::string p = spz_payload(s);
  REQUIRE(p.size() == 16 + 9 + 1 + 3 + 3 + 4 + 9);
  const auto* b = reinterpret_cast<const unsigned char*>(p.data());
  CHECK(b[0] == 0x4e);  // "NGSP" little endian
  CHECK(b[1] == 0x47);
  CHECK(b[2] == 0x53);
  CHECK(b[3] == 0x50);
  CHECK(b[4] == 3);
  CHECK(b[8] == 1);
  CHECK(b[12] == 1);
  CHECK(b[13] == 12);
  auto i24 = [&](int off) {
    std::uint32_t u = b[off] | b[off + 1] << 8 | b[off + 2] << 16;
    return std::int32_t(u & 0x800000u ? u | 0xff000000u : u);
  };
  CHECK(i24(16) == 4096);    // x
  CHECK(i24(19) == -8192);   // -y
  CHECK(i24(22) == 12288);   // -z
  CHECK(b[25] == 128);       // sigmoid(0) * 255 = 127.5 rounds up
  CHECK(b[26] == 166);       // 1 * 0.15 * 255 + 127.5 = 165.75
  CHECK(b[27] == 128);
  CHECK(b[28] == 89);        // 89.25
  CHECK(b[29] == 160);       // (0 + 10) * 16
  CHECK(b[30] == 0);
  CHECK(b[31] == 184);       // 11.5 * 16
  // Smallest three of (x, y, z, w) = (0, 0, -c, c): |z| and |w| tie, the first (z,
  // index 2) is largest, negative, so the quaternion is negated: w stored as -c
  // (sign 1, magnitude 511), x and y as 0.
  const std::uint32_t rot = b[32] | b[33] << 8 | b[34] << 16 | std::uint32_t(b[35]) << 24;
  CHECK(rot >> 30 == 2);
  CHECK(((rot >> 20) & 0x1ff) == 0);            // x (its sign bit is free)
  CHECK(((rot >> 10) & 0x1ff) == 0);            // y
  CHECK((rot & 0x3ff) == ((1u << 9) | 511u));   // w
  // SH degree 1 in RUB: y and z coefficients flip sign, x does not; 5-bit buckets of 8.
  CHECK(b[36] == 64);   // -0.5 * 128 + 128
  CHECK(b[37] == 64);
  CHECK(b[38] == 64);
  CHECK(b[39] == 96);   // -0.25
  CHECK(b[42] == 160);  // +0.25
}

TEST_CASE("spz: a version-2 stream written from the specification reads back", "[spz]") {
  using spz_test::put_i24;
  // Two Gaussians, degree 1, 10 fractional bits.
  std::string p = spz_test::header(spz_magic, 2, 2, 1, 10);
  // positions (file axes RUB): (1, 2, 3) and (-0.5, 0, 1024 steps = 1.0)
  put_i24(p, 1024);
  put_i24(p, 2048);
  put_i24(p, 3072);
  put_i24(p, -512);
  put_i24(p, 0);
  put_i24(p, 1024);
  p += std::string({char(255), char(0)});                                   // alphas
  p += std::string({char(128), char(166), char(89), char(0), char(255), char(128)});  // colours
  p += std::string({char(160), char(176), char(144), char(0), char(255), char(160)});  // scales
  // rotations, x y z bytes with w >= 0 rebuilt: identity, and x = 1 (byte 255)
  p += std::string({char(128), char(128), char(128), char(255), char(128), char(128)});
  // SH degree 1 (3 coefficients x RGB each)
  for (int g = 0; g < 2; ++g)
    p += std::string({char(192), char(128), char(64), char(128), char(128), char(128), char(0), char(128), char(128)});
  const auto s = read_spz_from_memory<double>(spz_detail::gzip_compress(p), "v2.spz");
  REQUIRE(s.size() == 2);
  REQUIRE(s.sh_degree == 1);
  // Means back in orbitforge's axes: y and z negated.
  CHECK(s.means[0] == Approx(1.0));
  CHECK(s.means[1] == Approx(-2.0));
  CHECK(s.means[2] == Approx(-3.0));
  CHECK(s.means[3] == Approx(-0.5));
  CHECK(s.means[4] == Approx(0.0));
  CHECK(s.means[5] == Approx(-1.0));
  CHECK(sigmoid(s.opacity_logits[0]) == Approx(1.0).margin(1e-3));
  CHECK(sigmoid(s.opacity_logits[1]) == Approx(0.0).margin(1e-3));
  CHECK(std::isfinite(s.opacity_logits[0]));
  CHECK(std::isfinite(s.opacity_logits[1]));
  CHECK(s.sh[0] == Approx((128 / 255.0 - 0.5) / 0.15));
  CHECK(s.sh[1] == Approx((166 / 255.0 - 0.5) / 0.15));
  CHECK(s.log_scales[0] == Approx(0.0).margin(1e-12));
  CHECK(s.log_scales[1] == Approx(1.0));
  CHECK(s.log_scales[2] == Approx(-1.0));
  CHECK(s.log_scales[3] == Approx(-10.0));
  CHECK(s.log_scales[4] == Approx(255 / 16.0 - 10.0));
  CHECK(s.rotations[0] == Approx(1.0).margin(1e-4));
  CHECK(s.rotations[1] == Approx(0.0039).margin(1e-3));  // (128 / 127.5 - 1)
  // x = 1: a 180-degree turn about x, the same in both axis conventions.
  CHECK(s.rotations[4] == Approx(0.0).margin(1e-12));
  CHECK(s.rotations[5] == Approx(1.0));
  // SH degree 1, coefficient k=1 (y) flips sign; k=3 (x) does not.
  const int K = 4;
  CHECK(s.sh[1 * 3 + 0] == Approx(-0.5));  // byte 192 = +0.5 in RUB
  CHECK(s.sh[1 * 3 + 2] == Approx(0.5));   // byte 64 = -0.5
  CHECK(s.sh[3 * 3 + 0] == Approx(-1.0));  // byte 0, x: unchanged
  CHECK(s.sh[(1 * K + 1) * 3 + 0] == Approx(-0.5));
}

TEST_CASE("spz: version 3 smallest-three rotations decode to unit quaternions", "[spz]") {
  // Every largest-component index and sign pattern, through the real writer and reader.
  GaussianScened s;
  s.resize(8, 0);
  const double q[8][4] = {{0.9, 0.1, -0.2, 0.3},  {0.1, -0.9, 0.2, 0.3},  {0.1, 0.2, 0.9, -0.3},
                          {-0.1, 0.2, 0.3, -0.9}, {-0.5, 0.5, -0.5, 0.5}, {0.0, 0.0, 0.0, 1.0},
                          {0.0, 0.0, 0.0, 0.0},   {1.0, 0.0, 0.0, 0.0}};
  for (int g = 0; g < 8; ++g)
    for (int i = 0; i < 4; ++i) s.rotations[4 * g + i] = q[g][i];
  const auto back = read_spz_from_memory<double>(spz_bytes(s), "rot.spz");
  for (int g = 0; g < 8; ++g) {
    INFO("Gaussian " << g);
    double n = 0, dot = 0, nq = 0;
    for (int i = 0; i < 4; ++i) {
      n += back.rotations[4 * g + i] * back.rotations[4 * g + i];
      nq += q[g][i] * q[g][i];
    }
    CHECK(n == Approx(1.0).margin(1e-6));
    if (g == 6) {  // a zero quaternion is written as the identity
      CHECK(std::abs(back.rotations[4 * g]) == Approx(1.0));
      continue;
    }
    for (int i = 0; i < 4; ++i) dot += back.rotations[4 * g + i] * q[g][i] / std::sqrt(nq);
    CHECK(std::abs(dot) > 1.0 - 1e-5);
  }
}

TEST_CASE("spz: degree 4 streams read to degree 3; large scenes lower the fractional bits", "[spz]") {
  const auto scene = spz_test::random_scene<double>(3, 3, 5u);
  std::string p = spz_payload(scene);
  // Rebuild as degree 4: 9 more coefficients (27 bytes) per Gaussian after each degree-3 block.
  const std::size_t sh_start = p.size() - 3 * 45;
  std::string p4 = p.substr(0, sh_start);
  p4[12] = 4;
  for (int g = 0; g < 3; ++g) p4 += p.substr(sh_start + std::size_t(45 * g), 45) + std::string(27, char(200));
  const auto back = read_spz_from_memory<double>(spz_detail::gzip_compress(p4), "deg4.spz");
  REQUIRE(back.sh_degree == 3);
  CHECK(spz_test::compare(scene, back, 12).sh_rest <= 1.0);

  GaussianScened far = spz_test::random_scene<double>(4, 0, 6u);
  far.means[0] = 5000.0;  // beyond 2048 = 2^23 / 2^12
  const std::string pf = spz_payload(far);
  CHECK(int(static_cast<unsigned char>(pf[13])) == 10);
  CHECK(spz_test::compare(far, read_spz_from_memory<double>(spz_bytes(far), "far.spz"), 10).mean <= 1.0);
  far.means[1] = std::nan("");
  require_error([&] { spz_payload(far); }, {"Gaussian 0", "non-finite mean"});
}

TEST_CASE("spz: bad input is refused with a message naming the problem", "[spz]") {
  const auto scene = spz_test::random_scene<float>(40, 1, 9u);
  const std::string payload = spz_payload(scene);
  const std::string good = spz_bytes(scene);
  REQUIRE_NOTHROW(read_spz_from_memory<float>(good, "good.spz"));

  // Truncated: the compressed file cut short, and a whole stream with too little data.
  require_error([&] { read_spz_from_memory<float>(good.substr(0, good.size() / 2), "cut.spz"); },
                {"cut.spz", "truncated", "gzip stream is cut short"});
  require_error([&] { read_spz_from_memory<float>(good.substr(0, 12), "tiny.spz"); }, {"tiny.spz", "truncated"});
  require_error(
      [&] { read_spz_from_memory<float>(spz_detail::gzip_compress(payload.substr(0, payload.size() - 1)), "short.spz"); },
      {"short.spz", "truncated", "40 Gaussians", std::to_string(payload.size())});
  require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(payload.substr(0, 10)), "hdr.spz"); },
                {"hdr.spz", "truncated", "16-byte header"});

  // Wrong magic inside a valid gzip stream.
  std::string bad = payload;
  bad[0] = 'X';
  require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(bad), "magic.spz"); },
                {"magic.spz", "wrong magic", "NGSP"});

  // Unsupported versions: 1 (half floats, never released), 5.
  for (std::uint32_t v : {1u, 5u}) {
    bad = payload;
    bad[4] = char(v);
    require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(bad), "version.spz"); },
                  {"version.spz", "unsupported SPZ version " + std::to_string(v)});
  }
  // Version 4 is zstd, with its header uncompressed at the start of the file.
  std::string v4 = spz_test::header(spz_magic, 4, 40, 1, 12);
  v4 += std::string(100, '\0');
  require_error([&] { read_spz_from_memory<float>(v4, "v4.spz"); }, {"v4.spz", "version 4", "not gzip", "zstd"});
  // An uncompressed version-3 stream is not an SPZ file.
  require_error([&] { read_spz_from_memory<float>(payload, "raw.spz"); }, {"raw.spz", "uncompressed"});

  // Garbage after the gzip magic; and a file that is not gzip at all.
  std::string garbage = good.substr(0, 2) + std::string(200, char(0xee));
  require_error([&] { read_spz_from_memory<float>(garbage, "garbage.spz"); }, {"garbage.spz", "not a valid gzip stream"});
  garbage = good;
  for (std::size_t i = 20; i < garbage.size(); i += 7) garbage[i] = char(garbage[i] ^ 0x5a);
  require_error([&] { read_spz_from_memory<float>(garbage, "flipped.spz"); }, {"flipped.spz"});
  require_error([&] { read_spz_from_memory<float>("ply\nformat ascii 1.0\n", "scene.ply"); },
                {"scene.ply", "not an SPZ file", "1f 8b"});
  require_error([&] { read_spz_from_memory<float>("", "empty.spz"); }, {"empty.spz", "not an SPZ file"});

  // Extensions and out-of-range header fields.
  bad = payload;
  bad[14] = 0x2;
  require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(bad), "ext.spz"); },
                {"ext.spz", "extensions"});
  bad = payload;
  bad[12] = 5;
  require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(bad), "deg.spz"); },
                {"deg.spz", "SH degree 5"});
  // A count far beyond the data stops at the data's end.
  bad = payload;
  bad[11] = char(0x7f);
  require_error([&] { read_spz_from_memory<float>(spz_detail::gzip_compress(bad), "count.spz"); },
                {"count.spz", "truncated"});
  require_error([&] { read_spz<float>("/nonexistent/scene.spz"); }, {"/nonexistent/scene.spz"});
}

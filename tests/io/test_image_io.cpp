#include <catch2/catch.hpp>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include <unistd.h>

#include "orbitforge/io/image_io.hpp"
#include "io/io_test_util.hpp"
#include "support/data.hpp"

using namespace orbitforge;
namespace fs = std::filesystem;
using orbitforge_test::error_of;
using orbitforge_test::scratch_dir;
using orbitforge_test::slurp;
using orbitforge_test::spit;

namespace {

float le_float(const std::string& bytes, std::size_t offset) {
  const auto* q = reinterpret_cast<const unsigned char*>(bytes.data() + offset);
  const std::uint32_t u =
      std::uint32_t(q[0]) | std::uint32_t(q[1]) << 8 | std::uint32_t(q[2]) << 16 | std::uint32_t(q[3]) << 24;
  float v;
  std::memcpy(&v, &u, 4);
  return v;
}

}  // namespace

TEMPLATE_TEST_CASE("PNG round trip of 8-bit values", "[io][image]", float, double) {
  using T = TestType;
  std::mt19937 rng(1);
  Image<T> img(13, 7, 3);
  for (auto& v : img.data) v = T(rng() % 256) / T(255);
  const auto path = (scratch_dir("image_io") / "rt.png").string();
  write_png(path, img);
  const auto back = read_image<T>(path);
  REQUIRE(back.same_shape(img));
  REQUIRE(back.data == img.data);

  // Clamping and rounding on write.
  Image<T> odd(3, 1, 3);
  odd.data = {T(-0.5), T(2), std::numeric_limits<T>::quiet_NaN(), T(0.5), T(1.0 / 255 * 0.49), T(1.0 / 255 * 0.51),
              T(1), T(0), T(0.999)};
  write_image((scratch_dir("image_io") / "odd.png").string(), odd);
  const auto o = read_image<T>((scratch_dir("image_io") / "odd.png").string());
  const int expected[9] = {0, 255, 0, 128, 0, 1, 255, 0, 255};
  for (int i = 0; i < 9; ++i) REQUIRE(o.data[std::size_t(i)] == T(expected[i]) / T(255));
}

namespace {

// CRC-32 of the PNG specification (polynomial 0xEDB88320, reflected), bit by
// bit: independent of the zlib the encoder uses.
std::uint32_t crc32_bitwise(const unsigned char* p, std::size_t n) {
  std::uint32_t c = 0xFFFFFFFFu;
  for (std::size_t i = 0; i < n; ++i) {
    c ^= p[i];
    for (int k = 0; k < 8; ++k) c = (c >> 1) ^ (0xEDB88320u & (0u - (c & 1u)));
  }
  return c ^ 0xFFFFFFFFu;
}

std::uint32_t be32(const std::string& s, std::size_t at) {
  const auto* q = reinterpret_cast<const unsigned char*>(s.data() + at);
  return std::uint32_t(q[0]) << 24 | std::uint32_t(q[1]) << 16 | std::uint32_t(q[2]) << 8 | std::uint32_t(q[3]);
}

}  // namespace

TEST_CASE("png_encode: chunks, CRCs and every sample back through a decoder", "[io][image][png]") {
  std::mt19937 rng(7);
  const int sizes[][2] = {{1, 1}, {1, 5}, {6, 1}, {37, 23}, {64, 64}};
  for (int channels = 1; channels <= 4; ++channels)
    for (const auto& wh : sizes)
      for (int content = 0; content < 3; ++content) {
        const int w = wh[0], h = wh[1];
        std::vector<unsigned char> px(std::size_t(w) * std::size_t(h) * std::size_t(channels));
        for (std::size_t i = 0; i < px.size(); ++i)
          px[i] = content == 0 ? static_cast<unsigned char>(rng() & 255u)                   // noise
                               : content == 1 ? static_cast<unsigned char>((i * 7 / 3) & 255u)  // ramps
                                              : static_cast<unsigned char>(200);               // flat
        INFO(w << "x" << h << "x" << channels << ", content " << content);
        const std::string png = png_encode(px.data(), w, h, channels);
        // Signature, then chunks IHDR, IDAT, IEND, each with its CRC.
        REQUIRE(png.compare(0, 8, std::string("\x89PNG\r\n\x1a\n", 8)) == 0);
        std::size_t at = 8;
        std::vector<std::string> types;
        while (at + 12 <= png.size()) {
          const std::uint32_t len = be32(png, at);
          REQUIRE(at + 12 + len <= png.size());
          types.push_back(png.substr(at + 4, 4));
          const auto* body = reinterpret_cast<const unsigned char*>(png.data() + at + 4);
          CHECK(be32(png, at + 8 + len) == crc32_bitwise(body, len + 4));
          if (types.back() == "IHDR") {
            REQUIRE(len == 13);
            CHECK(be32(png, at + 8) == std::uint32_t(w));
            CHECK(be32(png, at + 12) == std::uint32_t(h));
            const int colour_type[5] = {0, 0, 4, 2, 6};
            CHECK(int(static_cast<unsigned char>(png[at + 16])) == 8);
            CHECK(int(static_cast<unsigned char>(png[at + 17])) == colour_type[channels]);
          }
          at += 12 + len;
        }
        CHECK(at == png.size());
        REQUIRE(types == std::vector<std::string>{"IHDR", "IDAT", "IEND"});
        CHECK(be32(png, png.size() - 4) == 0xAE426082u);  // IEND's CRC, as the specification prints it
        int dw = 0, dh = 0, dc = 0;
        unsigned char* back = stbi_load_from_memory(reinterpret_cast<const stbi_uc*>(png.data()), int(png.size()), &dw,
                                                    &dh, &dc, channels);
        REQUIRE(back != nullptr);
        CHECK(dw == w);
        CHECK(dh == h);
        CHECK(dc == channels);
        CHECK(std::equal(px.begin(), px.end(), back));
        stbi_image_free(back);
      }
  CHECK_THROWS_WITH(png_encode(nullptr, 0, 3, 3), Catch::Contains("empty image"));
  const unsigned char one[5] = {};
  CHECK_THROWS_WITH(png_encode(one, 1, 1, 5), Catch::Contains("1..4 channels"));
}

TEST_CASE("PNG output rounds every value as std::lround(v * 255)", "[io][image][png]") {
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  Image<float> img(256, 64, 3);
  for (std::size_t i = 0; i < img.data.size(); ++i) {
    // Values a hair either side of each half step, and uniform ones.
    const float half = (float(i % 255) + 0.5f) / 255.0f;
    img.data[i] = i % 3 == 0 ? u(rng) : std::nextafter(half, i % 3 == 1 ? 0.0f : 1.0f);
  }
  const std::string png = png_bytes(img);
  int w = 0, h = 0, c = 0;
  unsigned char* back =
      stbi_load_from_memory(reinterpret_cast<const stbi_uc*>(png.data()), int(png.size()), &w, &h, &c, 3);
  REQUIRE(back != nullptr);
  REQUIRE(w * h * 3 == int(img.data.size()));
  std::size_t wrong = 0;
  for (std::size_t i = 0; i < img.data.size(); ++i)
    wrong += long(back[i]) != std::lround(double(img.data[i]) * 255.0) ? 1 : 0;
  stbi_image_free(back);
  CHECK(wrong == 0);
}

TEST_CASE("image readers convert grey and RGBA to RGB", "[io][image]") {
  Image<float> grey(4, 3, 1), rgba(4, 3, 4);
  for (std::size_t i = 0; i < grey.data.size(); ++i) grey.data[i] = float(i * 20) / 255.0f;
  for (std::size_t i = 0; i < rgba.data.size(); ++i) rgba.data[i] = float(i * 5 % 256) / 255.0f;
  write_png((scratch_dir("image_io") / "grey.png").string(), grey);
  write_png((scratch_dir("image_io") / "rgba.png").string(), rgba);
  const auto g = read_image<float>((scratch_dir("image_io") / "grey.png").string());
  const auto r = read_image<float>((scratch_dir("image_io") / "rgba.png").string());
  REQUIRE(g.channels == 3);
  REQUIRE(r.channels == 3);
  for (int y = 0; y < 3; ++y)
    for (int x = 0; x < 4; ++x)
      for (int c = 0; c < 3; ++c) {
        REQUIRE(g(x, y, c) == grey(x, y, 0));
        REQUIRE(r(x, y, c) == rgba(x, y, c));
      }
}

TEMPLATE_TEST_CASE("PFM round trip is bit-exact and stores the bottom row first", "[io][image][pfm]", float,
                   double) {
  using T = TestType;
  std::mt19937 rng(2);
  std::normal_distribution<float> nd(0.0f, 100.0f);
  Image<T> img(5, 4, 3);
  for (auto& v : img.data) v = T(nd(rng));
  img.data[0] = T(std::numeric_limits<float>::denorm_min());
  img.data[1] = T(-0.0f);
  img.data[2] = T(std::numeric_limits<float>::infinity());
  img.data[3] = T(1e30f);
  const auto path = (scratch_dir("image_io") / "rt.pfm").string();
  write_pfm(path, img);
  const auto back = read_pfm<T>(path);
  REQUIRE(back.same_shape(img));
  for (std::size_t i = 0; i < img.data.size(); ++i) {
    const float a = float(img.data[i]), b = float(back.data[i]);
    REQUIRE(std::memcmp(&a, &b, 4) == 0);
  }

  // The raw bytes, as the format defines them.
  const std::string raw = slurp(path);
  const std::string header = "PF\n5 4\n-1.0\n";
  REQUIRE(raw.compare(0, header.size(), header) == 0);
  REQUIRE(raw.size() == header.size() + 5 * 4 * 3 * 4);
  for (int row = 0; row < 4; ++row)  // stored row 0 = image row 3 (bottom)
    for (int x = 0; x < 5; ++x)
      for (int c = 0; c < 3; ++c) {
        const float stored = le_float(raw, header.size() + (std::size_t(row) * 5 * 3 + std::size_t(x) * 3 + c) * 4);
        const float expect = float(img(x, 3 - row, c));
        REQUIRE(std::memcmp(&stored, &expect, 4) == 0);
      }

  // One channel: "Pf".
  Image<T> grey(2, 2, 1);
  grey.data = {T(1), T(2), T(3), T(4)};
  write_image((scratch_dir("image_io") / "g.pfm").string(), grey);
  const std::string graw = slurp(scratch_dir("image_io") / "g.pfm");
  REQUIRE(graw.compare(0, 11, "Pf\n2 2\n-1.0") == 0);
  REQUIRE(le_float(graw, 12) == 3.0f);
  REQUIRE(le_float(graw, 24) == 2.0f);
  REQUIRE(read_pfm<T>((scratch_dir("image_io") / "g.pfm").string()).data == grey.data);
  // read_image gives RGB for any input.
  REQUIRE(read_image<T>((scratch_dir("image_io") / "g.pfm").string()).channels == 3);
}

TEST_CASE("PFM reader: big endian, whitespace, errors", "[io][image][pfm]") {
  // Hand-made big-endian (positive scale) 2x1 grey file with CRLF-free spacing.
  std::string be = "Pf\n2 1\n1.0\n";
  const float vals[2] = {1.5f, -2.25f};
  for (float v : vals) {
    unsigned char b[4];
    std::memcpy(b, &v, 4);
    for (int i = 3; i >= 0; --i) be.push_back(char(b[i]));
  }
  const auto img = decode_pfm<float>(be, "be.pfm");
  REQUIRE(img.width == 2);
  REQUIRE(img.height == 1);
  REQUIRE(img.data[0] == 1.5f);
  REQUIRE(img.data[1] == -2.25f);

  auto has = [](const std::string& msg, const std::string& part) {
    INFO("message: " << msg);
    REQUIRE(msg.find("x.pfm") != std::string::npos);
    REQUIRE(msg.find(part) != std::string::npos);
  };
  has(error_of([&] { decode_pfm<float>(be.substr(0, be.size() - 1), "x.pfm"); }), "truncated");
  has(error_of([&] { decode_pfm<float>("P6\n2 1\n255\n", "x.pfm"); }), "not a PFM");
  has(error_of([&] { decode_pfm<float>("PF\n2 -1\n-1.0\n", "x.pfm"); }), "height");
  has(error_of([&] { decode_pfm<float>("PF\n2 1\n0\n", "x.pfm"); }), "scale");
  has(error_of([&] { decode_pfm<float>("PF\n2 1\n", "x.pfm"); }), "missing scale");
  has(error_of([&] { decode_pfm<float>("PF\n99999999 99999999\n-1\n", "x.pfm"); }), "width");
  has(error_of([&] { decode_pfm<float>("PF\n9999 9999\n-1\n", "x.pfm"); }), "truncated");
  has(error_of([&] { decode_image<float>("garbage bytes", "x.pfm"); }), "cannot decode");
  has(error_of([&] { read_image<float>((scratch_dir("image_io") / "x.pfm" / "missing").string()); }), "does not exist");
  has(error_of([&] { write_image((scratch_dir("image_io") / "x.pfm.bmp").string(), Image<float>(2, 2, 3)); }), "unsupported");
  has(error_of([&] { write_pfm((scratch_dir("image_io") / "x.pfm").string(), Image<float>(2, 2, 2)); }), "1 or 3 channels");
}

TEST_CASE("JPEG read of a recorded frame", "[io][image][shared]") {
  const std::string rel = "v3d/doll/images/001.jpg";
  if (!orbitforge_test::have_shared_data(rel)) return;
  const auto img = read_image<float>(orbitforge_test::shared_path(rel));
  REQUIRE(img.width == 512);
  REQUIRE(img.height == 512);
  REQUIRE(img.channels == 3);
  double mean = 0, mean2 = 0;
  for (float v : img.data) {
    REQUIRE((v >= 0.0f && v <= 1.0f));
    mean += v;
    mean2 += double(v) * v;
  }
  mean /= double(img.data.size());
  mean2 /= double(img.data.size());
  REQUIRE((mean > 0.05 && mean < 0.95));
  REQUIRE(std::sqrt(mean2 - mean * mean) > 0.02);  // a picture, not a flat field
}

TEMPLATE_TEST_CASE("resize_image", "[io][image][resize]", float, double) {
  using T = TestType;
  const T tol = std::is_same<T, float>::value ? T(1e-5) : T(1e-12);

  SECTION("area: integer shrink is the box mean") {
    Image<T> in(4, 4, 1);
    for (int y = 0; y < 4; ++y)
      for (int x = 0; x < 4; ++x) in(x, y) = T(x + 10 * y);
    const auto out = resize_image(in, 2, 2, ResizeFilter::area);
    REQUIRE(out(0, 0) == Approx((0 + 1 + 10 + 11) / 4.0).margin(tol));
    REQUIRE(out(1, 1) == Approx((22 + 23 + 32 + 33) / 4.0).margin(tol));
  }
  SECTION("area: fractional footprints keep the mean") {
    std::mt19937 rng(3);
    Image<T> in(7, 5, 3);
    for (auto& v : in.data) v = T(rng() % 1000) / T(1000);
    const auto out = resize_image(in, 3, 2, ResizeFilter::area);
    REQUIRE(out.width == 3);
    REQUIRE(out.height == 2);
    for (int c = 0; c < 3; ++c) {
      double a = 0, b = 0;
      for (int y = 0; y < 5; ++y)
        for (int x = 0; x < 7; ++x) a += double(in(x, y, c));
      for (int y = 0; y < 2; ++y)
        for (int x = 0; x < 3; ++x) b += double(out(x, y, c));
      REQUIRE(b / 6 == Approx(a / 35).margin(tol));
    }
    // Output pixel (0,0) covers x in [0, 7/3), y in [0, 2.5): weights by overlap.
    double expect = 0;
    const double wx[3] = {1, 1, 1.0 / 3}, wy[3] = {1, 1, 0.5};
    for (int y = 0; y < 3; ++y)
      for (int x = 0; x < 3; ++x) expect += wx[x] * wy[y] * double(in(x, y, 1));
    expect /= (7.0 / 3) * 2.5;
    REQUIRE(double(out(0, 0, 1)) == Approx(expect).margin(tol));
  }
  SECTION("constant images stay constant, both filters, up and down") {
    Image<T> in(9, 6, 3, T(0.375));
    for (auto f : {ResizeFilter::area, ResizeFilter::bilinear})
      for (auto wh : {std::pair<int, int>{4, 5}, {20, 13}, {1, 1}, {512, 3}}) {
        const auto out = resize_image(in, wh.first, wh.second, f);
        for (T v : out.data) REQUIRE(v == Approx(T(0.375)).margin(tol));
      }
  }
  SECTION("bilinear reproduces a linear ramp inside the image") {
    Image<T> in(8, 8, 1);
    for (int y = 0; y < 8; ++y)
      for (int x = 0; x < 8; ++x) in(x, y) = T(2 * x + 3 * y);
    const auto out = resize_image(in, 16, 16, ResizeFilter::bilinear);
    // Output centre (X + 0.5) / 2 - 0.5 in input pixels; away from the clamped border.
    for (int y = 1; y < 15; ++y)
      for (int x = 1; x < 15; ++x) {
        const double ix = (x + 0.5) / 2 - 0.5, iy = (y + 0.5) / 2 - 0.5;
        REQUIRE(double(out(x, y)) == Approx(2 * ix + 3 * iy).margin(tol * 10));
      }
  }
  SECTION("bad sizes") {
    REQUIRE_THROWS_AS(resize_image(Image<T>(2, 2, 3), 0, 2), Error);
    REQUIRE_THROWS_AS(resize_image(Image<T>(), 2, 2), Error);
  }
}

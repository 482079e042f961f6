// Frame-size and memory limits of the renderer (core/limits.hpp): refused before
// anything is allocated, with the size, the estimate and the limit named; an
// allocation that fails anyway becomes OutOfMemory saying what it was for.
#include <catch2/catch.hpp>

#include <fstream>
#include <limits>
#include <random>
#include <string>

#include "orbitforge/splat/renderer.hpp"

#if defined(__linux__)
#include <sys/resource.h>
#endif

#include "support/sanitizer.hpp"  // ORBITFORGE_TEST_SANITIZED

using namespace orbitforge;

namespace {

Camera<float> limits_camera(int w, int h) {
  Camera<float> cam;
  cam.intrinsics = {float(w), float(w), 0.5f * float(w), 0.5f * float(h), w, h};
  cam.R.setIdentity();
  cam.t = Eigen::Vector3f(0, 0, 4);
  return cam;
}

// n Gaussians near the optical axis, each `log_scale` wide.
GaussianScene<float> limits_scene(std::size_t n, float log_scale) {
  std::mt19937 rng(5);
  std::uniform_real_distribution<float> u(-0.3f, 0.3f);
  GaussianScene<float> s;
  s.resize(n, 0);
  for (std::size_t i = 0; i < n; ++i) {
    for (int a = 0; a < 3; ++a) s.means[3 * i + std::size_t(a)] = u(rng);
    s.rotations[4 * i] = 1;
    for (int a = 0; a < 3; ++a) s.log_scales[3 * i + std::size_t(a)] = log_scale;
    s.opacity_logits[i] = 2;
  }
  for (auto& v : s.sh) v = 0.5f;
  return s;
}

std::string render_error(Renderer<float>& r, const GaussianScene<float>& s, const Camera<float>& cam) {
  try {
    r.render(SceneView<float>(s), cam);
  } catch (const Error& e) {
    return e.what();
  }
  return "";
}

bool has(const std::string& text, const std::string& part) { return text.find(part) != std::string::npos; }

}  // namespace

TEST_CASE("renderer refuses frames over the pixel and memory limits before allocating", "[render][limits]") {
  Limits l = limits();
  l.max_memory_bytes = std::uint64_t(8) << 30;
  l.max_image_pixels = std::uint64_t(1) << 28;
  ScopedLimits scope(l);
  const auto scene = limits_scene(50, -2.5f);
  RenderParams<float> p;
  p.threads = 2;
  Renderer<float> r(p);

  SECTION("30000 x 30000: the estimate is over the memory limit") {
    l.max_image_pixels = std::uint64_t(1) << 32;  // let the memory check speak
    set_limits(l);
    const std::string e = render_error(r, scene, limits_camera(30000, 30000));
    INFO(e);
    CHECK(has(e, "30000x30000 frame"));
    CHECK(has(e, "900000000 pixels at 34 bytes"));
    CHECK(has(e, "needs about 28.6 GiB"));
    CHECK(has(e, "over the memory limit of 8.0 GiB"));
    CHECK(r.output().color.empty());  // nothing was allocated
  }
  SECTION("30000 x 30000 and 2e9 x 1: over the pixel limit") {
    for (const auto& [w, h] : {std::pair<int, int>{30000, 30000}, std::pair<int, int>{2000000000, 1}}) {
      const std::string e = render_error(r, scene, limits_camera(w, h));
      INFO(e);
      CHECK(has(e, std::to_string(w) + "x" + std::to_string(h) + " frame (" +
                       std::to_string(std::uint64_t(w) * std::uint64_t(h)) + " pixels, about "));
      CHECK(has(e, "over the limit of 268435456 pixels"));
      CHECK(r.output().color.empty());
    }
  }
  SECTION("2e9 x 1 with the pixel limit lifted: the rasterizer's side limit") {
    l.max_image_pixels = std::uint64_t(1) << 40;
    l.max_memory_bytes = std::uint64_t(1) << 50;
    set_limits(l);
    const std::string e = render_error(r, scene, limits_camera(2000000000, 1));
    INFO(e);
    CHECK(has(e, "2000000000x1 frame; the rasterizer takes sides under 8388608"));
  }
  SECTION("frames within the limits render") {
    const auto& out = r.render(SceneView<float>(scene), limits_camera(64, 48));
    CHECK(out.color.width == 64);
    CHECK(out.frame.gaussians_visible > 0);
  }
  SECTION("tile lists over the memory limit are refused once counted") {
    // 112 x 112: 7 x 7 tiles, about 0.4 MiB of frame buffers; 8000 wide splats list
    // in every tile: 392000 entries of 4 bytes, 1.5 MiB of lists.
    const auto wide = limits_scene(8000, 0.0f);
    const auto cam = limits_camera(112, 112);
    l.max_memory_bytes = std::uint64_t(1) << 20;
    set_limits(l);
    REQUIRE(frame_memory_estimate(112, 112, 16, 2, sizeof(float)) < l.max_memory_bytes);
    const std::string e = render_error(r, wide, cam);
    INFO(e);
    CHECK(has(e, "bin_splats: the tile lists of a 112x112 frame"));
    CHECK(has(e, "over the memory limit of 1.0 MiB"));
    l.max_memory_bytes = std::uint64_t(64) << 20;
    set_limits(l);
    CHECK(r.render(SceneView<float>(wide), cam).frame.tile_entries > 100000);
  }
}

TEST_CASE("frame_memory_estimate: 34 bytes per float pixel plus per-tile arrays, saturating", "[render][limits]") {
  CHECK(frame_bytes_per_pixel(4) == 34);
  const std::uint64_t tiles = 64 * 64;
  CHECK(frame_memory_estimate(1024, 1024, 16, 2, 4) == 1024u * 1024u * 34u + tiles * (4 * 2 + 8));
  CHECK(frame_memory_estimate(std::uint64_t(1) << 40, std::uint64_t(1) << 40, 16, 2, 4) == UINT64_MAX);
}

TEST_CASE("Image refuses sizes over the pixel limit", "[render][limits]") {
  Limits l = limits();
  l.max_image_pixels = 1000;
  ScopedLimits scope(l);
  CHECK_NOTHROW(Image<float>(40, 25, 3));
  try {
    Image<float> img(40, 26, 3);
    FAIL("no error");
  } catch (const Error& e) {
    CHECK(has(e.what(), "Image: a 40x26 image (1040 pixels) is over the limit of 1000 pixels"));
  }
}

// A frame within the configured limit that the process still cannot allocate
// (here: address space capped with RLIMIT_AS) ends in OutOfMemory naming the frame
// and the estimate, not a bare std::bad_alloc.
TEST_CASE("an allocation failure while rendering says what was being allocated", "[render][limits]") {
#if !defined(__linux__) || defined(ORBITFORGE_TEST_SANITIZED)
  SUCCEED("needs Linux RLIMIT_AS without a sanitizer's shadow memory");
#else
  std::uint64_t mapped = 0;
  {
    std::ifstream in("/proc/self/status");
    std::string key;
    while (in >> key) {
      if (key == "VmSize:") {
        in >> mapped;
        mapped *= 1024;
        break;
      }
      std::getline(in, key);
    }
  }
  REQUIRE(mapped > 0);
  const auto scene = limits_scene(20, -2.5f);
  RenderParams<float> p;
  p.threads = 1;
  Renderer<float> r(p);
  Limits l = limits();
  l.max_memory_bytes = std::uint64_t(1) << 40;
  ScopedLimits scope(l);
  struct rlimit saved;
  REQUIRE(getrlimit(RLIMIT_AS, &saved) == 0);
  struct rlimit tight = saved;
  tight.rlim_cur = rlim_t(mapped + (std::uint64_t(64) << 20));  // a 6000 x 6000 frame needs ~1.1 GiB
  if (saved.rlim_cur != RLIM_INFINITY && saved.rlim_cur < tight.rlim_cur) tight.rlim_cur = saved.rlim_cur;
  REQUIRE(setrlimit(RLIMIT_AS, &tight) == 0);
  std::string message;
  try {
    r.render(SceneView<float>(scene), limits_camera(6000, 6000));
    message = "rendered";
  } catch (const OutOfMemory& e) {
    message = e.what();
  } catch (const std::bad_alloc&) {
    message = "bare std::bad_alloc";
  }
  setrlimit(RLIMIT_AS, &saved);
  INFO(message);
  CHECK(has(message, "out of memory while rendering a 6000x6000 frame of 20 Gaussians (about 1.1 GiB requested)"));
#endif
}

TEST_CASE("non-finite Gaussians: every one skipped is an error, more than 1 % a warning", "[render][nonfinite]") {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  RenderParams<float> p;
  p.threads = 1;
  Renderer<float> r(p);
  const auto cam = limits_camera(32, 24);
  auto scene = limits_scene(200, -2.5f);
  SECTION("all non-finite") {
    for (std::size_t i = 0; i < scene.size(); ++i) scene.opacity_logits[i] = nan;
    const std::string e = render_error(r, scene, cam);
    INFO(e);
    CHECK(has(e, "all 200 Gaussians of the scene were skipped as non-finite"));
  }
  SECTION("2 % non-finite warns, 0.5 % does not") {
    scene.means[0] = nan;
    const auto& quiet = r.render(SceneView<float>(scene), cam);
    CHECK(quiet.frame.projection.culled_nonfinite == 1);
    CHECK(nonfinite_warning(quiet.frame).empty());
    scene.log_scales[3 * 7] = std::numeric_limits<float>::infinity();
    scene.rotations[4 * 9] = nan;
    scene.sh[3 * 11] = nan;
    const auto& out = r.render(SceneView<float>(scene), cam);
    CHECK(out.frame.projection.culled_nonfinite == 4);
    const std::string w = nonfinite_warning(out.frame);
    INFO(w);
    CHECK(has(w, "4 of 200 Gaussians (2 %) were skipped as non-finite"));
  }
}

// The configuration macros of core/config.hpp besides ORBITFORGE_NO_SIMD (which
// render/test_scalar_build.cpp compiles), each defined before the includes as a
// host program would, in a program of their own:
//   ORBITFORGE_DEFAULT_THREADS 3       thread count 0 ("the default") means 3;
//   ORBITFORGE_NO_STB_IMPLEMENTATION   io/image_io.hpp compiles no stb of its own
//     and uses the host's, defined below with external linkage: were image_io's
//     static copy compiled too, the two definitions would clash in this unit.
#define ORBITFORGE_DEFAULT_THREADS 3
#define ORBITFORGE_NO_STB_IMPLEMENTATION 1
#include <catch2/catch.hpp>

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <string>

#include "orbitforge/core/parallel_for.hpp"
#include "orbitforge/io/image_io.hpp"

// The host's own stb implementation.
#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wunused-but-set-variable"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#pragma GCC diagnostic ignored "-Wtype-limits"
#pragma GCC diagnostic ignored "-Wshadow"
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wcast-qual"
#pragma GCC diagnostic ignored "-Wold-style-cast"
#endif
#define STB_IMAGE_IMPLEMENTATION
#if __has_include(<stb_image.h>)
#include <stb_image.h>
#else
#include <stb/stb_image.h>
#endif
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

using namespace orbitforge;

static_assert(ORBITFORGE_DEFAULT_THREADS == 3, "the host's definition is kept");

TEST_CASE("ORBITFORGE_DEFAULT_THREADS sets the default thread count", "[io][config]") {
  const int expect = std::min(3, limits().max_threads);
  CHECK(resolve_threads(0) == expect);
  CHECK(resolve_threads(2) == 2);  // an explicit count is kept
}

TEST_CASE("ORBITFORGE_NO_STB_IMPLEMENTATION: image_io runs on the host's stb", "[io][config]") {
  Image<float> img(5, 3, 3);
  for (std::size_t k = 0; k < img.data.size(); ++k) img.data[k] = float(k % 7) / 6.0f;
  const std::string path = "orbitforge_config_macros_" + std::to_string(::getpid()) + ".png";
  write_png(path, img);
  const Image<float> back = read_image(path);
  std::remove(path.c_str());
  REQUIRE(back.width == 5);
  REQUIRE(back.height == 3);
  for (std::size_t k = 0; k < img.data.size(); ++k) CHECK(back.data[k] == Approx(img.data[k]).margin(0.51 / 255));
}

// PNG output: png_bytes (io/png_encode.hpp: Paeth rows, zlib's run-length
// deflate) against stb_image_write's encoder (its default: the best of five
// filters per row, its own deflate at level 8), one thread, on a shaded,
// textured ball on a white backdrop (what the pipeline's orbit renders look
// like) or on the image named by ORBITFORGE_BENCH_IMAGE:
//
//   build-bench/bench/bench_io
//   ORBITFORGE_BENCH_IMAGE=out/pipeline/R1/0000.png build-bench/bench/bench_io
//
// Counters: ms per image and the file's size in bytes.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "orbitforge/io/image_io.hpp"

#if defined(__GNUC__)
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wsign-compare"
#pragma GCC diagnostic ignored "-Wunused-parameter"
#pragma GCC diagnostic ignored "-Wunused-function"
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wimplicit-fallthrough"
#pragma GCC diagnostic ignored "-Wconversion"
#pragma GCC diagnostic ignored "-Wdouble-promotion"
#pragma GCC diagnostic ignored "-Wold-style-cast"
#endif
#define STBIW_STATIC
#define STB_IMAGE_WRITE_IMPLEMENTATION
#include <stb/stb_image_write.h>  // Debian's libstb-dev layout
#if defined(__GNUC__)
#pragma GCC diagnostic pop
#endif

using namespace orbitforge;

namespace {

Image<float> ball_on_backdrop(int w, int h) {
  Image<float> img(w, h, 3);
  const float cx = 0.5f * float(w), cy = 0.5f * float(h), r = 0.35f * float(std::min(w, h));
  const float base[3] = {0.8f, 0.55f, 0.3f};
  for (int y = 0; y < h; ++y)
    for (int x = 0; x < w; ++x) {
      const float dx = (float(x) - cx) / r, dy = (float(y) - cy) / r, d2 = dx * dx + dy * dy;
      for (int c = 0; c < 3; ++c) {
        float v = 1.0f;  // white backdrop
        if (d2 < 1.0f) {
          const float nz = std::sqrt(1.0f - d2);
          const float light = std::max(0.0f, 0.3f * -dx + 0.4f * -dy + 0.87f * nz);
          const float texture = 0.85f + 0.15f * std::sin(23.0f * dx) * std::sin(17.0f * dy);
          v = base[c] * (0.15f + 0.85f * light) * texture;
        }
        img(x, y, c) = v;
      }
    }
  return img;
}

Image<float> bench_image(int w, int h) {
  const char* path = std::getenv("ORBITFORGE_BENCH_IMAGE");
  return path && *path ? read_image<float>(path) : ball_on_backdrop(w, h);
}

void stb_append(void* context, void* data, int size) {
  static_cast<std::string*>(context)->append(static_cast<const char*>(data), std::size_t(size));
}

// Args: width, height
void BM_PngBytes(benchmark::State& state) {
  const Image<float> img = bench_image(int(state.range(0)), int(state.range(1)));
  std::size_t bytes = 0;
  for (auto _ : state) {
    const std::string png = png_bytes(img);
    bytes = png.size();
    benchmark::DoNotOptimize(png.data());
  }
  state.counters["bytes"] = double(bytes);
}

// The same 8-bit conversion, then stb_image_write's encoder.
void BM_PngBytesStb(benchmark::State& state) {
  const Image<float> img = bench_image(int(state.range(0)), int(state.range(1)));
  std::size_t bytes = 0;
  for (auto _ : state) {
    std::vector<unsigned char> px(img.data.size());
    for (std::size_t i = 0; i < px.size(); ++i) {
      const float v = img.data[i];
      px[i] = v > 0.0f ? (v < 1.0f ? static_cast<unsigned char>(std::lround(double(v) * 255.0)) : 255) : 0;
    }
    std::string png;
    stbi_write_png_to_func(&stb_append, &png, img.width, img.height, img.channels, px.data(),
                           img.width * img.channels);
    bytes = png.size();
    benchmark::DoNotOptimize(png.data());
  }
  state.counters["bytes"] = double(bytes);
}

void sizes(benchmark::internal::Benchmark* b) {
  b->ArgNames({"w", "h"})->Args({512, 512})->Args({896, 512})->Unit(benchmark::kMillisecond);
}

}  // namespace

BENCHMARK(BM_PngBytes)->Apply(sizes);
BENCHMARK(BM_PngBytesStb)->Apply(sizes);

BENCHMARK_MAIN();

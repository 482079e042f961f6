#pragma once
// The background colour a reconstruction is trained and scored against,
// estimated from the data: the pixels along the image borders of the training
// frames. Generated orbit videos and studio captures show one plain colour
// there; a cluttered scene does not, and then the stated default is used.
//
// Rule: take every pixel within `band` of an image edge (a band of
// band_fraction * min(W, H) pixels, at least 1) of every frame; the estimate is
// the per-channel median. The borders agree when at least min_agreement of
// those pixels lie within `tolerance` (max over channels) of it; then the
// median is used, snapped to pure white or black when every channel is within
// snap of it (JPEG noise around a white studio). Otherwise: fallback.
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <random>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"

namespace orbitforge {

struct BackgroundParams {
  double band_fraction = 0.02;
  double tolerance = 0.08;      // per channel, in [0, 1]
  double min_agreement = 0.9;   // share of border pixels within tolerance of the median
  double snap = 2.0 / 255.0;
  std::array<double, 3> fallback{{0, 0, 0}};  // 3DGS's default background
  // When the borders disagree the backdrop is part of the scene: train on a
  // random colour per iteration (TrainParams::random_background) so that the
  // model explains it; `fallback` is then the colour of every other render.
  bool random_when_disagreeing = true;
  std::size_t max_samples = 400000;           // border pixels examined (evenly strided beyond this)
};

struct BackgroundEstimate {
  std::array<double, 3> color{{0, 0, 0}};
  bool from_data = false;   // the borders agreed
  bool random = false;      // train on a random colour per iteration (borders disagree)
  double agreement = 0;     // share of border pixels within tolerance of the median
  std::array<double, 3> border_median{{0, 0, 0}};
  std::string reason;       // one sentence for reports
};

template <class Scalar>
BackgroundEstimate estimate_background(const std::vector<const Image<Scalar>*>& frames,
                                       const BackgroundParams& p = {}) {
  ensure(p.band_fraction > 0 && p.band_fraction < 0.5, "estimate_background: band_fraction must be in (0, 0.5)");
  ensure(p.tolerance > 0 && p.min_agreement > 0 && p.min_agreement <= 1,
         "estimate_background: tolerance must be positive and min_agreement in (0, 1]");
  std::size_t total = 0;
  for (const Image<Scalar>* f : frames) {
    if (!f || f->empty()) continue;
    ensure(f->channels >= 3, "estimate_background: frames must be RGB, got ", f->channels, " channels");
    const int band = std::max(1, int(std::lround(p.band_fraction * std::min(f->width, f->height))));
    const std::size_t inner = std::size_t(std::max(0, f->width - 2 * band)) * std::size_t(std::max(0, f->height - 2 * band));
    total += std::size_t(f->width) * std::size_t(f->height) - inner;
  }
  BackgroundEstimate e;
  if (total == 0) {
    e.color = p.fallback;
    e.reason = "no frames to look at; default background";
    return e;
  }
  const std::size_t stride = std::max<std::size_t>(1, (total + p.max_samples - 1) / p.max_samples);
  std::array<std::vector<float>, 3> ch;
  std::size_t k = 0;
  for (const Image<Scalar>* f : frames) {
    if (!f || f->empty()) continue;
    const int band = std::max(1, int(std::lround(p.band_fraction * std::min(f->width, f->height))));
    for (int y = 0; y < f->height; ++y) {
      const bool row_in_band = y < band || y >= f->height - band;
      for (int x = 0; x < f->width; ++x) {
        if (!row_in_band && x >= band && x < f->width - band) {
          x = f->width - band - 1;  // skip the interior of the row
          continue;
        }
        if (k++ % stride) continue;
        const Scalar* px = &f->data[(std::size_t(y) * std::size_t(f->width) + std::size_t(x)) * std::size_t(f->channels)];
        for (int c = 0; c < 3; ++c) ch[std::size_t(c)].push_back(float(std::min(Scalar(1), std::max(Scalar(0), px[c]))));
      }
    }
  }
  const std::size_t n = ch[0].size();
  std::array<float, 3> med{};
  for (int c = 0; c < 3; ++c) {
    std::vector<float> v = ch[std::size_t(c)];
    std::nth_element(v.begin(), v.begin() + std::ptrdiff_t(n / 2), v.end());
    med[std::size_t(c)] = v[n / 2];
    e.border_median[std::size_t(c)] = double(med[std::size_t(c)]);
  }
  std::size_t agree = 0;
  for (std::size_t i = 0; i < n; ++i) {
    float d = 0;
    for (int c = 0; c < 3; ++c) d = std::max(d, std::abs(ch[std::size_t(c)][i] - med[std::size_t(c)]));
    agree += d <= float(p.tolerance) ? 1 : 0;
  }
  e.agreement = double(agree) / double(n);
  char buf[320];
  if (e.agreement >= p.min_agreement) {
    e.from_data = true;
    e.color = e.border_median;
    bool white = true, black = true;
    for (double v : e.color) {
      white = white && v >= 1.0 - p.snap;
      black = black && v <= p.snap;
    }
    if (white) e.color = {{1, 1, 1}};
    if (black) e.color = {{0, 0, 0}};
    std::snprintf(buf, sizeof(buf), "%.1f%% of the frames' border pixels lie within %.2f of their median colour",
                  100.0 * e.agreement, p.tolerance);
  } else {
    e.color = p.fallback;
    e.random = p.random_when_disagreeing;
    std::snprintf(buf, sizeof(buf),
                  "the frames' borders disagree (only %.1f%% of their pixels within %.2f of the median, need %.0f%%); "
                  "%s",
                  100.0 * e.agreement, p.tolerance, 100.0 * p.min_agreement,
                  e.random ? "training draws a random background colour each iteration, other renders use the default"
                           : "default background");
  }
  e.reason = buf;
  return e;
}

// The background of training iteration `it` with TrainParams::random_background:
// uniform in [0, 1)^3, drawn from a generator seeded by (seed, it) alone, so a
// run resumed from a checkpoint draws the same colours.
inline std::array<double, 3> random_background_at(unsigned seed, int it) {
  std::seed_seq seq{seed, unsigned(it), 0x6267u};
  std::mt19937 rng(seq);
  std::uniform_real_distribution<double> u(0.0, 1.0);
  return {{u(rng), u(rng), u(rng)}};
}

// A colour as a renderer's background (RenderParams::background) holds it.
template <class Scalar>
std::array<Scalar, 3> background_color(const std::array<double, 3>& c) {
  return {{Scalar(c[0]), Scalar(c[1]), Scalar(c[2])}};
}

}  // namespace orbitforge

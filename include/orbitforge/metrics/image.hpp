#pragma once
// Image quality metrics for images with values in [0, 1] (core/image.hpp layout):
//
//   mse        mean (a - b)^2 over pixels and channels
//   psnr       10 log10(1 / MSE) dB; +infinity for identical images (MSE == 0)
//   ssim       the training SSIM of image/ssim.hpp (11x11 Gaussian, sigma 1.5, zero
//              padding, mean over pixels and channels), evaluated in double
//   mae_255    mean |a - b| * 255: the "L1 on the 0-255 scale" of the paper's
//              adjacent-frame and loop-endpoint diagnostics
//
// All sums run in double whatever the image precision. compare_images() bundles them
// for a rendered frame against a reference loaded from a file, with error messages
// that name the pair.
#include <algorithm>
#include <cmath>
#include <cstddef>
#include <limits>
#include <string>
#include <vector>

#include "orbitforge/core/error.hpp"
#include "orbitforge/core/image.hpp"
#include "orbitforge/image/ssim.hpp"

namespace orbitforge {

namespace metrics_detail {
template <class Scalar>
void check_pair(const char* who, const Image<Scalar>& a, const Image<Scalar>& b, const std::string& label) {
  const std::string what = label.empty() ? std::string() : " (" + label + ")";
  ensure(a.same_shape(b), who, what, ": images differ in shape, ", a.width, "x", a.height, "x", a.channels,
         " vs ", b.width, "x", b.height, "x", b.channels);
  ensure(!a.empty(), who, what, ": empty images");
  ensure(a.data.size() == a.pixel_count() * std::size_t(a.channels) && b.data.size() == a.data.size(), who,
         what, ": image data size does not match width x height x channels");
}
}  // namespace metrics_detail

template <class Scalar>
double mse(const Image<Scalar>& a, const Image<Scalar>& b) {
  metrics_detail::check_pair("mse", a, b, "");
  double s = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) {
    const double d = double(a.data[i]) - double(b.data[i]);
    s += d * d;
  }
  return s / double(a.data.size());
}

// PSNR for a peak value of 1. MSE == 0 (identical images) gives +infinity; a negative
// or NaN MSE is an error.
inline double psnr_from_mse(double mse_value) {
  ensure(mse_value >= 0, "psnr: mean squared error must be >= 0, got ", mse_value);
  if (mse_value == 0) return std::numeric_limits<double>::infinity();
  return -10.0 * std::log10(mse_value);
}

template <class Scalar>
double psnr(const Image<Scalar>& a, const Image<Scalar>& b) {
  return psnr_from_mse(mse(a, b));
}

template <class Scalar>
double mae_255(const Image<Scalar>& a, const Image<Scalar>& b) {
  metrics_detail::check_pair("mae_255", a, b, "");
  double s = 0;
  for (std::size_t i = 0; i < a.data.size(); ++i) s += std::abs(double(a.data[i]) - double(b.data[i]));
  return 255.0 * s / double(a.data.size());
}

// SSIM as in image/ssim.hpp, always evaluated in double (no float cancellation in
// the variance terms); symmetric in a and b.
template <class Scalar>
double ssim_metric(const Image<Scalar>& a, const Image<Scalar>& b, int threads = 0) {
  metrics_detail::check_pair("ssim", a, b, "");
  Image<double> da, db;
  da.width = db.width = a.width;
  da.height = db.height = a.height;
  da.channels = db.channels = a.channels;
  da.data.assign(a.data.begin(), a.data.end());
  db.data.assign(b.data.begin(), b.data.end());
  SsimWorkspace<double> ws;
  return ssim(da, db, ws, SsimParams{}, threads);
}
inline double ssim_metric(const Image<double>& a, const Image<double>& b, int threads = 0) {
  metrics_detail::check_pair("ssim", a, b, "");
  SsimWorkspace<double> ws;
  return ssim(a, b, ws, SsimParams{}, threads);
}

// The first `channels` channels of an image (e.g. drop the alpha of an RGBA file).
template <class Scalar>
Image<Scalar> keep_channels(const Image<Scalar>& img, int channels) {
  ensure(channels >= 1 && channels <= img.channels, "keep_channels: cannot keep ", channels, " of ",
         img.channels, " channels");
  Image<Scalar> out(img.width, img.height, channels);
  for (std::size_t p = 0; p < img.pixel_count(); ++p)
    for (int c = 0; c < channels; ++c) out.data[p * channels + c] = img.data[p * img.channels + c];
  return out;
}

// Values clamped to [0, 1], as an 8-bit file would store them (rendered colours may
// exceed 1 before they are saved).
template <class Scalar>
Image<Scalar> clamp01(Image<Scalar> img) {
  for (auto& v : img.data) v = std::min(Scalar(1), std::max(Scalar(0), v));
  return img;
}

struct ImageQuality {
  double psnr = 0;   // dB, +infinity when identical
  double ssim = 0;
  double mse = 0;
  double mae_255 = 0;
};

// A rendered image against a reference (e.g. a frame loaded from a file). Both must
// have the same shape and finite values; both are clamped to [0, 1] first, as the
// 3DGS evaluation does. `label` (e.g. the reference file name) is put in error messages.
template <class Scalar>
ImageQuality compare_images(const Image<Scalar>& rendered, const Image<Scalar>& reference,
                            const std::string& label = "", int threads = 0) {
  metrics_detail::check_pair("compare_images", rendered, reference, label);
  for (const Image<Scalar>* img : {&rendered, &reference}) {
    for (std::size_t i = 0; i < img->data.size(); ++i) {
      if (!std::isfinite(double(img->data[i]))) {
        const std::size_t p = i / std::size_t(img->channels);
        fail("compare_images", label.empty() ? "" : " (" + label + ")", ": ",
             img == &rendered ? "rendered" : "reference", " image has a non-finite value at pixel (",
             p % std::size_t(img->width), ", ", p / std::size_t(img->width), ") channel ",
             i % std::size_t(img->channels));
      }
    }
  }
  const Image<Scalar> a = clamp01(rendered), b = clamp01(reference);
  ImageQuality q;
  q.mse = mse(a, b);
  q.psnr = psnr_from_mse(q.mse);
  q.mae_255 = mae_255(a, b);
  q.ssim = ssim_metric(a, b, threads);
  return q;
}

// Means over a set of views (PSNR is averaged per view in dB, as 3DGS reports it; one
// identical view makes the mean +infinity).
struct QualityMean {
  double psnr = 0, ssim = 0, mae_255 = 0;
  std::size_t views = 0;
};

inline QualityMean mean_quality(const std::vector<ImageQuality>& views) {
  QualityMean m;
  m.views = views.size();
  if (views.empty()) return m;
  for (const auto& q : views) {
    m.psnr += q.psnr;
    m.ssim += q.ssim;
    m.mae_255 += q.mae_255;
  }
  m.psnr /= double(views.size());
  m.ssim /= double(views.size());
  m.mae_255 /= double(views.size());
  return m;
}

// Percentile with linear interpolation between order statistics (numpy's default):
// p in [0, 100]; used for the 95th percentile of adjacent-frame L1.
inline double percentile(std::vector<double> values, double p) {
  ensure(!values.empty(), "percentile: no values");
  ensure(p >= 0 && p <= 100, "percentile: p must be in [0, 100], got ", p);
  std::sort(values.begin(), values.end());
  const double pos = p / 100.0 * double(values.size() - 1);
  const std::size_t lo = std::size_t(std::floor(pos));
  const std::size_t hi = std::min(values.size() - 1, lo + 1);
  const double f = pos - double(lo);
  return values[lo] + f * (values[hi] - values[lo]);
}

// Frame-to-frame stability of a rendered sequence, the paper's static-proxy
// diagnostics: feed the frames in order (clamped to [0, 1] here); adjacent_l1 is
// the mean over consecutive pairs of mae_255, adjacent_l1_p95 its 95th percentile
// over pairs, loop_l1 = mae_255(last, first), the pair that crosses the orbit's
// start. Streams: only the first and the previous frame are kept.
struct SequenceStability {
  double adjacent_l1 = 0, adjacent_l1_p95 = 0, loop_l1 = 0;
  int frames = 0;
};

template <class Scalar>
class SequenceStabilityMeter {
 public:
  void add(const Image<Scalar>& frame) {
    Image<Scalar> f = clamp01(frame);
    if (frames_ == 0) {
      first_ = f;
    } else {
      metrics_detail::check_pair("SequenceStabilityMeter", prev_, f, "frame " + std::to_string(frames_));
      pairs_.push_back(mae_255(prev_, f));
    }
    prev_ = std::move(f);
    ++frames_;
  }
  SequenceStability result() const {
    ensure(frames_ >= 2, "SequenceStabilityMeter: need at least 2 frames, got ", frames_);
    SequenceStability r;
    r.frames = frames_;
    for (double v : pairs_) r.adjacent_l1 += v;
    r.adjacent_l1 /= double(pairs_.size());
    r.adjacent_l1_p95 = percentile(pairs_, 95);
    r.loop_l1 = mae_255(prev_, first_);
    return r;
  }

 private:
  Image<Scalar> first_, prev_;
  std::vector<double> pairs_;
  int frames_ = 0;
};

}  // namespace orbitforge
